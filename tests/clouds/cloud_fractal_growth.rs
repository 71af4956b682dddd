//! Fractal growth (Nishita et al. 1996, §4): deterministic for a seed, grows the cloud, keeps the base flat.

use glam::DVec3;
use skybake_physics::cloud::fractal::{example_cumulus_base, grow, FractalParams};
use skybake_physics::cloud::metaballs::MetaballField;

fn params() -> FractalParams {
    let mut p = FractalParams::new(example_cumulus_base());
    p.levels = 2;
    p.max_mc_voxels = 150_000;
    p.seed = 42;
    p
}

#[test]
fn growth_is_deterministic_for_a_seed() {
    let a = grow(&params()).unwrap();
    let b = grow(&params()).unwrap();
    assert_eq!(a, b);
    let mut other = params();
    other.seed = 43;
    let c = grow(&other).unwrap();
    assert_ne!(a.balls, c.balls);
}

#[test]
fn growth_adds_smaller_balls_on_the_surface() {
    let p = params();
    let cloud = grow(&p).unwrap();
    let base = p.balls.len();
    assert_eq!(cloud.levels.len(), 2);
    assert!(cloud
        .levels
        .iter()
        .all(|l| l.balls_added > 0 && l.triangles > 0));
    let added = &cloud.balls[base..];
    assert_eq!(
        added.len(),
        cloud.levels.iter().map(|l| l.balls_added).sum::<usize>()
    );
    let mean_base_r = p.balls.iter().map(|b| b.radius_m).sum::<f64>() / base as f64;
    // Level-l radii are at most mean_base_r · ratio^l · (1 + jitter).
    let level1 = &added[..cloud.levels[0].balls_added];
    let level2 = &added[cloud.levels[0].balls_added..];
    let bound = |l: i32| mean_base_r * p.radius_ratio.powi(l) * (1.0 + p.radius_jitter) + 1e-9;
    assert!(level1.iter().all(|b| b.radius_m <= bound(1)));
    assert!(level2.iter().all(|b| b.radius_m <= bound(2)));
    // New centres lie on the marching-cubes surface of the base field: the exact field there
    // is the iso level up to the interpolation error of a lattice of a quarter base radius.
    let base_field = MetaballField::new(p.balls.clone()).unwrap();
    for b in level1 {
        let dev = base_field.density(b.centre_m) - p.iso_level;
        assert!(
            dev.abs() < 0.6 * p.iso_level,
            "density off the iso level by {dev}"
        );
    }
}

#[test]
fn base_stays_flat_no_ball_reaches_below_the_base_plane() {
    let p = params();
    let cloud = grow(&p).unwrap();
    let base_z = cloud.base_z_m.unwrap();
    for b in &cloud.balls[p.balls.len()..] {
        assert!(
            b.centre_m.z - b.radius_m >= base_z - 1e-9,
            "ball reaches {}",
            b.centre_m.z - b.radius_m
        );
    }
    // Hence the density below the base plane is exactly that of the base balls.
    let before = MetaballField::new(p.balls.clone()).unwrap();
    let after = MetaballField::new(cloud.balls.clone()).unwrap();
    for i in 0..40 {
        for j in 0..40 {
            let q = DVec3::new(
                -1000.0 + 50.0 * i as f64,
                -1000.0 + 50.0 * j as f64,
                base_z - 1.0,
            );
            assert_eq!(before.density(q), after.density(q));
        }
    }
    // Growth went upwards: clearly more new balls above the base centroid than below it.
    let zc = p.balls.iter().map(|b| b.centre_m.z).sum::<f64>() / p.balls.len() as f64;
    let added = &cloud.balls[p.balls.len()..];
    let above = added.iter().filter(|b| b.centre_m.z > zc).count();
    assert!(
        2 * above > 3 * (added.len() - above),
        "{above} of {}",
        added.len()
    );
}

/// The paper's own mechanism, without the base-plane guard: triangles facing down do not grow.
#[test]
fn downward_facing_surface_does_not_grow() {
    let mut p = params();
    p.flat_base = false;
    p.levels = 1;
    let zc = p.balls.iter().map(|b| b.centre_m.z).sum::<f64>() / p.balls.len() as f64;
    let below = |min_normal_z: f64| {
        let mut q = p.clone();
        q.min_normal_z = min_normal_z;
        let cloud = grow(&q).unwrap();
        let base_z = cloud.base_z_m.unwrap();
        let added = &cloud.balls[q.balls.len()..];
        let near_base = added
            .iter()
            .filter(|b| b.centre_m.z < base_z + 0.1 * (zc - base_z))
            .count();
        (added.len(), near_base)
    };
    let (all_free, base_free) = below(-1.0);
    let (all_limited, base_limited) = below(-0.25);
    let (all_none, _) = below(1.0);
    assert!(base_free > 0, "unrestricted growth reaches the base");
    assert_eq!(base_limited, 0, "no growth on the flat underside");
    assert!(all_limited < all_free);
    assert_eq!(all_none, 0);
}

#[test]
fn ball_budget_and_parameters_are_checked() {
    let mut p = params();
    p.max_balls = 20;
    assert_eq!(grow(&p).unwrap_err().field(), "max_balls");
    let mut p = params();
    p.radius_ratio = 1.5;
    assert_eq!(grow(&p).unwrap_err().field(), "radius_ratio");
    let mut p = params();
    p.levels = 99;
    assert_eq!(grow(&p).unwrap_err().field(), "levels");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(12))]

    /// For any seed and growth settings, no new ball reaches below the base plane and every
    /// new ball is smaller than the level's largest allowed radius.
    #[test]
    fn flat_base_holds_for_any_seed(
        seed in proptest::prelude::any::<u64>(),
        ratio in 0.3f64..0.6,
        coverage in 0.5f64..3.0,
        min_normal_z in -0.6f64..0.0,
    ) {
        let mut p = params();
        p.seed = seed;
        p.radius_ratio = ratio;
        p.coverage = coverage;
        p.min_normal_z = min_normal_z;
        let cloud = grow(&p).unwrap();
        let base_z = cloud.base_z_m.unwrap();
        let mean_base_r = p.balls.iter().map(|b| b.radius_m).sum::<f64>() / p.balls.len() as f64;
        for b in &cloud.balls[p.balls.len()..] {
            proptest::prop_assert!(b.centre_m.z - b.radius_m >= base_z - 1e-9);
            proptest::prop_assert!(b.radius_m <= mean_base_r * ratio * (1.0 + p.radius_jitter) + 1e-9);
        }
    }
}
