//! Cellular-automaton cloud animation (Dobashi et al. 2000, §4–5.1, appendices A–B).
//!
//! `control` holds the animator's inputs (wind, ellipsoids, terrain), `random` the random-bit
//! look-up table, `sim` the bit-packed automaton, `density` the smoothing and metaball basis that
//! turn binary cloud into a [`DensityGrid`]. Everything is deterministic for a seed and
//! independent of the number of threads.
//!
//! Where this departs from the paper, and why:
//! - Eq A.4 as printed keeps cloud where the p_ext row has a 1 (probability p_ext), the opposite
//!   of eq 5; A.5–A.6 print `c` and `∧` for `h ∨` and `a ∨`. The rules follow eqs 5–7.
//! - Appendix A indexes the table with one probability per word; here every cell has its own
//!   level. Rows of one sequence are nested (see [`random`]), so a word whose cells differ needs
//!   one comparison pass rather than 64 loads, and the result is still bit `x % 64` of row
//!   `(level(x), seq)`.
//! - Eq 11's weight is w ≡ 1 (a box average); eq B.2's printed constant 748πR/405 equals neither
//!   ∫h dr nor ∫h dV, so the metaball kernel is normalised by its own lattice sum (density 1 in
//!   solid cloud).
//! - §4.5 gives no probability profile inside an ellipsoid; 1 − ρ² is used (see [`Ellipsoid`]).
//! - Inside obstacles all three states are cleared (the paper zeroes the probabilities, which
//!   leaves growth by eq 3 free to enter the mountain).
//! - Wind blows along ±x only; other directions rotate the simulation space (§4.3).
//!
//! ```no_run
//! # use skybake_physics::cloud::automaton::{automaton_density, AutomatonParams};
//! let params = AutomatonParams::example([256, 128, 20], 7);
//! let grid = automaton_density(&params, 120.5)?; // halfway between steps 120 and 121
//! # Ok::<(), skybake_physics::Error>(())
//! ```

pub mod control;
pub mod density;
pub mod random;
pub mod sim;

pub use control::{
    Ellipsoid, Hill, Obstacle, ProbabilityControl, RandomEllipsoids, RuleProbabilities, WindKnot,
    WindProfile,
};
pub use density::{MetaballKernel, Smoothing};
pub use random::RandomBitTable;
pub use sim::{Automaton, CaState};

use crate::cloud::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Largest simulated time accepted, in steps.
pub const MAX_STEPS: f64 = 1_000_000.0;

/// Everything that defines a simulation. Units: cells and steps inside the automaton, metres for
/// the output grid. Deserialises from the `automaton` block of a scene (see
/// `config/scenes/automaton-field.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AutomatonParams {
    /// Cells along x (wind direction), y, z (up).
    pub dims: [usize; 3],
    /// Edge of a cubic cell, metres.
    pub cell_size_m: f64,
    /// Minimum corner of the space, metres.
    #[serde(default)]
    pub origin_m: [f64; 3],
    /// Seed of every random choice.
    pub seed: u64,
    /// Probability of hum = 1 in the initial state (§4.1).
    #[serde(default = "default_initial_hum")]
    pub initial_hum_probability: f64,
    /// Probability of act = 1 in the initial state (§4.1).
    #[serde(default = "default_initial_act")]
    pub initial_act_probability: f64,
    /// Probability levels n_p of the random-bit table (resolution 1/n_p), app. A.
    #[serde(default = "default_levels")]
    pub probability_levels: usize,
    /// Random sequences n_i per level, app. A.
    #[serde(default = "default_sequences")]
    pub random_sequences: usize,
    /// Vapour and activation are supplied every this many steps (§4.2); extinction acts every step.
    #[serde(default = "default_supply_interval")]
    pub supply_interval_steps: u64,
    /// Probabilities outside every ellipsoid.
    pub background: RuleProbabilities,
    /// Ellipsoids placed by hand (§4.5).
    #[serde(default)]
    pub ellipsoids: Vec<Ellipsoid>,
    /// Ellipsoids placed at random (§6), added to `ellipsoids`.
    #[serde(default)]
    pub random_ellipsoids: Option<RandomEllipsoids>,
    /// Wind profile v(z) along +x (§4.3); empty means calm.
    #[serde(default)]
    pub wind: Vec<WindKnot>,
    /// Terrain that cannot hold cloud.
    #[serde(default)]
    pub obstacle: Option<Obstacle>,
    /// Space-time smoothing window (eq 11).
    #[serde(default)]
    pub smoothing: Smoothing,
    /// Effective metaball radius R (eq 12), cells.
    #[serde(default = "default_radius")]
    pub metaball_radius_cells: f64,
}

fn default_initial_hum() -> f64 {
    0.3
}
fn default_initial_act() -> f64 {
    0.005
}
fn default_levels() -> usize {
    1000
}
fn default_sequences() -> usize {
    32
}
fn default_supply_interval() -> u64 {
    1
}
fn default_radius() -> f64 {
    1.5
}

