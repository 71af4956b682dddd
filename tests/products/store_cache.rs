//! The content-addressed cache: hits and misses, integrity, LRU eviction under a byte budget,
//! reuse after a restart, key validation, and concurrent use.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use skybake_physics::image::layout::{ATTR_CACHE_KEY, ATTR_ENGINE_VERSION, ATTR_SPEC_JSON};
use skybake_store::{cache_key, Cache, CacheConfig, SpectralImage, StoreError};

static SCRATCH_COUNTER: AtomicUsize = AtomicUsize::new(0);

/// A scratch directory removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "skybake-cache-{name}-{}-{}",
            std::process::id(),
            SCRATCH_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = fs::remove_dir_all(&dir);
        Scratch(dir)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

/// A small radiance image whose content depends on `seed`; 16x16 x 2 wavelengths, carrying
/// its cache key `key(seed)` as every cached product does.
fn image(seed: u32) -> SpectralImage {
    let mut image = unbound_image(seed);
    image.set_attribute(ATTR_CACHE_KEY, key(seed)).unwrap();
    image
}

/// [`image`] without the cache key attribute.
fn unbound_image(seed: u32) -> SpectralImage {
    let plane = |k: u32| -> Vec<f32> {
        (0..256u32)
            .map(|i| {
                ((i.wrapping_mul(2_654_435_761) ^ seed.wrapping_mul(97) ^ k) % 10_007) as f32 * 0.01
            })
            .collect()
    };
    let mut image =
        SpectralImage::emissive(16, 16, &[450.0, 650.0], vec![plane(1), plane(2)]).unwrap();
    let spec = format!(r#"{{"product":"sky","seed":{seed}}}"#);
    image.set_attribute(ATTR_SPEC_JSON, spec).unwrap();
    image.set_attribute(ATTR_ENGINE_VERSION, "test").unwrap();
    image
}

fn key(seed: u32) -> String {
    cache_key(&format!(r#"{{"product":"sky","seed":{seed}}}"#), "test")
}

/// All `.exr` files under the cache directory.
fn cache_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for shard in fs::read_dir(dir).unwrap() {
        let shard = shard.unwrap().path();
        if shard.is_dir() {
            for file in fs::read_dir(&shard).unwrap() {
                files.push(file.unwrap().path());
            }
        }
    }
    files.sort();
    files
}

fn disk_only(dir: &Path, disk_budget_bytes: u64) -> Cache {
    Cache::open(CacheConfig::new(dir, disk_budget_bytes, 0)).unwrap()
}

#[test]
fn put_then_get_hits_memory_then_disk_after_restart() {
    let scratch = Scratch::new("restart");
    let (k, img) = (key(1), image(1));
    let bytes = {
        let cache = Cache::open(CacheConfig::new(&scratch.0, 1 << 20, 1 << 20)).unwrap();
        assert_eq!(cache.get(&k).unwrap(), None);
        let bytes = cache.put_image(&k, &img).unwrap();
        assert_eq!(cache.get(&k).unwrap().as_deref(), Some(&bytes[..]));
        let stats = cache.stats();
        assert_eq!(
            (stats.hits, stats.memory_hits, stats.misses, stats.puts),
            (1, 1, 1, 1)
        );
        assert_eq!(stats.bytes_on_disk, bytes.len() as u64);
        assert_eq!(stats.entries_on_disk, 1);
        bytes
    };
    // The file sits at <dir>/<first 2 hex>/<key>.exr.
    assert_eq!(
        cache_files(&scratch.0),
        vec![scratch.0.join(&k[..2]).join(format!("{k}.exr"))]
    );

    // A new cache over the same directory sees the entry, verifies it and serves it from disk.
    let cache = Cache::open(CacheConfig::new(&scratch.0, 1 << 20, 1 << 20)).unwrap();
    assert_eq!(cache.stats().entries_on_disk, 1);
    assert!(cache.contains(&k));
    assert_eq!(cache.get(&k).unwrap().as_deref(), Some(&bytes[..]));
    assert_eq!(cache.get_image(&k).unwrap(), Some(img));
    let stats = cache.stats();
    assert_eq!((stats.hits, stats.disk_hits, stats.memory_hits), (2, 1, 1));
}

#[test]
fn flipped_byte_is_detected_removed_and_a_miss() {
    let scratch = Scratch::new("flip");
    let cache = disk_only(&scratch.0, 1 << 20);
    let k = key(2);
    cache.put_image(&k, &image(2)).unwrap();
    let path = cache.path_for(&k).unwrap();
    let mut bytes = fs::read(&path).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    fs::write(&path, &bytes).unwrap();

    assert_eq!(cache.get(&k).unwrap(), None);
    assert!(!path.exists(), "corrupt file must be deleted");
    let stats = cache.stats();
    assert_eq!(
        (stats.corrupt_detected, stats.misses, stats.hits),
        (1, 1, 0)
    );
    assert_eq!((stats.entries_on_disk, stats.bytes_on_disk), (0, 0));
    // Recompute-and-store works afterwards.
    cache.put_image(&k, &image(2)).unwrap();
    assert!(cache.get(&k).unwrap().is_some());
}

#[test]
fn truncated_file_is_detected_after_restart() {
    let scratch = Scratch::new("truncate");
    let k = key(3);
    let path = {
        let cache = disk_only(&scratch.0, 1 << 20);
        cache.put_image(&k, &image(3)).unwrap();
        cache.path_for(&k).unwrap()
    };
    let bytes = fs::read(&path).unwrap();
    fs::write(&path, &bytes[..bytes.len() - 100]).unwrap();

    let cache = disk_only(&scratch.0, 1 << 20);
    assert!(cache.contains(&k));
    assert_eq!(cache.get_image(&k).unwrap(), None);
    assert!(!path.exists());
    assert!(!cache.contains(&k));
    assert_eq!(cache.stats().corrupt_detected, 1);
}

#[test]
fn file_deleted_behind_the_cache_is_a_plain_miss() {
    let scratch = Scratch::new("vanished");
    let cache = disk_only(&scratch.0, 1 << 20);
    let k = key(4);
    cache.put_image(&k, &image(4)).unwrap();
    fs::remove_file(cache.path_for(&k).unwrap()).unwrap();
    assert_eq!(cache.get(&k).unwrap(), None);
    let stats = cache.stats();
    assert_eq!(
        (stats.misses, stats.corrupt_detected, stats.entries_on_disk),
        (1, 0, 0)
    );
}

#[test]
fn eviction_keeps_the_most_recently_used() {
    let scratch = Scratch::new("evict");
    let sizes: Vec<u64> = (10..13).map(|s| cache_key_size(&image(s))).collect();
    let largest = *sizes.iter().max().unwrap();
    // Room for two entries, not three.
    let cache = disk_only(&scratch.0, 2 * largest + largest / 2);
    cache.put_image(&key(10), &image(10)).unwrap();
    cache.put_image(&key(11), &image(11)).unwrap();
    assert!(cache.get(&key(10)).unwrap().is_some()); // 10 is now more recent than 11
    cache.put_image(&key(12), &image(12)).unwrap();

    assert!(cache.get(&key(10)).unwrap().is_some());
    assert!(cache.get(&key(12)).unwrap().is_some());
    assert_eq!(cache.get(&key(11)).unwrap(), None);
    assert!(!cache.path_for(&key(11)).unwrap().exists());
    let stats = cache.stats();
    assert_eq!(stats.evictions, 1);
    assert!(stats.bytes_on_disk <= cache.config().disk_budget_bytes);
    assert_eq!(cache_files(&scratch.0).len(), 2);
}

/// Size of the encoded file for `image`.
fn cache_key_size(image: &SpectralImage) -> u64 {
    skybake_store::encode_exr(image).unwrap().len() as u64
}

#[test]
fn access_order_survives_a_restart_through_mtimes() {
    let scratch = Scratch::new("restart-lru");
    let largest = (20..23).map(|s| cache_key_size(&image(s))).max().unwrap();
    let budget = 2 * largest + largest / 2;
    {
        let cache = disk_only(&scratch.0, budget);
        cache.put_image(&key(20), &image(20)).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        cache.put_image(&key(21), &image(21)).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        // A disk hit refreshes the mtime: 20 becomes the most recent.
        assert!(cache.get(&key(20)).unwrap().is_some());
    }
    let cache = disk_only(&scratch.0, budget);
    cache.put_image(&key(22), &image(22)).unwrap();
    assert!(cache.contains(&key(20)));
    assert!(cache.contains(&key(22)));
    assert!(!cache.contains(&key(21)));
}

#[test]
fn opening_with_a_smaller_budget_evicts_and_cleans_temp_files() {
    let scratch = Scratch::new("shrink");
    {
        let cache = disk_only(&scratch.0, 1 << 20);
        for seed in 30..34 {
            cache.put_image(&key(seed), &image(seed)).unwrap();
        }
    }
    let k = key(30);
    let stray = scratch
        .0
        .join(&k[..2])
        .join(format!(".{k}.exr.skybake-tmp.1.1"));
    fs::write(&stray, b"half-written").unwrap();
    let unrelated = scratch.0.join("README");
    fs::write(&unrelated, b"not ours").unwrap();

    let one = cache_key_size(&image(33)) + 10;
    let cache = disk_only(&scratch.0, one);
    let stats = cache.stats();
    assert_eq!(stats.entries_on_disk, 1);
    assert!(stats.bytes_on_disk <= one);
    assert!(cache.contains(&key(33)), "the newest file survives");
    assert!(!stray.exists(), "temp file from a crash is removed");
    assert!(
        unrelated.exists(),
        "files the cache did not write are left alone"
    );
}

#[test]
fn memory_tier_respects_its_budget() {
    let scratch = Scratch::new("memory");
    let size = cache_key_size(&image(50));
    // Room for eight entries of this size (each within the per-entry ceiling, budget / 8).
    let budget = 8 * size + size / 2;
    let cache = Cache::open(CacheConfig::new(&scratch.0, 1 << 20, budget)).unwrap();
    for s in 50..59 {
        cache.put_image(&key(s), &image(s)).unwrap();
    }
    let stats = cache.stats();
    assert_eq!(stats.entries_in_memory, 8);
    assert!(stats.bytes_in_memory <= budget);
    assert!(stats.memory_evictions >= 1);
    // All are still served: the newest from memory, the oldest from disk.
    assert!(cache.get(&key(58)).unwrap().is_some());
    assert!(cache.get(&key(50)).unwrap().is_some());
    let stats = cache.stats();
    assert_eq!((stats.memory_hits, stats.disk_hits), (1, 1));
}

#[test]
fn one_large_entry_does_not_flush_the_memory_tier() {
    let scratch = Scratch::new("memory-ceiling");
    let size = cache_key_size(&image(60));
    // Eight small entries fill the memory tier; a product over budget / 8 is kept on disk only.
    let budget = 8 * size + size / 2;
    let cache = Cache::open(CacheConfig::new(&scratch.0, 1 << 24, budget)).unwrap();
    for s in 60..68 {
        cache.put_image(&key(s), &image(s)).unwrap();
    }
    // 128² × 2 planes of scattered values (they do not compress away).
    let plane = |k: u32| -> Vec<f32> {
        (0..128 * 128u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) ^ k) as f32 * 1e-6)
            .collect()
    };
    let mut big =
        SpectralImage::emissive(128, 128, &[450.0, 650.0], vec![plane(1), plane(2)]).unwrap();
    big.set_attribute(ATTR_CACHE_KEY, key(99)).unwrap();
    assert!(cache_key_size(&big) > budget / 8);
    cache.put_image(&key(99), &big).unwrap();
    let stats = cache.stats();
    assert_eq!(stats.entries_in_memory, 8, "{stats:?}");
    assert_eq!(stats.memory_evictions, 0, "{stats:?}");
    assert!(cache.get(&key(99)).unwrap().is_some());
    assert_eq!(cache.stats().disk_hits, 1);
}

