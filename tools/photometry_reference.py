#!/usr/bin/env python3
"""Reference illuminance and correlated colour temperature from colour-science.

Writes tests/data/photometry_reference.json. Run from the repository root:

    python3 tools/photometry_reference.py

colour-science 0.4.7, numpy 2.4.6, scipy 1.17.1 (Python 3.11.7).

Each case is a spectral irradiance sampled at a few wavelengths, exactly as skybake's `sun` product
holds it. The spectrum is first brought onto 360-830 nm at 1 nm by the project's colour convention
(linear interpolation, constant beyond the first/last sample; tests/data/README.md,
colour_reference.json), then:
  * illuminance_lux: colour.luminous_flux (K_m = 683 lm/W, the CIE 1924 photopic V(lambda) of
    colour-science, which is the CIE 1931 y-bar);
  * cct_ohno2013_k, duv_ohno2013: colour.temperature.uv_to_CCT_Ohno2013 on the CIE 1960 uv of the
    CIE 1931 2-degree XYZ (colour.sd_to_XYZ with method 'Integration', k = 1);
  * cct_robertson1968_k: colour.temperature.uv_to_CCT_Robertson1968, as a second method.
"""

import json
import os
import warnings
from importlib.metadata import version

import numpy as np

warnings.filterwarnings("ignore")
import colour  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "photometry_reference.json")
GRID = np.arange(360, 831, dtype=float)
SIXTEEN = [400 + 20 * i for i in range(16)]  # 400..700


def planck(nm, t):
    """Planck's law normalised to 1 at 560 nm (W m-2 nm-1 in the cases)."""
    b = colour.colorimetry.planck_law(np.asarray(nm, float) * 1e-9, t)
    return b / colour.colorimetry.planck_law(560e-9, t)


def on_grid(nm, values):
    nm = np.asarray(nm, float)
    values = np.asarray(values, float)
    if len(nm) == 1:
        return np.full_like(GRID, values[0])
    return np.interp(GRID, nm, values)  # np.interp holds the end values beyond the ends


def case(name, nm, values, note):
    g = on_grid(nm, values)
    sd = colour.SpectralDistribution(dict(zip(GRID, g)), name=name)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(colour.SpectralShape(360, 830, 1))
    xyz = colour.sd_to_XYZ(sd, cmfs=cmfs, method="Integration", k=1)
    uv = colour.UCS_to_uv(colour.XYZ_to_UCS(xyz))
    cct, duv = colour.temperature.uv_to_CCT_Ohno2013(uv)
    try:
        rob = float(colour.temperature.uv_to_CCT_Robertson1968(uv)[0])
    except Exception:  # outside Robertson's table
        rob = None
    lux = float(colour.luminous_flux(sd, K_m=683.0))
    return {
        "name": name, "note": note, "wavelengths_nm": [float(x) for x in nm],
        "irradiance_w_m2_nm": [float(x) for x in values], "XYZ": [float(x) for x in xyz],
        "illuminance_lux": lux, "cct_ohno2013_k": float(cct), "duv_ohno2013": float(duv),
        "cct_robertson1968_k": rob,
    }


def main():
    cases = []
    for t in [2000.0, 3000.0, 4500.0, 6500.0, 12000.0, 25000.0]:
        cases.append(case(f"planck_{int(t)}_1nm", GRID, planck(GRID, t), "Planckian radiator, 1 nm samples"))
        cases.append(case(f"planck_{int(t)}_16", SIXTEEN, planck(SIXTEEN, t), "Planckian radiator, 16 samples"))
    for ill in ["A", "D50", "D65"]:
        sd = colour.SDS_ILLUMINANTS[ill].copy().align(colour.SpectralShape(360, 830, 1))
        v = sd.values / 100.0
        cases.append(case(f"cie_{ill.lower()}_1nm", GRID, v, f"CIE illuminant {ill} / 100 as W m-2 nm-1"))
        v16 = np.interp(SIXTEEN, GRID, v)
        cases.append(case(f"cie_{ill.lower()}_16", SIXTEEN, v16, f"CIE illuminant {ill} / 100, 16 samples"))
    # Bluish twilight-like global light: D65 tilted by (550/lambda)^1.5, 16 samples.
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(360, 830, 1)).values / 100.0
    blue = np.interp(SIXTEEN, GRID, d65) * (550.0 / np.array(SIXTEEN)) ** 1.5
    cases.append(case("d65_rayleigh_tilt_16", SIXTEEN, blue, "D65 x (550/lambda)^1.5, 16 samples"))
    header = {
        "source": "tools/photometry_reference.py",
        "package_versions": {"colour-science": version("colour-science"), "numpy": np.__version__,
                             "scipy": version("scipy")},
        "convention": "samples interpolated linearly onto 360-830 nm at 1 nm, constant beyond the ends; "
                      "XYZ = sum E cmf 1 nm (CIE 1931 2 deg); lux = 683 sum E V 1 nm",
        "notes": "CCT by Ohno 2013 (colour-science default) and Robertson 1968; Duv signed, positive above the locus",
    }
    json.dump({"header": header, "cases": cases}, open(OUT, "w"), indent=1)
    for c in cases:
        print(c["name"], round(c["illuminance_lux"], 3), round(c["cct_ohno2013_k"], 2), round(c["duv_ohno2013"], 5),
              c["cct_robertson1968_k"])


if __name__ == "__main__":
    main()