impl AutomatonParams {
    /// The setting of the paper's Fig. 8 on a `dims` space with 100 m cells: random ellipsoids
    /// with p_hum = 0.1, p_act = 0.001, p_ext = 0.1 at their centres, a wind rising from 0 at the
    /// ground to 2 cells per step at the top.
    pub fn example(dims: [usize; 3], seed: u64) -> Self {
        let [nx, ny, nz] = dims;
        let count = ((nx * ny) / 1500).max(1);
        let top = nz as f64;
        Self {
            dims,
            cell_size_m: 100.0,
            origin_m: [0.0; 3],
            seed,
            initial_hum_probability: default_initial_hum(),
            initial_act_probability: default_initial_act(),
            probability_levels: default_levels(),
            random_sequences: default_sequences(),
            supply_interval_steps: 1,
            background: RuleProbabilities {
                hum: 0.0,
                act: 0.0,
                ext: 0.3,
            },
            ellipsoids: Vec::new(),
            random_ellipsoids: Some(RandomEllipsoids {
                count,
                semi_axes_min_cells: [8.0, 8.0, 0.25 * top],
                semi_axes_max_cells: [20.0, 20.0, 0.45 * top],
                centre_height_range_cells: [0.4 * top, 0.6 * top],
                centre: RuleProbabilities {
                    hum: 0.1,
                    act: 0.001,
                    ext: 0.1,
                },
                ext_edge: 0.3,
            }),
            wind: vec![
                WindKnot {
                    height_cells: 0.0,
                    velocity_cells_per_step: 0.0,
                },
                WindKnot {
                    height_cells: top,
                    velocity_cells_per_step: 2.0,
                },
            ],
            obstacle: None,
            smoothing: Smoothing::default(),
            metaball_radius_cells: default_radius(),
        }
    }

    /// Checks the scalar parameters (the automaton checks sizes and controls).
    pub fn validate(&self) -> Result<()> {
        sim::checked_cells(self.dims)?;
        if !(self.cell_size_m.is_finite() && self.cell_size_m > 0.0) {
            return Err(Error::out_of_range(
                "cell_size_m",
                self.cell_size_m,
                "a finite value > 0",
            ));
        }
        if !self.origin_m.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid("origin_m", "must be finite"));
        }
        for (name, p) in [
            ("initial_hum_probability", self.initial_hum_probability),
            ("initial_act_probability", self.initial_act_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(Error::out_of_range(name, p, "0..=1"));
            }
        }
        if !(1..=1_000_000).contains(&self.supply_interval_steps) {
            return Err(Error::out_of_range(
                "supply_interval_steps",
                self.supply_interval_steps,
                "1..=1000000",
            ));
        }
        self.smoothing.validate()?;
        MetaballKernel::new(self.metaball_radius_cells)?;
        Ok(())
    }

    /// Hand-placed ellipsoids followed by the random ones (drawn from `setup_rng(seed, 1)`).
    pub fn all_ellipsoids(&self) -> Result<Vec<Ellipsoid>> {
        let mut out = self.ellipsoids.clone();
        if let Some(r) = &self.random_ellipsoids {
            if r.count > control::MAX_ELLIPSOIDS {
                return Err(Error::too_large(
                    "random_ellipsoids.count",
                    format!("{} ellipsoids", r.count),
                    control::MAX_ELLIPSOIDS,
                ));
            }
            let ok = (0..3).all(|a| {
                let (lo, hi) = (r.semi_axes_min_cells[a], r.semi_axes_max_cells[a]);
                lo.is_finite() && hi.is_finite() && lo > 0.0 && lo <= hi
            });
            if !ok {
                return Err(Error::invalid(
                    "random_ellipsoids.semi_axes_min_cells",
                    "each must be finite, > 0 and <= the matching semi_axes_max_cells",
                ));
            }
            let [z0, z1] = r.centre_height_range_cells;
            if !(z0.is_finite() && z1.is_finite() && z0 <= z1) {
                return Err(Error::invalid(
                    "random_ellipsoids.centre_height_range_cells",
                    "must be finite with min <= max",
                ));
            }
            let mut rng = random::setup_rng(self.seed, 1);
            let [nx, ny, _] = self.dims;
            for _ in 0..r.count {
                let u: [f64; 6] = std::array::from_fn(|_| rng.random::<f64>());
                let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
                out.push(Ellipsoid {
                    centre_cells: [u[0] * nx as f64, u[1] * ny as f64, lerp(z0, z1, u[2])],
                    semi_axes_cells: std::array::from_fn(|a| {
                        lerp(r.semi_axes_min_cells[a], r.semi_axes_max_cells[a], u[3 + a])
                    }),
                    centre: r.centre,
                    ext_edge: r.ext_edge,
                });
            }
        }
        Ok(out)
    }
}

