//! Bakes shared among processes (`skybake bake --shard I/N`): shares are disjoint and cover the
//! job, a shard killed with SIGKILL mid-item resumes without recomputing what it stored, `--status`
//! reports over all shards, and the manifest lists every artifact once. The bucket test needs
//! `SKYBAKE_TEST_S3_ENDPOINT` (skipped with a printed reason without it); the directory test
//! always runs.

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use serde_json::Value;
use skybake_engine::engine::Engine;
use skybake_job::bake::{bake_share, status, BakeEnv, Shard};
use skybake_product::params::Defaults;
use skybake_store::{Location, RetryPolicy};

use crate::service_support::s3;
use crate::service_support::Scratch;

const BIN: &str = env!("CARGO_BIN_EXE_skybake");

/// `n` cheap sky items (a sun-elevation sweep).
fn job(n: usize) -> String {
    let elevations: Vec<String> = (0..n).map(|i| format!("{}", 2 * i)).collect();
    format!(
        r#"{{"grids": [{{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "440,550,680",
            "elevation_count": 17, "azimuth_count": 16,
            "sweep": {{"sun_elevation_deg": [{}]}}}}]}}"#,
        elevations.join(", ")
    )
}

#[test]
fn shards_are_parsed_and_checked() {
    assert_eq!(Shard::parse("2/8").unwrap(), Shard { index: 2, count: 8 });
    for bad in ["8/8", "0/0", "a/4", "4", "1/100001", "-1/4"] {
        let e = Shard::parse(bad).unwrap_err();
        assert_eq!(e.parameter().as_deref(), Some("shard"), "{bad}");
    }
    let shares: Vec<Vec<usize>> = (0..3)
        .map(|s| {
            (0..10)
                .filter(|&i| Shard::new(s, 3).unwrap().owns(i))
                .collect()
        })
        .collect();
    assert_eq!(shares, vec![vec![0, 3, 6, 9], vec![1, 4, 7], vec![2, 5, 8]]);
}

