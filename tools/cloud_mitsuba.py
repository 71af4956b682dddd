#!/usr/bin/env python3
"""Mitsuba 3 reference images of the validation cloud (the 3-D cloud check of the path tracer, and Mitsuba's timings).

Renders tests/data/cloud_mitsuba_grid.npy (tools/cloud_grid.py) with Mitsuba 3's `volpath` integrator
(unbiased, all orders) through a `heterogeneous` medium whose `sigma_t` is a `gridvolume`, in vacuum,
with no ground, lit separately by a collimated sun (`directional`, irradiance 1 normal to the beam) and a
constant sky of radiance 1 over the upper hemisphere only (`envmap`, lower half of the bitmap 0), seen by
a pinhole camera from the side. Writes, under tests/data/:

  cloud_mitsuba.json                    header (versions, conventions, checks, timings) + per-case figures
  cloud_mitsuba_<case>.npy              float32 [120][160] radiance per unit sun irradiance / sky radiance
  cloud_mitsuba_<case>_stderr.npy       float32 [120][160] standard error of that mean (pass-to-pass)
  cloud_mitsuba_tau.npy                 float32 [120][160] optical depth along each pixel-centre ray
                                        (numpy ray march, extinction 0.02 /m; independent of Mitsuba)
  cloud_mitsuba_mask.npy                uint8 [120][160] cloud pixels: tau >= 1
  validation-cloud-<case>.json          the same scene in skybake's scene schema (frame_contract.md)

Usage (from the repository root; set DRJIT_LIBLLVM_PATH to a libLLVM >= 15 for the llvm variants):

  python3 tools/cloud_mitsuba.py checks                 # conventions, ~1 min
  python3 tools/cloud_mitsuba.py render CASE [SPP]      # one case, appends to the JSON
  python3 tools/cloud_mitsuba.py convergence            # time vs NRMSE series for case sun
  python3 tools/cloud_mitsuba.py scenes                 # writes the skybake scene files only
  python3 tools/cloud_mitsuba.py single-scatter-check   # sun_thin depth-2 image vs numpy, after rendering it

Versions used: mitsuba 3.9.1, drjit 1.5.0, numpy 2.4.6, scipy 1.17.1, Python 3.11.7; variant
llvm_ad_mono with libLLVM 19.1.7 (Debian bookworm package libllvm19, extracted with dpkg -x).
"""

import json
import math
import os
import sys
import time
from importlib.metadata import version

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.normpath(os.path.join(HERE, "..", "tests", "data"))
GRID_FILE = "cloud_mitsuba_grid.npy"
JSON_OUT = os.path.join(DATA, "cloud_mitsuba.json")

# ---- the scene (skybake world frame: metres, z up, azimuth from +y towards +x) --------------------
VOXEL_M = 30.0
ORIGIN_M = np.array([-960.0, -960.0, 1000.0])
EXTINCTION_PER_DENSITY_M = 0.02
SUN_ELEVATION_DEG = 35.0
SUN_AZIMUTH_DEG = 100.0
CAMERA = {
    "type": "pinhole",
    "position_m": [0.0, -3200.0, 1900.0],
    "look_at_m": [0.0, 0.0, 1900.0],
    "up": [0.0, 0.0, 1.0],
    "fov_deg": 45.0,
    "fov_axis": "horizontal",
    "width": 160,
    "height": 120,
}
WIDTH, HEIGHT = CAMERA["width"], CAMERA["height"]
# Further cameras (same image size): "below" stands under the cloud's base and looks up at it.
CAMERAS = {
    "side": CAMERA,
    "below": dict(CAMERA, position_m=[0.0, -900.0, 300.0], look_at_m=[0.0, 0.0, 1700.0]),
}
BLOCK = 8
MASK_TAU = 1.0
ENVMAP_HEIGHT = 2048  # rows of the lat-long sky bitmap: the horizon is blurred over +-90/2048 deg

# case -> (lights, g, albedo, extinction per density)
CASES = {
    "sun": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M),
    "sky": dict(sun=False, sky=True, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M),
    "sunsky": dict(sun=True, sky=True, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M),
    "sun_g05": dict(sun=True, sky=False, g=0.5, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M),
    "sun_albedo09": dict(sun=True, sky=False, g=0.85, albedo=0.9, ext=EXTINCTION_PER_DENSITY_M),
    "sun_thin": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M / 20.0),
    # Back-lit: the sun behind the cloud, 35 deg above the view axis (+y), and 22 deg from it
    # (elevation 20, azimuth 10: the cloud's upper edges are seen 5-20 deg from the sun).
    "sun_back35": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M,
                       sun_el=35.0, sun_az=0.0),
    "sun_back20": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M,
                       sun_el=20.0, sun_az=10.0),
    "sun_back35_thin": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M / 20.0,
                            sun_el=35.0, sun_az=0.0),
    # Sun + sky, back-lit: the image is the sum of the sun_back35 and sky renders (`sum`).
    "sunsky_back35": dict(sun=True, sky=True, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M,
                          sun_el=35.0, sun_az=0.0),
    # The camera below the cloud looking up at its base (view elevation 57 deg), sun as in `sun`.
    "below_sun": dict(sun=True, sky=False, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M, camera="below"),
    "below_sky": dict(sun=False, sky=True, g=0.85, albedo=1.0, ext=EXTINCTION_PER_DENSITY_M, camera="below"),
}


def case_camera(case):
    return CASES[case].get("camera", "side")


def case_sun(case):
    """(elevation, azimuth) of the case's sun in degrees."""
    c = CASES[case]
    return c.get("sun_el", SUN_ELEVATION_DEG), c.get("sun_az", SUN_AZIMUTH_DEG)


