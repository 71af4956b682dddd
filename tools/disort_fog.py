#!/usr/bin/env python3
"""Reference sky radiances and irradiances in fog-like haze (visibility 1-3 km) from DISORT.

Writes tests/data/disort_fog.json. Run from the repository root (a few minutes on one core):

    python3 tools/disort_fog.py

The atmosphere is what skybake builds from `visibility_km`, `boundary_layer_top_m` and
`aerosol_type` (crates/physics/src/atmosphere/haze.rs) over the Rayleigh air of
tools/disort_aerosol.py (scale height 8000 m, sea-level coefficients 3.31e-5, 1.3558e-5, 5.802e-6 per
metre at 440/550/680 nm, no ozone), plane-parallel, top 100 km, Lambertian ground:

- boundary layer, 0 to TOP (uniform): aerosol extinction at 550 nm from Koschmieder's law,
  beta_A = 3.912 / V - beta_R(550) (V the visibility in metres, beta_R the sea-level Rayleigh
  coefficient), times the type's extinction relative to 550 nm at the wavelength;
- free troposphere, TOP to 12 km: beta_A(550) f exp(-(h - TOP) / 2000 m) with f such that its optical
  depth at 550 nm is 0.02;
- stratosphere, 12 to 30 km: uniform, optical depth 0.005 at 550 nm;
- the type's extinction ratio and single-scattering albedo at each wavelength by linear interpolation
  in wavelength of data/aerosol_types_6sv.csv (6S standard models; Vermote et al. 1997); phase
  function Henyey-Greenstein with the type's asymmetry parameter at 550 nm (chi_l = g^l).

Each layer is homogeneous with the exact layer integrals of both profiles; its single-scattering
albedo and phase moments are mixed by scattering optical depth (as tools/disort_aerosol.py). cdisort
always applies delta-M; the Nakajima-Tanaka intensity correction (TMS + IMS) uses NMOM = 400 moments.

Before writing, the script
  1. refuses a stream count that puts a sun cosine within 1e-3 (relative) of a quadrature node,
  2. reruns every atmosphere at 440 nm, sun zenith 40 and 75, with NSTR_CHECK streams and with every
     layer halved, and records the largest relative change of every output (aborts above 2e-3),
  3. checks energy conservation in a conservative copy of every atmosphere (ssa = 1): upward flux at
     the top + (1 - albedo) x global flux at the ground = cos(sza) (aborts above 1e-5).
"""

import json
import math
import os
import sys
from importlib.metadata import version

import numpy as np
import torch
import pydisort

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import disort_aerosol as da  # noqa: E402  (run_disort, sky_points, view grid, node checks)

torch.set_num_threads(1)

KOSCHMIEDER = 3.912
RAYLEIGH_H_M = da.RAYLEIGH_H_M
BETA_RAYLEIGH_PER_M = da.BETA_RAYLEIGH_PER_M
TOP_M = da.TOP_M
FREE_TROPOSPHERE = (0.02, 2000.0, 12000.0)  # optical depth at 550 nm, scale height, tropopause (m)
STRATOSPHERE = (0.005, 30000.0)  # optical depth at 550 nm, top (m)
NSTR = 32
NSTR_CHECK = 48
SUN_ZENITH_DEG = [0.0, 40.0, 75.0]
CSV = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data", "aerosol_types_6sv.csv")
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "disort_fog.json")

# Fog-like haze: visibility 1 km in a 1.5 km boundary layer (optical depth 5.85 at 550 nm, about the
# thickest `visibility_km` allows), the same over a bright ground, the nearly conservative maritime
# type, and visibility 2 km (optical depth 2.9).
ATMOSPHERES = [
    dict(name="fog1_continental", visibility_km=1.0, top_m=1500.0, type="continental", albedo=0.1),
    dict(name="fog1_bright", visibility_km=1.0, top_m=1500.0, type="continental", albedo=0.5),
    dict(name="fog1_maritime", visibility_km=1.0, top_m=1500.0, type="maritime", albedo=0.1),
    dict(name="haze2_continental", visibility_km=2.0, top_m=1500.0, type="continental", albedo=0.1),
]


def aerosol_table(kind):
    """[(nm, extinction relative to 550 nm, ssa, g)] of one 6S type."""
    rows = []
    with open(CSV) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#") or line.startswith("type,"):
                continue
            c = line.split(",")
            if c[0] == kind:
                rows.append([float(v) for v in c[1:5]])
    if not rows:
        sys.exit(f"no rows for aerosol type {kind}")
    return rows


def interp(rows, col, nm):
    x = [r[0] for r in rows]
    return float(np.interp(nm, x, [r[col] for r in rows]))


def aerosol_properties(atm, nm):
    """(boundary-layer extinction at nm per m, ssa at nm, g) of the haze."""
    rows = aerosol_table(atm["type"])
    beta550 = KOSCHMIEDER / (atm["visibility_km"] * 1000.0) - BETA_RAYLEIGH_PER_M[550]
    g = next(r[3] for r in rows if r[0] == 550.0)
    return beta550 * interp(rows, 1, nm), interp(rows, 2, nm), g, beta550


