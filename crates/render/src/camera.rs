//! Primary rays of the frame cameras (pinhole, orthographic, equidistant fisheye), built on the
//! shared [`skybake_physics::camera::Ray`] leaf.

use super::scene::{CameraSpec, Projection};
use glam::DVec3;
use skybake_physics::camera::Ray;

/// The ray through image position (`px`, `py`) in pixels from the top-left corner (pixel centres
/// at i + ½); `None` outside a fisheye's circle.
pub fn primary_ray(c: &CameraSpec, px: f64, py: f64) -> Option<Ray> {
    let (w, h) = (c.width as f64, c.height as f64);
    // Image-plane coordinates in [-1, 1] (x right, y up).
    let sx = 2.0 * px / w - 1.0;
    let sy = 1.0 - 2.0 * py / h;
    match c.projection {
        Projection::Pinhole { half_w, half_h } => Some(Ray {
            origin_m: c.position_m,
            dir: (c.forward + c.right * (sx * half_w) + c.up * (sy * half_h)).normalize(),
            t_max_m: f64::INFINITY,
        }),
        Projection::Orthographic { half_w, half_h } => Some(Ray {
            origin_m: c.position_m + c.right * (sx * half_w) + c.up * (sy * half_h),
            dir: c.forward,
            t_max_m: f64::INFINITY,
        }),
        Projection::Fisheye { rad_per_px } => {
            let (dx, dy) = (px - 0.5 * w, 0.5 * h - py);
            let r = (dx * dx + dy * dy).sqrt();
            let theta = r * rad_per_px;
            if theta > std::f64::consts::PI {
                return None;
            }
            let (s, co) = theta.sin_cos();
            let (cx, cy) = if r > 0.0 {
                (dx / r, dy / r)
            } else {
                (0.0, 0.0)
            };
            Some(Ray {
                origin_m: c.position_m,
                dir: (c.forward * co + (c.right * cx + c.up * cy) * s).normalize(),
                t_max_m: f64::INFINITY,
            })
        }
    }
}

/// Distance along `dir` from `origin` to the entry and exit of the box `[lo, hi]`, clipped to
/// t ≥ 0; `None` if the ray misses it.
pub fn box_interval(origin: DVec3, dir: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let mut t0 = 0.0f64;
    let mut t1 = f64::INFINITY;
    for a in 0..3 {
        let (o, d) = (origin[a], dir[a]);
        if d.abs() < 1e-300 {
            if o < lo[a] || o > hi[a] {
                return None;
            }
        } else {
            let inv = 1.0 / d;
            let (mut ta, mut tb) = ((lo[a] - o) * inv, (hi[a] - o) * inv);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
        }
    }
    (t1 > t0).then_some((t0, t1))
}
