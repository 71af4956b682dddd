//! Density-integral table to the top of the atmosphere, D_k(r, μ) = ∫ ρ_k ds (metres), for rays
//! that do not hit the ground, parametrised as in Bruneton 2017 (`GetTransmittanceTextureUvFromRMu`):
//! x_r = ρ/H with ρ = sqrt(r² − R²), H = sqrt(R_top² − R²); x_μ = (d − d_min)/(d_max − d_min),
//! d the distance to the top. Stored as density integrals (not transmittance) so that huge optical
//! depths interpolate well and every wavelength reuses the same table (ARCHITECTURE.md, "Invariants").

use super::geometry::{
    chord_inside_sphere, distance_to_sphere_far, horizon_mu, radius_at, safe_sqrt,
};
use super::kernels::exp_fast;
use super::medium::{Medium, Profile, CONSTITUENTS};
use crate::image::SpectralImage;
use rayon::prelude::*;
use std::fmt::Write as _;

/// Version of the stored density-table layout (part of its store key, checked on load).
/// (2: each constituent's uniform layer taken out as an exact chord, [`DensityIntegralTable`].)
pub const DENSITY_TABLE_FORMAT: &str = "density-table-2";
/// Header attribute with the stored table's description ([`StoredDensity`] as JSON).
const ATTR_DENSITY: &str = "skybakeDensityTable";
/// Header attribute with the stored table's values (hex digits of the f64 bits).
const ATTR_DENSITY_DATA: &str = "skybakeDensityData";

/// What a stored density table was built for; it is used only if all of it matches.
#[derive(serde::Serialize)]
struct StoredDensity {
    format: &'static str,
    n_r: usize,
    n_mu: usize,
    steps: usize,
    bottom_radius_m: f64,
    top_radius_m: f64,
    profiles: [Profile; CONSTITUENTS],
}

impl StoredDensity {
    fn of(medium: &Medium, n_r: usize, n_mu: usize, steps: usize) -> Self {
        Self {
            format: DENSITY_TABLE_FORMAT,
            n_r,
            n_mu,
            steps,
            bottom_radius_m: medium.bottom_radius_m,
            top_radius_m: medium.top_radius_m,
            profiles: medium.profiles,
        }
    }
}

/// The table, `[i_r][i_mu]` of `[D_rayleigh, D_mie, D_ozone]`, each less the ray's chord through
/// its constituent's uniform layer where it has one ([`Profile::uniform_layer_top_m`]); lookups
/// add that chord back exactly at the point looked up.
///
/// A layered aerosol's density integral has a kink where the ray's start crosses the boundary
/// layer's top (D grows linearly below it, hardly at all above), which linear interpolation on
/// the table's radius nodes (25 m apart at the ground, 380 m at 1.5 km) rounds off: in fog of
/// visibility 1 km under a 1.5 km top it read the sun's optical depth 0.08–0.36 too large over
/// the layer's top 300 m (0.3 km of sunlight-converting haze, optical depth 1.5 at 440 nm), and
/// the single-scattered light there 10–30 % low; the precise method's energy over a white
/// ground read 0.926 instead of 1. The chord is continuous and exact; the rest is smooth.
#[derive(Debug, Clone)]
pub struct DensityIntegralTable {
    n_r: usize,
    n_mu: usize,
    /// Quadrature intervals per ray it was built with.
    steps: usize,
    bottom: f64,
    top: f64,
    /// Per constituent, the radius of the top of its uniform layer, if it has one.
    layer_radius: [Option<f64>; CONSTITUENTS],
    data: Vec<[f64; CONSTITUENTS]>,
}

/// Per constituent, the radius of the top of its uniform layer ([`Profile::uniform_layer_top_m`]).
fn layer_radii(medium: &Medium) -> [Option<f64>; CONSTITUENTS] {
    std::array::from_fn(|k| {
        medium.profiles[k]
            .uniform_layer_top_m()
            .map(|top| medium.bottom_radius_m + top)
    })
}