def layer_edges_m(top_m):
    """100 m layers in the boundary layer (edges at its top), 250 m to 3 km above it, 500 m to 6 km,
    1 km to 30 km (edges at the tropopause and the stratosphere's top), 5 km to 100 km."""
    tropo, strat_top = FREE_TROPOSPHERE[2], STRATOSPHERE[1]
    e = set(np.arange(0.0, top_m, 100.0).tolist())
    e |= set(np.arange(top_m, top_m + 3000.0, 250.0).tolist())
    e |= set(np.arange(top_m + 3000.0, 6000.0, 500.0).tolist())
    e |= set(np.arange(6000.0, strat_top, 1000.0).tolist())
    e |= set(np.arange(strat_top, TOP_M + 1.0, 5000.0).tolist())
    e |= {top_m, tropo, strat_top, TOP_M}
    return np.array(sorted(e))


def aerosol_layer_taus(atm, nm, edges):
    """Exact integral of the layered aerosol extinction over each layer, ground layer first."""
    beta, _, _, beta550 = aerosol_properties(atm, nm)
    top = atm["top_m"]
    ft_tau, ft_h, tropo = FREE_TROPOSPHERE
    st_tau, st_top = STRATOSPHERE
    free_ratio = ft_tau / (beta550 * ft_h * (1.0 - math.exp(-(tropo - top) / ft_h)))
    strat_ratio = st_tau / (beta550 * (st_top - tropo))
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        d = 0.0  # integral of the relative density
        lo, hi = a, min(b, top)
        if hi > lo:
            d += hi - lo
        lo, hi = max(a, top), min(b, tropo)
        if hi > lo:
            d += free_ratio * ft_h * (math.exp(-(lo - top) / ft_h) - math.exp(-(hi - top) / ft_h))
        lo, hi = max(a, tropo), min(b, st_top)
        if hi > lo:
            d += strat_ratio * (hi - lo)
        out.append(beta * d)
    return np.array(out)


def mixed_layers(atm, nm, edges, conservative=False):
    """(dtau, ssa, moments) per layer, ground layer first."""
    t_r = da.exp_layers(edges, BETA_RAYLEIGH_PER_M[nm], RAYLEIGH_H_M)
    t_a = aerosol_layer_taus(atm, nm, edges)
    _, ssa_a, g, _ = aerosol_properties(atm, nm)
    if conservative:
        ssa_a = 1.0
    s_a = ssa_a * t_a
    dtau = t_r + t_a
    ssa = (t_r + s_a) / dtau
    chi_r = da.rayleigh_moments(da.NMOM)
    chi_a = np.array([g ** (l + 1) for l in range(da.NMOM)])
    mom = (t_r[:, None] * chi_r[None, :] + s_a[:, None] * chi_a[None, :]) / (t_r + s_a)[:, None]
    return dtau, ssa, mom


def solve(atm, nm, sza, nstr=NSTR, edges=None, conservative=False):
    edges = layer_edges_m(atm["top_m"]) if edges is None else edges
    dtau, ssa, mom = mixed_layers(atm, nm, edges, conservative)
    mu0 = math.cos(math.radians(sza))
    vzs = da.view_zeniths(sza)
    umu = -np.cos(np.radians(vzs))
    flx, rad = da.run_disort(dtau, ssa, mom, nstr, mu0, atm["albedo"], umu, da.RELATIVE_AZIMUTH_DEG)
    boundary = aerosol_layer_taus(atm, 550, edges)[edges[1:] <= atm["top_m"]].sum()
    return {
        "points": da.sky_points(sza, rad),
        "direct_horizontal": float(flx[1, pydisort.kIRFLDIR]),
        "diffuse_horizontal": float(flx[1, pydisort.kIFLDN]),
        "global_horizontal": float(flx[1, pydisort.kIRFLDIR] + flx[1, pydisort.kIFLDN]),
        "top_up_flux": float(flx[0, pydisort.kIFLUP]),
        "total_optical_depth": float(np.sum(dtau)),
        "boundary_layer_aerosol_optical_depth_550": float(boundary),
    }


