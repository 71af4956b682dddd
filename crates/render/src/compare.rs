//! A frame's errors against a reference frame: the block and pixel NRMSE and the cloud-mean bias
//! that the renderer's validation states (against Mitsuba 3, DISORT slabs and the path tracer).

use serde::Serialize;

/// Image errors of a test frame against a reference frame.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct ImageErrors {
    /// RMS over 8×8-pixel blocks made only of cloud pixels of the block-mean difference,
    /// relative to the mean cloud radiance.
    pub nrmse_blocks: f64,
    /// The same per pixel.
    pub nrmse_pixels: f64,
    /// (mean test − mean reference) / mean reference over cloud pixels.
    pub mean_bias: f64,
    pub cloud_pixels: usize,
}

/// Compares spectral images `[px][λ]` over the pixels where `mask` is true (cloud pixels).
pub fn image_errors(
    test: &[f32],
    reference: &[f32],
    mask: &[bool],
    width: usize,
    n_l: usize,
) -> ImageErrors {
    let height = mask.len() / width.max(1);
    let px = |img: &[f32], i: usize| -> f64 {
        (0..n_l).map(|l| img[i * n_l + l] as f64).sum::<f64>() / n_l as f64
    };
    let (mut st, mut sr, mut se2, mut n) = (0.0, 0.0, 0.0, 0usize);
    for i in 0..mask.len() {
        if mask[i] {
            let (a, b) = (px(test, i), px(reference, i));
            st += a;
            sr += b;
            se2 += (a - b) * (a - b);
            n += 1;
        }
    }
    if n == 0 || sr <= 0.0 {
        return ImageErrors {
            nrmse_blocks: 0.0,
            nrmse_pixels: 0.0,
            mean_bias: 0.0,
            cloud_pixels: 0,
        };
    }
    let mean_r = sr / n as f64;
    // Cloud blocks: 8×8 blocks aligned at pixel (0, 0) whose pixels are all cloud pixels (the
    // definition of tests/data/README.md, shared with the Mitsuba comparison).
    let (mut be2, mut nb) = (0.0, 0usize);
    for by in 0..height / 8 {
        for bx in 0..width / 8 {
            let idx = |k: usize| (by * 8 + k / 8) * width + bx * 8 + k % 8;
            if (0..64).all(|k| mask[idx(k)]) {
                let a: f64 = (0..64).map(|k| px(test, idx(k))).sum::<f64>() / 64.0;
                let b: f64 = (0..64).map(|k| px(reference, idx(k))).sum::<f64>() / 64.0;
                be2 += (a - b).powi(2);
                nb += 1;
            }
        }
    }
    ImageErrors {
        nrmse_blocks: if nb > 0 {
            (be2 / nb as f64).sqrt() / mean_r
        } else {
            0.0
        },
        nrmse_pixels: (se2 / n as f64).sqrt() / mean_r,
        mean_bias: (st - sr) / sr,
        cloud_pixels: n,
    }
}
