//! Validated wavelength lists (1 to 64 values within 360–830 nm).

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Shortest wavelength accepted, nm.
pub const MIN_WAVELENGTH_NM: f64 = 360.0;
/// Longest wavelength accepted, nm.
pub const MAX_WAVELENGTH_NM: f64 = 830.0;
/// Most wavelengths in one request.
pub const MAX_WAVELENGTHS: usize = 64;

/// A canonical wavelength list: sorted ascending, distinct, each in 360–830 nm, 1–64 entries.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Wavelengths(Vec<f64>);

impl Wavelengths {
    /// Validates and canonicalises (sorts) a list of wavelengths in nm.
    pub fn new(mut nm: Vec<f64>) -> Result<Self> {
        if nm.is_empty() || nm.len() > MAX_WAVELENGTHS {
            return Err(Error::out_of_range(
                "wavelengths",
                format!("{} values", nm.len()),
                format!("1 to {MAX_WAVELENGTHS} values"),
            ));
        }
        for &w in &nm {
            if !(w.is_finite() && (MIN_WAVELENGTH_NM..=MAX_WAVELENGTH_NM).contains(&w)) {
                return Err(Error::out_of_range(
                    "wavelengths",
                    w,
                    format!("{MIN_WAVELENGTH_NM}–{MAX_WAVELENGTH_NM} nm"),
                ));
            }
        }
        nm.sort_by(f64::total_cmp);
        if let Some(w) = nm.windows(2).find(|w| w[0] == w[1]) {
            return Err(Error::invalid(
                "wavelengths",
                format!("{} nm is listed twice", w[0]),
            ));
        }
        Ok(Self(nm))
    }

    /// Parses a comma-separated list such as `"440,550,680"`.
    pub fn parse(text: &str) -> Result<Self> {
        let values = text
            .split(',')
            .map(|s| {
                s.trim().parse::<f64>().map_err(|_| {
                    Error::invalid(
                        "wavelengths",
                        format!("'{}' is not a number (expected e.g. 440,550,680)", s.trim()),
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Self::new(values)
    }

    /// `n` wavelengths evenly spaced over `[lo_nm, hi_nm]` (inclusive).
    pub fn linspace(lo_nm: f64, hi_nm: f64, n: usize) -> Result<Self> {
        if n == 1 {
            return Self::new(vec![lo_nm]);
        }
        Self::new(
            (0..n)
                .map(|i| lo_nm + (hi_nm - lo_nm) * i as f64 / (n - 1) as f64)
                .collect(),
        )
    }

    /// The default set: 16 wavelengths from 380 to 755 nm in 25 nm steps (enough for colour).
    pub fn default_set() -> Self {
        Self((0..16).map(|i| 380.0 + 25.0 * i as f64).collect())
    }

    /// The wavelengths, nm, ascending.
    pub fn as_nm(&self) -> &[f64] {
        &self.0
    }

    /// Number of wavelengths.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Always false: a list holds at least one wavelength.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Largest gap between neighbouring samples, nm (infinite for one wavelength).
    pub fn max_gap_nm(&self) -> f64 {
        if self.0.len() < 2 {
            return f64::INFINITY;
        }
        self.0.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max)
    }

    /// Whether the sampling supports colour output: covers 400–700 nm with gaps of at most 40 nm.
    pub fn adequate_for_colour(&self) -> bool {
        self.0.first().is_some_and(|&w| w <= 410.0)
            && self.0.last().is_some_and(|&w| w >= 680.0)
            && self.max_gap_nm() <= 40.0
    }
}

impl<'de> Deserialize<'de> for Wavelengths {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let v = Vec::<f64>::deserialize(d)?;
        Self::new(v).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sorts_and_rejects() {
        let w = Wavelengths::parse("680, 440,550").unwrap();
        assert_eq!(w.as_nm(), &[440.0, 550.0, 680.0]);
        assert_eq!(
            Wavelengths::parse("350").unwrap_err().field(),
            "wavelengths"
        );
        assert!(Wavelengths::parse("831").is_err());
        assert!(Wavelengths::parse("500,500").is_err());
        assert!(Wavelengths::parse("abc").is_err());
        assert!(Wavelengths::parse("NaN").is_err());
        assert!(Wavelengths::new(vec![]).is_err());
        assert!(Wavelengths::linspace(360.0, 830.0, 65).is_err());
        assert_eq!(Wavelengths::linspace(360.0, 830.0, 64).unwrap().len(), 64);
        assert!(Wavelengths::default_set().adequate_for_colour());
        assert!(!Wavelengths::parse("440,550,680")
            .unwrap()
            .adequate_for_colour());
    }
}
