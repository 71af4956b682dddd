use serde_json::{json, Value};
use skybake::engine::Engine;
use skybake::render::product::{execute_plan, measured_shares, plan_frame, sphere_facts};
use skybake::render::{lighting_for, render_tile, FrameScene, Method, Prepared};
use std::time::Instant;

fn scene(edit: impl FnOnce(&mut Value)) -> Value {
    let mut v: Value =
        serde_json::from_str(include_str!("../config/scenes/validation-frame.json")).unwrap();
    v["camera"]["width"] = json!(48);
    v["camera"]["height"] = json!(36);
    v["quality"] = json!("standard");
    edit(&mut v);
    v
}
fn parse(v: &Value) -> FrameScene {
    FrameScene::parse(&serde_json::to_vec(v).unwrap()).unwrap()
}
fn render(
    s: &FrameScene,
    grid: &skybake::cloud::DensityGrid,
    method: Method,
    spp: usize,
) -> (Vec<f32>, f64) {
    let t = Instant::now();
    let plan = plan_frame(s, grid, method);
    let run = execute_plan(&plan.without_cost_rules(), s, grid, method).unwrap();
    let g = run.grid.as_ref().unwrap_or(grid);
    let l = lighting_for(&run.scene, g, &Engine::new()).unwrap();
    let mut st = run.settings;
    st.spp = spp;
    let p = Prepared::new(&run.scene, g, &l, st, &|| false).unwrap();
    let r = render_tile(&p, None, &|_| {}, &|| false).unwrap().radiance;
    (r, t.elapsed().as_secs_f64() * 1e3)
}

#[test]
fn explore_spheres() {
    let sph: Value =
        serde_json::from_str(include_str!("../config/scenes/sphere-cloud.json")).unwrap();
    for (dist, fov) in [(30000.0, 12.0), (15000.0, 12.0)] {
        let v = scene(|v| {
            v["cloud"] = sph["cloud"].clone();
            v["cloud"]["voxel_size_m"] = json!(25.0);
            v["optics"]["extinction_per_density_m"] = json!(3.912 / 60.0);
            v["camera"]["position_m"] = json!([0, -dist, 1200]);
            v["camera"]["look_at_m"] = json!([0, 0, 1500]);
            v["camera"]["fov_deg"] = json!(fov);
        });
        let s = parse(&v);
        eprintln!("dist {dist}: facts {:?}", sphere_facts(&s).unwrap());
        let vox = |level: u32| {
            let mut c = s.cloud.clone();
            if let skybake::cloud::scene::CloudSource::Spheres(src) = &mut c.source {
                src.level = Some(level);
            }
            let t = Instant::now();
            let g = c
                .voxelize(&|_| Err(skybake::Error::invalid("p", "x")))
                .unwrap();
            (g, t.elapsed().as_secs_f64() * 1e3)
        };
        let (g6, t6) = vox(6);
        let empty =
            skybake::cloud::DensityGrid::zeros(g6.dims, g6.voxel_size_m, g6.origin_m).unwrap();
        let (bg, _) = render(&s, &empty, Method::Fast, 1);
        let (r6, rt6) = render(&s, &g6, Method::Fast, 1);
        let (pt, _) = render(&s, &g6, Method::Reference, 64);
        let sig = |x: &[f32]| {
            x.iter()
                .zip(&bg)
                .map(|(a, b)| (*a as f64 - *b as f64))
                .sum::<f64>()
                / x.len() as f64
        };
        let abs_sig = pt
            .iter()
            .zip(&bg)
            .map(|(a, b)| (*a as f64 - *b as f64).abs())
            .sum::<f64>()
            / pt.len() as f64;
        eprintln!("L6 vox {t6:.0} ms render {rt6:.0} ms dims {:?} signal {:.4e} pt {:.4e} bias vs pt {:+.3}", g6.dims, sig(&r6), sig(&pt), (sig(&r6)-sig(&pt))/abs_sig);
        for level in [5u32, 4, 3] {
            let (g, t) = vox(level);
            let (r, rt) = render(&s, &g, Method::Fast, 1);
            let rms = (r
                .iter()
                .zip(&r6)
                .map(|(a, b)| (*a as f64 - *b as f64).powi(2))
                .sum::<f64>()
                / r.len() as f64)
                .sqrt();
            eprintln!("L{level} vox {t:.0} ms render {rt:.0} ms dims {:?} change of mean {:+.4} rms {:.4} bias vs pt {:+.3}", g.dims, (sig(&r) - sig(&r6)) / abs_sig, rms / abs_sig, (sig(&r)-sig(&pt))/abs_sig);
        }
    }
}

#[test]
fn explore_deep() {
    let sph: Value =
        serde_json::from_str(include_str!("../config/scenes/sphere-cloud.json")).unwrap();
    let v = scene(|v| {
        v["cloud"] = sph["cloud"].clone();
        v["cloud"]["source"]["params"]["levels"] = json!(8);
        v["cloud"]["voxel_size_m"] = json!(25.0);
        v["optics"]["extinction_per_density_m"] = json!(3.912 / 60.0);
        v["camera"]["position_m"] = json!([0, -30000, 1200]);
        v["camera"]["look_at_m"] = json!([0, 0, 1500]);
        v["camera"]["fov_deg"] = json!(12);
    });
    let s = parse(&v);
    let t = Instant::now();
    eprintln!(
        "K8 facts {:?} in {:.0} ms",
        sphere_facts(&s).unwrap(),
        t.elapsed().as_secs_f64() * 1e3
    );
    for level in [8u32, 7, 6, 5, 4] {
        let mut c = s.cloud.clone();
        if let skybake::cloud::scene::CloudSource::Spheres(src) = &mut c.source {
            src.level = Some(level);
        }
        let t = Instant::now();
        let g = c
            .voxelize(&|_| Err(skybake::Error::invalid("p", "x")))
            .unwrap();
        let (r, rt) = render(&s, &g, Method::Fast, 1);
        let m = r.iter().map(|&x| x as f64).sum::<f64>() / r.len() as f64;
        eprintln!(
            "K8 L{level} vox {:.0} ms dims {:?} render {rt:.0} ms mean {m:.4e}",
            t.elapsed().as_secs_f64() * 1e3 - rt,
            g.dims
        );
    }
}

#[test]
fn explore_atmosphere_shares() {
    for albedo in [0.0, 0.02, 0.06, 0.3] {
        let v = scene(|v| {
            v["cloud"]["voxel_size_m"] = json!(50.0);
            v["atmosphere"] = json!("earth");
            v["sky"] = json!("atmosphere");
            v["sun"] = json!({"elevation_deg": 35, "azimuth_deg": 140});
            v["ground"] = json!({"albedo": albedo, "height_m": 0});
            v["wavelengths_nm"] = json!([440, 550, 680]);
        });
        let s = parse(&v);
        let grid = s
            .cloud
            .voxelize(&|_| Err(skybake::Error::invalid("p", "x")))
            .unwrap();
        let t = Instant::now();
        let l = lighting_for(&s, &grid, &Engine::new()).unwrap();
        eprintln!(
            "albedo {albedo}: lighting {:.0} ms shares {:?}",
            t.elapsed().as_secs_f64() * 1e3,
            measured_shares(&l)
        );
    }
}
