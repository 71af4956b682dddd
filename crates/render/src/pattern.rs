//! Orders 2 and 3 of multiple scattering by the reference pattern (§3.4 of Nishita,
//! Dobashi and Nakamae 1996, "Display of clouds taking into account multiple anisotropic
//! scattering and sky light"), selected per scene by `"multiple_scattering_method":
//! "reference_pattern"` instead of the all-order field of [`super::multiple`].
//!
//! What is computed, per voxel P of the cloud, is the in-scattered radiance of sunlight scattered
//! twice or three times, towards the camera, per unit scattering coefficient at P (the quantity
//! `Q` the final march multiplies by ω·σ_t, Nishita et al. 1996, §3.4 step 3):
//!
//! Q₂(P) = Σ_j σ_s(j) E T_sun(j) T(j→P) F₂(j→P),
//! Q₃(P) = Σ_{j,k} σ_s(j) E T_sun(j) T(j→k) σ_s(k) T(k→P) F₃(j→k→P),
//!
//! the discrete form of eq 6 truncated at the 3rd order: E the sun's normal irradiance,
//! T_sun(j) = exp(−k·D_sun(j)) the stored sun attenuation (§3.2), T(a→b) the transmittance
//! between voxel centres, and F the *modified form factors* of §3.4: the volume form factor
//! ∫_V dV/r² (Rushmeier's, for a receiving point) multiplied by the phase functions at each
//! scattering (θ′₁, θ′₂, θ′₃ of Fig. 3), integrated over sub-voxels (the paper subdivides the
//! voxels near P; here 4³ sub-voxels up to √3 voxels away, 2³ up to 2√3, the centre beyond), with
//! the average-density attenuation inside the voxel relative to the centre-to-centre one. A path
//! that starts and ends in the same voxel (the "self" form factor, r → 0) is integrated radially
//! over 128 directions: ∫dΩ ∫₀^{R(ω)} e^{−σ̄r} dr, R the distance to the voxel's face.
//!
//! The algorithm, as the paper's steps:
//!
//! 1. **Reference pattern** (step 1, Fig. 3–5): a *sample space* of S³ voxels (S = 21 by default;
//!    the paper's example is 30³, whose (N−1)² third-order paths cost 11× more) of uniform
//!    *average density* (the mean over the cloud's non-empty voxels), lit by the sun from outside,
//!    with P at its centre and the camera's central view direction. Every 2nd-order path (j→P)
//!    and every 3rd-order path (j→k→P) in it is evaluated (the third-order ones for ranking with
//!    one node per hop, its phase-weighted mean direction; the paths kept get the full
//!    sub-voxel form factors); the *contribution ratio* of a path is
//!    its share of the total 2nd + 3rd order intensity at P, that of a voxel the sum over the
//!    paths through it. The *bounding box* of the voxels whose ratio exceeds the threshold is the
//!    reference pattern; inside it the highest-ratio paths whose ratios sum to r (r = 0.8, the
//!    paper's value) are kept: n₂ paths of total ratio r_H (≤ r when the box holds less).
//! 2. **Scanning the cloud** (step 2): the pattern is moved voxel by voxel over the grid. At each
//!    voxel, n₁ of the n₂ paths are drawn by random numbers, with probability proportional to their
//!    ratio (the paper: "to use these voxels with high possibility"; stratified over the
//!    cumulative ratios); each drawn path is evaluated with the *local* densities (its σ_s at j
//!    and k, the stored sun attenuation at j, the transmittances between the voxel centres from
//!    the grid, trapezoid rule through the voxels crossed) and the stored modified form factors.
//!    The intensity is then corrected for the selection: with paths drawn uniformly the paper's
//!    estimate is I·n₂/n₁ rescaled by the ratio r; with draws in proportion to the ratios c_s
//!    the unbiased sum over the n₂ paths is (1/n₁) Σ I_s/p_s, p_s = c_s/Σc, which reduces to
//!    I·n₂/n₁ for equal ratios. The n₂ paths carry the share r_H of the total in the sample space,
//!    so the total is that sum **divided** by r_H. (The paper prints "I·r·n₂/n₁"; with r defined
//!    as the n₂ paths' share of the total, multiplying by r would count the paths kept as less
//!    than themselves and bias the result low by the factor r² = 0.64; dividing is the reading
//!    consistent with its definitions.)
//! 3. The final march (step 3) interpolates Q trilinearly between voxel centres, as the all-order
//!    field.
//!
//! The paper aligns the pattern with the eye's z axis (one viewing direction). Here the phase
//! function of the last scattering is evaluated for 3 × 3 viewing directions spread over the
//! image (one for an orthographic camera) and interpolated at each voxel's own direction to the
//! camera; the selection uses the central direction. Only the sun's light is scattered by the
//! pattern (as in the paper, §3.5's sky light enters at the first order): sky and ground light
//! keep their single scattering. Orders ≥ 4 are left out ("we truncated more than 4th order of
//! scattering"), which suits optically thin clouds; thick ones (τ ≳ 5) get most of their light
//! from higher orders and need the all-order method (README: measured figures).

use super::camera::{box_interval, primary_ray};
use super::light::{fibonacci, sun_density_integrals};
use super::lighting::Lighting;
use super::scene::{FrameScene, Projection};
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::DensityGrid;
use skybake_physics::phase::Phase;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Settings of the reference pattern.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatternSettings {
    /// Edge of the sample space, voxels (odd, 3 to 31; clipped to twice the grid's largest
    /// dimension less one). Its (S³)² third-order paths are all ranked: 86 million at 21.
    pub sample_space: usize,
    /// A voxel belongs to the pattern's bounding box when its contribution ratio exceeds this.
    pub voxel_threshold: f64,
    /// r: the total contribution ratio of the high-ratio paths kept (the paper's 0.8).
    pub ratio: f64,
    /// n₁: paths evaluated per voxel.
    pub paths_per_voxel: usize,
    /// Most high-ratio paths kept (n₂ ≤ this).
    pub max_paths: usize,
    /// Seed of the stochastic selection.
    pub seed: u64,
}

