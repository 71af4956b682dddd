//! The bit-packed automaton against a plain one-cell-at-a-time implementation of Dobashi et al. 2000, eqs 1–10
//! (bool arrays, the same random-bit table and the same per-word draws), plus wind, obstacle and
//! density properties.

use skybake_physics::cloud::automaton::control::{ACT, EXT, HUM};
use skybake_physics::cloud::automaton::random::{draw, slice_rng};
use skybake_physics::cloud::automaton::{
    automaton_density, automaton_frames, Automaton, AutomatonParams, Ellipsoid, Hill, Obstacle,
    RandomEllipsoids, RuleProbabilities, Smoothing, WindKnot,
};
use skybake_physics::cloud::scene::{parse_scene_file, voxelize, AutomatonSource, CloudSource};

/// Plain reference: one bool per cell, index (z·ny + y)·nx + x.
struct Reference {
    dims: [usize; 3],
    hum: Vec<bool>,
    act: Vec<bool>,
    cld: Vec<bool>,
}

impl Reference {
    fn from(sim: &Automaton) -> Self {
        let [nx, ny, nz] = sim.dims();
        let s = sim.state();
        let mut r = Reference {
            dims: sim.dims(),
            hum: vec![false; nx * ny * nz],
            act: vec![false; nx * ny * nz],
            cld: vec![false; nx * ny * nz],
        };
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let (w, b) = sim.word_bit(x, y, z);
                    let i = r.idx(x, y, z);
                    r.hum[i] = (s.hum[w] >> b) & 1 == 1;
                    r.act[i] = (s.act[w] >> b) & 1 == 1;
                    r.cld[i] = (s.cld[w] >> b) & 1 == 1;
                }
            }
        }
        r
    }

    fn idx(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// act at (x, y, z) with zero outside the space.
    fn act_at(&self, x: isize, y: isize, z: isize) -> bool {
        let [nx, ny, nz] = self.dims;
        if x < 0 || y < 0 || z < 0 || x >= nx as isize || y >= ny as isize || z >= nz as isize {
            return false;
        }
        self.act[self.idx(x as usize, y as usize, z as usize)]
    }

    /// One step, using `sim` (before its step) for the controls, table and seed.
    fn step(&mut self, sim: &Automaton) {
        let [nx, ny, nz] = self.dims;
        let m = nx.div_ceil(64);
        let step = sim.steps_done();
        let supply = sim.supplies_at(step);
        let table = sim.table();
        let n = nx * ny * nz;
        let (mut h, mut a, mut c) = (vec![false; n], vec![false; n], vec![false; n]);
        let mut row_levels = vec![[0u16; 3]; nx];
        for z in 0..nz {
            let mut rng = slice_rng(sim.seed(), step, z);
            for y in 0..ny {
                let seqs: Vec<[usize; 3]> = (0..m)
                    .map(|_| std::array::from_fn(|_| table.sequence_of(draw(&mut rng))))
                    .collect();
                sim.control().fill_row(y, z, &mut row_levels);
                for x in 0..nx {
                    let i = self.idx(x, y, z);
                    let (xi, yi, zi) = (x as isize, y as isize, z as isize);
                    // Eq 4, neighbour by neighbour.
                    let f = [
                        (1, 0, 0),
                        (0, 1, 0),
                        (0, 0, 1),
                        (-1, 0, 0),
                        (0, -1, 0),
                        (0, 0, -1),
                        (-2, 0, 0),
                        (2, 0, 0),
                        (0, -2, 0),
                        (0, 2, 0),
                        (0, 0, -2),
                    ]
                    .iter()
                    .any(|&(dx, dy, dz)| self.act_at(xi + dx, yi + dy, zi + dz));
                    let mut hn = self.hum[i] && !self.act[i]; // eq 1
                    let mut cn = self.cld[i] || self.act[i]; // eq 2
                    let mut an = !self.act[i] && self.hum[i] && f; // eq 3
                    let [s_ext, s_hum, s_act] = seqs[x / 64];
                    let lv = row_levels[x];
                    cn = cn && !table.bit(lv[EXT], s_ext, x % 64); // eq 5
                    if supply {
                        hn = hn || table.bit(lv[HUM], s_hum, x % 64); // eq 6
                        an = an || table.bit(lv[ACT], s_act, x % 64); // eq 7
                    }
                    h[i] = hn;
                    a[i] = an;
                    c[i] = cn;
                }
            }
        }
        // Eqs 8–10, then obstacles.
        for z in 0..nz {
            let v = sim.wind().velocity_cells(z) as isize;
            for y in 0..ny {
                for x in 0..nx {
                    let src = x as isize - v;
                    let i = self.idx(x, y, z);
                    let inside = src >= 0 && src < nx as isize && sim.is_open(x, y, z);
                    let s = if inside {
                        self.idx(src as usize, y, z)
                    } else {
                        0
                    };
                    self.hum[i] = inside && h[s];
                    self.act[i] = inside && a[s];
                    self.cld[i] = inside && c[s];
                }
            }
        }
    }
}

