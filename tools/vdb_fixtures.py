#!/usr/bin/python3 -s
"""OpenVDB test fixtures written by the reference OpenVDB library (Debian's python3-openvdb).

Writes into tests/data (or --out DIR):

  cloud_vdb_density.vdb    one float grid "density": a sparse tree (leaves, an 8^3 constant tile
                           after prune(), empty regions, negative index coordinates) with a uniform
                           scale-and-translate transform (voxel 25 m, translation below)
  cloud_vdb_density.npy    the same voxels as a dense float32 array (nz, ny, nx) over the grid's
                           active bounding box, written by NumPy; cloud_vdb_fixtures.json gives its
                           origin_m and voxel size, so the .npy import reads the same grid
  cloud_vdb_half.vdb       the same grid saved as half floats (saveFloatAsHalf): refused (the
                           decoder misreads half arrays); every value is exactly representable in
                           binary16, so a reader of half floats must read it back equal
  cloud_vdb_multi.vdb      grids "temperature" (float), "vel" (Vec3S) and "density" (float, the
                           density grid again): selection by name, wrong value type
  cloud_vdb_levelset.vdb   a level-set sphere (grid class "level set"): not a density, refused
  cloud_vdb_rotated.vdb    the density grid under a rotated (affine) transform: refused
  cloud_vdb_oversize.vdb   two active voxels 4000 voxels apart: a 4001^3 box, refused by size

and config/scenes/vdb-cloud.vdb (the example frame scene's fog volume: the two balls of the density
grid without the constant block, centred over the origin at about 1.5 km).

Run with Debian's interpreter (the package installs for it):
    apt-get install -y python3-openvdb
    /usr/bin/python3 -s tools/vdb_fixtures.py            # writes tests/data and the example
    /usr/bin/python3 -s tools/vdb_fixtures.py --check    # rewrites into a temporary directory and
                                                         # compares with the committed files
A .vdb file carries a random UUID (bytes 21..57 of the header); --check compares everything else
byte for byte.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile

import numpy as np
import pyopenvdb as vdb

VOXEL_M = 25.0
TRANSLATION_M = (-1000.0, 500.0, 1500.0)
EXAMPLE_TRANSLATION_M = (-100.0, -400.0, 1250.0)
# Index box of the density (half-open): x in [-12, 20), y in [4, 28), z in [0, 24).
LO = (-12, 4, 0)
SHAPE_XYZ = (32, 24, 24)
UUID_BYTES = (21, 57)


def density_xyz(block=True):
    """Dense density indexed [x][y][z] (index space from LO), exactly representable in binary16."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in SHAPE_XYZ), indexing="ij")
    x, y, z = i + LO[0], j + LO[1], k + LO[2]

    def ball(cx, cy, cz, r, peak):
        d2 = ((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / r**2
        return np.where(d2 < 1.0, peak * (1.0 - d2) ** 2, 0.0)

    d = ball(-2.0, 14.0, 9.0, 9.0, 0.8) + ball(10.0, 18.0, 12.0, 7.5, 0.6)
    d[d < 0.02] = 0.0  # background: inactive voxels
    # An 8^3 constant block aligned to a leaf (index [8, 16)^3): prune() makes it a tile.
    if block:
        d[8 - LO[0]:16 - LO[0], 8 - LO[1]:16 - LO[1], 8 - LO[2]:16 - LO[2]] = 0.75
    return d.astype(np.float16).astype(np.float32)


def transform(rotated=False, translation=TRANSLATION_M):
    m = np.diag([VOXEL_M, VOXEL_M, VOXEL_M, 1.0])
    if rotated:
        # Exactly 30°, from operations rounded the same on every CPU (numpy's SIMD cos and sin
        # differ in the last bit between AVX2 and AVX-512 machines, and the file holds the bits).
        c, s = np.sqrt(3.0) / 2.0, 0.5
        m[:3, :3] = VOXEL_M * np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    m[3, :3] = translation
    return vdb.createLinearTransform(m)


def density_grid(name="density", rotated=False):
    g = vdb.FloatGrid()
    g.name = name
    g.copyFromArray(density_xyz(), ijk=LO)
    g.prune()
    g.transform = transform(rotated)
    return g


def write_example(out):
    out.mkdir(parents=True, exist_ok=True)
    g = vdb.FloatGrid()
    g.name = "density"
    g.copyFromArray(density_xyz(block=False), ijk=LO)
    g.gridClass = vdb.GridClass.FOG_VOLUME
    g.transform = transform(translation=EXAMPLE_TRANSLATION_M)
    vdb.write(str(out / "vdb-cloud.vdb"), [g])


def write_all(out):
    out.mkdir(parents=True, exist_ok=True)
    d = density_xyz()
    g = density_grid()
    vdb.write(str(out / "cloud_vdb_density.vdb"), [g])

    h = density_grid()
    h.saveFloatAsHalf = True
    vdb.write(str(out / "cloud_vdb_half.vdb"), [h])

    t = vdb.FloatGrid()
    t.name = "temperature"
    t.copyFromArray(np.full((4, 4, 4), 280.0, np.float32), ijk=(0, 0, 0))
    t.transform = transform()
    v = vdb.Vec3SGrid()
    v.name = "vel"
    v.copyFromArray(np.ones((4, 4, 4, 3), np.float32), ijk=(0, 0, 0))
    v.transform = transform()
    vdb.write(str(out / "cloud_vdb_multi.vdb"), [t, v, density_grid()])

    ls = vdb.createLevelSetSphere(radius=50.0, center=(0, 0, 0), voxelSize=VOXEL_M, halfWidth=2.0)
    ls.name = "surface"
    vdb.write(str(out / "cloud_vdb_levelset.vdb"), [ls])

    vdb.write(str(out / "cloud_vdb_rotated.vdb"), [density_grid(rotated=True)])

    o = vdb.FloatGrid()
    o.name = "density"
    acc = o.getAccessor()
    acc.setValueOn((0, 0, 0), 0.5)
    acc.setValueOn((4000, 4000, 4000), 0.5)
    o.transform = transform()
    vdb.write(str(out / "cloud_vdb_oversize.vdb"), [o])

    # The same voxels for the .npy import: shape (nz, ny, nx) over the active bounding box.
    active = np.argwhere(d > 0.0)
    lo, hi = active.min(axis=0), active.max(axis=0) + 1
    box = d[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    np.save(out / "cloud_vdb_density.npy", np.ascontiguousarray(box.transpose(2, 1, 0)))
    bbox_min = [int(lo[a] + LO[a]) for a in range(3)]
    # Voxel (i, j, k) is centred at index·voxel + translation: the box's minimum corner is half a
    # voxel below the first active centre.
    origin = [(bbox_min[a] - 0.5) * VOXEL_M + TRANSLATION_M[a] for a in range(3)]
    meta = {
        "source": "tools/vdb_fixtures.py, OpenVDB %s (python3-openvdb), NumPy %s"
        % (".".join(map(str, vdb.LIBRARY_VERSION)), np.__version__),
        "density_npy": {
            "file": "cloud_vdb_density.npy",
            "dims_xyz": [int(n) for n in box.shape],
            "voxel_size_m": VOXEL_M,
            "origin_m": origin,
            "index_bbox_min": bbox_min,
            "active_voxels": int((d > 0.0).sum()),
            "sum": float(d.astype(np.float64).sum()),
        },
        "density_vdb": {
            "leaf_count": int(g.leafCount()),
            "active_voxels": int(g.activeVoxelCount()),
            "active_bbox": [list(map(int, c)) for c in g.evalActiveVoxelBoundingBox()],
        },
    }
    (out / "cloud_vdb_fixtures.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


def same_except_uuid(a, b):
    if len(a) != len(b):
        return False
    s, e = UUID_BYTES
    return a[:s] == b[:s] and a[e:] == b[e:]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=pathlib.Path,
                    default=pathlib.Path(__file__).resolve().parent.parent / "tests" / "data")
    ap.add_argument("--examples", type=pathlib.Path,
                    default=pathlib.Path(__file__).resolve().parent.parent / "config" / "scenes")
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    if not args.check:
        meta = write_all(args.out)
        write_example(args.examples)
        print(json.dumps(meta["density_vdb"]))
        return
    with tempfile.TemporaryDirectory() as tmp:
        write_all(pathlib.Path(tmp) / "data")
        write_example(pathlib.Path(tmp) / "examples")
        bad = []
        pairs = [(pathlib.Path(tmp) / "data" / f, args.out / f)
                 for f in sorted(os.listdir(pathlib.Path(tmp) / "data"))]
        pairs.append((pathlib.Path(tmp) / "examples" / "vdb-cloud.vdb",
                      args.examples / "vdb-cloud.vdb"))
        for new_path, old_path in pairs:
            f = old_path.name
            new = new_path.read_bytes()
            old = old_path.read_bytes() if old_path.exists() else b""
            same = same_except_uuid(new, old) if f.endswith(".vdb") else new == old
            if not same:
                bad.append(f)
        if bad:
            sys.exit("OpenVDB fixtures differ from a fresh write: " + ", ".join(bad))
        print("OpenVDB fixtures match a fresh write")


if __name__ == "__main__":
    main()
