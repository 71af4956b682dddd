#!/usr/bin/env python3
"""Reference solar positions from pvlib's implementation of the NREL SPA (Reda & Andreas 2004/2008).

Writes tests/data/pvlib_spa.json. Run from the repository root:

    python3 tools/spa_reference.py

pvlib.solarposition.spa_python (how="numpy") is called once per case with the case's latitude,
longitude, altitude, pressure, temperature, delta_t and atmos_refract. Cases cover latitudes -89..89,
longitudes -180..180 and UTC instants 1950..2100: equinoxes and solstices, polar day and night, the sun
within a degree of the horizon (sunrise/sunset found by bisection on pvlib's own elevation), the
refraction cut-off, and seeded random cases.
"""

import json
import math
import os
import sys
from importlib.metadata import version

import numpy as np
import pandas as pd
import pvlib

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "pvlib_spa.json")
PRESSURE_PA = 101325.0
TEMPERATURE_C = 12.0
ALTITUDE_M = 0.0
DELTA_T_S = 69.0
ATMOS_REFRACT_DEG = 0.5667
SEED = 1854


def spa(time_utc, lat, lon, altitude_m=ALTITUDE_M, delta_t_s=DELTA_T_S, pressure_pa=PRESSURE_PA,
        temperature_c=TEMPERATURE_C):
    t = pd.DatetimeIndex([pd.Timestamp(time_utc)]).tz_localize("UTC") if pd.Timestamp(time_utc).tzinfo is None \
        else pd.DatetimeIndex([pd.Timestamp(time_utc)])
    df = pvlib.solarposition.spa_python(
        t, lat, lon, altitude=altitude_m, pressure=pressure_pa, temperature=temperature_c,
        delta_t=delta_t_s, atmos_refract=ATMOS_REFRACT_DEG, how="numpy",
    )
    return df.iloc[0], t[0]


def find_elevation_crossing(day_utc, lat, lon, target_elevation_deg, rising):
    """Bisect for the instant on day_utc where the true (unrefracted) elevation equals the target."""
    t0 = pd.Timestamp(day_utc, tz="UTC")
    grid = [t0 + pd.Timedelta(minutes=10 * i) for i in range(145)]
    elev = [spa(t, lat, lon)[0]["elevation"] for t in grid]
    for a, b, ea, eb in zip(grid[:-1], grid[1:], elev[:-1], elev[1:]):
        if (ea - target_elevation_deg) * (eb - target_elevation_deg) <= 0 and ((eb > ea) == rising):
            for _ in range(30):
                m = a + (b - a) / 2
                em = spa(m, lat, lon)[0]["elevation"]
                if (ea - target_elevation_deg) * (em - target_elevation_deg) <= 0:
                    b, eb = m, em
                else:
                    a, ea = m, em
            return (a + (b - a) / 2).round("s")
    raise RuntimeError(f"no crossing of {target_elevation_deg} on {day_utc} at {lat}, {lon}")