fn knot(h: f64, v: f64) -> WindKnot {
    WindKnot {
        height_cells: h,
        velocity_cells_per_step: v,
    }
}

fn busy_params(dims: [usize; 3], seed: u64) -> AutomatonParams {
    let mut p = AutomatonParams::example(dims, seed);
    let [nx, ny, nz] = dims;
    p.initial_act_probability = 0.02;
    p.probability_levels = 200;
    p.random_sequences = 16;
    p.supply_interval_steps = 3;
    p.background = RuleProbabilities {
        hum: 0.02,
        act: 0.005,
        ext: 0.05,
    };
    p.ellipsoids = vec![Ellipsoid {
        centre_cells: [nx as f64 * 0.4, ny as f64 * 0.5, nz as f64 * 0.5],
        semi_axes_cells: [nx as f64 * 0.3, ny as f64 * 0.4, nz as f64 * 0.4],
        centre: RuleProbabilities {
            hum: 0.5,
            act: 0.05,
            ext: 0.01,
        },
        ext_edge: 0.2,
    }];
    p.random_ellipsoids = Some(RandomEllipsoids {
        count: 3,
        semi_axes_min_cells: [5.0, 2.0, 2.0],
        semi_axes_max_cells: [30.0, 4.0, 3.0],
        centre_height_range_cells: [1.0, nz as f64 - 1.0],
        centre: RuleProbabilities {
            hum: 0.3,
            act: 0.02,
            ext: 0.02,
        },
        ext_edge: 0.3,
    });
    // Sheared wind, both directions, one layer faster than a word.
    p.wind = vec![
        knot(0.0, -3.0),
        knot(nz as f64 * 0.5, 1.0),
        knot(nz as f64, 70.0),
    ];
    p.obstacle = Some(Obstacle::Hills {
        hills: vec![Hill {
            centre_cells: [nx as f64 * 0.7, ny as f64 * 0.5],
            height_cells: nz as f64 * 0.5,
            sigma_cells: nx as f64 * 0.1,
        }],
    });
    p
}

fn assert_same(sim: &Automaton, r: &Reference, step: u64) {
    let [nx, ny, nz] = sim.dims();
    let s = sim.state();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let (w, b) = sim.word_bit(x, y, z);
                let i = r.idx(x, y, z);
                assert_eq!(
                    (s.hum[w] >> b) & 1 == 1,
                    r.hum[i],
                    "hum ({x},{y},{z}) step {step}"
                );
                assert_eq!(
                    (s.act[w] >> b) & 1 == 1,
                    r.act[i],
                    "act ({x},{y},{z}) step {step}"
                );
                assert_eq!(
                    (s.cld[w] >> b) & 1 == 1,
                    r.cld[i],
                    "cld ({x},{y},{z}) step {step}"
                );
            }
        }
        // Padding bits beyond nx stay clear.
        let pad_word = (z * ny) * sim.words_per_row() + sim.words_per_row() - 1;
        if nx % 64 != 0 {
            assert_eq!(s.cld[pad_word] >> (nx % 64), 0);
        }
    }
}

#[test]
fn packed_automaton_matches_cell_by_cell_reference_bit_exactly() {
    for (dims, seed, steps) in [
        ([131usize, 7usize, 9usize], 11u64, 60u64),
        ([37, 5, 6], 3, 80),
        ([64, 6, 5], 5, 40),
        ([200, 3, 4], 9, 40),
    ] {
        let params = busy_params(dims, seed);
        let mut sim = Automaton::new(&params).unwrap();
        let mut reference = Reference::from(&sim);
        let mut max_cloud = 0usize;
        let mut extinctions = 0usize;
        for s in 0..steps {
            let before = reference.cld.iter().filter(|c| **c).count();
            reference.step(&sim);
            sim.step();
            assert_same(&sim, &reference, s);
            let count = reference.cld.iter().filter(|c| **c).count();
            max_cloud = max_cloud.max(count);
            // Net losses of cloud cells (extinction outpacing growth).
            extinctions += before.saturating_sub(count);
        }
        // The comparison is only meaningful if clouds formed and died.
        assert!(max_cloud > 20, "{dims:?}: max cloud cells {max_cloud}");
        assert!(extinctions > 0, "{dims:?}: no extinction happened");
    }
}

