#!/usr/bin/env python3
"""Reference radiances and fluxes of a homogeneous Henyey-Greenstein cloud slab from DISORT (pydisort).

Writes tests/data/cloud_slab_disort.json (the path tracer's slab check). Run from the repository root:

    python3 tools/cloud_slab_disort.py        # ~1 min

Setup: a laterally infinite, homogeneous, plane-parallel slab in vacuum over a black ground (Lambertian
albedo 0), Henyey-Greenstein phase function g = 0.85 (Legendre moments chi_l = g^l, NMOM of them),
optical thickness 1, 8, 32, 128, single-scattering albedo 1, 0.999, 0.99, collimated sun of unit
irradiance normal to the beam (fbeam = 1) at mu0 = cos(sun zenith) = 1 and 0.5; one layer.
cdisort always applies delta-M scaling (DISORT 2: truncation fraction f = chi_NSTR); the Nakajima-Tanaka
intensity correction is on ("intensity_correction,old_intensity_correction": the TMS single-scattering
correction with the full NMOM-moment phase function; pydisort 1.8.13's new Buras-Emde-Mayer correction
returns NaN without user phase-function tables, so it is not used).

Before writing, the script
  1. reruns DISORT's own published test problem 3 (Henyey-Greenstein g = 0.75, tau 1 and 8, mu0 = 1,
     16 streams, 32 moments, delta-M + Nakajima-Tanaka; "correct answers" from the DISOTEST.f of the
     DISORT 2.0 distribution, which compares with van de Hulst's tables) and requires agreement to the
     6 published digits,
  2. checks the thin-slab limit (tau = 1e-5) against analytic single scattering with the HG phase
     function over the whole view/azimuth grid, both outputs, both suns (this also pins the azimuth
     convention),
  3. checks energy conservation for albedo 1 (R + T = 1) and that every sun cosine stays at least
     1e-3 (relative) from a double-Gauss quadrature node (cdisort silently moves the sun otherwise),
  4. reruns every case with twice the streams (NSTR_CHECK) and records the largest relative change
     of each output (the convergence figure in the header); it must stay below STREAM_TOLERANCE.
Any failed check aborts without writing.
"""

import json
import math
import os
import sys
from importlib.metadata import version

import numpy as np
import torch
import pydisort
from pydisort import Disort, DisortOptions

torch.set_num_threads(1)

G = 0.85
TAUS = [1.0, 8.0, 32.0, 128.0]
ALBEDOS = [1.0, 0.999, 0.99]
MU0S = [1.0, 0.5]
VIEW_ZENITH_DEG = [0.0, 30.0, 60.0, 75.0]
RELATIVE_AZIMUTH_DEG = [0.0, 90.0, 180.0]
NSTR = 64
NSTR_CHECK = 128
NMOM = 400  # 0.85^400 ~ 5e-29: the HG series is complete for the intensity correction
FLAGS = "usrtau,usrang,lamber,quiet,intensity_correction,old_intensity_correction"
# cdisort moves the sun when |mu0 - node| / mu0 < 1e-4; with >= 80 streams the largest node lies within
# 1e-3 of mu0 = 1 (128 streams: 3.5e-4), so demand twice the cdisort tolerance.
NODE_MARGIN_REQUIRED = 2e-4
STREAM_TOLERANCE = 2e-3

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "cloud_slab_disort.json")


def hg_moments(g, nmom):
    """Legendre coefficients chi_1..chi_nmom of the Henyey-Greenstein phase function: chi_l = g^l."""
    return np.array([g ** (l + 1) for l in range(nmom)])


