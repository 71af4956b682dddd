#!/usr/bin/env python3
"""The fast cloud method's sun single scattering on a plane-parallel slab, by quadrature.

A diagnosis of the DISORT slab's views towards the sun (tests/clouds/render_validation.rs,
`slab_split_by_smooth_scatterings_against_disort`; docs/frames.md, "DISORT slab at every listed
angle"): the march's first orders (crates/render/src/march.rs, `Prepared::march`, with the peak
tables of crates/render/src/peak.rs) written out for a laterally infinite slab, split into the
smooth part (light of one smooth scattering, n = 1) and the part scattered last within the
truncated peak (n = 0), to set against the classed path tracer's classes and
tools/cloud_slab_peak_beam.py. Henyey-Greenstein g = 0.85, albedo 1, f = g^3.5, g* = (g - f)/(1 - f):

- the smooth part: omega p(theta) (p - r+)_eff/p at lambda = omega f+ (tau_sun + tau_view),
  through exp(-(1 - omega f+)(tau_sun + tau_view));
- the peak's part: omega p(theta) r+_eff/p at lambda = omega f+ tau_sun, through
  exp(-(1 - omega f+) tau_sun - tau_view);

tau_sun = z / mu0 and tau_view = z / mu_v the true optical depths at depth z, per unit normal
irradiance. It reads the 4-voxel slab's fast single scattering within 1-3 % (the march's
voxels and sun-path interpolation are left out).

numpy only; seconds. Usage: python3 tools/cloud_slab_fast_first_orders.py
"""
import math

import numpy as np

G = 0.85
F = G**3.5
GS = (G - F) / (1 - F)
L_MAX = 384
N_QUAD = 8192


def hg(g, m):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * m) ** 1.5)


def legendre(x, order):
    x = np.atleast_1d(np.asarray(x, float))
    out = np.zeros((order + 1, x.size))
    out[0] = 1
    out[1] = x
    for k in range(2, order + 1):
        out[k] = ((2 * k - 1) * x * out[k - 1] - (k - 1) * out[k - 2]) / k
    return out


_u = (np.arange(N_QUAD) + 0.5) / N_QUAD
_mu = 1 - 2 * _u * _u
_dmu = 4 * _u / N_QUAD
_pq = legendre(_mu, L_MAX)
_p = hg(G, _mu)
_r = np.maximum(_p - (1 - F) * hg(GS, _mu), 0)
P_L = (2 * np.pi * _p * _dmu * _pq).sum(1)
H_L = (2 * np.pi * _r * _dmu * _pq).sum(1)
F_PLUS = H_L[0]
_ORDERS = np.arange(L_MAX + 1)


def ratios(cos_theta, lam):
    """(p - r+)_eff/p and r+_eff/p at the scattering angle's cosine for lambda = omega f tau
    (the peak's rate f+/f applied), as peak.rs tabulates them."""
    c = (2 * _ORDERS + 1) / (4 * np.pi) * legendre(cos_theta, L_MAX)[:, 0]
    terms, peak = c * P_L, c * H_L
    spread = peak + c * (1 - F) * GS**_ORDERS
    held = (spread - terms).sum()
    s0 = terms.sum()
    decay = np.exp(-np.outer(lam, (F_PLUS / F) * (1 - H_L / F_PLUS)))
    full = np.maximum(((decay * spread).sum(1) - held) / s0, 0)
    last = np.clip((decay * peak).sum(1) / s0, 0, full)
    return full - last, last


def first_orders(tau, vz, raz, mu0=0.5, n=4000):
    """(smooth part, peak's part) of the reflected radiance at view zenith vz and azimuth raz
    from the sun's side (tests/data/cloud_slab_disort.json's conventions)."""
    muv = math.cos(math.radians(vz))
    ct = -mu0 * muv + math.sqrt(1 - mu0 * mu0) * math.sin(math.radians(vz)) * math.cos(math.radians(raz))
    z = (np.arange(n) + 0.5) / n * tau
    ts, tv = z / mu0, z / muv
    rest = 1 - F_PLUS
    smooth, _ = ratios(ct, F * (ts + tv))
    _, last = ratios(ct, F * ts)
    w = hg(G, ct) * tau / n / muv
    return (w * smooth * np.exp(-rest * (ts + tv))).sum(), (w * last * np.exp(-rest * ts - tv)).sum()


if __name__ == "__main__":
    for tau in (1.0, 8.0):
        for vz, raz in [(0, 0), (60, 0), (60, 180), (75, 0), (75, 90), (75, 180)]:
            s, p = first_orders(tau, vz, raz)
            print(f"tau {tau} view [{vz} {raz}]: smooth part (n = 1) {s:.5f}, peak's part (n = 0) {p:.5f}, sum {s + p:.5f}")