#[test]
fn wind_moves_each_layer_by_its_velocity_per_step() {
    let dims = [150, 3, 5];
    let mut p = AutomatonParams::example(dims, 4);
    // Nothing but advection: no activation, no supply, no extinction, no ellipsoids.
    p.initial_hum_probability = 0.5;
    p.initial_act_probability = 0.0;
    p.background = RuleProbabilities {
        hum: 0.0,
        act: 0.0,
        ext: 0.0,
    };
    p.random_ellipsoids = None;
    p.wind = vec![knot(0.5, -2.0), knot(4.5, 66.0)]; // layers: −2, 15, 32, 49, 66
    let mut sim = Automaton::new(&p).unwrap();
    let v: Vec<i32> = (0..5).map(|k| sim.wind().velocity_cells(k)).collect();
    assert_eq!(v, vec![-2, 15, 32, 49, 66]);
    let hum = |s: &Automaton, x: usize, y: usize, z: usize| {
        let (w, b) = s.word_bit(x, y, z);
        (s.state().hum[w] >> b) & 1 == 1
    };
    for _ in 0..3 {
        let before = sim.clone();
        sim.step();
        for (z, vz) in v.iter().enumerate() {
            for y in 0..3 {
                for x in 0..150 {
                    let src = x as i64 - *vz as i64;
                    let expect = (0..150).contains(&src) && hum(&before, src as usize, y, z);
                    assert_eq!(hum(&sim, x, y, z), expect, "({x},{y},{z})");
                }
            }
        }
    }
    // Something was actually moving: layer 0 still holds vapour that came from x + 2.
    assert!((0..148).any(|x| hum(&sim, x, 1, 0)));
}

#[test]
fn obstacles_never_hold_cloud_and_clouds_form_around_them() {
    let dims = [96, 32, 12];
    let mut p = busy_params(dims, 21);
    p.wind = vec![knot(0.0, 1.0)];
    p.obstacle = Some(Obstacle::Hills {
        hills: vec![Hill {
            centre_cells: [48.0, 16.0],
            height_cells: 9.0,
            sigma_cells: 8.0,
        }],
    });
    let heights = p.obstacle.as_ref().unwrap().column_heights(96, 32).unwrap();
    let mut sim = Automaton::new(&p).unwrap();
    let mut solid = 0;
    for step in 0..50 {
        sim.step();
        let s = sim.state();
        for z in 0..12 {
            for y in 0..32 {
                for x in 0..96 {
                    let inside = (z as f64 + 0.5) < heights[y * 96 + x];
                    assert_eq!(sim.is_open(x, y, z), !inside);
                    if inside {
                        solid += 1;
                        let (w, b) = sim.word_bit(x, y, z);
                        let any = (s.hum[w] | s.act[w] | s.cld[w]) >> b & 1;
                        assert_eq!(any, 0, "({x},{y},{z}) at step {step}");
                    }
                }
            }
        }
    }
    assert!(solid > 0);
    // Cloud right above the summit region.
    let above = (0..96)
        .flat_map(|x| (0..32).map(move |y| (x, y)))
        .filter(|&(x, y)| heights[y * 96 + x] > 4.0)
        .any(|(x, y)| (0..12).any(|z| sim.cloud(x, y, z)));
    assert!(above);
}

#[test]
fn same_seed_same_run_any_thread_count_and_seeds_differ() {
    let p = busy_params([100, 9, 7], 77);
    let run = |p: &AutomatonParams| {
        let mut s = Automaton::new(p).unwrap();
        for _ in 0..25 {
            s.step();
        }
        s.state().clone()
    };
    let a = run(&p);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = pool.install(|| run(&p));
    assert_eq!(a, b);
    let mut q = p.clone();
    q.seed = 78;
    assert_ne!(a, run(&q));
}

#[test]
fn frames_interpolate_between_steps_and_stay_in_unit_range() {
    let mut p = AutomatonParams::example([70, 40, 10], 5);
    p.smoothing = Smoothing {
        i0: 1,
        j0: 1,
        k0: 1,
        t0: 2,
    };
    let frames = automaton_frames(&p, &[31.0, 30.25, 30.0]).unwrap();
    let (f31, f3025, f30) = (&frames[0], &frames[1], &frames[2]);
    assert!(f30.max_density() > 0.05, "no cloud: {}", f30.max_density());
    for i in 0..f30.data.len() {
        let expect = 0.75 * f30.data[i] + 0.25 * f31.data[i];
        assert!((f3025.data[i] - expect).abs() < 1e-6);
        assert!(f30.data[i] >= 0.0 && f30.data[i] <= 1.0 + 1e-5);
    }
    assert_eq!(f30.dims, [70, 40, 10]);
    assert_eq!(f30.voxel_size_m, 100.0);
    // A separate call for one time gives the same grid.
    let single = automaton_density(&p, 30.25).unwrap();
    assert_eq!(&single, f3025);
}

