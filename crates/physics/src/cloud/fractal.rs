//! Fractal growth of metaball clouds (Nishita et al. 1996, §4).
//!
//! Starting from a few user-placed balls, each level extracts the isosurface of the current field
//! by marching cubes, scatters new, smaller balls over its triangles (random positions within each
//! triangle, random radii that shrink with distance from the cloud centre) and repeats. Growth is
//! suppressed on triangles whose outward normal points down, and (optionally) no new ball may
//! reach below the lowest point of the initial surface, so cloud bases stay flat while tops
//! become bumpy. z is up. Deterministic for a given seed (`Pcg64`).

use super::marching_cubes::{self, triangle_area_m2, triangle_normal};
use super::metaballs::{validate_balls, Metaball, MetaballField, MAX_BALLS};
use super::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Most growth levels.
pub const MAX_LEVELS: u32 = 6;
/// Most triangles one marching-cubes pass may produce.
pub const MAX_TRIANGLES: usize = 2_000_000;
/// Most voxels of one marching-cubes pass (256³).
pub const MAX_MC_VOXELS: usize = 1 << 24;

/// Parameters of fractal growth (the `"fractal"` cloud source). Defaults in brackets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FractalParams {
    /// Balls forming the basic shape of the cloud.
    pub balls: Vec<Metaball>,
    /// Number of growth levels, 0..=6 [3].
    #[serde(default = "default_levels")]
    pub levels: u32,
    /// Density of the isosurface taken as the cloud surface, > 0 [0.1].
    #[serde(default = "default_iso_level")]
    pub iso_level: f64,
    /// Radius of level-`l` balls is `mean base radius × radius_ratio^l`, in (0, 1) [0.45].
    #[serde(default = "default_radius_ratio")]
    pub radius_ratio: f64,
    /// Expected new balls per `π r_l²` of surface, in (0, 10] [1.5].
    #[serde(default = "default_coverage")]
    pub coverage: f64,
    /// Relative random spread of new radii, `r × (1 ± jitter)`, in [0, 1) [0.3].
    #[serde(default = "default_radius_jitter")]
    pub radius_jitter: f64,
    /// Fraction by which new radii shrink from the cloud centre to its outermost surface point,
    /// in [0, 1) [0.5].
    #[serde(default = "default_radial_falloff")]
    pub radial_falloff: f64,
    /// Density of new balls relative to the mean density of the base balls, in (0, 10] [0.8].
    #[serde(default = "default_density_ratio")]
    pub density_ratio: f64,
    /// Triangles whose unit outward normal has a z component below this do not grow, in
    /// [-1, 1] [-0.25].
    #[serde(default = "default_min_normal_z")]
    pub min_normal_z: f64,
    /// Keep the base flat: no new ball reaches below the lowest point of the initial surface
    /// [true].
    #[serde(default = "default_true")]
    pub flat_base: bool,
    /// Random seed [1].
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Most balls in the grown cloud; exceeding it is an error, 1..=1 000 000 [50 000].
    #[serde(default = "default_max_balls")]
    pub max_balls: usize,
    /// Most voxels of a marching-cubes pass; the pass voxel (a quarter of the previous level's radius)
    /// is enlarged to fit, 8..=16 777 216 [2 097 152].
    #[serde(default = "default_max_mc_voxels")]
    pub max_mc_voxels: usize,
}

fn default_levels() -> u32 {
    3
}
fn default_iso_level() -> f64 {
    0.1
}
fn default_radius_ratio() -> f64 {
    0.45
}
fn default_coverage() -> f64 {
    1.5
}
fn default_radius_jitter() -> f64 {
    0.3
}
fn default_radial_falloff() -> f64 {
    0.5
}
fn default_density_ratio() -> f64 {
    0.8
}
fn default_min_normal_z() -> f64 {
    -0.25
}
fn default_true() -> bool {
    true
}
fn default_seed() -> u64 {
    1
}
fn default_max_balls() -> usize {
    50_000
}
fn default_max_mc_voxels() -> usize {
    1 << 21
}

impl FractalParams {
    /// Parameters with the documented defaults around the given base balls.
    pub fn new(balls: Vec<Metaball>) -> Self {
        Self {
            balls,
            levels: default_levels(),
            iso_level: default_iso_level(),
            radius_ratio: default_radius_ratio(),
            coverage: default_coverage(),
            radius_jitter: default_radius_jitter(),
            radial_falloff: default_radial_falloff(),
            density_ratio: default_density_ratio(),
            min_normal_z: default_min_normal_z(),
            flat_base: default_true(),
            seed: default_seed(),
            max_balls: default_max_balls(),
            max_mc_voxels: default_max_mc_voxels(),
        }
    }

