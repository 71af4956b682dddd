//! The reference: a spectral Monte Carlo path tracer with delta tracking for
//! free paths, ratio tracking for shadow rays towards the sun, all orders of scattering, unbiased
//! Russian roulette, the scene's phase functions, sun, environment (sky above, ground light
//! below) and, in vacuum, the Lambertian ground plane. Wavelengths with identical optics share
//! their paths (a grey cloud traces one path for all wavelengths). Each pixel draws from its own
//! random stream seeded by (seed, pixel), so results do not depend on tiling or threads.
//!
//! Per sample it returns the radiance scattered by the cloud towards the camera, I_a (eq 3's
//! gain terms together), and whether the primary ray left the cloud unscattered (an unbiased
//! estimate of the cloud's transmittance T_c), so the caller composites background and aerial
//! perspective exactly as the fast method does.

use super::lighting::Lighting;
use super::scene::Optics;
use super::volume::CloudVolume;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use skybake_physics::camera::Ray;
use skybake_physics::phase::orthonormal_basis;
use std::f64::consts::PI;

/// Depth after which Russian roulette keeps a path with probability 0.9 (and divides its weight).
const RR_DEPTH: usize = 64;
/// Hard cap on scattering events per path (a path this long in τ ≤ 1000 clouds has negligible
/// weight; the cap bounds the work a scene can cause).
const MAX_DEPTH: usize = 100_000;

/// One path-traced estimate: cloud radiance per wavelength and the unscattered indicator.
pub struct Sample {
    pub radiance: Vec<f64>,
    pub transmitted: Vec<f64>,
}

/// The path tracer for one scene.
pub struct PathTracer<'a> {
    pub vol: &'a CloudVolume,
    pub optics: &'a Optics,
    pub lighting: &'a Lighting,
    pub groups: Vec<Vec<usize>>,
    pub seed: u64,
    /// Largest number of scattering events counted (cloud and ground); `usize::MAX` for all
    /// orders. Lower values measure the contribution of orders 1..=N.
    pub max_orders: usize,
    /// Smallest number of scattering events counted: light that reaches the camera after fewer
    /// is dropped (with 1 or more, the unscattered background too: `transmitted` stays 0).
    /// `min_orders` 2 and `max_orders` 3 give the orders of the reference pattern of Nishita et al. 1996, §3.4.
    pub min_orders: usize,
}

impl<'a> PathTracer<'a> {
    pub fn new(
        vol: &'a CloudVolume,
        optics: &'a Optics,
        lighting: &'a Lighting,
        seed: u64,
    ) -> Self {
        Self {
            vol,
            optics,
            lighting,
            groups: optics.groups(),
            seed,
            max_orders: usize::MAX,
            min_orders: 0,
        }
    }

    /// A random stream for pixel (x, y), sample batch `batch`.
    pub fn rng(&self, x: usize, y: usize, batch: u64) -> Pcg64 {
        let key = (y as u64) << 32 | x as u64;
        Pcg64::seed_from_u64(
            self.seed
                ^ key.wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ batch.wrapping_mul(0xD1B5_4A32_D192_ED03),
        )
    }

    /// Traces one primary ray for every wavelength group.
    pub fn sample(&self, ray: &Ray, rng: &mut Pcg64) -> Sample {
        let n_l = self.optics.albedo.len();
        let mut radiance = vec![0.0; n_l];
        let mut transmitted = vec![0.0; n_l];
        for group in &self.groups {
            self.trace(ray, group, rng, &mut radiance, &mut transmitted);
        }
        Sample {
            radiance,
            transmitted,
        }
    }

    /// Delta tracking from `o` along `d` within the box (extinction `k` per unit density):
    /// distance to a real collision, or None.
    pub fn free_path(&self, o: DVec3, d: DVec3, k: f64, rng: &mut Pcg64) -> Option<f64> {
        let smax = k * self.vol.rho_max;
        if smax <= 0.0 {
            return None;
        }
        let (t0, t1) = self.vol.interval(o, d)?;
        let mut t = t0;
        loop {
            t -= (1.0 - rng.random::<f64>()).ln() / smax;
            if t >= t1 {
                return None;
            }
            let rho = self.vol.rho(o + d * t);
            if rng.random::<f64>() * self.vol.rho_max < rho {
                return Some(t);
            }
        }
    }

    /// Ratio tracking: an unbiased estimate of the transmittance from `o` along `d` to the box exit
    /// (extinction `k` per unit density).
    pub fn transmittance(&self, o: DVec3, d: DVec3, k: f64, rng: &mut Pcg64) -> f64 {
        let smax = k * self.vol.rho_max;
        if smax <= 0.0 {
            return 1.0;
        }
        let Some((t0, t1)) = self.vol.interval(o, d) else {
            return 1.0;
        };
        let mut t = t0;
        let mut tr = 1.0;
        loop {
            t -= (1.0 - rng.random::<f64>()).ln() / smax;
            if t >= t1 {
                return tr;
            }
            tr *= 1.0 - self.vol.rho(o + d * t) / self.vol.rho_max;
            if tr < 1e-3 {
                // Russian roulette on the estimate itself keeps it unbiased.
                if rng.random::<f64>() < 0.5 {
                    return 0.0;
                }
                tr *= 2.0;
            }
        }
    }

