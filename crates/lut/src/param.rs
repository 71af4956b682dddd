//! The texture parameterisation of Bruneton 2017 ("Precomputed Atmospheric Scattering: a New
//! Implementation", the 2017 revision of Bruneton & Neyret 2008, §4 of the 2008 paper for the 4-D
//! mapping): texture sizes, the mappings between texture coordinates and (r, μ, μs, ν), and the
//! `AtmosphereParameters` his shader functions read. Written from his documentation; the
//! mappings are the same so that his `GetTransmittanceTextureUvFromRMu`,
//! `GetScatteringTextureUvwzFromRMuMuSNu` and `GetIrradianceTextureUvFromRMuS` read our textures.

use serde::Serialize;

/// Transmittance texture: width (μ) × height (r).
pub const TRANSMITTANCE_WIDTH: usize = 256;
pub const TRANSMITTANCE_HEIGHT: usize = 64;
/// Scattering texture: ν × μs × μ × r.
pub const SCATTERING_R: usize = 32;
pub const SCATTERING_MU: usize = 128;
pub const SCATTERING_MU_S: usize = 32;
pub const SCATTERING_NU: usize = 8;
/// The 3-D scattering texture's width (ν · μs) and depth (r); its height is μ.
pub const SCATTERING_WIDTH: usize = SCATTERING_NU * SCATTERING_MU_S;
/// Irradiance texture: width (μs) × height (r).
pub const IRRADIANCE_WIDTH: usize = 64;
pub const IRRADIANCE_HEIGHT: usize = 16;

/// What his shader functions need of the atmosphere (the fields of his `AtmosphereParameters`
/// that the lookups and `GetSkyRadiance…` read), per channel where spectral. Lengths in m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AtmosphereParameters {
    /// Extraterrestrial solar spectral irradiance per channel, in the bundle's irradiance unit.
    pub solar_irradiance: Vec<f64>,
    /// Angular radius of the sun, radians.
    pub sun_angular_radius: f64,
    /// Ground and top-of-atmosphere radii, m.
    pub bottom_radius: f64,
    pub top_radius: f64,
    /// Rayleigh and Mie scattering coefficients at relative density 1, m⁻¹ (his
    /// `GetExtrapolatedSingleMieScattering` reads their ratio).
    pub rayleigh_scattering: Vec<f64>,
    pub mie_scattering: Vec<f64>,
    /// Asymmetry of his Cornette-Shanks Mie phase function.
    pub mie_phase_function_g: f64,
    /// Cosine of the largest sun zenith angle the scattering texture holds.
    pub mu_s_min: f64,
    /// Ground albedo per channel (for the client's ground shading).
    pub ground_albedo: Vec<f64>,
}

impl AtmosphereParameters {
    /// H: distance to the top boundary of a horizontal ray on the ground.
    pub fn h(&self) -> f64 {
        (self.top_radius * self.top_radius - self.bottom_radius * self.bottom_radius).sqrt()
    }

    /// ρ: distance to the horizon from radius `r`.
    pub fn rho(&self, r: f64) -> f64 {
        safe_sqrt(r * r - self.bottom_radius * self.bottom_radius)
    }

    pub fn distance_to_top(&self, r: f64, mu: f64) -> f64 {
        let disc = r * r * (mu * mu - 1.0) + self.top_radius * self.top_radius;
        (-r * mu + safe_sqrt(disc)).max(0.0)
    }

    pub fn distance_to_bottom(&self, r: f64, mu: f64) -> f64 {
        let disc = r * r * (mu * mu - 1.0) + self.bottom_radius * self.bottom_radius;
        (-r * mu - safe_sqrt(disc)).max(0.0)
    }

    /// His `RayIntersectsGround`.
    pub fn ray_intersects_ground(&self, r: f64, mu: f64) -> bool {
        mu < 0.0 && r * r * (mu * mu - 1.0) + self.bottom_radius * self.bottom_radius >= 0.0
    }

