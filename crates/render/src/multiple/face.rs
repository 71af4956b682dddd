//! The field in a surface voxel seen through the cloud's face: the light arriving from the
//! empty side builds up with depth.
//!
//! Just below a face that borders empty space, radiance travelling inwards at a cosine μ' to
//! the inward normal has crossed only the cloud between the face and the point: without
//! sources outside, L(z, μ') = ∫₀^z S e^{−(z−z')/μ'} dz'/μ' = S (1 − e^{−z/μ'}) for a source S
//! uniform over the layer (z scaled optical depth along the normal; the formal solution,
//! Chandrasekhar 1960 §1.8). A coarse cell's track-length tally is the mean over its depth T_c,
//! S (1 − (μ'/T_c)(1 − e^{−T_c/μ'})), while a view ray entering through the face at cosine μ_v
//! weights the depths it crosses by e^{−z/μ_v}: over the voxel's depth T_v it sees
//! S·ā_v(μ') with ā_v the view-weighted mean of 1 − e^{−z/μ'}. The inward radiance the view sees
//! is therefore the cell's times r(μ') = ā_v / ā_c (1 for an optically thin voxel; μ_v/(μ_v + μ')
//! for a semi-infinite one), most below 1 for grazing views (small μ_v) and grazing inward light
//! (small μ'): the forward-scattered light a grazing view collects near a lit face.
//!
//! [`MsField::inscatter_face`] takes J* = ∫ p*(ω_o·ω') L(ω') dω' with the inward hemisphere's
//! L scaled by r, the rest as [`MsField::inscatter`] has it.
//!
//! The outward light, from below the point, also varies with depth: near a face of a thick
//! cloud it follows the diffusion (Milne) profile L(τ, μ) ∝ τ_tr + 0.7104 + μ, τ_tr the
//! transport optical depth τ(1 − g*) below the face and 0.7104 the extrapolation length
//! (Chandrasekhar 1960, ch. IV, §§ 28–29), lower at the top of the voxel a grazing view sees than
//! the cell's mean. In voxels of less than [`OUTWARD_MAX_DEPTH`] scaled optical depths the outward
//! hemisphere's radiance is scaled by the ratio of that profile at the view-weighted mean depth
//! over the voxel to the profile at the cell's mean depth ([`outward_profile`]); thicker voxels'
//! cells have skins (see `skin`), whose tallies hold the light near the face already.

use super::{real_sh, MsField, MAX_ORDER};
use glam::DVec3;
use skybake_physics::phase::orthonormal_basis;
use std::f64::consts::PI;

mod lanes;

/// Gauss-Legendre nodes and weights on [0, 1] for the inward cosine μ' (8 points).
pub const MU_NODES: [(f64, f64); 8] = [
    (0.019_855_071_751_231_85, 0.050_614_268_145_188_13),
    (0.101_666_761_293_186_6, 0.111_190_517_226_687_2),
    (0.237_233_795_041_835_5, 0.156_853_322_938_943_6),
    (0.408_282_678_752_175_1, 0.181_341_891_689_181),
    (0.591_717_321_247_825, 0.181_341_891_689_181),
    (0.762_766_204_958_164_5, 0.156_853_322_938_943_6),
    (0.898_333_238_706_813_4, 0.111_190_517_226_687_2),
    (0.980_144_928_248_768_1, 0.050_614_268_145_188_13),
];

/// Azimuths per inward cosine.
pub const N_PHI: usize = 16;

/// Voxels of a scaled optical depth below this along the face's axis have their outward
/// hemisphere scaled by [`outward_profile`] (the module text); thicker ones have skins.
pub const OUTWARD_MAX_DEPTH: f64 = super::THICK_STEP;

const N_SH: usize = (MAX_ORDER + 1) * (MAX_ORDER + 1);

