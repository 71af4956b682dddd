//! Sphere-hierarchy cloud (Ostroushko et al.): containment, traversal against brute force, transmittance
//! bounds and monotonicity, level of detail, animation, voxelisation and validation.

use glam::DVec3;
use proptest::prelude::*;
use skybake_physics::cloud::scene::{parse_scene_file, voxelize, CloudSource, SpheresSource};
use skybake_physics::cloud::spheres::{
    edge_weight, Camera, Ray, SphereCloud, SphereCloudParams, TraceStats, MAX_LEVELS,
};

/// Every child lies inside its parent: |c_child − c_parent| + r_child ≤ r_parent, up to the
/// single-precision storage (relative 1e-5 of the parent radius).
fn assert_nested(cloud: &SphereCloud) {
    for k in 1..=cloud.max_level() {
        let parents = cloud.level(k - 1);
        for (i, c) in cloud.level(k).iter().enumerate() {
            let p = &parents[i / 5];
            let gap = p.radius as f64 - (c.centre_m().distance(p.centre_m()) + c.radius as f64);
            assert!(
                gap >= -1e-5 * p.radius as f64,
                "level {k} sphere {i} sticks out by {}",
                -gap
            );
            let ratio = c.radius as f64 / p.radius as f64;
            assert!((0.26 - 1e-6..=0.76 + 1e-6).contains(&ratio), "I = {ratio}");
        }
    }
}

fn flat_cloud(levels: u32, seed: u64) -> SphereCloudParams {
    // Strongly anisotropic sizes, so the first split's deformation coefficients matter.
    SphereCloudParams {
        levels,
        size_m: [3000.0, 800.0, 500.0],
        centre_m: [100.0, -50.0, 2000.0],
        mor_m: 40.0,
        seed,
        radius_factor_range: [0.26, 0.76],
        offset_factor_range: [0.9, 1.0],
    }
}

#[test]
fn children_lie_inside_parents_at_every_level() {
    assert_nested(&SphereCloud::new(&SphereCloudParams::cumulus(6, 3)).unwrap());
    assert_nested(&SphereCloud::new(&flat_cloud(6, 4)).unwrap());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn nesting_holds_for_any_seed_size_and_interpolation(
        seed in any::<u64>(),
        a in 10.0f64..5000.0, b in 10.0f64..5000.0, c in 10.0f64..5000.0,
        tau in 0.0f64..=1.0,
    ) {
        let mut p = flat_cloud(4, seed);
        p.size_m = [a, b, c];
        let x = SphereCloud::new(&p).unwrap();
        assert_nested(&x);
        p.seed = seed.wrapping_add(1);
        let y = SphereCloud::new(&p).unwrap();
        assert_nested(&SphereCloud::interpolate(&x, &y, tau).unwrap());
    }

    #[test]
    fn transmittance_is_in_unit_range_and_falls_along_the_ray(
        seed in 0u64..1000,
        ox in -3000.0f64..3000.0, oy in -3000.0f64..3000.0, oz in -1000.0f64..1000.0,
        tx in -400.0f64..400.0, ty in -300.0f64..300.0, tz in -200.0f64..200.0,
        steps in proptest::collection::vec(0.0f64..600.0, 6),
    ) {
        let cloud = SphereCloud::new(&flat_cloud(4, seed)).unwrap();
        let centre = cloud.centre_m();
        let origin = centre + DVec3::new(ox, oy, oz);
        let dir = centre + DVec3::new(tx, ty, tz) - origin;
        prop_assume!(dir.length() > 1.0);
        let mut t_max = 0.0;
        let mut last = 1.0;
        for s in steps {
            t_max += s;
            let ray = Ray::new(origin, dir, t_max).unwrap();
            let t = cloud.transmittance(&ray, None, &mut TraceStats::default());
            prop_assert!((0.0..=1.0).contains(&t));
            prop_assert!(t <= last + 1e-15, "T rose from {} to {} at {}", last, t, t_max);
            last = t;
        }
    }
}

