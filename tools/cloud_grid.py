#!/usr/bin/env python3
"""The validation cloud: a small cumulus of metaballs voxelised in numpy (no skybake code involved).

Writes tests/data/cloud_mitsuba_grid.npy (float32, shape (nz, ny, nx) = (64, 64, 64), C order,
[z][y][x] with x fastest), the density grid that both Mitsuba 3 (tools/cloud_mitsuba.py) and
skybake's validation scenes (tests/data/validation-cloud-*.json, `"type": "grid"`) read.

Geometry (the .npy holds none; it is repeated in every scene and in tests/data/cloud_mitsuba.json):
voxel edge 30 m, box minimum corner ORIGIN_M = (-960, -960, 1000) m, so the box is
[-960, 960] x [-960, 960] x [1000, 2920] m in skybake's world frame (z up). Voxel (i, j, k) holds the
density at its centre ORIGIN_M + (i + 1/2, j + 1/2, k + 1/2) * 30 m (crates/physics/src/cloud/grid.rs convention).

Density (dimensionless, in [0, 1]): Wyvill-type soft field f(p) = sum_b (1 - |p - c_b|^2 / R_b^2)^3
(zero outside each ball), mapped to density = clamp((f - 0.1) / 0.4, 0, 1) and multiplied by a
smoothstep that flattens the base between z = 1100 and 1250 m. The outermost layer of voxels is 0,
so the clamped-to-face convention never adds density at the box faces.

    python3 tools/cloud_grid.py        # instant; numpy only
"""

import os

import numpy as np

DIMS = 64
VOXEL_M = 30.0
ORIGIN_M = (-960.0, -960.0, 1000.0)
# (centre x, y, z in metres, radius in metres)
BALLS = [
    (0.0, 0.0, 1550.0, 650.0),
    (-380.0, 150.0, 1750.0, 500.0),
    (400.0, -120.0, 1800.0, 480.0),
    (50.0, -80.0, 2150.0, 460.0),
    (-150.0, 220.0, 2450.0, 320.0),
    (300.0, 300.0, 1500.0, 420.0),
]
BASE_Z_M = (1100.0, 1250.0)

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "cloud_mitsuba_grid.npy")


def density_at(x, y, z):
    """Density at world points (metres); broadcasting numpy arrays."""
    f = np.zeros(np.broadcast(x, y, z).shape)
    for cx, cy, cz, r in BALLS:
        q = ((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / r**2
        f += np.where(q < 1.0, (1.0 - q) ** 3, 0.0)
    d = np.clip((f - 0.1) / 0.4, 0.0, 1.0)
    t = np.clip((z - BASE_Z_M[0]) / (BASE_Z_M[1] - BASE_Z_M[0]), 0.0, 1.0)
    return d * t * t * (3.0 - 2.0 * t)


def make_grid():
    c = (np.arange(DIMS) + 0.5) * VOXEL_M
    z, y, x = np.meshgrid(ORIGIN_M[2] + c, ORIGIN_M[1] + c, ORIGIN_M[0] + c, indexing="ij")
    g = density_at(x, y, z).astype(np.float32)
    if g[0].any() or g[-1].any() or g[:, 0].any() or g[:, -1].any() or g[:, :, 0].any() or g[:, :, -1].any():
        raise SystemExit("cloud touches the box faces")
    return g


def main():
    g = make_grid()
    np.save(OUT, g)
    print(f"wrote {os.path.normpath(OUT)}: shape {g.shape}, max {g.max():.3f}, "
          f"mean {g.mean():.4f}, non-zero {np.count_nonzero(g)}")


if __name__ == "__main__":
    main()