#[test]
fn bad_parameters_are_refused_with_their_name() {
    let p = AutomatonParams::example([64, 64, 8], 1);
    let field = |f: &dyn Fn(&mut AutomatonParams)| {
        let mut q = p.clone();
        f(&mut q);
        automaton_density(&q, 1.0).unwrap_err().field().to_string()
    };
    assert_eq!(field(&|q| q.dims = [100_000, 100_000, 100]), "dims");
    assert_eq!(field(&|q| q.dims = [0, 4, 4]), "dims");
    assert_eq!(
        field(&|q| q.metaball_radius_cells = 0.0),
        "metaball_radius_cells"
    );
    assert_eq!(field(&|q| q.cell_size_m = -1.0), "cell_size_m");
    assert_eq!(field(&|q| q.smoothing.t0 = 1000), "smoothing.t0");
    assert_eq!(field(&|q| q.background.ext = 1.5), "background.ext");
    assert_eq!(field(&|q| q.random_sequences = 0), "random_sequences");
    // Huge parcels would need unbounded stamps.
    assert_eq!(
        field(&|q| q.random_ellipsoids.as_mut().unwrap().semi_axes_max_cells = [1e6; 3]),
        "ellipsoids"
    );
    assert_eq!(
        automaton_density(&p, -1.0).unwrap_err().field(),
        "times_steps"
    );
    assert_eq!(
        automaton_density(&p, f64::NAN).unwrap_err().field(),
        "times_steps"
    );
}

#[test]
fn example_scene_parses_runs_and_documents_every_parameter() {
    let text = include_str!("../../config/scenes/automaton-field.json");
    let section = parse_scene_file(text.as_bytes()).unwrap();
    let CloudSource::Automaton(source) = &section.source else {
        panic!("automaton-field.json is not an automaton scene")
    };
    assert_eq!(source.frame_time_steps, 150.5);
    let params = &source.params;
    assert_eq!(section.voxel_size_m, params.cell_size_m);
    let scene: serde_json::Value = serde_json::from_str(text).unwrap();
    let block = &scene["cloud"]["source"]["params"];
    let doc = scene["doc"].as_object().unwrap();
    for key in block.as_object().unwrap().keys() {
        assert!(doc.contains_key(key), "parameter {key} is not documented");
    }
    for key in ["voxel_size_m", "frame_time_steps"] {
        assert!(doc.contains_key(key), "{key} is not documented");
    }
    let mut sim = Automaton::new(params).unwrap();
    for _ in 0..60 {
        sim.step();
    }
    assert!(sim.cloud_cover() > 0.001, "cover {}", sim.cloud_cover());
    assert!(
        !sim.is_open(170, 64, 0),
        "the mountain is solid at its foot"
    );
}

/// The scene source at another voxel size resamples the automaton's own grid over the same box,
/// and bad frame times are refused naming the field.
#[test]
fn scene_source_resamples_and_checks_the_frame_time() {
    let mut params = busy_params([64, 32, 8], 5);
    params.cell_size_m = 100.0;
    let direct = automaton_density(&params, 12.25).unwrap();
    let source = |t: f64| {
        CloudSource::Automaton(Box::new(AutomatonSource {
            frame_time_steps: t,
            params: params.clone(),
        }))
    };
    let no_files = |path: &str| -> skybake_physics::Result<Vec<u8>> {
        Err(skybake_physics::Error::invalid(
            "path",
            format!("no file {path}"),
        ))
    };
    let same = voxelize(&source(12.25), 100.0, &no_files).unwrap();
    assert_eq!(same, direct);
    let coarse = voxelize(&source(12.25), 200.0, &no_files).unwrap();
    assert_eq!(coarse.dims, [32, 16, 4]);
    assert_eq!(coarse.origin_m, direct.origin_m);
    // A coarse voxel centre sits on a corner shared by 2×2×2 fine cells: their mean.
    let mut mean = 0.0;
    for (dx, dy, dz) in (0..8).map(|i| (i & 1, (i >> 1) & 1, i >> 2)) {
        mean += direct.at(10 + dx, 6 + dy, 2 + dz) as f64 / 8.0;
    }
    assert!((coarse.at(5, 3, 1) as f64 - mean).abs() < 1e-5);
    for t in [-0.5, 2e6, f64::NAN] {
        assert_eq!(
            voxelize(&source(t), 100.0, &no_files).unwrap_err().field(),
            "frame_time_steps"
        );
    }
}