    fn clamp_radius(&self, r: f64) -> f64 {
        r.clamp(self.bottom_radius, self.top_radius)
    }

    /// Transmittance texture coordinates of (r, μ) (his `GetTransmittanceTextureUvFromRMu`).
    pub fn transmittance_uv(&self, r: f64, mu: f64) -> (f64, f64) {
        let h = self.h();
        let rho = self.rho(r);
        let d = self.distance_to_top(r, mu);
        let (d_min, d_max) = (self.top_radius - r, rho + h);
        let x_mu = if d_max > d_min {
            (d - d_min) / (d_max - d_min)
        } else {
            0.0
        };
        (
            coord_from_unit(x_mu, TRANSMITTANCE_WIDTH),
            coord_from_unit(rho / h, TRANSMITTANCE_HEIGHT),
        )
    }

    /// (r, μ) of transmittance texture coordinates (the inverse mapping).
    pub fn transmittance_r_mu(&self, u: f64, v: f64) -> (f64, f64) {
        let x_mu = unit_from_coord(u, TRANSMITTANCE_WIDTH);
        let x_r = unit_from_coord(v, TRANSMITTANCE_HEIGHT);
        let h = self.h();
        let rho = h * x_r;
        let r = (rho * rho + self.bottom_radius * self.bottom_radius).sqrt();
        let (d_min, d_max) = (self.top_radius - r, rho + h);
        let d = d_min + x_mu * (d_max - d_min);
        let mu = if d == 0.0 {
            1.0
        } else {
            (h * h - rho * rho - d * d) / (2.0 * r * d)
        };
        (r, mu.clamp(-1.0, 1.0))
    }

    /// Scattering texture coordinates (u_ν, u_μs, u_μ, u_r) of a ray (his
    /// `GetScatteringTextureUvwzFromRMuMuSNu`): μ maps to the lower half of the texture when the
    /// ray hits the ground, to the upper half otherwise; μs through his ad-hoc function that
    /// is 0 at `mu_s_min`.
    pub fn scattering_uvwz(
        &self,
        r: f64,
        mu: f64,
        mu_s: f64,
        nu: f64,
        hits_ground: bool,
    ) -> [f64; 4] {
        let h = self.h();
        let rho = self.rho(r);
        let u_r = coord_from_unit(rho / h, SCATTERING_R);
        let r_mu = r * mu;
        let disc = r_mu * r_mu - r * r + self.bottom_radius * self.bottom_radius;
        let u_mu = if hits_ground {
            let d = -r_mu - safe_sqrt(disc);
            let (d_min, d_max) = (r - self.bottom_radius, rho);
            let x = if d_max == d_min {
                0.0
            } else {
                (d - d_min) / (d_max - d_min)
            };
            0.5 - 0.5 * coord_from_unit(x, SCATTERING_MU / 2)
        } else {
            let d = -r_mu + safe_sqrt(disc + h * h);
            let (d_min, d_max) = (self.top_radius - r, rho + h);
            0.5 + 0.5 * coord_from_unit((d - d_min) / (d_max - d_min), SCATTERING_MU / 2)
        };
        let u_mu_s = coord_from_unit(self.x_mu_s(mu_s), SCATTERING_MU_S);
        [(nu + 1.0) / 2.0, u_mu_s, u_mu, u_r]
    }

    /// His μs mapping before the texel-centre correction: 0 at `mu_s_min`, 1 at μs = 1.
    fn x_mu_s(&self, mu_s: f64) -> f64 {
        let h = self.h();
        let d_min = self.top_radius - self.bottom_radius;
        let a = (self.distance_to_top(self.bottom_radius, mu_s) - d_min) / (h - d_min);
        let big_a = (self.distance_to_top(self.bottom_radius, self.mu_s_min) - d_min) / (h - d_min);
        (1.0 - a / big_a).max(0.0) / (1.0 + a)
    }

