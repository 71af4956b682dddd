#!/usr/bin/env python3
"""Mitsuba 3's time to reach the fast method's error on skybake's bench frame.

The scene is skybake's bench frame (crates/harness/src/frame_bench.rs: the 128^3 cumulus of 12 m voxels, extinction
0.04 /m per unit density, albedo 1, Henyey-Greenstein g 0.85, pinhole camera 50 deg horizontal at
(0, -3200, 1300) m looking at (0, 0, 1500) m) under the light skybake computes at the cloud for the
bench scene (earth atmosphere, sun 35 deg elevation / 140 deg azimuth, ground albedo 0.3, 440/550/680
nm), as exported by `crates/harness/examples/mitsuba_bench_export.rs`: the sun's transmitted normal irradiance per
wavelength (Mitsuba `directional`) and `Lighting::env`, sky radiance above the horizontal and ground
light below, as a lat-long map (Mitsuba `envmap`). Both renderers see the cloud in vacuum, with no
aerial perspective and no ground plane, so each image is I_a + T_c * env (the cloud's radiance plus
the environment seen through it). The three wavelengths are the three channels of `llvm_ad_rgb` (the
cloud is grey, so one path serves all three, as in skybake's path tracer).

Usage (from the repository root; DRJIT_LIBLLVM_PATH must point to a libLLVM >= 15, see
tools/cloud_mitsuba.py):

  cargo run --release --locked -p skybake-harness --features probes --example mitsuba_bench_export -- DIR 160 120 1024   # ~100 s CPU
  python3 tools/cloud_mitsuba_bench.py checks DIR      # envmap orientation and channels, sun irradiance
  python3 tools/cloud_mitsuba_bench.py series DIR [SPP ...]   # Mitsuba at increasing spp
  python3 tools/cloud_mitsuba_bench.py summary DIR     # writes tests/data/cloud_mitsuba_bench.json
  python3 tools/cloud_mitsuba_bench.py pair DIR SPP    # two renders: noise without a reference
                                                       # (for DIR exported at 640 480 0 and 160 120 0)

Each `series` render is stored in DIR (mitsuba_spp<N>_seed<S>.npy with its wall and CPU time) so the
summary can pool them. Errors follow crates/harness/src/frame_bench.rs `image_errors`: pixel value = mean over the
three wavelengths; cloud pixels = transmittance < 0.99 (skybake's fast march, pixel centres); cloud
blocks = aligned 8x8 blocks of cloud pixels only; block NRMSE, pixel NRMSE and cloud-mean bias
relative to the reference's mean over cloud pixels.
"""

import glob
import json
import math
import os
import resource
import sys
import time
from importlib.metadata import version

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.normpath(os.path.join(HERE, "..", "tests", "data"))
JSON_OUT = os.path.join(DATA, "cloud_mitsuba_bench.json")
BLOCK = 8
THREADS = int(os.environ.get("MI_THREADS", "2"))
# Mitsuba's Russian roulette starts at this depth (volpath's default is 5; tools/cloud_mitsuba.py
# used 10). With albedo 1 it keeps a path with probability 0.95 per event, raising its weight.
RR_DEPTH = int(os.environ.get("MI_RR_DEPTH", "10"))


def load_export(d):
    with open(os.path.join(d, "meta.json")) as f:
        meta = json.load(f)
    return meta


def mitsuba():
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(os.environ.get("MI_VARIANT", "llvm_ad_rgb"))
    dr.set_thread_count(THREADS)
    return mi


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


# ---- the scene -------------------------------------------------------------------------------------
def env_emitter(mi, env):
    # Mitsuba's envmap: local direction v -> u = atan2(v.x, -v.z) / 2pi, v = acos(v.y) / pi, texel
    # centres at (j + 1/2, i + 1/2). Rotating +90 deg about x maps local (x, y, z) to world (x, -z, y),
    # so u = atan2(w.x, w.y) / 2pi (azimuth from +y towards +x) and v = zenith angle / pi: the export's
    # layout. Verified in `checks`.
    return {"type": "envmap", "bitmap": mi.Bitmap(env.astype(np.float32)),
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}


