#!/usr/bin/env python3
"""CIE 1931 XYZ, linear sRGB and chromaticity of sampled spectra, computed with colour-science.

Writes tests/data/colour_reference.json. Run from the repository root:

    python3 tools/colour_reference.py

The skybake colour convention this file pins down:
  1. A spectrum given at N sample wavelengths (nm) is linearly interpolated onto the 1 nm grid
     360..830 nm and held constant beyond its first and last sample.
  2. XYZ = sum over the grid of L(lambda) * cmf(lambda) * 1 nm, with the CIE 1931 2-degree CMFs and no
     683 lm/W factor and no normalisation (k = 1, equal-energy illuminant of ones).
  3. Linear sRGB = M * XYZ with the IEC 61966-2-1 XYZ -> sRGB matrix (D65 white, no chromatic
     adaptation, no transfer function, no clipping).
  4. Chromaticity x = X / (X + Y + Z), y = Y / (X + Y + Z).
Every step is done by colour-science itself: colour.algebra.LinearInterpolator wrapped in
colour.algebra.Extrapolator(method="Constant"), colour.sd_to_XYZ(method="Integration", k=100, which colour-science
divides by 100 when k is given, i.e. k = 1 in our formula),
colour.XYZ_to_RGB with the sRGB colourspace (no chromatic adaptation), colour.XYZ_to_xy.
"""

import csv
import json
import os
import sys
from importlib.metadata import version

import numpy as np
import colour
from colour import SpectralDistribution, SpectralShape
from colour.algebra import Extrapolator, LinearInterpolator

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
OUT = os.path.join(ROOT, "tests", "data", "colour_reference.json")
ASTM = "/work/shared/data/astm_g173_extraterrestrial.csv"
SHAPE = SpectralShape(360, 830, 1)
CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
SRGB = colour.RGB_COLOURSPACES["sRGB"]
SEED = 20261125


def read_astm():
    wl, e = [], []
    with open(ASTM) as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))]
    for r in rows[1:]:
        wl.append(float(r[0]))
        e.append(float(r[1]))
    return np.array(wl), np.array(e)


def to_grid(wavelengths_nm, values):
    """Linear interpolation onto 360..830 nm at 1 nm, constant beyond the first/last sample (colour-science)."""
    if len(wavelengths_nm) == 1:
        # colour-science cannot build a one-sample distribution; constant extrapolation of one value.
        return np.full(len(SHAPE.wavelengths), float(values[0]))
    # colour-science's own linear interpolator wrapped in its constant extrapolator. (Going through
    # SpectralDistribution.interpolate would start the 1 nm grid at the first sample, which is not an
    # integer wavelength for arbitrary samples.)
    resample = Extrapolator(
        LinearInterpolator(np.asarray(wavelengths_nm, dtype=float), np.asarray(values, dtype=float)),
        method="Constant", left=None, right=None,
    )
    return np.asarray(resample(SHAPE.wavelengths), dtype=float)


def colour_of(wavelengths_nm, values):
    grid = to_grid(wavelengths_nm, values)
    sd = SpectralDistribution(grid, SHAPE.wavelengths, name="grid")
    # colour-science divides by 100 whenever k is given ("absolute" XYZ from percentages), so k = 100
    # here is k = 1 in the skybake formula: XYZ = sum L * cmf * 1 nm.
    XYZ = colour.sd_to_XYZ(sd, cmfs=CMFS, illuminant=colour.sd_ones(SHAPE), k=100, method="Integration")
    rgb = colour.XYZ_to_RGB(XYZ, SRGB, chromatic_adaptation_transform=None, apply_cctf_encoding=False)
    xy = colour.XYZ_to_xy(XYZ)
    # Independent check of the same convention with numpy (np.interp holds the end values constant).
    grid_np = np.interp(SHAPE.wavelengths, wavelengths_nm, values)
    if not np.allclose(grid_np, grid, rtol=1e-12, atol=1e-15):
        sys.exit(f"colour-science and numpy resampling disagree for {wavelengths_nm}")
    xyz_np = grid @ CMFS.values
    if not np.allclose(xyz_np, XYZ, rtol=1e-12, atol=0):
        sys.exit(f"colour-science and numpy disagree: {XYZ} vs {xyz_np}")
    return grid, XYZ, rgb, xy