#[test]
fn traversal_equals_brute_force_over_all_leaves() {
    let cloud = SphereCloud::new(&flat_cloud(5, 9)).unwrap();
    let centre = cloud.centre_m();
    let mut hits = 0;
    let mut stats = TraceStats::default();
    for i in 0..400 {
        // Rays from a ring around the cloud towards jittered points inside it.
        let a = i as f64 * 0.7;
        let origin =
            centre + DVec3::new(2500.0 * a.cos(), 2500.0 * a.sin(), 300.0 * (a * 3.1).sin());
        let target = centre
            + DVec3::new(
                600.0 * (a * 1.3).sin(),
                200.0 * (a * 2.1).cos(),
                150.0 * (a * 0.7).sin(),
            );
        let ray = Ray::new(origin, target - origin, f64::INFINITY).unwrap();
        let fast = cloud.transmittance(&ray, None, &mut stats);
        let brute = cloud.transmittance_brute_force(&ray);
        assert!(
            (fast - brute).abs() <= 1e-12 * brute.max(1e-300),
            "ray {i}: hierarchy {fast} vs brute force {brute}"
        );
        if brute < 0.999 {
            hits += 1;
        }
    }
    assert!(hits > 200, "only {hits} rays met the cloud");
    // The hierarchy tested far fewer spheres than 400 rays × 3125 leaves.
    assert!(stats.spheres_tested < 400 * 3125 / 4, "{stats:?}");
}

#[test]
fn single_sphere_transmittance_is_two_percent_over_one_mor() {
    // K = 0: one sphere of radius min(a,b,c)/2 = 250 m. Through its centre d = 0, so eq 3 is
    // T = t^chord; with MOR = 500 m = the chord, T is the 0.02 contrast threshold (definition).
    let mut p = flat_cloud(0, 1);
    p.mor_m = 500.0;
    let cloud = SphereCloud::new(&p).unwrap();
    let c = cloud.centre_m();
    let ray = Ray::new(c - DVec3::X * 1000.0, DVec3::X, f64::INFINITY).unwrap();
    let t = cloud.transmittance(&ray, None, &mut TraceStats::default());
    assert!((t - 0.02).abs() < 1e-12, "{t}");
    // Offset by half the radius: chord 2·√(r² − d²), weight f = 1/2.
    let d = 125.0;
    let ray = Ray::new(
        c - DVec3::X * 1000.0 + DVec3::Z * d,
        DVec3::X,
        f64::INFINITY,
    )
    .unwrap();
    let chord = 2.0 * (250.0f64 * 250.0 - d * d).sqrt();
    let expect = 0.5 * 0.02f64.powf(chord / 500.0) + 0.5;
    let t = cloud.transmittance(&ray, None, &mut TraceStats::default());
    assert!((t - expect).abs() < 1e-12);
    assert_eq!(edge_weight(d, 250.0), 0.5);
}

#[test]
fn level_of_detail_saves_work_and_changes_the_image_little() {
    // K = 8 seen from 25 km in a 160×120, 12° frame: one pixel is ~44 m, so levels 5–8 (radii
    // below ~25 m) are sub-pixel and the one-pixel LOD stops above them.
    let cloud = SphereCloud::new(&SphereCloudParams::cumulus(8, 5)).unwrap();
    let camera = Camera {
        eye_m: cloud.centre_m() + DVec3::new(0.0, -25_000.0, 500.0),
        target_m: cloud.centre_m(),
        up: DVec3::Z,
        fov_y_deg: 12.0,
        width: 160,
        height: 120,
    };
    let (full, s_full) = cloud.render_transmittance(&camera, None).unwrap();
    let (lod, s_lod) = cloud.render_transmittance(&camera, Some(1.0)).unwrap();
    let covered = full.iter().filter(|t| **t < 0.99).count();
    assert!(covered > 400, "cloud covers {covered} pixels");
    let opacity = |img: &[f32]| img.iter().map(|t| 1.0 - *t as f64).sum::<f64>();
    let mean_diff: f64 = full
        .iter()
        .zip(&lod)
        .map(|(a, b)| (a - b).abs() as f64)
        .sum::<f64>()
        / covered as f64;
    let (o_full, o_lod) = (opacity(&full), opacity(&lod));
    println!(
        "LOD: tests {} -> {}, opacity {o_full:.1} -> {o_lod:.1}, mean |dT| {mean_diff:.4}",
        s_full.spheres_tested, s_lod.spheres_tested
    );
    // Work: at least 15 % fewer sphere tests (the hierarchy already prunes most of the tree).
    assert!(s_lod.spheres_tested * 100 < s_full.spheres_tested * 85);
    // Image: the cloud's total opacity within 5 %, per-pixel change under 0.05 on average.
    assert!(
        (o_lod - o_full).abs() < 0.05 * o_full,
        "{o_full} vs {o_lod}"
    );
    assert!(mean_diff < 0.05, "mean |dT| = {mean_diff}");
}