def sensor(mi, meta, spp, seed):
    c = meta["camera"]
    pos = np.array(c["position_m"])
    return {
        "type": "perspective", "fov": c["fov_deg"], "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=pos.tolist(), target=(pos + c["forward"]).tolist(),
                                                   up=[0.0, 0.0, 1.0]),
        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        "film": {"type": "hdrfilm", "width": c["width"], "height": c["height"], "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
    }


def box(meta):
    g = meta["grid"]
    lo = np.array(g["origin_m"])
    return lo, lo + g["voxel_size_m"] * np.array(g["dims_xyz"])


def cloud_shape(mi, meta, grid):
    lo, hi = box(meta)
    o = meta["optics"]
    vol = {"type": "gridvolume", "grid": mi.VolumeGrid(grid), "filter_type": "trilinear",
           "to_world": mi.ScalarTransform4f().translate(lo.tolist()).scale((hi - lo).tolist())}
    medium = {"type": "heterogeneous", "sigma_t": vol, "scale": o["extinction_per_density_m"][0],
              "albedo": o["single_scattering_albedo"][0], "phase": {"type": "hg", "g": o["henyey_greenstein_g"]}}
    return {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
            "to_world": mi.ScalarTransform4f().translate(((lo + hi) / 2).tolist()).scale(((hi - lo) / 2).tolist())}


def sun_emitter(meta):
    return {"type": "directional", "direction": (-np.array(meta["sun_direction"])).tolist(),
            "irradiance": {"type": "rgb", "value": meta["sun_irradiance_w_m2_nm"]}}


def bench_scene(mi, meta, grid, env, spp, seed):
    o = meta["optics"]
    if len(set(o["extinction_per_density_m"])) != 1 or len(set(o["single_scattering_albedo"])) != 1:
        sys.exit("the export's optics vary with wavelength; this script renders a grey cloud only")
    return {"type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": RR_DEPTH},
            "sensor": sensor(mi, meta, spp, seed), "cloud": cloud_shape(mi, meta, grid),
            "sun": sun_emitter(meta), "env": env_emitter(mi, env)}


def render(mi, scene_dict):
    scene = mi.load_dict(scene_dict)
    return np.array(mi.render(scene), dtype=np.float64)[..., :3]


# ---- statistics (crates/harness/src/frame_bench.rs image_errors) ----------------------------------------------------
def blocks(img):
    h, w = img.shape[:2]
    hb, wb = h // BLOCK, w // BLOCK
    return img[: hb * BLOCK, : wb * BLOCK].reshape(hb, BLOCK, wb, BLOCK).mean(axis=(1, 3))


def errors(test, ref, mask):
    """test, ref: (h, w) pixel values (mean over wavelengths)."""
    m = ref[mask].mean()
    cb = blocks(mask.astype(float)) == 1.0
    return {
        "block_nrmse": float(np.sqrt(np.mean((blocks(test)[cb] - blocks(ref)[cb]) ** 2)) / m),
        "pixel_nrmse": float(np.sqrt(np.mean((test[mask] - ref[mask]) ** 2)) / m),
        "cloud_mean_bias": float(test[mask].mean() / m - 1.0),
    }


def mask_of(d):
    return np.load(os.path.join(d, "transmittance.npy")) < 0.99