crate::simd_dispatch_avx512! {
    /// Integrates ρ_k along the ray (r, mu) over `[0, length]` with `steps` intervals, midpoint
    /// rule in u with t = length·u² (dense at the start, where an upward ray is densest). Sums in
    /// f64; steps are taken in blocks so each profile's loop is branch-free and vectorises (with
    /// the polynomial `exp` of `kernels`, 1e-14 relative).
    ///
    /// A layered aerosol's boundary layer (relative density 1 up to its top, [`Profile::uniform_layer_top_m`])
    /// is taken exactly, as the ray's chord through it ([`chord_inside_sphere`]); the quadrature
    /// integrates only the rest. A midpoint rule across the layer's top (a jump from 1 to the
    /// free troposphere's ~0.003) is off by up to half a step: ~25 m on a vertical ray from the
    /// ground at 500 steps, an optical depth of 0.12 in fog of visibility 1 km.
    pub fn density_integrals(
        medium: &Medium,
        r: f64,
        mu: f64,
        length: f64,
        steps: usize,
    ) -> [f64; CONSTITUENTS] {
        const BLOCK: usize = 64;
        // Independent partial sums (vertical SIMD adds): a strict left-to-right sum would not
        // vectorise.
        const PARTS: usize = 8;
        let mut d = [0.0; CONSTITUENTS];
        if length <= 0.0 || steps == 0 {
            return d;
        }
        let bottom = medium.bottom_radius_m;
        let (mut h, mut w) = ([0.0f64; BLOCK], [0.0f64; BLOCK]);
        let mut i0 = 0;
        while i0 < steps {
            let n = BLOCK.min(steps - i0);
            for j in 0..BLOCK {
                let u = ((i0 + j) as f64 + 0.5) / steps as f64;
                // Past the last step: weight 0 (the block is always processed whole).
                w[j] = if j < n { 2.0 * length * u / steps as f64 } else { 0.0 };
                h[j] = (radius_at(r, mu, length * u * u) - bottom).max(0.0);
            }
            for (k, dk) in d.iter_mut().enumerate() {
                let mut acc = [0.0f64; PARTS];
                match medium.profiles[k] {
                    Profile::None => {}
                    Profile::Exponential { scale_height_m } => {
                        let inv = 1.0 / scale_height_m;
                        for c in 0..BLOCK / PARTS {
                            for q in 0..PARTS {
                                let j = c * PARTS + q;
                                acc[q] += exp_fast(-h[j] * inv) * w[j];
                            }
                        }
                    }
                    Profile::Tent {
                        peak_m,
                        half_width_m,
                    } => {
                        for c in 0..BLOCK / PARTS {
                            for q in 0..PARTS {
                                let j = c * PARTS + q;
                                acc[q] += (1.0 - (h[j] - peak_m).abs() / half_width_m).max(0.0) * w[j];
                            }
                        }
                    }
                    layered @ Profile::Layered { .. } => {
                        // The boundary layer's uniform part is added exactly below.
                        for c in 0..BLOCK / PARTS {
                            for q in 0..PARTS {
                                let j = c * PARTS + q;
                                acc[q] += layered.density_above_uniform_layer(h[j]) * w[j];
                            }
                        }
                    }
                }
                *dk += acc.iter().sum::<f64>();
            }
            i0 += n;
        }
        for (k, dk) in d.iter_mut().enumerate() {
            if let Some(top) = medium.profiles[k].uniform_layer_top_m() {
                *dk += chord_inside_sphere(r, mu, bottom + top, length);
            }
        }
        d
    }
}

impl DensityIntegralTable {
    /// Builds the table (`n_r` × `n_mu` entries, `steps` quadrature intervals per ray).
    pub fn new(medium: &Medium, n_r: usize, n_mu: usize, steps: usize) -> Self {
        Self::new_unless(medium, n_r, n_mu, steps, &|| false)
            .unwrap_or_else(|| unreachable!("never cancelled"))
    }

