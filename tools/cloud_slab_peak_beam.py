#!/usr/bin/env python3
"""The light of a plane-parallel slab scattered only within the delta-M truncated peak, by Monte Carlo.

A diagnosis of the fast cloud method's TMS single scattering on the DISORT slab
(tests/clouds/render_validation.rs, `slab_split_by_smooth_scatterings_against_disort`;
docs/frames.md, "DISORT slab at every listed angle"). Henyey-Greenstein g = 0.85, albedo 1, the
delta-M truncation f = g^3.5 of the fast method, g* = (g - f)/(1 - f). Each collision of the true
medium is classed as within the truncated peak with probability r+(mu)/p(mu),
r+ = max(p - (1 - f) HG(g*), 0) (as the classed path tracers of
crates/harness/examples/back_probe.rs and of that test do).

Photons enter the top of a laterally infinite slab of optical thickness tau from a collimated
sun (cosine mu0, normal irradiance 1) and fly in the true medium; a peak collision only turns
them; their first smooth collision ends them (n = 0 light only). Printed:

1. the fluence of that light per depth bin over the delta-M scaled direct beam's exp(-(1 - f) z / mu0)
   (bin means): the spread beam's longer paths;
2. the radiance reflected towards the test's views after one smooth scattering (the smooth part
   min(p, (1 - f) HG(g*)) at the photon's own direction, seen through the scaled extinction
   exp(-(1 - f) z / mu)): light of one smooth scattering with the sun's side exact and the view's
   side as delta-M has it ("exact"), and the same with every photon advancing along the sun's
   direction whatever its own ("straight": the Goudsmit & Saunderson picture of the fast
   method's peak spread, crates/render/src/peak.rs, angles exact, paths straight);
3. the same for the light scattered last within the peak (n = 0: the peak's part r+ at the
   photon's own direction, seen through the true extinction exp(-z / mu), as the fast method's
   march sees it), exact and straight;
4. both again with every photon's depth its path so far times the cosine of the direction halfway
   between the sun's and its own ("halfway": the mean direction of a small-angle random walk that
   ends in that direction), a candidate closed form of the exact sun side.

numpy only; a few minutes of CPU. Usage: python3 tools/cloud_slab_peak_beam.py
"""
import math

import numpy as np

G = 0.85
F = G**3.5
GS = (G - F) / (1 - F)


def hg(g, m):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * m) ** 1.5)


def sample_hg(g, u):
    s = (1 - g * g) / (1 - g + 2 * g * u)
    return (1 + g * g - s * s) / (2 * g)


def turn(d, m, rng):
    """Directions d turned by angle acos(m), uniform azimuth."""
    phi = 2 * np.pi * rng.random(len(m))
    sn = np.sqrt(np.maximum(0, 1 - m * m))
    helper = np.zeros_like(d)
    near_z = np.abs(d[:, 2]) >= 0.9
    helper[~near_z, 2] = 1
    helper[near_z, 0] = 1
    t = np.cross(d, helper)
    t /= np.linalg.norm(t, axis=1)[:, None]
    b = np.cross(d, t)
    return t * (sn * np.cos(phi))[:, None] + b * (sn * np.sin(phi))[:, None] + d * m[:, None]