    /// (r, μ, μs, ν, hits ground) at the centre of scattering texel (ν index, μs index, μ index,
    /// r index), with ν clamped to the range (μ, μs) allow (his
    /// `GetRMuMuSNuFromScatteringTextureFragCoord`: ν nodes are at exactly −1…1).
    pub fn scattering_texel(
        &self,
        i_nu: usize,
        i_mu_s: usize,
        i_mu: usize,
        i_r: usize,
    ) -> (f64, f64, f64, f64, bool) {
        let h = self.h();
        let w = (i_r as f64 + 0.5) / SCATTERING_R as f64;
        let z = (i_mu as f64 + 0.5) / SCATTERING_MU as f64;
        let y = (i_mu_s as f64 + 0.5) / SCATTERING_MU_S as f64;
        let x = i_nu as f64 / (SCATTERING_NU - 1) as f64;
        let rho = h * unit_from_coord(w, SCATTERING_R);
        let r = (rho * rho + self.bottom_radius * self.bottom_radius).sqrt();
        let (mu, hits_ground) = if z < 0.5 {
            let (d_min, d_max) = (r - self.bottom_radius, rho);
            let d = d_min + (d_max - d_min) * unit_from_coord(1.0 - 2.0 * z, SCATTERING_MU / 2);
            let mu = if d == 0.0 {
                -1.0
            } else {
                (-(rho * rho + d * d) / (2.0 * r * d)).clamp(-1.0, 1.0)
            };
            (mu, true)
        } else {
            let (d_min, d_max) = (self.top_radius - r, rho + h);
            let d = d_min + (d_max - d_min) * unit_from_coord(2.0 * z - 1.0, SCATTERING_MU / 2);
            let mu = if d == 0.0 {
                1.0
            } else {
                ((h * h - rho * rho - d * d) / (2.0 * r * d)).clamp(-1.0, 1.0)
            };
            (mu, false)
        };
        let x_mu_s = unit_from_coord(y, SCATTERING_MU_S);
        let d_min = self.top_radius - self.bottom_radius;
        let big_a = (self.distance_to_top(self.bottom_radius, self.mu_s_min) - d_min) / (h - d_min);
        let a = (big_a - x_mu_s * big_a) / (1.0 + x_mu_s * big_a);
        let d = d_min + a.min(big_a) * (h - d_min);
        let mu_s = if d == 0.0 {
            1.0
        } else {
            ((h * h - d * d) / (2.0 * self.bottom_radius * d)).clamp(-1.0, 1.0)
        };
        let nu = (x * 2.0 - 1.0).clamp(-1.0, 1.0);
        let spread = ((1.0 - mu * mu) * (1.0 - mu_s * mu_s)).max(0.0).sqrt();
        let nu = nu.clamp(mu * mu_s - spread, mu * mu_s + spread);
        (r, mu, mu_s, nu, hits_ground)
    }

    /// Irradiance texture coordinates (his `GetIrradianceTextureUvFromRMuS`).
    pub fn irradiance_uv(&self, r: f64, mu_s: f64) -> (f64, f64) {
        let x_r = (r - self.bottom_radius) / (self.top_radius - self.bottom_radius);
        (
            coord_from_unit(mu_s * 0.5 + 0.5, IRRADIANCE_WIDTH),
            coord_from_unit(x_r, IRRADIANCE_HEIGHT),
        )
    }

    /// (r, μs) of irradiance texture coordinates.
    pub fn irradiance_r_mu_s(&self, u: f64, v: f64) -> (f64, f64) {
        let x_mu_s = unit_from_coord(u, IRRADIANCE_WIDTH);
        let x_r = unit_from_coord(v, IRRADIANCE_HEIGHT);
        (
            self.bottom_radius + x_r * (self.top_radius - self.bottom_radius),
            (2.0 * x_mu_s - 1.0).clamp(-1.0, 1.0),
        )
    }