impl PatternSettings {
    /// Preset per quality: n₁ = 32, 64, 128, 256 paths per voxel.
    pub fn for_quality(q: Quality) -> Self {
        let n1 = match q {
            Quality::Draft => 32,
            Quality::Standard => 64,
            Quality::High => 128,
            Quality::Reference => 256,
        };
        Self {
            sample_space: 21,
            voxel_threshold: 5e-4,
            ratio: 0.8,
            paths_per_voxel: n1,
            max_paths: 1 << 16,
            seed: 0x5EED,
        }
    }

    /// Checks the ranges (errors name the field).
    pub fn validate(&self) -> Result<()> {
        if !(3..=31).contains(&self.sample_space) || self.sample_space % 2 == 0 {
            return Err(Error::out_of_range(
                "pattern.sample_space",
                self.sample_space,
                "an odd number of voxels from 3 to 31",
            ));
        }
        if !(self.voxel_threshold.is_finite() && (0.0..=0.5).contains(&self.voxel_threshold)) {
            return Err(Error::out_of_range(
                "pattern.voxel_threshold",
                self.voxel_threshold,
                "0 to 0.5",
            ));
        }
        if !(self.ratio.is_finite() && self.ratio > 0.0 && self.ratio <= 1.0) {
            return Err(Error::out_of_range("pattern.ratio", self.ratio, "(0, 1]"));
        }
        if !(1..=1 << 16).contains(&self.paths_per_voxel) {
            return Err(Error::out_of_range(
                "pattern.paths_per_voxel",
                self.paths_per_voxel,
                "1 to 65536",
            ));
        }
        if !(1..=1 << 17).contains(&self.max_paths) {
            return Err(Error::out_of_range(
                "pattern.max_paths",
                self.max_paths,
                "1 to 131072",
            ));
        }
        Ok(())
    }
}

/// Most sub-voxels per axis within the beam spread.
const MAX_SUBDIVISION: usize = 6;