/// Density grids at the given times (in steps, fractional allowed; Dobashi et al. 2000, §5.1): q by eq 11 at
/// the steps either side, ρ by eq 12 at the cell centres, then linear interpolation in time. The
/// grid has one voxel per cell, `cell_size_m` voxels, origin `origin_m`; values are dimensionless
/// (1 inside a fully cloudy region). Frames come back in the order asked.
pub fn automaton_frames(params: &AutomatonParams, times_steps: &[f64]) -> Result<Vec<DensityGrid>> {
    automaton_frames_unless(params, times_steps, &|| false)
}

/// [`automaton_frames`], stopped with [`Error::Cancelled`] once `cancelled` returns true (asked
/// before every step of the simulation).
pub fn automaton_frames_unless(
    params: &AutomatonParams,
    times_steps: &[f64],
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<Vec<DensityGrid>> {
    params.validate()?;
    let cells = sim::checked_cells(params.dims)?;
    if times_steps.is_empty() {
        return Err(Error::invalid(
            "times_steps",
            "at least one frame time is needed",
        ));
    }
    let total = cells.checked_mul(times_steps.len());
    if total.is_none_or(|t| t > crate::cloud::grid::MAX_VOXELS) {
        return Err(Error::too_large(
            "times_steps",
            format!("{} frames of {cells} cells", times_steps.len()),
            format!("{} voxels in total", crate::cloud::grid::MAX_VOXELS),
        ));
    }
    for &t in times_steps {
        if !(0.0..=MAX_STEPS).contains(&t) {
            return Err(Error::out_of_range(
                "times_steps",
                t,
                format!("0..={MAX_STEPS}"),
            ));
        }
    }
    let kernel = MetaballKernel::new(params.metaball_radius_cells)?;
    let mut sim = Automaton::new(params)?;
    let dims = params.dims;
    let m = sim.words_per_row();
    let t0 = params.smoothing.t0 as u64;
    // Snapshots of cld by step, kept for the smoothing window.
    let mut history: std::collections::VecDeque<(u64, Vec<u64>)> = Default::default();
    history.push_back((0, sim.state().cld.clone()));
    let mut cache: Vec<(u64, Vec<f32>)> = Vec::new();
    let mut order: Vec<usize> = (0..times_steps.len()).collect();
    order.sort_by(|&a, &b| times_steps[a].total_cmp(&times_steps[b]));
    let mut frames: Vec<Option<DensityGrid>> = vec![None; times_steps.len()];
    let origin = DVec3::from_array(params.origin_m);
    for idx in order {
        let t = times_steps[idx];
        let n = t.floor() as u64;
        let alpha = (t - n as f64) as f32;
        let mut rho_at = |step: u64| -> Result<Vec<f32>> {
            if let Some((_, r)) = cache.iter().find(|(s, _)| *s == step) {
                return Ok(r.clone());
            }
            while sim.steps_done() < step + t0 {
                if cancelled() {
                    return Err(Error::Cancelled);
                }
                sim.step();
                history.push_back((sim.steps_done(), sim.state().cld.clone()));
                while history.len() > (2 * t0 + 2) as usize {
                    history.pop_front();
                }
            }
            let window: Vec<&[u64]> = (0..=2 * t0)
                .map(|d| {
                    let s = (step + d).saturating_sub(t0);
                    let found = history.iter().find(|(hs, _)| *hs == s);
                    // Frames are visited in time order and the history keeps 2·t0 + 2 steps, so
                    // the window is always present.
                    debug_assert!(found.is_some(), "step {s} missing from the history");
                    found.map_or(history[0].1.as_slice(), |(_, w)| w.as_slice())
                })
                .collect();
            let q = density::smoothed_fraction(&window, dims, m, &params.smoothing);
            let rho = kernel.density(&q, dims);
            cache.push((step, rho.clone()));
            if cache.len() > 2 {
                cache.remove(0);
            }
            Ok(rho)
        };
        let a = rho_at(n)?;
        let data = if alpha > 0.0 {
            let b = rho_at(n + 1)?;
            a.iter()
                .zip(&b)
                .map(|(x, y)| x * (1.0 - alpha) + y * alpha)
                .collect()
        } else {
            a
        };
        frames[idx] = Some(DensityGrid::from_data(
            dims,
            params.cell_size_m,
            origin,
            data,
        )?);
    }
    Ok(frames.into_iter().flatten().collect())
}

/// The density grid at one time, in steps (see [`automaton_frames`]).
pub fn automaton_density(params: &AutomatonParams, time_steps: f64) -> Result<DensityGrid> {
    automaton_density_unless(params, time_steps, &|| false)
}

/// [`automaton_density`], stopped with [`Error::Cancelled`] once `cancelled` returns true (asked
/// before every step).
pub fn automaton_density_unless(
    params: &AutomatonParams,
    time_steps: f64,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<DensityGrid> {
    let mut frames = automaton_frames_unless(params, &[time_steps], cancelled)?;
    frames
        .pop()
        .ok_or_else(|| Error::invalid("time_steps", "no frame produced"))
}