#[test]
fn same_seed_same_cloud_and_animation_endpoints() {
    let a = SphereCloud::new(&flat_cloud(4, 1)).unwrap();
    let b = SphereCloud::new(&flat_cloud(4, 1)).unwrap();
    assert!(a == b);
    let c = SphereCloud::new(&flat_cloud(4, 2)).unwrap();
    assert!(a != c);
    assert!(SphereCloud::interpolate(&a, &c, 0.0).unwrap() == a);
    assert!(SphereCloud::interpolate(&a, &c, 1.0).unwrap().leaves() == c.leaves());
    let mid = SphereCloud::interpolate(&a, &c, 0.5).unwrap();
    let (x, y, m) = (a.leaves()[7], c.leaves()[7], mid.leaves()[7]);
    assert!((m.radius - 0.5 * (x.radius + y.radius)).abs() < 1e-3);
    let other_k = SphereCloud::new(&flat_cloud(3, 2)).unwrap();
    assert_eq!(
        SphereCloud::interpolate(&a, &other_k, 0.5)
            .unwrap_err()
            .field(),
        "levels"
    );
    assert_eq!(
        SphereCloud::interpolate(&a, &c, 1.5).unwrap_err().field(),
        "tau"
    );
}

#[test]
fn voxel_density_is_the_sum_of_leaf_edge_functions() {
    let cloud = SphereCloud::new(&flat_cloud(3, 8)).unwrap();
    let grid = cloud.voxelize(40.0, None).unwrap();
    assert!(grid.max_density() > 0.5);
    let base = cloud.centre_m();
    let [nx, ny, nz] = grid.dims;
    for (x, y, z) in [
        (nx / 2, ny / 2, nz / 2),
        (nx / 3, ny / 2, nz / 2),
        (0, 0, 0),
        (nx - 1, ny / 3, nz / 4),
    ] {
        let p = grid.voxel_centre(x, y, z);
        let brute: f64 = cloud
            .leaves()
            .iter()
            .map(|s| edge_weight(p.distance(base + s.centre_m()), s.radius as f64))
            .sum();
        assert!(
            (grid.at(x, y, z) as f64 - brute).abs() < 1e-5,
            "({x},{y},{z})"
        );
    }
    // The box is the leaves' bounding box.
    let lo = cloud
        .leaves()
        .iter()
        .map(|s| s.centre[0] as f64 - s.radius as f64)
        .fold(f64::INFINITY, f64::min);
    assert!((grid.origin_m.x - (base.x + lo)).abs() < 1e-6);
    assert_eq!(
        cloud.voxelize(0.001, None).unwrap_err().field(),
        "voxel_size_m"
    );
    assert_eq!(
        cloud.voxelize(-1.0, None).unwrap_err().field(),
        "voxel_size_m"
    );
    assert_eq!(cloud.voxelize(10.0, Some(9)).unwrap_err().field(), "level");
}