# ---- numpy look-ups for the checks -------------------------------------------------------------------
def camera_dirs(meta, sub):
    """Pixel ray directions as skybake's pinhole camera (crates/render/src/camera.rs) at sub x sub stratified
    points per pixel: (h, w, sub*sub, 3)."""
    c = meta["camera"]
    w, h = c["width"], c["height"]
    fwd, right, up = (np.array(c[k]) for k in ("forward", "right", "up"))
    half_w = math.tan(math.radians(c["fov_deg"]) / 2)
    half_h = half_w * h / w
    offs = (np.arange(sub) + 0.5) / sub
    ox, oy = np.meshgrid(offs, offs, indexing="xy")
    i = np.arange(w)[None, :, None] + ox.ravel()[None, None, :]
    j = np.arange(h)[:, None, None] + oy.ravel()[None, None, :]
    sx = (2 * i / w - 1) * half_w
    sy = (1 - 2 * j / h) * half_h
    d = fwd + sx[..., None] * right + sy[..., None] * up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def env_lookup(env, dirs, mirror=False):
    """Bilinear look-up in the lat-long map (texel centres at half-integers, azimuth wraps, rows clamp)."""
    rows, cols = env.shape[:2]
    theta = np.arccos(np.clip(dirs[..., 2], -1, 1))
    phi = np.arctan2(dirs[..., 0], dirs[..., 1]) % (2 * math.pi)
    if mirror:
        phi = (-phi) % (2 * math.pi)
    y = theta / math.pi * rows - 0.5
    x = phi / (2 * math.pi) * cols - 0.5
    y0 = np.floor(y).astype(int)
    x0 = np.floor(x).astype(int)
    fy, fx = (y - y0)[..., None], (x - x0)[..., None]
    r0, r1 = np.clip(y0, 0, rows - 1), np.clip(y0 + 1, 0, rows - 1)
    c0, c1 = x0 % cols, (x0 + 1) % cols
    return ((1 - fy) * ((1 - fx) * env[r0, c0] + fx * env[r0, c1]) + fy * ((1 - fx) * env[r1, c0] + fx * env[r1, c1]))


# ---- commands ----------------------------------------------------------------------------------------------
def load_json():
    if os.path.exists(JSON_OUT):
        with open(JSON_OUT) as f:
            return json.load(f)
    return {}


def save_json(data):
    with open(JSON_OUT, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")


def cmd_checks(d):
    """(1) The environment alone, seen by the camera: Mitsuba (64 spp) against a numpy look-up of the
    exported map along skybake's pixel rays (4x4 per pixel), per channel; the azimuth-mirrored map must
    differ (the map is symmetric about the sun's azimuth 140 deg only). (2) The sun's irradiance: a
    white Lambertian plane of albedo 1 facing the sun (normal = sun direction) seen by the camera must
    read E / pi per channel."""
    mi = mitsuba()
    meta = load_export(d)
    env = np.load(os.path.join(d, "env.npy")).astype(np.float64)
    scene = {"type": "scene", "integrator": {"type": "volpath"}, "sensor": sensor(mi, meta, 64, 1),
             "env": env_emitter(mi, env)}
    img = render(mi, scene)
    want = env_lookup(env, camera_dirs(meta, 4)).mean(axis=2)
    mirrored = env_lookup(env, camera_dirs(meta, 4), mirror=True).mean(axis=2)
    h = img.shape[0]
    # Rows touching the horizon see the map's sky/ground step blurred differently by the two
    # filters; compare the rest.
    horizon = np.abs(camera_dirs(meta, 1)[..., 0, 2]) < 2 * math.tan(math.radians(25)) / meta["camera"]["width"]
    keep = ~np.repeat(horizon.any(axis=1, keepdims=True), img.shape[1], axis=1)
    rel = np.abs(img - want)[keep] / want[keep]
    rel_m = np.abs(img - mirrored)[keep] / mirrored[keep]
    env_check = {"what": "environment seen by the camera: Mitsuba 64 spp vs numpy bilinear look-up (4x4 per pixel)",
                 "max_rel_diff_per_channel": rel.max(axis=0).tolist(),
                 "mean_rel_diff_per_channel": rel.mean(axis=0).tolist(),
                 "mean_rel_diff_if_azimuth_mirrored": rel_m.mean(axis=0).tolist(),
                 "rows_excluded_at_horizon": int(h - keep[:, 0].sum())}
    if rel.max() > 0.01:
        sys.exit(f"envmap check failed: {env_check}")
    # Sun: a plane facing the sun, filling the view, in front of the camera.
    s = np.array(meta["sun_direction"])
    c = meta["camera"]
    centre = np.array(c["position_m"]) + 100.0 * np.array(c["forward"])
    frame = mi.ScalarTransform4f().look_at(origin=centre.tolist(), target=(centre + s).tolist(), up=[0, 0, 1])
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 2}, "sensor": sensor(mi, meta, 4, 1),
             "plane": {"type": "rectangle", "to_world": frame @ mi.ScalarTransform4f().scale([1000, 1000, 1]),
                       "bsdf": {"type": "diffuse", "reflectance": 1.0}},
             "sun": sun_emitter(meta)}
    img = render(mi, scene)
    # The rectangle's normal is +z of its frame, which look_at points at the sun: it faces the sun but
    # is seen from behind by the camera for some orientations; use the two-sided check on the value.
    e = np.array(meta["sun_irradiance_w_m2_nm"])
    got = img.reshape(-1, 3).max(axis=0)
    sun_check = {"what": "white Lambertian plane facing the sun: max pixel vs E/pi per channel",
                 "got": got.tolist(), "want": (e / math.pi).tolist()}
    if np.abs(got / (e / math.pi) - 1).max() > 1e-3:
        sys.exit(f"sun irradiance check failed: {sun_check}")
    data = load_json()
    data["checks"] = {"environment": env_check, "sun_irradiance": sun_check}
    save_json(data)
    print(json.dumps(data["checks"], indent=1))


