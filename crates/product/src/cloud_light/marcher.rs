//! The reference marcher of a pre-lit cloud volume: what a real-time client does with the
//! export, in Rust, from the decoded [`CloudLight`] alone (no call into the renderer's light
//! computation; it shares only two closed-form integrals: the exact per-step weight of the sun
//! term, [`skybake_render::march::sun_step`], and the field's build-up below a face,
//! [`skybake_render::multiple::face_build_up`], over the frame's quadrature of the inward
//! hemisphere). Per pixel it marches the view ray through the box in steps of the export's
//! `step_voxels`, interpolating the per-voxel textures trilinearly at each step and evaluating
//! the source towards the camera from the direction tables; steps over voxels of many optical
//! depths are taken in sub-steps with the field's skin tallies (docs/cloud-light.md, "Thick
//! steps"), and the sun's path is continued beyond the outermost voxel centres, as the fast
//! frame does them; the fast frame's march
//! (`skybake_render::march`, the TMS form of Nakajima & Tanaka 1988, eqs 13–15, with the δ-M
//! scaling of Wiscombe 1977) is what it reproduces, with the sky and multiple-scattering sources
//! evaluated at each sample rather than at voxel centres first. The field seen through the
//! surface voxels' faces depends on where the camera is: [`Marcher::new`] takes the
//! [`Viewer`] and computes it per surface voxel first, as the frame does (docs/cloud-light.md,
//! "Faces").

use glam::DVec3;
use skybake_render::march::sun_step;
use std::f64::consts::PI;

use super::{
    surface_voxel, CloudLight, MAX_SUB_STEPS, SKY_ELEMENTS, SUN_NEAR_INTERVALS, SUN_NEAR_VOXELS,
};
use skybake_physics::phase::orthonormal_basis;
use skybake_render::march::{MARCH_CUTOFF, THICK_STEP};
use skybake_render::multiple::{
    face_build_up, face_outward_profiles, face_outward_ratio, FACE_MU_NODES as MU_NODES,
    FACE_N_PHI as N_PHI, FACE_OUTWARD_MAX_DEPTH, ONCE_MOMENTS,
};

/// Where a client's ray leaves the cloud, per wavelength: the cloud's radiance I and its true
/// transmittance T_c (the background is seen as T_c·B), and the distance of the cloud's front.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudSample {
    pub radiance: Vec<f64>,
    pub transmittance: Vec<f64>,
    pub front_m: Option<f64>,
}

/// Where the camera looks from: the fast frame takes each voxel's source towards the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Viewer {
    /// A camera at this point (pinhole, fisheye): voxel centre p is seen along p − point.
    Point(DVec3),
    /// Every voxel seen along this direction (orthographic).
    Direction(DVec3),
}

/// The marcher over one decoded export, for one viewer.
pub struct Marcher<'a> {
    cl: &'a CloudLight,
    lo: DVec3,
    hi: DVec3,
    /// The largest density of the grid (whether any step can be thick).
    rho_max: f64,
    /// Per wavelength and voxel, the field's source lowered by seeing it through the voxel's
    /// face towards the viewer, W m⁻² sr⁻¹ nm⁻¹ per unit scaled extinction (docs/cloud-light.md,
    /// "Faces"); empty without the export's faces.
    face: Vec<Vec<f32>>,
    /// Per wavelength and voxel, the sun's once-scattered light's change of the field's
    /// source towards the viewer, max(…) of Σ_lm K_lm·Y_lm(−d) at voxels not seen through a
    /// face, 0 at those that are (docs/cloud-light.md); empty without `once_scattered.exr`.
    once: Vec<Vec<f32>>,
}

/// What every step of one ray shares (see [`Marcher::march`]).
struct Ray<'r> {
    o: DVec3,
    d: DVec3,
    cos_sun: f64,
    sun_on: bool,
    /// ω/s·E_sun·p(θ) per wavelength.
    sun_src: &'r [f64],
    /// The sky-element table at the view direction, `[entry·n_λ + λ]`.
    sky: &'r [f64],
    /// Y_lm(−d).
    ylm: &'r [f64; 25],
}

/// The radiance and transmittances along one ray, per wavelength.
struct State {
    ia: Vec<f64>,
    tc: Vec<f64>,
    ts: Vec<f64>,
    /// T⁺, the transmittance of the sun's once-scattered light (k·s⁺).
    tp: Vec<f64>,
    /// The true optical depth from the ray's start.
    tv: Vec<f64>,
}

/// Real orthonormal spherical harmonics up to l = 3 in the manifest's order (Sloan 2008,
/// appendix A2, in its Cartesian forms with x² + y² + z² kept); higher orders are not needed by
/// exports of angular order ≤ 3 (the δ-M scaled moments vanish from l = 4 on).
fn sh(d: DVec3, out: &mut [f64; 25]) {
    let (x, y, z) = (d.x, d.y, d.z);
    out[0] = 0.282_094_791_773_878_14;
    out[1] = 0.488_602_511_902_919_9 * y;
    out[2] = 0.488_602_511_902_919_9 * z;
    out[3] = 0.488_602_511_902_919_9 * x;
    out[4] = 1.092_548_430_592_079_2 * x * y;
    out[5] = 1.092_548_430_592_079_2 * y * z;
    out[6] = 0.315_391_565_252_520_05 * (3.0 * z * z - 1.0);
    out[7] = 1.092_548_430_592_079_2 * x * z;
    out[8] = 0.546_274_215_296_039_6 * (x * x - y * y);
    let (x2, y2, z2) = (x * x, y * y, z * z);
    out[9] = 0.590_043_589_926_643_5 * y * (3.0 * x2 - y2);
    out[10] = 2.890_611_442_640_554 * x * y * z;
    out[11] = 0.457_045_799_464_465_8 * y * (4.0 * z2 - x2 - y2);
    out[12] = 0.373_176_332_590_115_4 * z * (2.0 * z2 - 3.0 * x2 - 3.0 * y2);
    out[13] = 0.457_045_799_464_465_8 * x * (4.0 * z2 - x2 - y2);
    out[14] = 1.445_305_721_320_277 * z * (x2 - y2);
    out[15] = 0.590_043_589_926_643_5 * x * (x2 - 3.0 * y2);
}

