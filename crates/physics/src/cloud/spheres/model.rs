//! Building the sphere hierarchy (Ostroushko et al., "Mathematical model of the cloud").

use super::optics::extinction_from_mor_per_m;
use crate::{Error, Result};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Deepest level accepted. Level K holds 5^K spheres and all levels (5^(K+1) − 1)/4, 16 bytes
/// each: K = 10 is 9 765 625 leaves and 195 MB, the paper's largest case (table 1).
pub const MAX_LEVELS: u32 = 10;
/// Children per sphere (Ostroushko et al.: "divided into five similar figures").
pub const CHILDREN: usize = 5;

/// Inputs of the model (Ostroushko et al.). Deserialises from the `spheres` block of a scene (see
/// `config/scenes/sphere-cloud.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereCloudParams {
    /// Level of detail K: the number of subdivisions (0..=[`MAX_LEVELS`]).
    pub levels: u32,
    /// Cloud sizes a, b, c along x, y, z, metres.
    pub size_m: [f64; 3],
    /// Centre of the base sphere, metres.
    #[serde(default)]
    pub centre_m: [f64; 3],
    /// Meteorological optical range S_M inside the cloud, metres.
    pub mor_m: f64,
    /// Seed of the random choices.
    pub seed: u64,
    /// Range of the radius factor I_j (child radius = I_j · parent radius); the paper's cumulus
    /// setting is 0.26–0.76.
    #[serde(default = "default_radius_range")]
    pub radius_factor_range: [f64; 2],
    /// Range of the offset factor s_j; the paper's cumulus setting is 0.9–1.
    #[serde(default = "default_offset_range")]
    pub offset_factor_range: [f64; 2],
}

fn default_radius_range() -> [f64; 2] {
    [0.26, 0.76]
}
fn default_offset_range() -> [f64; 2] {
    [0.9, 1.0]
}

impl SphereCloudParams {
    /// A 2 km × 1.2 km × 1 km cumulus with the paper's cumulus ranges and a 60 m optical range.
    pub fn cumulus(levels: u32, seed: u64) -> Self {
        Self {
            levels,
            size_m: [2000.0, 1200.0, 1000.0],
            centre_m: [0.0, 0.0, 1500.0],
            mor_m: 60.0,
            seed,
            radius_factor_range: default_radius_range(),
            offset_factor_range: default_offset_range(),
        }
    }

    /// Checks every field; K is bounded so memory is (see [`MAX_LEVELS`]).
    pub fn validate(&self) -> Result<()> {
        if self.levels > MAX_LEVELS {
            return Err(Error::too_large(
                "levels",
                format!("K = {} would need 5^K leaf spheres", self.levels),
                format!("K <= {MAX_LEVELS}"),
            ));
        }
        if !self
            .size_m
            .iter()
            .all(|s| s.is_finite() && *s > 0.0 && *s <= 1e6)
        {
            return Err(Error::out_of_range(
                "size_m",
                format!("{:?}", self.size_m),
                "each finite, > 0 and <= 1e6",
            ));
        }
        if !self.centre_m.iter().all(|c| c.is_finite()) {
            return Err(Error::invalid("centre_m", "must be finite"));
        }
        if !(self.mor_m.is_finite() && self.mor_m > 0.0) {
            return Err(Error::out_of_range(
                "mor_m",
                self.mor_m,
                "a finite value > 0",
            ));
        }
        let [i0, i1] = self.radius_factor_range;
        if !(i0 > 0.0 && i0 <= i1 && i1 < 1.0) {
            return Err(Error::out_of_range(
                "radius_factor_range",
                format!("{:?}", self.radius_factor_range),
                "0 < min <= max < 1",
            ));
        }
        let [s0, s1] = self.offset_factor_range;
        if !(s0 >= 0.0 && s0 <= s1 && s1 <= 1.0) {
            return Err(Error::out_of_range(
                "offset_factor_range",
                format!("{:?}", self.offset_factor_range),
                "0 <= min <= max <= 1",
            ));
        }
        Ok(())
    }
}

/// One sphere, stored in single precision relative to the cloud centre.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sphere {
    /// Centre relative to the cloud centre, metres.
    pub centre: [f32; 3],
    /// Radius, metres.
    pub radius: f32,
}

impl Sphere {
    /// Centre relative to the cloud centre, metres, in double precision.
    #[inline]
    pub fn centre_m(&self) -> DVec3 {
        DVec3::new(
            self.centre[0] as f64,
            self.centre[1] as f64,
            self.centre[2] as f64,
        )
    }
}