def cmd_series(d, spps):
    mi = mitsuba()
    meta = load_export(d)
    grid = np.load(os.path.join(d, "grid.npy"))
    env = np.load(os.path.join(d, "env.npy"))
    render(mi, bench_scene(mi, meta, grid, env, 1, 999_999))  # JIT and scene set-up warm-up, not timed
    for spp in spps:
        tag = "" if RR_DEPTH == 10 else f"_rr{RR_DEPTH}"
        done = glob.glob(os.path.join(d, f"mitsuba{tag}_spp{spp}_seed*.npy"))
        seed = 1000 * spp + len(done) + 100 * (RR_DEPTH != 10)
        t, c = time.perf_counter(), cpu_seconds()
        img = render(mi, bench_scene(mi, meta, grid, env, spp, seed))
        wall, cpu = time.perf_counter() - t, cpu_seconds() - c
        np.save(os.path.join(d, f"mitsuba{tag}_spp{spp}_seed{seed}.npy"), img.astype(np.float32))
        with open(os.path.join(d, f"mitsuba{tag}_spp{spp}_seed{seed}.json"), "w") as f:
            json.dump({"spp": spp, "seed": seed, "rr_depth": RR_DEPTH, "wall_s": wall, "cpu_s": cpu,
                       "threads": THREADS, "load_average": os.getloadavg()}, f)
        print(f"spp {spp} seed {seed}: wall {wall:.1f} s, cpu {cpu:.1f} s, load {os.getloadavg()[0]:.1f}", flush=True)