/// One quadrature direction of a face's inward hemisphere.
struct Node {
    dir: DVec3,
    /// Index into [`MU_NODES`].
    mu: usize,
    /// Solid-angle weight, sr.
    weight: f64,
    ylm: [f64; N_SH],
    /// The mirror image of `dir` in the face (outward, the same cosine to the normal).
    out_dir: DVec3,
    /// Y_lm of `out_dir`.
    ylm_out: [f64; N_SH],
}

/// The inward hemispheres of the 6 axis faces (outward normals −x, +x, −y, +y, −z, +z).
pub struct FaceQuadrature {
    faces: Vec<Vec<Node>>,
    /// Per face, the nodes' directions (x, y, z) and weights as arrays, for the node loops
    /// that run over all nodes at once.
    pub(super) arrays: Vec<[Vec<f64>; 4]>,
    /// The sun's first scattering towards every node, per face, for one direction of the
    /// sun's travel and the frame's asymmetries (see [`Self::with_sun`]).
    sun_first: Vec<SunFirst>,
}

/// [`sun_first_scattering`] at every node of every face for one sun and one asymmetry g.
struct SunFirst {
    travel: DVec3,
    g: f64,
    faces: Vec<Vec<f64>>,
}

/// The sun's first scattering towards `dir` per unit irradiance, Henyey-Greenstein of
/// asymmetry `g`, for light travelling along `travel` (what [`MsField::inscatter_face`] weighs
/// the build-up profile of the sun's beam with).
#[inline]
pub(super) fn sun_first_scattering(g: f64, travel: DVec3, dir: DVec3) -> f64 {
    let x = (1.0 + g * g - 2.0 * g * travel.dot(dir)).max(1e-12);
    (1.0 - g * g) / (4.0 * PI * x * x.sqrt())
}

impl FaceQuadrature {
    /// The quadrature for a field of angular order `order`.
    pub fn new(order: usize) -> Self {
        let order = order.min(MAX_ORDER);
        let faces = (0..6)
            .map(|f| {
                let n = face_normal(f);
                let (t1, t2) = orthonormal_basis(-n);
                let mut nodes = Vec::with_capacity(MU_NODES.len() * N_PHI);
                for (i, &(mu, w)) in MU_NODES.iter().enumerate() {
                    let s = (1.0 - mu * mu).max(0.0).sqrt();
                    for j in 0..N_PHI {
                        let phi = 2.0 * PI * (j as f64 + 0.5) / N_PHI as f64;
                        let dir = -n * mu + (t1 * phi.cos() + t2 * phi.sin()) * s;
                        let mut ylm = [0.0; N_SH];
                        real_sh(dir, order, &mut ylm);
                        let out_dir = dir + n * (2.0 * mu);
                        let mut ylm_out = [0.0; N_SH];
                        real_sh(out_dir, order, &mut ylm_out);
                        nodes.push(Node {
                            dir,
                            mu: i,
                            weight: w * 2.0 * PI / N_PHI as f64,
                            ylm,
                            out_dir,
                            ylm_out,
                        });
                    }
                }
                nodes
            })
            .collect::<Vec<Vec<Node>>>();
        let arrays = faces
            .iter()
            .map(|nodes| {
                [
                    nodes.iter().map(|n| n.dir.x).collect(),
                    nodes.iter().map(|n| n.dir.y).collect(),
                    nodes.iter().map(|n| n.dir.z).collect(),
                    nodes.iter().map(|n| n.weight).collect(),
                ]
            })
            .collect();
        Self {
            faces,
            arrays,
            sun_first: Vec::new(),
        }
    }

    /// The quadrature with the sun's first scattering towards every node kept per face, for
    /// light travelling along `travel` and each asymmetry of `gs` (the first phase moments p*₁
    /// of the field's wavelengths): it depends on neither the voxel nor the view, and
    /// [`MsField::inscatter_face_lanes`] reads it instead of computing it per voxel (the same
    /// values).
    pub fn with_sun(mut self, travel: DVec3, gs: &[f64]) -> Self {
        for &g in gs {
            if self.sun_first.iter().any(|s| s.g == g) {
                continue;
            }
            let faces = self
                .faces
                .iter()
                .map(|nodes| {
                    nodes
                        .iter()
                        .map(|n| sun_first_scattering(g, travel, n.dir))
                        .collect()
                })
                .collect();
            self.sun_first.push(SunFirst { travel, g, faces });
        }
        self
    }