impl<'a> Marcher<'a> {
    /// The marcher of `cl` for a camera at `viewer` (the field seen through the surface
    /// voxels' faces towards it is computed here). Refuses an export whose multiple-scattering
    /// order this marcher does not evaluate.
    pub fn new(cl: &'a CloudLight, viewer: Viewer) -> crate::Result<Self> {
        if cl.ms_order.is_some_and(|o| o > 3) {
            return Err(crate::Error::out_of_range(
                "settings.angular_order",
                cl.ms_order.unwrap_or(0),
                "0 to 3 (the reference marcher's harmonics)",
            ));
        }
        let lo = DVec3::from_array(cl.origin_m);
        let n = DVec3::new(cl.dims[0] as f64, cl.dims[1] as f64, cl.dims[2] as f64);
        let mut out = Self {
            cl,
            lo,
            hi: lo + n * cl.voxel_size_m,
            rho_max: cl.density.iter().fold(0.0f64, |m, &r| m.max(r as f64)),
            face: Vec::new(),
            once: Vec::new(),
        };
        let dir_at = |p: DVec3| match viewer {
            Viewer::Point(o) => (p - o).normalize_or(DVec3::Z),
            Viewer::Direction(d) => d.normalize_or(DVec3::Z),
        };
        if !cl.once.is_empty() {
            let [nx, ny, nz] = cl.dims;
            let n_l = cl.n_l();
            let mut once = vec![vec![0f32; nx * ny * nz]; n_l];
            let mut ylm = [0.0; 25];
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let idx = (z * ny + y) * nx + x;
                        if (0..n_l * ONCE_MOMENTS).all(|i| cl.once[i][idx] == 0.0) {
                            continue;
                        }
                        let h = cl.voxel_size_m;
                        let p = lo + DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5) * h;
                        let d = dir_at(p);
                        if out.view_face([x, y, z], d).is_some() {
                            continue;
                        }
                        sh(-d, &mut ylm);
                        for (l, o) in once.iter_mut().enumerate() {
                            o[idx] = (0..ONCE_MOMENTS)
                                .map(|m| cl.once[l * ONCE_MOMENTS + m][idx] as f64 * ylm[m])
                                .sum::<f64>() as f32;
                        }
                    }
                }
            }
            out.once = once;
        }
        if cl.faces.is_some() {
            let [nx, ny, nz] = cl.dims;
            let n_l = cl.n_l();
            let mut face = vec![vec![0f32; nx * ny * nz]; n_l];
            let mut low = vec![0.0; n_l];
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        if !surface_voxel(&cl.density, cl.dims, [x, y, z]) {
                            continue;
                        }
                        let h = cl.voxel_size_m;
                        let p = lo + DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5) * h;
                        let d = dir_at(p);
                        out.face_lowering([x, y, z], d, &mut low);
                        let idx = (z * ny + y) * nx + x;
                        for l in 0..n_l {
                            face[l][idx] = low[l] as f32;
                        }
                    }
                }
            }
            out.face = face;
        }
        Ok(out)
    }

    /// The face of voxel `ijk` a viewer looking along `d` sees it through, as the frame takes
    /// it: of the faces towards the viewer whose neighbour is empty (or beyond the grid), the one
    /// the view crosses most squarely, with its |cos|; `None` for an empty voxel or none.
    fn view_face(&self, ijk: [usize; 3], d: DVec3) -> Option<(usize, f64)> {
        let cl = self.cl;
        let dims = cl.dims;
        let at = |q: [usize; 3]| cl.density[(q[2] * dims[1] + q[1]) * dims[0] + q[0]] as f64;
        if at(ijk) <= 0.0 {
            return None;
        }
        let mut best: Option<(usize, f64)> = None;
        for a in 0..3 {
            let up = d[a] < 0.0;
            let mv = d[a].abs();
            if mv <= 0.0 {
                continue;
            }
            let mut q = ijk;
            let empty = if up {
                q[a] += 1;
                ijk[a] + 1 >= dims[a] || at(q) <= 0.0
            } else {
                ijk[a] == 0 || {
                    q[a] -= 1;
                    at(q) <= 0.0
                }
            };
            if empty && best.is_none_or(|(_, m)| mv > m) {
                best = Some((2 * a + usize::from(up), mv));
            }
        }
        best
    }

    /// How much seeing the field through the face of surface voxel `ijk` towards a viewer
    /// looking along `d` lowers its source, per wavelength (docs/cloud-light.md, "Faces"): 0
    /// where the voxel's neighbour towards the viewer holds cloud; else, through the face the
    /// view crosses most squarely of those with an empty neighbour, the inward hemisphere's
    /// radiance L(ω') weighted by the scaled phase function towards the viewer and by
    /// 1 − r(μ'), r = the view-weighted build-up over the voxel's depth over the cell's mean
    /// (the formal solution below a face, Chandrasekhar 1960 §1.8), for the scattered light
    /// (uniform in depth) and the sun's first scattering in the scaled problem (Henyey-Greenstein
    /// g* = p*_1, falling as the scaled beam).
    fn face_lowering(&self, ijk: [usize; 3], d: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let cl = self.cl;
        let Some(faces) = &cl.faces else {
            return;
        };
        let Some(order) = cl.ms_order else {
            return;
        };
        let dims = cl.dims;
        let idx = (ijk[2] * dims[1] + ijk[1]) * dims[0] + ijk[0];
        let rho = cl.density[idx] as f64;
        let Some((face, _)) = self.view_face(ijk, d) else {
            return;
        };
        let a = face / 2;
        let normal = {
            let mut n = DVec3::ZERO;
            n[a] = if face % 2 == 0 { -1.0 } else { 1.0 };
            n
        };
        let moments = (order + 1) * (order + 1);
        let wo = -d;
        let mv = wo.dot(normal);
        let mut ylm_o = [0.0; 25];
        sh(wo, &mut ylm_o);
        let travel = -DVec3::from_array(cl.sun_direction);
        let sun_on = cl.sun_irradiance.iter().any(|&e| e > 0.0);
        let mu0 = if sun_on { travel.dot(-normal) } else { 0.0 };
        let sun_used = sun_on && mu0 > 0.05;
        let h = cl.voxel_size_m;
        let face_density_m = if sun_used {
            (cl.sun_path[idx] as f64 - 0.5 * rho * h / mu0.max(0.05)).max(0.0)
        } else {
            0.0
        };
        let (t1, t2) = orthonormal_basis(-normal);
        let (k, s) = (&cl.extinction_per_density_m, &cl.extinction_scale);
        for (l, o) in out.iter_mut().enumerate() {
            let pl = &faces.scaled_phase_moments[l];
            let v: Vec<f64> = (0..moments)
                .map(|m| faces.radiance[l * moments + m][idx] as f64)
                .collect();
            let mut j = 0.0;
            for (ord, p_l) in pl.iter().enumerate().take(order + 1) {
                for m in ord * ord..(ord + 1) * (ord + 1) {
                    j += p_l * v[m] * ylm_o[m];
                }
            }
            let ks = k[l] * s[l];
            let (tv, tc) = (
                ks * rho * h,
                ks * faces.cell_density[idx] as f64 * faces.cell_size_m[a],
            );
            if mv <= 0.0 || tv < 1e-4 {
                continue;
            }
            let g = pl.get(1).copied().unwrap_or(0.0);
            let e_face = if sun_used {
                cl.sun_irradiance[l] * (-ks * face_density_m).exp()
            } else {
                0.0
            };
            let mut deficit = 0.0;
            let mut ylm = [0.0; 25];
            for &(mu, w) in &MU_NODES {
                let [u_c, u_v, e_c, e_v] = face_build_up(mu, mv, mu0, tv, tc);
                let sin = (1.0 - mu * mu).max(0.0).sqrt();
                for jphi in 0..N_PHI {
                    let phi = 2.0 * PI * (jphi as f64 + 0.5) / N_PHI as f64;
                    let dir = -normal * mu + (t1 * phi.cos() + t2 * phi.sin()) * sin;
                    sh(dir, &mut ylm);
                    let (mut radiance, mut source) = (0.0, 0.0);
                    for (ord, p_l) in pl.iter().enumerate().take(order + 1) {
                        let mut sum = 0.0;
                        for m in ord * ord..(ord + 1) * (ord + 1) {
                            sum += v[m] * ylm[m];
                        }
                        radiance += sum;
                        source += p_l * sum;
                    }
                    if radiance <= 0.0 {
                        continue;
                    }
                    let first = if sun_used {
                        let x = (1.0 + g * g - 2.0 * g * travel.dot(dir)).max(1e-12);
                        e_face * (1.0 - g * g) / (4.0 * PI * x * x.sqrt())
                    } else {
                        0.0
                    };
                    let source = source.max(0.0);
                    let den = source * u_c + first * e_c;
                    if den <= 0.0 {
                        continue;
                    }
                    let r = ((source * u_v + first * e_v) / den).clamp(0.0, 2.0);
                    // p*(cos θ) = Σ_l (2l + 1)/(4π) p*_l P_l(cos θ).
                    let c = wo.dot(dir);
                    let legendre = [
                        1.0,
                        c,
                        0.5 * (3.0 * c * c - 1.0),
                        0.5 * c * (5.0 * c * c - 3.0),
                    ];
                    let phase: f64 = pl
                        .iter()
                        .zip(legendre)
                        .enumerate()
                        .map(|(ord, (p_l, leg))| (2 * ord + 1) as f64 * p_l * leg)
                        .sum();
                    deficit +=
                        w * 2.0 * PI / N_PHI as f64 * phase / (4.0 * PI) * (1.0 - r) * radiance;
                }
            }
            if tv < FACE_OUTWARD_MAX_DEPTH {
                deficit += outward_lowering(OutwardFace {
                    normal,
                    basis: (t1, t2),
                    wo,
                    mv,
                    tv,
                    tc,
                    pl,
                    v: &v,
                    order,
                    sun: sun_used.then_some((travel, mu0, e_face)),
                });
            }
            *o = faces.scaled_albedo[l] * (j.max(0.0) - (j - deficit).max(0.0));
        }
    }

    /// Trilinear weights of the 8 voxels around `p` (centres at origin + h·(i + ½); clamped to
    /// the outermost centres inside the box); `None` outside the box.
    fn weights(&self, p: DVec3) -> Option<[(usize, f64); 8]> {
        let local = (p - self.lo) / self.cl.voxel_size_m;
        let n = self.cl.dims;
        let (mut i0, mut i1, mut f) = ([0usize; 3], [0usize; 3], [0f64; 3]);
        for a in 0..3 {
            let l = local[a];
            if !(l >= 0.0 && l <= n[a] as f64) {
                return None;
            }
            let c = (l - 0.5).clamp(0.0, (n[a] - 1) as f64);
            i0[a] = (c.floor() as usize).min(n[a] - 1);
            i1[a] = (i0[a] + 1).min(n[a] - 1);
            f[a] = c - i0[a] as f64;
        }
        let mut out = [(0usize, 0f64); 8];
        for (corner, o) in out.iter_mut().enumerate() {
            let pick = |a: usize, bit: usize| {
                if corner & bit == 0 {
                    (i0[a], 1.0 - f[a])
                } else {
                    (i1[a], f[a])
                }
            };
            let ((x, wx), (y, wy), (z, wz)) = (pick(0, 1), pick(1, 2), pick(2, 4));
            *o = ((z * n[1] + y) * n[0] + x, wx * wy * wz);
        }
        Some(out)
    }

    fn interp(w: &[(usize, f64); 8], v: &[f32]) -> f64 {
        w.iter().map(|&(i, wi)| wi * v[i] as f64).sum()
    }

    /// The density at `p`, trilinear (0 outside the box).
    fn rho(&self, p: DVec3) -> f64 {
        self.weights(p)
            .map_or(0.0, |w| Self::interp(&w, &self.cl.density))
    }

    /// D_sun at `p`: trilinear between voxel centres, and between the outermost centres and
    /// the box's faces continued linearly from the two outermost centres along each axis that
    /// lies beyond them (not below 0), as the fast frame does: a cloud that fills its outer
    /// voxels keeps thinning towards the sun up to the face instead of holding the centre's
    /// path there. 0 outside the box.
    fn sun_path_at(&self, p: DVec3) -> f64 {
        let cl = self.cl;
        let Some(w) = self.weights(p) else {
            return 0.0;
        };
        let d = Self::interp(&w, &cl.sun_path);
        let h = cl.voxel_size_m;
        let local = (p - self.lo) / h;
        let mut out = d;
        for a in 0..3 {
            let n = cl.dims[a] as f64;
            if cl.dims[a] < 2 || (local[a] >= 0.5 && local[a] <= n - 0.5) {
                continue;
            }
            let (excess, inward) = if local[a] < 0.5 {
                (0.5 - local[a], 1.0)
            } else {
                (local[a] - (n - 0.5), -1.0)
            };
            // The next centre inwards along this axis.
            let mut q = p;
            q[a] += inward * (excess + 1.0) * h;
            let di = self
                .weights(q)
                .map_or(0.0, |w| Self::interp(&w, &cl.sun_path));
            out += excess * (d - di);
        }
        out.max(0.0)
    }

    /// D_sun at `p` resolved within the voxels next to it, for thick steps: the density
    /// integrated towards the sun over [`SUN_NEAR_VOXELS`] voxels (composite Simpson,
    /// [`SUN_NEAR_INTERVALS`] intervals; up to the box's face if nearer) plus
    /// [`Self::sun_path_at`] where that ends. Over a density ramp of many optical depths D
    /// grows quadratically between the centres, which the interpolation overestimates at the
    /// lit surface.
    fn sun_path_near(&self, p: DVec3, sun: DVec3) -> f64 {
        let reach = SUN_NEAR_VOXELS * self.cl.voxel_size_m;
        let exit = box_interval(p, sun, self.lo, self.hi).map_or(0.0, |(_, t1)| t1);
        let len = reach.min(exit);
        if len <= 0.0 {
            return 0.0;
        }
        let n = SUN_NEAR_INTERVALS;
        let dx = len / n as f64;
        let mut sum = 0.0;
        for k in 0..=n {
            let c = if k == 0 || k == n {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            };
            sum += c * self.rho(p + sun * (k as f64 * dx));
        }
        let tail = if exit > reach {
            self.sun_path_at(p + sun * reach)
        } else {
            0.0
        };
        sum * dx / 3.0 + tail
    }

    /// The sky-element table at view direction `d` (bilinear; elevation clamped, azimuth
    /// wrapped), `[entry·n_λ + λ]`. With `split_at_horizon`, rows on the other side of the
    /// horizon from `d` are not blended in (for E16, the environment radiance, which jumps there
    /// from sky to ground light; E00–E15 are smooth in d).
    fn sky_entries_split(&self, d: DVec3, split_at_horizon: bool, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let Some(t) = &self.cl.sky else {
            return;
        };
        let e = d.z.clamp(-1.0, 1.0).asin();
        let az = d.x.atan2(d.y).rem_euclid(2.0 * PI);
        let u = ((e + 0.5 * PI) / PI * (t.n_elev - 1) as f64).clamp(0.0, (t.n_elev - 1) as f64);
        let v = az / (2.0 * PI) * t.n_az as f64;
        let mut r0 = (u.floor() as usize).min(t.n_elev - 1);
        let mut r1 = (r0 + 1).min(t.n_elev - 1);
        let mut fr = u - r0 as f64;
        let elevation = |r: usize| -90.0 + 180.0 * r as f64 / (t.n_elev - 1) as f64;
        if split_at_horizon && elevation(r0) < 0.0 && elevation(r1) >= 0.0 {
            // d.z ≥ 0 is the sky's side (the renderer's convention).
            let r = if d.z >= 0.0 { r1 } else { r0 };
            (r0, r1, fr) = (r, r, 0.0);
        }
        let c0 = (v.floor() as usize) % t.n_az;
        let c1 = (c0 + 1) % t.n_az;
        let fc = v - v.floor();
        let corners = [
            (r0 * t.n_az + c0, (1.0 - fr) * (1.0 - fc)),
            (r0 * t.n_az + c1, (1.0 - fr) * fc),
            (r1 * t.n_az + c0, fr * (1.0 - fc)),
            (r1 * t.n_az + c1, fr * fc),
        ];
        for (o, ch) in out.iter_mut().zip(&t.values) {
            *o = corners.iter().map(|&(i, w)| w * ch[i] as f64).sum();
        }
    }

    /// [`Self::sky_entries_split`] without the split: what the fast frame interpolates.
    fn sky_entries(&self, d: DVec3, out: &mut [f64]) {
        self.sky_entries_split(d, false, out)
    }

    /// The phase function of wavelength `l` at cos θ (the table, linear in √(θ/π)).
    fn phase(&self, l: usize, cos_theta: f64) -> f64 {
        let t = &self.cl.phase[l];
        let n = t.len();
        let x = (cos_theta.clamp(-1.0, 1.0).acos() / PI).sqrt() * (n - 1) as f64;
        let i0 = (x.floor() as usize).min(n - 2);
        let f = x - i0 as f64;
        t[i0] as f64 * (1.0 - f) + t[i0 + 1] as f64 * f
    }

    /// The peak spread p_eff/p of wavelength `l` at cos θ and λ (bilinear, λ held beyond the
    /// table).
    /// The peak spread p_eff/p of wavelength `l` at cos θ and λ split into the part scattered
    /// last by the smooth remainder and the part scattered last within the peak (bilinear, λ
    /// held beyond the table): (smooth, peak).
    fn spread(&self, l: usize, cos_theta: f64, lambda: f64) -> (f64, f64) {
        let Some(p) = &self.cl.peak else {
            return (1.0, 0.0);
        };
        let x = cos_theta.clamp(-1.0, 1.0).acos().to_degrees() * (p.n_theta - 1) as f64 / 180.0;
        let i0 = (x.floor() as usize).min(p.n_theta - 2);
        let w1 = (x - i0 as f64).clamp(0.0, 1.0);
        let y =
            (lambda.max(0.0) / p.lambda_max * (p.n_lambda - 1) as f64).min((p.n_lambda - 1) as f64);
        let j0 = (y.floor() as usize).min(p.n_lambda - 2);
        let v = y - j0 as f64;
        let bilinear = |t: &[f32]| {
            let at = |i: usize, j: usize| t[i * p.n_lambda + j] as f64;
            let a = at(i0, j0) * (1.0 - v) + at(i0, j0 + 1) * v;
            let b = at(i0 + 1, j0) * (1.0 - v) + at(i0 + 1, j0 + 1) * v;
            a * (1.0 - w1) + b * w1
        };
        let (full, last) = (bilinear(&p.values[l]), bilinear(&p.last_in_peak[l]));
        (full - last, last)
    }

    /// The density and D_sun of the voxel holding `y` (0 outside the box).
    fn nearest(&self, y: DVec3) -> (f64, f64) {
        let cl = self.cl;
        let local = (y - self.lo) / cl.voxel_size_m;
        let (mut idx, mut stride) = (0usize, 1usize);
        for a in 0..3 {
            let v = local[a];
            if !(v >= 0.0 && v < cl.dims[a] as f64) {
                return (0.0, 0.0);
            }
            idx += (v as usize).min(cl.dims[a] - 1) * stride;
            stride *= cl.dims[a];
        }
        (cl.density[idx] as f64, cl.sun_path[idx] as f64)
    }

    /// The part of the spread scattered last within the peak at λ, wavelength `l`, for the
    /// step centred on `x` (as the fast frame's `march/turned.rs`; docs/cloud-light.md,
    /// "Marching the volume"): its turned part T = r⁺_eff(λ) − e^{−ωf⁺τ_s}·r⁺_eff(0) gathered
    /// along b = normalize(s + d) through the density and D_sun (bins of 1, 1, 2, 4, … 32
    /// voxels, each at its middle: trilinear in the first two, the nearest voxel beyond; up to
    /// the box's face; one path per thick step, at its middle; views within 90° of the sun
    /// only) instead of the straight line to the
    /// sun: r⁺_eff(λ) + (G − 1)·T, G = Σ ρᵢwᵢ·e^{−k⁺(D(yᵢ) + ∫ρ)} / (D·e^{−k⁺D}), T/D at a
    /// lit surface the table's slope at λ = 10⁻³.
    fn peak_turned(&self, ray: &Ray<'_>, x: DVec3, l: usize, lambda: f64, kp: f64) -> f64 {
        let cl = self.cl;
        let (_, now) = self.spread(l, ray.cos_sun, lambda);
        let (rate, k) = (cl.peak_rate[l], cl.extinction_per_density_m[l]);
        if ray.cos_sun <= 0.0 || now <= 0.0 || rate <= 0.0 || k <= 0.0 {
            return now;
        }
        let b = DVec3::from_array(cl.sun_direction) + ray.d;
        let len = b.length();
        let mut gathered = 0.0;
        let d_s = lambda / (rate * k);
        if len >= 1e-6 {
            let b = b / len;
            let exit = box_interval(x, b, self.lo, self.hi).map_or(0.0, |(_, t1)| t1);
            let h = cl.voxel_size_m;
            let (mut lo, mut width, mut cum) = (0.0, h, 0.0);
            for bin in 0..7 {
                if lo >= exit {
                    break;
                }
                let hi = (lo + width).min(exit);
                let w = hi - lo;
                let y = x + b * (lo + 0.5 * w);
                let (rho, d_sun) = if bin < 2 {
                    (self.rho(y), self.sun_path_at(y))
                } else {
                    self.nearest(y)
                };
                let path = d_sun + cum + 0.5 * rho * w;
                gathered += rho * w * (-kp * (path - d_s)).min(600.0).exp();
                cum += rho * w;
                lo = hi;
                if bin > 0 {
                    width *= 2.0;
                }
            }
        }
        let (_, first) = self.spread(l, ray.cos_sun, 0.0);
        let per_lambda = (1.0 - cl.first_extinction_scale[l]) / rate;
        let turned_at = |lam: f64, v: f64| v - (-lam * per_lambda).exp() * first;
        let lam_e = lambda.max(1e-3);
        let slope = if lam_e > lambda {
            turned_at(lam_e, self.spread(l, ray.cos_sun, lam_e).1)
        } else {
            turned_at(lambda, now)
        } / (lam_e / (rate * k));
        (now + gathered * slope - turned_at(lambda, now)).max(0.0)
    }

    /// Marches the ray from `o` along unit `d` through the cloud.
    pub fn march(&self, o: DVec3, d: DVec3) -> CloudSample {
        let cl = self.cl;
        let n_l = cl.n_l();
        let mut st = State {
            ia: vec![0.0; n_l],
            tc: vec![1.0; n_l],
            ts: vec![1.0; n_l],
            tp: vec![1.0; n_l],
            tv: vec![0.0; n_l],
        };
        let Some((t0, t1)) = box_interval(o, d, self.lo, self.hi) else {
            return CloudSample {
                radiance: st.ia,
                transmittance: st.tc,
                front_m: None,
            };
        };
        let sun = DVec3::from_array(cl.sun_direction);
        let cos_sun = sun.dot(d);
        let s = &cl.extinction_scale;
        let sun_src: Vec<f64> = (0..n_l)
            .map(|l| cl.albedo[l] / s[l] * cl.sun_irradiance[l] * self.phase(l, cos_sun))
            .collect();
        let sun_on = cl.sun_irradiance.iter().any(|&e| e > 0.0);
        let mut sky = vec![0.0; SKY_ELEMENTS * n_l];
        self.sky_entries(d, &mut sky);
        let mut ylm = [0.0; 25];
        sh(-d, &mut ylm);
        let ray = Ray {
            o,
            d,
            cos_sun,
            sun_on,
            sun_src: &sun_src,
            sky: &sky,
            ylm: &ylm,
        };
        let step = cl.step_voxels * cl.voxel_size_m;
        // Thick steps (docs/cloud-light.md, "Thick steps") where a step can hold more than
        // THICK_STEP scaled optical depths.
        let ks_max = (0..n_l)
            .map(|l| cl.extinction_per_density_m[l] * s[l])
            .fold(0.0f64, f64::max);
        let thick_possible = ks_max * self.rho_max * step > THICK_STEP;
        let mut t = t0;
        let mut d0 = if sun_on {
            self.sun_path_at(o + d * t)
        } else {
            0.0
        };
        let mut front = None;
        while t < t1 {
            let dt = step.min(t1 - t);
            let pm = o + d * (t + 0.5 * dt);
            t += dt;
            let d1 = if sun_on {
                self.sun_path_at(o + d * t)
            } else {
                0.0
            };
            let d_start = d0;
            d0 = d1;
            let Some(w) = self.weights(pm) else {
                continue;
            };
            let tau_max = if thick_possible {
                w.iter()
                    .map(|&(i, _)| cl.density[i] as f64)
                    .fold(0.0, f64::max)
                    * ks_max
                    * dt
            } else {
                0.0
            };
            let alive = if tau_max > THICK_STEP {
                self.thick_step(&ray, t - dt, dt, tau_max, &mut st, &mut front)
            } else {
                let rho = Self::interp(&w, &cl.density);
                if rho <= 0.0 {
                    continue;
                }
                front.get_or_insert(t - dt);
                self.step(&ray, &w, rho, dt, (d_start, d1), false, pm, &mut st)
            };
            if !alive {
                break;
            }
        }
        let (mut ia, tc, tp) = (st.ia, st.tc, st.tp);
        // The view cap: sky light from behind each point along the view ray itself, and the
        // forward peak's share of the radiance from behind, both through T⁺.
        if front.is_some() && cl.sky.is_some() {
            for l in 0..n_l {
                if tp[l] <= 0.0 {
                    continue;
                }
                let tau = -tp[l].ln();
                let cap = cl.albedo[l] / cl.first_extinction_scale[l] * sky[15 * n_l + l];
                let behind = sky[16 * n_l + l];
                ia[l] = (ia[l] + cap * tau * tp[l] + behind * (tp[l] - tc[l])).max(0.0);
            }
        }
        CloudSample {
            radiance: ia,
            transmittance: tc,
            front_m: front,
        }
    }

    /// One step of length `dt` at density `rho`, the sun's path `(D₀, D₁)` at its ends and the
    /// textures interpolated with the weights `w` (docs/cloud-light.md, "Marching the volume");
    /// with `skin`, the sub-step of a thick step whose source within the skin's depth of the
    /// ray's scaled optical depth is the skin's. Returns whether any T* is above the cutoff.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        ray: &Ray<'_>,
        w: &[(usize, f64); 8],
        rho: f64,
        dt: f64,
        (d_start, d_end): (f64, f64),
        skin: bool,
        at: DVec3,
        st: &mut State,
    ) -> bool {
        let cl = self.cl;
        let n_l = cl.n_l();
        let (k, s) = (&cl.extinction_per_density_m, &cl.extinction_scale);
        let mut paths = [0.0f64; 15];
        if !cl.sky_paths.is_empty() {
            paths[0] = Self::interp(w, &cl.sun_path);
            for (e, p) in cl.sky_paths.iter().enumerate() {
                paths[e + 1] = Self::interp(w, p);
            }
        }
        let moments = cl.ms_order.map_or(0, |o| (o + 1) * (o + 1));
        let skin = if skin { cl.skin.as_ref() } else { None };
        let mut alive = false;
        for l in 0..n_l {
            let ks = k[l] * s[l];
            let a = -(-k[l] * rho * dt).exp_m1();
            let a_ms = -(-ks * rho * dt).exp_m1();
            // Sun, single scattering with the true phase function and the spread peak, through
            // k·s⁺ on both paths, the smooth part spread over the sun's and the view's true
            // optical depths. The part scattered last within the peak is seen through the true
            // extinction: its step weight with k (times s, as sun_src holds ω/s), and T_c.
            let kp = k[l] * cl.first_extinction_scale[l];
            let (a_p, sun_t, sun_peak) = if ray.sun_on {
                let (weight, d_eff) = sun_step(kp * rho, kp * (d_end - d_start), dt, kp * d_start);
                let lambda = cl.peak_rate[l] * k[l] * (d_start + (d_end - d_start) * d_eff);
                let lambda_view = cl.peak_rate[l] * (st.tv[l] + 0.5 * k[l] * rho * dt);
                let (smooth, _) = self.spread(l, ray.cos_sun, lambda + lambda_view);
                let peak = self.peak_turned(ray, at, l, lambda, kp);
                let (w_true, _) = sun_step(k[l] * rho, kp * (d_end - d_start), dt, kp * d_start);
                (
                    -(-kp * rho * dt).exp_m1(),
                    weight * smooth * s[l] / cl.first_extinction_scale[l],
                    w_true * peak * s[l],
                )
            } else {
                // T⁺ also carries the view cap's sky light (step 3).
                (-(-kp * rho * dt).exp_m1(), 0.0, 0.0)
            };
            // Sky and ground light through the sun cap and the lattice elements.
            let mut src = 0.0;
            if !cl.sky_paths.is_empty() {
                let mut q = 0.0;
                for (e, &path) in paths.iter().enumerate() {
                    q += ray.sky[e * n_l + l] * (-kp * path).exp();
                }
                src += cl.albedo[l] / s[l] * q;
            }
            // Multiple scattering, all orders (the cell's, and within the skin the skin's).
            let (mut j, mut j_skin) = (0.0, 0.0);
            for m in 0..moments {
                let c = Self::interp(w, &cl.ms[l * moments + m]);
                j += c * ray.ylm[m];
                if let Some(sk) = skin {
                    j_skin += (c + Self::interp(w, &sk.delta[l * moments + m])) * ray.ylm[m];
                }
            }
            // The cell's field seen through the surface voxels' faces (not the skin's), and the
            // sun's once-scattered light in place of the field's where it is not.
            let j = match self.face.get(l) {
                Some(face) => j.max(0.0) - Self::interp(w, face),
                None => j.max(0.0),
            };
            let j = match self.once.get(l) {
                Some(once) => (j + Self::interp(w, once)).max(0.0),
                None => j,
            };
            let field = match skin {
                Some(sk) => {
                    // The skin's source over the part of the sub-step within its depth of
                    // the ray's front (counted in the ray's scaled optical depth), the
                    // cell's beyond.
                    let left = sk.depth_scaled_tau[l] + st.ts[l].max(1e-300).ln();
                    if left <= 0.0 {
                        a_ms * (src + j)
                    } else {
                        let b = -(-left.min(ks * rho * dt)).exp_m1();
                        b * (src + j_skin.max(0.0)) + (a_ms - b) * (src + j)
                    }
                }
                None => a_ms * (src + j),
            };
            st.ia[l] +=
                st.ts[l] * field + ray.sun_src[l] * (st.tp[l] * sun_t + st.tc[l] * sun_peak);
            st.tc[l] *= 1.0 - a;
            st.ts[l] *= 1.0 - a_ms;
            st.tp[l] *= 1.0 - a_p;
            st.tv[l] += k[l] * rho * dt;
            alive |= st.ts[l] > MARCH_CUTOFF;
        }
        alive
    }

    /// A step over voxels of many optical depths (docs/cloud-light.md, "Thick steps"): in
    /// sub-steps of at most [`THICK_STEP`] scaled optical depths, each with the textures
    /// weighted by the voxels' density (the lit surface sees the cloud's voxels, not the
    /// empty ones beside it), the sun's path integrated from the density near the point, and
    /// the skin's source in the first optical depths along the ray (the formal solution
    /// I = ∫ S(τ) e^{−τ} dτ, Chandrasekhar 1960 §1.8, takes its radiance from there).
    fn thick_step(
        &self,
        ray: &Ray<'_>,
        t_start: f64,
        dt: f64,
        tau_max: f64,
        st: &mut State,
        front: &mut Option<f64>,
    ) -> bool {
        let cl = self.cl;
        let sun = DVec3::from_array(cl.sun_direction);
        let n = ((tau_max / THICK_STEP).ceil() as usize).clamp(2, MAX_SUB_STEPS);
        let h = dt / n as f64;
        let mut d_prev: Option<f64> = None;
        for j in 0..n {
            let ts = t_start + j as f64 * h;
            let Some(w) = self.weights(ray.o + ray.d * (ts + 0.5 * h)) else {
                d_prev = None;
                continue;
            };
            let rho = Self::interp(&w, &cl.density);
            if rho <= 0.0 {
                d_prev = None;
                continue;
            }
            let wd = w.map(|(i, wi)| (i, wi * cl.density[i] as f64 / rho));
            let (d0, d1) = if ray.sun_on {
                let d0 = match d_prev {
                    Some(v) => v,
                    None => self.sun_path_near(ray.o + ray.d * ts, sun),
                };
                (d0, self.sun_path_near(ray.o + ray.d * (ts + h), sun))
            } else {
                (0.0, 0.0)
            };
            d_prev = Some(d1);
            front.get_or_insert(ts);
            let at = ray.o + ray.d * (t_start + 0.5 * dt);
            if !self.step(ray, &wd, rho, h, (d0, d1), cl.skin.is_some(), at, st) {
                return false;
            }
        }
        true
    }

    /// The environment radiance L(d) of the export's sky table (zero without sky light), not
    /// blended across the horizon: the background of a vacuum scene without ground.
    pub fn environment(&self, d: DVec3, out: &mut [f64]) {
        let n_l = self.cl.n_l();
        let mut sky = vec![0.0; SKY_ELEMENTS * n_l];
        self.sky_entries_split(d, true, &mut sky);
        out.copy_from_slice(&sky[16 * n_l..17 * n_l]);
    }
}