/// The phase function's beam spread θ_b (Nishita et al. 1996, Fig. 3: the angle holding the forward lobe,
/// here where the phase falls to 10 % of its forward value) as its cosine, and the lobe's
/// half-width at half maximum (rad; 0 when the phase has no forward peak, p(0) < 2·p(90°)).
fn beam_spread(phase: Phase) -> (f64, f64) {
    let p0 = phase.eval(1.0);
    if p0 < 2.0 * phase.eval(0.0) {
        return (1.0, 0.0);
    }
    let angle_at = |frac: f64| {
        // Bisection on the angle: p decreases from the forward direction.
        let (mut lo, mut hi) = (0.0f64, PI / 2.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if phase.eval(mid.cos()) > frac * p0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    };
    (angle_at(0.1).cos(), angle_at(0.5))
}

/// Directions of the self form factor's radial integration.
const SELF_DIRECTIONS: usize = 128;
/// Largest number of viewing directions of a pattern (the central one and a 3 × 3 grid).
const MAX_VIEWS: usize = 10;

/// One quadrature node of a hop: travel direction from the source sub-voxel to the receiving
/// point, weight (m·sr: sub-voxel volume / r², times the average-density attenuation relative
/// to the centre-to-centre one), and the weight times the first phase function p(s·u).
#[derive(Debug, Clone, Copy)]
struct Node {
    u: DVec3,
    w: f64,
    ws: f64,
}

/// A hop reduced to one node (for ranking paths).
#[derive(Debug, Clone, Copy)]
struct Lump {
    ws: f64,
    wl: f64,
    /// Mean direction weighted by w·p(s·u) (zero when the hop's directions spread widely).
    u: DVec3,
    /// Mean direction weighted by w·p(u·ω).
    ul: DVec3,
}

/// The modified form factors' quadrature for every hop offset within ±(S − 1) voxels.
struct Kernel {
    half: i32,
    side: usize,
    range: Vec<(u32, u32)>,
    nodes: Vec<Node>,
    /// exp(−σ̄·h·|e|) per hop offset (the sample space's centre-to-centre transmittance).
    trans: Vec<f64>,
    /// Mean distance from a voxel's centre to its faces over directions, m (self hops).
    r_mean_m: f64,
}

fn radial(sigma: f64, r: f64) -> f64 {
    if sigma * r < 1e-9 {
        r
    } else {
        -(-sigma * r).exp_m1() / sigma
    }
}

impl Kernel {
    /// Quadrature of every hop within ±`half` voxels; `beam` holds the directions whose phase
    /// lobes decide the beam spread (the sun's travel direction and the outgoing views).
    fn new(half: i32, h: f64, sigma_bar: f64, phase: Phase, s_in: DVec3, beam: &[DVec3]) -> Self {
        let side = (2 * half + 1) as usize;
        let (cos_spread, width) = beam_spread(phase);
        let mut range = Vec::with_capacity(side * side * side);
        let mut nodes = Vec::new();
        let mut trans = Vec::with_capacity(side * side * side);
        let mut r_sum = 0.0;
        for ez in -half..=half {
            for ey in -half..=half {
                for ex in -half..=half {
                    let start = nodes.len() as u32;
                    let c = DVec3::new(ex as f64, ey as f64, ez as f64) * h;
                    let dist = c.length();
                    trans.push((-sigma_bar * dist).exp());
                    if ex == 0 && ey == 0 && ez == 0 {
                        let dw = 4.0 * PI / SELF_DIRECTIONS as f64;
                        for i in 0..SELF_DIRECTIONS {
                            let u = fibonacci(i, SELF_DIRECTIONS);
                            let r = 0.5 * h / u.x.abs().max(u.y.abs()).max(u.z.abs());
                            r_sum += r;
                            let w = dw * radial(sigma_bar, r);
                            nodes.push(Node {
                                u,
                                w,
                                ws: w * phase.eval(s_in.dot(u)),
                            });
                        }
                    } else {
                        let d2 = ex * ex + ey * ey + ez * ez;
                        let mut m = if d2 <= 3 {
                            4
                        } else if d2 <= 12 {
                            2
                        } else {
                            1
                        };
                        // Within the beam spread, sub-voxels no wider than the phase lobe's
                        // half-width (Nishita et al. 1996, §3.4: "every volume element within the beam
                        // spread … is subdivided into smaller sub-voxels").
                        let u_c = -c / dist;
                        let alpha = (0.87 / (d2 as f64).sqrt()).min(1.0);
                        let spread = cos_spread.acos() + alpha;
                        if width > 0.0 && beam.iter().any(|b| b.dot(u_c) > spread.min(PI).cos()) {
                            let need = (1.0 / ((d2 as f64).sqrt() * width)).ceil() as usize;
                            m = m.max(need.min(MAX_SUBDIVISION));
                        }
                        let sub = h / m as f64;
                        let dv = sub * sub * sub;
                        for k in 0..m {
                            for j in 0..m {
                                for i in 0..m {
                                    let x = c + DVec3::new(
                                        (i as f64 + 0.5) * sub - 0.5 * h,
                                        (j as f64 + 0.5) * sub - 0.5 * h,
                                        (k as f64 + 0.5) * sub - 0.5 * h,
                                    );
                                    let r = x.length();
                                    let u = -x / r;
                                    let w = dv / (r * r) * (-sigma_bar * (r - dist)).exp();
                                    nodes.push(Node {
                                        u,
                                        w,
                                        ws: w * phase.eval(s_in.dot(u)),
                                    });
                                }
                            }
                        }
                    }
                    range.push((start, nodes.len() as u32));
                }
            }
        }
        Self {
            half,
            side,
            range,
            nodes,
            trans,
            r_mean_m: r_sum / SELF_DIRECTIONS as f64,
        }
    }

    /// One node per hop for ranking the paths: Σ w·p(s·u) with its mean direction (the first
    /// hop of a path) and Σ w·p(u·ω) with its mean direction (the last hop), ω the outgoing
    /// central view direction. A mean direction of zero length is stored as zero.
    fn lumps(&self, phase: Phase, omega: DVec3) -> Vec<Lump> {
        self.range
            .iter()
            .map(|&(a, b)| {
                let nodes = &self.nodes[a as usize..b as usize];
                let ws: f64 = nodes.iter().map(|n| n.ws).sum();
                let wl: f64 = nodes.iter().map(|n| n.w * phase.eval(n.u.dot(omega))).sum();
                let us: DVec3 = nodes.iter().map(|n| n.u * n.ws).sum();
                let ul: DVec3 = nodes
                    .iter()
                    .map(|n| n.u * n.w * phase.eval(n.u.dot(omega)))
                    .sum();
                let unit = |v: DVec3, total: f64| {
                    if v.length() > 0.5 * total.abs() && total > 0.0 {
                        v.normalize()
                    } else {
                        DVec3::ZERO
                    }
                };
                Lump {
                    ws,
                    wl,
                    u: unit(us, ws),
                    ul: unit(ul, wl),
                }
            })
            .collect()
    }

    #[inline]
    fn index(&self, e: [i32; 3]) -> usize {
        let h = self.half;
        (((e[2] + h) as usize * self.side) + (e[1] + h) as usize) * self.side + (e[0] + h) as usize
    }

    /// Quadrature nodes of the hop from a source voxel at offset `e` to a receiving voxel centre.
    #[inline]
    fn hop(&self, e: [i32; 3]) -> &[Node] {
        let (a, b) = self.range[self.index(e)];
        &self.nodes[a as usize..b as usize]
    }

    /// F₂ for the 2nd-order path from offset `dj` to the centre, for each outgoing direction.
    fn f2(&self, phase: Phase, dj: [i32; 3], views: &[DVec3], out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        for n in self.hop(dj) {
            for (o, v) in out.iter_mut().zip(views) {
                *o += n.ws * phase.eval(n.u.dot(*v));
            }
        }
    }

    /// F₃ for the 3rd-order path j → k → centre (offsets `dj`, `dk`), for each outgoing direction.
    fn f3(&self, phase: Phase, dj: [i32; 3], dk: [i32; 3], views: &[DVec3], out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let first = self.hop(sub(dj, dk));
        for n in self.hop(dk) {
            let a: f64 = first.iter().map(|m| m.ws * phase.eval(m.u.dot(n.u))).sum();
            let wa = n.w * a;
            for (o, v) in out.iter_mut().zip(views) {
                *o += wa * phase.eval(n.u.dot(*v));
            }
        }
    }
}

#[inline]
fn sub(a: [i32; 3], b: [i32; 3]) -> [i32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Viewing directions of a pattern: a 3 × 3 grid over the image (one for an orthographic
/// camera), as outgoing directions (towards the camera), interpolated bilinearly in image
/// coordinates at each voxel.
struct Views {
    n: usize,
    /// Outgoing directions, row-major over the grid.
    dirs: Vec<DVec3>,
    centre: DVec3,
}

impl Views {
    fn new(scene: &FrameScene) -> Self {
        let cam = &scene.camera;
        let n = match cam.projection {
            Projection::Orthographic { .. } => 1,
            _ => 3,
        };
        let mut dirs = Vec::with_capacity(n * n);
        for j in 0..n {
            for i in 0..n {
                let (px, py) = if n == 1 {
                    (0.5 * cam.width as f64, 0.5 * cam.height as f64)
                } else {
                    (
                        i as f64 / (n - 1) as f64 * cam.width as f64,
                        j as f64 / (n - 1) as f64 * cam.height as f64,
                    )
                };
                // A fisheye's corners past 180° look straight back.
                let d = primary_ray(cam, px, py)
                    .map(|r| r.dir)
                    .unwrap_or(-cam.forward);
                dirs.push(-d);
            }
        }
        Self {
            n,
            dirs,
            centre: -cam.forward,
        }
    }

    /// Bilinear weights of the grid's directions for the voxel at `p`.
    fn weights(&self, scene: &FrameScene, p: DVec3) -> [(usize, f64); 4] {
        if self.n == 1 {
            return [(0, 1.0), (0, 0.0), (0, 0.0), (0, 0.0)];
        }
        let cam = &scene.camera;
        let v = (p - cam.position_m).normalize_or(cam.forward);
        let (w, h) = (cam.width as f64, cam.height as f64);
        let (px, py) = match cam.projection {
            Projection::Pinhole { half_w, half_h } => {
                let z = v.dot(cam.forward).max(1e-9);
                let sx = (v.dot(cam.right) / (z * half_w)).clamp(-1.0, 1.0);
                let sy = (v.dot(cam.up) / (z * half_h)).clamp(-1.0, 1.0);
                (0.5 * (sx + 1.0) * w, 0.5 * (1.0 - sy) * h)
            }
            Projection::Fisheye { rad_per_px } => {
                let theta = v.dot(cam.forward).clamp(-1.0, 1.0).acos();
                let phi = v.dot(cam.up).atan2(v.dot(cam.right));
                let r = theta / rad_per_px;
                (0.5 * w + r * phi.cos(), 0.5 * h - r * phi.sin())
            }
            Projection::Orthographic { .. } => (0.5 * w, 0.5 * h),
        };
        let last = (self.n - 1) as f64;
        let gx = (px / w * last).clamp(0.0, last);
        let gy = (py / h * last).clamp(0.0, last);
        let (i0, j0) = (
            (super::volume::floor(gx) as usize).min(self.n - 2),
            (super::volume::floor(gy) as usize).min(self.n - 2),
        );
        let (fx, fy) = (gx - i0 as f64, gy - j0 as f64);
        let at = |i: usize, j: usize| j * self.n + i;
        [
            (at(i0, j0), (1.0 - fx) * (1.0 - fy)),
            (at(i0 + 1, j0), fx * (1.0 - fy)),
            (at(i0, j0 + 1), (1.0 - fx) * fy),
            (at(i0 + 1, j0 + 1), fx * fy),
        ]
    }
}

/// A high-ratio path of the pattern.
#[derive(Debug, Clone)]
struct Path {
    /// Offset of the first scattering voxel j from P.
    dj: [i32; 3],
    /// Offset of the second scattering voxel k (3rd order only).
    dk: Option<[i32; 3]>,
    /// Contribution in the sample space (its ratio times the total).
    c: f64,
    /// Start and end of the path's transmittance segments in [`ReferencePattern::segs`].
    segs: (u32, u32),
}

/// The reference pattern of one set of optics, average density and sun and view directions.
pub struct ReferencePattern {
    /// σ_t per unit density, m⁻¹; single-scattering albedo.
    k: f64,
    albedo: f64,
    /// Sample-space average extinction σ̄, m⁻¹.
    sigma_bar: f64,
    r_mean_m: f64,
    paths: Vec<Path>,
    /// Cumulative sample-space contributions of `paths` (for the draws).
    cdf: Vec<f64>,
    /// Modified form factors per path and viewing direction, `[path][view]`.
    f: Vec<f32>,
    n_views: usize,
    /// Offsets from P and trapezoid weights (m) of the voxels on the paths' centre-to-centre
    /// segments.
    segs: Vec<([i32; 3], f32)>,
    pub stats: PatternStats,
}

/// What the pattern holds (reported in the frame's stages).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PatternStats {
    /// Edge of the sample space, voxels.
    pub sample_space: usize,
    /// Average density of the sample space (mean over the cloud's non-empty voxels).
    pub average_density: f64,
    /// Optical thickness of one voxel at the average density.
    pub voxel_optical_thickness: f64,
    /// Bounding box of the voxels above the threshold, offsets from P (min, max per axis).
    pub box_min: [i32; 3],
    pub box_max: [i32; 3],
    /// High-ratio paths kept (n₂) of the 2nd and 3rd order.
    pub paths_order2: usize,
    pub paths_order3: usize,
    /// Total contribution ratio of the kept paths, r_H.
    pub ratio_kept: f64,
    /// Share of the 3rd order in the sample space's 2nd + 3rd order total.
    pub third_order_share: f64,
    pub build_ms: f64,
}

/// Histogram bins per decade of contribution ratio for the path selection.
const BINS_PER_DECADE: f64 = 100.0;
const DECADES: f64 = 14.0;

impl ReferencePattern {
    /// Step 1: builds the pattern for extinction `k` (m⁻¹ per unit density), albedo, phase, the
    /// average density, the sun's direction (towards the sun), the outgoing viewing directions
    /// (`views[0]` is the central one used for the selection) and voxel size `h`.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        k: f64,
        albedo: f64,
        phase: Phase,
        average_density: f64,
        sun_dir: DVec3,
        views: &[DVec3],
        h: f64,
        settings: &PatternSettings,
    ) -> Self {
        let t0 = Instant::now();
        let s_in = -sun_dir.normalize();
        let sigma_bar = k * average_density;
        let sbar_s = albedo * sigma_bar;
        let half_s = (settings.sample_space / 2) as i32;
        let side = settings.sample_space;
        let mut beam = vec![s_in];
        beam.extend_from_slice(views);
        let kernel = Kernel::new(2 * half_s, h, sigma_bar, phase, s_in, &beam);
        let centre_view = [views[0]];
        let n_vox = side * side * side;
        let offset = |i: usize| -> [i32; 3] {
            [
                (i % side) as i32 - half_s,
                ((i / side) % side) as i32 - half_s,
                (i / (side * side)) as i32 - half_s,
            ]
        };
        // Sun attenuation in the sample space: uniform density, lit from outside the box.
        let lo = DVec3::splat(-(half_s as f64 + 0.5) * h);
        let tsun: Vec<f64> = (0..n_vox)
            .map(|i| {
                let d = offset(i);
                let p = DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64) * h;
                let t = box_interval(p, -s_in, lo, -lo)
                    .map(|(_, t1)| t1)
                    .unwrap_or(0.0);
                (-sigma_bar * t).exp()
            })
            .collect();
        let c2 = |dj: [i32; 3]| -> f64 {
            let mut f = [0.0];
            kernel.f2(phase, dj, &centre_view, &mut f);
            let j = idx_of(dj, half_s, side);
            sbar_s * tsun[j] * kernel.trans[kernel.index(dj)] * f[0]
        };
        // The (N − 1)² third-order paths are ranked with one node per hop (its phase-weighted
        // mean direction); the paths kept get the full sub-voxel form factors below.
        let lumps = kernel.lumps(phase, views[0]);
        // Per hop: the first hop's weight with the centre-to-centre transmittance, and its
        // direction (zero: spread, the middle phase averages to 1/4π).
        let first_w: Vec<f64> = lumps
            .iter()
            .zip(&kernel.trans)
            .map(|(l, t)| l.ws * t)
            .collect();
        let first_u: Vec<DVec3> = lumps.iter().map(|l| l.u).collect();
        let hs = half_s;
        // c₃ for the row of j = (x0..=x1, y, z) through k = dk, into `out`.
        let c3_row = |dk: [i32; 3], y: i32, z: i32, x0: i32, x1: i32, out: &mut [f64]| {
            let k = kernel.index(dk);
            let b = &lumps[k];
            let bw = sbar_s * sbar_s * b.wl * kernel.trans[k];
            let jb = idx_of([x0, y, z], hs, side);
            let eb = kernel.index([x0 - dk[0], y - dk[1], z - dk[2]]);
            let n = (x1 - x0 + 1) as usize;
            if b.ul == DVec3::ZERO {
                let iso = bw / (4.0 * PI);
                for (i, o) in out[..n].iter_mut().enumerate() {
                    *o = tsun[jb + i] * first_w[eb + i] * iso;
                }
            } else {
                for (i, o) in out[..n].iter_mut().enumerate() {
                    let u = first_u[eb + i];
                    let pm = if u == DVec3::ZERO {
                        1.0 / (4.0 * PI)
                    } else {
                        phase.eval(u.dot(b.ul))
                    };
                    *o = tsun[jb + i] * first_w[eb + i] * pm * bw;
                }
            }
        };
        // Contribution ratios of every path and voxel in the sample space.
        let (mut voxel, total3) = (0..n_vox)
            .into_par_iter()
            .fold(
                || (vec![0.0f64; n_vox], 0.0f64),
                |(mut acc, mut t3), ik| {
                    let dk = offset(ik);
                    let mut via_k = 0.0;
                    let mut row = vec![0.0; side];
                    for z in -hs..=hs {
                        for y in -hs..=hs {
                            c3_row(dk, y, z, -hs, hs, &mut row);
                            let jb = idx_of([-hs, y, z], hs, side);
                            for (a, c) in acc[jb..jb + side].iter_mut().zip(&row) {
                                *a += c;
                                via_k += c;
                            }
                        }
                    }
                    acc[ik] += via_k;
                    t3 += via_k;
                    (acc, t3)
                },
            )
            .reduce(
                || (vec![0.0f64; n_vox], 0.0),
                |(mut a, t_a), (b, t_b)| {
                    for (x, y) in a.iter_mut().zip(&b) {
                        *x += y;
                    }
                    (a, t_a + t_b)
                },
            );
        let mut total2 = 0.0;
        for (ij, v) in voxel.iter_mut().enumerate() {
            let c = c2(offset(ij));
            *v += c;
            total2 += c;
        }
        let total = total2 + total3;
        // The bounding box of the voxels whose ratio exceeds the threshold.
        let mut box_min = [0i32; 3];
        let mut box_max = [0i32; 3];
        for (i, v) in voxel.iter().enumerate() {
            if total > 0.0 && *v / total > settings.voxel_threshold {
                let d = offset(i);
                for a in 0..3 {
                    box_min[a] = box_min[a].min(d[a]);
                    box_max[a] = box_max[a].max(d[a]);
                }
            }
        }
        let in_box: Vec<[i32; 3]> = (0..n_vox)
            .map(offset)
            .filter(|d| (0..3).all(|a| d[a] >= box_min[a] && d[a] <= box_max[a]))
            .collect();
        // Paths in the box: the highest ratios summing to r (a log histogram finds the cut).
        let n_bins = (DECADES * BINS_PER_DECADE) as usize;
        let bin = |c: f64| -> Option<usize> {
            if !(c > 0.0 && total > 0.0) {
                return None;
            }
            let x = -(c / total).log10() * BINS_PER_DECADE;
            Some((x.max(0.0) as usize).min(n_bins - 1))
        };
        // Every 3rd-order path of the box, row by row of j, for each k in the box.
        let box_rows = |dk: [i32; 3], f: &mut dyn FnMut([i32; 3], f64)| {
            let mut row = vec![0.0; side];
            for z in box_min[2]..=box_max[2] {
                for y in box_min[1]..=box_max[1] {
                    c3_row(dk, y, z, box_min[0], box_max[0], &mut row);
                    for (i, c) in row[..(box_max[0] - box_min[0] + 1) as usize]
                        .iter()
                        .enumerate()
                    {
                        f([box_min[0] + i as i32, y, z], *c);
                    }
                }
            }
        };
        let (hist_c, hist_n) = in_box
            .par_iter()
            .fold(
                || (vec![0.0f64; n_bins], vec![0usize; n_bins]),
                |(mut hc, mut hn), &dk| {
                    box_rows(dk, &mut |_, c| {
                        if let Some(b) = bin(c) {
                            hc[b] += c;
                            hn[b] += 1;
                        }
                    });
                    (hc, hn)
                },
            )
            .reduce(
                || (vec![0.0; n_bins], vec![0; n_bins]),
                |(mut a, mut an), (b, bn)| {
                    for i in 0..n_bins {
                        a[i] += b[i];
                        an[i] += bn[i];
                    }
                    (a, an)
                },
            );
        let (mut hist_c, mut hist_n) = (hist_c, hist_n);
        for &dj in &in_box {
            let c = c2(dj);
            if let Some(b) = bin(c) {
                hist_c[b] += c;
                hist_n[b] += 1;
            }
        }
        let mut cut = n_bins;
        let (mut acc_c, mut acc_n) = (0.0, 0usize);
        for b in 0..n_bins {
            if acc_n + hist_n[b] > settings.max_paths || acc_c >= settings.ratio * total {
                break;
            }
            acc_c += hist_c[b];
            acc_n += hist_n[b];
            cut = b + 1;
        }
        // Keep every path whose bin is above the cut.
        let keep = |c: f64| bin(c).is_some_and(|b| b < cut);
        let mut paths: Vec<Path> = in_box
            .iter()
            .filter_map(|&dj| {
                let c = c2(dj);
                keep(c).then_some(Path {
                    dj,
                    dk: None,
                    c,
                    segs: (0, 0),
                })
            })
            .collect();
        let n2 = paths.len();
        let third: Vec<Path> = in_box
            .par_iter()
            .flat_map_iter(|&dk| {
                let mut kept = Vec::new();
                box_rows(dk, &mut |dj, c| {
                    if keep(c) {
                        kept.push(Path {
                            dj,
                            dk: Some(dk),
                            c,
                            segs: (0, 0),
                        });
                    }
                });
                kept
            })
            .collect();
        paths.extend(third);
        // Modified form factors for every viewing direction, and the transmittance segments.
        let n_views = views.len();
        let f: Vec<f32> = paths
            .par_iter()
            .flat_map_iter(|p| {
                let mut out = [0.0f64; MAX_VIEWS];
                match p.dk {
                    None => kernel.f2(phase, p.dj, views, &mut out[..n_views]),
                    Some(dk) => kernel.f3(phase, p.dj, dk, views, &mut out[..n_views]),
                }
                (0..n_views).map(move |v| out[v] as f32)
            })
            .collect();
        let mut segs = Vec::new();
        for p in paths.iter_mut() {
            let a = segs.len() as u32;
            match p.dk {
                None => push_segment(p.dj, [0; 3], h, &mut segs),
                Some(dk) => {
                    push_segment(p.dj, dk, h, &mut segs);
                    push_segment(dk, [0; 3], h, &mut segs);
                }
            }
            p.segs = (a, segs.len() as u32);
        }
        let mut cdf = Vec::with_capacity(paths.len());
        let mut run = 0.0;
        for p in &paths {
            run += p.c;
            cdf.push(run);
        }
        let stats = PatternStats {
            sample_space: side,
            average_density,
            voxel_optical_thickness: sigma_bar * h,
            box_min,
            box_max,
            paths_order2: n2,
            paths_order3: paths.len() - n2,
            ratio_kept: if total > 0.0 { run / total } else { 0.0 },
            third_order_share: if total > 0.0 { total3 / total } else { 0.0 },
            build_ms: t0.elapsed().as_secs_f64() * 1e3,
        };
        Self {
            k,
            albedo,
            sigma_bar,
            r_mean_m: kernel.r_mean_m,
            paths,
            cdf,
            f,
            n_views,
            segs,
            stats,
        }
    }

    /// Step 2 at one voxel: the estimated Q₂ + Q₃ per unit sun irradiance (sr⁻¹), from `n1`
    /// paths drawn at stratified positions `(i + xi)/n1` of the cumulative ratios.
    #[allow(clippy::too_many_arguments)]
    fn at_voxel(
        &self,
        grid: &DensityGrid,
        d_sun: &[f32],
        voxel: [usize; 3],
        view_w: &[(usize, f64); 4],
        n1: usize,
        xi: f64,
    ) -> f64 {
        let Some(&c_total) = self.cdf.last() else {
            return 0.0;
        };
        if c_total <= 0.0 || self.stats.ratio_kept <= 0.0 {
            return 0.0;
        }
        let dims = grid.dims;
        let at = |off: [i32; 3]| -> Option<usize> {
            let x = voxel[0] as i64 + off[0] as i64;
            let y = voxel[1] as i64 + off[1] as i64;
            let z = voxel[2] as i64 + off[2] as i64;
            (x >= 0
                && y >= 0
                && z >= 0
                && (x as usize) < dims[0]
                && (y as usize) < dims[1]
                && (z as usize) < dims[2])
                .then(|| grid.index(x as usize, y as usize, z as usize))
        };
        let rho = |off: [i32; 3]| at(off).map_or(0.0, |i| grid.data[i] as f64);
        let self_factor = |sigma: f64| -> f64 {
            radial(sigma, self.r_mean_m) / radial(self.sigma_bar, self.r_mean_m)
        };
        let rho_p = rho([0; 3]);
        let mut est = 0.0;
        for i in 0..n1 {
            let u = (i as f64 + xi) / n1 as f64 * c_total;
            let s = self
                .cdf
                .partition_point(|&c| c < u)
                .min(self.paths.len() - 1);
            let p = &self.paths[s];
            let Some(j) = at(p.dj) else { continue };
            let rho_j = grid.data[j] as f64;
            if rho_j <= 0.0 {
                continue;
            }
            let mut v = self.albedo * self.k * rho_j * (-self.k * d_sun[j] as f64).exp();
            match p.dk {
                None => {
                    if p.dj == [0; 3] {
                        v *= self_factor(self.k * rho_p);
                    }
                }
                Some(dk) => {
                    let rho_k = rho(dk);
                    if rho_k <= 0.0 {
                        continue;
                    }
                    v *= self.albedo * self.k * rho_k;
                    if p.dj == dk {
                        v *= self_factor(self.k * rho_k);
                    }
                    if dk == [0; 3] {
                        v *= self_factor(self.k * rho_p);
                    }
                }
            }
            let tau: f64 = self.segs[p.segs.0 as usize..p.segs.1 as usize]
                .iter()
                .map(|(off, w)| *w as f64 * rho(*off))
                .sum();
            let f: f64 = view_w
                .iter()
                .map(|&(g, w)| w * self.f[s * self.n_views + g] as f64)
                .sum();
            // I_s / p_s with p_s = c_s / Σc.
            est += v * (-self.k * tau).exp() * f * c_total / p.c;
        }
        est / n1 as f64 / self.stats.ratio_kept
    }
}

