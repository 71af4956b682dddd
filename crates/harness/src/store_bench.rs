//! Throughput figures for the storage layer, for `skybake-harness bench store` (not asserted in tests).

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use skybake_store::{
    cache_key, checksum, decode_exr, encode_exr_with, Cache, CacheConfig, ExrCompression,
    SpectralImage,
};
use skybake_store::{Bucket, StoreError};

/// Median timings of the storage operations on one synthetic sky-like image.
#[derive(Debug, Clone, Serialize)]
pub struct StoreBench {
    pub width: usize,
    pub height: usize,
    pub wavelengths: usize,
    pub compression: ExrCompression,
    /// Raw f32 payload (spectral + RGB planes).
    pub payload_bytes: u64,
    /// Encoded file size.
    pub file_bytes: u64,
    pub encode_ms: f64,
    pub decode_ms: f64,
    /// Checksum verification alone (what a disk hit costs besides the read).
    pub verify_ms: f64,
    /// `Cache::put_image`: encode + atomic durable write.
    pub cache_put_ms: f64,
    /// `Cache::get` from disk: read + verify.
    pub cache_disk_get_ms: f64,
    /// `Cache::get` from the memory tier.
    pub cache_memory_get_ms: f64,
    /// With a bucket: `Cache::put_image` on a cache shared through it (encode, disk write, PUT).
    pub bucket_put_ms: Option<f64>,
    /// With a bucket: `Cache::get` on a shared cache whose disk misses (GET, verify, local copy).
    pub bucket_get_ms: Option<f64>,
    pub repetitions: usize,
}

/// Times encode, decode, verify and cache put/get on a `width × height` image with
/// `wavelength_count` wavelengths plus RGB with `compression`, `repetitions` times each (median
/// reported). Uses a scratch directory under `dir`, removed afterwards.
pub fn bench_store(
    dir: &Path,
    width: usize,
    height: usize,
    wavelength_count: usize,
    compression: ExrCompression,
    repetitions: usize,
    bucket: Option<&Arc<Bucket>>,
) -> Result<StoreBench, StoreError> {
    let repetitions = repetitions.max(1);
    let image = sky_like_image(width, height, wavelength_count)?;
    let payload_bytes = (image.plane_count() * image.pixel_count() * 4) as u64;

    let mut bytes = Vec::new();
    let encode_ms = median_ms(repetitions, || {
        bytes = encode_exr_with(&image, compression)?;
        Ok(())
    })?;
    let decode_ms = median_ms(repetitions, || decode_exr(&bytes).map(drop))?;
    let verify_ms = median_ms(repetitions, || checksum::verify(&bytes))?;

    let scratch = dir.join(format!("skybake-bench-{}", std::process::id()));
    let result = (|| {
        let config = CacheConfig {
            compression,
            ..CacheConfig::new(&scratch, u64::MAX, 0)
        };
        let disk_only = Cache::open(config)?;
        let key = cache_key("bench", "bench");
        let cache_put_ms = median_ms(repetitions, || disk_only.put_image(&key, &image).map(drop))?;
        let cache_disk_get_ms = median_ms(repetitions, || disk_only.get(&key).map(drop))?;
        let in_memory = Cache::open(CacheConfig::new(&scratch, u64::MAX, u64::MAX))?;
        in_memory.get(&key)?;
        let cache_memory_get_ms = median_ms(repetitions, || in_memory.get(&key).map(drop))?;
        let (mut bucket_put_ms, mut bucket_get_ms) = (None, None);
        if let Some(bucket) = bucket {
            let shared = |name: &str| {
                let config = CacheConfig {
                    compression,
                    ..CacheConfig::new(scratch.join(name), u64::MAX, 0)
                };
                Cache::open_shared(config, bucket.clone())
            };
            let writer = shared("writer")?;
            bucket_put_ms = Some(median_ms(repetitions, || {
                writer.put_image(&key, &image).map(drop)
            })?);
            // A cache of its own each time, so the disk tier misses and the bucket answers.
            let mut times = Vec::with_capacity(repetitions);
            for n in 0..repetitions {
                let reader = shared(&format!("reader-{n}"))?;
                let start = Instant::now();
                let found = reader.get(&key)?;
                times.push(start.elapsed().as_secs_f64() * 1e3);
                if found.is_none() {
                    return Err(StoreError::Corrupt(
                        "the bench entry is not in the bucket".into(),
                    ));
                }
            }
            times.sort_by(f64::total_cmp);
            bucket_get_ms = Some(times[times.len() / 2]);
        }
        Ok::<_, StoreError>((
            cache_put_ms,
            cache_disk_get_ms,
            cache_memory_get_ms,
            bucket_put_ms,
            bucket_get_ms,
        ))
    })();
    // Best effort: the scratch directory only holds bench files.
    let _ = std::fs::remove_dir_all(&scratch);
    let (cache_put_ms, cache_disk_get_ms, cache_memory_get_ms, bucket_put_ms, bucket_get_ms) =
        result?;

    Ok(StoreBench {
        width,
        height,
        wavelengths: wavelength_count,
        compression,
        payload_bytes,
        file_bytes: bytes.len() as u64,
        encode_ms,
        decode_ms,
        verify_ms,
        cache_put_ms,
        cache_disk_get_ms,
        cache_memory_get_ms,
        bucket_put_ms,
        bucket_get_ms,
        repetitions,
    })
}

/// Smooth gradients with fine-scale variation, roughly as compressible as a rendered sky.
fn sky_like_image(
    width: usize,
    height: usize,
    wavelength_count: usize,
) -> Result<SpectralImage, StoreError> {
    let count = wavelength_count.max(1);
    let wavelengths_nm: Vec<f64> = (0..count)
        .map(|k| 380.0 + 400.0 * k as f64 / count as f64)
        .collect();
    let plane = |scale: f32| -> Vec<f32> {
        (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as f32, (i / width) as f32);
                let smooth = scale * (1.0 + (x * 0.01).sin() * (y * 0.013).cos());
                smooth * (1.0 + 1e-3 * ((i as u32).wrapping_mul(2_654_435_761) >> 22) as f32)
            })
            .collect()
    };
    let planes = (0..count).map(|k| plane(0.1 + k as f32 * 0.01)).collect();
    let mut image = SpectralImage::emissive(width, height, &wavelengths_nm, planes)?;
    image.set_rgb([plane(1.0), plane(0.9), plane(0.8)])?;
    Ok(image)
}

fn median_ms(
    repetitions: usize,
    mut run: impl FnMut() -> Result<(), StoreError>,
) -> Result<f64, StoreError> {
    let mut times = Vec::with_capacity(repetitions);
    for _ in 0..repetitions {
        let start = Instant::now();
        run()?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    Ok(times[times.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_runs_and_cleans_up() {
        let dir = std::env::temp_dir().join(format!("skybake-bench-test-{}", std::process::id()));
        let report = bench_store(&dir, 40, 30, 3, ExrCompression::Piz, 1, None).unwrap();
        assert_eq!(report.payload_bytes, 40 * 30 * 6 * 4);
        assert!(report.file_bytes > 0);
        assert!(!dir
            .join(format!("skybake-bench-{}", std::process::id()))
            .exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
