#!/usr/bin/env python3
"""The DISORT slab's reflected light by order, in the true medium and in the fast method's delta-M
scaled transport, by Monte Carlo: where the field's excess in backward views comes from.

A diagnosis of `fast_slab_every_angle_against_disort` (tests/clouds/render_validation.rs;
docs/frames.md, "DISORT slab at every listed angle", "(B)"). Plane-parallel slab, Henyey-Greenstein
g = 0.85, albedo 1, sun at mu0 = 0.5, the fast method's truncation f = g^3.5, g* = (g - f)/(1 - f),
r+ = max(p - (1 - f) HG(g*), 0) (f+ = its integral, 0.582). Collision estimators of the radiance
leaving the top towards the test's views (view zenith, azimuth from the sun's side as the test's
columns: 180 = the camera on the sun's side), split by the number n of smooth scatterings (classes
n = 0, 1, 2, 3, 4-5, 6-9, >= 10; the last scattering's part classed as the path tracer of
`slab_split_by_smooth_scatterings_against_disort` does). Modes:

- true: the true medium (HG g, optical thickness tau), each collision classed as within the peak
  with probability r+/p (the reference; its total matches DISORT within the noise);
- scaled: the delta-M scaled transport the field's photon pass flies (extinction (1 - f), HG(g*),
  the peak a forward delta), the last scattering with HG(g*); order k counts as n = k;
- scaledK: the same transport, the last scattering with the true smooth part (p - r+)/(1 - f);
- scaledP: transport with the true smooth part (p - r+)/(1 - f+) and extinction (1 - f+) (the peak
  a forward delta);
- scaledPD: as scaledP, and the peak's deflections (a Poisson number, mean f+/(1 - f+) per scaled
  free path, each drawn from r+) applied at the end of each free path, without displacement.
- scaledM: the photon pass's transport (`multiple/turns.rs`): the scaled collisions (extinction
  (1 - f)) scatter with (p - r+ + (f+ - f) r+/f+)/(1 - f), and the peak's delta part turns the photon
  between them (each event of the true medium a turn with probability f, drawn from r+/f+, at its
  place); the last scattering with HG(g*) at the scaled collisions, as the field's reconstruction.

numpy only. Usage: python3 tools/cloud_slab_field_orders.py TAU PHOTONS MODE [SEED]
(tau 8: 200000 photons, a few minutes; tau 32 true: 60000, about ten).
"""
import math, sys
import numpy as np
G = 0.85; F = G**3.5; GS = (G - F) / (1 - F)
tau = float(sys.argv[1]); N = int(sys.argv[2]); mode = sys.argv[3]  # 'scaled' | 'true' | 'scaledP' (transport with (p-r+)/(1-f+))
mu0 = 0.5; rng = np.random.default_rng(int(sys.argv[4]) if len(sys.argv) > 4 else 1)
sun = np.array([math.sqrt(1 - mu0**2), 0.0, -mu0])
def hg(g, m): return (1 - g*g) / (4*np.pi*(1 + g*g - 2*g*m)**1.5)
def sample_hg(g, u):
    s = (1 - g*g) / (1 - g + 2*g*u); return (1 + g*g - s*s) / (2*g)
def rplus(m): return np.maximum(hg(G, m) - (1 - F)*hg(GS, m), 0)
def turn(d, m):
    phi = 2*np.pi*rng.random(len(m)); sn = np.sqrt(np.maximum(0, 1 - m*m))
    helper = np.zeros_like(d); nz = np.abs(d[:, 2]) >= 0.9
    helper[~nz, 2] = 1; helper[nz, 0] = 1
    t = np.cross(d, helper); t /= np.linalg.norm(t, axis=1)[:, None]; b = np.cross(d, t)
    return d*m[:, None] + (t*np.cos(phi)[:, None] + b*np.sin(phi)[:, None])*sn[:, None]
views = []
for vz, az in [(75, 180), (75, 0), (75, 90), (60, 180), (0, 0)]:
    mu = math.cos(math.radians(vz)); s = math.sin(math.radians(vz))
    sx = 1.0 if az == 0 else (-1.0 if az == 180 else 0.0); sy = 1.0 if az == 90 else 0.0
    views.append((vz, az, np.array([s*sx, s*sy, mu])))
NC = 7  # classes 0,1,2,3,4-5,6-9,10+
def cls(n): return np.select([n <= 3, n <= 5, n <= 9], [n, 4, 5], 6)
acc = np.zeros((len(views), NC))
# rejection sampler for the smooth remainder (p - r+)/(1-f+): sample HG(g*) and accept with min(p,(1-f)HGs)/((1-f)HGs)
FP = 0.582
if mode in ('scaled', 'scaledK'):
    T = tau*(1 - F); gph = GS
elif mode == 'scaledM':
    T = tau*(1 - F); gph = None