def cmd_summary(d):
    meta = load_export(d)
    mask = mask_of(d)
    ref_l = np.load(os.path.join(d, "reference.npy")).astype(np.float64)
    var_l = np.load(os.path.join(d, "reference_var.npy")).astype(np.float64)
    ref = ref_l.mean(axis=2)
    # The wavelengths share their paths: the standard error of their mean is about the mean of theirs.
    se = np.sqrt(var_l).mean(axis=2)
    cb = blocks(mask.astype(float)) == 1.0
    m = ref[mask].mean()
    ref_block_noise = float(np.sqrt(np.mean(blocks(se**2)[cb] / BLOCK**2)) / m)
    ref_pixel_noise = float(np.sqrt(np.mean(se[mask] ** 2)) / m)
    fast = np.load(os.path.join(d, "fast.npy")).astype(np.float64).mean(axis=2)
    rows = []
    images = {}
    for f in sorted(glob.glob(os.path.join(d, "mitsuba*_spp*_seed*.json"))):
        with open(f) as fh:
            r = json.load(fh)
        r.setdefault("rr_depth", 10)
        img = np.load(f[:-5] + ".npy").astype(np.float64)
        images.setdefault(r["spp"], []).append(img)
        e = errors(img.mean(axis=2), ref, mask)
        # Remove the reference's own noise in quadrature (independent of Mitsuba's).
        e["block_nrmse_ref_noise_removed"] = math.sqrt(max(e["block_nrmse"] ** 2 - ref_block_noise**2, 0.0))
        e["pixel_nrmse_ref_noise_removed"] = math.sqrt(max(e["pixel_nrmse"] ** 2 - ref_pixel_noise**2, 0.0))
        rows.append({**r, **e})
    rows.sort(key=lambda r: (r["rr_depth"], r["spp"], r["seed"]))
    # The pooled Mitsuba image (all renders, weighted by spp) against skybake's path tracer: the two
    # unbiased renderers on the same scene.
    tot = sum(k * len(v) for k, v in images.items())
    pooled = sum(k * sum(v) for k, v in images.items()) / tot
    per_channel_bias = [float(pooled[..., l][mask].mean() / ref_l[..., l][mask].mean() - 1) for l in range(3)]
    # Time to reach a given block NRMSE: fit NRMSE^2 = a / spp over the renders of >= 64 spp (the
    # reference's noise removed; below 64 spp rare long paths make the error heavy-tailed), and
    # CPU seconds per sample per pixel from the same renders.
    fast_e = errors(fast, ref, mask)
    to_reach = {}
    for rr in sorted({r["rr_depth"] for r in rows}):
        fit_rows = [r for r in rows if r["spp"] >= 64 and r["rr_depth"] == rr]
        if not fit_rows:
            continue
        a = float(np.mean([r["block_nrmse_ref_noise_removed"] ** 2 * r["spp"] for r in fit_rows]))
        cpu_per_spp = float(np.median([r["cpu_s"] / r["spp"] for r in fit_rows]))
        wall_per_spp = float(np.median([r["wall_s"] / r["spp"] for r in fit_rows]))
        target = {"rr_depth": rr, "renders_fitted": len(fit_rows),
                  "fit": "block NRMSE^2 = a / spp over renders of >= 64 spp (reference noise removed)",
                  "a": a, "cpu_s_per_spp": cpu_per_spp, "wall_s_per_spp": wall_per_spp,
                  "scaling_to_640x480": "x16 pixels at the same spp (block noise per spp checked with `pair`)"}
        for name, e in (("5 %", 0.05), ("fast method", fast_e["block_nrmse"])):
            spp = a / e**2
            target[name] = {"block_nrmse": e, "spp": spp, "cpu_s": spp * cpu_per_spp, "wall_s": spp * wall_per_spp,
                            "cpu_s_at_640x480": 16 * spp * cpu_per_spp}
        to_reach[f"rr_depth_{rr}"] = target
    data = load_json()
    data.update({
        "what": "Mitsuba 3 on skybake's bench frame: time to reach the fast method's error",
        "scene": "crates/harness/src/frame_bench.rs bench_cumulus + bench_scene under Lighting (sun + env) at the cloud, in vacuum "
                 "(no aerial perspective, no ground plane): crates/harness/examples/mitsuba_bench_export.rs",
        "resolution": [meta["camera"]["width"], meta["camera"]["height"]],
        "versions": {"mitsuba": version("mitsuba"), "drjit": version("drjit"), "numpy": np.__version__,
                     "variant": os.environ.get("MI_VARIANT", "llvm_ad_rgb"), "libLLVM": "19.1.7 (Debian libllvm19)",
                     "python": sys.version.split()[0]},
        "mitsuba_integrator": "volpath, max_depth -1, rr_depth per render (10 unless stated), box filter, "
                              "independent sampler, 2 threads; times are the Python process's (drjit's "
                              "threads included), the scene load and JIT warmed up by a 1-spp render first",
        "cloud_pixels": int(mask.sum()), "cloud_blocks": int(cb.sum()),
        "reference": {"renderer": "skybake path tracer (Method::Reference)", "spp": meta["reference_spp"],
                      "wall_s": meta["reference_ms"] / 1e3 if meta["reference_ms"] else None,
                      "block_noise": ref_block_noise, "pixel_noise": ref_pixel_noise, "cloud_mean": float(m)},
        "fast": {"wall_s": meta["fast_ms"] / 1e3, "stages_ms": meta["fast_stages_ms"], **fast_e},
        "mitsuba_to_reach": to_reach,
        "mitsuba_pooled_vs_path_tracer": {"spp_total": tot, **errors(pooled.mean(axis=2), ref, mask),
                                          "cloud_mean_bias_per_wavelength": per_channel_bias},
        "mitsuba_series": rows,
    })
    save_json(data)
    print(json.dumps({k: data[k] for k in ("reference", "fast", "mitsuba_pooled_vs_path_tracer", "mitsuba_to_reach")},
                     indent=1))
    print("| rr_depth | spp | wall s | CPU s | block NRMSE | (ref noise removed) | pixel NRMSE | cloud-mean bias |")
    for r in rows:
        print(f"| {r['rr_depth']} | {r['spp']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {100 * r['block_nrmse']:.1f} % | "
              f"{100 * r['block_nrmse_ref_noise_removed']:.1f} % | {100 * r['pixel_nrmse']:.0f} % | "
              f"{100 * r['cloud_mean_bias']:+.1f} % |")


