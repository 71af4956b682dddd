#!/usr/bin/env python3
"""The light of one smooth scattering of a plane-parallel slab with the peak's turns gathered
along a few directions, against the exact sun side, by Monte Carlo.

A check of the fast cloud method's gathering of the smooth part's turned light
(crates/render/src/march/turned.rs, `smooth_rays`; docs/frames.md, "δ-M truncation and TMS",
item 10) on the DISORT slab. Photons of the true medium (Henyey-Greenstein g = 0.85, albedo 1,
the delta-M truncation f = g^3.5 of the fast method) enter the top of a laterally infinite slab
from a sun of cosine mu0 = 0.5; each collision is classed as within the truncated peak with
probability r+(mu)/p(mu) (as tools/cloud_slab_peak_beam.py does): a peak collision only turns
the photon, the first smooth one ends it. The radiance towards each view after that smooth
scattering (min(p, (1 - f) HG(g*)) at the photon's direction, seen through exp(-(1 - f) z / mu))
is printed for:

- "exact": every photon advancing along its own direction;
- "straight": every photon advancing along the sun's direction (the peak table's picture);
- "ring": a photon the peak has turned advancing along one of three directions, equally
  weighted: a ring at the single turn's RMS angle sqrt(2 (1 - h1)) round the sun's direction
  tilted towards the view by (1 - h1) 3 g* sin T / (1 + g*^2 - 2 g* cos T) (T the scattering
  angle), at azimuths 0, 120 and 240 degrees (the renderer's first-order form, exact in a
  laterally infinite slab);

and "ring15", the same at 15 degrees.

numpy only; a few minutes of CPU per optical thickness. Usage:
python3 tools/cloud_slab_smooth_turns.py TAU [PHOTONS]
"""
import math
import sys

import numpy as np

from cloud_slab_peak_beam import F, G, GS, hg, sample_hg, turn


def peak_moments():
    """The truncated peak's normalised mean cosine h1 (r+ = max(p - (1 - f) HG(g*), 0))."""
    u = (np.arange(200_000) + 0.5) / 200_000
    mu = 1 - 2 * u * u
    w = 4 * u / 200_000
    r = np.maximum(hg(G, mu) - (1 - F) * hg(GS, mu), 0)
    return (r * mu * w).sum() / (r * w).sum()


H1 = peak_moments()


def ring(theta, radius):
    """(tilt, out-of-plane) angles in radians of the ring's three directions."""
    tilt = min((1 - H1) * 3 * GS * math.sin(theta) / (1 + GS * GS - 2 * GS * math.cos(theta)), theta)
    return [(tilt + radius * math.cos(p), radius * math.sin(p)) for p in (0, 2 * math.pi / 3, 4 * math.pi / 3)]


def run(tau, mu0, view, n, mode, radius=0.0, seed=1):
    rng = np.random.default_rng(seed)
    vz, raz = view
    muv, sv = math.cos(math.radians(vz)), math.sin(math.radians(vz))
    # The direction towards the camera (z: depth, positive downwards; the beam travels towards +x).
    v = np.array([sv * math.cos(math.radians(raz)), sv * math.sin(math.radians(raz)), -muv])
    s = np.array([math.sqrt(1 - mu0 * mu0), 0.0, mu0])
    e = v - (v @ s) * s
    e = e / np.linalg.norm(e) if np.linalg.norm(e) > 1e-9 else np.array([0.0, 1.0, 0.0])
    nrm = np.cross(s, e)
    if mode == "ring":
        advs = []
        for a, c in ring(math.acos(float(v @ s)), radius):
            m = math.cos(a) * s + math.sin(a) * e
            b = math.cos(c) * m + math.sin(c) * nrm
            advs.append(max(b[2], 1e-3))
    else:
        advs = [None]
    total = 0.0
    ks = 1 - F
    for adv_t in advs:
        d = np.tile(s, (n, 1))
        z = np.zeros(n)
        turned = np.zeros(n, bool)
        alive = np.ones(n, bool)
        rad = 0.0
        while alive.any():
            idx = np.nonzero(alive)[0]
            step = -np.log(1 - rng.random(idx.size))
            if mode == "exact":
                adv = d[idx, 2]
            elif mode == "straight":
                adv = np.full(idx.size, mu0)
            else:
                adv = np.where(turned[idx], adv_t, mu0)
            z0 = z[idx]
            z1 = z0 + step * adv
            esc = (z1 < 0) | (z1 > tau)
            z1 = np.clip(z1, 0, tau)
            length = np.abs(z1 - z0) / (np.abs(adv) + 1e-12)
            c = d[idx] @ v
            smooth = np.minimum(hg(G, c), (1 - F) * hg(GS, c))
            a = ks * adv / muv
            with np.errstate(divide="ignore", invalid="ignore"):
                integral = np.where(
                    np.abs(a) > 1e-9,
                    np.exp(-ks * z0 / muv) * (1 - np.exp(-a * length)) / a,
                    np.exp(-ks * z0 / muv) * length,
                )
            rad += (smooth * integral).sum() / muv
            z[idx] = z1
            alive[idx[esc]] = False
            idx = idx[~esc]
            m = sample_hg(G, rng.random(idx.size))
            p = hg(G, m)
            peak = rng.random(idx.size) * p < np.maximum(p - (1 - F) * hg(GS, m), 0)
            alive[idx[~peak]] = False
            idx = idx[peak]
            d[idx] = turn(d[idx], m[peak], rng)
            turned[idx] = True
        total += rad / n * mu0 / len(advs)
    return total


if __name__ == "__main__":
    tau = float(sys.argv[1])
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 60_000
    radius = math.sqrt(2 * (1 - H1))
    print(f"h1 {H1:.4f}, ring radius {math.degrees(radius):.1f} deg")
    views = [(0, 0), (30, 0), (30, 180), (60, 0), (60, 180), (75, 0), (75, 90), (75, 180)]
    for view in views:
        ex = run(tau, 0.5, view, n, "exact")
        st = run(tau, 0.5, view, n, "straight")
        r = run(tau, 0.5, view, n, "ring", radius)
        r15 = run(tau, 0.5, view, n, "ring", math.radians(15))
        print(f"tau {tau} view {view}: exact {ex:.5f}, straight {st / ex - 1:+.3f}, ring {r / ex - 1:+.3f}, "
              f"ring15 {r15 / ex - 1:+.3f}", flush=True)
