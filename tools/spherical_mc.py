#!/usr/bin/env python3
"""Backward Monte Carlo radiance in a pure-Rayleigh atmosphere on a spherical shell (numpy).

Written from scratch for skybake's twilight accuracy work as a reference that, unlike DISORT, sees the planet's
curvature, the Earth's shadow and the lit upper atmosphere in twilight. Nothing here is taken from
skybake's Rust code: geometry, optical depths, sampling and estimators are its own.

Model (the `rayleigh-only` preset): planet radius R = 6 360 km, atmosphere top R + 100 km, Rayleigh
scattering coefficient beta(z) = beta0 exp(-z / 8000 m) with beta0 = 3.31e-5 (440 nm), 1.3558e-5
(550 nm), 5.802e-6 (680 nm) per metre, single-scattering albedo 1, Rayleigh phase function
3/(16 pi)(1 + cos^2), Lambertian ground of albedo a, no refraction. Sun: a uniform disk of angular
radius 0.2666 deg at infinity, irradiance 1 normal to the beam; results are radiance per unit solar
irradiance (sr^-1), diffuse light only (the sun's disk itself is not counted).

Estimator (backward path tracing from the observer along the line of sight d):
  * the segment of the ray inside the shell [t0, t1] is found analytically; the optical depth along
    it is tabulated by the trapezoid rule on 2 x NODES nodes placed quadratically dense towards the
    ray's lowest point (split at the perigee when it lies on the segment);
  * single scattering of sunlight along the whole segment is integrated by Q_NODES stratified
    (jittered, hence unbiased) samples: sigma(t) T(t0, t) p(d . s) T_sun(t), with s drawn uniformly
    on the sun's disk, T_sun by GL_NODES-point Gauss-Legendre per side of the perigee, and zero when
    the ground blocks the sun; where the segment ends on a reflecting ground, the ground's reflection
    of direct sunlight T(t0, t1) (a/pi) mu_s T_sun is added;
  * the path continues (diffuse light) by a forced collision inside the segment, weight
    x (1 - T(t0, t1)), distance drawn from sigma(t) T(t0, t) / (1 - T(t0, t1)) by inverting the
    tabulated optical depth; where the segment ends on a reflecting ground it reaches the ground with
    probability T(t0, t1) instead and bounces into a cosine-distributed direction with weight x a;
  * new directions from the Rayleigh phase function (exact inverse CDF); Russian roulette below
    weight 0.05; at most 200 orders.
Every estimate carries its standard error (standard deviation of the per-path totals / sqrt(N)).

Self-checks (run with --check; figures recorded in the JSON header):
  1. the tabulated and Gauss-Legendre optical depths against a 20 000-interval midpoint rule, on
     rays from the ground to 400 km, grazing and passing their perigee;
  2. the plane-parallel limit (R x 10, as skybake's tests do) against tests/data/disort_rayleigh.json
     (pydisort 1.8.13, 40 streams).

Usage (from the repository root; numpy only, 1 thread, deterministic seeds):
    python3 tools/spherical_mc.py --check                 # optical depths + DISORT comparison
    python3 tools/spherical_mc.py --set NAME --out tests/data/spherical_mc_NAME.json

numpy 2.4.6, Python 3.11.7.
"""

import argparse
import json
import math
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import numpy as np  # noqa: E402

R_EARTH_M = 6_360_000.0
TOP_M = 100_000.0
H_M = 8000.0
BETA0 = {440: 3.31e-5, 550: 1.3558e-5, 680: 5.802e-6}
SUN_RADIUS_DEG = 0.2666
NODES = 96  # trapezoid nodes per piece of a path segment
GL_NODES = 24  # Gauss-Legendre nodes per piece of a sun ray
Q_NODES = 8  # stratified samples per segment for single scattering of sunlight
RR_WEIGHT = 0.05
MAX_ORDERS = 200

GL_X, GL_W = np.polynomial.legendre.leggauss(GL_NODES)
GL_U = 0.5 * (GL_X + 1.0)  # on [0, 1]
GL_WU = 0.5 * GL_W


class Atmosphere:
    def __init__(self, radius_m, beta0, albedo):
        self.R = radius_m
        self.Rt = radius_m + TOP_M
        self.beta0 = beta0
        self.albedo = albedo

    def density(self, r):
        """Relative density exp(-z/H), z clipped to >= 0 (rounding at the ground)."""
        return np.exp(-np.maximum(r - self.R, 0.0) / H_M)