    /// [`Self::new`], stopped (`None`) when `cancelled` returns true: it is asked once per row of
    /// radius, as the row's first entry starts, so an abandoned request stops within a row.
    pub fn new_unless(
        medium: &Medium,
        n_r: usize,
        n_mu: usize,
        steps: usize,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<Self> {
        let bottom = medium.bottom_radius_m;
        let top = medium.top_radius_m;
        let h = safe_sqrt(top * top - bottom * bottom);
        let layer_radius = layer_radii(medium);
        let data = (0..n_r * n_mu)
            .into_par_iter()
            .map(|idx| {
                let (i_r, i_mu) = (idx / n_mu, idx % n_mu);
                if i_mu == 0 && cancelled() {
                    return None;
                }
                let x_r = i_r as f64 / (n_r - 1) as f64;
                let x_mu = i_mu as f64 / (n_mu - 1) as f64;
                let rho = h * x_r;
                let r = safe_sqrt(rho * rho + bottom * bottom);
                let d_min = top - r;
                let d_max = rho + h;
                let d = d_min + x_mu * (d_max - d_min);
                let mu = if d == 0.0 {
                    1.0
                } else {
                    ((h * h - rho * rho - d * d) / (2.0 * r * d)).clamp(-1.0, 1.0)
                };
                let mut v = density_integrals(medium, r, mu, d, steps);
                for (k, rl) in layer_radius.iter().enumerate() {
                    if let Some(rl) = *rl {
                        v[k] = (v[k] - chord_inside_sphere(r, mu, rl, d)).max(0.0);
                    }
                }
                Some(v)
            })
            // Stops taking new entries at the first `None`.
            .collect::<Option<Vec<_>>>()?;
        Some(Self {
            n_r,
            n_mu,
            steps,
            bottom,
            top,
            layer_radius,
            data,
        })
    }

    /// The table as an image for the table store (tables kept between processes, `store::tables`): the density integrals, f64 exactly,
    /// as 16 hex digits per value (little-endian `[i_r][i_mu][k]` order) in a header attribute,
    /// with a description of what it was built for beside it; the single pixel is unused (a
    /// stored table is an EXR entry of the product cache like any other, so it is written
    /// atomically, checksummed, bound to its key and counted in the disk budget).
    pub fn to_image(&self, medium: &Medium) -> crate::Result<SpectralImage> {
        let mut image = SpectralImage::emissive(1, 1, &[550.0], vec![vec![0.0]])?;
        let meta = StoredDensity::of(medium, self.n_r, self.n_mu, self.steps);
        let json = serde_json::to_string(&meta)
            .map_err(|e| crate::Error::invalid("density_table", e.to_string()))?;
        let mut hex = String::with_capacity(self.data.len() * CONSTITUENTS * 16);
        for v in self.data.iter().flatten() {
            // Writing to a String cannot fail.
            let _ = write!(hex, "{:016x}", v.to_bits());
        }
        image.set_attribute(ATTR_DENSITY, json)?;
        image.set_attribute(ATTR_DENSITY_DATA, hex)?;
        Ok(image)
    }

    /// The table stored by [`Self::to_image`], if it was made for exactly this medium's radii
    /// and density profiles with these resolutions and holds only finite, non-negative values.
    pub fn from_image(
        image: &SpectralImage,
        medium: &Medium,
        n_r: usize,
        n_mu: usize,
        steps: usize,
    ) -> Option<Self> {
        let meta: serde_json::Value = serde_json::from_str(image.attribute(ATTR_DENSITY)?).ok()?;
        let expected = serde_json::to_value(StoredDensity::of(medium, n_r, n_mu, steps)).ok()?;
        let hex = image.attribute(ATTR_DENSITY_DATA)?.as_bytes();
        let n = n_r.checked_mul(n_mu)?;
        if meta != expected || n_r < 2 || n_mu < 2 || hex.len() != n * CONSTITUENTS * 16 {
            return None;
        }
        let mut data = Vec::with_capacity(n);
        for entry in hex.chunks_exact(CONSTITUENTS * 16) {
            let mut d = [0.0; CONSTITUENTS];
            for (k, digits) in entry.chunks_exact(16).enumerate() {
                let bits = u64::from_str_radix(std::str::from_utf8(digits).ok()?, 16).ok()?;
                let v = f64::from_bits(bits);
                if !(v.is_finite() && v >= 0.0) {
                    return None;
                }
                d[k] = v;
            }
            data.push(d);
        }
        Some(Self {
            n_r,
            n_mu,
            steps,
            bottom: medium.bottom_radius_m,
            top: medium.top_radius_m,
            layer_radius: layer_radii(medium),
            data,
        })
    }

    /// Density integrals from radius `r` along `mu` to the top. For rays below the horizon,
    /// the grazing ray's value (callers handle the ground's shadow separately).
    #[inline]
    pub fn lookup(&self, r: f64, mu: f64) -> [f64; CONSTITUENTS] {
        self.at_radius(r, 0.0).lookup(mu)
    }

    /// Fraction of the sun's disk above the local horizon at radius `r`, with the sun's zenith
    /// cosine `mu_s` (smoothstep over the disk's angular radius: no pop at sunset).
    #[inline]
    pub fn sun_visibility(&self, r: f64, mu_s: f64, sun_radius_rad: f64) -> f64 {
        self.at_radius(r, sun_radius_rad).sun_visibility(mu_s)
    }

    /// [`Self::lookup`] and [`Self::sun_visibility`] at one radius, with what depends on the
    /// radius alone computed once (for loops over many directions at one point: the precise
    /// table's order-1 pass); the same values.
    #[inline]
    pub fn at_radius(&self, r: f64, sun_radius_rad: f64) -> AtRadius<'_> {
        let mu_h_vis = horizon_mu(r.max(self.bottom), self.bottom);
        let r = r.clamp(self.bottom, self.top);
        let h = safe_sqrt(self.top * self.top - self.bottom * self.bottom);
        let rho = safe_sqrt(r * r - self.bottom * self.bottom);
        let x_r = (rho / h).clamp(0.0, 1.0);
        let fr = x_r * (self.n_r - 1) as f64;
        let ir = (fr.floor() as usize).min(self.n_r - 2);
        AtRadius {
            table: self,
            r,
            mu_h: horizon_mu(r, self.bottom),
            d_min: self.top - r,
            d_max: rho + h,
            ir,
            ar: fr - ir as f64,
            mu_h_vis,
            width: (sun_radius_rad * safe_sqrt(1.0 - mu_h_vis * mu_h_vis)).max(1e-9),
        }
    }
}

/// [`AtRadius::neg_optical_depths_many`]'s last step: for each sun `q`, the rows' (`[node][λ]`,
/// `n_l` wavelengths, from node `lo`) node `node[q]` and the next interpolated with weight
/// `am[q]`, negated, as f32 into `out[l * stride + q]` (0 where `vis[q]` is 0): each sun's two
/// rows read once for all its wavelengths.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gather_depths(
    n_l: usize,
    rows: &[f64],
    lo: usize,
    node: &[u32],
    am: &[f64],
    vis: &[f64],
    out: &mut [f32],
    stride: usize,
) {
    let n = vis.len().min(node.len()).min(am.len());
    for q in 0..n {
        let j = (node[q] as usize - lo) * n_l;
        let r = &rows[j..j + 2 * n_l];
        let a = am[q];
        let on = vis[q] > 0.0;
        for l in 0..n_l {
            let od = r[l] * (1.0 - a) + r[n_l + l] * a;
            out[l * stride + q] = if on { -od as f32 } else { 0.0 };
        }
    }
}

