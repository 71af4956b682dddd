//! Precise shared tables persisted between processes: a second engine on the
//! same cache directory loads the table instead of building it and gets bit-identical products;
//! a corrupt table file is detected, never used, and rebuilt; the CLI, the server and `bake` all
//! load the table stored in the configured cache directory; `--no-table-cache` and requests that
//! need no precise table leave the directory alone.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use service_support::{settings, Scratch};
use skybake_engine::engine::{DomeShape, Engine, Table};
use skybake_engine::spec::CommonSpec;
use skybake_product::engines::engine_for_settings;
use skybake_product::params::{Defaults, RequestParams};
use skybake_store::tables::CacheTableStore;
use skybake_store::{Cache, CacheConfig};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use tower::ServiceExt;

fn spec(wavelengths: &str) -> CommonSpec {
    let pairs = [
        ("sun_elevation_deg", "20"),
        ("wavelengths", wavelengths),
        ("method", "precise"),
        ("quality", "draft"),
    ];
    let p = RequestParams::from_pairs(pairs.iter().copied()).unwrap();
    skybake_product::params::common_spec(&p, -18.0).unwrap()
}

const SHAPE: DomeShape = DomeShape {
    elevation_count: 9,
    azimuth_count: 4,
};

fn open(dir: &Path) -> Arc<Cache> {
    Arc::new(Cache::open(CacheConfig::new(dir, 1 << 30, 1 << 26)).unwrap())
}

fn exr_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for sub in std::fs::read_dir(dir).unwrap().flatten() {
        if sub.path().is_dir() {
            for f in std::fs::read_dir(sub.path()).unwrap().flatten() {
                if f.path().extension().is_some_and(|e| e == "exr") {
                    out.push(f.path());
                }
            }
        }
    }
    out
}

/// The stored tables of one kind: files carrying the precise table's (`skybakeSharedTable`) or
/// the density table's (`skybakeDensityTable`) description attribute.
fn table_files(dir: &Path, attribute: &str) -> Vec<PathBuf> {
    let needle = attribute.as_bytes();
    exr_files(dir)
        .into_iter()
        .filter(|f| {
            let bytes = std::fs::read(f).unwrap();
            bytes.windows(needle.len()).any(|w| w == needle)
        })
        .collect()
}

fn precise_files(dir: &Path) -> Vec<PathBuf> {
    table_files(dir, "skybakeSharedTable")
}

fn density_files(dir: &Path) -> Vec<PathBuf> {
    table_files(dir, "skybakeDensityTable")
}

#[test]
fn precise_tables_persist_across_engines_and_corrupt_ones_are_rebuilt() {
    let scratch = Scratch::new("tables");
    let dir = scratch.path();
    let s = spec("440,550");

    let first = Engine::with_table_store(Arc::new(CacheTableStore::new(open(dir))));
    let built = first.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(first.table_builds(Table::Precise), 1);
    assert_eq!(first.table_loads(), (0, 0));
    assert_eq!(precise_files(dir).len(), 1, "one precise table file");
    assert_eq!(density_files(dir).len(), 1, "one density table file");
    assert_eq!(exr_files(dir).len(), 2);

    // A fresh engine on the same directory (what a second process sees) loads, builds nothing,
    // and produces the same radiance bit for bit, with the same convergence record.
    let second = Engine::with_table_store(Arc::new(CacheTableStore::new(open(dir))));
    let loaded = second.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(second.table_builds(Table::Precise), 0);
    assert_eq!(second.table_loads(), (1, 0));
    assert_eq!(second.density_table_loads(), (1, 0));
    assert_eq!(second.table_builds(Table::Density), 0);
    assert_eq!(built.table.radiance, loaded.table.radiance);
    assert_eq!(
        built.meta.error_estimate.scattering_orders,
        loaded.meta.error_estimate.scattering_orders
    );
    assert!(loaded.meta.error_estimate.scattering_orders.unwrap() >= 2);

    // Other wavelengths are another precise table, and the same density table (it depends on
    // the atmosphere only).
    second.sky(&spec("440,680"), SHAPE, &[]).unwrap();
    assert_eq!(second.table_builds(Table::Precise), 1);
    assert_eq!(second.density_table_loads(), (2, 0));
    assert_eq!(precise_files(dir).len(), 2);
    assert_eq!(density_files(dir).len(), 1);

    // Flip one byte in the middle of every table: the checksum catches it, the file is removed,
    // the table is rebuilt (and stored again) and the product is unchanged.
    for f in exr_files(dir) {
        let mut bytes = std::fs::read(&f).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x5a;
        std::fs::write(&f, bytes).unwrap();
    }
    let cache = open(dir);
    let third = Engine::with_table_store(Arc::new(CacheTableStore::new(cache.clone())));
    let rebuilt = third.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(third.table_builds(Table::Precise), 1);
    assert_eq!(third.table_loads().0, 0);
    assert_eq!(third.density_table_loads().0, 0);
    assert_eq!(third.table_builds(Table::Density), 1);
    assert!(cache.stats().corrupt_detected >= 1);
    // Counted as refused tables (`skybake_engine_table_rejected_total`), not only as corrupt files.
    assert_eq!(third.table_loads().1, 1, "precise tables refused");
    assert_eq!(third.density_table_loads().1, 1, "density tables refused");
    assert_eq!(built.table.radiance, rebuilt.table.radiance);
    let on_disk: u64 = exr_files(dir)
        .iter()
        .map(|f| std::fs::metadata(f).unwrap().len())
        .sum();
    assert_eq!(
        cache.stats().bytes_on_disk,
        on_disk,
        "tables count in the budget"
    );

    // A disk budget of the density table and one and a half precise tables keeps one precise
    // table: the older one is evicted (the density table was used since).
    let small = scratch.path().join("small");
    let density_bytes = std::fs::metadata(&density_files(dir)[0]).unwrap().len();
    let budget = density_bytes + (on_disk - density_bytes) * 3 / 4;
    let cache = Arc::new(Cache::open(CacheConfig::new(&small, budget, 0)).unwrap());
    let tight = Engine::with_table_store(Arc::new(CacheTableStore::new(cache.clone())));
    tight.sky(&s, SHAPE, &[]).unwrap();
    tight.sky(&spec("440,680"), SHAPE, &[]).unwrap();
    assert_eq!(precise_files(&small).len(), 1);
    assert_eq!(density_files(&small).len(), 1);
    assert_eq!(cache.stats().evictions, 1);

    // Without a store nothing is read or written.
    let plain = Engine::new();
    let again = plain.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(plain.table_builds(Table::Precise), 1);
    assert_eq!(built.table.radiance, again.table.radiance);
}

