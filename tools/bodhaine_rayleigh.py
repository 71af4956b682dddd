#!/usr/bin/env python3
"""Rayleigh optical depth and cross-section from Bodhaine et al. (1999).

Bodhaine, B. A., Wood, N. B., Dutton, E. G., Slusser, J. R. (1999): On Rayleigh optical depth
calculations. J. Atmos. Oceanic Technol. 16, 1854-1861.

Writes tests/data/bodhaine1999_rayleigh_optical_depth.json. Run from the repository root:

    python3 tools/bodhaine_rayleigh.py

The tabulated values are the paper's closed-form fits (sea level, 1013.25 hPa, 45 deg latitude,
360 ppm CO2):
  eq. 29  sigma(lambda) [1e-28 cm^2] = (1.0455996 - 341.29061 l^-2 - 0.90230850 l^2)
                                       / (1 + 0.0027059889 l^-2 - 85.968563 l^2)
  eq. 30  tau_R(lambda) = 0.0021520 * (same rational function)          (l in micrometres)
As an independent check the script also evaluates the paper's full chain (refractive index of
Peck & Reeves 1972 eq. 21 scaled to 360 ppm CO2 by eq. 19, King factor eqs. 23-27, cross-section
eq. 2, optical depth eq. 4 with g from eq. 11 at the mass-weighted column altitude z_c of eq. 10) and
records its relative difference from the fits. No third-party package is needed.
"""

import json
import math
import os
import sys

WAVELENGTHS_NM = list(range(360, 701, 20)) + [750, 800, 830]
PRESSURE_HPA = 1013.25
LATITUDE_DEG = 45.0
ALTITUDE_M = 0.0
CO2_PPM = 360.0
AVOGADRO = 6.0221367e23  # mol^-1, as used by Bodhaine et al.
N_S_PER_CM3 = 2.546899e19  # molecular density of standard air, 288.15 K and 1013.25 hPa (their eq. 3)

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data",
                   "bodhaine1999_rayleigh_optical_depth.json")


def rational_fit(lambda_um):
    l2 = lambda_um**2
    return (1.0455996 - 341.29061 / l2 - 0.90230850 * l2) / (1.0 + 0.0027059889 / l2 - 85.968563 * l2)


def sigma_eq29_cm2(lambda_um):
    return rational_fit(lambda_um) * 1e-28


def tau_eq30(lambda_um):
    return 0.0021520 * rational_fit(lambda_um)


def refractive_index_minus_one(lambda_um, co2_ppm):
    """Peck & Reeves (1972) for 300 ppm CO2 (Bodhaine eq. 21), scaled to co2_ppm by eq. 19."""
    s2 = 1.0 / lambda_um**2
    n300_minus_1 = (8060.51 + 2480990.0 / (132.274 - s2) + 17455.7 / (39.32957 - s2)) * 1e-8
    return n300_minus_1 * (1.0 + 0.54 * (co2_ppm * 1e-6 - 0.0003))


def king_factor(lambda_um, co2_ppm):
    """Depolarisation (King) factor of air, Bodhaine eqs. 23-27 (concentrations in percent by volume)."""
    s2 = 1.0 / lambda_um**2
    f_n2 = 1.034 + 3.17e-4 * s2
    f_o2 = 1.096 + 1.385e-3 * s2 + 1.448e-4 * s2**2
    f_ar = 1.00
    f_co2 = 1.15
    c_co2 = co2_ppm * 1e-4
    return (78.084 * f_n2 + 20.946 * f_o2 + 0.934 * f_ar + c_co2 * f_co2) / (78.084 + 20.946 + 0.934 + c_co2)


def sigma_full_cm2(lambda_um, co2_ppm):
    """Bodhaine eq. 2: sigma = 24 pi^3 (n^2 - 1)^2 / (lambda^4 N_s^2 (n^2 + 2)^2) * F_air."""
    n = 1.0 + refractive_index_minus_one(lambda_um, co2_ppm)
    lam_cm = lambda_um * 1e-4
    return (24.0 * math.pi**3 * (n * n - 1.0) ** 2 / (lam_cm**4 * N_S_PER_CM3**2 * (n * n + 2.0) ** 2)
            * king_factor(lambda_um, co2_ppm))


def gravity_cm_s2(latitude_deg, z_m):
    """Bodhaine eqs. 10-11 (List 1968): g at altitude z for latitude phi, cm s^-2."""
    c2 = math.cos(2.0 * math.radians(latitude_deg))
    g0 = 980.6160 * (1.0 - 0.0026373 * c2 + 0.0000059 * c2 * c2)
    return (g0 - (3.085462e-4 + 2.27e-7 * c2) * z_m + (7.254e-11 + 1.0e-13 * c2) * z_m**2
            - (1.517e-17 + 6e-20 * c2) * z_m**3)


