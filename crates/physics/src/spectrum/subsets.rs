//! Subsets of a spectrum's wavelengths for an RGB-only output (the planner's wavelength rule). RGB planes
//! interpolate a sampled spectrum linearly onto the 1 nm grid ([`super::colour`]), so leaving
//! wavelengths out changes the RGB by the interpolation error of the spectrum between those kept.
//! Given proxy spectra known at every wavelength, backward elimination drops, one at a time, the
//! interior wavelength whose loss changes the worst proxy's linear sRGB least.

use super::colour::xyz_to_linear_srgb;
use super::data::cie1931_cmfs;

/// Fewest wavelengths a subset keeps (the colour needs blue, green and red).
pub const MIN_RGB_WAVELENGTHS: usize = 3;

/// The CIE 1931 colour-matching functions on the 1 nm grid 360–830 nm.
fn cmf_grid() -> Vec<[f64; 3]> {
    let cmfs = cie1931_cmfs();
    (0..=470)
        .map(|k| {
            let l = 360.0 + k as f64;
            [cmfs[0].eval(l), cmfs[1].eval(l), cmfs[2].eval(l)]
        })
        .collect()
}

/// Linear sRGB of each proxy known at the wavelengths `keep` (indices into `nm`, ascending),
/// linear between them and constant beyond the ends, as `colour::XyzWeights`.
fn rgb_at(nm: &[f64], keep: &[usize], proxies: &[Vec<f64>], cmf: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut xyz = vec![[0.0f64; 3]; proxies.len()];
    let mut j = 0;
    for (k, c) in cmf.iter().enumerate() {
        let l = 360.0 + k as f64;
        while j + 1 < keep.len() && nm[keep[j + 1]] <= l {
            j += 1;
        }
        let (i0, i1, t) = if l <= nm[keep[0]] || j + 1 >= keep.len() {
            (keep[j], keep[j], 0.0)
        } else {
            let (a, b) = (keep[j], keep[j + 1]);
            (a, b, (l - nm[a]) / (nm[b] - nm[a]))
        };
        for (acc, p) in xyz.iter_mut().zip(proxies) {
            let v = p[i0] * (1.0 - t) + p[i1] * t;
            for ch in 0..3 {
                acc[ch] += v * c[ch];
            }
        }
    }
    xyz.into_iter().map(xyz_to_linear_srgb).collect()
}

/// The largest change of any proxy's RGB against `full`, relative to its mean |channel|.
fn worst_change(rgb: &[[f64; 3]], full: &[[f64; 3]]) -> f64 {
    rgb.iter()
        .zip(full)
        .map(|(a, f)| {
            let scale = (f[0].abs() + f[1].abs() + f[2].abs()) / 3.0;
            let d = (0..3).map(|c| (a[c] - f[c]).abs()).fold(0.0, f64::max);
            if scale > 0.0 {
                d / scale
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max)
}

/// Subsets of `nm` (ascending) by backward elimination on `proxies` (each known at every
/// wavelength of `nm`; the all-zero and non-finite ones are ignored), fewest wavelengths first,
/// each with the largest relative change of a proxy's linear sRGB against the full set. The first
/// and last wavelengths stay (beyond them the spectrum is held constant); none with
/// [`MIN_RGB_WAVELENGTHS`] wavelengths or fewer, or without a lit proxy.
pub fn rgb_subsets(nm: &[f64], proxies: &[Vec<f64>]) -> Vec<(Vec<f64>, f64)> {
    let proxies: Vec<Vec<f64>> = proxies
        .iter()
        .filter(|p| {
            p.len() == nm.len() && p.iter().any(|v| *v > 0.0) && p.iter().all(|v| v.is_finite())
        })
        .cloned()
        .collect();
    let mut out = Vec::new();
    if nm.len() <= MIN_RGB_WAVELENGTHS || proxies.is_empty() {
        return out;
    }
    let cmf = cmf_grid();
    let all: Vec<usize> = (0..nm.len()).collect();
    let full = rgb_at(nm, &all, &proxies, &cmf);
    let mut keep = all;
    while keep.len() > MIN_RGB_WAVELENGTHS {
        let mut best: Option<(usize, f64)> = None;
        for j in 1..keep.len() - 1 {
            let mut trial = keep.clone();
            trial.remove(j);
            let e = worst_change(&rgb_at(nm, &trial, &proxies, &cmf), &full);
            if best.is_none_or(|(_, b)| e < b) {
                best = Some((j, e));
            }
        }
        let Some((j, e)) = best else { break };
        keep.remove(j);
        out.push((keep.iter().map(|&i| nm[i]).collect(), e));
    }
    out.reverse();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_full_set_reproduces_the_colour_module() {
        let nm: Vec<f64> = (0..16).map(|i| 380.0 + 25.0 * i as f64).collect();
        let proxies: Vec<Vec<f64>> = vec![
            nm.iter().map(|l| (l / 550.0).powi(-4)).collect(),
            nm.iter()
                .map(|&l| super::super::data::solar_irradiance_at(l))
                .collect(),
        ];
        let all: Vec<usize> = (0..nm.len()).collect();
        let ours = rgb_at(&nm, &all, &proxies, &cmf_grid());
        let w = super::super::colour::XyzWeights::new(&nm);
        for (p, rgb) in proxies.iter().zip(&ours) {
            let theirs = w.linear_srgb(p);
            for c in 0..3 {
                assert!((rgb[c] - theirs[c]).abs() <= 1e-9 * theirs[c].abs().max(1e-30));
            }
        }
        let subsets = rgb_subsets(&nm, &proxies);
        assert_eq!(subsets.len(), 16 - MIN_RGB_WAVELENGTHS);
        for (i, (kept, e)) in subsets.iter().enumerate() {
            assert_eq!(kept.len(), MIN_RGB_WAVELENGTHS + i);
            assert_eq!((kept[0], kept[kept.len() - 1]), (380.0, 755.0));
            assert!(e.is_finite() && *e >= 0.0);
        }
        // A smooth spectrum alone (λ⁻⁴) loses little; the solar spectrum's 1 nm samples more.
        let smooth = rgb_subsets(&nm, &proxies[..1]);
        assert!(smooth[5].1 < subsets[5].1);
        assert!(rgb_subsets(&nm[..3], &proxies).is_empty());
    }
}