/// A table whose settings hold a tolerance that is not a short decimal (the planner's "orders under
/// the budget" gives such values, e.g. 0.0019387852715243381 for the CLI's default sky) is loaded
/// by the next process: its JSON description round-trips every f64 exactly (serde_json's
/// `float_roundtrip`; without it this value came back one ulp off and every call rebuilt).
#[test]
fn a_table_with_an_unround_tolerance_is_loaded_not_rebuilt() {
    let scratch = Scratch::new("tables-tolerance");
    let dir = scratch.path();
    let s = spec("440,550");
    let tolerance = 0.001_938_785_271_524_338_1;
    let never = &|| false;
    let first = Engine::with_table_store(Arc::new(CacheTableStore::new(open(dir))));
    let built = first.shared_with(&s, Some(tolerance), never).unwrap();
    assert_eq!(built.precise_settings.tolerance, tolerance);
    built.precise();
    assert_eq!(first.table_builds(Table::Precise), 1);
    let second = Engine::with_table_store(Arc::new(CacheTableStore::new(open(dir))));
    second
        .shared_with(&s, Some(tolerance), never)
        .unwrap()
        .precise();
    assert_eq!(second.table_loads(), (1, 0), "loaded, not refused");
    assert_eq!(second.table_builds(Table::Precise), 0);
}

/// The precise request every path below makes (draft quality, two wavelengths, small table).
const PAIRS: [(&str, &str); 7] = [
    ("method", "precise"),
    ("quality", "draft"),
    ("wavelengths", "440,550"),
    ("sun_elevation_deg", "20"),
    ("elevation_count", "5"),
    ("azimuth_count", "3"),
    ("probe", "60:0"),
];

fn cli(args: &[&str], cache_dir: &Path) -> serde_json::Value {
    let mut all = vec!["sky".to_string()];
    for (k, v) in PAIRS {
        if args.contains(&format!("--{k}").as_str()) {
            continue;
        }
        all.push(format!("--{}", k.replace('_', "-")));
        all.push(v.to_string());
    }
    all.extend(args.iter().map(|a| a.to_string()));
    let out = Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(&all)
        .env("SKYBAKE_CACHE_DIR", cache_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The first `name` member anywhere in `v`.
fn find<'a>(v: &'a serde_json::Value, name: &str) -> Option<&'a serde_json::Value> {
    match v {
        serde_json::Value::Object(m) => m
            .get(name)
            .or_else(|| m.values().find_map(|x| find(x, name))),
        serde_json::Value::Array(a) => a.iter().find_map(|x| find(x, name)),
        _ => None,
    }
}