#[test]
fn keys_that_are_not_hex_are_refused_and_write_nothing() {
    let scratch = Scratch::new("keys");
    let cache = Cache::open(CacheConfig::new(&scratch.0, 1 << 20, 1 << 20)).unwrap();
    let escape = format!("../../{}", "a".repeat(58));
    let bad_keys = [
        escape.as_str(),
        "../etc/passwd",
        "",
        &"A".repeat(64),
        &"z".repeat(64),
        &"a".repeat(63),
        &format!("{}/", "a".repeat(63)),
        &format!("{}\0", "a".repeat(63)),
    ];
    for bad in bad_keys {
        let invalid = |r: Result<(), StoreError>| matches!(r, Err(StoreError::Invalid(ref e)) if e.field() == "cache_key");
        assert!(invalid(cache.get(bad).map(drop)), "{bad:?}");
        assert!(
            invalid(cache.put_image(bad, &image(1)).map(drop)),
            "{bad:?}"
        );
        assert!(
            invalid(cache.put_bytes(bad, vec![1, 2, 3]).map(drop)),
            "{bad:?}"
        );
        assert!(invalid(cache.remove(bad).map(drop)), "{bad:?}");
        assert!(invalid(cache.path_for(bad).map(drop)), "{bad:?}");
        assert!(!cache.contains(bad));
    }
    assert!(cache_files(&scratch.0).is_empty());
    assert!(!scratch.0.parent().unwrap().join("etc").exists());
}