    /// The point at distance `d` along the ray (r, μ) and the cosines there: (r_d, μ_d, μs_d).
    pub fn along(&self, r: f64, mu: f64, mu_s: f64, nu: f64, d: f64) -> (f64, f64, f64) {
        let r_d = self.clamp_radius((d * d + 2.0 * r * mu * d + r * r).sqrt());
        (r_d, (r * mu + d) / r_d, (r * mu_s + d * nu) / r_d)
    }
}

/// His `GetTextureCoordFromUnitRange`: x ∈ [0, 1] to the centres of the first and last texels.
pub fn coord_from_unit(x: f64, n: usize) -> f64 {
    0.5 / n as f64 + x * (1.0 - 1.0 / n as f64)
}

/// His `GetUnitRangeFromTextureCoord`, the inverse.
pub fn unit_from_coord(u: f64, n: usize) -> f64 {
    (u - 0.5 / n as f64) / (1.0 - 1.0 / n as f64)
}

pub fn safe_sqrt(x: f64) -> f64 {
    x.max(0.0).sqrt()
}

/// Rayleigh phase function, sr⁻¹.
pub fn rayleigh_phase(nu: f64) -> f64 {
    3.0 / (16.0 * std::f64::consts::PI) * (1.0 + nu * nu)
}

/// His Mie phase function (Cornette-Shanks), sr⁻¹.
pub fn mie_phase(g: f64, nu: f64) -> f64 {
    let k = 3.0 / (8.0 * std::f64::consts::PI) * (1.0 - g * g) / (2.0 + g * g);
    k * (1.0 + nu * nu) / (1.0 + g * g - 2.0 * g * nu).max(1e-12).powf(1.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn earth() -> AtmosphereParameters {
        AtmosphereParameters {
            solar_irradiance: vec![1.0],
            sun_angular_radius: 0.00465,
            bottom_radius: 6_360_000.0,
            top_radius: 6_460_000.0,
            rayleigh_scattering: vec![1.0],
            mie_scattering: vec![1.0],
            mie_phase_function_g: 0.8,
            mu_s_min: -0.37,
            ground_albedo: vec![0.1],
        }
    }

    #[test]
    fn texel_centres_map_back_to_their_coordinates() {
        // (On the ground, r index 0, every ray of the lower μ half has length 0: his mapping
        // folds that half to one point, so those texels do not map back.)
        let a = earth();
        for &(i_nu, i_mu_s, i_mu, i_r) in &[
            (0, 0, 0, 1),
            (3, 17, 40, 5),
            (7, 31, 127, 31),
            (5, 2, 70, 20),
            (1, 9, 63, 12),
        ] {
            let (r, mu, mu_s, nu, g) = a.scattering_texel(i_nu, i_mu_s, i_mu, i_r);
            let uvwz = a.scattering_uvwz(r, mu, mu_s, nu, g);
            let want = [
                uvwz[0],
                (i_mu_s as f64 + 0.5) / SCATTERING_MU_S as f64,
                (i_mu as f64 + 0.5) / SCATTERING_MU as f64,
                (i_r as f64 + 0.5) / SCATTERING_R as f64,
            ];
            for k in 1..4 {
                assert!(
                    (uvwz[k] - want[k]).abs() < 1e-6,
                    "{k}: {uvwz:?} vs {want:?}"
                );
            }
        }
        for (u, v) in [(0.3, 0.7), (0.01, 0.99), (0.9, 0.2)] {
            let (r, mu) = a.transmittance_r_mu(u, v);
            let (u2, v2) = a.transmittance_uv(r, mu);
            assert!((u - u2).abs() < 1e-9 && (v - v2).abs() < 1e-9);
            let (r, mu_s) = a.irradiance_r_mu_s(u, v);
            let (u2, v2) = a.irradiance_uv(r, mu_s);
            assert!((u - u2).abs() < 1e-9 && (v - v2).abs() < 1e-9);
        }
    }
}