fn orders(v: &serde_json::Value) -> u64 {
    find(v, "scattering_orders").unwrap().as_u64().unwrap()
}

/// Marks the one stored table: its convergence record now says `MARK` orders (the checksum and
/// key are rewritten through the store, so the file is valid). Whoever reports `MARK` orders has
/// loaded this file instead of building the table.
const MARK: u64 = 99;

fn mark_stored_table(cache_dir: &Path) {
    let files = precise_files(cache_dir);
    assert_eq!(files.len(), 1, "one stored table");
    let key = files[0].file_stem().unwrap().to_str().unwrap().to_string();
    let cache = open(cache_dir);
    let mut image = cache.get_image(&key).unwrap().unwrap();
    let mut meta: serde_json::Value =
        serde_json::from_str(image.attribute("skybakeSharedTable").unwrap()).unwrap();
    meta["convergence"]["orders"] = MARK.into();
    image
        .set_attribute("skybakeSharedTable", meta.to_string())
        .unwrap();
    use skybake_physics::atmosphere::shared::TableStore;
    CacheTableStore::new(cache).save(&key, &image);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cli_server_and_bake_share_the_stored_table() {
    let scratch = Scratch::new("tables-shared");
    let cache_dir = scratch.path().join("cache");

    // A request that needs no precise table does not even create the directory.
    let none = cli(&["--method", "none"], &cache_dir);
    assert!(find(&none, "scattering_orders").is_none());
    assert!(!cache_dir.exists(), "method none touched the table cache");

    // First CLI call: builds and stores the table.
    let built = cli(&[], &cache_dir);
    assert!(orders(&built) >= 2);
    mark_stored_table(&cache_dir);

    // Second CLI call: loads it.
    let loaded = cli(&[], &cache_dir);
    assert_eq!(orders(&loaded), MARK);
    assert_eq!(find(&loaded, "probes"), find(&built, "probes"));

    // --no-table-cache: builds in-process and leaves the directory alone.
    let untouched = scratch.path().join("untouched");
    let own = cli(&["--no-table-cache"], &untouched);
    assert_eq!(orders(&own), orders(&built));
    assert!(!untouched.exists());

    // The server on the same directory loads it, and says so in /metrics.
    let state = skybake_service::AppState::new(settings(&cache_dir)).unwrap();
    let query: Vec<String> = PAIRS.iter().map(|(k, v)| format!("{k}={v}")).collect();
    let get = |uri: String| {
        let app = skybake_service::app(state.clone());
        async move {
            let req = Request::builder().uri(uri).body(Body::empty()).unwrap();
            let resp = app.oneshot(req).await.unwrap();
            assert_eq!(resp.status(), 200);
            axum::body::to_bytes(resp.into_body(), 1 << 26)
                .await
                .unwrap()
        }
    };
    let body = get(format!("/v1/sky?{}", query.join("&"))).await;
    let served: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(orders(&served), MARK);
    assert_eq!(state.engine().table_loads(), (1, 0));
    assert_eq!(state.engine().table_builds(Table::Precise), 0);
    let metrics = String::from_utf8(get("/metrics".into()).await.to_vec()).unwrap();
    assert!(
        metrics.contains("skybake_engine_table_loads_total{table=\"precise\"} 1"),
        "{metrics}"
    );
    assert!(metrics.contains("skybake_engine_table_builds_total{table=\"precise\"} 0"));

    // A bake on the same settings loads it too.
    let item: serde_json::Map<String, serde_json::Value> = PAIRS
        .iter()
        .filter(|(k, _)| *k != "probe")
        .map(|(k, v)| (k.to_string(), serde_json::Value::from(*v)))
        .chain([("product".to_string(), "sky".into())])
        .collect();
    let job = serde_json::json!({ "products": [item] });
    let engine = engine_for_settings(&settings(&cache_dir));
    let summary = skybake_job::bake::bake(
        job.to_string().as_bytes(),
        &scratch.path().join("baked"),
        &Defaults::default(),
        10,
        &engine,
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!(summary.computed, 1);
    assert_eq!(engine.table_loads(), (1, 0));
    assert_eq!(engine.table_builds(Table::Precise), 0);
}

/// A verified table file that was made for another medium (here: another wavelength list, stored
/// under this medium's key) is refused by the engine, counted, and rebuilt; it is never used.
#[test]
fn a_stored_table_for_another_medium_is_refused_and_rebuilt() {
    let scratch = Scratch::new("tables-mismatch");
    let (dir_a, dir_b) = (scratch.path().join("a"), scratch.path().join("b"));
    let (a, b) = (spec("440,550"), spec("440,680"));
    Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir_a))))
        .sky(&a, SHAPE, &[])
        .unwrap();
    let built_b = Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir_b))))
        .sky(&b, SHAPE, &[])
        .unwrap();
    let key_of = |dir: &Path| -> String {
        let files = precise_files(dir);
        assert_eq!(files.len(), 1);
        files[0].file_stem().unwrap().to_str().unwrap().to_string()
    };
    let (key_a, key_b) = (key_of(&dir_a), key_of(&dir_b));
    assert_ne!(key_a, key_b);

    // Table A, re-bound to B's key (valid checksum and key attribute), replaces B's table.
    let cache_b = open(&dir_b);
    let table_a = open(&dir_a).get_image(&key_a).unwrap().unwrap();
    use skybake_physics::atmosphere::shared::TableStore;
    CacheTableStore::new(cache_b.clone()).save(&key_b, &table_a);

    let engine = Engine::with_table_store(Arc::new(CacheTableStore::new(cache_b)));
    let rebuilt = engine.sky(&b, SHAPE, &[]).unwrap();
    assert_eq!(engine.table_loads(), (0, 1));
    assert_eq!(engine.table_builds(Table::Precise), 1);
    assert_eq!(rebuilt.table.radiance, built_b.table.radiance);
}

