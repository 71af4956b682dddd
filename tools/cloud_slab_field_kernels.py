#!/usr/bin/env python3
"""The fast method's delta-M scaled transport in the DISORT slab, reconstructed as the frame does:
the orders >= 2 leaving the top towards the test's views, exact against the 4 cells' tallies.

A diagnosis of `fast_slab_every_angle_against_disort` (docs/frames.md, "The backward views' field,
by order"). Plane-parallel slab, g = 0.85, f = g^3.5, g* = (g - f)/(1 - f), sun at mu0 = 0.5;
photons fly the scaled transport (extinction (1 - f), HG(g*)) as the field's photon pass does. Printed
per view (zenith, azimuth from the sun's side; 180 = the camera on the sun's side):
- exact: collision estimator of the orders >= 2 (HG(g*) last);
- layer-exact-kernel: the source averaged over each of the slab's 4 cells (track lengths weighted by
  HG(g*) towards the view), seen through exp(-z/mu);
- P3 ...: the 4 cells' radiance moments to l = 3 convolved with the named Legendre moments (the
  frame's view kernel is (g^l - f)/(1 - f)).

numpy only. Usage: python3 tools/cloud_slab_field_kernels.py TAU PHOTONS (tau 8: 200000, a few minutes)
"""
import math, sys
import numpy as np
G = 0.85; F = G**3.5; GS = (G - F) / (1 - F)
tau = float(sys.argv[1]) if len(sys.argv) > 1 else 8.0
N = int(sys.argv[2]) if len(sys.argv) > 2 else 200000
NL = 4
ts = tau * (1 - F)  # scaled optical thickness (albedo 1)
mu0 = 0.5
sun = np.array([math.sqrt(1 - mu0**2), 0.0, -mu0])  # travel: +x azimuth, downward
rng = np.random.default_rng(1)

def hg(g, m):
    return (1 - g*g) / (4*np.pi*(1 + g*g - 2*g*m)**1.5)

def sample_hg(g, u):
    s = (1 - g*g) / (1 - g + 2*g*u)
    return (1 + g*g - s*s) / (2*g)

def turn(d, m):
    phi = 2*np.pi*rng.random(len(m)); sn = np.sqrt(np.maximum(0, 1 - m*m))
    helper = np.zeros_like(d); nz = np.abs(d[:, 2]) >= 0.9
    helper[~nz, 2] = 1; helper[nz, 0] = 1
    t = np.cross(d, helper); t /= np.linalg.norm(t, axis=1)[:, None]
    b = np.cross(d, t)
    return d*m[:, None] + (t*np.cos(phi)[:, None] + b*np.sin(phi)[:, None])*sn[:, None]

def real_sh(d):
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    c = [0.28209479177387814, 0.4886025119029199, 1.0925484305920792, 0.31539156525252005,
         0.5462742152960396, 0.5900435899266435, 2.890611442640554, 0.4570457994644658, 0.3731763325901154, 1.445305721320277]
    return np.stack([np.full_like(x, c[0]), c[1]*y, c[1]*z, c[1]*x,
                     c[2]*x*y, c[2]*y*z, c[3]*(3*z*z-1), c[2]*x*z, c[4]*(x*x-y*y),
                     c[5]*y*(3*x*x-y*y), c[6]*x*y*z, c[7]*y*(5*z*z-1), c[8]*z*(5*z*z-3), c[7]*x*(5*z*z-1), c[9]*z*(x*x-y*y), c[5]*x*(x*x-3*y*y)], axis=1)
LDEG = np.array([0,1,1,1,2,2,2,2,2,3,3,3,3,3,3,3])

# Views: (zenith, azimuth from the sun's side); the sun travels along +x, so azimuth 0 (the camera
# away from the sun, looking towards it) is light leaving along +x, 180 along -x.
views = []
for vz, az in [(75, 180), (75, 0), (75, 90), (60, 180), (60, 0), (0, 0)]:
    mu = math.cos(math.radians(vz)); s = math.sin(math.radians(vz))
    sx = 1.0 if az == 0 else (-1.0 if az == 180 else 0.0); sy = 1.0 if az == 90 else 0.0
    views.append((vz, az, np.array([s*sx, s*sy, mu])))