def main():
    nodes = {}
    for n in (NSTR, NSTR_CHECK):
        for sza in SUN_ZENITH_DEG:
            d = da.min_relative_node_distance(n, sza)
            nodes[f"{n} streams, sza {sza:g}"] = d
            if d < da.NODE_MARGIN_REQUIRED:
                sys.exit(f"cos({sza} deg) within {d:.2e} of a {n}-stream node; choose another stream count")

    cases = []
    worst_energy = 0.0
    for atm in ATMOSPHERES:
        for nm in BETA_RAYLEIGH_PER_M:
            for sza in SUN_ZENITH_DEG:
                r = solve(atm, nm, sza)
                cases.append(dict(atmosphere=atm["name"], wavelength_nm=nm, sun_zenith_deg=sza, **r))
                c = solve(atm, nm, sza, conservative=True)
                mu0 = math.cos(math.radians(sza))
                absorbed = (1.0 - atm["albedo"]) * c["global_horizontal"]
                worst_energy = max(worst_energy, abs(c["top_up_flux"] + absorbed - mu0) / mu0)
        print(f"{atm['name']} done (boundary layer optical depth at 550 nm "
              f"{cases[-1]['boundary_layer_aerosol_optical_depth_550']:.3f})", flush=True)
    if worst_energy > 1e-5:
        sys.exit(f"energy not conserved: {worst_energy}")

    streams, layers = {}, {}
    for atm in ATMOSPHERES:
        fine = da.halved(layer_edges_m(atm["top_m"]))
        for sza in (40.0, 75.0):
            base = next(c for c in cases if c["atmosphere"] == atm["name"] and c["wavelength_nm"] == 440
                        and c["sun_zenith_deg"] == sza)
            da.merge_max(streams, da.rel_change(base, solve(atm, 440, sza, nstr=NSTR_CHECK)))
            da.merge_max(layers, da.rel_change(base, solve(atm, 440, sza, edges=fine)))
        print(f"{atm['name']} checked: streams {streams}, layers {layers}", flush=True)
    if max(streams.values()) > 2e-3 or max(layers.values()) > 2e-3:
        sys.exit(f"not converged: streams {streams}, layers {layers}")

    header = {
        "source": "DISORT (Stamnes et al. 1988, Appl. Opt. 27, 2502) via pydisort (cdisort 2.1.3 core), "
                  "generated by tools/disort_fog.py",
        "package_versions": {"pydisort": version("pydisort"), "torch": torch.__version__,
                             "numpy": np.__version__, "python": sys.version.split()[0]},
        "inputs": {
            "geometry": "plane-parallel",
            "top_altitude_m": TOP_M,
            "layer_edges_m": {a["name"]: layer_edges_m(a["top_m"]).tolist() for a in ATMOSPHERES},
            "layering": "each layer homogeneous: optical depths are the exact layer integrals of the Rayleigh "
                        "exponential and the layered aerosol; ssa and Legendre moments mixed by scattering "
                        "optical depth",
            "rayleigh": {"scale_height_m": RAYLEIGH_H_M, "scattering_coefficient_sea_level_per_m":
                         {str(k): v for k, v in BETA_RAYLEIGH_PER_M.items()},
                         "phase_function": "3/(16 pi)(1 + cos^2), chi_2 = 0.1, scalar"},
            "aerosol": {
                "boundary_layer": "uniform from the ground to top_m, extinction at 550 nm "
                                  "3.912 / visibility - rayleigh(550) (Koschmieder)",
                "free_troposphere": {"optical_depth_550": FREE_TROPOSPHERE[0], "scale_height_m":
                                     FREE_TROPOSPHERE[1], "from": "top_m", "to_m": FREE_TROPOSPHERE[2]},
                "stratosphere": {"optical_depth_550": STRATOSPHERE[0], "from_m": FREE_TROPOSPHERE[2],
                                 "to_m": STRATOSPHERE[1]},
                "spectral": "data/aerosol_types_6sv.csv, extinction ratio and ssa linear in wavelength",
                "phase_function": "Henyey-Greenstein, the type's asymmetry at 550 nm, chi_l = g^l",
                "per_wavelength": {a["name"]: {str(nm): dict(zip(
                    ("boundary_layer_extinction_per_m", "single_scattering_albedo", "g"),
                    aerosol_properties(a, nm)[:3])) for nm in BETA_RAYLEIGH_PER_M} for a in ATMOSPHERES},
            },
            "atmospheres": ATMOSPHERES,
            "streams": NSTR,
            "phase_moments": da.NMOM,
            "delta_m": "always on in cdisort (truncation f = chi_NSTR)",
            "intensity_correction": "Nakajima-Tanaka TMS + IMS (old_intensity_correction)",
            "fbeam": 1.0,
            "sun_zenith_deg": SUN_ZENITH_DEG,
            "view_zenith_deg": "VIEW_ZENITH_DEG plus sza +- 2 and 5 deg, up to 80 deg: "
                               + str(da.VIEW_ZENITH_DEG),
            "relative_azimuth_deg": da.RELATIVE_AZIMUTH_DEG,
        },
        "units": "fbeam = 1: radiances in sr^-1 per unit normal solar irradiance; fluxes on a horizontal "
                 "surface per unit normal solar irradiance (top-of-atmosphere incident flux cos(sza)).",
        "conventions": {
            "points": "[view_zenith_deg, relative_azimuth_deg, scattering_angle_deg, radiance_per_sr]: "
                      "diffuse downward radiance at the ground at that view zenith; relative azimuth 0 = "
                      "towards the sun (as disort_aerosol.json). The direct beam is not included.",
            "direct_horizontal": "cos(sza) exp(-tau / cos(sza))",
            "diffuse_horizontal": "scattered downward flux at the ground",
            "global_horizontal": "direct + diffuse",
            "top_up_flux": "upward flux at the top",
        },
        "validation": {
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