/// The density-integral table is stored once per set of density profiles and loaded by the next
/// engine (bit for bit the same products); a stored density table made for other density profiles
/// (a valid file, re-bound to this atmosphere's key) or a corrupt one is refused, counted and
/// rebuilt.
#[test]
fn density_tables_persist_and_foreign_or_corrupt_ones_are_rebuilt() {
    let scratch = Scratch::new("tables-density");
    let (dir_a, dir_b) = (scratch.path().join("a"), scratch.path().join("b"));
    let earth = spec("440,550");
    let p = RequestParams::from_pairs(
        [
            ("sun_elevation_deg", "20"),
            ("wavelengths", "440,550"),
            ("method", "precise"),
            ("quality", "draft"),
            ("atmosphere", "rayleigh-only"),
        ]
        .iter()
        .copied(),
    )
    .unwrap();
    let other = skybake_product::params::common_spec(&p, -18.0).unwrap();
    let built = Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir_a))))
        .sky(&earth, SHAPE, &[])
        .unwrap();
    Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir_b))))
        .sky(&other, SHAPE, &[])
        .unwrap();
    let key_of = |dir: &Path| -> String {
        let files = density_files(dir);
        assert_eq!(files.len(), 1);
        files[0].file_stem().unwrap().to_str().unwrap().to_string()
    };
    let (key_a, key_b) = (key_of(&dir_a), key_of(&dir_b));
    assert_ne!(key_a, key_b, "one density table per set of profiles");

    // Loaded by a second engine: same radiance bit for bit, nothing built.
    let engine = Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir_a))));
    let loaded = engine.sky(&earth, SHAPE, &[]).unwrap();
    assert_eq!(engine.density_table_loads(), (1, 0));
    assert_eq!(engine.table_builds(Table::Density), 0);
    assert_eq!(loaded.table.radiance, built.table.radiance);

    // Rayleigh-only's density table (other profiles) under earth's key: refused, rebuilt,
    // never used.
    let cache_a = open(&dir_a);
    let other_table = open(&dir_b).get_image(&key_b).unwrap().unwrap();
    use skybake_physics::atmosphere::shared::TableStore;
    CacheTableStore::new(cache_a.clone()).save(&key_a, &other_table);
    let engine = Engine::with_table_store(Arc::new(CacheTableStore::new(cache_a)));
    let rebuilt = engine.sky(&earth, SHAPE, &[]).unwrap();
    assert_eq!(engine.density_table_loads(), (0, 1));
    assert_eq!(engine.table_builds(Table::Density), 1);
    assert_eq!(rebuilt.table.radiance, built.table.radiance);

    // A flipped byte in the stored density table: the checksum refuses the file; rebuilt.
    let f = &density_files(&dir_a)[0];
    let mut bytes = std::fs::read(f).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x01;
    std::fs::write(f, bytes).unwrap();
    let cache = open(&dir_a);
    let engine = Engine::with_table_store(Arc::new(CacheTableStore::new(cache.clone())));
    let again = engine.sky(&earth, SHAPE, &[]).unwrap();
    assert_eq!(engine.density_table_loads().0, 0);
    assert_eq!(engine.table_builds(Table::Density), 1);
    assert!(cache.stats().corrupt_detected >= 1);
    assert_eq!(
        engine.density_table_loads().1,
        1,
        "the corrupt table counts as refused"
    );
    assert_eq!(again.table.radiance, built.table.radiance);
}