/// [`gather_depths`] for three wavelengths, the output's three rows sliced first (no bounds
/// check or index arithmetic per wavelength): the same values.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gather_depths_rgb(
    rows: &[f64],
    lo: usize,
    node: &[u32],
    am: &[f64],
    vis: &[f64],
    out: &mut [f32],
    stride: usize,
) {
    let n = vis.len().min(node.len()).min(am.len());
    let (o0, rest) = out.split_at_mut(stride);
    let (o1, o2) = rest.split_at_mut(stride);
    let (o0, o1, o2) = (&mut o0[..n], &mut o1[..n], &mut o2[..n]);
    let (node, am, vis) = (&node[..n], &am[..n], &vis[..n]);
    for q in 0..n {
        let j = (node[q] as usize - lo) * 3;
        let r: &[f64; 6] = rows[j..j + 6].try_into().unwrap();
        let a = am[q];
        let on = vis[q] > 0.0;
        let od = |l: usize| -(r[l] * (1.0 - a) + r[3 + l] * a) as f32;
        o0[q] = if on { od(0) } else { 0.0 };
        o1[q] = if on { od(1) } else { 0.0 };
        o2[q] = if on { od(2) } else { 0.0 };
    }
}

/// The optical depth of each wavelength (`ext[l]` · the density integrals) at a μ node of the
/// table's two radius rows (`v0`, `v1`) interpolated in r with weight `ar`, into `out`.
#[inline(always)]
fn node_depth(
    ext: &[[f64; CONSTITUENTS]],
    v0: &[f64; CONSTITUENTS],
    v1: &[f64; CONSTITUENTS],
    ar: f64,
    out: &mut [f64],
) {
    let d: [f64; CONSTITUENTS] = std::array::from_fn(|k| v0[k] * (1.0 - ar) + v1[k] * ar);
    for (o, e) in out.iter_mut().zip(ext) {
        *o = e[0] * d[0] + e[1] * d[1] + e[2] * d[2];
    }
}

/// [`node_depth`] of the μ nodes `nodes` of the rows, `[node][λ]`, into `rows`.
#[inline(always)]
fn node_depths(
    ext: &[[f64; CONSTITUENTS]],
    row0: &[[f64; CONSTITUENTS]],
    row1: &[[f64; CONSTITUENTS]],
    ar: f64,
    nodes: std::ops::RangeInclusive<usize>,
    rows: &mut [f64],
) {
    let n_l = ext.len();
    let (row0, row1) = (&row0[nodes.clone()], &row1[nodes]);
    for (o, (v0, v1)) in rows.chunks_exact_mut(n_l).zip(row0.iter().zip(row1)) {
        node_depth(ext, v0, v1, ar, o);
    }
}

/// [`node_depths`] and [`gather_depths`] sun by sun, each sun's two nodes formed where it reads
/// them (for fewer suns than the nodes they span): the same operations, so the same values.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn direct_depths<const N: usize>(
    ext: &[[f64; CONSTITUENTS]; N],
    row0: &[[f64; CONSTITUENTS]],
    row1: &[[f64; CONSTITUENTS]],
    ar: f64,
    node: &[u32],
    am: &[f64],
    vis: &[f64],
    out: &mut [f32],
    stride: usize,
) {
    let n = vis.len().min(node.len()).min(am.len());
    for q in 0..n {
        let j = node[q] as usize;
        let (mut r0, mut r1) = ([0.0; N], [0.0; N]);
        node_depth(ext, &row0[j], &row1[j], ar, &mut r0);
        node_depth(ext, &row0[j + 1], &row1[j + 1], ar, &mut r1);
        let a = am[q];
        let on = vis[q] > 0.0;
        for l in 0..N {
            let od = r0[l] * (1.0 - a) + r1[l] * a;
            out[l * stride + q] = if on { -od as f32 } else { 0.0 };
        }
    }
}

/// One sun's place in the transmittance table ([`AtRadius::sun_position`]).
struct SunPosition {
    vis: f64,
    mu: f64,
    dist: f64,
    node: f64,
    frac: f64,
}

/// Buffers of [`AtRadius::neg_optical_depths_many`], kept between calls.
#[derive(Default)]
pub struct OpticalDepthScratch {
    /// Per sun: the μ node below and the weight of the one above.
    node: Vec<u32>,
    am: Vec<f64>,
    /// `[node][λ]`: the optical depths of the nodes the suns read.
    rows: Vec<f64>,
}

/// The density table at one radius ([`DensityIntegralTable::at_radius`]).
pub struct AtRadius<'a> {
    table: &'a DensityIntegralTable,
    /// The radius, clamped to the atmosphere.
    r: f64,
    /// Horizon zenith cosine there.
    mu_h: f64,
    /// Shortest and longest distance to the top from there.
    d_min: f64,
    d_max: f64,
    /// Radius interpolation position.
    ir: usize,
    ar: f64,
    /// Horizon zenith cosine at the unclamped radius (above the ground) and width of the sun's
    /// disk across it, for [`Self::sun_visibility`].
    mu_h_vis: f64,
    width: f64,
}