def mask_file(camera):
    return "cloud_mitsuba_mask.npy" if camera == "side" else f"cloud_mitsuba_mask_{camera}.npy"


def tau_file(camera):
    return "cloud_mitsuba_tau.npy" if camera == "side" else f"cloud_mitsuba_tau_{camera}.npy"


def load_mask(case):
    return np.load(os.path.join(DATA, mask_file(case_camera(case)))).astype(bool)


def sun_direction(case="sun"):
    """Unit vector from the scene towards the case's sun (frame_contract.md azimuth convention)."""
    e, a = (math.radians(x) for x in case_sun(case))
    return np.array([math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), math.sin(e)])


def box_max_m(grid):
    nz, ny, nx = grid.shape
    return ORIGIN_M + VOXEL_M * np.array([nx, ny, nz])


def load_grid():
    g = np.load(os.path.join(DATA, GRID_FILE))
    assert g.dtype == np.float32 and g.ndim == 3
    return g


# ---- camera rays in numpy (our convention, independent of Mitsuba) --------------------------------
def camera_rays(sub=1, camera="side"):
    """Ray directions through sub x sub stratified points of every pixel (sub = 1: pixel centres).

    Pixel (0, 0) is the top-left; pixel centres at (i + 0.5, j + 0.5); the field of view spans the
    image width edge to edge. Returns origin (3,), dirs (HEIGHT, WIDTH, sub*sub, 3)."""
    cam = CAMERAS[camera]
    pos = np.array(cam["position_m"])
    fwd = np.array(cam["look_at_m"]) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    half_w = math.tan(math.radians(cam["fov_deg"]) / 2.0)
    half_h = half_w * HEIGHT / WIDTH
    offs = (np.arange(sub) + 0.5) / sub
    ox, oy = np.meshgrid(offs, offs, indexing="xy")
    ox, oy = ox.ravel(), oy.ravel()
    i = np.arange(WIDTH)[None, :, None] + ox[None, None, :]
    j = np.arange(HEIGHT)[:, None, None] + oy[None, None, :]
    sx = (2.0 * i / WIDTH - 1.0) * half_w
    sy = (1.0 - 2.0 * j / HEIGHT) * half_h
    d = fwd + sx[..., None] * right + sy[..., None] * up
    return pos, d / np.linalg.norm(d, axis=-1, keepdims=True)