elif mode in ('scaledP', 'scaledPD'):
    T = tau*(1 - FP); gph = None
else:
    T = tau; gph = G
z = np.zeros(N); d = np.tile(sun, (N, 1)); n = np.zeros(N, int); alive = np.ones(N, bool)
for it in range(100000):
    idx = np.nonzero(alive)[0]
    if len(idx) == 0: break
    dd = d[idx]; t = -np.log(1 - rng.random(len(idx)))
    if mode == 'scaledM':
        # once scattered, every event of the true medium: free paths (1 - f) scaled on average
        t = np.where(n[idx] > 0, t*(1 - F), t)
        isturn = (n[idx] > 0) & (rng.random(len(idx)) < F)
    z1 = z[idx] - dd[:, 2]*t
    inside = (z1 >= 0) & (z1 <= T)
    alive[idx[~inside]] = False
    ii = idx[inside]; z[ii] = z1[inside]; dn = d[ii]; zz = z[ii]; nn = n[ii]
    if mode == 'scaledM':
        tt = isturn[inside]; ti = ii[tt]
        if len(ti):
            c = np.empty(len(ti)); todo = np.arange(len(ti))
            while len(todo):
                cc = sample_hg(G, rng.random(len(todo)))
                ok = rng.random(len(todo))*hg(G, cc) <= rplus(cc)
                c[todo[ok]] = cc[ok]; todo = todo[~ok]
            d[ti] = turn(d[ti], c)
        ii = ii[~tt]; dn = d[ii]; zz = z[ii]; nn = n[ii]
    if mode == 'scaledPD':
        # peak deflections over the flight just ended (no displacement): Poisson(f+/(1-f+) t)
        k = rng.poisson(FP/(1 - FP)*t[inside])
        while (k > 0).any():
            sel = np.nonzero(k > 0)[0]
            c = np.empty(len(sel)); todo = np.arange(len(sel))
            while len(todo):
                cc = sample_hg(G, rng.random(len(todo)))
                ok = rng.random(len(todo))*hg(G, cc) <= rplus(cc)
                c[todo[ok]] = cc[ok]; todo = todo[~ok]
            dn[sel] = turn(dn[sel], c); k[sel] -= 1
    for vi, (_, _, o) in enumerate(views):
        mu = o[2]; m = dn @ o; att = np.exp(-zz/mu)/mu
        if mode == 'true':
            pk = rplus(m); allp = hg(G, m)
            np.add.at(acc[vi], cls(nn), pk*att); np.add.at(acc[vi], cls(nn + 1), (allp - pk)*att)
        elif mode in ('scaled', 'scaledM'):
            np.add.at(acc[vi], cls(nn + 1), hg(GS, m)*att)
        elif mode == 'scaledK':
            np.add.at(acc[vi], cls(nn + 1), np.minimum(hg(G, m), (1 - F)*hg(GS, m))/(1 - F)*att)
        else:
            ps = np.minimum(hg(G, m), (1 - F)*hg(GS, m))/(1 - FP)
            np.add.at(acc[vi], cls(nn + 1), ps*att)
    if mode in ('scaledP', 'scaledPD'):
        m = np.empty(len(ii)); todo = np.arange(len(ii))
        while len(todo):
            c = sample_hg(GS, rng.random(len(todo)))
            ok = rng.random(len(todo))*(1 - F)*hg(GS, c) <= np.minimum(hg(G, c), (1 - F)*hg(GS, c))
            m[todo[ok]] = c[ok]; todo = todo[~ok]
        d[ii] = turn(dn, m); n[ii] += 1
    elif mode == 'scaledM':
        # p drawn, classed by r+/p; a peak draw kept with (f+ - f)/f+, else drawn again
        m = np.empty(len(ii)); todo = np.arange(len(ii))
        while len(todo):
            c = sample_hg(G, rng.random(len(todo)))
            pk = rng.random(len(todo))*hg(G, c) < rplus(c)
            ok = ~pk | (rng.random(len(todo)) < (FP - F)/FP)
            m[todo[ok]] = c[ok]; todo = todo[~ok]
        d[ii] = turn(dn, m); n[ii] += 1
    else:
        m = sample_hg(gph, rng.random(len(ii)))
        if mode == 'true':
            smooth = rng.random(len(ii))*hg(G, m) >= rplus(m)
            n[ii] += smooth
        else:
            n[ii] += 1
        d[ii] = turn(dn, m)
acc *= mu0 / N
print(f"{mode} tau {tau} N {N}: classes 0,1,2,3,4-5,6-9,10+")
for vi, (vz, az, o) in enumerate(views):
    a = acc[vi]
    print(f"[{vz} {az}] total {a.sum():.5f} n<=1 {a[:2].sum():.5f} n>=2 {a[2:].sum():.5f} | " + " ".join(f"{x:.5f}" for x in a))