#[inline]
fn idx_of(d: [i32; 3], half: i32, side: usize) -> usize {
    (((d[2] + half) as usize * side) + (d[1] + half) as usize) * side + (d[0] + half) as usize
}

/// Trapezoid rule along the centre-to-centre segment from offset `a` to `b`: the voxels at
/// `a + e·i/n` (rounded), i = 0..=n, n = max |e_i|, weights |e|·h/n (halved at the ends).
fn push_segment(a: [i32; 3], b: [i32; 3], h: f64, out: &mut Vec<([i32; 3], f32)>) {
    let e = sub(b, a);
    let n = e[0].abs().max(e[1].abs()).max(e[2].abs());
    if n == 0 {
        return;
    }
    let len = ((e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) as f64).sqrt() * h;
    let dl = len / n as f64;
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let off = [
            a[0] + (e[0] as f64 * t).round() as i32,
            a[1] + (e[1] as f64 * t).round() as i32,
            a[2] + (e[2] as f64 * t).round() as i32,
        ];
        let w = if i == 0 || i == n { 0.5 * dl } else { dl };
        out.push((off, w as f32));
    }
}

/// splitmix64 of `x`, as a uniform number in [0, 1).
fn hash01(x: u64) -> f64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// The orders-2-and-3 field: `q[voxel][λ]`, W m⁻² sr⁻¹ nm⁻¹ (in-scattered radiance towards the
/// camera per unit scattering coefficient, the march's `Q`), and one pattern's figures per group
/// of wavelengths with identical optics.
pub struct PatternField {
    pub n_l: usize,
    pub q: Vec<f32>,
    pub stats: Vec<PatternStats>,
    /// Time of step 2 (scanning the grid), ms.
    pub apply_ms: f64,
}

