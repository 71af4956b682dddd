//! The cache, tiles and leases on a real S3-compatible server (`SKYBAKE_TEST_S3_ENDPOINT`;
//! skipped with a printed reason without one): a product stored by one cache is found by another
//! process's cache; corrupt, truncated and mis-keyed objects are detected, counted, deleted and
//! never served; a bucket that stops answering is `Unavailable` after the retries, and serves
//! again when it is back; leases exclude a second holder until they expire, and of contenders
//! racing for one lease exactly one holds it.

use std::sync::Arc;
use std::time::Duration;

use skybake_physics::image::layout::{ATTR_CACHE_KEY, ATTR_ENGINE_VERSION, ATTR_SPEC_JSON};
use skybake_store::cache::object_name;
use skybake_store::lease::{Acquired, Lease};
use skybake_store::tiles::ATTR_TILE_OF;
use skybake_store::{
    cache_key, encode_exr, Bucket, Cache, CacheConfig, RetryPolicy, SpectralImage, StoreError,
    TileStore,
};

use crate::service_support::s3;
use crate::service_support::Scratch;

fn key(seed: u32) -> String {
    cache_key(
        &format!(r#"{{"product":"sky","bucket-seed":{seed}}}"#),
        "test",
    )
}

/// A small image bound to `key(seed)`, its content depending on `seed`.
fn image(seed: u32) -> SpectralImage {
    let plane: Vec<f32> = (0..64u32).map(|i| (i * 7 + seed) as f32 * 0.25).collect();
    let mut image = SpectralImage::emissive(8, 8, &[550.0], vec![plane]).unwrap();
    image
        .set_attribute(ATTR_SPEC_JSON, format!(r#"{{"seed":{seed}}}"#))
        .unwrap();
    image.set_attribute(ATTR_ENGINE_VERSION, "test").unwrap();
    image.set_attribute(ATTR_CACHE_KEY, key(seed)).unwrap();
    image
}

fn shared_cache(dir: &Scratch, name: &str, bucket: &Arc<Bucket>) -> Cache {
    let config = CacheConfig::new(dir.path().join(name), 1 << 30, 1 << 20);
    Cache::open_shared(config, bucket.clone()).unwrap()
}

#[test]
fn a_product_stored_by_one_cache_is_served_by_another_from_the_bucket() {
    let Some(endpoint) = s3::endpoint("a_product_stored_by_one_cache_is_served_by_another") else {
        return;
    };
    let dir = Scratch::new("bucket-share");
    let url = s3::fresh_url("share");
    let (a_bucket, b_bucket) = (
        s3::open(&url, &endpoint, RetryPolicy::default()),
        s3::open(&url, &endpoint, RetryPolicy::default()),
    );
    let a = shared_cache(&dir, "a", &a_bucket);
    let b = shared_cache(&dir, "b", &b_bucket);
    assert_eq!(b.get(&key(1)).unwrap(), None);
    let stored = a.put_image(&key(1), &image(1)).unwrap();
    // Another process with its own directory: a miss on disk, a verified hit in the bucket.
    let got = b.get(&key(1)).unwrap().expect("served from the bucket");
    assert_eq!(&got[..], &stored[..]);
    assert_eq!(b.stats().bucket_hits, 1);
    // Now on b's disk and in its memory: the bucket is not asked again.
    let gets = b_bucket.stats().gets;
    assert!(b.get(&key(1)).unwrap().is_some());
    assert_eq!(b_bucket.stats().gets, gets);
    assert_eq!(b.stats().memory_hits, 1);
}

#[test]
fn corrupt_truncated_and_mis_keyed_objects_are_counted_deleted_and_never_served() {
    let Some(endpoint) = s3::endpoint("corrupt_truncated_and_mis_keyed_objects") else {
        return;
    };
    let dir = Scratch::new("bucket-corrupt");
    let bucket = s3::open(&s3::fresh_url("corrupt"), &endpoint, RetryPolicy::default());
    let writer = shared_cache(&dir, "writer", &bucket);
    for seed in [1, 2, 3] {
        writer.put_image(&key(seed), &image(seed)).unwrap();
    }
    // 1: a flipped byte in the pixel data; 2: the object cut in half; 3: a valid object of
    // another key (2's bytes) put under key 3.
    let mut flipped = bucket.get(&object_name(&key(1))).unwrap().unwrap();
    let n = flipped.len();
    flipped[n - 10] ^= 0x20;
    bucket.put(&object_name(&key(1)), &flipped).unwrap();
    let whole = bucket.get(&object_name(&key(2))).unwrap().unwrap();
    bucket
        .put(&object_name(&key(2)), &whole[..whole.len() / 2])
        .unwrap();
    bucket.put(&object_name(&key(3)), &whole).unwrap();

    let reader = shared_cache(&dir, "reader", &bucket);
    for seed in [1, 2, 3] {
        assert_eq!(reader.get(&key(seed)).unwrap(), None, "seed {seed} served");
        assert_eq!(
            bucket.get(&object_name(&key(seed))).unwrap(),
            None,
            "seed {seed} kept"
        );
    }
    let stats = reader.stats();
    assert_eq!((stats.corrupt_detected, stats.key_mismatches), (2, 1));
    assert_eq!((stats.hits, stats.misses), (0, 3));
    // Recomputed and stored again, the product is served.
    reader.put_image(&key(1), &image(1)).unwrap();
    let third = shared_cache(&dir, "third", &bucket);
    assert!(third.get(&key(1)).unwrap().is_some());
}

#[test]
fn a_bucket_that_stops_answering_is_unavailable_after_the_retries_then_serves_again() {
    let Some(endpoint) = s3::endpoint("a_bucket_that_stops_answering") else {
        return;
    };
    let dir = Scratch::new("bucket-fault");
    let proxy = s3::Proxy::start(&endpoint);
    let bucket = s3::open(
        &s3::fresh_url("fault"),
        &proxy.endpoint(),
        s3::quick_retry(),
    );
    let cache = shared_cache(&dir, "c", &bucket);
    cache.put_image(&key(1), &image(1)).unwrap();
    proxy.stop();
    // A miss on disk goes to the bucket, which refuses connections: every try fails.
    match cache.get(&key(2)) {
        Err(StoreError::Unavailable { retry_after_s, .. }) => assert!(retry_after_s >= 1),
        other => panic!("expected Unavailable, got {other:?}"),
    }
    assert!(matches!(
        cache.put_image(&key(3), &image(3)),
        Err(StoreError::Unavailable { .. })
    ));
    let stats = bucket.stats();
    assert_eq!(stats.failures, 2);
    assert_eq!(
        stats.retries,
        2 * 2,
        "3 tries each: 2 retries per operation"
    );
    // What is on the local disk is still served while the bucket is away.
    assert!(cache.get(&key(1)).unwrap().is_some());
    proxy.resume();
    assert_eq!(cache.get(&key(2)).unwrap(), None);
    let other = shared_cache(&dir, "other", &bucket);
    assert!(other.get(&key(1)).unwrap().is_some());
}

#[test]
fn tiles_in_a_bucket_are_verified_and_bound_to_their_place() {
    let Some(endpoint) = s3::endpoint("tiles_in_a_bucket_are_verified") else {
        return;
    };
    let bucket = s3::open(&s3::fresh_url("tiles"), &endpoint, RetryPolicy::default());
    let store = TileStore::in_bucket(bucket.clone(), "tiles");
    let tiles = store.frame(&key(9)).unwrap();
    let tile = |index: usize| {
        let mut img = SpectralImage::emissive(2, 2, &[550.0], vec![vec![index as f32; 4]]).unwrap();
        img.set_attribute(ATTR_TILE_OF, tiles.binding(index))
            .unwrap();
        encode_exr(&img).unwrap()
    };
    assert_eq!(tiles.get(0).unwrap(), None);
    tiles.put(0, &tile(0)).unwrap();
    assert_eq!(tiles.get(0).unwrap(), Some(tile(0)));
    // Tile 0's bytes at index 1 are refused (and removed); so is a damaged tile.
    tiles.put(1, &tile(0)).unwrap();
    assert_eq!(tiles.get(1).unwrap(), None);
    let mut bad = tile(2);
    let n = bad.len();
    bad[n - 3] ^= 1;
    tiles.put(2, &bad).unwrap();
    assert_eq!(tiles.get(2).unwrap(), None);
    assert_eq!(tiles.count(), 1);
    assert_eq!(store.prune(Duration::from_secs(3600)).unwrap(), 0);
    tiles.remove_all().unwrap();
    assert_eq!(tiles.count(), 0);
}

/// Contenders racing for the same lease at the same instant: exactly one holds it. This is the
/// server's conditional create (`If-None-Match: *`) being atomic with the write, as S3's is; a
/// server that checks and then writes in two steps lets two replicas compute the same product.
#[test]
fn contenders_racing_for_one_lease_leave_exactly_one_holder() {
    let Some(endpoint) = s3::endpoint("contenders_racing_for_one_lease") else {
        return;
    };
    let bucket = s3::open(
        &s3::fresh_url("lease-race"),
        &endpoint,
        RetryPolicy::default(),
    );
    const CONTENDERS: usize = 6;
    for round in 0..25 {
        let name = format!("leases/race-{round}");
        let start = std::sync::Barrier::new(CONTENDERS);
        let held = std::thread::scope(|scope| {
            let tries: Vec<_> = (0..CONTENDERS)
                .map(|i| {
                    let (bucket, name, start) = (&bucket, &name, &start);
                    scope.spawn(move || {
                        start.wait();
                        Lease::try_acquire(bucket, name, &format!("c{i}"), Duration::from_secs(30))
                            .unwrap()
                    })
                })
                .collect();
            // Joined before any lease is dropped, so a winner cannot release it for a later one.
            let outcomes: Vec<Acquired> = tries.into_iter().map(|t| t.join().unwrap()).collect();
            outcomes
                .iter()
                .filter(|o| matches!(o, Acquired::Held(_)))
                .count()
        });
        assert_eq!(
            held, 1,
            "round {round}: {held} of {CONTENDERS} contenders hold the lease"
        );
    }
}

#[test]
fn a_lease_excludes_other_holders_until_released_or_expired() {
    let Some(endpoint) = s3::endpoint("a_lease_excludes_other_holders") else {
        return;
    };
    let bucket = s3::open(&s3::fresh_url("lease"), &endpoint, RetryPolicy::default());
    let long = Duration::from_secs(30);
    let Acquired::Held(first) = Lease::try_acquire(&bucket, "leases/x", "a", long).unwrap() else {
        panic!("a fresh lease is free");
    };
    match Lease::try_acquire(&bucket, "leases/x", "b", long).unwrap() {
        Acquired::Busy { holder, expires_in } => {
            assert_eq!(holder, "a");
            assert!(expires_in <= long && expires_in > Duration::from_secs(20));
        }
        Acquired::Held(_) => panic!("two holders"),
    }
    drop(first);
    let Acquired::Held(second) = Lease::try_acquire(&bucket, "leases/x", "b", long).unwrap() else {
        panic!("a released lease is free");
    };
    drop(second);
    // A live holder renews its lease: still busy after twice its duration.
    let short = Duration::from_millis(900);
    let Acquired::Held(live) = Lease::try_acquire(&bucket, "leases/y", "c", short).unwrap() else {
        panic!("a fresh lease is free");
    };
    std::thread::sleep(short * 2);
    assert!(matches!(
        Lease::try_acquire(&bucket, "leases/y", "d", short).unwrap(),
        Acquired::Busy { .. }
    ));
    assert!(!live.lost());
    drop(live);
    // A lease its holder left behind when it died (the documented object, expired a second
    // ago) is taken over.
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64;
    let stale = format!(r#"{{"holder":"dead","expires_unix_ms":{}}}"#, now_ms - 1000);
    bucket.put("leases/z", stale.as_bytes()).unwrap();
    assert!(matches!(
        Lease::try_acquire(&bucket, "leases/z", "e", long).unwrap(),
        Acquired::Held(_)
    ));
}