dz = ts / NL
# tallies
coll = np.zeros(len(views)); trk_exact = np.zeros((len(views), NL)); mom = np.zeros((NL, 16))
pos_z = np.zeros(N); d = np.tile(sun, (N, 1)); w = np.ones(N); nsc = np.zeros(N, int); alive = np.ones(N, bool)
for it in range(2000):
    idx = np.nonzero(alive)[0]
    if len(idx) == 0: break
    z0 = pos_z[idx]; dd = d[idx]; t = -np.log(1 - rng.random(len(idx)))
    z1 = z0 - dd[:, 2]*t  # depth increases downward: dz_depth = -d_z * t
    # track tallies for scattered photons (nsc >= 1)
    sc = nsc[idx] >= 1
    zc0 = np.clip(z0, 0, ts); zc1 = np.clip(z1, 0, ts)
    for L in range(NL):
        a, b = L*dz, (L+1)*dz
        lo = np.minimum(zc0, zc1); hi = np.maximum(zc0, zc1)
        ov = np.clip(np.minimum(hi, b) - np.maximum(lo, a), 0, None)
        mz = np.abs(dd[:, 2]); tl = np.where(mz > 1e-9, ov/np.maximum(mz, 1e-9), np.where((z0 >= a) & (z0 < b), t, 0))
        tl = tl * sc
        if tl.any():
            mom[L] += (tl[:, None] * real_sh(dd)).sum(0)
            for vi, (_, _, o) in enumerate(views):
                trk_exact[vi, L] += (tl * hg(GS, dd @ o)).sum()
    inside = (z1 >= 0) & (z1 <= ts)
    alive[idx[~inside]] = False
    ii = idx[inside]; pos_z[ii] = z1[inside]
    # collision estimator for photons that already scattered once (this collision makes order >= 2)
    dn = d[ii]; zz = pos_z[ii]; ok = nsc[ii] >= 1
    for vi, (_, _, o) in enumerate(views):
        mu = o[2]
        coll[vi] += (ok * hg(GS, dn @ o) * np.exp(-zz/mu) / mu).sum()
    m = sample_hg(GS, rng.random(len(ii)))
    d[ii] = turn(dn, m); nsc[ii] += 1
# normalisation: photons per unit horizontal area = mu0 (unit normal irradiance) / N
norm = mu0 / N
print(f"tau {tau} scaled {ts:.3f} N {N}")
# J in layer L towards o: exact = trk_exact / (dz), the fluence-weighted phase; P3: sum_l (2l+1)... real SH: J = sum_lm p_l L_lm Y_lm(o) where L_lm = mom/(dz)
for vi, (vz, az, o) in enumerate(views):
    mu = o[2]
    Y = real_sh(o[None, :])[0]
    # view weight per layer: ∫_layer e^{-z/mu} dz/mu (layer constant source)
    wts = np.array([math.exp(-L*dz/mu) - math.exp(-(L+1)*dz/mu) for L in range(NL)])
    ex = coll[vi]*norm
    lay = (trk_exact[vi]/dz*wts).sum()*norm
    res = [f"[{vz} {az}] exact {ex:.5f} layer-exact-kernel {lay:.5f} ({(lay/ex-1)*100:+.1f} %)"]
    for name, pl in [("HG g*^l", [GS**l for l in range(4)]), ("dM (g^l-f)/(1-f)", [(G**l - F)/(1-F) for l in range(4)]), ("smooth", [0.9644, 0.6571, 0.4353, 0.2826]), ("smooth l0=1", [1.0, 0.6571, 0.4353, 0.2826]), ("dM l3=.28", [1.0, 0.6542, 0.3603, 0.2826])]:
        Jl = np.array([(mom[L]/dz * np.array([pl[k] for k in LDEG]) * Y).sum() for L in range(NL)])
        Jl = np.maximum(Jl, 0)
        v = (Jl*wts).sum()*norm
        res.append(f"P3 {name} {v:.5f} ({(v/ex-1)*100:+.1f} %)")
    print("; ".join(res))
