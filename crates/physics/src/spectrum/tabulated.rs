//! Piecewise-linear tabulated functions of wavelength.

use crate::{Error, Result};

/// A function sampled at increasing abscissae, linearly interpolated between samples and held
/// constant beyond the ends.
#[derive(Debug, Clone, PartialEq)]
pub struct Tabulated {
    x: Vec<f64>,
    y: Vec<f64>,
}

impl Tabulated {
    /// Builds a table; `x` must be strictly increasing and all values finite.
    pub fn new(field: &str, x: Vec<f64>, y: Vec<f64>) -> Result<Self> {
        if x.is_empty() || x.len() != y.len() {
            return Err(Error::invalid(
                field,
                "needs at least one (wavelength, value) pair",
            ));
        }
        if x.iter().chain(&y).any(|v| !v.is_finite()) {
            return Err(Error::invalid(field, "values must be finite"));
        }
        if x.windows(2).any(|w| w[1] <= w[0]) {
            return Err(Error::invalid(
                field,
                "wavelengths must be strictly increasing",
            ));
        }
        Ok(Self { x, y })
    }

    /// Parses an embedded CSV: `#` comment lines, one header line, then numeric columns;
    /// takes column 0 as x and column `column` as y.
    pub fn from_csv(name: &str, text: &str, column: usize) -> Result<Self> {
        let mut x = Vec::new();
        let mut y = Vec::new();
        for line in text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .skip(1)
        {
            let cols: Vec<&str> = line.split(',').collect();
            let parse = |i: usize| -> Result<f64> {
                cols.get(i)
                    .and_then(|s| s.trim().parse::<f64>().ok())
                    .ok_or_else(|| Error::invalid(name, format!("bad CSV line '{line}'")))
            };
            x.push(parse(0)?);
            y.push(parse(column)?);
        }
        Self::new(name, x, y)
    }

    /// Value at `x` (linear between samples, constant beyond the ends).
    pub fn eval(&self, x: f64) -> f64 {
        let n = self.x.len();
        if x <= self.x[0] {
            return self.y[0];
        }
        if x >= self.x[n - 1] {
            return self.y[n - 1];
        }
        let i = self.x.partition_point(|&v| v <= x) - 1;
        let t = (x - self.x[i]) / (self.x[i + 1] - self.x[i]);
        self.y[i] + t * (self.y[i + 1] - self.y[i])
    }

    /// Mean value over `[a, b]` (exact integral of the piecewise-linear function / width).
    pub fn mean_over(&self, a: f64, b: f64) -> f64 {
        if b <= a {
            return self.eval(a);
        }
        let mut knots = vec![a];
        knots.extend(self.x.iter().copied().filter(|&v| v > a && v < b));
        knots.push(b);
        let integral: f64 = knots
            .windows(2)
            .map(|w| 0.5 * (self.eval(w[0]) + self.eval(w[1])) * (w[1] - w[0]))
            .sum();
        integral / (b - a)
    }

    /// The abscissae.
    pub fn xs(&self) -> &[f64] {
        &self.x
    }

    /// The ordinates.
    pub fn ys(&self) -> &[f64] {
        &self.y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_and_clamps() {
        let t = Tabulated::new("t", vec![1.0, 2.0, 4.0], vec![10.0, 20.0, 0.0]).unwrap();
        assert_eq!(t.eval(0.0), 10.0);
        assert_eq!(t.eval(1.5), 15.0);
        assert_eq!(t.eval(3.0), 10.0);
        assert_eq!(t.eval(9.0), 0.0);
        assert!((t.mean_over(1.0, 2.0) - 15.0).abs() < 1e-12);
        assert!(Tabulated::new("t", vec![2.0, 1.0], vec![0.0, 0.0]).is_err());
    }
}