/// The hierarchy: `level(k)[i]` has children `level(k + 1)[5i .. 5i + 5]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereCloud {
    centre_m: DVec3,
    mor_m: f64,
    levels: Vec<Vec<Sphere>>,
}

impl SphereCloud {
    /// Builds the hierarchy (Ostroushko et al.). Level 0 is one sphere of radius min(a,b,c)/2 when K = 0,
    /// max(a,b,c)/2 otherwise; the first split scales the children's offsets by the deformation
    /// coefficients d = (a, b, c)/(2r⁰), later splits by 1. Child j of a sphere (x, r) has radius
    /// r_j = I_j·r and, with D = r − r_j and e = √(D² − (D·s_j)²) (the paper's f_Δ):
    /// 1: (x + D s d_x, y, z + ξe); 2: (x − D s d_x, y, z + ξe); 3: (x + ξe, y, z + D s d_z);
    /// 4: (x + ξe, y, z − D s d_z); 5: y − D s d_y and, for ξ = −1, x − e, for ξ = +1, z + e.
    /// Since s, d ≤ 1, every child lies inside its parent. The random numbers of each parent come
    /// from its own stream, so the result does not depend on thread count.
    pub fn new(params: &SphereCloudParams) -> Result<Self> {
        params.validate()?;
        let [a, b, c] = params.size_m;
        let k_max = params.levels;
        let r0 = if k_max == 0 {
            a.min(b).min(c) / 2.0
        } else {
            a.max(b).max(c) / 2.0
        };
        let deform0 = DVec3::new(a, b, c) / (2.0 * r0);
        let mut levels = vec![vec![Sphere {
            centre: [0.0; 3],
            radius: r0 as f32,
        }]];
        for k in 0..k_max {
            let parents = &levels[k as usize];
            let d = if k == 0 { deform0 } else { DVec3::ONE };
            let mut children = vec![Sphere::default(); parents.len() * CHILDREN];
            children
                .par_chunks_mut(CHILDREN)
                .zip(parents.par_iter())
                .enumerate()
                .for_each(|(i, (out, p))| {
                    let mut rng = parent_rng(params.seed, k, i as u64);
                    split(p, d, params, &mut rng, out);
                });
            levels.push(children);
        }
        Ok(Self {
            centre_m: DVec3::from_array(params.centre_m),
            mor_m: params.mor_m,
            levels,
        })
    }

    /// Linear interpolation of every sphere's centre and radius (and the optical range) between
    /// two realisations with the same K (Ostroushko et al., animation), `tau` in [0, 1]. Containment
    /// survives: it is a convex condition on (centre, radius) pairs.
    pub fn interpolate(a: &SphereCloud, b: &SphereCloud, tau: f64) -> Result<SphereCloud> {
        if a.levels.len() != b.levels.len() {
            return Err(Error::invalid(
                "levels",
                format!(
                    "realisations must share K to be interpolated ({} vs {})",
                    a.max_level(),
                    b.max_level()
                ),
            ));
        }
        if !(0.0..=1.0).contains(&tau) {
            return Err(Error::out_of_range("tau", tau, "0..=1"));
        }
        let t = tau as f32;
        // Exact at both ends: tau = 0 gives a, tau = 1 gives b.
        let lerp = |x: f32, y: f32| x * (1.0 - t) + y * t;
        let levels = a
            .levels
            .iter()
            .zip(&b.levels)
            .map(|(la, lb)| {
                la.par_iter()
                    .zip(lb.par_iter())
                    .map(|(p, q)| Sphere {
                        centre: std::array::from_fn(|i| lerp(p.centre[i], q.centre[i])),
                        radius: lerp(p.radius, q.radius),
                    })
                    .collect()
            })
            .collect();
        Ok(SphereCloud {
            centre_m: a.centre_m.lerp(b.centre_m, tau),
            mor_m: a.mor_m * (1.0 - tau) + b.mor_m * tau,
            levels,
        })
    }

    /// Centre of the base sphere, metres.
    pub fn centre_m(&self) -> DVec3 {
        self.centre_m
    }

    /// Meteorological optical range, metres.
    pub fn mor_m(&self) -> f64 {
        self.mor_m
    }

    /// Extinction coefficient inside a sphere, per metre (−ln 0.02 / S_M).
    pub fn extinction_per_m(&self) -> f64 {
        extinction_from_mor_per_m(self.mor_m)
    }

    /// Deepest level K.
    pub fn max_level(&self) -> u32 {
        (self.levels.len() - 1) as u32
    }

    /// Spheres of level `k` (5^k of them), centres relative to [`Self::centre_m`].
    pub fn level(&self, k: u32) -> &[Sphere] {
        &self.levels[k as usize]
    }