#[test]
fn put_bytes_accepts_only_verified_files() {
    let scratch = Scratch::new("put-bytes");
    let cache = disk_only(&scratch.0, 1 << 20);
    let unbound = skybake_store::encode_exr(&unbound_image(60)).unwrap();
    assert!(matches!(
        cache.put_bytes(&key(60), unbound),
        Err(StoreError::Invalid(_))
    ));
    let good = skybake_store::encode_exr(&image(60)).unwrap();
    assert!(matches!(
        cache.put_bytes(&key(61), good.clone()),
        Err(StoreError::Invalid(_))
    ));
    let mut bad = good.clone();
    let middle = bad.len() / 2;
    bad[middle] ^= 1;
    assert!(matches!(
        cache.put_bytes(&key(60), bad),
        Err(StoreError::Corrupt(_))
    ));
    assert!(!cache.contains(&key(60)));
    cache.put_bytes(&key(60), good.clone()).unwrap();
    assert_eq!(cache.get(&key(60)).unwrap().as_deref(), Some(&good[..]));
    assert!(cache.remove(&key(60)).unwrap());
    assert!(!cache.remove(&key(60)).unwrap());
    assert_eq!(cache.stats().entries_on_disk, 0);
}

#[test]
fn concurrent_gets_and_puts_stay_consistent() {
    let scratch = Scratch::new("concurrent");
    let seeds: Vec<u32> = (70..82).collect();
    let images: Arc<Vec<SpectralImage>> = Arc::new(seeds.iter().map(|&s| image(s)).collect());
    let largest = images.iter().map(cache_key_size).max().unwrap();
    // Room for about four of the twelve entries on disk and eight in memory (each within the
    // memory tier's per-entry ceiling): eviction races with reads.
    let cache =
        Arc::new(Cache::open(CacheConfig::new(&scratch.0, 4 * largest, 8 * largest)).unwrap());
    let gets = Arc::new(AtomicUsize::new(0));

    let threads: Vec<_> = (0..8u32)
        .map(|t| {
            let (cache, images, gets) =
                (Arc::clone(&cache), Arc::clone(&images), Arc::clone(&gets));
            let seeds = seeds.clone();
            std::thread::spawn(move || {
                for step in 0..60u32 {
                    let i = ((t * 7 + step * 5) % seeds.len() as u32) as usize;
                    let k = key(seeds[i]);
                    if (t + step) % 3 == 0 {
                        cache.put_image(&k, &images[i]).unwrap();
                    } else {
                        gets.fetch_add(1, Ordering::Relaxed);
                        if let Some(found) = cache.get_image(&k).unwrap() {
                            // Whatever is served is exactly what was stored under that key.
                            assert_eq!(found, images[i]);
                        }
                    }
                }
            })
        })
        .collect();
    for thread in threads {
        thread.join().unwrap();
    }

    let stats = cache.stats();
    assert_eq!(
        stats.hits + stats.misses,
        gets.load(Ordering::Relaxed) as u64
    );
    assert_eq!(stats.corrupt_detected, 0);
    assert!(stats.bytes_on_disk <= 4 * largest);
    assert!(stats.bytes_in_memory <= 8 * largest);
    // The index agrees with the directory.
    let files = cache_files(&scratch.0);
    assert_eq!(files.len() as u64, stats.entries_on_disk);
    let on_disk: u64 = files.iter().map(|f| fs::metadata(f).unwrap().len()).sum();
    assert_eq!(on_disk, stats.bytes_on_disk);
}