def main():
    cases = []

    def add(label, time_utc, lat, lon, altitude_m=ALTITUDE_M, delta_t_s=DELTA_T_S, pressure_pa=PRESSURE_PA,
            temperature_c=TEMPERATURE_C):
        row, t = spa(time_utc, lat, lon, altitude_m, delta_t_s, pressure_pa, temperature_c)
        cases.append({
            "label": label,
            "time_utc": t.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "unix_seconds": int(t.timestamp()),
            "latitude_deg": float(lat),
            "longitude_deg": float(lon),
            "elevation_m": float(altitude_m),
            "pressure_pa": float(pressure_pa),
            "temperature_c": float(temperature_c),
            "delta_t_s": float(delta_t_s),
            "atmos_refract_deg": ATMOS_REFRACT_DEG,
            "zenith_deg": float(row["zenith"]),
            "elevation_deg": float(row["elevation"]),
            "apparent_zenith_deg": float(row["apparent_zenith"]),
            "apparent_elevation_deg": float(row["apparent_elevation"]),
            "azimuth_deg": float(row["azimuth"]),
            "equation_of_time_min": float(row["equation_of_time"]),
        })

    # Reda & Andreas (2004) worked example (Table A4.1 inputs: 2003-10-17 12:30:30 local time, UTC-7,
    # 820 mbar, 11 C). Their published results: topocentric zenith 50.11162 deg, azimuth 194.34024 deg;
    # SPA's "topocentric zenith angle" includes refraction, so it is pvlib's apparent_zenith.
    add("reda_andreas_2004_example", "2003-10-17T19:30:30", 39.742476, -105.1786, 1830.14, 67.0, 82000.0, 11.0)
    ex = cases[-1]
    if abs(ex["apparent_zenith_deg"] - 50.11162) > 1e-5 or abs(ex["azimuth_deg"] - 194.34024) > 1e-5:
        sys.exit(f"pvlib does not reproduce the Reda & Andreas example: {ex}")

    # Equinoxes and solstices, several latitudes, local solar noon-ish at longitude 0 and elsewhere.
    for date in ["2000-03-20T12:00:00", "2000-06-21T12:00:00", "2000-09-22T12:00:00", "2000-12-21T12:00:00"]:
        for lat in [-60.0, -23.44, 0.0, 23.44, 51.5]:
            add(f"equinox_solstice {date[:10]}", date, lat, 0.0)
    # Polar day and night at both poles around the solstices, several hours.
    for date, lat, what in [("2024-06-21T00:00:00", 89.0, "polar day"), ("2024-06-21T06:00:00", 89.0, "polar day"),
                            ("2024-06-21T12:00:00", -89.0, "polar night"), ("2024-12-21T18:00:00", -89.0, "polar day"),
                            ("2024-12-21T00:00:00", 89.0, "polar night"), ("1975-06-21T03:00:00", 78.2, "polar day"),
                            ("2085-12-21T13:00:00", 75.0, "polar night")]:
        add(what, date, lat, 15.0 if lat > 0 else -70.0)
    # Sun near the horizon: true elevation 0, -0.5 (refraction lifts it) and -0.9 (below the cut-off).
    for day, lat, lon, target, rising in [("2024-03-20", 40.0, -105.0, 0.0, True),
                                          ("2024-03-20", 40.0, -105.0, -0.5, False),
                                          ("1988-07-04", 60.17, 24.94, 0.2, True),
                                          ("2050-11-02", -33.9, 151.2, -0.3, False),
                                          ("2010-01-15", 35.7, 139.7, -0.85, True),
                                          ("2099-09-01", -54.8, -68.3, 0.5, False)]:
        t = find_elevation_crossing(day, lat, lon, target, rising)
        add(f"near horizon (true elevation ~{target})", t, lat, lon)
    # Extreme longitudes and the date line.
    add("date line east", "2001-01-01T00:00:00", 10.0, 180.0)
    add("date line west", "2001-01-01T00:00:00", 10.0, -180.0)
    add("early range", "1950-01-01T00:00:00", 45.0, 90.0, delta_t_s=29.0)
    add("late range", "2100-12-31T23:59:59", -45.0, -90.0, delta_t_s=203.0)
    add("delta_t zero", "2020-05-05T05:05:05", 30.0, 120.0, delta_t_s=0.0)
    add("high altitude", "2015-08-15T16:00:00", -16.5, -68.15, altitude_m=4000.0)
    # Seeded random cases.
    rng = np.random.default_rng(SEED)
    t_lo = pd.Timestamp("1950-01-01", tz="UTC").timestamp()
    t_hi = pd.Timestamp("2100-12-31", tz="UTC").timestamp()
    for i in range(20):
        t = pd.Timestamp(int(rng.uniform(t_lo, t_hi)), unit="s", tz="UTC")
        add("random", t, float(np.round(rng.uniform(-89.0, 89.0), 4)), float(np.round(rng.uniform(-180.0, 180.0), 4)))

    data = {
        "header": {
            "source": "pvlib.solarposition.spa_python (NREL SPA, Reda & Andreas 2004, Solar Energy 76, 577-589; "
                      "corrigendum 2007), generated by tools/spa_reference.py",
            "package_versions": {"pvlib": version("pvlib"), "numpy": np.__version__, "pandas": pd.__version__,
                                 "python": sys.version.split()[0]},
            "inputs": {
                "how": "numpy",
                "default_pressure_pa": PRESSURE_PA, "default_temperature_c": TEMPERATURE_C,
                "default_altitude_m": ALTITUDE_M, "default_delta_t_s": DELTA_T_S,
                "atmos_refract_deg": ATMOS_REFRACT_DEG,
                "per_case": "every case repeats its own inputs; time_utc is exact to the second and unix_seconds "
                            "is the same instant",
            },
            "fields": {
                "zenith_deg": "topocentric zenith angle without refraction",
                "elevation_deg": "topocentric elevation without refraction (90 - zenith)",
                "apparent_zenith_deg": "with SPA refraction (Reda & Andreas eq. 42), applied only when the true "
                                       "elevation >= -(0.26667 + atmos_refract_deg)",
                "apparent_elevation_deg": "90 - apparent_zenith_deg",
                "azimuth_deg": "topocentric azimuth, eastward from north (0..360)",
                "equation_of_time_min": "SPA equation of time (Reda & Andreas A.1), minutes",
            },
            "notes": [
                "delta_t_s is an input (TT - UT1); we use 69 s for most cases regardless of the year so the "
                "comparison tests the algorithm, not a delta-T model; a few cases use other values to exercise it.",
                "pvlib converts pressure from Pa to mbar (hPa) before SPA's refraction formula.",
                "Case 'reda_andreas_2004_example' uses the paper's own inputs (altitude 1830.14 m, delta_t 67 s, "
                "820 mbar, 11 C); pvlib reproduces the published (refracted) zenith 50.11162 deg and azimuth 194.34024 deg "
                "to 1e-5 deg (checked by the script). All other cases use 101325 Pa and 12 C.",
            ],
        },
        "cases": cases,
    }
    with open(OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    print(f"wrote {os.path.normpath(OUT)}: {len(cases)} cases")


if __name__ == "__main__":
    main()