#[test]
fn bad_parameters_are_refused_with_their_name() {
    let p = flat_cloud(3, 1);
    let field = |f: &dyn Fn(&mut SphereCloudParams)| {
        let mut q = p.clone();
        f(&mut q);
        SphereCloud::new(&q).unwrap_err().field().to_string()
    };
    assert_eq!(field(&|q| q.levels = MAX_LEVELS + 1), "levels");
    assert_eq!(field(&|q| q.mor_m = 0.0), "mor_m");
    assert_eq!(field(&|q| q.size_m = [1.0, f64::NAN, 1.0]), "size_m");
    assert_eq!(
        field(&|q| q.radius_factor_range = [0.5, 1.2]),
        "radius_factor_range"
    );
    assert_eq!(
        field(&|q| q.offset_factor_range = [0.9, 0.8]),
        "offset_factor_range"
    );
    assert!(Ray::new(DVec3::ZERO, DVec3::ZERO, 1.0).is_err());
    let cloud = SphereCloud::new(&p).unwrap();
    let cam = Camera {
        eye_m: DVec3::ZERO,
        target_m: DVec3::X,
        up: DVec3::Z,
        fov_y_deg: 200.0,
        width: 4,
        height: 4,
    };
    assert_eq!(
        cloud.render_transmittance(&cam, None).unwrap_err().field(),
        "fov_y_deg"
    );
}

#[test]
fn example_scene_parses_builds_and_documents_every_parameter() {
    let text = include_str!("../../config/scenes/sphere-cloud.json");
    let section = parse_scene_file(text.as_bytes()).unwrap();
    let CloudSource::Spheres(source) = &section.source else {
        panic!("sphere-cloud.json is not a spheres scene")
    };
    assert_eq!(source.level, None);
    let scene: serde_json::Value = serde_json::from_str(text).unwrap();
    let block = &scene["cloud"]["source"]["params"];
    let doc = scene["doc"].as_object().unwrap();
    for key in block.as_object().unwrap().keys() {
        assert!(doc.contains_key(key), "parameter {key} is not documented");
    }
    for key in ["voxel_size_m", "level"] {
        assert!(doc.contains_key(key), "{key} is not documented");
    }
    let cloud = SphereCloud::new(&source.params).unwrap();
    assert_eq!(cloud.leaves().len(), 15_625);
    // The scene API gives the same grid as the model's own voxeliser.
    let no_files = |path: &str| -> skybake_physics::Result<Vec<u8>> {
        Err(skybake_physics::Error::invalid(
            "path",
            format!("no file {path}"),
        ))
    };
    let grid = section.voxelize(&no_files).unwrap();
    assert_eq!(grid, cloud.voxelize(section.voxel_size_m, None).unwrap());
    assert!(grid.max_density() > 0.5);
}

/// `level` picks a coarser level of the same hierarchy; a level above K is refused by name.
#[test]
fn scene_source_level_selects_the_summed_spheres() {
    let params = SphereCloudParams::cumulus(3, 9);
    let cloud = SphereCloud::new(&params).unwrap();
    let no_files = |path: &str| -> skybake_physics::Result<Vec<u8>> {
        Err(skybake_physics::Error::invalid(
            "path",
            format!("no file {path}"),
        ))
    };
    let source = |level: Option<u32>| {
        CloudSource::Spheres(SpheresSource {
            level,
            params: params.clone(),
        })
    };
    let coarse = voxelize(&source(Some(1)), 100.0, &no_files).unwrap();
    assert_eq!(coarse, cloud.voxelize(100.0, Some(1)).unwrap());
    let p = coarse.voxel_centre(coarse.dims[0] / 2, coarse.dims[1] / 2, coarse.dims[2] / 2);
    assert!((coarse.sample(p) as f64 - cloud.density_at(p, 1)).abs() < 1e-5);
    assert_eq!(
        voxelize(&source(Some(4)), 100.0, &no_files)
            .unwrap_err()
            .field(),
        "level"
    );
}