#[test]
fn cache_can_be_shared_across_threads_and_tasks() {
    fn assert_send_sync<T: Send + Sync + 'static>() {}
    assert_send_sync::<Cache>();
    assert_send_sync::<Arc<[u8]>>();
    assert_send_sync::<SpectralImage>();
    assert_send_sync::<StoreError>();
}

#[test]
fn a_file_under_another_keys_name_is_a_miss_and_counted() {
    let scratch = Scratch::new("foreign-key");
    {
        let cache = disk_only(&scratch.0, 1 << 20);
        cache.put_image(&key(23), &image(23)).unwrap();
        cache.put_image(&key(24), &image(24)).unwrap();
    }
    // Copy the valid file of key 23 over the one of key 24, then restart.
    let path = |k: &str| scratch.0.join(&k[..2]).join(format!("{k}.exr"));
    fs::copy(path(&key(23)), path(&key(24))).unwrap();
    let cache = disk_only(&scratch.0, 1 << 20);
    assert!(cache.get(&key(24)).unwrap().is_none());
    let stats = cache.stats();
    assert_eq!(stats.key_mismatches, 1);
    assert_eq!(stats.corrupt_detected, 0);
    assert!(!path(&key(24)).exists(), "the foreign file is removed");
    assert!(
        cache.get(&key(23)).unwrap().is_some(),
        "the original still hits"
    );
    // An image that carries another key is refused at put.
    let mut other = image(25);
    other.set_attribute(ATTR_CACHE_KEY, key(26)).unwrap();
    assert!(matches!(
        cache.put_image(&key(25), &other),
        Err(StoreError::Invalid(_))
    ));
}