def cmd_pair(d, spp):
    """Noise without a reference, for the resolution scaling: two independent renders at `spp`; the
    RMS of their difference over cloud blocks (pixels) divided by sqrt 2 is one render's block
    (pixel) noise, relative to the pair's mean over cloud pixels. Renders are stored as in
    `series` (seeds 1000 * spp + 500 + k) and the figures go to `pairs` in the JSON."""
    mi = mitsuba()
    meta = load_export(d)
    grid = np.load(os.path.join(d, "grid.npy"))
    env = np.load(os.path.join(d, "env.npy"))
    mask = mask_of(d)
    render(mi, bench_scene(mi, meta, grid, env, 1, 999_999))
    imgs, walls, cpus = [], [], []
    for k in range(2):
        seed = 1000 * spp + 500 + k
        t, c = time.perf_counter(), cpu_seconds()
        img = render(mi, bench_scene(mi, meta, grid, env, spp, seed))
        walls.append(time.perf_counter() - t)
        cpus.append(cpu_seconds() - c)
        np.save(os.path.join(d, f"pair_spp{spp}_seed{seed}.npy"), img.astype(np.float32))
        imgs.append(img.mean(axis=2))
        print(f"spp {spp} seed {seed}: wall {walls[-1]:.1f} s, cpu {cpus[-1]:.1f} s", flush=True)
    a, b = imgs
    m = 0.5 * (a[mask].mean() + b[mask].mean())
    cb = blocks(mask.astype(float)) == 1.0
    row = {"width": meta["camera"]["width"], "height": meta["camera"]["height"], "spp": spp,
           "wall_s": walls, "cpu_s": cpus, "threads": THREADS, "cloud_pixels": int(mask.sum()),
           "cloud_blocks": int(cb.sum()),
           "block_noise": float(np.sqrt(np.mean((blocks(a)[cb] - blocks(b)[cb]) ** 2) / 2) / m),
           "pixel_noise": float(np.sqrt(np.mean((a[mask] - b[mask]) ** 2) / 2) / m)}
    data = load_json()
    pairs = [p for p in data.get("pairs", []) if (p["width"], p["spp"]) != (row["width"], spp)]
    data["pairs"] = sorted(pairs + [row], key=lambda p: (p["width"], p["spp"]))
    save_json(data)
    print(json.dumps(row))


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    cmd, d = sys.argv[1], sys.argv[2]
    if cmd == "checks":
        cmd_checks(d)
    elif cmd == "series":
        cmd_series(d, [int(x) for x in sys.argv[3:]] or [4, 16, 64, 256])
    elif cmd == "pair":
        cmd_pair(d, int(sys.argv[3]))
    elif cmd == "summary":
        cmd_summary(d)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