impl PatternField {
    /// One line for the frame's stages.
    pub fn describe(&self) -> String {
        match self.stats.first() {
            None => "multiple scattering, orders 2 and 3 by the reference pattern (Nishita et al. 1996, §3.4): no sunlight or no cloud, nothing to scatter".into(),
            Some(s) => format!(
                "multiple scattering, orders 2 and 3 of sunlight by the reference pattern (Nishita et al. 1996, §3.4): sample space {0}³ at average density {1:.3} ({2:.3} per voxel), bounding box {3:?}..{4:?}, {5} + {6} high-ratio paths of ratio r = {7:.3}, drawn stochastically per voxel (pattern built in {8:.0} ms, grid scanned in {9:.0} ms); orders ≥ 4 left out",
                s.sample_space,
                s.average_density,
                s.voxel_optical_thickness,
                s.box_min,
                s.box_max,
                s.paths_order2,
                s.paths_order3,
                s.ratio_kept,
                self.stats.iter().map(|s| s.build_ms).sum::<f64>(),
                self.apply_ms
            ),
        }
    }
}

/// Orders 2 and 3 of the sun's light at every voxel where `mask` is set (Nishita et al. 1996, §3.4 steps 1
/// and 2), with `settings.paths_per_voxel` paths per voxel. `cancel` is polled per slab.
pub fn compute(
    scene: &FrameScene,
    grid: &DensityGrid,
    lighting: &Lighting,
    settings: &PatternSettings,
    mask: &[bool],
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<PatternField> {
    settings.validate()?;
    let optics = &scene.optics;
    let n_l = optics.albedo.len();
    let n_vox = grid.data.len();
    let mut q = vec![0f32; n_vox * n_l];
    let sun_on = lighting.sun_dir.is_finite() && lighting.sun_irradiance.iter().any(|&e| e > 0.0);
    let (sum, count) = grid
        .data
        .iter()
        .filter(|&&v| v > 0.0)
        .fold((0.0f64, 0usize), |(s, n), &v| (s + v as f64, n + 1));
    let mut stats = Vec::new();
    let mut apply_ms = 0.0;
    if !sun_on || count == 0 || mask.len() != n_vox {
        return Ok(PatternField {
            n_l,
            q,
            stats,
            apply_ms,
        });
    }
    let average = sum / count as f64;
    let views = Views::new(scene);
    let mut view_dirs = vec![views.centre];
    view_dirs.extend(views.dirs.iter().copied());
    let mut s = *settings;
    let max_dim = grid.dims.iter().copied().max().unwrap_or(1);
    // Both odd: a sample space need not reach past the grid from any voxel.
    s.sample_space = s.sample_space.min(2 * max_dim - 1).max(3);
    let d_sun = sun_density_integrals(grid, lighting.sun_dir);
    let [nx, ny, _] = grid.dims;
    let cancelled = AtomicBool::new(false);
    for group in optics.groups() {
        let l0 = group[0];
        if optics.albedo[l0] <= 0.0 {
            continue;
        }
        let pattern = ReferencePattern::build(
            optics.extinction_per_density_m[l0],
            optics.albedo[l0],
            optics.phase[l0],
            average,
            lighting.sun_dir,
            &view_dirs,
            grid.voxel_size_m,
            &s,
        );
        let t = Instant::now();
        let e: Vec<f64> = group.iter().map(|&l| lighting.sun_irradiance[l]).collect();
        q.par_chunks_mut(nx * ny * n_l)
            .enumerate()
            .for_each(|(z, slab)| {
                if cancelled.load(Ordering::Relaxed) || cancel() {
                    cancelled.store(true, Ordering::Relaxed);
                    return;
                }
                for i in 0..nx * ny {
                    let idx = z * nx * ny + i;
                    if !mask[idx] {
                        continue;
                    }
                    let (x, y) = (i % nx, i / nx);
                    let p = grid.voxel_centre(x, y, z);
                    // The pattern's form factors are `[centre, grid…]`.
                    let mut w = views.weights(scene, p);
                    for ww in w.iter_mut() {
                        ww.0 += 1;
                    }
                    let xi =
                        hash01(settings.seed ^ (idx as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
                    let v = pattern.at_voxel(grid, &d_sun, [x, y, z], &w, s.paths_per_voxel, xi);
                    for (gi, &l) in group.iter().enumerate() {
                        slab[i * n_l + l] += (e[gi] * v) as f32;
                    }
                }
            });
        if cancelled.load(Ordering::Relaxed) {
            return Err(Error::Cancelled);
        }
        apply_ms += t.elapsed().as_secs_f64() * 1e3;
        stats.push(pattern.stats);
    }
    Ok(PatternField {
        n_l,
        q,
        stats,
        apply_ms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hop weights are the volume form factor ∫ dV e^{−σ̄r}/r² of each voxel seen from a
    /// voxel centre; summed over the cube of half-width R they approach the ball's analytic
    /// 4π(1 − e^{−σ̄R})/σ̄ (plus the cube's corners), and without attenuation the self voxel's
    /// ∫_cube dV/r² = ∫ R(ω) dω, which a midpoint rule over the cube reproduces.
    #[test]
    fn form_factors_integrate_the_volume() {
        let h = 1.0;
        let iso = Phase::Isotropic;
        let k0 = Kernel::new(1, h, 0.0, iso, DVec3::Z, &[]);
        let self_w: f64 = k0.hop([0, 0, 0]).iter().map(|n| n.w).sum();
        // Independent: midpoint rule over the unit cube with 200³ cells (the singular centre
        // cell integrated analytically as a ball of equal volume, 4π r_eq).
        let m = 200;
        let c = 1.0 / m as f64;
        let mut direct = 0.0;
        for i in 0..m {
            for j in 0..m {
                for k in 0..m {
                    let x = DVec3::new(
                        (i as f64 + 0.5) * c - 0.5,
                        (j as f64 + 0.5) * c - 0.5,
                        (k as f64 + 0.5) * c - 0.5,
                    );
                    direct += c * c * c / x.length_squared();
                }
            }
        }
        assert!(
            (self_w - direct).abs() / direct < 0.02,
            "self form factor {self_w} vs {direct}"
        );
        // With attenuation, over a large cube: hop weight × centre transmittance.
        let sigma = 0.5;
        let half = 14;
        let k = Kernel::new(half, h, sigma, iso, DVec3::Z, &[]);
        let mut sum = 0.0;
        for z in -half..=half {
            for y in -half..=half {
                for x in -half..=half {
                    let e = [x, y, z];
                    let w: f64 = k.hop(e).iter().map(|n| n.w).sum();
                    sum += w * k.trans[k.index(e)];
                }
            }
        }
        let ball = 4.0 * PI * (1.0 - (-sigma * half as f64).exp()) / sigma;
        assert!((sum - ball).abs() / ball < 0.01, "{sum} vs {ball}");
    }

    /// The self hop's directions carry the first phase function: Σ dω·p(s·u) over its 128
    /// directions is ∫ p dω = 1 (the phase function's normalisation).
    #[test]
    fn self_hop_phase_weights_normalise() {
        let hg = Phase::HenyeyGreenstein { g: 0.5 };
        let k = Kernel::new(0, 1.0, 0.0, hg, DVec3::new(0.3, -0.2, 0.9).normalize(), &[]);
        let nodes = k.hop([0, 0, 0]);
        // Σ (w/R) p = Σ dω p ≈ 1 (128-point Fibonacci rule for a g = 0.5 lobe).
        let s: f64 = nodes
            .iter()
            .map(|n| n.ws / (0.5 / n.u.x.abs().max(n.u.y.abs()).max(n.u.z.abs())))
            .sum();
        assert!((s - 1.0).abs() < 0.02, "{s}");
    }

    #[test]
    fn segments_are_exact_for_uniform_density() {
        let mut segs = Vec::new();
        push_segment([3, -2, 1], [0, 0, 0], 2.0, &mut segs);
        let len: f64 = segs.iter().map(|(_, w)| *w as f64).sum();
        assert!((len - 2.0 * 14f64.sqrt()).abs() < 1e-5);
        assert_eq!(segs.first().map(|s| s.0), Some([3, -2, 1]));
        assert_eq!(segs.last().map(|s| s.0), Some([0, 0, 0]));
    }

    #[test]
    fn settings_are_validated() {
        let mut s = PatternSettings::for_quality(Quality::Draft);
        assert!(s.validate().is_ok());
        s.sample_space = 14;
        assert_eq!(s.validate().unwrap_err().field(), "pattern.sample_space");
        s.sample_space = 15;
        s.ratio = 0.0;
        assert_eq!(s.validate().unwrap_err().field(), "pattern.ratio");
    }
}