impl AtRadius<'_> {
    /// [`DensityIntegralTable::lookup`] at this radius.
    #[inline(always)]
    pub fn lookup(&self, mu: f64) -> [f64; CONSTITUENTS] {
        let t = self.table;
        let mu = mu.max(self.mu_h);
        let d = distance_to_sphere_far(self.r, mu, t.top).unwrap_or(0.0);
        let (d_min, d_max) = (self.d_min, self.d_max);
        let x_mu = if d_max > d_min {
            ((d - d_min) / (d_max - d_min)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let fm = x_mu * (t.n_mu - 1) as f64;
        let im = (fm.floor() as usize).min(t.n_mu - 2);
        let (ir, ar, am) = (self.ir, self.ar, fm - im as f64);
        let at = |i: usize, j: usize| &t.data[i * t.n_mu + j];
        let mut out = [0.0; CONSTITUENTS];
        for (k, o) in out.iter_mut().enumerate() {
            let v0 = at(ir, im)[k] * (1.0 - am) + at(ir, im + 1)[k] * am;
            let v1 = at(ir + 1, im)[k] * (1.0 - am) + at(ir + 1, im + 1)[k] * am;
            *o = v0 * (1.0 - ar) + v1 * ar;
            if let Some(rl) = t.layer_radius[k] {
                *o += chord_inside_sphere(self.r, mu, rl, d);
            }
        }
        out
    }

    /// [`DensityIntegralTable::sun_visibility`] at this radius (with the sun radius given to
    /// [`DensityIntegralTable::at_radius`]).
    #[inline(always)]
    pub fn sun_visibility(&self, mu_s: f64) -> f64 {
        let x = ((mu_s - self.mu_h_vis) / self.width * 0.5 + 0.5).clamp(0.0, 1.0);
        x * x * (3.0 - 2.0 * x)
    }

    /// Whether a constituent has a uniform layer (its chord is added per direction), where
    /// [`Self::neg_optical_depths_many`] does not apply.
    #[inline]
    pub fn has_layers(&self) -> bool {
        self.table.layer_radius.iter().any(Option::is_some)
    }

    /// One sun's place in the table, branch-free (so the loops of [`Self::lookup_many`] and
    /// [`Self::neg_optical_depths_many`] vectorise): [`Self::sun_visibility`], μs raised to the
    /// horizon's, [`Self::lookup`]'s `distance_to_sphere_far(..).unwrap_or(0.0)`, and the μ node
    /// and fraction of the row (`spans`: whether the row's distances span an interval, else
    /// every x_μ is 0; `scale` = n_μ − 1, `last` = n_μ − 2).
    #[inline(always)]
    fn sun_position(&self, mu_s: f64, spans: bool, scale: f64, last: f64) -> SunPosition {
        let (r, top, d_min, d_max) = (self.r, self.table.top, self.d_min, self.d_max);
        let x = ((mu_s - self.mu_h_vis) / self.width * 0.5 + 0.5).clamp(0.0, 1.0);
        let mu = mu_s.max(self.mu_h);
        let disc = r * r * (mu * mu - 1.0) + top * top;
        let tq = -r * mu + disc.sqrt();
        let dist = if disc >= 0.0 && tq >= 0.0 { tq } else { 0.0 };
        let x_in = ((dist - d_min) / (d_max - d_min)).clamp(0.0, 1.0);
        let x_mu = if spans { x_in } else { 0.0 };
        let fm = x_mu * scale;
        let node = fm.floor().min(last);
        SunPosition {
            vis: x * x * (3.0 - 2.0 * x),
            mu,
            dist,
            node,
            frac: fm - node,
        }
    }

    /// For each sun zenith cosine `mu_s[t]`: [`Self::sun_visibility`] into `vis[t]` and, for
    /// each wavelength `l`, the sun's optical depth from here, `ext[l] · `[`Self::lookup`]`(μs)`
    /// (0 where the sun is hidden), negated and rounded to f32, into `out[l * stride + t]`.
    /// The table's two radius rows are interpolated in r and turned into optical depths once
    /// for the μ nodes the suns read, so each sun interpolates one row of `ext.len()` values
    /// in μ instead of four corners of every constituent: the same linear interpolation as
    /// [`Self::lookup_many`]'s (its sums in another order: a few units in the last place of the
    /// f64 optical depth). Not for tables with uniform layers ([`Self::has_layers`]).
    #[inline(always)]
    pub fn neg_optical_depths_many(
        &self,
        mu_s: &[f64],
        ext: &[[f64; CONSTITUENTS]],
        vis: &mut [f64],
        out: &mut [f32],
        stride: usize,
        scratch: &mut OpticalDepthScratch,
    ) {
        debug_assert!(!self.has_layers());
        let t = self.table;
        let n = mu_s.len().min(vis.len());
        let n_l = ext.len();
        let (d_min, d_max) = (self.d_min, self.d_max);
        let ar = self.ar;
        let last = (t.n_mu - 2) as f64;
        let scale = (t.n_mu - 1) as f64;
        let spans = d_max > d_min;
        let OpticalDepthScratch { node, am, rows } = scratch;
        node.resize(n, 0);
        am.resize(n, 0.0);
        let (node, am, vis) = (&mut node[..n], &mut am[..n], &mut vis[..n]);
        // `lookup_many`'s first loop: visibility and interpolation position, branch-free; the
        // node (an exact integer, 0 ≤ node ≤ n_μ − 2) as an integer.
        for q in 0..n {
            let p = self.sun_position(mu_s[q], spans, scale, last);
            vis[q] = p.vis;
            node[q] = p.node as u32;
            am[q] = p.frac;
        }
        if n == 0 {
            return;
        }
        let lo = node.iter().fold(u32::MAX, |a, &b| a.min(b)) as usize;
        let hi = node.iter().fold(0, |a, &b| a.max(b)) as usize;
        // The optical depths of the μ nodes lo..=hi + 1 at this radius, `[node][λ]`.
        let row0 = &t.data[self.ir * t.n_mu..][..t.n_mu];
        let row1 = &t.data[(self.ir + 1) * t.n_mu..][..t.n_mu];
        // Fewer suns than the nodes they span (a focused ray's few suns): each sun's own two.
        if let (Ok(ext), true) = (<&[_; 3]>::try_from(ext), 2 * n < hi + 2 - lo) {
            direct_depths(ext, row0, row1, ar, node, am, vis, out, stride);
            return;
        }
        rows.clear();
        rows.resize((hi + 2 - lo) * n_l, 0.0);
        // RGB written out (the loops over wavelengths unrolled).
        if n_l == 3 {
            node_depths(&ext[..3], row0, row1, ar, lo..=hi + 1, rows);
            gather_depths_rgb(rows, lo, node, am, vis, out, stride);
        } else {
            node_depths(ext, row0, row1, ar, lo..=hi + 1, rows);
            gather_depths(n_l, rows, lo, node, am, vis, out, stride);
        }
    }

    /// The suns of `mu_s` from the first to the last whose [`Self::sun_visibility`] is positive
    /// (empty where none is): the others' single scattering is 0, so loops over suns may skip
    /// them. Scans from both ends, so it costs what the hidden suns at the ends do.
    #[inline(always)]
    pub fn visible_range(&self, mu_s: &[f64]) -> std::ops::Range<usize> {
        // A sun at or below `below` is hidden (its smoothstep argument before the clamp is
        // below −0.5): one comparison per sun, the division only for the suns above it.
        let below = self.mu_h_vis - 2.0 * self.width - 1e-12 * (1.0 + self.mu_h_vis.abs());
        let seen = |&m: &f64| m > below && self.sun_visibility(m) > 0.0;
        match mu_s.iter().position(seen) {
            Some(first) => first..mu_s.len() - mu_s.iter().rev().position(seen).unwrap_or(0),
            None => 0..0,
        }
    }

    /// For each sun zenith cosine `mu_s[t]`: [`Self::sun_visibility`] into `vis[t]` and, where
    /// it is positive, [`Self::lookup`] into `d[k][t]` (0 where the sun is hidden): the same
    /// values as those calls one sun at a time, with the square roots, divisions and
    /// interpolation of a block of suns computed as vectors (only the table reads stay
    /// scalar), for loops compiled with SIMD ([`crate::simd_dispatch`]).
    #[inline(always)]
    pub fn lookup_many(&self, mu_s: &[f64], vis: &mut [f64], d: [&mut [f64]; CONSTITUENTS]) {
        const BLOCK: usize = 16;
        let t = self.table;
        let n = mu_s.len().min(vis.len());
        let [d0, d1, d2] = d;
        let (d_min, d_max) = (self.d_min, self.d_max);
        let r = self.r;
        let (ir, ar) = (self.ir, self.ar);
        let last = (t.n_mu - 2) as f64;
        let scale = (t.n_mu - 1) as f64;
        let row0 = &t.data[ir * t.n_mu..(ir + 1) * t.n_mu];
        let row1 = &t.data[(ir + 1) * t.n_mu..(ir + 2) * t.n_mu];
        let mut mu = [0.0f64; BLOCK];
        let mut dist = [0.0f64; BLOCK];
        let mut imf = [0.0f64; BLOCK];
        let mut am = [0.0f64; BLOCK];
        // `[corner][constituent][sun]`: the table's four (r, μ) corners.
        let mut c = [[[0.0f64; BLOCK]; CONSTITUENTS]; 4];
        // Whether the row's distances span an interval (else every x_μ is 0), hoisted so the
        // loop below is branch-free and vectorises (the same operations per sun).
        let spans = d_max > d_min;
        for s0 in (0..n).step_by(BLOCK) {
            let m = BLOCK.min(n - s0);
            let mu_s = &mu_s[s0..s0 + m];
            let vis_b = &mut vis[s0..s0 + m];
            for q in 0..m {
                let p = self.sun_position(mu_s[q], spans, scale, last);
                vis_b[q] = p.vis;
                mu[q] = p.mu;
                dist[q] = p.dist;
                imf[q] = p.node;
                am[q] = p.frac;
            }
            for q in 0..m {
                // 0 ≤ imf ≤ n_mu − 2: an exact small integer.
                let im = imf[q] as usize;
                let (v00, v01, v10, v11) = (&row0[im], &row0[im + 1], &row1[im], &row1[im + 1]);
                for k in 0..CONSTITUENTS {
                    c[0][k][q] = v00[k];
                    c[1][k][q] = v01[k];
                    c[2][k][q] = v10[k];
                    c[3][k][q] = v11[k];
                }
            }
            for (k, dk) in [&mut *d0, &mut *d1, &mut *d2].into_iter().enumerate() {
                let dk = &mut dk[s0..s0 + m];
                let (c00, c01, c10, c11) = (&c[0][k], &c[1][k], &c[2][k], &c[3][k]);
                for q in 0..m {
                    let a = am[q];
                    let v0 = c00[q] * (1.0 - a) + c01[q] * a;
                    let v1 = c10[q] * (1.0 - a) + c11[q] * a;
                    dk[q] = v0 * (1.0 - ar) + v1 * ar;
                }
                if let Some(rl) = t.layer_radius[k] {
                    for q in 0..m {
                        dk[q] += chord_inside_sphere(r, mu[q], rl, dist[q]);
                    }
                }
                for q in 0..m {
                    dk[q] = if vis[s0 + q] > 0.0 { dk[q] } else { 0.0 };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atmosphere::presets::preset;
    use crate::spectrum::Wavelengths;

    #[test]
    fn table_takes_a_boundary_layer_top_exactly_in_fog() {
        // Visibility 1 km in a 1.5 km boundary layer (optical depth 5.85 at 550 nm): the sun's
        // transmittance through the table just under and over the layer's top, where linear
        // interpolation across the density integral's kink read the optical depth up to 0.36 too
        // large, against the chord (exact) plus the free troposphere integrated finely.
        let mut a = preset("earth").unwrap();
        crate::atmosphere::haze::Haze {
            visibility_km: Some(1.0),
            aerosol_type: None,
            boundary_layer_top_m: Some(1500.0),
        }
        .apply(&mut a)
        .unwrap();
        let m = Medium::new(&a, &Wavelengths::parse("440").unwrap(), None).unwrap();
        let table = DensityIntegralTable::new(&m, 64, 256, 500);
        let bl = m.bottom_radius_m + 1500.0;
        for &h in &[1100.0, 1300.0, 1400.0, 1450.0, 1499.0, 1501.0, 1600.0] {
            let r = m.bottom_radius_m + h;
            for &mu in &[1.0, 0.5, 0.26, 0.1] {
                let d = distance_to_sphere_far(r, mu, m.top_radius_m).unwrap();
                let mut exact = density_integrals(&m, r, mu, d, 100_000);
                // The chord directly, independently of the one density_integrals adds.
                let t_exit = distance_to_sphere_far(r, mu, bl).unwrap_or(0.0);
                let bl_part = if r < bl { t_exit } else { 0.0 };
                assert!((chord_inside_sphere(r, mu, bl, d) - bl_part).abs() < 1e-6);
                exact[1] = exact[1] - chord_inside_sphere(r, mu, bl, d) + bl_part;
                let tau_e = m.optical_depth(0, &exact);
                let tau_g = m.optical_depth(0, &table.lookup(r, mu));
                // The rest interpolates to ≤ 0.005 + 0.1 %: the free troposphere's own, smaller
                // kink at the top (relative density 0.0026 of the layer's); without the chord the
                // error was 0.08–0.36 per unit airmass.
                assert!(
                    (tau_e - tau_g).abs() < 0.01 + 2e-3 * tau_e,
                    "h {h} mu {mu}: {tau_e} vs {tau_g}"
                );
            }
        }
    }

    crate::simd_dispatch_avx512! {
        /// [`AtRadius::lookup_many`] compiled as the bundle's kernels compile it.
        fn many(
            at: &AtRadius<'_>,
            mu_s: &[f64],
            vis: &mut [f64],
            d0: &mut [f64],
            d1: &mut [f64],
            d2: &mut [f64],
        ) {
            at.lookup_many(mu_s, vis, [d0, d1, d2]);
        }
    }

    #[test]
    fn lookups_of_many_suns_equal_the_single_lookups() {
        // A layered aerosol (its chord added back per sun) and the plain preset, at the ground,
        // inside and above the layer and near the top; suns from below the horizon (hidden: 0)
        // through the horizon's disk to the zenith, more than one block of them.
        let plain = preset("earth").unwrap();
        let mut foggy = plain.clone();
        crate::atmosphere::haze::Haze {
            visibility_km: Some(2.0),
            aerosol_type: None,
            boundary_layer_top_m: Some(1500.0),
        }
        .apply(&mut foggy)
        .unwrap();
        let mu_s: Vec<f64> = (0..203).map(|i| -0.3 + 1.3 * i as f64 / 202.0).collect();
        for a in [&plain, &foggy] {
            let m = Medium::new(a, &Wavelengths::parse("550").unwrap(), None).unwrap();
            let table = DensityIntegralTable::new(&m, 32, 128, 200);
            for &h in &[0.0, 700.0, 1500.0, 1600.0, 30_000.0, 99_990.0] {
                let at = table.at_radius(m.bottom_radius_m + h, m.sun_angular_radius_rad);
                let n = mu_s.len();
                let mut vis = vec![f64::NAN; n];
                let mut d: [Vec<f64>; CONSTITUENTS] = std::array::from_fn(|_| vec![f64::NAN; n]);
                let [d0, d1, d2] = &mut d;
                many(&at, &mu_s, &mut vis, d0, d1, d2);
                let mut hidden = 0;
                for (t, &mu) in mu_s.iter().enumerate() {
                    let v = at.sun_visibility(mu);
                    let want = if v > 0.0 {
                        at.lookup(mu)
                    } else {
                        hidden += 1;
                        [0.0; CONSTITUENTS]
                    };
                    assert_eq!(vis[t].to_bits(), v.to_bits(), "h {h} mu_s {mu}");
                    for k in 0..CONSTITUENTS {
                        assert_eq!(
                            d[k][t].to_bits(),
                            want[k].to_bits(),
                            "h {h} mu_s {mu} k {k}"
                        );
                    }
                }
                assert!(hidden > 0 && hidden < n, "h {h}: {hidden} hidden");
            }
        }
    }

    #[test]
    fn visible_range_holds_every_lit_sun() {
        // Suns from below the horizon to the zenith, both ways round, and all hidden: the
        // range holds every sun `sun_visibility` lights and starts and ends on lit ones.
        let m = Medium::new(
            &preset("earth").unwrap(),
            &Wavelengths::parse("550").unwrap(),
            None,
        )
        .unwrap();
        let table = DensityIntegralTable::new(&m, 16, 64, 50);
        let up: Vec<f64> = (0..203).map(|i| -0.3 + 1.3 * i as f64 / 202.0).collect();
        let down: Vec<f64> = up.iter().rev().copied().collect();
        let dark: Vec<f64> = up.iter().map(|&mu| mu.min(-0.2)).collect();
        for &h in &[0.0, 1500.0, 30_000.0, 99_990.0] {
            let at = table.at_radius(m.bottom_radius_m + h, m.sun_angular_radius_rad);
            for mu_s in [&up, &down, &dark] {
                let range = at.visible_range(mu_s);
                let lit: Vec<usize> = (0..mu_s.len())
                    .filter(|&t| at.sun_visibility(mu_s[t]) > 0.0)
                    .collect();
                match (lit.first(), lit.last()) {
                    (Some(&a), Some(&b)) => assert_eq!(range, a..b + 1, "h {h}"),
                    _ => assert!(range.is_empty(), "h {h}"),
                }
            }
            assert!(at.visible_range(&dark).is_empty());
            assert!(at.visible_range(&up).len() < up.len());
        }
    }

    crate::simd_dispatch_avx512! {
        /// [`AtRadius::neg_optical_depths_many`] compiled as the bundle's kernels compile it.
        fn depths(
            at: &AtRadius<'_>,
            mu_s: &[f64],
            ext: &[[f64; CONSTITUENTS]],
            vis: &mut [f64],
            out: &mut [f32],
            stride: usize,
            scratch: &mut OpticalDepthScratch,
        ) {
            at.neg_optical_depths_many(mu_s, ext, vis, out, stride, scratch);
        }
    }

    #[test]
    fn optical_depths_of_many_suns_equal_the_single_lookups() {
        // Against `lookup` one sun at a time, the extinction applied after: the same
        // interpolation summed in another order, so within a few units in the last place of
        // the f64 optical depth, one of the f32 it is rounded to; the visibility bit for bit.
        // Each of its paths: RGB and other wavelength counts, many suns (the nodes' depths
        // gathered) and a few far apart (each sun's own two nodes).
        let many: Vec<f64> = (0..203).map(|i| -0.3 + 1.3 * i as f64 / 202.0).collect();
        let few = vec![-0.21, 0.05, 0.62, 0.97];
        for wavelengths in ["440,550,680", "450,520,600,680,750"] {
            let m = Medium::new(
                &preset("earth").unwrap(),
                &Wavelengths::parse(wavelengths).unwrap(),
                None,
            )
            .unwrap();
            let table = DensityIntegralTable::new(&m, 32, 128, 200);
            let ext: Vec<[f64; CONSTITUENTS]> = (0..m.len())
                .map(|l| std::array::from_fn(|k| m.extinction_per_m[k][l]))
                .collect();
            let mut scratch = OpticalDepthScratch::default();
            for mu_s in [&many, &few] {
                let n = mu_s.len();
                for &h in &[0.0, 700.0, 30_000.0, 99_990.0] {
                    let at = table.at_radius(m.bottom_radius_m + h, m.sun_angular_radius_rad);
                    assert!(!at.has_layers());
                    let stride = n + 5;
                    let mut vis = vec![f64::NAN; n];
                    let mut out = vec![f32::NAN; ext.len() * stride];
                    depths(&at, mu_s, &ext, &mut vis, &mut out, stride, &mut scratch);
                    for (t, &mu) in mu_s.iter().enumerate() {
                        let v = at.sun_visibility(mu);
                        assert_eq!(vis[t].to_bits(), v.to_bits(), "h {h} mu_s {mu}");
                        let d = if v > 0.0 {
                            at.lookup(mu)
                        } else {
                            [0.0; CONSTITUENTS]
                        };
                        for (l, e) in ext.iter().enumerate() {
                            let want = -(e[0] * d[0] + e[1] * d[1] + e[2] * d[2]);
                            let got = out[l * stride + t] as f64;
                            assert!(
                                (got - want).abs() <= 1e-7 * want.abs(),
                                "{wavelengths} h {h} mu_s {mu} l {l}: {got} vs {want}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn table_matches_direct_integration_everywhere() {
        let m = Medium::new(
            &preset("earth").unwrap(),
            &Wavelengths::parse("550").unwrap(),
            None,
        )
        .unwrap();
        let table = DensityIntegralTable::new(&m, 64, 256, 2000);
        for &h in &[0.0, 10.0, 1500.0, 12_000.0, 60_000.0, 99_999.0] {
            let r = m.bottom_radius_m + h;
            let mu_h = horizon_mu(r, m.bottom_radius_m);
            for &mu in &[1.0, 0.5, 0.1, 0.02, 0.0, mu_h + 0.01, mu_h + 1e-4] {
                let d = distance_to_sphere_far(r, mu, m.top_radius_m).unwrap();
                let exact = density_integrals(&m, r, mu, d, 20_000);
                let got = table.lookup(r, mu);
                let tau_e = m.optical_depth(0, &exact);
                let tau_g = m.optical_depth(0, &got);
                // Transmittance error, the quantity that matters: within 0.5 % (or absolute 1e-4).
                let (te, tg) = ((-tau_e).exp(), (-tau_g).exp());
                assert!(
                    (te - tg).abs() <= 0.005 * te + 1e-4,
                    "h {h} mu {mu}: {te} vs {tg}"
                );
            }
        }
    }
}
