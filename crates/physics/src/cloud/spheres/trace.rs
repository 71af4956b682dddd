//! Ray traversal of the sphere hierarchy (Ostroushko et al., "bounding primitives"): a ray enters a
//! sphere's children only if it hits the sphere, stops at the leaves or where the level of detail
//! says a sphere is too small to split further, and multiplies the transmittances of eq 3.

use super::model::{Sphere, SphereCloud, CHILDREN};
use super::optics::sphere_transmittance;
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

/// Relative inflation of bounding tests, covering the single-precision rounding of tangent
/// children so pruning never drops a leaf the ray touches.
const BOUND_SLACK: f64 = 1e-5;

pub use crate::camera::{Camera, Ray};

/// Level of detail (Ostroushko et al., conclusion): a sphere whose angular diameter seen from `eye_m` is
/// below `min_angle_rad` is not split further and counts as a leaf.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lod {
    /// Viewpoint, metres.
    pub eye_m: DVec3,
    /// Smallest angular diameter worth splitting, radians (typically one pixel).
    pub min_angle_rad: f64,
}

impl Lod {
    /// Whether a sphere of radius `r` centred at `c` is too small to split: 2·asin(r/dist) below
    /// the threshold, i.e. r/dist < sin(min_angle/2). Never true with the eye inside the sphere.
    #[inline]
    fn stops(&self, c: DVec3, r: f64, sin2_half: f64) -> bool {
        let dist2 = c.distance_squared(self.eye_m);
        dist2 > r * r && r * r < dist2 * sin2_half
    }
}

/// Work counters of a traversal.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct TraceStats {
    /// Ray–sphere tests performed.
    pub spheres_tested: u64,
    /// Spheres that contributed a transmittance factor.
    pub spheres_used: u64,
}

impl std::ops::AddAssign for TraceStats {
    fn add_assign(&mut self, o: Self) {
        self.spheres_tested += o.spheres_tested;
        self.spheres_used += o.spheres_used;
    }
}

/// Ray against one sphere: (distance of the centre from the line, entry t, exit t) or None.
#[inline]
fn intersect(ray: &Ray, c: DVec3, r: f64) -> Option<(f64, f64, f64)> {
    let oc = c - ray.origin_m;
    let b = oc.dot(ray.dir);
    let d2 = (oc.length_squared() - b * b).max(0.0);
    if d2 >= r * r {
        return None;
    }
    let h = (r * r - d2).sqrt();
    Some((d2.sqrt(), b - h, b + h))
}

/// The factor of eq 3 for a sphere the segment passes through, or None when it misses.
#[inline]
fn factor(ray: &Ray, c: DVec3, r: f64, sigma: f64) -> Option<f64> {
    let (d, t0, t1) = intersect(ray, c, r)?;
    let chord = t1.min(ray.t_max_m) - t0.max(0.0);
    (chord > 0.0).then(|| sphere_transmittance(sigma, chord, d, r))
}

/// Whether the segment may touch sphere (c, r), with slack for rounding.
#[inline]
fn bound_hit(ray: &Ray, c: DVec3, r: f64) -> bool {
    let r = r * (1.0 + BOUND_SLACK) + 1e-6;
    match intersect(ray, c, r) {
        Some((_, t0, t1)) => t1 > 0.0 && t0 < ray.t_max_m,
        None => false,
    }
}

impl SphereCloud {
    /// Transmittance along `ray` through the cloud: the product over the spheres reached of
    /// eq 3, descending only into spheres the ray hits, down to the leaves or, with `lod`, to the
    /// first sphere too small to split. Leaves are multiplied in index order.
    pub fn transmittance(&self, ray: &Ray, lod: Option<&Lod>, stats: &mut TraceStats) -> f64 {
        let sigma = self.extinction_per_m();
        let base = self.centre_m();
        let k_max = self.max_level();
        let sin2_half = lod.map_or(0.0, |l| (0.5 * l.min_angle_rad).sin().powi(2));
        let mut t = 1.0;
        // Depth-first stack of (level, index); children pushed in reverse so they pop in order.
        // Depth ≤ MAX_LEVELS and at most four siblings wait per level, so 64 entries suffice.
        let mut stack = [(0u32, 0u32); 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let (k, i) = stack[sp];
            let s: &Sphere = &self.level(k)[i as usize];
            let c = base + s.centre_m();
            let r = s.radius as f64;
            stats.spheres_tested += 1;
            let leaf = k == k_max || lod.is_some_and(|l| l.stops(c, r, sin2_half));
            if leaf {
                if let Some(f) = factor(ray, c, r, sigma) {
                    t *= f;
                    stats.spheres_used += 1;
                }
            } else if bound_hit(ray, c, r) {
                for j in (0..CHILDREN as u32).rev() {
                    stack[sp] = (k + 1, i * CHILDREN as u32 + j);
                    sp += 1;
                }
            }
        }
        t
    }

    /// Transmittance by brute force: eq 3 over every leaf in index order, no hierarchy.
    pub fn transmittance_brute_force(&self, ray: &Ray) -> f64 {
        let sigma = self.extinction_per_m();
        let base = self.centre_m();
        self.leaves()
            .iter()
            .filter_map(|s| factor(ray, base + s.centre_m(), s.radius as f64, sigma))
            .product()
    }
}

impl SphereCloud {
    /// Transmittance image (row-major, row 0 at the top), rows in parallel. `lod_pixels`: split
    /// only spheres wider than this many pixels (None: always descend to the leaves).
    pub fn render_transmittance(
        &self,
        camera: &Camera,
        lod_pixels: Option<f64>,
    ) -> Result<(Vec<f32>, TraceStats)> {
        camera.validate()?;
        if let Some(p) = lod_pixels {
            if !(p.is_finite() && p > 0.0) {
                return Err(Error::out_of_range("lod_pixels", p, "a finite value > 0"));
            }
        }
        let lod = lod_pixels.map(|p| Lod {
            eye_m: camera.eye_m,
            min_angle_rad: p * camera.pixel_angle_rad(),
        });
        let w = camera.width;
        let mut image = vec![0f32; w * camera.height];
        let stats = image
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                let mut st = TraceStats::default();
                for (x, px) in row.iter_mut().enumerate() {
                    *px = self.transmittance(&camera.ray(x, y), lod.as_ref(), &mut st) as f32;
                }
                st
            })
            .reduce(TraceStats::default, |mut a, b| {
                a += b;
                a
            });
        Ok((image, stats))
    }
}
