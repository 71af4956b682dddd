#!/usr/bin/env python3
"""Writes the .npy fixtures for tests/clouds/cloud_import_grids.rs with NumPy's own writer (np.save),
so the Rust reader is checked against an independent implementation of the format.

Values: v[z, y, x] = 0.5 + 0.1 x + 0.01 y + 0.001 z, shape (nz, ny, nx) = (3, 4, 5).
Run from the repository root: python3 tools/make_cloud_npy_fixtures.py
"""
import numpy as np

nz, ny, nx = 3, 4, 5
z, y, x = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
v = 0.5 + 0.1 * x + 0.01 * y + 0.001 * z

out = "tests/data/"
np.save(out + "cloud_grid_f4.npy", v.astype("<f4"))
np.save(out + "cloud_grid_f8.npy", v.astype("<f8"))
np.save(out + "cloud_grid_fortran.npy", np.asfortranarray(v.astype("<f4")))
np.save(out + "cloud_grid_big_endian.npy", v.astype(">f4"))
np.save(out + "cloud_grid_int32.npy", (v * 100).astype("<i4"))
np.save(out + "cloud_grid_2d.npy", v[0].astype("<f4"))
print("numpy", np.__version__)
