//! Marching cubes (Nishita et al. 1996, §4): a metaball sphere gives the analytic area and volume, and the
//! surface of any field that vanishes on the grid border is closed and consistently oriented.

use glam::DVec3;
use proptest::prelude::*;
use skybake_physics::cloud::marching_cubes::{extract, triangle_normal, TriangleMesh};
use skybake_physics::cloud::metaballs::{Metaball, MetaballField};
use skybake_physics::cloud::{wyvill, DensityGrid};
use std::collections::HashMap;

/// Radius at which Wyvill's field equals `iso` (bisection; h decreases on [0, R]).
fn iso_radius(iso: f64, radius_m: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, radius_m);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if wyvill::h(mid, radius_m) > iso {
            lo = mid
        } else {
            hi = mid
        }
    }
    0.5 * (lo + hi)
}

/// Every directed edge has its reverse exactly once: closed, consistently oriented surface.
fn assert_closed_and_oriented(mesh: &TriangleMesh) {
    let key = |v: DVec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
    let mut edges: HashMap<([u64; 3], [u64; 3]), i32> = HashMap::new();
    for t in &mesh.triangles {
        for i in 0..3 {
            let (a, b) = (key(t[i]), key(t[(i + 1) % 3]));
            if a == b {
                continue;
            }
            *edges.entry((a, b)).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &edges {
        let back = edges.get(&(b, a)).copied().unwrap_or(0);
        assert_eq!(
            n, back,
            "edge used {n} times forward, {back} times backward"
        );
    }
}

/// Relative area and volume errors of the marching-cubes sphere at lattice spacing `spacing_m`.
fn sphere_errors(spacing_m: f64) -> (f64, f64, TriangleMesh, DVec3) {
    let radius_m = 1000.0;
    let iso = 0.5;
    let centre = DVec3::new(10.0, -20.0, 1500.0);
    let field = MetaballField::new(vec![Metaball {
        centre_m: centre,
        radius_m,
        density: 1.0,
    }])
    .unwrap();
    let grid = field.voxelize(spacing_m, 2.0 * spacing_m).unwrap();
    let mesh = extract(&grid, iso as f32, 10_000_000).unwrap();
    let rs = iso_radius(iso, radius_m);
    let area = 4.0 * std::f64::consts::PI * rs * rs;
    let volume = 4.0 / 3.0 * std::f64::consts::PI * rs.powi(3);
    (
        mesh.area_m2() / area - 1.0,
        mesh.enclosed_volume_m3() / volume - 1.0,
        mesh,
        centre,
    )
}

#[test]
fn sphere_area_and_volume_match_analytic_values() {
    // Lattice spacing R/40 ≈ rs/16. Linear interpolation places vertices inside the curved
    // surface and chords cut inside it, both second order in the spacing: 0.3 % bounds them.
    let (area_err, volume_err, mesh, centre) = sphere_errors(1000.0 / 40.0);
    assert!(area_err.abs() < 3e-3, "area off by {area_err}");
    assert!(volume_err.abs() < 3e-3, "volume off by {volume_err}");
    assert_closed_and_oriented(&mesh);
    // Normals point outwards (away from the centre) on every facet.
    for t in &mesh.triangles {
        let mid = (t[0] + t[1] + t[2]) / 3.0;
        assert!(triangle_normal(t).dot(mid - centre) > 0.0);
    }
    // Second-order convergence: halving the spacing cuts the volume error about fourfold.
    let (_, coarse_volume_err, _, _) = sphere_errors(1000.0 / 20.0);
    assert!(
        coarse_volume_err.abs() > 2.5 * volume_err.abs(),
        "{coarse_volume_err} vs {volume_err}"
    );
}

#[test]
fn too_many_triangles_is_an_error_naming_the_limit() {
    let field = MetaballField::new(vec![Metaball {
        centre_m: DVec3::ZERO,
        radius_m: 100.0,
        density: 1.0,
    }])
    .unwrap();
    let grid = field.voxelize(5.0, 5.0).unwrap();
    assert_eq!(
        extract(&grid, 0.5, 100).unwrap_err().field(),
        "max_triangles"
    );
    assert_eq!(
        extract(&grid, f32::NAN, 100).unwrap_err().field(),
        "iso_level"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Random fields (including every ambiguous face and cube case) with an empty border give a
    /// closed, consistently oriented surface of non-negative volume.
    #[test]
    fn random_fields_give_closed_oriented_surfaces(values in prop::collection::vec(0.0f32..1.0, 6 * 6 * 6)) {
        let mut grid = DensityGrid::zeros([8, 8, 8], 1.0, DVec3::ZERO).unwrap();
        for z in 0..6 {
            for y in 0..6 {
                for x in 0..6 {
                    let i = grid.index(x + 1, y + 1, z + 1);
                    grid.data[i] = values[(z * 6 + y) * 6 + x];
                }
            }
        }
        let mesh = extract(&grid, 0.5, 1_000_000).unwrap();
        assert_closed_and_oriented(&mesh);
        prop_assert!(mesh.enclosed_volume_m3() >= -1e-9);
    }
}