def segment(atm, p, d):
    """Part of rays p + t d inside the shell: (t0, t1, hits_ground, valid)."""
    b = np.einsum("ij,ij->i", p, d)
    c = np.einsum("ij,ij->i", p, p)
    disc_t = b * b - c + atm.Rt**2
    sq_t = np.sqrt(np.maximum(disc_t, 0.0))
    inside = c <= atm.Rt**2 * (1 + 1e-12)
    t_far = -b + sq_t
    t_near = -b - sq_t
    t0 = np.where(inside, 0.0, t_near)
    valid = np.where(inside, True, (disc_t > 0) & (t_near > 0))
    disc_g = b * b - c + atm.R**2
    hits = (b < 0) & (disc_g > 0)
    t_g = -b - np.sqrt(np.maximum(disc_g, 0.0))
    t1 = np.where(hits, t_g, t_far)
    t1 = np.maximum(t1, t0)
    return t0, t1, hits & valid, valid


def _pieces(p, d, t0, t1):
    """Split point m = perigee clipped to [t0, t1]; rays are dense towards m on both sides."""
    b = np.einsum("ij,ij->i", p, d)
    m = np.clip(-b, t0, t1)
    return b, m


def tabulate(atm, p, d, t0, t1):
    """Nodes t (N, 2 NODES - 1) ascending and cumulative optical depth tau(t) from t0."""
    b, m = _pieces(p, d, t0, t1)
    c = np.einsum("ij,ij->i", p, p)
    u = np.linspace(0.0, 1.0, NODES)
    u2 = u * u
    ta = m[:, None] - (m - t0)[:, None] * u2[::-1][None, :]  # t0 .. m, dense at m
    tb = m[:, None] + (t1 - m)[:, None] * u2[None, :]  # m .. t1, dense at m
    t = np.concatenate([ta, tb[:, 1:]], axis=1)
    r = np.sqrt(np.maximum(c[:, None] + 2 * b[:, None] * t + t * t, 0.0))
    sig = atm.beta0 * atm.density(r)
    dt = np.diff(t, axis=1)
    cum = np.concatenate([np.zeros((len(t), 1)), np.cumsum(0.5 * (sig[:, 1:] + sig[:, :-1]) * dt, axis=1)], axis=1)
    return t, cum


def tau_gl(atm, p, d, t0, t1):
    """Optical depth along [t0, t1] by Gauss-Legendre on each piece, t = m -/+ L u^2."""
    b, m = _pieces(p, d, t0, t1)
    c = np.einsum("ij,ij->i", p, p)
    total = np.zeros(len(p))
    for lo, L, sign in ((m, m - t0, -1.0), (m, t1 - m, 1.0)):
        t = lo[:, None] + sign * L[:, None] * (GL_U * GL_U)[None, :]
        r = np.sqrt(np.maximum(c[:, None] + 2 * b[:, None] * t + t * t, 0.0))
        total += (atm.density(r) * (2.0 * L[:, None] * GL_U[None, :]) * GL_WU[None, :]).sum(axis=1)
    return atm.beta0 * total


def tau_reference(atm, p, d, t0, t1, n=20000):
    """Midpoint rule with n intervals (check only)."""
    b = np.einsum("ij,ij->i", p, d)
    c = np.einsum("ij,ij->i", p, p)
    x = (np.arange(n) + 0.5) / n
    t = t0[:, None] + (t1 - t0)[:, None] * x[None, :]
    r = np.sqrt(np.maximum(c[:, None] + 2 * b[:, None] * t + t * t, 0.0))
    return atm.beta0 * atm.density(r).sum(axis=1) * (t1 - t0) / n


