//! The shared camera/ray leaf: a ray segment and the pinhole camera of the sphere-hierarchy
//! renderer (Ostroushko et al.). The frame renderer's cameras (`render::camera`) build on [`Ray`].

use crate::{Error, Result};
use glam::DVec3;

/// A ray segment `origin + t·dir`, `t` in [0, `t_max_m`], `dir` unit length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Start point, metres.
    pub origin_m: DVec3,
    /// Unit direction.
    pub dir: DVec3,
    /// Length of the segment, metres (may be infinite).
    pub t_max_m: f64,
}

impl Ray {
    /// A ray from `origin_m` along `dir` (normalised here) to `t_max_m`.
    pub fn new(origin_m: DVec3, dir: DVec3, t_max_m: f64) -> Result<Self> {
        let dir = dir.normalize_or_zero();
        if dir == DVec3::ZERO || !dir.is_finite() || !origin_m.is_finite() {
            return Err(Error::invalid(
                "ray",
                "origin must be finite, direction non-zero",
            ));
        }
        if t_max_m.is_nan() || t_max_m < 0.0 {
            return Err(Error::out_of_range("t_max_m", t_max_m, ">= 0"));
        }
        Ok(Self {
            origin_m,
            dir,
            t_max_m,
        })
    }
}

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position, metres.
    pub eye_m: DVec3,
    /// Point looked at, metres.
    pub target_m: DVec3,
    /// Up direction (need not be orthogonal to the view).
    pub up: DVec3,
    /// Vertical field of view, degrees (0 < fov < 180).
    pub fov_y_deg: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

/// Largest image accepted, pixels.
pub const MAX_PIXELS: usize = 16_777_216;

impl Camera {
    /// Checks the field of view, the image size and the view geometry.
    pub fn validate(&self) -> Result<()> {
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return Err(Error::out_of_range(
                "fov_y_deg",
                self.fov_y_deg,
                "0 < fov < 180",
            ));
        }
        let pixels = self.width.saturating_mul(self.height);
        if self.width == 0 || self.height == 0 || pixels > MAX_PIXELS {
            return Err(Error::too_large(
                "width",
                format!("{}x{} pixels", self.width, self.height),
                format!("1..={MAX_PIXELS} pixels"),
            ));
        }
        let fwd = self.target_m - self.eye_m;
        if !(fwd.is_finite() && fwd.length() > 0.0 && fwd.cross(self.up).length() > 0.0) {
            return Err(Error::invalid(
                "camera",
                "eye and target must differ and up must not be parallel to the view",
            ));
        }
        Ok(())
    }

    /// Angular size of one pixel (vertical), radians.
    pub fn pixel_angle_rad(&self) -> f64 {
        self.fov_y_deg.to_radians() / self.height as f64
    }

    /// The ray through the centre of pixel (x, y), row 0 at the top.
    pub fn ray(&self, x: usize, y: usize) -> Ray {
        let fwd = (self.target_m - self.eye_m).normalize();
        let right = fwd.cross(self.up).normalize();
        let up = right.cross(fwd);
        let h = (0.5 * self.fov_y_deg.to_radians()).tan();
        let aspect = self.width as f64 / self.height as f64;
        let u = ((x as f64 + 0.5) / self.width as f64 * 2.0 - 1.0) * h * aspect;
        let v = (1.0 - (y as f64 + 0.5) / self.height as f64 * 2.0) * h;
        Ray {
            origin_m: self.eye_m,
            dir: (fwd + right * u + up * v).normalize(),
            t_max_m: f64::INFINITY,
        }
    }
}