#[test]
fn two_shards_in_one_directory_bake_the_job_once_and_write_one_manifest() {
    let dir = Scratch::new("shards-dir");
    let out = Location::Dir(dir.path().join("out"));
    let body = job(5);
    let (defaults, engine) = (Defaults::default(), Engine::new());
    let env = BakeEnv {
        defaults: &defaults,
        max_products: 1000,
        engine: &engine,
        cancel: &|| false,
    };
    let first = bake_share(
        body.as_bytes(),
        &out,
        Shard::new(0, 2).unwrap(),
        &env,
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!((first.total, first.computed), (3, 3));
    let half = status(body.as_bytes(), &out, &defaults, 1000).unwrap();
    assert_eq!((half.total, half.present, half.manifest), (5, 3, false));
    assert_eq!(half.missing, vec![1, 3]);
    let second = bake_share(
        body.as_bytes(),
        &out,
        Shard::new(1, 2).unwrap(),
        &env,
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!((second.total, second.computed), (2, 2));
    let done = status(body.as_bytes(), &out, &defaults, 1000).unwrap();
    assert_eq!(
        (done.present, done.manifest, done.shards.len()),
        (5, true, 2)
    );
    let manifest: Value =
        serde_json::from_slice(&out.get("manifest.json").unwrap().unwrap()).unwrap();
    let indices: Vec<u64> = manifest["artifacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["index"].as_u64().unwrap())
        .collect();
    assert_eq!(indices, vec![0, 1, 2, 3, 4]);
    // A rerun of a shard reuses its verified files.
    let again = bake_share(
        body.as_bytes(),
        &out,
        Shard::new(1, 2).unwrap(),
        &env,
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!((again.computed, again.reused, again.rejected), (0, 2, 0));
}

fn shard_command(
    job: &std::path::Path,
    url: &str,
    endpoint: &str,
    cache: &std::path::Path,
) -> Command {
    let mut cmd = Command::new(BIN);
    cmd.arg("bake")
        .arg(job)
        .args(["--out", url])
        .env("SKYBAKE_CACHE_DIR", cache)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    s3::aws_env(&mut cmd, endpoint);
    cmd
}

fn summary(output: std::process::Output) -> Value {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn four_shard_processes_on_one_bucket_survive_a_sigkill_and_compute_each_item_once() {
    let Some(endpoint) = s3::endpoint("four_shard_processes_on_one_bucket") else {
        return;
    };
    let dir = Scratch::new("shards-s3");
    let job_path = dir.path().join("job.json");
    std::fs::write(&job_path, job(24)).unwrap();
    let url = s3::fresh_url("shards");
    let cache = dir.path().join("cache");

    // Shard 3 takes its share from a Kubernetes Indexed Job's variables.
    let mut children = Vec::new();
    for index in 0..4 {
        let mut cmd = shard_command(&job_path, &url, &endpoint, &cache);
        if index == 3 {
            cmd.env("JOB_COMPLETION_INDEX", "3")
                .env("JOB_COMPLETIONS", "4");
        } else {
            cmd.args(["--shard", &format!("{index}/4")]);
        }
        children.push(cmd.spawn().unwrap());
    }
    // Shard 1 dies with SIGKILL once it has stored its first item, i.e. inside its second.
    let mut victim = children.remove(1);
    let stderr = victim.stderr.take().unwrap();
    let mut first_line = String::new();
    BufReader::new(stderr).read_line(&mut first_line).unwrap();
    assert!(first_line.contains("[1/6] computed"), "{first_line}");
    victim.kill().unwrap();
    victim.wait().unwrap();
    for child in children {
        let s = summary(child.wait_with_output().unwrap());
        assert_eq!(
            (s["total"].as_u64(), s["computed"].as_u64()),
            (Some(6), Some(6)),
            "{s}"
        );
        assert_eq!(s["reused"].as_u64(), Some(0));
    }

    let status_of = || {
        let mut cmd = shard_command(&job_path, &url, &endpoint, &cache);
        summary(cmd.arg("--status").output().unwrap())
    };
    let partial = status_of();
    assert_eq!(partial["total"].as_u64(), Some(24));
    assert_eq!(partial["manifest"].as_bool(), Some(false));
    let stored_by_victim = 6 - partial["missing"].as_array().unwrap().len() as u64;
    assert!(stored_by_victim >= 1, "{partial}");
    assert!(partial["missing"]
        .as_array()
        .unwrap()
        .iter()
        .all(|i| i.as_u64().unwrap() % 4 == 1));

    // Restarted with the same index, it computes only what it had not stored.
    let mut cmd = shard_command(&job_path, &url, &endpoint, &cache);
    let restarted = summary(cmd.args(["--shard", "1/4"]).output().unwrap());
    assert_eq!(
        restarted["reused"].as_u64(),
        Some(stored_by_victim),
        "{restarted}"
    );
    assert_eq!(restarted["computed"].as_u64(), Some(6 - stored_by_victim));
    assert_eq!(restarted["rejected"].as_u64(), Some(0));

    let done = status_of();
    assert_eq!(
        (done["present"].as_u64(), done["manifest"].as_bool()),
        (Some(24), Some(true)),
        "{done}"
    );
    assert_eq!(done["shards"].as_object().unwrap().len(), 4);
    let bucket = s3::open(&url, &endpoint, RetryPolicy::default());
    let manifest: Value =
        serde_json::from_slice(&bucket.get("manifest.json").unwrap().unwrap()).unwrap();
    let artifacts = manifest["artifacts"].as_array().unwrap();
    let files: BTreeSet<&str> = artifacts
        .iter()
        .map(|a| a["file"].as_str().unwrap())
        .collect();
    let indices: BTreeSet<u64> = artifacts
        .iter()
        .map(|a| a["index"].as_u64().unwrap())
        .collect();
    assert_eq!((artifacts.len(), files.len(), indices.len()), (24, 24, 24));
    for file in files {
        let bytes = bucket.get(file).unwrap().expect("listed artifact present");
        skybake_store::checksum::verify(&bytes).unwrap();
    }
}

/// A texture-bundle item (`"bundles"`) is baked by its shard into its textures and its bundle
/// manifest (written last, linking them), listed in the job's manifest as product `lut`, and
/// reused by a rerun (its manifest is for the same request and its textures pass their
/// checksums).
#[test]
fn bundle_items_are_baked_by_their_shard_and_reused() {
    let dir = Scratch::new("shards-lut");
    let out = Location::Dir(dir.path().join("out"));
    let body = r#"{"grids": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "440,550,680",
        "elevation_count": 17, "azimuth_count": 16, "sweep": {"sun_elevation_deg": [10]}}],
        "bundles": [{"quality": "draft", "ground_albedo": 0.2}]}"#;
    let (defaults, engine) = (Defaults::default(), Engine::new());
    let env = BakeEnv {
        defaults: &defaults,
        max_products: 1000,
        engine: &engine,
        cancel: &|| false,
    };
    let shard = |i| Shard::new(i, 2).unwrap();
    let sky = bake_share(body.as_bytes(), &out, shard(0), &env, |_, _, _| {}).unwrap();
    assert_eq!((sky.total, sky.computed), (1, 1));
    let lut = bake_share(body.as_bytes(), &out, shard(1), &env, |_, _, _| {}).unwrap();
    assert_eq!((lut.total, lut.computed, lut.failed), (1, 1, 0), "{lut:?}");
    let manifest: Value =
        serde_json::from_slice(&out.get("manifest.json").unwrap().unwrap()).unwrap();
    let item = &manifest["artifacts"][1];
    assert_eq!(item["product"], "lut");
    let file = item["file"].as_str().unwrap();
    assert!(
        file.starts_with("000001-lut-") && file.ends_with(".json"),
        "{file}"
    );
    let bundle: Value = serde_json::from_slice(&out.get(file).unwrap().unwrap()).unwrap();
    assert_eq!(bundle["request"]["form"], "rgb");
    assert_eq!(bundle["request"]["quality"], "draft");
    let links = bundle["links"].as_object().unwrap();
    let names: BTreeSet<&str> = links.keys().map(String::as_str).collect();
    assert_eq!(
        names,
        BTreeSet::from(["irradiance.exr", "scattering.exr", "transmittance.exr"])
    );
    for stored in links.values() {
        let bytes = out.get(stored.as_str().unwrap()).unwrap().unwrap();
        skybake_store::checksum::verify(&bytes).unwrap();
    }
    let again = bake_share(body.as_bytes(), &out, shard(1), &env, |_, _, _| {}).unwrap();
    assert_eq!((again.computed, again.reused, again.rejected), (0, 1, 0));
}

/// A bake cancelled while it computes a bundle stops inside it (in the tables' build or at the
/// next texture row), not after the whole bundle, and stores nothing for that item.
#[test]
fn a_cancelled_bake_stops_inside_a_bundle_item() {
    let dir = Scratch::new("shards-lut-cancel");
    let out = Location::Dir(dir.path().join("out"));
    let body = r#"{"bundles": [{"quality": "draft", "ground_albedo": 0.3}]}"#;
    let (defaults, engine) = (Defaults::default(), Engine::new());
    // The poll before the item says "go on"; every later one (inside the bundle) says "stop".
    let polls = std::sync::atomic::AtomicUsize::new(0);
    let cancel = || polls.fetch_add(1, std::sync::atomic::Ordering::Relaxed) >= 1;
    let env = BakeEnv {
        defaults: &defaults,
        max_products: 1000,
        engine: &engine,
        cancel: &cancel,
    };
    let err = bake_share(body.as_bytes(), &out, Shard::ALL, &env, |_, _, _| {})
        .expect_err("the bake must stop inside the bundle");
    assert!(err.to_string().contains("cancelled in item 0"), "{err}");
    // Polled inside the bundle, not only between items.
    assert!(polls.load(std::sync::atomic::Ordering::Relaxed) >= 3);
    assert!(out.get("manifest.json").unwrap().is_none());
}

/// A pre-lit cloud volume item (`"cloud_lights"`) is baked into its textures and its manifest
/// (linking them, with the request and engine version), listed as product `cloud_light`,
/// decodes through its links into the export the same request computes, and is reused by a
/// rerun; the service refuses such a job (offline only), and a bad entry names its field.
#[test]
fn cloud_light_items_are_baked_decoded_and_reused() {
    use skybake_product::cloud_light::{CloudLight, CloudLightRequest};
    let dir = Scratch::new("bake-cloud-light");
    let out = Location::Dir(dir.path().join("out"));
    let scene = serde_json::json!({
        "name": "ball",
        "cloud": {"voxel_size_m": 100.0, "source": {"type": "metaballs",
            "balls": [{"centre_m": [0, 0, 1500], "radius_m": 400, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": 0.02, "single_scattering_albedo": 1.0,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "pinhole", "position_m": [0, -4000, 1500], "look_at_m": [0, 0, 1500],
                   "up": [0, 0, 1], "fov_deg": 30, "width": 16, "height": 16},
        "sun": {"collimated": {"elevation_deg": 40, "azimuth_deg": 120, "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": {"constant_radiance_w_m2_sr_nm": 0.05}, "ground": null,
        "wavelengths_nm": [550], "quality": "draft"
    });
    let body = serde_json::json!({"cloud_lights": [{"scene": scene}]}).to_string();
    let (defaults, engine) = (Defaults::default(), Engine::new());
    let env = BakeEnv {
        defaults: &defaults,
        max_products: 1000,
        engine: &engine,
        cancel: &|| false,
    };
    let all = Shard::new(0, 1).unwrap();
    let first = bake_share(body.as_bytes(), &out, all, &env, |_, _, _| {}).unwrap();
    assert_eq!(
        (first.total, first.computed, first.failed),
        (1, 1, 0),
        "{first:?}"
    );
    let manifest: Value =
        serde_json::from_slice(&out.get("manifest.json").unwrap().unwrap()).unwrap();
    let item = &manifest["artifacts"][0];
    assert_eq!(item["product"], "cloud_light");
    let file = item["file"].as_str().unwrap();
    assert!(
        file.starts_with("000000-cloud_light-") && file.ends_with(".json"),
        "{file}"
    );
    let baked: Value = serde_json::from_slice(&out.get(file).unwrap().unwrap()).unwrap();
    assert_eq!(baked["product"], "cloud_light");
    let links = baked["links"].as_object().unwrap().clone();
    let names: BTreeSet<&str> = links.keys().map(String::as_str).collect();
    assert!(
        names.contains("multiple_scattering.exr") && names.contains("sun_path.exr"),
        "{names:?}"
    );
    // Decoded through the links (a client following them) it is the export of the request.
    let decoded = CloudLight::from_files(&|name: &str| {
        let stored = if name == "manifest.json" {
            file.to_string()
        } else {
            links[name].as_str().unwrap().to_string()
        };
        Ok(out.get(&stored).unwrap().unwrap())
    })
    .unwrap();
    let req = CloudLightRequest::parse(scene.to_string().as_bytes()).unwrap();
    let direct = req
        .compute(&engine, &|_| unreachable!("no files"), &|| false)
        .unwrap();
    assert_eq!(decoded, direct.light);
    let again = bake_share(body.as_bytes(), &out, all, &env, |_, _, _| {}).unwrap();
    assert_eq!((again.computed, again.reused, again.rejected), (0, 1, 0));
    // Bad entries name their field.
    let bad = r#"{"cloud_lights": [{"example": "no-such-scene"}]}"#;
    let e = skybake_job::spec::JobSpec::parse_body(bad.as_bytes(), 10).unwrap_err();
    assert!(e.to_string().contains("cloud_lights[0].example"), "{e}");
    let bad = r#"{"cloud_lights": [{"example": "cumulus-frame", "scene": {}}]}"#;
    let e = skybake_job::spec::JobSpec::parse_body(bad.as_bytes(), 10).unwrap_err();
    assert!(e.to_string().contains("cloud_lights[0]"), "{e}");
}