    /// Checks every parameter against its documented range.
    pub fn validate(&self) -> Result<()> {
        validate_balls(&self.balls)?;
        let check = |field: &str, v: f64, ok: bool, allowed: &str| {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(Error::out_of_range(field, v, allowed))
            }
        };
        if self.levels > MAX_LEVELS {
            return Err(Error::out_of_range(
                "levels",
                self.levels,
                format!("0..={MAX_LEVELS}"),
            ));
        }
        check("iso_level", self.iso_level, self.iso_level > 0.0, "> 0")?;
        let r = self.radius_ratio;
        check("radius_ratio", r, r > 0.0 && r < 1.0, "(0, 1)")?;
        let c = self.coverage;
        check("coverage", c, c > 0.0 && c <= 10.0, "(0, 10]")?;
        let j = self.radius_jitter;
        check("radius_jitter", j, (0.0..1.0).contains(&j), "[0, 1)")?;
        let f = self.radial_falloff;
        check("radial_falloff", f, (0.0..1.0).contains(&f), "[0, 1)")?;
        let d = self.density_ratio;
        check("density_ratio", d, d > 0.0 && d <= 10.0, "(0, 10]")?;
        let n = self.min_normal_z;
        check("min_normal_z", n, (-1.0..=1.0).contains(&n), "[-1, 1]")?;
        if !(1..=MAX_BALLS).contains(&self.max_balls) {
            return Err(Error::out_of_range(
                "max_balls",
                self.max_balls,
                format!("1..={MAX_BALLS}"),
            ));
        }
        if self.balls.len() > self.max_balls {
            return Err(Error::too_large(
                "max_balls",
                format!("{} base balls", self.balls.len()),
                self.max_balls,
            ));
        }
        if !(8..=MAX_MC_VOXELS).contains(&self.max_mc_voxels) {
            return Err(Error::out_of_range(
                "max_mc_voxels",
                self.max_mc_voxels,
                format!("8..={MAX_MC_VOXELS}"),
            ));
        }
        Ok(())
    }
}

/// What one growth level did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LevelStats {
    /// Voxel edge of the marching-cubes pass, metres.
    pub mc_voxel_size_m: f64,
    /// Triangles of the extracted isosurface.
    pub triangles: usize,
    /// Balls added at this level.
    pub balls_added: usize,
}

/// A grown cloud: the base balls followed by every level's new balls.
#[derive(Debug, Clone, PartialEq)]
pub struct FractalCloud {
    /// All balls, base first.
    pub balls: Vec<Metaball>,
    /// Per-level statistics.
    pub levels: Vec<LevelStats>,
    /// Height of the base plane (lowest point of the initial surface), metres; `None` when no
    /// level ran.
    pub base_z_m: Option<f64>,
}

