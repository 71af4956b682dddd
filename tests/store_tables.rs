//! Precise shared tables persisted between processes (issue 17 item 1): a second engine on the
//! same cache directory loads the table instead of building it and gets bit-identical products;
//! a corrupt table file is detected, never used, and rebuilt.

use skybake::engine::{DomeShape, Engine};
use skybake::spec::{CommonSpec, RequestParams};
use skybake::store::tables::CacheTableStore;
use skybake::store::{Cache, CacheConfig};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn spec(wavelengths: &str) -> CommonSpec {
    let p = RequestParams {
        sun_elevation_deg: Some("20".into()),
        wavelengths: Some(wavelengths.into()),
        method: Some("precise".into()),
        quality: Some("draft".into()),
        ..Default::default()
    };
    CommonSpec::from_params(&p, -18.0).unwrap()
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

#[test]
fn precise_tables_persist_across_engines_and_corrupt_ones_are_rebuilt() {
    let dir = std::env::temp_dir().join(format!("skybake-tables-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let s = spec("440,550");

    let first = Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir))));
    let built = first.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(first.build_count("precise"), 1);
    assert_eq!(first.table_loads(), (0, 0));
    assert_eq!(exr_files(&dir).len(), 1, "one table file");

    // A fresh engine on the same directory (what a second process sees) loads, builds nothing,
    // and produces the same radiance bit for bit, with the same convergence record.
    let second = Engine::with_table_store(Arc::new(CacheTableStore::new(open(&dir))));
    let loaded = second.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(second.build_count("precise"), 0);
    assert_eq!(second.table_loads(), (1, 0));
    assert_eq!(built.table.radiance, loaded.table.radiance);
    assert_eq!(
        built.meta.error_estimate.scattering_orders,
        loaded.meta.error_estimate.scattering_orders
    );
    assert!(loaded.meta.error_estimate.scattering_orders.unwrap() >= 2);

    // Other wavelengths are another table.
    second.sky(&spec("440,680"), SHAPE, &[]).unwrap();
    assert_eq!(second.build_count("precise"), 1);
    assert_eq!(exr_files(&dir).len(), 2);

    // Flip one byte in the middle of every table: the checksum catches it, the file is removed,
    // the table is rebuilt (and stored again) and the product is unchanged.
    for f in exr_files(&dir) {
        let mut bytes = std::fs::read(&f).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x5a;
        std::fs::write(&f, bytes).unwrap();
    }
    let cache = open(&dir);
    let third = Engine::with_table_store(Arc::new(CacheTableStore::new(cache.clone())));
    let rebuilt = third.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(third.build_count("precise"), 1);
    assert_eq!(third.table_loads().0, 0);
    assert!(cache.stats().corrupt_detected >= 1);
    assert_eq!(built.table.radiance, rebuilt.table.radiance);

    // Without a store nothing is read or written.
    let plain = Engine::new();
    let again = plain.sky(&s, SHAPE, &[]).unwrap();
    assert_eq!(plain.build_count("precise"), 1);
    assert_eq!(built.table.radiance, again.table.radiance);
    std::fs::remove_dir_all(&dir).unwrap();
}