    /// The kept first scattering at face `face`'s nodes for `travel` and `g`, if kept.
    pub(super) fn sun_first(&self, face: usize, travel: DVec3, g: f64) -> Option<&[f64]> {
        self.sun_first
            .iter()
            .find(|s| s.g == g && s.travel == travel)
            .map(|s| &s.faces[face][..])
    }
}

/// Outward normal of face `f` (0 … 5: −x, +x, −y, +y, −z, +z).
pub fn face_normal(f: usize) -> DVec3 {
    let s = if f % 2 == 0 { -1.0 } else { 1.0 };
    match f / 2 {
        0 => DVec3::X * s,
        1 => DVec3::Y * s,
        _ => DVec3::Z * s,
    }
}

/// 1 − e^{−x}, accurate for small x.
fn one_minus_exp(x: f64) -> f64 {
    -(-x).exp_m1()
}

/// Mean of e^{−z/a} over z ∈ [0, t].
fn mean_exp(a: f64, t: f64) -> f64 {
    if t <= 1e-9 * a {
        return 1.0 - 0.5 * t / a;
    }
    a / t * one_minus_exp(t / a)
}

/// Mean of e^{−z/a} over z ∈ [0, t] weighted by the view's e^{−z/v}.
fn view_exp(a: f64, v: f64, t: f64) -> f64 {
    if t <= 1e-9 * a.min(v) {
        return 1.0 - 0.5 * t / a;
    }
    let k = 1.0 / a + 1.0 / v;
    one_minus_exp(t * k) / k / (v * one_minus_exp(t / v))
}

/// The inward radiance's depth profiles at inward cosine `m`, averaged over the cell's depth
/// `t_cell` and over the voxel's `t_voxel` as the view (cosine `mv`) weights it: `[uniform
/// source (cell, view), source falling as the sun's beam e^{−z/μ₀} (cell, view)]`, each per
/// unit source at the face. The cloud-light export's reference marcher applies the same
/// profiles (docs/cloud-light.md, "Faces").
pub fn profiles(m: f64, mv: f64, mu0: f64, t_voxel: f64, t_cell: f64) -> [f64; 4] {
    let t_cell = t_cell.max(t_voxel);
    let uniform_cell = 1.0 - mean_exp(m, t_cell);
    let uniform_view = 1.0 - view_exp(m, mv, t_voxel);
    if mu0 <= 0.0 {
        return [uniform_cell, uniform_view, 0.0, 0.0];
    }
    // (μ₀/(μ₀ − m))(e^{−z/μ₀} − e^{−z/m}); μ₀ nudged off m (the limit is finite).
    let mu0 = if (mu0 - m).abs() < 1e-3 {
        m + 1e-3
    } else {
        mu0
    };
    let c = mu0 / (mu0 - m);
    [
        uniform_cell,
        uniform_view,
        c * (mean_exp(mu0, t_cell) - mean_exp(m, t_cell)),
        c * (view_exp(mu0, mv, t_voxel) - view_exp(m, mv, t_voxel)),
    ]
}