def frame(d):
    """Two unit vectors orthogonal to each row of d."""
    a = np.where(np.abs(d[:, 0:1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    return e1, e2


def rotate(d, cos_t, phi):
    e1, e2 = frame(d)
    sin_t = np.sqrt(np.maximum(1 - cos_t * cos_t, 0.0))
    out = d * cos_t[:, None] + (e1 * np.cos(phi)[:, None] + e2 * np.sin(phi)[:, None]) * sin_t[:, None]
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def rayleigh_phase(c):
    return 3.0 / (16.0 * math.pi) * (1.0 + c * c)


def sample_rayleigh(xi):
    """Inverse of the Rayleigh CDF (3 mu + mu^3 + 4)/8."""
    u = 4.0 * xi - 2.0
    s = np.sqrt(u * u + 1.0)
    return np.clip(np.cbrt(u + s) + np.cbrt(u - s), -1.0, 1.0)


def sun_transmittance(atm, x, sun, cos_disk, rng):
    """Transmittance from points x towards a uniformly sampled point of the sun's disk (0 if the
    ground is in the way), and the sampled directions."""
    n = len(x)
    cos_a = 1.0 - rng.random(n) * (1.0 - cos_disk)
    s = rotate(np.broadcast_to(sun, (n, 3)).copy(), cos_a, 2 * math.pi * rng.random(n))
    t0, t1, hits, valid = segment(atm, x, s)
    T = np.zeros(n)
    lit = ~hits
    if lit.any():
        T[lit] = np.exp(-tau_gl(atm, x[lit], s[lit], t0[lit], t1[lit]))
    return T, s


def direct_along_segment(atm, p, d, t0, tn, cum, sun, cos_disk, rng):
    """Single scattering of sunlight along each segment, by Q_NODES jittered (stratified) samples in
    u with t = t0 + (t1 - t0) u over the tabulated nodes' parameter: unbiased for any jitter.
    Integrand sigma(t) T(t0, t) p(d . s) T_sun(t); T(t0, t) interpolated from the table."""
    n = len(p)
    q = Q_NODES
    # Stratified positions in the table's node index space (the nodes are dense where air is).
    k_float = (np.arange(q)[None, :] + rng.random((n, 1))) / q * (tn.shape[1] - 1)
    k = np.minimum(k_float.astype(int), tn.shape[1] - 2)
    f = k_float - k
    rows = np.arange(n)[:, None]
    ta, tb = tn[rows, k], tn[rows, k + 1]
    t = ta + f * (tb - ta)
    dt_dk = (tb - ta) * (tn.shape[1] - 1) / q  # dt per stratum
    tau = cum[rows, k] + f * (cum[rows, k + 1] - cum[rows, k])
    x = (p[:, None, :] + d[:, None, :] * t[:, :, None]).reshape(-1, 3)
    r = np.linalg.norm(x, axis=1)
    sig = atm.beta0 * atm.density(r).reshape(n, q)
    weight = sig * np.exp(-tau) * dt_dk
    T_sun, s = sun_transmittance(atm, x, sun, cos_disk, rng)
    cs = np.einsum("ij,ij->i", np.repeat(d, q, axis=0), s)
    return (weight * (rayleigh_phase(cs) * T_sun).reshape(n, q)).sum(axis=1)


def radiance(atm, altitude_m, sun_elev_deg, vz_deg, va_deg, n_paths, seed, batch=4000, max_orders=MAX_ORDERS):
    """Mean radiance per unit solar irradiance and its standard error, diffuse only."""
    rng = np.random.default_rng(seed)
    e = math.radians(sun_elev_deg)
    sun = np.array([math.cos(e), 0.0, math.sin(e)])
    cos_disk = math.cos(math.radians(SUN_RADIUS_DEG))
    th, ph = math.radians(vz_deg), math.radians(va_deg)
    view = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    origin = np.array([0.0, 0.0, atm.R + altitude_m])
    totals = []
    done = 0
    while done < n_paths:
        n = min(batch, n_paths - done)
        done += n
        idx = np.arange(n)
        p = np.broadcast_to(origin, (n, 3)).copy()
        d = np.broadcast_to(view, (n, 3)).copy()
        w = np.ones(n)
        acc = np.zeros(n)
        for order in range(max_orders):
            if len(idx) == 0:
                break
            t0, t1, hits, valid = segment(atm, p, d)
            keep = valid & (t1 > t0)
            idx, p, d, w, t0, t1, hits = idx[keep], p[keep], d[keep], w[keep], t0[keep], t1[keep], hits[keep]
            if len(idx) == 0:
                break
            m = len(idx)
            tn, cum = tabulate(atm, p, d, t0, t1)
            T_end = np.exp(-cum[:, -1])
            # Expected single scattering of sunlight along the whole segment.
            contrib = w * direct_along_segment(atm, p, d, t0, tn, cum, sun, cos_disk, rng)
            # Ground at the end: its reflection of direct sunlight, expected value.
            reflect = hits & (atm.albedo > 0)
            if reflect.any():
                xg = p[reflect] + d[reflect] * t1[reflect, None]
                nrm = xg / np.linalg.norm(xg, axis=1, keepdims=True)
                Tg, sg = sun_transmittance(atm, nrm * atm.R, sun, cos_disk, rng)
                mu_s = np.maximum(np.einsum("ij,ij->i", nrm, sg), 0.0)
                contrib[reflect] += w[reflect] * T_end[reflect] * atm.albedo / math.pi * mu_s * Tg
            np.add.at(acc, idx, contrib)
            # Continuation (diffuse light): to the ground with probability T_end where it reflects,
            # otherwise a forced collision inside the segment.
            ground = reflect & (rng.random(m) < T_end)
            sc = ~ground
            w_next = np.where(reflect, w, w * (1.0 - T_end))
            xi = rng.random(m)
            tau_star = np.where(reflect, -np.log(np.maximum(1.0 - xi * (1.0 - T_end), 1e-300)),
                                -np.log1p(-xi * (1.0 - T_end)))
            k = (cum < tau_star[:, None]).sum(axis=1) - 1
            k = np.clip(k, 0, cum.shape[1] - 2)
            rows = np.arange(m)
            c0, c1 = cum[rows, k], cum[rows, k + 1]
            f = np.where(c1 > c0, (tau_star - c0) / np.maximum(c1 - c0, 1e-300), 0.0)
            t_star = tn[rows, k] + f * (tn[rows, k + 1] - tn[rows, k])
            x = p + d * t_star[:, None]
            new_d = np.empty_like(d)
            if sc.any():
                ns = sc.sum()
                new_d[sc] = rotate(d[sc], sample_rayleigh(rng.random(ns)), 2 * math.pi * rng.random(ns))
            if ground.any():
                ng = ground.sum()
                xg = p[ground] + d[ground] * t1[ground, None]
                nrm = xg / np.linalg.norm(xg, axis=1, keepdims=True)
                new_d[ground] = rotate(nrm, np.sqrt(rng.random(ng)), 2 * math.pi * rng.random(ng))
                x[ground] = nrm * (atm.R + 1e-3)
                w_next[ground] = w[ground] * atm.albedo
            w = w_next
            low = w < RR_WEIGHT
            survive = ~low | (rng.random(m) < w / RR_WEIGHT)
            w = np.where(low, RR_WEIGHT, w)
            keep = survive & (w > 0)
            idx, p, d, w = idx[keep], x[keep], new_d[keep], w[keep]
        totals.append(acc)
    allv = np.concatenate(totals)
    return float(allv.mean()), float(allv.std(ddof=1) / math.sqrt(len(allv)))


def check_optical_depths():
    atm = Atmosphere(R_EARTH_M, BETA0[550], 0.0)
    worst = 0.0
    rng = np.random.default_rng(1)
    for h in [0.0, 1.0, 500.0, 10e3, 60e3, 400e3]:
        for vz in np.linspace(0, 180, 181):
            th = math.radians(vz)
            p = np.array([[0.0, 0.0, atm.R + h]])
            d = np.array([[math.sin(th), 0.0, math.cos(th)]])
            t0, t1, hits, valid = segment(atm, p, d)
            if not valid[0] or t1[0] <= t0[0]:
                continue
            ref = tau_reference(atm, p, d, t0, t1)[0]
            if ref < 1e-6:
                continue
            a = tau_gl(atm, p, d, t0, t1)[0]
            b = tabulate(atm, p, d, t0, t1)[1][0, -1]
            worst = max(worst, abs(a / ref - 1), abs(b / ref - 1))
    del rng
    return worst


def check_disort(n_paths):
    """Plane-parallel limit (R x 10) against DISORT: sun zenith 0/60, view zenith 0/60, azimuth 0/180,
    440/550/680 nm, albedo 0/0.3 (48 radiances)."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "disort_rayleigh.json")
    data = json.load(open(path))
    vz = data["view_zenith_deg"]
    va = data["relative_azimuth_deg"]
    rows = []
    seed = 100
    for case in data["cases"]:
        if case["sun_zenith_deg"] not in (0.0, 60.0):
            continue
        lam = int(case["wavelength_nm"])
        atm = Atmosphere(R_EARTH_M * 10, BETA0[lam], case["ground_albedo"])
        for i, z in enumerate(vz):
            if z not in (0.0, 60.0):
                continue
            for j, a in enumerate(va):
                if a not in (0.0, 180.0):
                    continue
                ref = case["bottom_downwelling_radiance_per_sr"][i][j]
                seed += 1
                m, se = radiance(atm, 0.0, 90.0 - case["sun_zenith_deg"], z, a, n_paths, seed)
                rows.append({
                    "wavelength_nm": lam, "ground_albedo": case["ground_albedo"],
                    "sun_zenith_deg": case["sun_zenith_deg"], "view_zenith_deg": z, "view_azimuth_deg": a,
                    "mc": m, "mc_std_error": se, "disort": ref,
                    "deviation": m / ref - 1, "sigmas": (m - ref) / se,
                })
                print(f"{lam} a={case['ground_albedo']} sza={case['sun_zenith_deg']} vz={z} va={a}: "
                      f"mc {m:.6e} +- {100*se/m:.2f} %  disort {ref:.6e}  dev {100*(m/ref-1):+.2f} % "
                      f"({(m-ref)/se:+.1f} sigma)", flush=True)
    return rows


def _grid(lams, albedos, alts, suns, vzs, vas):
    return [dict(wavelength_nm=l, ground_albedo=a, observer_altitude_m=h, sun_elevation_deg=e,
                 view_zenith_deg=z, view_azimuth_deg=v)
            for l in lams for a in albedos for h in alts for e in suns for z in vzs for v in vas
            # The zenith and the nadir do not depend on azimuth: once.
            if z not in (0.0, 180.0) or v == vas[0]]


SUNS = [10.0, 2.0, 0.0, -2.0, -4.0, -6.0, -9.0, -12.0]
# Each set: (cases, relative standard error aimed at per sun elevation band, most paths per case).
SETS = {
    # Ground observer, 550 nm, black ground: the full sun range, view zenith 0-89 deg.
    "ground": (_grid([550], [0.0], [0.0], SUNS, [0.0, 45.0, 75.0, 85.0, 89.0], [0.0, 90.0, 180.0]),
               400_000),
    # Colour and ground bounce: 440/550/680 nm, albedo 0.3, sun 0 and -6 deg.
    "spectral": (_grid([440, 550, 680], [0.3], [0.0], [2.0, -6.0], [0.0, 85.0], [0.0, 180.0]), 300_000),
    # Observer at 10 km: sky and ground views; at 400 km: the lit planet and the limb (the
    # geometric horizon is at view zenith 109.8 deg there).
    "altitude": (_grid([550], [0.3], [10_000.0], [2.0, -6.0], [0.0, 85.0, 95.0, 135.0, 180.0], [0.0, 180.0])
                 + _grid([550], [0.3], [400_000.0], [10.0, -6.0], [180.0, 140.0, 112.0, 108.0], [0.0, 180.0]),
                 300_000),
}


def target_error(sun_elev_deg):
    """Relative standard error aimed at: a fifth of the test tolerance of each band."""
    if sun_elev_deg >= 0:
        return 0.004
    if sun_elev_deg >= -6:
        return 0.008
    return 0.02


def run_set(name, out, max_seconds):
    cases, max_paths = SETS[name]
    results = []
    if os.path.exists(out):
        results = json.load(open(out))["cases"]
    done_keys = {json.dumps({k: c[k] for k in cases[0]}, sort_keys=True) for c in results}
    per_case = max_seconds / max(1, len(cases))
    for i, c in enumerate(cases):
        key = json.dumps(c, sort_keys=True)
        if key in done_keys:
            continue
        atm = Atmosphere(R_EARTH_M, BETA0[c["wavelength_nm"]], c["ground_albedo"])
        t = time.time()
        sums, n, chunk = [], 0, 8000
        seed = 1000 + i
        while True:
            m, se = radiance(atm, c["observer_altitude_m"], c["sun_elevation_deg"], c["view_zenith_deg"],
                             c["view_azimuth_deg"], chunk, seed)
            seed += 100_000
            sums.append((m, se, chunk))
            n += chunk
            tot = sum(s[2] for s in sums)
            mean = sum(s[0] * s[2] for s in sums) / tot
            # Pooled sample variance of all per-path estimates from the chunks' means and errors.
            var = sum((s[1] ** 2 * s[2]) * (s[2] - 1) + s[2] * (s[0] - mean) ** 2 for s in sums) / (tot - 1)
            sem = math.sqrt(var / tot)
            if mean > 0 and sem / mean <= target_error(c["sun_elevation_deg"]):
                break
            if n >= max_paths or time.time() - t > per_case:
                break
        row = dict(c, radiance_per_sr=mean, std_error_per_sr=sem, paths=n, seconds=round(time.time() - t, 1))
        results.append(row)
        print(f"[{name} {i + 1}/{len(cases)}] {c}: {mean:.5e} +- {100 * sem / mean if mean else 0:.2f} % "
              f"({n} paths, {time.time() - t:.0f} s)", flush=True)
        _write(out, name, results)
    return results


def _write(out, name, results):
    header = {
        "source": "tools/spherical_mc.py (backward Monte Carlo on the spherical shell, the twilight reference)",
        "package_versions": {"python": sys.version.split()[0], "numpy": np.__version__},
        "set": name,
        "inputs": {
            "planet_radius_m": R_EARTH_M, "atmosphere_height_m": TOP_M, "rayleigh_scale_height_m": H_M,
            "rayleigh_scattering_sea_level_per_m": {str(k): v for k, v in BETA0.items()},
            "sun_angular_radius_deg": SUN_RADIUS_DEG, "phase": "Rayleigh 3/(16 pi)(1 + cos^2)",
            "ground": "Lambertian", "refraction": "none", "absorption": "none",
        },
        "units": "radiance per unit extraterrestrial solar irradiance normal to the beam, sr^-1; diffuse only",
        "conventions": "view zenith from the local vertical at the observer; view azimuth from the sun's azimuth "
                       "(0 = towards the sun); sun elevation from the observer's horizontal plane",
        "noise": "std_error_per_sr = standard deviation of the per-path estimates / sqrt(paths)",
        "validation": "see tools/README.md (optical depths vs a 20 000-interval midpoint rule; plane-parallel limit "
                      "vs tests/data/disort_rayleigh.json)",
    }
    tmp = out + ".tmp"
    json.dump({"header": header, "cases": results}, open(tmp, "w"), indent=1)
    os.replace(tmp, out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--check-paths", type=int, default=40000)
    ap.add_argument("--set")
    ap.add_argument("--out")
    ap.add_argument("--probe", nargs=6, type=float, metavar=("LAMBDA", "ALBEDO", "ALT_M", "SUN_DEG", "VZ", "VA"))
    ap.add_argument("--paths", type=int, default=20000)
    ap.add_argument("--max-seconds", type=float, default=3600.0)
    ap.add_argument("--orders", type=int, default=MAX_ORDERS, help="with --probe: scattering orders counted")
    args = ap.parse_args()
    if args.probe:
        lam, a, h, e, z, az = args.probe
        atm = Atmosphere(R_EARTH_M, BETA0[int(lam)], a)
        t = time.time()
        m, se = radiance(atm, h, e, z, az, args.paths, 7, max_orders=args.orders)
        print(f"{m:.6e} +- {se:.2e} ({100*se/m if m else 0:.2f} %)  {time.time()-t:.1f} s")
        return
    if args.check:
        t = time.time()
        w = check_optical_depths()
        print(f"optical depth: worst relative error {w:.2e} ({time.time()-t:.1f} s)", flush=True)
        rows = check_disort(args.check_paths)
        devs = np.array([r["deviation"] for r in rows])
        sig = np.array([r["sigmas"] for r in rows])
        print(f"DISORT: max |dev| {100*np.abs(devs).max():.2f} %, mean dev {100*devs.mean():+.3f} %, "
              f"rms sigma {np.sqrt((sig**2).mean()):.2f}, max |sigma| {np.abs(sig).max():.1f}")
        if args.out:
            json.dump({"optical_depth_worst_relative_error": w, "disort_rows": rows}, open(args.out, "w"), indent=1)
        return
    if args.set:
        run_set(args.set, args.out, args.max_seconds)


if __name__ == "__main__":
    main()
