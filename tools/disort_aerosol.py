#!/usr/bin/env python3
"""Reference sky radiances and irradiances for layered Rayleigh + exponential aerosol air from DISORT.

Writes tests/data/disort_aerosol.json. Run from the repository root (about 3 min on one core):

    python3 tools/disort_aerosol.py

Setup (plane-parallel; see tools/README.md): Rayleigh as in tools/disort_rayleigh.py (scale height
8000 m, the same sea-level coefficients, phase 3/(16 pi)(1 + cos^2)) plus an exponential aerosol of
scale height 1200 m whose vertical optical depth at 550 nm is AOD and follows the Angstrom law
tau(lambda) = AOD (lambda / 550)^-1.3, single-scattering albedo ssa, Henyey-Greenstein or
Cornette-Shanks phase function (Nishita et al. 1996, eq 5) of parameter g. Top 100 km, Lambertian
ground. Each layer is homogeneous with the exact layer integrals of both exponentials; its
single-scattering albedo and phase moments are mixed by scattering optical depth:
    chi_l = (tau_R chi_R,l + ssa tau_A chi_A,l) / (tau_R + ssa tau_A).
cdisort always applies delta-M (truncation f = chi_NSTR); the Nakajima-Tanaka intensity correction
(TMS + IMS, "old_intensity_correction") uses NMOM = 400 moments, so the single-scattered aureole is
exact and the forward peak of the multiple part is restored.

Before writing, the script
  1. checks the optically thin limit (aerosol-only layer, tau = 1e-5, g = 0.8) against analytic
     single scattering over the whole view grid including the aureole (pins the azimuth convention
     and the phase function's moments, both HG and CS),
  2. refuses a stream count that puts a sun cosine within 1e-3 (relative) of a quadrature node,
  3. reruns a subset (every atmosphere, 440 nm, sun zenith 40 and 75) with NSTR_CHECK streams and
     with every layer halved, and records the largest relative change of every output,
  4. checks energy conservation in the conservative case (ssa = 1).
Any failed check aborts without writing the file.
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

RAYLEIGH_H_M = 8000.0
AEROSOL_H_M = 1200.0
TOP_M = 100e3
BETA_RAYLEIGH_PER_M = {440: 3.31e-5, 550: 1.3558e-5, 680: 5.802e-6}
ANGSTROM = 1.3
REFERENCE_NM = 550.0
NSTR = 32
NSTR_CHECK = 48
NMOM = 400
FLAGS = "usrtau,usrang,lamber,quiet,intensity_correction,old_intensity_correction"
NODE_MARGIN_REQUIRED = 1e-3
SUN_ZENITH_DEG = [0.0, 40.0, 75.0]
VIEW_ZENITH_DEG = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 75.0]
# Around each sun: the aureole in the sun's vertical plane.
AUREOLE_OFFSETS_DEG = [2.0, 5.0]
RELATIVE_AZIMUTH_DEG = [0.0, 2.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 150.0, 180.0]

# The atmospheres: a base case (AOD 0.4, HG g 0.7, ssa 0.9, albedo 0.1) and one-at-a-time changes
# that span the range (AOD 0.05-2, g 0.6-0.8, ssa 0.8-1, HG and CS, albedo 0-0.5).
ATMOSPHERES = [
    dict(name="base", aod=0.4, phase="henyey_greenstein", g=0.7, ssa=0.9, albedo=0.1),
    dict(name="thin", aod=0.05, phase="henyey_greenstein", g=0.7, ssa=0.9, albedo=0.1),
    dict(name="thick", aod=2.0, phase="henyey_greenstein", g=0.7, ssa=0.9, albedo=0.1),
    dict(name="conservative_g06", aod=0.4, phase="henyey_greenstein", g=0.6, ssa=1.0, albedo=0.1),
    dict(name="absorbing_g08", aod=0.4, phase="henyey_greenstein", g=0.8, ssa=0.8, albedo=0.1),
    dict(name="black_ground", aod=0.4, phase="henyey_greenstein", g=0.7, ssa=0.9, albedo=0.0),
    dict(name="cornette_shanks", aod=0.4, phase="cornette_shanks", g=0.7, ssa=0.9, albedo=0.1),
    dict(name="cs_g08_bright", aod=1.0, phase="cornette_shanks", g=0.8, ssa=0.95, albedo=0.5),
]

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "disort_aerosol.json")


def layer_edges_m():
    """Layer boundaries from the ground up: 100 m to 2.4 km (two aerosol scale heights), 300 m to 6 km,
    1 km to 20 km, 5 km to the top."""
    edges = list(np.arange(0.0, 2400.0, 100.0)) + list(np.arange(2400.0, 6000.0, 300.0))
    edges += list(np.arange(6000.0, 20000.0, 1000.0)) + list(np.arange(20000.0, TOP_M + 1.0, 5000.0))
    return np.array(edges)


def halved(edges):
    mid = 0.5 * (edges[:-1] + edges[1:])
    return np.sort(np.concatenate([edges, mid]))


def exp_layers(edges, beta0, h):
    """Exact integral of beta0 exp(-z/h) over each layer, ground layer first."""
    return beta0 * h * (np.exp(-edges[:-1] / h) - np.exp(-edges[1:] / h))


def aerosol_tau(aod550, nm):
    return aod550 * (nm / REFERENCE_NM) ** -ANGSTROM


def hg(g, mu):
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def cornette_shanks(g, mu):
    """Nishita et al. 1996, eq 5, divided by 4 pi (normalised over the sphere)."""
    return 3.0 / (8.0 * math.pi) * (1.0 - g * g) * (1.0 + mu * mu) / ((2.0 + g * g) * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def phase_value(phase, g, mu):
    return hg(g, mu) if phase == "henyey_greenstein" else cornette_shanks(g, mu)


def aerosol_moments(phase, g, nmom):
    """Legendre coefficients chi_1..chi_nmom, p(mu) = (1/4pi) sum (2l+1) chi_l P_l(mu): g^l for HG;
    for CS by 4000-point Gauss-Legendre projection chi_l = 2 pi int p(mu) P_l(mu) dmu (checked: chi_0 = 1)."""
    if phase == "henyey_greenstein":
        return np.array([g ** (l + 1) for l in range(nmom)])
    x, w = np.polynomial.legendre.leggauss(4000)
    p = np.array([cornette_shanks(g, m) for m in x])
    chi = np.empty(nmom + 1)
    p_prev, p_cur = np.ones_like(x), x.copy()
    chi[0] = 2.0 * math.pi * np.sum(w * p)
    chi[1] = 2.0 * math.pi * np.sum(w * p * p_cur)
    for l in range(2, nmom + 1):
        p_next = ((2 * l - 1) * x * p_cur - (l - 1) * p_prev) / l
        p_prev, p_cur = p_cur, p_next
        chi[l] = 2.0 * math.pi * np.sum(w * p * p_cur)
    if abs(chi[0] - 1.0) > 1e-10:
        sys.exit(f"Cornette-Shanks moments: chi_0 = {chi[0]}")
    return chi[1:]


def rayleigh_moments(nmom):
    m = np.zeros(nmom)
    m[1] = 0.1
    return m


def double_gauss_nodes(nstr):
    t, _ = np.polynomial.legendre.leggauss(nstr // 2)
    return np.sort((t + 1.0) / 2.0)


def min_relative_node_distance(nstr, sun_zenith_deg):
    mu0 = math.cos(math.radians(sun_zenith_deg))
    return float(np.min(np.abs(mu0 - double_gauss_nodes(nstr)) / mu0))


def mixed_layers(atm, nm, edges):
    """(dtau, ssa, moments) per layer, ground layer first."""
    t_r = exp_layers(edges, BETA_RAYLEIGH_PER_M[nm], RAYLEIGH_H_M)
    col_a = AEROSOL_H_M * (1.0 - math.exp(-TOP_M / AEROSOL_H_M))
    t_a = exp_layers(edges, aerosol_tau(atm["aod"], nm) / col_a, AEROSOL_H_M)
    s_a = atm["ssa"] * t_a
    dtau = t_r + t_a
    ssa = (t_r + s_a) / dtau
    chi_r = rayleigh_moments(NMOM)
    chi_a = aerosol_moments(atm["phase"], atm["g"], NMOM)
    mom = (t_r[:, None] * chi_r[None, :] + s_a[:, None] * chi_a[None, :]) / (t_r + s_a)[:, None]
    return dtau, ssa, mom


def run_disort(dtau_ground_first, ssa, mom, nstr, umu0, albedo, user_mu, user_phi_deg):
    """One DISORT solve (fbeam = 1, phi0 = 0), output at the top and the ground.
    Returns (fluxes[2, 8], radiance[nphi, 2, numu])."""
    nlyr = len(dtau_ground_first)
    op = DisortOptions().flags(FLAGS)
    ds = op.ds()
    ds.nlyr = nlyr
    ds.nstr = nstr
    ds.nmom = NMOM
    ds.nphase = nstr
    total = float(np.sum(dtau_ground_first))
    op.user_tau(np.array([0.0, total]))
    op.user_mu(np.asarray(user_mu, dtype=float))
    op.user_phi(np.asarray(user_phi_deg, dtype=float))
    solver = Disort(op)
    prop = torch.zeros((1, 1, nlyr, 2 + NMOM), dtype=torch.float64)
    prop[0, 0, :, 0] = torch.tensor(np.asarray(dtau_ground_first, dtype=float)[::-1].copy())
    prop[0, 0, :, 1] = torch.tensor(np.asarray(ssa, dtype=float)[::-1].copy())
    prop[0, 0, :, 2:] = torch.tensor(np.asarray(mom, dtype=float)[::-1].copy())
    f64 = dict(dtype=torch.float64)
    solver.forward(prop, umu0=torch.tensor([umu0], **f64), phi0=torch.tensor([0.0], **f64),
                   fbeam=torch.tensor([[1.0]], **f64), albedo=torch.tensor([[albedo]], **f64))
    return solver.gather_flx()[0, 0].numpy().copy(), solver.gather_rad()[0, 0].numpy().copy()


def view_zeniths(sza):
    extra = [sza + s * o for o in AUREOLE_OFFSETS_DEG for s in (-1.0, 1.0)]
    return sorted({v for v in VIEW_ZENITH_DEG + extra if 0.0 <= v <= 80.0})


def scattering_angle_deg(sza, vz, raz):
    c = (math.cos(math.radians(sza)) * math.cos(math.radians(vz))
         + math.sin(math.radians(sza)) * math.sin(math.radians(vz)) * math.cos(math.radians(raz)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def sky_points(sza, rad):
    """Diffuse downward radiance at the ground: [(vz, raz, scattering angle, radiance)] (DISORT's
    user_mu: downward (negative) cosines -cos(vz), increasing, i.e. view zenith increasing)."""
    vzs = view_zeniths(sza)
    points = []
    for k, vz in enumerate(vzs):
        for j, raz in enumerate(RELATIVE_AZIMUTH_DEG):
            if sza == 0.0 and raz != 0.0:
                continue  # sun at the zenith: no azimuth dependence
            if vz == 0.0 and raz != 0.0:
                continue
            points.append([vz, raz, scattering_angle_deg(sza, vz, raz), float(rad[j, 1, k])])
    return points


def solve(atm, nm, sza, nstr=NSTR, edges=None):
    edges = layer_edges_m() if edges is None else edges
    dtau, ssa, mom = mixed_layers(atm, nm, edges)
    mu0 = math.cos(math.radians(sza))
    vzs = view_zeniths(sza)
    umu = -np.cos(np.radians(vzs))
    flx, rad = run_disort(dtau, ssa, mom, nstr, mu0, atm["albedo"], umu, RELATIVE_AZIMUTH_DEG)
    return {
        "points": sky_points(sza, rad),
        "direct_horizontal": float(flx[1, pydisort.kIRFLDIR]),
        "diffuse_horizontal": float(flx[1, pydisort.kIFLDN]),
        "global_horizontal": float(flx[1, pydisort.kIRFLDIR] + flx[1, pydisort.kIFLDN]),
        "top_up_flux": float(flx[0, pydisort.kIFLUP]),
        "total_optical_depth": float(np.sum(dtau)),
    }


def check_single_scattering_limit():
    """Thin aerosol-only slab (tau 1e-5, ssa 1, black ground): DISORT's downward diffuse radiance at
    the bottom against mu0/(mu - mu0) p(Theta) (exp(-tau/mu) - exp(-tau/mu0)), per phase function."""
    tau = 1e-5
    worst = {}
    for phase in ("henyey_greenstein", "cornette_shanks"):
        g = 0.8
        mom = aerosol_moments(phase, g, NMOM)[None, :]
        w = 0.0
        for sza in (40.0, 75.0):
            mu0 = math.cos(math.radians(sza))
            vzs = view_zeniths(sza)
            umu = -np.cos(np.radians(vzs))
            _, rad = run_disort(np.array([tau]), np.array([1.0]), mom, NSTR, mu0, 0.0, umu, RELATIVE_AZIMUTH_DEG)
            for vz, raz, theta, value in sky_points(sza, rad):
                mu = math.cos(math.radians(vz))
                p = phase_value(phase, g, math.cos(math.radians(theta)))
                if abs(mu - mu0) < 1e-9:
                    ref = p * tau / mu0 * math.exp(-tau / mu0)
                else:
                    ref = p * mu0 / (mu - mu0) * (math.exp(-tau / mu) - math.exp(-tau / mu0))
                w = max(w, abs(value / ref - 1.0))
        worst[phase] = w
    if max(worst.values()) > 1e-3:
        sys.exit(f"single-scattering limit mismatch: {worst}")
    return worst


def rel_change(a, b):
    worst = {"radiance": 0.0, "diffuse_horizontal": 0.0, "global_horizontal": 0.0}
    for pa, pb in zip(a["points"], b["points"]):
        worst["radiance"] = max(worst["radiance"], abs(pb[3] / pa[3] - 1.0))
    for k in ("diffuse_horizontal", "global_horizontal"):
        worst[k] = max(worst[k], abs(b[k] / a[k] - 1.0))
    return worst


def merge_max(acc, new):
    for k, v in new.items():
        acc[k] = max(acc.get(k, 0.0), v)


def main():
    nodes = {}
    for n in (NSTR, NSTR_CHECK):
        for sza in SUN_ZENITH_DEG:
            d = min_relative_node_distance(n, sza)
            nodes[f"{n} streams, sza {sza:g}"] = d
            if d < NODE_MARGIN_REQUIRED:
                sys.exit(f"cos({sza} deg) within {d:.2e} of a {n}-stream node; choose another stream count")
    ss = check_single_scattering_limit()
    print(f"single scattering: {ss}", flush=True)

    cases = []
    worst_energy = 0.0
    for atm in ATMOSPHERES:
        for nm in BETA_RAYLEIGH_PER_M:
            for sza in SUN_ZENITH_DEG:
                r = solve(atm, nm, sza)
                if atm["ssa"] == 1.0:
                    mu0 = math.cos(math.radians(sza))
                    absorbed = (1.0 - atm["albedo"]) * r["global_horizontal"]
                    worst_energy = max(worst_energy, abs(r["top_up_flux"] + absorbed - mu0) / mu0)
                cases.append(dict(atmosphere=atm["name"], wavelength_nm=nm, sun_zenith_deg=sza, **r))
        print(f"{atm['name']} done", flush=True)
    if worst_energy > 1e-5:
        sys.exit(f"energy not conserved: {worst_energy}")

    streams, layers = {}, {}
    fine = halved(layer_edges_m())
    for atm in ATMOSPHERES:
        for sza in (40.0, 75.0):
            base = next(c for c in cases if c["atmosphere"] == atm["name"] and c["wavelength_nm"] == 440
                        and c["sun_zenith_deg"] == sza)
            merge_max(streams, rel_change(base, solve(atm, 440, sza, nstr=NSTR_CHECK)))
            merge_max(layers, rel_change(base, solve(atm, 440, sza, edges=fine)))
        print(f"{atm['name']} checked: streams {streams}, layers {layers}", flush=True)
    if max(streams.values()) > 2e-3 or max(layers.values()) > 2e-3:
        sys.exit(f"not converged: streams {streams}, layers {layers}")

    edges = layer_edges_m()
    header = {
        "source": "DISORT (Stamnes et al. 1988, Appl. Opt. 27, 2502) via pydisort (cdisort 2.1.3 core), "
                  "generated by tools/disort_aerosol.py",
        "package_versions": {"pydisort": version("pydisort"), "torch": torch.__version__,
                             "numpy": np.__version__, "python": sys.version.split()[0]},
        "inputs": {
            "geometry": "plane-parallel",
            "top_altitude_m": TOP_M,
            "layer_edges_m": edges.tolist(),
            "layering": "each layer homogeneous: optical depths are the exact layer integrals of both "
                        "exponentials; ssa and Legendre moments mixed by scattering optical depth",
            "rayleigh": {"scale_height_m": RAYLEIGH_H_M, "scattering_coefficient_sea_level_per_m":
                         {str(k): v for k, v in BETA_RAYLEIGH_PER_M.items()},
                         "phase_function": "3/(16 pi)(1 + cos^2), chi_2 = 0.1, scalar"},
            "aerosol": {"scale_height_m": AEROSOL_H_M, "optical_depth": "aod * (lambda / 550 nm)^-1.3, "
                        "vertical column ground to top", "angstrom_exponent": ANGSTROM,
                        "henyey_greenstein": "chi_l = g^l",
                        "cornette_shanks": "Nishita et al. 1996 eq 5 / (4 pi); moments by 4000-point "
                                           "Gauss-Legendre projection"},
            "atmospheres": ATMOSPHERES,
            "streams": NSTR,
            "phase_moments": NMOM,
            "delta_m": "always on in cdisort (truncation f = chi_NSTR)",
            "intensity_correction": "Nakajima-Tanaka TMS + IMS (old_intensity_correction)",
            "fbeam": 1.0,
            "sun_zenith_deg": SUN_ZENITH_DEG,
            "view_zenith_deg": "VIEW_ZENITH_DEG plus sza +- 2 and 5 deg (aureole), up to 80 deg: "
                               + str(VIEW_ZENITH_DEG),
            "relative_azimuth_deg": RELATIVE_AZIMUTH_DEG,
        },
        "units": "fbeam = 1: radiances in sr^-1 per unit normal solar irradiance; fluxes on a horizontal "
                 "surface per unit normal solar irradiance (top-of-atmosphere incident flux cos(sza)).",
        "conventions": {
            "points": "[view_zenith_deg, relative_azimuth_deg, scattering_angle_deg, radiance_per_sr]: "
                      "diffuse downward radiance at the ground seen by an observer looking at that view "
                      "zenith; relative azimuth 0 = towards the sun (as disort_rayleigh.json). The row "
                      "view zenith = sun zenith is the almucantar; relative azimuth 0 near the sun "
                      "the aureole. The direct beam is not included.",
            "direct_horizontal": "cos(sza) exp(-tau / cos(sza))",
            "diffuse_horizontal": "scattered downward flux at the ground",
            "global_horizontal": "direct + diffuse",
        },
        "validation": {
            "single_scattering_limit_tau_1e-5_g08_max_rel_diff": ss,
            "max_rel_change_streams": {"streams": NSTR_CHECK, "subset": "every atmosphere, 440 nm, sza 40 "
                                       "and 75", **streams},
            "max_rel_change_layers_halved": {"subset": "every atmosphere, 440 nm, sza 40 and 75", **layers},
            "energy_conservation_max_rel_residual_ssa1": worst_energy,
            "sun_cosine_min_rel_distance_to_nodes": nodes,
        },
    }
    with open(OUT, "w") as f:
        json.dump({"header": header, "cases": cases}, f, indent=1)
        f.write("\n")
    print(f"wrote {os.path.normpath(OUT)}: {len(cases)} cases; streams {streams}; layers {layers}; "
          f"energy {worst_energy:.2e}")


if __name__ == "__main__":
    main()