/// The outward radiance's depth profiles at outward cosine `m`: `[diffuse, sun (cell), sun
/// (view)]`. The diffuse part follows the diffusion (Milne) profile τ_tr + 0.7104 + μ
/// (Chandrasekhar 1960, ch. IV), τ_tr = z(1 − `g`) with z the scaled optical depth below the face:
/// its ratio at the mean depth over the voxel's `t_voxel` as a view of cosine `mv` weights it
/// (e^{−z/μ_v}) over the ratio at the mean depth of the cell's `t_cell`. The sun's first
/// scattering towards the outward direction, per unit source at the face, falls as the beam:
/// L₁(z) = (μ₀/(μ₀ + μ)) e^{−z/μ₀} below a deep face, averaged over the cell and, as the view
/// weights it, over the voxel (0 when `mu0` ≤ 0). The cloud-light export's reference marcher
/// applies the same profiles (docs/cloud-light.md, "Faces").
pub fn outward_profiles(m: f64, mv: f64, mu0: f64, g: f64, t_voxel: f64, t_cell: f64) -> [f64; 3] {
    let x = t_voxel / mv;
    // ∫₀ᵗ z e^{−z/μ_v} dz / ∫₀ᵗ e^{−z/μ_v} dz = μ_v − t/(e^{t/μ_v} − 1).
    let z_view = if x < 1e-6 {
        0.5 * t_voxel
    } else {
        mv - t_voxel / x.exp_m1()
    };
    let t_cell = t_cell.max(t_voxel);
    let a = 1.0 - g;
    let diffuse =
        (z_view * a + MILNE_EXTRAPOLATION + m) / (0.5 * t_cell * a + MILNE_EXTRAPOLATION + m);
    if mu0 <= 0.0 {
        return [diffuse, 0.0, 0.0];
    }
    let c = mu0 / (mu0 + m);
    [
        diffuse,
        c * mean_exp(mu0, t_cell),
        c * view_exp(mu0, mv, t_voxel),
    ]
}

/// The ratio of the outward radiance a view sees through the voxel to the cell's `radiance`
/// (> 0), of which the sun's first scattering holds `first`·`sun[1]` (at most all of it) and
/// the rest is diffuse (`sun` from [`outward_profiles`]), clamped to [0, 2].
#[inline(always)]
pub fn outward_ratio(radiance: f64, first: f64, sun: [f64; 3]) -> f64 {
    let [diffuse, sun_c, sun_v] = sun;
    let p_c = first * sun_c;
    let (p_c, p_v) = if p_c > radiance {
        (radiance, first * sun_v * (radiance / p_c))
    } else {
        (p_c, first * sun_v)
    };
    (((radiance - p_c) * diffuse + p_v) / radiance).clamp(0.0, 2.0)
}

/// The Milne problem's extrapolation length q(∞) (Chandrasekhar 1960, ch. IV, Table VI).
const MILNE_EXTRAPOLATION: f64 = 0.710_446;

/// Node weight times the scaled phase function towards `wo` from `dir`, / 4π:
/// p*(cos θ) = Σ_l (2l + 1) p*_l P_l(cos θ) (shared by the scalar and side-by-side paths).
fn phase_weight(weight: f64, wo: DVec3, dir: DVec3, pl: &[f64]) -> f64 {
    let c = wo.dot(dir);
    let legendre = [
        1.0,
        c,
        0.5 * (3.0 * c * c - 1.0),
        0.5 * c * (5.0 * c * c - 3.0),
        0.125 * (35.0 * c.powi(4) - 30.0 * c * c + 3.0),
    ];
    let mut phase = 0.0;
    for (order, p_l) in pl.iter().enumerate() {
        phase += (2 * order + 1) as f64 * p_l * legendre[order];
    }
    weight * phase / (4.0 * PI)
}

/// The sun's light at a surface voxel: its direction of travel, its irradiance per
/// wavelength before the cloud, and the density integral along its path to the voxel's centre.
pub struct SunAtVoxel<'a> {
    pub travel: DVec3,
    pub irradiance: &'a [f64],
    pub density_m: f64,
}