/// What [`outward_lowering`] reads of one surface voxel, face and wavelength.
struct OutwardFace<'v> {
    /// The face's outward normal and an orthonormal basis of its plane.
    normal: DVec3,
    basis: (DVec3, DVec3),
    /// Towards the viewer, and its cosine to the normal.
    wo: DVec3,
    mv: f64,
    /// Scaled optical depths of the voxel and the cell along the face's axis.
    tv: f64,
    tc: f64,
    /// p*_l and the radiance moments L_lm.
    pl: &'v [f64],
    v: &'v [f64],
    order: usize,
    /// The sun's direction of travel, μ₀ and E_f, where it enters through this face.
    sun: Option<(DVec3, f64, f64)>,
}

/// The outward hemisphere's part of a face's lowering (docs/cloud-light.md, "Faces", step 4b):
/// over the mirror images ω = μn + √(1 − μ²)(cos φ t₁ + sin φ t₂) of the inward nodes, the
/// radiance R = Σ_lm L_lm Y_lm(ω) (skip R ≤ 0) weighted by the scaled phase function towards the
/// viewer and by 1 − r, r the view's share of R over the cell's with R's diffuse part following
/// the diffusion (Milne) profile (Chandrasekhar 1960, ch. IV) and the sun's first scattering the
/// beam ([`face_outward_profiles`], [`face_outward_ratio`]).
fn outward_lowering(f: OutwardFace) -> f64 {
    let g = f.pl.get(1).copied().unwrap_or(0.0);
    let (t1, t2) = f.basis;
    let mu0 = f.sun.map_or(0.0, |s| s.1);
    let mut ylm = [0.0; 25];
    let mut deficit = 0.0;
    for &(mu, w) in &MU_NODES {
        let prof = face_outward_profiles(mu, f.mv, mu0, g, f.tv, f.tc);
        let sin = (1.0 - mu * mu).max(0.0).sqrt();
        for jphi in 0..N_PHI {
            let phi = 2.0 * PI * (jphi as f64 + 0.5) / N_PHI as f64;
            let dir = f.normal * mu + (t1 * phi.cos() + t2 * phi.sin()) * sin;
            sh(dir, &mut ylm);
            let radiance: f64 = (0..(f.order + 1) * (f.order + 1))
                .map(|m| f.v[m] * ylm[m])
                .sum();
            if radiance <= 0.0 {
                continue;
            }
            let first = f.sun.map_or(0.0, |(travel, _, e_face)| {
                let x = (1.0 + g * g - 2.0 * g * travel.dot(dir)).max(1e-12);
                e_face * (1.0 - g * g) / (4.0 * PI * x * x.sqrt())
            });
            let r = face_outward_ratio(radiance, first, prof);
            let c = f.wo.dot(dir);
            let legendre = [
                1.0,
                c,
                0.5 * (3.0 * c * c - 1.0),
                0.5 * c * (5.0 * c * c - 3.0),
            ];
            let phase: f64 =
                f.pl.iter()
                    .zip(legendre)
                    .enumerate()
                    .map(|(ord, (p_l, leg))| (2 * ord + 1) as f64 * p_l * leg)
                    .sum();
            deficit += w * 2.0 * PI / N_PHI as f64 * phase / (4.0 * PI) * (1.0 - r) * radiance;
        }
    }
    deficit
}

/// Entry and exit distances (≥ 0) of the ray with the box (slab method).
fn box_interval(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-300 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (ta, tb) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 < t1).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Surface voxels: cloud with an empty face neighbour or on the grid's edge.
    #[test]
    fn surface_voxels_border_empty_space() {
        let dims = [3, 3, 3];
        let mut density = vec![1.0f32; 27];
        assert!(surface_voxel(&density, dims, [0, 1, 1]));
        assert!(!surface_voxel(&density, dims, [1, 1, 1]));
        // Voxel (2, 1, 1) emptied.
        density[(3 + 1) * 3 + 2] = 0.0;
        assert!(surface_voxel(&density, dims, [1, 1, 1]));
        assert!(!surface_voxel(&density, dims, [2, 1, 1]));
    }
}
