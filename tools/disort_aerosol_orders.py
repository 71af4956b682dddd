#!/usr/bin/env python3
"""Diagnostic (writes nothing under tests/data): the DISORT aerosol references split by order of
scattering, to locate which order of the precise method carries a deviation.

    python3 tools/disort_aerosol_orders.py ATMOSPHERE NM SUN_ZENITH_DEG [OUT.json]

Method: analytic continuation in the single-scattering albedo. With every layer's ssa and the
ground albedo multiplied by s, the radiance is a power series I(s) = sum_n s^n I_n, n the number of
interactions (scatterings by the air and reflections by the ground, as the precise method counts
its orders: order 1 is single scattering plus the ground's reflection of direct sun). DISORT is run
(tools/disort_aerosol.py's exact setup, 32 streams, delta-M + Nakajima-Tanaka) at K = 16 values
s in (0, 0.3] and a polynomial of degree 12 without constant term is fitted by least squares; its
first coefficients are I_1, I_2, I_3. A second fit of degree 10 gives the extraction's uncertainty
("fit diff", relative to the total): below 1e-6 for I_1 and I_2 and 1e-4 for I_3 except at view
zeniths within a few degrees of the sun zenith (the low sky around a low sun), where the series
converges slowly and I_3 is not usable. Prints, per point of the reference's grid and for the
diffuse irradiance, the shares I_1/I, I_2/I, I_3/I and the rest; writes them to OUT.json.
"""
import json
import math
import os
import sys

import numpy as np
import pydisort

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import disort_aerosol as da  # noqa: E402

S_MAX, SAMPLES, DEGREE = 0.3, 16, 12


def solve_scaled(atm, nm, sza, s):
    """Radiances at the reference's points and the diffuse irradiance, ssa and albedo times s."""
    dtau, ssa, mom = da.mixed_layers(atm, nm, da.layer_edges_m())
    vzs = da.view_zeniths(sza)
    flx, rad = da.run_disort(dtau, ssa * s, mom, da.NSTR, math.cos(math.radians(sza)),
                             atm["albedo"] * s, -np.cos(np.radians(vzs)), da.RELATIVE_AZIMUTH_DEG)
    pts = da.sky_points(sza, rad)
    return np.array([p[3] for p in pts] + [float(flx[1, pydisort.kIFLDN])]), pts


def main():
    name, nm, sza = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    atm = next(a for a in da.ATMOSPHERES if a["name"] == name)
    total, pts = solve_scaled(atm, nm, sza, 1.0)
    ss = S_MAX * np.arange(1, SAMPLES + 1) / SAMPLES
    y = np.array([solve_scaled(atm, nm, sza, s)[0] for s in ss])
    a = np.array([[s ** n for n in range(1, DEGREE + 1)] for s in ss])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    check, *_ = np.linalg.lstsq(a[:, :DEGREE - 2], y, rcond=None)
    labels = [p[:3] for p in pts] + [["diffuse_horizontal"]]
    for i, p in enumerate(labels):
        o = [coef[n][i] / total[i] for n in range(3)]
        d = [abs(coef[n][i] - check[n][i]) / total[i] for n in range(3)]
        print(p, "I1 %.4f I2 %.4f I3 %.4f rest %.4f  (fit diff %.1e %.1e %.1e)" % (*o, 1 - sum(o), *d))
    if len(sys.argv) > 4:
        with open(sys.argv[4], "w") as f:
            json.dump({"atmosphere": name, "nm": nm, "sza": sza, "points": labels,
                       "total": total.tolist(), "orders": [coef[n].tolist() for n in range(3)],
                       "orders_check": [check[n].tolist() for n in range(3)]}, f)


if __name__ == "__main__":
    main()