def mean_molecular_weight_g_mol(co2_ppm):
    """Bodhaine eq. 6: m_a = 15.0556 CO2 + 28.9595 (CO2 as a volume fraction)."""
    return 15.0556 * co2_ppm * 1e-6 + 28.9595


def tau_full(lambda_um):
    """Bodhaine eq. 4: tau = sigma P A / (m_a g), with g at the mass-weighted altitude z_c (eq. 10)."""
    z_c = 0.73737 * ALTITUDE_M + 5517.56
    p_dyn_cm2 = PRESSURE_HPA * 1000.0
    return (sigma_full_cm2(lambda_um, CO2_PPM) * p_dyn_cm2 * AVOGADRO
            / (mean_molecular_weight_g_mol(CO2_PPM) * gravity_cm_s2(LATITUDE_DEG, z_c)))


def main():
    rows = []
    worst_sigma = 0.0
    worst_tau = 0.0
    for wl in WAVELENGTHS_NM:
        lam = wl / 1000.0
        s29 = sigma_eq29_cm2(lam)
        t30 = tau_eq30(lam)
        s_full = sigma_full_cm2(lam, CO2_PPM)
        t_full = tau_full(lam)
        worst_sigma = max(worst_sigma, abs(s_full / s29 - 1.0))
        worst_tau = max(worst_tau, abs(t_full / t30 - 1.0))
        rows.append({
            "wavelength_nm": wl,
            "optical_depth_eq30": t30,
            "cross_section_eq29_m2": s29 * 1e-4,
            "optical_depth_full_formula": t_full,
            "cross_section_full_formula_m2": s_full * 1e-4,
            "king_factor": king_factor(lam, CO2_PPM),
            "refractive_index_minus_one": refractive_index_minus_one(lam, CO2_PPM),
            "scattering_coefficient_standard_air_per_m": s_full * 1e-4 * N_S_PER_CM3 * 1e6,
        })
    # The fits are least-squares fits to the full calculation; they agree with it to ~1e-4 here.
    if worst_sigma > 2e-4 or worst_tau > 5e-4:
        sys.exit(f"full formula disagrees with the fits: sigma {worst_sigma:.2e}, tau {worst_tau:.2e}")
    data = {
        "header": {
            "source": "Bodhaine, Wood, Dutton & Slusser (1999), J. Atmos. Oceanic Technol. 16, 1854-1861; "
                      "generated by tools/bodhaine_rayleigh.py (pure Python, no packages)",
            "package_versions": {"python": sys.version.split()[0]},
            "inputs": {
                "pressure_hpa": PRESSURE_HPA, "latitude_deg": LATITUDE_DEG, "altitude_m": ALTITUDE_M,
                "co2_ppm": CO2_PPM, "wavelengths_nm": WAVELENGTHS_NM,
            },
            "fields": {
                "optical_depth_eq30": "vertical Rayleigh optical depth of the whole atmosphere, eq. 30 fit",
                "cross_section_eq29_m2": "scattering cross-section per molecule, eq. 29 fit (paper gives cm^2; "
                                         "converted with 1 cm^2 = 1e-4 m^2)",
                "optical_depth_full_formula": "eq. 4 with eq. 2 cross-section, g from eq. 11 at z_c = 5517.56 m "
                                              "(eq. 10), m_a from eq. 6, A = 6.0221367e23",
                "cross_section_full_formula_m2": "eq. 2 with n from Peck & Reeves (eq. 21) scaled by eq. 19, "
                                                 "King factor eqs. 23-27, N_s = 2.546899e19 cm^-3",
                "king_factor": "F_air, eq. 23 with eqs. 24-27",
                "refractive_index_minus_one": "n - 1 of dry air at 288.15 K, 1013.25 hPa, 360 ppm CO2",
                "scattering_coefficient_standard_air_per_m": "cross_section_full_formula_m2 * N_s (standard air, "
                                                             "288.15 K, 1013.25 hPa); not the same number density "
                                                             "as a 0 degC or 'US standard' sea level",
            },
            "validation": {
                "max_rel_diff_cross_section_full_vs_eq29": worst_sigma,
                "max_rel_diff_optical_depth_full_vs_eq30": worst_tau,
            },
            "notes": [
                "Wavelengths are in vacuum as used by Bodhaine et al. (lambda in micrometres in the fits).",
                "The eq. 30 fit is for sea level; for another surface pressure scale by P/1013.25 hPa (eq. 4), "
                "for another latitude recompute g (eq. 11).",
            ],
        },
        "rows": rows,
    }
    with open(OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    print(f"wrote {os.path.normpath(OUT)}; sigma diff {worst_sigma:.2e}, tau diff {worst_tau:.2e}")
    for r in rows:
        if r["wavelength_nm"] in (400, 440, 550, 680, 700):
            print(r["wavelength_nm"], r["optical_depth_eq30"], r["optical_depth_full_formula"], r["cross_section_eq29_m2"])


if __name__ == "__main__":
    main()