#[test]
fn a_directory_at_an_entry_path_is_cleared_not_a_permanent_error() {
    let scratch = Scratch::new("dir-at-path");
    let cache = disk_only(&scratch.0, 1 << 20);
    let k = key(70);
    let path = scratch.0.join(&k[..2]).join(format!("{k}.exr"));
    // Before the first put: a directory (with content) where the file goes.
    fs::create_dir_all(path.join("inner")).unwrap();
    cache.put_image(&k, &image(70)).unwrap();
    assert!(path.is_file());
    assert!(cache.get(&k).unwrap().is_some());
    // After a put: the file replaced by a directory is a miss, and the next put stores again.
    let cache = disk_only(&scratch.0, 1 << 20);
    fs::remove_file(&path).unwrap();
    fs::create_dir_all(path.join("inner")).unwrap();
    assert!(cache.get(&k).unwrap().is_none());
    cache.put_image(&k, &image(70)).unwrap();
    assert!(cache.get(&k).unwrap().is_some());
}

#[test]
fn a_product_larger_than_the_disk_budget_is_returned_but_not_stored() {
    let scratch = Scratch::new("oversize");
    let small = skybake_store::encode_exr(&image(80)).unwrap().len() as u64;
    let cache = disk_only(&scratch.0, small + small / 2);
    cache.put_image(&key(80), &image(80)).unwrap();
    let big = {
        let plane: Vec<f32> = (0..64 * 64u32)
            .map(|i| i.wrapping_mul(2_654_435_761) as f32 * 1e-3)
            .collect();
        SpectralImage::emissive(64, 64, &[450.0, 650.0], vec![plane.clone(), plane]).unwrap()
    };
    let bytes = cache.put_image(&key(81), &big).unwrap();
    assert!(bytes.len() as u64 > small + small / 2);
    assert!(!cache.contains(&key(81)));
    let stats = cache.stats();
    assert_eq!(stats.not_stored, 1);
    assert_eq!(stats.evictions, 0, "the oversized product evicts nothing");
    assert!(cache.get(&key(80)).unwrap().is_some());
}