impl MsField {
    /// The radiance's coefficients L_lm at `p` with [`Self::inscatter`]'s weights (not
    /// convolved with the phase function), `[λ][(L + 1)²]` into `out`: what
    /// [`Self::inscatter_face`] reconstructs the inward radiance from.
    pub fn coefficients(&self, p: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let n = self.moments;
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for (i, v) in self.data[c * self.n_l * n..(c + 1) * self.n_l * n]
                .iter()
                .enumerate()
            {
                out[i] += w * *v as f64;
            }
        }
    }

    /// The mean density of the coarse cell holding `p` (clamped to the grid): with the
    /// cell's edge, the depth [`Self::inscatter_face`] takes the cell's tally as the mean over.
    pub fn cell_density(&self, p: DVec3) -> f64 {
        let local = (p - self.origin_m) / self.cell_m;
        let idx: [usize; 3] = std::array::from_fn(|b| {
            (crate::volume::floor(local[b]).max(0.0) as usize).min(self.dims[b] - 1)
        });
        self.rho[(idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0]] as f64
    }

    /// [`MsField::inscatter`] at a voxel whose neighbour across face `face` (see
    /// [`face_normal`]) is empty, seen through that face: the inward radiance scaled by r(μ')
    /// (module text). `voxel_density_m` is the voxel's density times its edge along the face's
    /// axis, `k_true` the true extinction per density per wavelength.
    #[allow(clippy::too_many_arguments)]
    pub fn inscatter_face(
        &self,
        quad: &FaceQuadrature,
        p: DVec3,
        d: DVec3,
        face: usize,
        voxel_density_m: f64,
        k_true: &[f64],
        sun: Option<&SunAtVoxel>,
        out: &mut [f64],
    ) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let n = self.moments;
        let wo = -d;
        let normal = face_normal(face);
        let mv = wo.dot(normal);
        // The interpolated (not convolved) coefficients.
        let mut coef = vec![0.0; self.n_l * n];
        self.coefficients(p, &mut coef);
        // The cell holding p: its mean density over its edge along the face's axis.
        let cell_density_m = self.cell_density(p) * self.cell_m[face / 2];
        // The sun's beam enters through this face (cosine to the inward normal).
        let mu0 = sun.map_or(0.0, |s| s.travel.dot(-normal));
        let sun = sun.filter(|_| mu0 > 0.05);
        let face_density_m = sun.map_or(0.0, |s| {
            (s.density_m - 0.5 * voxel_density_m / mu0.max(0.05)).max(0.0)
        });
        let mut ylm_o = [0.0; N_SH];
        real_sh(wo, self.angular_order, &mut ylm_o);
        let nodes = &quad.faces[face];
        // Per node: its weight times p*(ω_o·ω'), and the sun's first scattering towards it
        // per unit irradiance (Henyey-Greenstein g*); shared by the wavelengths whose phase
        // moments are the previous one's.
        let mut shape = vec![(0.0, 0.0); nodes.len()];
        let mut shape_of: Option<&[f64]> = None;
        let mut prof = [[0.0f64; 4]; 8];
        let mut prof_of: Option<(f64, f64)> = None;
        // The outward hemisphere's phase weights towards the viewer and its profile ratios.
        let mut out_shape = vec![(0.0, 0.0); nodes.len()];
        let mut out_prof = [[0.0f64; 3]; 8];
        let mut out_of: Option<(&[f64], f64, f64)> = None;
        for (l, o) in out.iter_mut().enumerate() {
            let v = &coef[l * n..(l + 1) * n];
            let pl = &self.phase_moments[l][..];
            let mut j = 0.0;
            for (order, p_l) in pl.iter().enumerate() {
                for m in order * order..(order + 1) * (order + 1) {
                    j += p_l * v[m] * ylm_o[m];
                }
            }
            let ks = k_true[l] * self.extinction_scale[l];
            let (t_v, t_c) = (ks * voxel_density_m, ks * cell_density_m);
            if mv <= 0.0 || t_v < 1e-4 {
                *o = j.max(0.0);
                continue;
            }
            if prof_of != Some((t_v, t_c)) {
                prof = std::array::from_fn(|i| profiles(MU_NODES[i].0, mv, mu0, t_v, t_c));
                prof_of = Some((t_v, t_c));
            }
            if shape_of != Some(pl) {
                let g = pl.get(1).copied().unwrap_or(0.0);
                for (sh, node) in shape.iter_mut().zip(nodes) {
                    let first = sun.map_or(0.0, |s| sun_first_scattering(g, s.travel, node.dir));
                    *sh = (phase_weight(node.weight, wo, node.dir, pl), first);
                }
                shape_of = Some(pl);
            }
            // The sun's first scattering in the scaled problem, per unit scaled optical depth
            // at the face.
            let e_face = sun.map_or(0.0, |s| s.irradiance[l] * (-ks * face_density_m).exp());
            let mut deficit = 0.0;
            for (node, &(w_phase, hg)) in nodes.iter().zip(&shape) {
                let (mut radiance, mut source) = (0.0, 0.0);
                for (order, p_l) in pl.iter().enumerate() {
                    let mut sum = 0.0;
                    for m in order * order..(order + 1) * (order + 1) {
                        sum += v[m] * node.ylm[m];
                    }
                    radiance += sum;
                    source += p_l * sum;
                }
                if radiance <= 0.0 {
                    continue;
                }
                let source = source.max(0.0);
                let first = e_face * hg;
                let [u_c, u_v, e_c, e_v] = prof[node.mu];
                let den = source * u_c + first * e_c;
                if den <= 0.0 {
                    continue;
                }
                let r = ((source * u_v + first * e_v) / den).clamp(0.0, 2.0);
                deficit += w_phase * (1.0 - r) * radiance;
            }
            if t_v < OUTWARD_MAX_DEPTH {
                if out_of != Some((pl, t_v, t_c)) {
                    let g = pl.get(1).copied().unwrap_or(0.0);
                    for (i, r) in out_prof.iter_mut().enumerate() {
                        *r = outward_profiles(MU_NODES[i].0, mv, mu0, g, t_v, t_c);
                    }
                    for (w, node) in out_shape.iter_mut().zip(nodes) {
                        let first =
                            sun.map_or(0.0, |s| sun_first_scattering(g, s.travel, node.out_dir));
                        *w = (phase_weight(node.weight, wo, node.out_dir, pl), first);
                    }
                    out_of = Some((pl, t_v, t_c));
                }
                deficit += outward_deficit(nodes, v, pl.len(), e_face, &out_shape, &out_prof);
            }
            *o = (j - deficit).max(0.0);
        }
    }
}