def optical_depth(grid, origin, dirs, ext, steps=600):
    """Optical depth along rays through the trilinear, cell-centred grid (midpoint rule inside the box)."""
    from scipy.ndimage import map_coordinates

    lo, hi = ORIGIN_M, box_max_m(grid)
    flat = dirs.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - origin) / flat
        t1 = (hi - origin) / flat
    tn = np.nanmax(np.minimum(t0, t1), axis=1).clip(min=0.0)
    tf = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = tf > tn
    tau = np.zeros(len(flat))
    idx = np.nonzero(hit)[0]
    for chunk in np.array_split(idx, max(1, len(idx) // 2000)):
        n = len(chunk)
        dt = (tf[chunk] - tn[chunk]) / steps
        t = tn[chunk, None] + (np.arange(steps)[None, :] + 0.5) * dt[:, None]
        p = origin + t[..., None] * flat[chunk, None, :]
        c = (p - lo) / VOXEL_M - 0.5  # centre coordinates x, y, z
        coords = np.stack([c[..., 2].ravel(), c[..., 1].ravel(), c[..., 0].ravel()])
        v = map_coordinates(grid, coords, order=1, mode="nearest").reshape(n, steps)
        tau[chunk] = ext * v.sum(axis=1) * dt
    return tau.reshape(dirs.shape[:-1])


# ---- Mitsuba ------------------------------------------------------------------------------------------
def mitsuba(variant=None):
    import mitsuba as mi

    if variant is None:
        variant = os.environ.get("MI_VARIANT", "llvm_ad_mono")
    mi.set_variant(variant)
    return mi


def to_world_box(mi, grid):
    lo, hi = ORIGIN_M, box_max_m(grid)
    return mi.ScalarTransform4f().translate(lo.tolist()).scale((hi - lo).tolist())


def sky_bitmap(mi):
    b = np.zeros((ENVMAP_HEIGHT, 2 * ENVMAP_HEIGHT, 3), np.float32)
    b[: ENVMAP_HEIGHT // 2] = 1.0
    return mi.Bitmap(b)


def sky_emitter(mi):
    # Mitsuba's envmap is y-up in its local frame; rotating +90 deg about x maps local +y to world +z
    # (verified in `checks`: zenith 1, nadir 0).
    return {"type": "envmap", "bitmap": sky_bitmap(mi), "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}


def sensor(mi, spp, seed, camera="side"):
    cam = CAMERAS[camera]
    return {
        "type": "perspective",
        "fov": cam["fov_deg"],
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=cam["position_m"], target=cam["look_at_m"],
                                                   up=cam["up"]),
        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        "film": {"type": "hdrfilm", "width": WIDTH, "height": HEIGHT, "rfilter": {"type": "box"},
                 "pixel_format": "luminance" if "mono" in mi.variant() else "rgb"},
    }


def cloud_scene(mi, grid, case, spp, seed, max_depth=-1):
    c = CASES[case]
    vol = {"type": "gridvolume", "grid": mi.VolumeGrid(grid), "to_world": to_world_box(mi, grid),
           "filter_type": "trilinear"}
    medium = {"type": "heterogeneous", "sigma_t": vol, "scale": c["ext"], "albedo": c["albedo"],
              "phase": {"type": "hg", "g": c["g"]}}
    lo, hi = ORIGIN_M, box_max_m(grid)
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": max_depth, "rr_depth": 10},
        "sensor": sensor(mi, spp, seed, case_camera(case)),
        "cloud": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                  "to_world": mi.ScalarTransform4f().translate(((lo + hi) / 2).tolist()).scale(((hi - lo) / 2).tolist())},
    }
    if c["sun"]:
        scene["sun"] = {"type": "directional", "direction": (-sun_direction(case)).tolist(), "irradiance": 1.0}
    if c["sky"]:
        scene["sky"] = sky_emitter(mi)
    return scene


def render(mi, scene_dict):
    scene = mi.load_dict(scene_dict)
    img = np.array(mi.render(scene), dtype=np.float64)
    return img[..., 0] if img.ndim == 3 else img


# ---- checks ---------------------------------------------------------------------------------------------
def check_gridvolume(mi):
    """Values at voxel centres, trilinear between, clamped to the outermost centre out to the face."""
    a = np.zeros((2, 1, 3), np.float32)
    a[0, 0] = [0.0, 1.0, 4.0]
    a[1, 0] = [10.0, 11.0, 14.0]
    v = mi.load_dict({"type": "gridvolume", "grid": mi.VolumeGrid(a), "filter_type": "trilinear",
                      "to_world": mi.ScalarTransform4f().scale([3.0, 1.0, 2.0])})
    si = mi.SurfaceInteraction3f()
    probes = {  # world point -> expected under skybake's convention (crates/physics/src/cloud/grid.rs)
        (0.05, 0.5, 0.5): 0.0, (0.5, 0.5, 0.5): 0.0, (1.0, 0.5, 0.5): 0.5, (1.5, 0.5, 0.5): 1.0,
        (2.0, 0.5, 0.5): 2.5, (2.5, 0.5, 0.5): 4.0, (2.95, 0.5, 0.5): 4.0, (0.5, 0.2, 0.5): 0.0,
        (0.5, 0.5, 1.0): 5.0, (1.5, 0.5, 1.5): 11.0, (2.5, 0.5, 1.9): 14.0, (1.25, 0.5, 1.25): 0.25 * 0.75 + 0.75 * (0.25 * 10.0 + 0.75 * 11.0),
    }
    worst = 0.0
    got = {}
    for p, want in probes.items():
        si.p = mi.Point3f(*p)
        val = float(np.array(v.eval_1(si)).ravel()[0])
        got[str(p)] = val
        worst = max(worst, abs(val - want))
    if worst > 1e-5:
        sys.exit(f"gridvolume convention differs: {got}")
    return {"probes_world_xyz_to_value": got, "max_abs_diff_vs_cell_centred": worst,
            "grid_zyx": a.tolist(), "box": "[0,3]x[0,1]x[0,2]"}


def check_sky_and_camera(mi, grid):
    """Empty scene lit by the hemisphere sky: 1 above the horizon row, 0 below; then a purely absorbing
    cloud under a uniform sky of radiance 1 must show exp(-tau) with tau from our own numpy ray march
    (pins down camera orientation, field of view, pixel convention and grid placement together)."""
    spp = 64
    empty = {"type": "scene", "integrator": {"type": "volpath"}, "sensor": sensor(mi, spp, 1), "sky": sky_emitter(mi)}
    img = render(mi, empty)
    # With the camera level at the cloud's mid height, the horizon is the horizontal centre line.
    # The two rows touching the horizon see the bitmap's bilinear blur (+-1 texel = +-0.044 deg of a
    # 0.255 deg pixel); it is antisymmetric, so their sum stays 2 x 0.5.
    h = HEIGHT // 2
    top, bottom = img[: h - 1], img[h + 1:]
    rows = img[h - 1: h + 1].mean(axis=1)
    sky = {"rows_above_horizon_min": float(top.min()), "rows_above_horizon_max": float(top.max()),
           "rows_below_horizon_max": float(bottom.max()),
           "horizon_rows_mean_59_60": rows.tolist(), "horizon_rows_sum": float(rows.sum()), "spp": spp}
    if (abs(sky["rows_above_horizon_min"] - 1) > 1e-6 or abs(sky["rows_above_horizon_max"] - 1) > 1e-6
            or sky["rows_below_horizon_max"] > 1e-6 or abs(rows.sum() - 1.0) > 0.01):
        sys.exit(f"sky orientation check failed: {sky}")
    # Zenith and nadir, and the horizon profile, from a camera looking up / a narrow camera on the horizon.
    em = mi.load_dict(sky_emitter(mi))
    si = mi.SurfaceInteraction3f()
    prof = {}
    for elev_deg in [90.0, 10.0, 0.2, 0.05, 0.0, -0.05, -0.2, -10.0, -90.0]:
        e = math.radians(elev_deg)
        d = np.array([0.3 * math.cos(e), 0.954 * math.cos(e), math.sin(e)])
        si.wi = mi.Vector3f(*[float(x) for x in -d / np.linalg.norm(d)])
        prof[f"{elev_deg:g}"] = float(np.array(em.eval(si)).ravel()[0])
    sky["radiance_by_elevation_deg"] = prof
    want = {"90": 1.0, "10": 1.0, "0.2": 1.0, "-0.2": 0.0, "-10": 0.0, "-90": 0.0}
    if any(abs(prof[k] - v) > 1e-6 for k, v in want.items()):
        sys.exit(f"sky profile wrong: {prof}")

    return sky, check_camera(mi, grid, "side")


def check_camera(mi, grid, camera):
    """Absorbing cloud under a uniform sky: pixel value = pixel-average of exp(-tau) from our numpy ray
    march (pins down camera orientation, field of view, pixel convention and grid placement together)."""
    # Absorbing cloud under a uniform sky: pixel value = pixel-average of exp(-tau).
    absorbing = {"type": "scene", "integrator": {"type": "volpath", "max_depth": -1},
                 "sensor": sensor(mi, 256, 2, camera), "light": {"type": "constant", "radiance": 1.0},
                 "cloud": cloud_scene(mi, grid, "sun", 1, 1)["cloud"]}
    absorbing["cloud"]["interior"]["albedo"] = 0.0
    img = render(mi, absorbing)
    origin, dirs = camera_rays(sub=4, camera=camera)
    trans = np.exp(-optical_depth(grid, origin, dirs, EXTINCTION_PER_DENSITY_M)).mean(axis=-1)
    diff = img - trans
    bdiff = blocks(img) - blocks(trans)
    cam = {"what": "Mitsuba (256 spp, box filter) vs numpy pixel average (4x4 stratified) of exp(-tau), "
                   "absorbing cloud (albedo 0), uniform light 1; differences are Monte Carlo noise",
           "pixel_max_abs_diff": float(np.abs(diff).max()), "pixel_mean_abs_diff": float(np.abs(diff).mean()),
           "block8_max_abs_diff": float(np.abs(bdiff).max()),
           "pixel_mean_abs_diff_if_mirrored_left_right": float(np.abs(img[:, ::-1] - trans).mean()),
           "pixel_mean_abs_diff_if_flipped_up_down": float(np.abs(img[::-1] - trans).mean()),
           "min_transmittance": float(trans.min()), "spp": 256}
    # Each of Mitsuba's samples is 0 or 1 (absorbed or not) with probability = the pixel's transmittance:
    # the expected mean |difference| from noise alone is sqrt(2/pi) sqrt(T (1 - T) / spp).
    cam["pixel_mean_abs_diff_expected_from_noise"] = float(np.mean(np.sqrt(2.0 / np.pi * trans * (1.0 - trans) / 256)))
    if cam["block8_max_abs_diff"] > 0.01 or cam["pixel_mean_abs_diff"] > 1.2 * cam["pixel_mean_abs_diff_expected_from_noise"] + 5e-4:
        sys.exit(f"camera/grid placement check failed ({camera}): {cam}")
    return cam


# ---- statistics -------------------------------------------------------------------------------------------
def blocks(img):
    return img.reshape(HEIGHT // BLOCK, BLOCK, WIDTH // BLOCK, BLOCK).mean(axis=(1, 3))


def cloud_blocks(mask):
    """Blocks all of whose 64 pixels are cloud pixels."""
    return blocks(mask.astype(float)) == 1.0


def compare(test, ref, mask):
    """NRMSE over cloud blocks (8x8 means), per-pixel NRMSE over cloud pixels, cloud-mean bias; all
    normalised by the reference's mean over cloud pixels."""
    m = ref[mask].mean()
    cb = cloud_blocks(mask)
    return {
        "block_nrmse": float(np.sqrt(np.mean((blocks(test)[cb] - blocks(ref)[cb]) ** 2)) / m),
        "pixel_nrmse": float(np.sqrt(np.mean((test[mask] - ref[mask]) ** 2)) / m),
        "cloud_mean_bias": float(test[mask].mean() / m - 1.0),
    }


def load_json():
    if os.path.exists(JSON_OUT):
        with open(JSON_OUT) as f:
            return json.load(f)
    return {"header": {}, "cases": {}}


def save_json(data):
    with open(JSON_OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")


def mask_and_tau(grid, camera="side"):
    origin, dirs = camera_rays(sub=1, camera=camera)
    tau = optical_depth(grid, origin, dirs, EXTINCTION_PER_DENSITY_M)[..., 0]
    return tau, tau >= MASK_TAU


# ---- commands --------------------------------------------------------------------------------------------------
def cmd_camera(camera):
    """Mask, optical depth and the absorbing-cloud camera check for a further camera."""
    mi = mitsuba()
    grid = load_grid()
    cam = check_camera(mi, grid, camera)
    tau, mask = mask_and_tau(grid, camera)
    np.save(os.path.join(DATA, tau_file(camera)), tau.astype(np.float32))
    np.save(os.path.join(DATA, mask_file(camera)), mask.astype(np.uint8))
    data = load_json()
    data["header"].setdefault("checks", {})[f"camera_and_grid_{camera}"] = cam
    data["header"][f"mask_{camera}"] = {"cloud_pixels": int(mask.sum()),
                                        "cloud_blocks_8x8": int(cloud_blocks(mask).sum()),
                                        "tau_max": float(tau.max()),
                                        "tau_median_over_cloud_pixels": float(np.median(tau[mask]))}
    save_json(data)
    print(json.dumps(cam), data["header"][f"mask_{camera}"])


def cmd_checks():
    mi = mitsuba()
    grid = load_grid()
    grid_check = check_gridvolume(mi)
    sky, cam = check_sky_and_camera(mi, grid)
    tau, mask = mask_and_tau(grid)
    np.save(os.path.join(DATA, "cloud_mitsuba_tau.npy"), tau.astype(np.float32))
    np.save(os.path.join(DATA, "cloud_mitsuba_mask.npy"), mask.astype(np.uint8))
    data = load_json()
    data["header"]["checks"] = {"gridvolume_convention": grid_check, "sky_hemisphere": sky, "camera_and_grid": cam}
    data["header"]["mask"] = {"cloud_pixels": int(mask.sum()), "cloud_blocks_8x8": int(cloud_blocks(mask).sum()),
                              "tau_max": float(tau.max()), "tau_median_over_cloud_pixels": float(np.median(tau[mask]))}
    save_json(data)
    print(json.dumps(data["header"]["checks"]["camera_and_grid"]), json.dumps(sky), data["header"]["mask"])


PASSES_DIR = os.environ.get("CLOUD_MITSUBA_PASSES", os.path.join(HERE, "..", "target", "cloud_mitsuba_passes"))


def pass_dir(name):
    d = os.path.join(PASSES_DIR, name)
    os.makedirs(d, exist_ok=True)
    return d


def render_passes(mi, grid, case, name, spp_per_pass, passes, max_depth=-1):
    """Renders `passes` independent images (distinct seeds) and stores each one under PASSES_DIR/name, so
    later runs add passes instead of starting again. Returns the seconds per pass."""
    d = pass_dir(name)
    done = [f for f in os.listdir(d) if f.startswith("seed")]
    # Seeds 1000 * (1 + case index) + 0..99 were used by the legacy passes; new passes start at + 100.
    seed0 = 1000 * (1 + list(CASES).index(case)) + 100_000 * (max_depth != -1) + 100 + len(done)
    times = []
    render(mi, cloud_scene(mi, grid, case, 1, 999_999, max_depth))  # JIT warm-up, not timed
    for k in range(passes):
        seed = seed0 + k
        t = time.perf_counter()
        img = render(mi, cloud_scene(mi, grid, case, spp_per_pass, seed, max_depth))
        times.append(time.perf_counter() - t)
        np.save(os.path.join(d, f"seed{seed}_spp{spp_per_pass}_s{times[-1]:.1f}.npy"), img.astype(np.float32))
        print(f"  {name} pass {k + 1}/{passes}: {times[-1]:.1f} s", flush=True)
    return times


def load_passes(name):
    """All stored passes of `name`: unit passes (one render each, same spp) plus an optional legacy
    bundle (`legacy_n<N>.npy`, the mean of N earlier passes of the same spp whose individual images
    were not kept). Returns (unit images [n, H, W], legacy mean or None, legacy N, spp per pass, times)."""
    d = pass_dir(name)
    units, spps, times, legacy, n_legacy = [], set(), [], None, 0
    for f in sorted(os.listdir(d)):
        if f.startswith("seed"):
            units.append(np.load(os.path.join(d, f)).astype(np.float64))
            parts = f[:-4].split("_")
            spps.add(int(parts[1][3:]))
            times.append(float(parts[2][1:]))
        elif f.startswith("legacy_n") and not f.endswith("_stderr.npy"):
            legacy = np.load(os.path.join(d, f)).astype(np.float64)
            n_legacy = int(f[len("legacy_n"):-4])
    if len(spps) > 1:
        sys.exit(f"passes of {name} have different spp: {spps}")
    return np.array(units), legacy, n_legacy, spps.pop(), times


def cmd_render(case, spp_per_pass, passes, max_depth=-1, suffix=""):
    mi = mitsuba()
    grid = load_grid()
    name = case + suffix
    if passes > 0:
        render_passes(mi, grid, case, name, spp_per_pass, passes, max_depth)
    cmd_collect(case, name, max_depth)


def cmd_collect(case, name, max_depth):
    """Mean and noise of every stored pass of `name` -> tests/data (image, stderr image, JSON entry).
    The noise per pass is estimated from the unit passes (independent seeds) and divided by the total
    number of passes, legacy bundle included (all passes are identically distributed)."""
    mask = load_mask(case)
    units, legacy, n_legacy, spp, times = load_passes(name)
    n_units = len(units)
    if n_units < 2:
        sys.exit(f"{name}: need at least 2 unit passes for a noise estimate")
    n_total = n_units + n_legacy
    mean = units.sum(axis=0)
    if legacy is not None:
        mean += n_legacy * legacy
    mean /= n_total
    var_pass = units.var(axis=0, ddof=1)
    stderr = np.sqrt(var_pass / n_total)
    bvar = np.array([blocks(im) for im in units]).var(axis=0, ddof=1)
    bstderr = np.sqrt(bvar / n_total)
    cb = cloud_blocks(mask)
    m = mean[mask].mean()
    cm = np.array([im[mask].mean() for im in units])
    np.save(os.path.join(DATA, f"cloud_mitsuba_{name}.npy"), mean.astype(np.float32))
    np.save(os.path.join(DATA, f"cloud_mitsuba_{name}_stderr.npy"), stderr.astype(np.float32))
    entry = {
        "image": f"cloud_mitsuba_{name}.npy", "stderr_image": f"cloud_mitsuba_{name}_stderr.npy",
        "scene": f"validation-cloud-{case}.json", **CASES[case],
        "max_depth": max_depth, "spp_total": spp * n_total, "passes": n_total, "spp_per_pass": spp,
        "passes_with_image_kept": n_units,
        "seconds_per_pass_timed": times, "seconds_per_spp_median": float(np.median(times) / spp) if times else None,
        "cloud_mean": float(m),
        "noise": {
            "pixel_rms_rel_stderr": float(np.sqrt(np.mean(stderr[mask] ** 2)) / m),
            "pixel_median_rel_stderr": float(np.median(stderr[mask] / np.maximum(mean[mask], 1e-30))),
            "block_rms_rel_stderr": float(np.sqrt(np.mean(bstderr[cb] ** 2)) / m),
            "block_max_rel_stderr": float(bstderr[cb].max() / m),
            "cloud_mean_rel_stderr": float(cm.std(ddof=1) / math.sqrt(n_total) / m),
        },
        "background_mean_outside_mask": float(mean[~mask].mean()),
    }
    if n_legacy:
        entry["legacy_passes"] = (f"{n_legacy} earlier passes of {spp} spp (seeds 1000..1007, same settings) enter "
                                  "the mean only; their images were not kept")
    data = load_json()
    data["cases"][name] = entry
    save_json(data)
    print(name, json.dumps(entry["noise"]), f"cloud mean {m:.5f}, spp {spp * n_total}", flush=True)


def cmd_sum(a, b, name):
    """Image of two lights together from the separate renders (radiance is linear in the sources), with
    the stderr images added in quadrature. Block noise from the pixel stderr, pixels taken as independent
    (they are: every pass samples each pixel independently)."""
    mask = np.load(os.path.join(DATA, "cloud_mitsuba_mask.npy")).astype(bool)
    ia, ib = (np.load(os.path.join(DATA, f"cloud_mitsuba_{x}.npy")).astype(np.float64) for x in (a, b))
    sa, sb = (np.load(os.path.join(DATA, f"cloud_mitsuba_{x}_stderr.npy")).astype(np.float64) for x in (a, b))
    img, se = ia + ib, np.hypot(sa, sb)
    np.save(os.path.join(DATA, f"cloud_mitsuba_{name}.npy"), img.astype(np.float32))
    np.save(os.path.join(DATA, f"cloud_mitsuba_{name}_stderr.npy"), se.astype(np.float32))
    m = img[mask].mean()
    cb = cloud_blocks(mask)
    bse = np.sqrt(blocks(se**2) / BLOCK**2)
    data = load_json()
    ca, cbb = data["cases"][a], data["cases"][b]
    data["cases"][name] = {
        "image": f"cloud_mitsuba_{name}.npy", "stderr_image": f"cloud_mitsuba_{name}_stderr.npy",
        "scene": f"validation-cloud-{name if name in CASES else 'sunsky'}.json", "sum_of": [a, b], "spp_total": [ca["spp_total"], cbb["spp_total"]],
        "cloud_mean": float(m),
        "noise": {
            "pixel_rms_rel_stderr": float(np.sqrt(np.mean(se[mask] ** 2)) / m),
            "block_rms_rel_stderr": float(np.sqrt(np.mean(bse[cb] ** 2)) / m),
            "block_max_rel_stderr": float(bse[cb].max() / m),
            "cloud_mean_rel_stderr": float(math.hypot(ca["noise"]["cloud_mean_rel_stderr"] * ca["cloud_mean"],
                                                      cbb["noise"]["cloud_mean_rel_stderr"] * cbb["cloud_mean"]) / m),
        },
    }
    if "sunsky" in data["cases"] and name != "sunsky":
        direct = np.load(os.path.join(DATA, "cloud_mitsuba_sunsky.npy")).astype(np.float64)
        data["cases"][name]["vs_direct_sunsky_render"] = compare(direct, img, mask)
    save_json(data)
    print(name, data["cases"][name])


def cmd_convergence(case="sun", spps=(4, 16, 64, 256), repeats=2):
    """Mitsuba's time to reach a given error: independent renders at increasing spp
    against the converged image of the same case (whose own noise is in cases.<case>.noise: the
    measured NRMSE floors at that level)."""
    mi = mitsuba()
    grid = load_grid()
    mask = np.load(os.path.join(DATA, "cloud_mitsuba_mask.npy")).astype(bool)
    ref = np.load(os.path.join(DATA, f"cloud_mitsuba_{case}.npy")).astype(np.float64)
    render(mi, cloud_scene(mi, grid, case, 1, 999_998))
    rows = []
    for spp in spps:
        for r in range(repeats):
            t = time.perf_counter()
            img = render(mi, cloud_scene(mi, grid, case, spp, 500_000 + 1000 * spp + r))
            dt = time.perf_counter() - t
            rows.append({"spp": spp, "seconds": dt, **compare(img, ref, mask)})
            print(rows[-1], flush=True)
    data = load_json()
    data[f"convergence_{case}"] = {
        "reference": f"cloud_mitsuba_{case}.npy (its own noise: cases.{case}.noise)",
        "variant": mi.variant(), "threads": "2 (drjit default on this 2-core machine, shared with 4 other "
                                           "sessions: load average 12-17 during the runs)",
        "pixels": WIDTH * HEIGHT, "rows": rows,
    }
    save_json(data)


def single_scatter_numpy(grid, ext, g, sub=2, steps=600):
    """Single-scattered sun radiance per pixel (pixel average over sub x sub points), albedo 1, unit
    normal irradiance: L = int sigma_t(x) p_HG(sun_dir . ray_dir) T_sun(x) T_cam(x) dt. T_sun comes from
    the optical depth towards the sun, ray-marched at every voxel centre and interpolated trilinearly
    (smooth, so interpolating tau rather than T is accurate)."""
    from scipy.ndimage import map_coordinates

    lo, hi = ORIGIN_M, box_max_m(grid)
    sd = sun_direction()
    nz, ny, nx = grid.shape
    c = (np.arange(64) + 0.5) * VOXEL_M
    zz, yy, xx = np.meshgrid(lo[2] + c[:nz], lo[1] + c[:ny], lo[0] + c[:nx], indexing="ij")
    pts = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    # distance to the box exit along the sun direction
    with np.errstate(divide="ignore"):
        tmax = np.min(np.where(sd > 0, (hi - pts) / sd, np.where(sd < 0, (lo - pts) / sd, np.inf)), axis=1)

    def dens(p):
        cc = (p - lo) / VOXEL_M - 0.5
        return map_coordinates(grid, np.stack([cc[..., 2].ravel(), cc[..., 1].ravel(), cc[..., 0].ravel()]),
                               order=1, mode="nearest").reshape(p.shape[:-1])

    tau_sun = np.zeros(len(pts))
    n_sun = 400
    for chunk in np.array_split(np.arange(len(pts)), 64):
        dt = tmax[chunk] / n_sun
        t = (np.arange(n_sun)[None, :] + 0.5) * dt[:, None]
        tau_sun[chunk] = ext * dens(pts[chunk, None, :] + t[..., None] * sd).sum(axis=1) * dt
    tau_sun = tau_sun.reshape(grid.shape).astype(np.float64)

    origin, dirs = camera_rays(sub=sub)
    flat = dirs.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - origin) / flat
        t1 = (hi - origin) / flat
    tn = np.nanmax(np.minimum(t0, t1), axis=1).clip(min=0.0)
    tf = np.nanmin(np.maximum(t0, t1), axis=1)
    out = np.zeros(len(flat))
    idx = np.nonzero(tf > tn)[0]
    for chunk in np.array_split(idx, max(1, len(idx) // 1000)):
        dt = (tf[chunk] - tn[chunk]) / steps
        t = tn[chunk, None] + (np.arange(steps)[None, :] + 0.5) * dt[:, None]
        p = origin + t[..., None] * flat[chunk, None, :]
        cc = (p - lo) / VOXEL_M - 0.5
        coords = np.stack([cc[..., 2].ravel(), cc[..., 1].ravel(), cc[..., 0].ravel()])
        sig = ext * map_coordinates(grid, coords, order=1, mode="nearest").reshape(p.shape[:-1])
        ts = map_coordinates(tau_sun, coords, order=1, mode="nearest").reshape(p.shape[:-1])
        tcam = np.cumsum(sig, axis=1) * dt[:, None] - 0.5 * sig * dt[:, None]  # optical depth to the midpoint
        phase = hg_phase(g, flat[chunk] @ sd)
        out[chunk] = phase * np.sum(sig * np.exp(-ts - tcam), axis=1) * dt
    return out.reshape(dirs.shape[:-1]).mean(axis=-1)


def hg_phase(g, cos_theta):
    """Henyey-Greenstein phase function (1/sr), cos_theta between propagation directions."""
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


def cmd_single_scatter_check():
    """Mitsuba's max_depth = 2 image (single scattering) of the thin case against numpy."""
    grid = load_grid()
    mask = np.load(os.path.join(DATA, "cloud_mitsuba_mask.npy")).astype(bool)
    c = CASES["sun_thin"]
    ref = single_scatter_numpy(grid, c["ext"], c["g"])
    np.save(os.path.join(DATA, "cloud_mitsuba_sun_thin_single_numpy.npy"), ref.astype(np.float32))
    mi_img = np.load(os.path.join(DATA, "cloud_mitsuba_sun_thin_depth2.npy")).astype(np.float64)
    mi_err = np.load(os.path.join(DATA, "cloud_mitsuba_sun_thin_depth2_stderr.npy")).astype(np.float64)
    res = compare(mi_img, ref, mask)
    res["mitsuba_noise_pixel_rms_rel"] = float(np.sqrt(np.mean(mi_err[mask] ** 2)) / ref[mask].mean())
    res["what"] = ("Mitsuba volpath max_depth 2 (single scattering), case sun_thin, vs an independent numpy "
                   "single-scattering ray march (tools/cloud_mitsuba.py single_scatter_numpy, 2x2 points per "
                   "pixel, 600 steps); confirms sun direction, HG sign convention, irradiance units and camera")
    # The same comparison with the sun mirrored (azimuth -> 180 - azimuth) or g -> -g would fail:
    res["cloud_mean_numpy"] = float(ref[mask].mean())
    data = load_json()
    data["header"].setdefault("checks", {})["single_scattering_thin_vs_numpy"] = res
    save_json(data)
    print(json.dumps(res))
    if abs(res["cloud_mean_bias"]) > 0.01 or res["block_nrmse"] > 0.02:
        sys.exit("single-scattering check failed")


def skybake_scene(case):
    c = CASES[case]
    desc = {
        "sun": "sun only", "sky": "sky only (the sun's irradiance is 0)", "sunsky": "sun and sky",
        "sun_g05": "sun only, HG g = 0.5", "sun_albedo09": "sun only, single-scattering albedo 0.9",
        "sun_thin": "sun only, optically thin (extinction / 20)",
        "sun_back35": "sun only, behind the cloud 35 deg above the view axis",
        "sun_back20": "sun only, behind the cloud 22 deg from the view axis (elevation 20, azimuth 10)",
        "sun_back35_thin": "sun only, behind the cloud 35 deg above the view axis, optically thin (extinction / 20)",
        "sunsky_back35": "sun and sky, the sun behind the cloud 35 deg above the view axis",
        "below_sun": "sun only, camera below the cloud looking up", "below_sky": "sky only, camera below the cloud looking up",
    }[case]
    sun_el, sun_az = case_sun(case)
    return {
        "name": f"validation-cloud-{case}",
        "description": f"Mitsuba 3 validation scene ({desc}); reference image tests/data/cloud_mitsuba_{case}.npy "
                       "made by tools/cloud_mitsuba.py. Vacuum, no ground, grey optics.",
        "cloud": {"voxel_size_m": VOXEL_M,
                  "source": {"type": "grid", "path": GRID_FILE, "origin_m": ORIGIN_M.tolist()}},
        "optics": {"extinction_per_density_m": c["ext"], "single_scattering_albedo": c["albedo"],
                   "phase": {"henyey_greenstein": {"g": c["g"]}}},
        "camera": CAMERAS[case_camera(case)],
        "sun": {"collimated": {"elevation_deg": sun_el, "azimuth_deg": sun_az,
                               "normal_irradiance_w_m2_nm": 1.0 if c["sun"] else 0.0}},
        "atmosphere": None,
        "sky": {"constant_radiance_w_m2_sr_nm": 1.0} if c["sky"] else None,
        "ground": None,
        "wavelengths_nm": [550],
        "quality": "standard",
    }


def cmd_scenes():
    for case in CASES:
        with open(os.path.join(DATA, f"validation-cloud-{case}.json"), "w") as f:
            json.dump(skybake_scene(case), f, indent=2)
            f.write("\n")


def header():
    import mitsuba as mi
    import scipy

    return {
        "source": "Mitsuba 3 (Jakob et al. 2022) volpath, generated by tools/cloud_mitsuba.py",
        "package_versions": {"mitsuba": version("mitsuba"), "drjit": version("drjit"), "numpy": np.__version__,
                             "scipy": scipy.__version__, "python": sys.version.split()[0]},
        "variant": mi.variant(),
        "geometry": {
            "grid": GRID_FILE, "grid_shape_zyx": [64, 64, 64], "voxel_size_m": VOXEL_M,
            "origin_m": ORIGIN_M.tolist(), "box_max_m": (ORIGIN_M + 64 * VOXEL_M).tolist(),
            "convention": "values at voxel centres, trilinear, clamped to the outermost centre out to the box "
                          "face, zero outside the box (Mitsuba: gridvolume with to_world mapping [0,1]^3 onto the "
                          "box, inside a cube shape with a null BSDF that bounds the medium)",
        },
        "camera": CAMERA,
        "cameras": CAMERAS,
        "cases_geometry": "a case's `camera` (default side) names one of `cameras`, its `sun_el`/`sun_az` (default "
                          "`sun`) the sun's elevation and azimuth in degrees; cases of the camera `below` use "
                          "cloud_mitsuba_mask_below.npy",
        "camera_notes": "Mitsuba perspective, fov_axis x (full angle across the image width), look_at(position, "
                        "look_at, up); box reconstruction filter: each pixel is the average over its square "
                        "footprint (uniform jitter), pixel (0, 0) top-left, image row 0 at the top.",
        "sun": {"elevation_deg": SUN_ELEVATION_DEG, "azimuth_deg": SUN_AZIMUTH_DEG,
                "direction_towards_sun": sun_direction().tolist(), "normal_irradiance": 1.0,
                "mitsuba": "directional emitter, direction = -direction_towards_sun, irradiance 1"},
        "sky": {"radiance": 1.0, "where": "upper hemisphere (z > 0) only, 0 below",
                "mitsuba": f"envmap, {2 * ENVMAP_HEIGHT}x{ENVMAP_HEIGHT} lat-long bitmap, rows of the upper half 1, "
                           "lower half 0, to_world = rotate +90 deg about x (local +y -> world +z); bilinear "
                           f"lookup blurs the horizon over +-{90.0 / ENVMAP_HEIGHT:.3f} deg, symmetrically"},
        "medium": "heterogeneous: sigma_t = extinction_per_density_m * density (1/m), albedo constant, "
                  "Henyey-Greenstein phase (g > 0 forward), grey (one channel)",
        "integrator": "volpath, max_depth -1 (all orders), rr_depth 10 (Russian roulette is unbiased)",
        "units": "images: radiance per unit sun normal irradiance (sun cases) or per unit sky radiance (sky "
                 "case); sunsky = both at 1 together. Multiply by the scene's values.",
        "notes": [
            "Noise: with g = 0.85 and a collimated sun the next-event estimate is dominated by rare paths pointing "
            "nearly at the sun (forward peak); g = 0.5 is ~4x less noisy at equal spp. rr_depth 10 vs no Russian "
            "roulette: same variance within the estimate.",
            "Speed (2 cores shared with four other sessions, load average 12-17): 16 spp of case sun took 8.8 s "
            "with llvm_ad_mono, 11.3 s with llvm_ad_rgb and 16.3 s with scalar_rgb in one contended side-by-side "
            "run; per-case seconds per spp are in cases.<case>.seconds_per_spp_median.",
            "sunsky_sum = sun + sky (linearity); the directly rendered sunsky agrees with it within noise "
            "(cases.sunsky_sum.vs_direct_sunsky_render).",
        ],
        "statistics": {
            "mask": "cloud_mitsuba_mask.npy: pixel-centre optical depth (extinction 0.02/m, i.e. the thick "
                    f"cases) >= {MASK_TAU}; the same mask is used for every case, including sun_thin",
            "blocks": "8x8 pixel blocks aligned at pixel (0, 0) (20 x 15 blocks); a cloud block has all 64 "
                      "pixels in the mask; block value = mean of its 64 pixels",
            "block_nrmse": "sqrt(mean over cloud blocks of (test - ref)^2) / (mean of ref over cloud pixels)",
            "pixel_nrmse": "sqrt(mean over cloud pixels of (test - ref)^2) / (mean of ref over cloud pixels)",
            "cloud_mean_bias": "mean(test over cloud pixels) / mean(ref over cloud pixels) - 1",
            "noise": "from `passes` independent renders (different seeds): stderr = std(passes, ddof=1) / "
                     "sqrt(passes), per pixel / per block / of the cloud mean, relative to the cloud mean",
        },
    }


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    cmd = sys.argv[1]
    if cmd == "checks":
        cmd_checks()
    elif cmd == "render":
        case = sys.argv[2]
        spp_per_pass = int(sys.argv[3]) if len(sys.argv) > 3 else 256
        passes = int(sys.argv[4]) if len(sys.argv) > 4 else 8  # 0: only collect the stored passes
        max_depth = int(sys.argv[5]) if len(sys.argv) > 5 else -1
        suffix = "" if max_depth == -1 else f"_depth{max_depth}"
        cmd_render(case, spp_per_pass, passes, max_depth, suffix)
    elif cmd == "convergence":
        cmd_convergence(*sys.argv[2:3])
    elif cmd == "sum":
        cmd_sum(sys.argv[2], sys.argv[3], sys.argv[4])
    elif cmd == "camera":
        cmd_camera(sys.argv[2])
    elif cmd == "scenes":
        cmd_scenes()
    elif cmd == "single-scatter-check":
        cmd_single_scatter_check()
    else:
        sys.exit(__doc__)
    if cmd not in ("scenes", "single-scatter-check", "sum"):
        mitsuba()
        data = load_json()
        data["header"].update(header())
        save_json(data)


if __name__ == "__main__":
    main()