    /// Level of detail for a resolution (Ostroushko et al., conclusion: "choosing the desired level of
    /// detail, taking into account the angular resolution"): the deepest level whose mean sphere
    /// diameter is still at least `resolution_m` (a voxel size, or a pixel's footprint at the
    /// cloud's distance); level 0 if even the base sphere is smaller.
    pub fn level_for_resolution(&self, resolution_m: f64) -> u32 {
        let mut best = 0;
        for (k, level) in self.levels.iter().enumerate() {
            let mean_d =
                2.0 * level.iter().map(|s| s.radius as f64).sum::<f64>() / level.len() as f64;
            if mean_d >= resolution_m {
                best = k as u32;
            } else {
                break;
            }
        }
        best
    }

    /// The leaves (level K).
    pub fn leaves(&self) -> &[Sphere] {
        &self.levels[self.levels.len() - 1]
    }
}

/// Random stream of parent `index` at level `k`.
fn parent_rng(seed: u64, k: u32, index: u64) -> Pcg64Mcg {
    let mut z = seed ^ (k as u64).rotate_left(56) ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    Pcg64Mcg::seed_from_u64(z ^ (z >> 31))
}

/// The five children of `p` (Ostroushko et al.), drawing per child I_j, s_j and ξ_j in that order.
fn split(p: &Sphere, d: DVec3, params: &SphereCloudParams, rng: &mut Pcg64Mcg, out: &mut [Sphere]) {
    let [i0, i1] = params.radius_factor_range;
    let [s0, s1] = params.offset_factor_range;
    let c = p.centre_m();
    let r = p.radius as f64;
    for (j, child) in out.iter_mut().enumerate() {
        let big_i = i0 + (i1 - i0) * rng.random::<f64>();
        let s = s0 + (s1 - s0) * rng.random::<f64>();
        let xi = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let rj = big_i * r;
        let dd = r - rj;
        let along = dd * s;
        // f_Δ(C, R) = √(R² − C²): the other coordinate that keeps the child tangent inside.
        let e = (dd * dd - along * along).max(0.0).sqrt();
        let offset = match j {
            0 => DVec3::new(along * d.x, 0.0, xi * e),
            1 => DVec3::new(-along * d.x, 0.0, xi * e),
            2 => DVec3::new(xi * e, 0.0, along * d.z),
            3 => DVec3::new(xi * e, 0.0, -along * d.z),
            _ => {
                if xi < 0.0 {
                    DVec3::new(-e, -along * d.y, 0.0)
                } else {
                    DVec3::new(0.0, -along * d.y, e)
                }
            }
        };
        let cc = c + offset;
        *child = Sphere {
            centre: [cc.x as f32, cc.y as f32, cc.z as f32],
            radius: rj as f32,
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_sphere_and_deformation() {
        let mut p = SphereCloudParams::cumulus(0, 1);
        let c = SphereCloud::new(&p).unwrap();
        assert_eq!(c.level(0)[0].radius, 500.0);
        p.levels = 1;
        let c = SphereCloud::new(&p).unwrap();
        assert_eq!(c.level(0)[0].radius, 1000.0);
        // Children 1 and 2 move along x by D·s·d_x with d_x = 1; child 5 along y by D·s·d_y
        // with d_y = 0.6, so its |y| offset is at most 0.6·D.
        let ch = c.level(1);
        let d5 = 1000.0 - ch[4].radius as f64;
        assert!((ch[4].centre[1] as f64).abs() <= 0.6 * d5 + 1e-3);
        assert!((ch[4].centre[1] as f64).abs() >= 0.6 * 0.9 * d5 - 1e-3);
    }

    #[test]
    fn resolution_picks_the_deepest_resolved_level() {
        let c = SphereCloud::new(&SphereCloudParams::cumulus(6, 2)).unwrap();
        assert_eq!(c.level_for_resolution(1e-3), 6);
        assert_eq!(c.level_for_resolution(1e6), 0);
        // Mean radii shrink by about (0.26 + 0.76)/2 = 0.51 per level: at 100 m resolution the
        // level with ~130 m mean radius (k = 3) is the deepest still resolved.
        let k = c.level_for_resolution(100.0);
        let mean = |k: u32| {
            let l = c.level(k);
            2.0 * l.iter().map(|s| s.radius as f64).sum::<f64>() / l.len() as f64
        };
        assert!(mean(k) >= 100.0 && mean(k + 1) < 100.0, "k = {k}");
    }

    #[test]
    fn oversized_levels_are_refused() {
        let p = SphereCloudParams::cumulus(MAX_LEVELS + 1, 1);
        assert_eq!(SphereCloud::new(&p).unwrap_err().field(), "levels");
    }
}