    /// Distance along `d` from `o` to the explicit ground plane, if the path tracer uses one.
    fn ground_hit(&self, o: DVec3, d: DVec3) -> Option<f64> {
        let g = self.lighting.ground.as_ref().filter(|g| g.explicit)?;
        if d.z >= 0.0 || o.z <= g.height_m {
            return None;
        }
        Some((g.height_m - o.z) / d.z)
    }

    fn trace(
        &self,
        ray: &Ray,
        group: &[usize],
        rng: &mut Pcg64,
        radiance: &mut [f64],
        transmitted: &mut [f64],
    ) {
        let l0 = group[0];
        let k = self.optics.extinction_per_density_m[l0];
        let albedo = self.optics.albedo[l0];
        let phase = self.optics.phase[l0];
        let lt = self.lighting;
        let sun_on = lt.sun_dir.is_finite() && group.iter().any(|&l| lt.sun_irradiance[l] > 0.0);
        let mut thr = vec![1.0; group.len()];
        let mut env = vec![0.0; lt.wavelengths_nm.len()];
        let mut pos = ray.origin_m;
        let mut dir = ray.dir;
        let mut depth = 0usize;
        let ground_light = lt.ground.as_ref().is_some_and(|g| g.explicit) && !lt.below.is_zero();
        loop {
            match self.free_path(pos, dir, k, rng) {
                Some(t) => {
                    pos += dir * t;
                    if depth >= self.max_orders {
                        return;
                    }
                    for x in thr.iter_mut() {
                        *x *= albedo;
                    }
                    // Next-event estimation towards the sun (a delta light: the only way to it);
                    // the light it finds has scattered depth + 1 times.
                    if sun_on && depth + 1 >= self.min_orders {
                        let blocked = self.ground_hit(pos, lt.sun_dir).is_some();
                        if !blocked {
                            let tr = self.transmittance(pos, lt.sun_dir, k, rng);
                            let f = phase.eval(lt.sun_dir.dot(dir)) * tr;
                            for (gi, &l) in group.iter().enumerate() {
                                radiance[l] += thr[gi] * lt.sun_irradiance[l] * f;
                            }
                        }
                    }
                    let mut more = || rng.random::<f64>();
                    let (u1, u2) = (more(), more());
                    dir = phase.sample(dir, u1, u2, &mut more).0;
                    depth += 1;
                    let m = thr.iter().copied().fold(0.0, f64::max);
                    if m <= 0.0 || depth > MAX_DEPTH {
                        return;
                    }
                    if depth > RR_DEPTH || m < 0.1 {
                        let keep = if m < 0.1 { m.max(0.01) / 0.1 } else { 0.9 };
                        let keep = keep.min(0.9);
                        if rng.random::<f64>() >= keep {
                            return;
                        }
                        for x in thr.iter_mut() {
                            *x /= keep;
                        }
                    }
                }
                None => {
                    if depth == 0 {
                        // The primary ray left unscattered: the caller adds T_c · background.
                        if self.min_orders == 0 {
                            for &l in group {
                                transmitted[l] += 1.0;
                            }
                        }
                        return;
                    }
                    if let Some(tg) = self.ground_hit(pos, dir) {
                        if !ground_light || depth >= self.max_orders {
                            return;
                        }
                        // Lambertian reflection at the ground: sun by NEE, then a cosine-weighted
                        // bounce (the pdf cancels the BRDF's cosine and 1/π).
                        let g = lt
                            .ground
                            .as_ref()
                            .map(|g| g.albedo.clone())
                            .unwrap_or_default();
                        pos += dir * tg;
                        pos.z += 1e-6;
                        for (gi, &l) in group.iter().enumerate() {
                            thr[gi] *= g[l];
                        }
                        if sun_on && lt.sun_dir.z > 0.0 && depth + 1 >= self.min_orders {
                            let tr = self.transmittance(pos, lt.sun_dir, k, rng);
                            for (gi, &l) in group.iter().enumerate() {
                                radiance[l] +=
                                    thr[gi] * lt.sun_irradiance[l] * lt.sun_dir.z / PI * tr;
                            }
                        }
                        let (u1, u2) = (rng.random::<f64>(), rng.random::<f64>());
                        let r = u1.sqrt();
                        let phi = 2.0 * PI * u2;
                        let (t, b) = orthonormal_basis(DVec3::Z);
                        dir = (t * (r * phi.cos())
                            + b * (r * phi.sin())
                            + DVec3::Z * (1.0 - u1).max(0.0).sqrt())
                        .normalize();
                        depth += 1;
                        if thr.iter().all(|&x| x <= 0.0) {
                            return;
                        }
                        continue;
                    }
                    // Escaped: the environment (with an explicit ground, only the sky above).
                    let explicit = lt.ground.as_ref().is_some_and(|g| g.explicit);
                    if (dir.z >= 0.0 || !explicit) && depth >= self.min_orders {
                        lt.env(dir, &mut env);
                        for (gi, &l) in group.iter().enumerate() {
                            radiance[l] += thr[gi] * env[l];
                        }
                    }
                    return;
                }
            }
        }
    }
}