def main():
    rng = np.random.default_rng(SEED)
    astm_wl, astm_e = read_astm()

    def astm_at(wls):
        return np.interp(wls, astm_wl, astm_e)

    cases_in = []
    wl1 = list(range(360, 831))
    cases_in.append(("astm_g173_etr_1nm", wl1, astm_at(wl1),
                     "ASTM G173 extraterrestrial W m^-2 nm^-1 at every integer nm 360..830 (table values)"))
    wl16 = list(range(400, 701, 20))
    cases_in.append(("astm_g173_etr_16", wl16, astm_at(wl16), "ASTM G173 ETR at 400, 420, ..., 700 nm"))
    wl4 = [400, 500, 600, 700]
    cases_in.append(("astm_g173_etr_4", wl4, astm_at(wl4), "ASTM G173 ETR at 400, 500, 600, 700 nm"))
    wl3d = [440, 550, 680]
    cases_in.append(("astm_g173_etr_3_rgb_bands", wl3d, astm_at(wl3d),
                     "ASTM G173 ETR at 440, 550, 680 nm (constant extrapolation below 440 and above 680)"))
    cases_in.append(("flat_one", wl1, np.ones(len(wl1)), "L = 1 at every nm 360..830"))
    cases_in.append(("flat_one_2_samples", [360, 830], [1.0, 1.0], "L = 1 given at two samples"))
    cases_in.append(("single_sample", [550], [2.0], "one sample: constant 2 everywhere"))
    cases_in.append(("spike_550_7", [400, 450, 500, 550, 600, 650, 700], [0, 0, 0, 1.0, 0, 0, 0],
                     "triangle of half-width 50 nm at 550 nm"))
    cases_in.append(("spike_450_3", [440, 450, 460], [0.0, 1.0, 0.0], "narrow triangle at 450 nm"))
    cases_in.append(("spike_620_3", [615, 620, 625], [0.0, 1.0, 0.0], "narrow triangle at 620 nm"))
    wl3r = sorted(rng.choice(np.arange(380, 781), 3, replace=False).tolist())
    cases_in.append(("random_3", wl3r, rng.uniform(0.05, 2.0, 3), "random positive, 3 random integer nm"))
    wl7r = sorted((rng.uniform(360, 830, 7)).round(3).tolist())
    cases_in.append(("random_7", wl7r, rng.uniform(0.05, 2.0, 7),
                     "random positive, 7 random non-integer nm (interpolation between grid points)"))
    wl16r = np.linspace(360, 830, 16).round(6).tolist()
    cases_in.append(("random_16", wl16r, rng.uniform(0.05, 2.0, 16), "random positive, 16 evenly spaced nm"))
    wl16s = [370, 390, 410, 430, 450, 470, 490, 510, 530, 560, 590, 620, 650, 690, 740, 800]
    cases_in.append(("random_16_uneven", wl16s, rng.uniform(0.05, 2.0, 16), "random positive, 16 uneven nm"))

    cases = []
    for name, wls, vals, note in cases_in:
        vals = [float(v) for v in vals]
        wls = [float(w) for w in wls]
        _, XYZ, rgb, xy = colour_of(wls, vals)
        cases.append({
            "name": name, "note": note,
            "wavelengths_nm": wls, "values": vals,
            "XYZ": XYZ.tolist(), "linear_srgb": rgb.tolist(), "xy": xy.tolist(),
        })

    shared = np.loadtxt("/work/shared/data/cie1931_2deg_cmf_1nm.csv", delimiter=",", comments="#", skiprows=3)
    cmf_diff = float(np.max(np.abs(shared[:, 1:] - CMFS.values)))

    data = {
        "header": {
            "source": "colour-science (colour.MSDS_CMFS, colour.sd_to_XYZ, colour.XYZ_to_RGB, colour.XYZ_to_xy); "
                      "generated by tools/colour_reference.py",
            "package_versions": {"colour-science": version("colour-science"), "numpy": np.__version__,
                                 "python": sys.version.split()[0]},
            "inputs": {
                "cmfs": "CIE 1931 2 Degree Standard Observer (colour.MSDS_CMFS), 360..830 nm at 1 nm",
                "astm_file": "/work/shared/data/astm_g173_extraterrestrial.csv (W m^-2 nm^-1); values at "
                             "non-tabulated wavelengths by linear interpolation of the table",
                "random_seed": SEED,
            },
            "convention": {
                "resampling": "linear interpolation onto the integer-nm grid 360..830; constant (first/last sample "
                              "value) outside the sampled range; a single sample means a constant spectrum",
                "XYZ": "sum_{lambda=360}^{830} L(lambda) * cmf(lambda) * 1 nm; no 683 factor, k = 1",
                "linear_srgb": "xyz_to_linear_srgb_matrix @ XYZ (IEC 61966-2-1, D65, no chromatic adaptation, "
                               "no gamma, no clipping)",
                "xy": "x = X/(X+Y+Z), y = Y/(X+Y+Z)",
            },
            "xyz_to_linear_srgb_matrix": SRGB.matrix_XYZ_to_RGB.tolist(),
            "notes": [
                f"The CMFs below equal /work/shared/data/cie1931_2deg_cmf_1nm.csv to {cmf_diff:.1e} (max abs).",
                "colour-science's sRGB XYZ->RGB matrix is the 4-decimal IEC 61966-2-1 matrix itself.",
                "colour.sd_to_XYZ was called with k = 100 because colour-science divides by 100 whenever k is "
                "given (its 'absolute XYZ' convention); the result is exactly sum L * cmf * 1 nm.",
                "Each case was also resampled with numpy.interp and integrated as grid @ cmfs; both agree with "
                "colour-science to 1e-12 relative.",
            ],
        },
        "cmf_wavelengths_nm": SHAPE.wavelengths.astype(int).tolist(),
        "cmf_x_bar": CMFS.values[:, 0].tolist(),
        "cmf_y_bar": CMFS.values[:, 1].tolist(),
        "cmf_z_bar": CMFS.values[:, 2].tolist(),
        "cases": cases,
    }
    with open(OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    print(f"wrote {os.path.normpath(OUT)}: {len(cases)} cases, cmf diff vs shared csv {cmf_diff:.1e}")
    for c in cases:
        print(c["name"], np.round(c["XYZ"], 4), np.round(c["xy"], 4))


if __name__ == "__main__":
    main()
