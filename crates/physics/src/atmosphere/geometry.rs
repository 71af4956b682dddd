//! Spherical-planet ray geometry (Bruneton 2017, "Precomputed atmospheric scattering: a new
//! implementation", §Geometry), with named guards against rounding (`clamp_cos`, `safe_sqrt`).
//!
//! A ray starts at radius `r` with `mu` = cosine of its zenith angle. Points along it at distance
//! `t` have radius `sqrt(r² + 2 r mu t + t²)`.

/// Clamps a cosine to [−1, 1].
#[inline]
pub fn clamp_cos(mu: f64) -> f64 {
    mu.clamp(-1.0, 1.0)
}

/// Square root of `max(x, 0)`.
#[inline]
pub fn safe_sqrt(x: f64) -> f64 {
    x.max(0.0).sqrt()
}

/// Radius at distance `t` along the ray (r, mu).
#[inline]
pub fn radius_at(r: f64, mu: f64, t: f64) -> f64 {
    safe_sqrt(r * r + 2.0 * r * mu * t + t * t)
}

/// Distance from radius `r` along `mu` to the sphere of radius `rs` going outward (the far
/// intersection), or `None` if the ray misses it. Valid for `r` inside or outside the sphere.
#[inline]
pub fn distance_to_sphere_far(r: f64, mu: f64, rs: f64) -> Option<f64> {
    let disc = r * r * (mu * mu - 1.0) + rs * rs;
    if disc < 0.0 {
        return None;
    }
    let t = -r * mu + disc.sqrt();
    (t >= 0.0).then_some(t)
}

/// Length of the part of the ray (r, mu), t ∈ [0, `length`], that lies inside the sphere of
/// radius `rs` (exact: between the roots of r² + 2 r μ t + t² = rs², clipped to the segment).
/// The discriminant is formed as (rs − r)(rs + r) + r²μ², without the cancellation of
/// rs² − r² in a planet-sized radius.
#[inline]
pub fn chord_inside_sphere(r: f64, mu: f64, rs: f64, length: f64) -> f64 {
    let disc = (rs - r) * (rs + r) + r * r * mu * mu;
    if disc <= 0.0 || length <= 0.0 {
        return 0.0;
    }
    let q = disc.sqrt();
    let (t0, t1) = (-r * mu - q, -r * mu + q);
    (t1.min(length) - t0.max(0.0)).max(0.0)
}

/// Distance to the near intersection with a sphere of radius `rs` when entering it from
/// outside (or hitting it from above), or `None` if the ray misses or points away.
#[inline]
pub fn distance_to_sphere_near(r: f64, mu: f64, rs: f64) -> Option<f64> {
    let disc = r * r * (mu * mu - 1.0) + rs * rs;
    if disc < 0.0 {
        return None;
    }
    let t = -r * mu - disc.sqrt();
    (t >= 0.0).then_some(t)
}

/// Cosine of the zenith angle of the geometric horizon seen from radius `r` above a sphere
/// of radius `bottom` (−sqrt(1 − (bottom/r)²); 0 on the ground).
#[inline]
pub fn horizon_mu(r: f64, bottom: f64) -> f64 {
    -safe_sqrt(1.0 - (bottom / r).min(1.0).powi(2))
}

/// Whether the ray (r, mu) hits the ground sphere (grazing rays count as missing it).
#[inline]
pub fn ray_hits_ground(r: f64, mu: f64, bottom: f64) -> bool {
    mu < 0.0 && r * r * (mu * mu - 1.0) + bottom * bottom > 0.0
}

/// The part of a ray inside the atmosphere shell: `[t_start, t_end]`, and whether it ends on
/// the ground. `None` if the ray never enters the atmosphere (space looking away).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub t_start: f64,
    pub t_end: f64,
    pub hits_ground: bool,
}

/// Clips the ray (r, mu) to the atmosphere shell `[bottom, top]`.
pub fn atmosphere_segment(r: f64, mu: f64, bottom: f64, top: f64) -> Option<Segment> {
    let mu = clamp_cos(mu);
    let r = r.max(bottom);
    let t_start = if r > top {
        distance_to_sphere_near(r, mu, top)?
    } else {
        0.0
    };
    if ray_hits_ground(r, mu, bottom) {
        let t_ground = distance_to_sphere_near(r, mu, bottom).unwrap_or(0.0);
        return Some(Segment {
            t_start,
            t_end: t_ground.max(t_start),
            hits_ground: true,
        });
    }
    let t_end = distance_to_sphere_far(r, mu, top)?;
    (t_end > t_start || r <= top).then_some(Segment {
        t_start,
        t_end: t_end.max(t_start),
        hits_ground: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    const R: f64 = 6_360_000.0;
    const T: f64 = 6_460_000.0;

    #[test]
    fn segments_for_typical_observers() {
        let up = atmosphere_segment(R, 1.0, R, T).unwrap();
        assert!((up.t_end - 100_000.0).abs() < 1e-6 && !up.hits_ground);
        let down = atmosphere_segment(R + 1000.0, -1.0, R, T).unwrap();
        assert!((down.t_end - 1000.0).abs() < 1e-6 && down.hits_ground);
        // Exactly horizontal on the ground: grazes, does not hit.
        let h = atmosphere_segment(R, 0.0, R, T).unwrap();
        assert!(!h.hits_ground && (h.t_end - (T * T - R * R).sqrt()).abs() < 1e-3);
        // From space, looking straight down: enters at the top.
        let s = atmosphere_segment(R + 400_000.0, -1.0, R, T).unwrap();
        assert!((s.t_start - 300_000.0).abs() < 1e-6 && (s.t_end - 400_000.0).abs() < 1e-6);
        // From space, looking away: nothing.
        assert!(atmosphere_segment(R + 400_000.0, 0.5, R, T).is_none());
        // At exactly the top, looking up: an empty segment inside the shell.
        let top = atmosphere_segment(T, 1.0, R, T).unwrap();
        assert!(top.t_end.abs() < 1e-6);
    }
}