/// The outward hemisphere's part of the face's deficit: Σ_nodes w·(1 − r)·L(ω_out) over the
/// mirror images of the inward nodes, L from the coefficients `v` up to order `orders` − 1
/// (nodes of non-positive radiance skipped), `shape` the nodes' [`phase_weight`]s towards the
/// viewer and the sun's first scattering towards ω_out per unit irradiance, `e_face` that
/// irradiance at the face, r the [`outward_ratio`] with the [`outward_profiles`] per cosine node.
fn outward_deficit(
    nodes: &[Node],
    v: &[f64],
    orders: usize,
    e_face: f64,
    shape: &[(f64, f64)],
    prof: &[[f64; 3]; 8],
) -> f64 {
    let mut deficit = 0.0;
    for (node, &(w_phase, hg)) in nodes.iter().zip(shape) {
        let mut radiance = 0.0;
        for order in 0..orders {
            let mut sum = 0.0;
            for m in order * order..(order + 1) * (order + 1) {
                sum += v[m] * node.ylm_out[m];
            }
            radiance += sum;
        }
        if radiance <= 0.0 {
            continue;
        }
        let r = outward_ratio(radiance, e_face * hg, prof[node.mu]);
        deficit += w_phase * (1.0 - r) * radiance;
    }
    deficit
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The profiles' closed forms against a midpoint sum over depth.
    #[test]
    fn profiles_match_their_depth_integrals() {
        let (m, mv, mu0, tv, tc) = (0.3, 0.26, 0.5, 0.87, 1.3);
        let n = 200_000;
        let (mut s_uc, mut s_ec) = (0.0, 0.0);
        for i in 0..n {
            let z = tc * (i as f64 + 0.5) / n as f64;
            s_uc += 1.0 - (-z / m).exp();
            s_ec += mu0 / (mu0 - m) * ((-z / mu0).exp() - (-z / m).exp());
        }
        let (mut s_uv, mut s_ev, mut s_w) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let z = tv * (i as f64 + 0.5) / n as f64;
            let w = (-z / mv).exp();
            s_uv += w * (1.0 - (-z / m).exp());
            s_ev += w * mu0 / (mu0 - m) * ((-z / mu0).exp() - (-z / m).exp());
            s_w += w;
        }
        let want = [s_uc / n as f64, s_uv / s_w, s_ec / n as f64, s_ev / s_w];
        let got = profiles(m, mv, mu0, tv, tc);
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{got:?} vs {want:?}");
        }
        // A semi-infinite layer seen from the face: μ_v/(μ_v + μ') of the saturated radiance.
        let deep = profiles(m, mv, 0.0, 1e3, 1e3);
        assert!((deep[0] - (1.0 - m / 1e3)).abs() < 1e-9, "{deep:?}");
        assert!((deep[1] - mv / (mv + m)).abs() < 1e-9, "{deep:?}");
        // An optically thin voxel: the view sees the cell's mean.
        let thin = profiles(m, mv, mu0, 1e-6, 1e-6);
        assert!((thin[1] / thin[0] - 1.0).abs() < 1e-3, "{thin:?}");
        assert!((thin[3] / thin[2] - 1.0).abs() < 1e-3, "{thin:?}");
    }

    /// The outward profiles' view-weighted means against midpoint sums, and their limits: 1
    /// for an optically thin voxel, the profile at the face over the cell's middle for a thick
    /// one seen at a grazing angle.
    #[test]
    fn outward_profiles_match_their_depth_means() {
        let (m, mv, mu0, g, tv, tc) = (0.4, 0.26, 0.5, 0.45, 0.87, 1.3);
        let n = 200_000;
        let (mut zw, mut ew, mut w) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let z = tv * (i as f64 + 0.5) / n as f64;
            let e = (-z / mv).exp();
            zw += z * e;
            ew += e * (-z / mu0).exp();
            w += e;
        }
        let mut ec = 0.0;
        for i in 0..n {
            ec += (-(tc * (i as f64 + 0.5) / n as f64) / mu0).exp();
        }
        let q = MILNE_EXTRAPOLATION;
        let c = mu0 / (mu0 + m);
        let want = [
            (zw / w * (1.0 - g) + q + m) / (0.5 * tc * (1.0 - g) + q + m),
            c * ec / n as f64,
            c * ew / w,
        ];
        let got = outward_profiles(m, mv, mu0, g, tv, tc);
        for (a, b) in got.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{got:?} vs {want:?}");
        }
        let thin = outward_profiles(m, mv, mu0, g, 1e-9, 1e-9);
        assert!((thin[0] - 1.0).abs() < 1e-9 && (thin[2] / thin[1] - 1.0).abs() < 1e-6);
        let deep = outward_profiles(m, 1e-3, 0.0, g, 50.0, 50.0);
        let face = (q + m) / (25.0 * (1.0 - g) + q + m);
        assert!((deep[0] - face).abs() < 1e-3, "{deep:?} vs {face}");
        // All of the radiance the sun's first scattering: the view sees the beam's profile.
        let p = outward_profiles(m, mv, mu0, g, tv, tc);
        let r = outward_ratio(2.0, 2.0 / p[1], p);
        assert!((r - p[2] / p[1]).abs() < 1e-12, "{r}");
    }

    /// Each face's inward quadrature integrates the hemisphere's solid angle and the inward
    /// cosine exactly.
    #[test]
    fn face_quadrature_covers_the_inward_hemisphere() {
        let q = FaceQuadrature::new(3);
        for (f, nodes) in q.faces.iter().enumerate() {
            let n = face_normal(f);
            let area: f64 = nodes.iter().map(|x| x.weight).sum();
            let flux: f64 = nodes.iter().map(|x| x.weight * -x.dir.dot(n)).sum();
            assert!((area - 2.0 * PI).abs() < 1e-9, "{area}");
            assert!((flux - PI).abs() < 1e-9, "{flux}");
            assert!(nodes.iter().all(|x| x.dir.dot(n) < 0.0));
        }
    }
}