def hg_phase(g, cos_theta):
    """Henyey-Greenstein phase function normalised to 1 over the sphere, sr^-1."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


def double_gauss_nodes(nstr):
    t, _ = np.polynomial.legendre.leggauss(nstr // 2)
    return np.sort((t + 1.0) / 2.0)


def min_relative_node_distance(nstr, mu0):
    return float(np.min(np.abs(mu0 - double_gauss_nodes(nstr)) / mu0))


def run_disort(tau, ssa, g, nstr, nmom, umu0, fbeam, user_tau, user_mu, user_phi_deg, flags=FLAGS):
    """One single-layer DISORT solve. Returns (fluxes[ntau, 8], radiance[nphi, ntau, numu])."""
    op = DisortOptions().flags(flags)
    ds = op.ds()
    ds.nlyr = 1
    ds.nstr = nstr
    ds.nmom = nmom
    ds.nphase = nstr
    op.user_tau(np.asarray(user_tau, dtype=float))
    op.user_mu(np.asarray(user_mu, dtype=float))
    op.user_phi(np.asarray(user_phi_deg, dtype=float))
    solver = Disort(op)
    prop = torch.zeros((1, 1, 1, 2 + nmom), dtype=torch.float64)
    prop[0, 0, 0, 0] = tau
    prop[..., 1] = ssa
    prop[0, 0, 0, 2:] = torch.tensor(hg_moments(g, nmom))
    f64 = dict(dtype=torch.float64)
    solver.forward(
        prop,
        umu0=torch.tensor([umu0], **f64),
        phi0=torch.tensor([0.0], **f64),
        fbeam=torch.tensor([[fbeam]], **f64),
        albedo=torch.tensor([[0.0]], **f64),
    )
    return solver.gather_flx()[0, 0].numpy().copy(), solver.gather_rad()[0, 0].numpy().copy()


def check_published_test_problem_3():
    """DISOTEST problem 3 (HG g = 0.75, ssa 1, mu0 = 1, fbeam = pi, 16 streams, 32 moments).

    Correct answers from DISOTEST.f (DISORT 2.0), TSTFIR, TSTFDN, TSTFUP, TSTUU(itau, iumu) at
    utau = 0 and tau, umu = -1, -0.5, -0.1, 0.1, 0.5, 1."""
    umu = [-1.0, -0.5, -0.1, 0.1, 0.5, 1.0]
    published = {
        "3a": dict(tau=1.0, fir=[3.14159e+00, 1.15573e+00], fdn=[0.0, 1.73849e+00], fup=[2.47374e-01, 0.0],
                   uu=[[0, 0, 0, 1.51159e-01, 1.01103e-01, 3.95460e-02],
                       [3.05855e+00, 2.66648e-01, 2.13750e-01, 0, 0, 0]]),
        "3b": dict(tau=8.0, fir=[3.14159e+00, 1.05389e-03], fdn=[0.0, 1.54958e+00], fup=[1.59096e+00, 0.0],
                   uu=[[0, 0, 0, 3.79740e-01, 5.19598e-01, 4.93302e-01],
                       [6.69581e-01, 4.22350e-01, 2.36362e-01, 0, 0, 0]]),
    }
    result = {}
    worst = 0.0
    for name, p in published.items():
        flx, rad = run_disort(p["tau"], 1.0, 0.75, 16, 32, 1.0, math.pi, [0.0, p["tau"]], umu, [0.0])
        ours = np.concatenate([flx[:, pydisort.kIRFLDIR], flx[:, pydisort.kIFLDN], flx[:, pydisort.kIFLUP],
                               rad[0].ravel()])
        ref = np.concatenate([p["fir"], p["fdn"], p["fup"], np.ravel(p["uu"])])
        mask = np.abs(ref) > 0
        rel = float(np.max(np.abs(ours[mask] / ref[mask] - 1.0)))
        result[name] = {"tau": p["tau"], "max_rel_diff": rel}
        worst = max(worst, rel)
    if worst > 2e-5:
        sys.exit(f"DISOTEST problem 3 mismatch: {result}")
    return result


def user_mu_grid():
    """Increasing cosines: downward-travelling (negative) first, then upward."""
    mu = np.cos(np.radians(VIEW_ZENITH_DEG))
    return np.concatenate([-mu, mu[::-1]])


def split_radiance(rad):
    """rad[nphi, ntau=2, numu] -> (top upwelling, bottom downwelling), each [view_zenith][rel_azimuth]."""
    nv = len(VIEW_ZENITH_DEG)
    up_top = rad[:, 0, nv:][:, ::-1].T
    down_bottom = rad[:, 1, :nv].T
    return up_top, down_bottom


def check_single_scattering_limit():
    # At 1e-4 the O(tau) multiple scattering still adds up to 1.1e-3 to the weak back-scattered radiance
    # (HG g = 0.85); at 1e-6 cdisort loses precision. 1e-5 leaves 3e-4.
    tau = 1e-5
    worst = 0.0
    for mu0 in MU0S + [math.cos(math.radians(60.0)) * 1.2]:
        _, rad = run_disort(tau, 1.0, G, NSTR, NMOM, mu0, 1.0, [0.0, tau], user_mu_grid(), RELATIVE_AZIMUTH_DEG)
        up, down = split_radiance(rad)
        s0 = math.sqrt(1.0 - mu0 * mu0)
        for i, vz in enumerate(VIEW_ZENITH_DEG):
            mu = math.cos(math.radians(vz))
            s = math.sin(math.radians(vz)) * s0
            for j, az in enumerate(RELATIVE_AZIMUTH_DEG):
                c = math.cos(math.radians(az))
                p_down = hg_phase(G, mu0 * mu + s * c)
                p_up = hg_phase(G, -mu0 * mu + s * c)
                if abs(mu - mu0) < 1e-12:
                    ref_down = p_down * tau / mu0 * math.exp(-tau / mu0)
                else:
                    ref_down = p_down * mu0 / (mu - mu0) * (math.exp(-tau / mu) - math.exp(-tau / mu0))
                ref_up = p_up * mu0 / (mu0 + mu) * (1.0 - math.exp(-tau * (1.0 / mu0 + 1.0 / mu)))
                worst = max(worst, abs(down[i, j] / ref_down - 1.0), abs(up[i, j] / ref_up - 1.0))
    if worst > 5e-4:
        sys.exit(f"single-scattering limit mismatch: {worst}")
    return worst


def solve_case(tau, ssa, mu0, nstr):
    flx, rad = run_disort(tau, ssa, G, nstr, NMOM, mu0, 1.0, [0.0, tau], user_mu_grid(), RELATIVE_AZIMUTH_DEG)
    up, down = split_radiance(rad)
    return {
        "reflected_radiance_per_sr": up,
        "transmitted_diffuse_radiance_per_sr": down,
        "reflected_flux": float(flx[0, pydisort.kIFLUP]),
        "transmitted_direct_flux": float(flx[1, pydisort.kIRFLDIR]),
        "transmitted_diffuse_flux": float(flx[1, pydisort.kIFLDN]),
    }


def main():
    nodes = {}
    for n in (NSTR, NSTR_CHECK):
        for mu0 in MU0S:
            d = min_relative_node_distance(n, mu0)
            nodes[f"nstr {n}, mu0 {mu0:g}"] = d
            if d < NODE_MARGIN_REQUIRED:
                sys.exit(f"mu0 = {mu0} within {d:.2e} of a {n}-stream node")
    test3 = check_published_test_problem_3()
    ss = check_single_scattering_limit()

    cases = []
    conv = {"reflected_radiance": 0.0, "transmitted_diffuse_radiance": 0.0, "reflected_flux": 0.0,
            "transmitted_diffuse_flux": 0.0}
    conv_where = {}
    worst_energy = 0.0
    for tau in TAUS:
        for ssa in ALBEDOS:
            for mu0 in MU0S:
                a = solve_case(tau, ssa, mu0, NSTR)
                b = solve_case(tau, ssa, mu0, NSTR_CHECK)
                for key, k2 in [("reflected_radiance", "reflected_radiance_per_sr"),
                                ("transmitted_diffuse_radiance", "transmitted_diffuse_radiance_per_sr"),
                                ("reflected_flux", "reflected_flux"),
                                ("transmitted_diffuse_flux", "transmitted_diffuse_flux")]:
                    d = float(np.max(np.abs(np.asarray(a[k2]) / np.asarray(b[k2]) - 1.0)))
                    if d > conv[key]:
                        conv[key] = d
                        conv_where[key] = f"tau {tau:g}, albedo {ssa:g}, mu0 {mu0:g}"
                total_t = b["transmitted_direct_flux"] + b["transmitted_diffuse_flux"]
                if ssa == 1.0:
                    worst_energy = max(worst_energy, abs(b["reflected_flux"] + total_t - mu0) / mu0)
                cases.append({
                    "optical_thickness": tau,
                    "single_scattering_albedo": ssa,
                    "mu0": mu0,
                    "sun_zenith_deg": math.degrees(math.acos(mu0)),
                    "reflected_radiance_per_sr": np.round(b["reflected_radiance_per_sr"], 10).tolist(),
                    "transmitted_diffuse_radiance_per_sr": np.round(b["transmitted_diffuse_radiance_per_sr"],
                                                                    10).tolist(),
                    "reflected_flux": b["reflected_flux"],
                    "transmitted_direct_flux": b["transmitted_direct_flux"],
                    "transmitted_diffuse_flux": b["transmitted_diffuse_flux"],
                    "transmitted_total_flux": total_t,
                    "reflectance": b["reflected_flux"] / mu0,
                    "transmittance_total": total_t / mu0,
                    "absorptance": 1.0 - (b["reflected_flux"] + total_t) / mu0,
                })
    if max(conv.values()) > STREAM_TOLERANCE:
        sys.exit(f"stream convergence too poor: {conv} at {conv_where}")
    if worst_energy > 1e-6:
        sys.exit(f"energy not conserved: {worst_energy}")

    header = {
        "source": "DISORT (Stamnes et al. 1988, Appl. Opt. 27, 2502) via pydisort (cdisort 2.1.3 core), "
                  "generated by tools/cloud_slab_disort.py",
        "package_versions": {"pydisort": version("pydisort"), "torch": torch.__version__, "numpy": np.__version__,
                             "python": sys.version.split()[0]},
        "inputs": {
            "geometry": "plane-parallel homogeneous slab (laterally infinite), one layer, vacuum above and below",
            "ground": "black (Lambertian albedo 0): nothing comes back from below",
            "phase_function": f"Henyey-Greenstein g = {G}, p(cos) = (1-g^2)/(4 pi (1+g^2-2g cos)^1.5), Legendre "
                              f"moments chi_l = g^l for l = 1..{NMOM}",
            "optical_thickness": TAUS,
            "single_scattering_albedo": ALBEDOS,
            "mu0": MU0S,
            "fbeam": 1.0,
            "streams": NSTR_CHECK,
            "moments": NMOM,
            "delta_m": "always on in cdisort (truncation f = chi_NSTR)",
            "intensity_correction": "Nakajima-Tanaka (flags intensity_correction + old_intensity_correction)",
            "view_zenith_deg": VIEW_ZENITH_DEG,
            "relative_azimuth_deg": RELATIVE_AZIMUTH_DEG,
        },
        "units": "fbeam = 1: the sun's irradiance on a surface normal to the beam is 1. Radiances in sr^-1 per unit "
                 "of that irradiance (for a skybake scene with sun {collimated: {normal_irradiance_w_m2_nm: 1}} "
                 "they are W m^-2 sr^-1 nm^-1). Fluxes are on a horizontal surface per unit normal irradiance, so "
                 "the incident flux is mu0; reflectance = reflected_flux / mu0, transmittance_total = "
                 "(direct + diffuse) / mu0.",
        "conventions": {
            "reflected_radiance_per_sr[i][j]": "diffuse radiance leaving the TOP of the slab travelling upward with "
                "zenith angle view_zenith_deg[i]. relative_azimuth_deg[j] is the azimuth of the observer's line of "
                "sight (looking down) relative to the sun's azimuth: 0 = the observer above looks towards the sun's "
                "side (forward-scattering side), 180 = looks away from the sun. In skybake's frame "
                "(frame_contract.md: azimuth from +y towards +x, sun direction points towards the sun with "
                "azimuth a_sun) the radiance travels along (sin vz sin(a_sun + 180 + raz), sin vz cos(a_sun + 180 "
                "+ raz), cos vz); a camera above looks along minus that. cos(scattering angle) = -mu0 cos vz + "
                "sqrt(1-mu0^2) sin vz cos raz.",
            "transmitted_diffuse_radiance_per_sr[i][j]": "diffuse (scattered) radiance leaving the BOTTOM travelling "
                "downward; an observer below looks up at zenith angle view_zenith_deg[i], relative_azimuth_deg[j] "
                "from the sun's azimuth (0 = looking towards the sun). The radiance travels along (sin vz sin(a_sun "
                "+ 180 + raz), sin vz cos(a_sun + 180 + raz), -cos vz). cos(scattering angle) = mu0 cos vz + "
                "sqrt(1-mu0^2) sin vz cos raz. The direct beam is NOT included (at vz = 0 with mu0 = 1 the value "
                "is the diffuse radiance exactly in the beam direction, the peak of the aureole).",
            "mu0_1": "with the sun at the zenith the radiances do not depend on the azimuth (the three columns are "
                     "equal).",
            "disort_azimuth": "DISORT's phi is the azimuth of propagation; phi0 = 0 and relative_azimuth_deg = phi - "
                              "phi0 (verified against analytic single scattering, see validation).",
            "reflected_flux": "upward diffuse flux at the top (horizontal surface)",
            "transmitted_direct_flux": "mu0 exp(-tau / mu0)",
            "transmitted_diffuse_flux": "downward diffuse flux at the bottom",
            "absorptance": "1 - reflectance - transmittance_total (0 for albedo 1 up to the energy residual)",
        },
        "validation": {
            "disotest_problem_3_max_rel_diff": test3,
            "single_scattering_limit_tau_1e-5_mu0_1_0.6_0.5_max_rel_diff": ss,
            "stream_convergence": {
                "what": f"max over all cases and angles of |value({NSTR} streams) / value({NSTR_CHECK} streams) - 1|;"
                        f" the table holds the {NSTR_CHECK}-stream values",
                "max_rel_diff": conv, "where": conv_where,
            },
            "energy_conservation_albedo_1_max_rel_residual": worst_energy,
            "sun_cosine_min_rel_distance_to_nodes": nodes,
        },
        "notes": [
            "Accuracy: the stream-convergence figures bound the discrete-ordinate error of the table (the error "
            f"of the {NSTR_CHECK}-stream values is expected to be well below the {NSTR}-vs-{NSTR_CHECK} "
            "difference).",
            "A finite-size test slab must be wide enough that light leaking out of its sides is negligible: at "
            "tau = 128 photons travel laterally of the order of the slab thickness times a few before escaping.",
        ],
    }
    data = {
        "header": header,
        "optical_thickness": TAUS,
        "single_scattering_albedo": ALBEDOS,
        "mu0": MU0S,
        "view_zenith_deg": VIEW_ZENITH_DEG,
        "relative_azimuth_deg": RELATIVE_AZIMUTH_DEG,
        "cases": cases,
    }
    with open(OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    print(f"wrote {os.path.normpath(OUT)}: {len(cases)} cases; test3 {test3}; single-scatter {ss:.2e}; "
          f"streams {conv} at {conv_where}; energy {worst_energy:.2e}")


if __name__ == "__main__":
    main()
