//! Spectral radiance → CIE 1931 XYZ → linear sRGB.
//!
//! Convention (also used by `tools/colour_reference.py`): the spectrum known at the requested
//! wavelengths is interpolated linearly onto the 1 nm grid 360–830 nm (held constant beyond the
//! first and last sample), then X = Σ L(λ) x̄(λ) · 1 nm (no 683 lm/W factor), likewise Y and Z.
//! Linear sRGB uses the IEC 61966-2-1 matrix (D65 white, no chromatic adaptation).

use super::{data::cie1931_cmfs, Tabulated};

/// IEC 61966-2-1 XYZ → linear sRGB matrix (rows R, G, B).
pub const XYZ_TO_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// Precomputed weights mapping samples at given wavelengths to XYZ (a 3 × N matrix), so that
/// converting many pixels costs 3·N multiply-adds each.
#[derive(Debug, Clone)]
pub struct XyzWeights {
    /// `weights[c][i]`: contribution of sample `i` to X (c = 0), Y, Z.
    pub weights: [Vec<f64>; 3],
}

impl XyzWeights {
    /// Weights for samples at `wavelengths_nm` (ascending).
    pub fn new(wavelengths_nm: &[f64]) -> Self {
        let n = wavelengths_nm.len();
        let cmfs = cie1931_cmfs();
        let mut weights = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        for k in 0..=470 {
            let lambda = 360.0 + k as f64;
            // Interpolation weights of the sample spectrum at `lambda`.
            let (i0, i1, t) = bracket(wavelengths_nm, lambda);
            for (c, cmf) in cmfs.iter().enumerate() {
                let v = cmf.eval(lambda);
                weights[c][i0] += v * (1.0 - t);
                weights[c][i1] += v * t;
            }
        }
        Self { weights }
    }

    /// XYZ of a spectrum sampled at the wavelengths these weights were made for.
    pub fn xyz(&self, samples: &[f64]) -> [f64; 3] {
        let dot = |w: &[f64]| w.iter().zip(samples).map(|(a, b)| a * b).sum::<f64>();
        [
            dot(&self.weights[0]),
            dot(&self.weights[1]),
            dot(&self.weights[2]),
        ]
    }

    /// Linear sRGB of a sampled spectrum.
    pub fn linear_srgb(&self, samples: &[f64]) -> [f64; 3] {
        xyz_to_linear_srgb(self.xyz(samples))
    }
}

/// Indices and weight of `x` between samples of the ascending list `xs` (constant beyond ends).
fn bracket(xs: &[f64], x: f64) -> (usize, usize, f64) {
    let n = xs.len();
    if n == 1 || x <= xs[0] {
        return (0, 0, 0.0);
    }
    if x >= xs[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    let i = xs.partition_point(|&v| v <= x) - 1;
    (i, i + 1, (x - xs[i]) / (xs[i + 1] - xs[i]))
}

/// XYZ of a spectrum given at `wavelengths_nm` (ascending) with values `samples`.
pub fn spectrum_to_xyz(wavelengths_nm: &[f64], samples: &[f64]) -> [f64; 3] {
    XyzWeights::new(wavelengths_nm).xyz(samples)
}

/// Linear sRGB from XYZ.
pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    XYZ_TO_SRGB.map(|row| row[0] * xyz[0] + row[1] * xyz[1] + row[2] * xyz[2])
}

/// sRGB transfer function (linear → display-encoded), input clamped to [0, 1].
pub fn srgb_encode(linear: f64) -> f64 {
    let c = linear.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// A tabulated spectrum's XYZ over 360–830 nm at 1 nm (for tests and reports).
pub fn tabulated_to_xyz(s: &Tabulated) -> [f64; 3] {
    let nm: Vec<f64> = (0..=470).map(|k| 360.0 + k as f64).collect();
    let v: Vec<f64> = nm.iter().map(|&l| s.eval(l)).collect();
    spectrum_to_xyz(&nm, &v)
}