def run(tau, mu0, views, n=200_000, bins=16, seed=1, straight=False, halfway=False):
    """Fluence ratio by depth bin and the radiance towards each (view zenith, azimuth from the
    sun's side) of `views` (azimuth 0: the camera on the side the sun's beam travels towards)."""
    rng = np.random.default_rng(seed)
    d = np.zeros((n, 3))
    d[:, 2] = mu0  # z: depth, positive downwards; the beam travels towards +x
    d[:, 0] = math.sqrt(1 - mu0 * mu0)
    vs = []
    for vz, raz in views:
        muv, sv = math.cos(math.radians(vz)), math.sin(math.radians(vz))
        vs.append((muv, np.array([sv * math.cos(math.radians(raz)), sv * math.sin(math.radians(raz)), -muv])))
    z = np.zeros(n)
    path = np.zeros(n)
    alive = np.ones(n, bool)
    edges = np.linspace(0, tau, bins + 1)
    track = np.zeros(bins)
    rad = np.zeros(len(views))
    rad0 = np.zeros(len(views))
    ks = 1 - F
    while alive.any():
        idx = np.nonzero(alive)[0]
        s = -np.log(1 - rng.random(idx.size))
        mu = d[idx, 2]
        adv = np.full(idx.size, mu0) if straight else mu
        z0 = z[idx]
        z1 = z0 + s * adv
        if halfway:
            # The depth reached after a path s in direction d: s times the cosine of the direction
            # halfway between the sun's and d (the mean direction of a small-angle random walk
            # that ends at d).
            half = d[idx] + np.array([math.sqrt(1 - mu0 * mu0), 0.0, mu0])
            half /= np.linalg.norm(half, axis=1)[:, None]
            adv = np.maximum(half[:, 2], 1e-3)
            z0 = path[idx] * adv
            z1 = z0 + s * adv
            path[idx] += s
        esc = (z1 < 0) | (z1 > tau)
        z1 = np.clip(z1, 0, tau)
        am = np.abs(adv) + 1e-12
        lo, hi = np.minimum(z0, z1), np.maximum(z0, z1)
        for b in range(bins):
            track[b] += (np.clip(np.minimum(hi, edges[b + 1]) - np.maximum(lo, edges[b]), 0, None) / am).sum()
        length = np.abs(z1 - z0) / am
        for j, (muv, v) in enumerate(vs):
            c = d[idx] @ v
            smooth = np.minimum(hg(G, c), (1 - F) * hg(GS, c))
            a = ks * adv / muv
            with np.errstate(divide="ignore", invalid="ignore"):
                integral = np.where(
                    np.abs(a) > 1e-9,
                    np.exp(-ks * z0 / muv) * (1 - np.exp(-a * length)) / a,
                    np.exp(-ks * z0 / muv) * length,
                )
            rad[j] += (smooth * integral).sum() / muv
            # The light scattered last within the peak (n = 0), seen through the true extinction.
            a1 = adv / muv
            with np.errstate(divide="ignore", invalid="ignore"):
                integral1 = np.where(
                    np.abs(a1) > 1e-9,
                    np.exp(-z0 / muv) * (1 - np.exp(-a1 * length)) / a1,
                    np.exp(-z0 / muv) * length,
                )
            rad0[j] += (np.maximum(hg(G, c) - (1 - F) * hg(GS, c), 0) * integral1).sum() / muv
        z[idx] = z1
        alive[idx[esc]] = False
        idx = idx[~esc]
        m = sample_hg(G, rng.random(idx.size))
        p = hg(G, m)
        peak = rng.random(idx.size) * p < np.maximum(p - (1 - F) * hg(GS, m), 0)
        alive[idx[~peak]] = False
        idx = idx[peak]
        d[idx] = turn(d[idx], m[peak], rng)
    dz = tau / bins
    # One photon carries mu0 of horizontal flux for normal irradiance 1.
    fluence = track / (n * dz) * mu0
    k = ks / mu0
    beam = (np.exp(-k * edges[:-1]) - np.exp(-k * edges[1:])) / (k * dz)
    return 0.5 * (edges[1:] + edges[:-1]), fluence / beam, rad / n * mu0, rad0 / n * mu0


if __name__ == "__main__":
    views = [(0, 0), (60, 0), (60, 180), (75, 0), (75, 90), (75, 180)]
    for tau, mu0 in [(1.0, 0.5), (8.0, 0.5), (8.0, 1.0)]:
        zc, ratio, exact, exact0 = run(tau, mu0, views, bins=8 if tau < 2 else 16)
        _, _, straight, straight0 = run(tau, mu0, views, bins=8, straight=True)
        _, _, half, half0 = run(tau, mu0, views, bins=8, halfway=True)
        print(f"tau {tau} mu0 {mu0}: peak-only fluence / scaled beam by depth: "
              + " ".join(f"{a:.2f}:{r:.2f}" for a, r in zip(zc, ratio)))
        for (vz, raz), e, st, h, e0, st0, h0 in zip(views, exact, straight, half, exact0, straight0, half0):
            print(f"tau {tau} mu0 {mu0} view [{vz} {raz}]: one smooth scattering, exact {e:.5f}, straight {st:.5f}, "
                  f"halfway {h:.5f}; scattered last within the peak (n = 0), exact {e0:.5f}, straight {st0:.5f}, "
                  f"halfway {h0:.5f}")