/// Grows a cloud from `params` (Nishita et al. 1996, §4).
pub fn grow(params: &FractalParams) -> Result<FractalCloud> {
    params.validate()?;
    let base = &params.balls;
    let mean_radius_m = base.iter().map(|b| b.radius_m).sum::<f64>() / base.len() as f64;
    let mean_density = base.iter().map(|b| b.density).sum::<f64>() / base.len() as f64;
    let weight: f64 = base.iter().map(|b| b.density * b.radius_m.powi(3)).sum();
    let centre_m = if weight > 0.0 {
        base.iter()
            .map(|b| b.centre_m * (b.density * b.radius_m.powi(3)))
            .sum::<DVec3>()
            / weight
    } else {
        base.iter().map(|b| b.centre_m).sum::<DVec3>() / base.len() as f64
    };
    let new_density = (mean_density * params.density_ratio).min(super::metaballs::MAX_DENSITY);
    let mut rng = Pcg64::seed_from_u64(params.seed);
    let mut balls = base.clone();
    let mut levels = Vec::new();
    let mut base_z_m = None;
    for level in 1..=params.levels {
        let field = MetaballField::new(balls.clone())?;
        let previous_radius_m = mean_radius_m * params.radius_ratio.powi(level as i32 - 1);
        let grid = voxelize_for_mc(&field, previous_radius_m * 0.25, params.max_mc_voxels)?;
        let mesh = marching_cubes::extract(&grid, params.iso_level as f32, MAX_TRIANGLES)?;
        if level == 1 {
            base_z_m = mesh
                .triangles
                .iter()
                .flatten()
                .map(|v| v.z)
                .reduce(f64::min);
        }
        let floor_z = if params.flat_base { base_z_m } else { None };
        let radius_m = mean_radius_m * params.radius_ratio.powi(level as i32);
        let reach_m = mesh
            .triangles
            .iter()
            .flatten()
            .map(|v| v.distance(centre_m))
            .fold(0.0, f64::max)
            .max(f64::MIN_POSITIVE);
        let per_area = params.coverage / (PI * radius_m * radius_m);
        let mut added = 0usize;
        for tri in &mesh.triangles {
            // Always draw the same numbers per triangle so the sequence does not depend on
            // which triangles are suppressed.
            let expected = triangle_area_m2(tri) * per_area;
            let count =
                expected.floor() as usize + usize::from(rng.random::<f64>() < expected.fract());
            if triangle_normal(tri).z < params.min_normal_z {
                continue;
            }
            for _ in 0..count {
                let (u, v, jitter): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
                let su = u.sqrt();
                let p = tri[0] * (1.0 - su) + tri[1] * (su * (1.0 - v)) + tri[2] * (su * v);
                let shrink =
                    1.0 - params.radial_falloff * (p.distance(centre_m) / reach_m).min(1.0);
                let mut r = radius_m * shrink * (1.0 + params.radius_jitter * (2.0 * jitter - 1.0));
                if let Some(floor) = floor_z {
                    // Shrink balls that would reach below the base plane; drop tiny ones.
                    let room = p.z - floor;
                    if room < r {
                        if room < 0.5 * r {
                            continue;
                        }
                        r = room;
                    }
                }
                if balls.len() >= params.max_balls {
                    return Err(Error::too_large(
                        "max_balls",
                        format!("fractal growth at level {level} needs more balls"),
                        params.max_balls,
                    ));
                }
                balls.push(Metaball {
                    centre_m: p,
                    radius_m: r,
                    density: new_density,
                });
                added += 1;
            }
        }
        levels.push(LevelStats {
            mc_voxel_size_m: grid.voxel_size_m,
            triangles: mesh.triangles.len(),
            balls_added: added,
        });
    }
    Ok(FractalCloud {
        balls,
        levels,
        base_z_m,
    })
}

/// Voxelises `field` at `voxel_size_m` (enlarged until the grid fits `max_voxels`) with a
/// one-voxel margin, so the border lies outside every ball and the isosurface is closed.
fn voxelize_for_mc(
    field: &MetaballField,
    voxel_size_m: f64,
    max_voxels: usize,
) -> Result<DensityGrid> {
    let (lo, hi) = field.bounds_m();
    let extent = hi - lo;
    let mut voxel = voxel_size_m;
    loop {
        let n = (extent / voxel).ceil() + 2.0;
        if n.x * n.y * n.z <= max_voxels as f64 {
            break;
        }
        voxel *= 1.1;
    }
    field.voxelize(voxel, voxel)
}

/// Grows the cloud and voxelises it at `voxel_size_m` (Nishita et al. 1996, §4; then Nishita & Dobashi 2001, eq 3).
pub fn voxelize(params: &FractalParams, voxel_size_m: f64) -> Result<DensityGrid> {
    voxelize_within(params, voxel_size_m, super::grid::MAX_VOXELS)
}

/// [`voxelize`], refusing a grid of more than `max_voxels` voxels (too large on `dims`) once the
/// grown balls give its box, before it is allocated.
pub fn voxelize_within(
    params: &FractalParams,
    voxel_size_m: f64,
    max_voxels: usize,
) -> Result<DensityGrid> {
    voxelize_unless(params, voxel_size_m, max_voxels, &|| false)
}

/// [`voxelize_within`], stopped with [`crate::Error::Cancelled`] once `cancelled` returns true
/// (asked after the growth and before every z-slice of the grid).
pub fn voxelize_unless(
    params: &FractalParams,
    voxel_size_m: f64,
    max_voxels: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<DensityGrid> {
    let cloud = grow(params)?;
    MetaballField::new(cloud.balls)?.voxelize_within_unless(
        voxel_size_m,
        voxel_size_m,
        max_voxels,
        cancelled,
    )
}

/// A small cumulus base (five balls, about 1.6 km across, base near 1 km altitude), used by the
/// benchmark and the example scene.
pub fn example_cumulus_base() -> Vec<Metaball> {
    let ball = |x: f64, y: f64, z: f64, r: f64| Metaball {
        centre_m: DVec3::new(x, y, z),
        radius_m: r,
        density: 1.0,
    };
    vec![
        ball(0.0, 0.0, 1400.0, 500.0),
        ball(450.0, 100.0, 1300.0, 380.0),
        ball(-420.0, -80.0, 1320.0, 400.0),
        ball(80.0, 380.0, 1300.0, 360.0),
        ball(60.0, -60.0, 1750.0, 330.0),
    ]
}
