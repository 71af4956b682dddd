//! Metaball field (Nishita & Dobashi 2001, eq 3): the binned evaluator and the voxeliser agree with a brute-force
//! sum over all balls, and bad input is refused with the offending field named.

use glam::DVec3;
use proptest::prelude::*;
use skybake_physics::cloud::metaballs::{density_brute_force, Metaball, MetaballField};
use skybake_physics::cloud::wyvill;

fn ball(x: f64, y: f64, z: f64, r: f64, q: f64) -> Metaball {
    Metaball {
        centre_m: DVec3::new(x, y, z),
        radius_m: r,
        density: q,
    }
}

fn arb_ball() -> impl Strategy<Value = Metaball> {
    (
        -500.0..500.0f64,
        -500.0..500.0f64,
        0.0..800.0f64,
        // Mixed sizes: small fringe balls next to large base balls stress the bin sizing.
        prop_oneof![5.0..30.0f64, 100.0..400.0f64],
        0.0..2.0f64,
    )
        .prop_map(|(x, y, z, r, q)| ball(x, y, z, r, q))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Binned lookup equals the brute-force sum at random points (inside and around the support).
    #[test]
    fn binned_density_equals_brute_force(
        balls in prop::collection::vec(arb_ball(), 1..120),
        points in prop::collection::vec((-1000.0..1000.0f64, -1000.0..1000.0f64, -500.0..1300.0f64), 64),
    ) {
        let field = MetaballField::new(balls.clone()).unwrap();
        for (x, y, z) in points {
            let p = DVec3::new(x, y, z);
            let fast = field.density(p);
            let slow = density_brute_force(&balls, p);
            prop_assert!((fast - slow).abs() <= 1e-12 * slow.max(1.0), "{fast} vs {slow} at {p}");
        }
        // And at every ball centre, where the field is at least that ball's own density.
        for b in &balls {
            let fast = field.density(b.centre_m);
            prop_assert!((fast - density_brute_force(&balls, b.centre_m)).abs() <= 1e-12 * fast.max(1.0));
            prop_assert!(fast >= b.density - 1e-12);
        }
    }
}

#[test]
fn voxelised_grid_holds_the_field_at_voxel_centres() {
    let balls = vec![
        ball(0.0, 0.0, 1000.0, 300.0, 1.0),
        ball(250.0, 40.0, 1100.0, 200.0, 0.7),
        ball(-100.0, 200.0, 900.0, 50.0, 2.0),
    ];
    let field = MetaballField::new(balls.clone()).unwrap();
    let grid = field.voxelize(20.0, 40.0).unwrap();
    let (lo, hi) = field.bounds_m();
    // The box covers the support plus the margin.
    assert!(grid.origin_m.cmple(lo - 40.0 + 1e-9).all());
    assert!(grid.max_corner_m().cmpge(hi + 40.0 - 1e-9).all());
    for z in (0..grid.dims[2]).step_by(3) {
        for y in (0..grid.dims[1]).step_by(2) {
            for x in 0..grid.dims[0] {
                let p = grid.voxel_centre(x, y, z);
                let expected = density_brute_force(&balls, p) as f32;
                assert!((grid.at(x, y, z) - expected).abs() <= 1e-6 * expected.max(1.0));
            }
        }
    }
}

#[test]
fn gradient_matches_finite_differences() {
    let balls = vec![
        ball(0.0, 0.0, 0.0, 100.0, 1.0),
        ball(60.0, 10.0, -20.0, 80.0, 0.5),
    ];
    let field = MetaballField::new(balls).unwrap();
    for p in [
        DVec3::new(20.0, 5.0, 3.0),
        DVec3::new(70.0, -10.0, 10.0),
        DVec3::new(-50.0, 30.0, 20.0),
    ] {
        let e = 1e-4;
        let fd = DVec3::new(
            field.density(p + DVec3::X * e) - field.density(p - DVec3::X * e),
            field.density(p + DVec3::Y * e) - field.density(p - DVec3::Y * e),
            field.density(p + DVec3::Z * e) - field.density(p - DVec3::Z * e),
        ) / (2.0 * e);
        assert!(
            (fd - field.gradient(p)).length() < 1e-7,
            "{fd} vs {}",
            field.gradient(p)
        );
    }
}

#[test]
fn total_density_of_a_ball_is_centre_density_times_wyvill_volume() {
    // Nishita & Dobashi 2001, eq 3 with q as centre density: ∫ρ dV = q · 736π/2835 R³ (corrected eq B.2).
    let b = ball(5.0, -3.0, 7.0, 40.0, 0.8);
    let grid = MetaballField::new(vec![b])
        .unwrap()
        .voxelize(1.0, 0.0)
        .unwrap();
    let total: f64 = grid.data.iter().map(|&v| v as f64).sum::<f64>() * grid.voxel_size_m.powi(3);
    let expected = 0.8 * wyvill::normalisation_m3(40.0);
    assert!(
        (total / expected - 1.0).abs() < 1e-3,
        "{total} vs {expected}"
    );
}

#[test]
fn bad_balls_and_oversized_grids_are_refused() {
    let err = MetaballField::new(vec![
        ball(0.0, 0.0, 0.0, 10.0, 1.0),
        ball(0.0, 0.0, 0.0, -1.0, 1.0),
    ])
    .unwrap_err();
    assert_eq!(err.field(), "balls[1].radius_m");
    let err = MetaballField::new(vec![ball(f64::NAN, 0.0, 0.0, 10.0, 1.0)]).unwrap_err();
    assert_eq!(err.field(), "balls[0].centre_m");
    let err = MetaballField::new(vec![ball(0.0, 0.0, 0.0, 10.0, -0.5)]).unwrap_err();
    assert_eq!(err.field(), "balls[0].density");
    assert_eq!(MetaballField::new(vec![]).unwrap_err().field(), "balls");

    let field = MetaballField::new(vec![ball(0.0, 0.0, 0.0, 5000.0, 1.0)]).unwrap();
    let err = field.voxelize(1.0, 0.0).unwrap_err();
    assert_eq!(err.field(), "voxel_size_m");
    assert_eq!(
        field.voxelize(0.0, 0.0).unwrap_err().field(),
        "voxel_size_m"
    );
    assert_eq!(field.voxelize(100.0, -1.0).unwrap_err().field(), "margin_m");
}
