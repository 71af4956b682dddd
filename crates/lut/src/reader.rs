//! Evaluates a bundle the way a real-time client does: Bruneton 2017's `GetSkyRadiance`,
//! `GetSkyRadianceToPoint` and `GetSunAndSkyIrradiance` (his documented functions, written here
//! in Rust, without light shafts), on the textures as a GPU samples them (bilinear or trilinear
//! filtering, clamped to the edge, of the stored — for the RGB bundle half-float — values). It
//! is the proof that the bundle reproduces skybake's products, and the CPU twin of the viewer's
//! shader.

use crate::build::{Bundle, Channels, Texture};
use crate::param::{self, *};

type Vec3 = [f64; 3];

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn length(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// The segment from `camera` to `point` as his `GetSkyRadianceToPoint` starts it: a camera above
/// the atmosphere's top (radius `top`) moves to where the segment enters it. Returns that camera,
/// the unit direction, r, r·μ and the length left to `point`. Both layouts' readers use it.
pub(crate) fn segment_in_atmosphere(
    camera: Vec3,
    point: Vec3,
    top: f64,
) -> (Vec3, Vec3, f64, f64, f64) {
    let diff = [
        point[0] - camera[0],
        point[1] - camera[1],
        point[2] - camera[2],
    ];
    let mut d = length(diff);
    let view = [diff[0] / d, diff[1] / d, diff[2] / d];
    let mut camera = camera;
    let mut r = length(camera);
    let mut rmu = dot(camera, view);
    let to_top = -rmu - (rmu * rmu - r * r + top * top).sqrt();
    if to_top > 0.0 {
        camera = [
            camera[0] + view[0] * to_top,
            camera[1] + view[1] * to_top,
            camera[2] + view[2] * to_top,
        ];
        r = top;
        rmu += to_top;
        d -= to_top;
    }
    (camera, view, r, rmu, d)
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Linear filtering weights of texture coordinate `u` over `n` texels (clamp to edge).
fn filter(u: f64, n: usize) -> (usize, usize, f64) {
    let x = (u * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
    let i0 = (x.floor() as usize).min(n - 1);
    let i1 = (i0 + 1).min(n - 1);
    (i0, i1, x - i0 as f64)
}

/// Bilinear sample of a 2-D texture at (u, v), all channels.
fn sample2(t: &Texture, u: f64, v: f64) -> Vec<f64> {
    sample3(t, u, v, 0.5)
}

/// Trilinear sample of a 3-D texture at (u, v, w), all channels.
fn sample3(t: &Texture, u: f64, v: f64, w: f64) -> Vec<f64> {
    let (x0, x1, fx) = filter(u, t.width);
    let (y0, y1, fy) = filter(v, t.height);
    let (z0, z1, fz) = filter(w, t.depth);
    let mut out = vec![0.0; t.channels];
    for (z, wz) in [(z0, 1.0 - fz), (z1, fz)] {
        for (y, wy) in [(y0, 1.0 - fy), (y1, fy)] {
            for (x, wx) in [(x0, 1.0 - fx), (x1, fx)] {
                let w = wx * wy * wz;
                if w == 0.0 {
                    continue;
                }
                for (o, v) in out.iter_mut().zip(t.texel(x, y, z)) {
                    *o += w * *v as f64;
                }
            }
        }
    }
    out
}

/// His `GetTransmittanceToTopAtmosphereBoundary` on transmittance texture `t`.
pub fn transmittance_to_top(t: &Texture, a: &AtmosphereParameters, r: f64, mu: f64) -> Vec<f64> {
    let (u, v) = a.transmittance_uv(r, mu);
    sample2(t, u, v)
}

/// His `GetTransmittance` on transmittance texture `t`: from (r, μ) over distance `d`, the ratio
/// of two lookups to the top (towards the ground: of the reversed ray's).
pub fn transmittance(
    t: &Texture,
    a: &AtmosphereParameters,
    r: f64,
    mu: f64,
    d: f64,
    hits_ground: bool,
) -> Vec<f64> {
    let r_d = (d * d + 2.0 * r * mu * d + r * r)
        .sqrt()
        .clamp(a.bottom_radius, a.top_radius);
    let mu_d = ((r * mu + d) / r_d).clamp(-1.0, 1.0);
    let (num, den) = if hits_ground {
        (
            transmittance_to_top(t, a, r_d, -mu_d),
            transmittance_to_top(t, a, r, -mu),
        )
    } else {
        (
            transmittance_to_top(t, a, r, mu),
            transmittance_to_top(t, a, r_d, mu_d),
        )
    };
    num.iter()
        .zip(den)
        .map(|(n, d)| if d > 0.0 { (n / d).min(1.0) } else { 0.0 })
        .collect()
}

/// His `GetTransmittanceToSun` on transmittance texture `t`: to the top, times the fraction of
/// the sun's disk above the horizon (a smoothstep over its angular radius).
pub fn transmittance_to_sun(t: &Texture, a: &AtmosphereParameters, r: f64, mu_s: f64) -> Vec<f64> {
    let sin_h = a.bottom_radius / r;
    let cos_h = -(1.0 - sin_h * sin_h).max(0.0).sqrt();
    let f = smoothstep(
        -sin_h * a.sun_angular_radius,
        sin_h * a.sun_angular_radius,
        mu_s - cos_h,
    );
    transmittance_to_top(t, a, r, mu_s)
        .into_iter()
        .map(|t| t * f)
        .collect()
}

/// A bundle read with Bruneton's functions. Radiances and irradiances are in the bundle's unit
/// (W × [`crate::build::UNIT_SCALE`]), one value per channel; positions in m from the planet's
/// centre; directions unit vectors.
pub struct Reader<'a> {
    pub bundle: &'a Bundle,
}

impl<'a> Reader<'a> {
    pub fn new(bundle: &'a Bundle) -> Self {
        Self { bundle }
    }

    fn a(&self) -> &AtmosphereParameters {
        &self.bundle.params
    }

    /// His `GetTransmittanceToTopAtmosphereBoundary`.
    pub fn transmittance_to_top(&self, r: f64, mu: f64) -> Vec<f64> {
        transmittance_to_top(&self.bundle.transmittance, self.a(), r, mu)
    }

    /// His `GetTransmittance`: from (r, μ) over distance `d`.
    pub fn transmittance(&self, r: f64, mu: f64, d: f64, hits_ground: bool) -> Vec<f64> {
        transmittance(&self.bundle.transmittance, self.a(), r, mu, d, hits_ground)
    }

    /// His `GetTransmittanceToSun`: to the top, times the fraction of the sun's disk above the
    /// horizon (a smoothstep over its angular radius).
    pub fn transmittance_to_sun(&self, r: f64, mu_s: f64) -> Vec<f64> {
        transmittance_to_sun(&self.bundle.transmittance, self.a(), r, mu_s)
    }

    /// His `GetCombinedScattering` (or the two lookups of the non-combined layout): the
    /// scattering without phase functions and the single Mie scattering, both interpolated over
    /// ν by hand between the two nearest ν slices.
    pub fn scattering(
        &self,
        r: f64,
        mu: f64,
        mu_s: f64,
        nu: f64,
        hits_ground: bool,
    ) -> (Vec<f64>, Vec<f64>) {
        let b = self.bundle;
        let uvwz = self.a().scattering_uvwz(r, mu, mu_s, nu, hits_ground);
        let tex_coord_x = uvwz[0] * (SCATTERING_NU - 1) as f64;
        let tex_x = tex_coord_x.floor().min((SCATTERING_NU - 1) as f64);
        let lerp = tex_coord_x - tex_x;
        let x0 = (tex_x + uvwz[1]) / SCATTERING_NU as f64;
        let x1 = (tex_x + 1.0 + uvwz[1]) / SCATTERING_NU as f64;
        let mix = |t: &Texture| -> Vec<f64> {
            let s0 = sample3(t, x0, uvwz[2], uvwz[3]);
            if lerp == 0.0 {
                return s0;
            }
            let s1 = sample3(t, x1, uvwz[2], uvwz[3]);
            s0.iter()
                .zip(s1)
                .map(|(a, b)| a * (1.0 - lerp) + b * lerp)
                .collect()
        };
        let combined = mix(&b.scattering);
        match (&b.channels, &b.single_mie) {
            (Channels::Spectral, Some(mie)) => (combined, mix(mie)),
            _ => {
                let rgb = combined[..3].to_vec();
                let mie = self.extrapolated_single_mie(&rgb, combined[3]);
                (rgb, mie)
            }
        }
    }

    /// His `GetExtrapolatedSingleMieScattering`: the single Mie of every channel from that of
    /// the first, assuming single Mie / scattering scales like the Mie / Rayleigh coefficients.
    fn extrapolated_single_mie(&self, rgb: &[f64], alpha: f64) -> Vec<f64> {
        let a = self.a();
        if rgb[0] <= 0.0 || a.mie_scattering[0] <= 0.0 {
            return vec![0.0; rgb.len()];
        }
        rgb.iter()
            .enumerate()
            .map(|(c, v)| {
                v * alpha / rgb[0]
                    * (a.rayleigh_scattering[0] / a.mie_scattering[0])
                    * (a.mie_scattering[c] / a.rayleigh_scattering[c])
            })
            .collect()
    }

    /// His `GetSkyRadiance` (no light shafts): the sky's radiance towards `camera` from
    /// direction `view`, with the sun in direction `sun`, and the transmittance of the view ray
    /// to the top (0 when it hits the ground).
    pub fn sky_radiance(&self, camera: Vec3, view: Vec3, sun: Vec3) -> (Vec<f64>, Vec<f64>) {
        let a = self.a();
        let n = self.bundle.wavelengths_nm.len();
        let mut camera = camera;
        let mut r = length(camera);
        let mut rmu = dot(camera, view);
        let to_top = -rmu - (rmu * rmu - r * r + a.top_radius * a.top_radius).sqrt();
        if to_top > 0.0 {
            camera = [
                camera[0] + view[0] * to_top,
                camera[1] + view[1] * to_top,
                camera[2] + view[2] * to_top,
            ];
            r = a.top_radius;
            rmu += to_top;
        } else if r > a.top_radius {
            return (vec![0.0; n], vec![1.0; n]);
        }
        let mu = rmu / r;
        let mu_s = dot(camera, sun) / r;
        let nu = dot(view, sun);
        let ground = a.ray_intersects_ground(r, mu);
        let transmittance = if ground {
            vec![0.0; n]
        } else {
            self.transmittance_to_top(r, mu)
        };
        let (s, mie) = self.scattering(r, mu, mu_s, nu, ground);
        let (p_r, p_m) = (
            param::rayleigh_phase(nu),
            param::mie_phase(a.mie_phase_function_g, nu),
        );
        (
            s.iter().zip(&mie).map(|(s, m)| s * p_r + m * p_m).collect(),
            transmittance,
        )
    }

    /// His `GetSkyRadianceToPoint` (no light shafts): the radiance scattered towards `camera`
    /// between it and `point`, and the transmittance between them.
    pub fn sky_radiance_to_point(
        &self,
        camera: Vec3,
        point: Vec3,
        sun: Vec3,
    ) -> (Vec<f64>, Vec<f64>) {
        let a = self.a();
        let (camera, view, r, rmu, d) = segment_in_atmosphere(camera, point, a.top_radius);
        let mu = rmu / r;
        let mu_s = dot(camera, sun) / r;
        let nu = dot(view, sun);
        let ground = a.ray_intersects_ground(r, mu);
        let transmittance = self.transmittance(r, mu, d, ground);
        let (s, mie) = self.scattering(r, mu, mu_s, nu, ground);
        let (r_p, mu_p, mu_s_p) = a.along(r, mu, mu_s, nu, d);
        let (s_p, mie_p) = self.scattering(r_p, mu_p, mu_s_p, nu, ground);
        let s: Vec<f64> = s
            .iter()
            .zip(&s_p)
            .zip(&transmittance)
            .map(|((s, sp), t)| s - t * sp)
            .collect();
        let mie: Vec<f64> = match self.bundle.channels {
            Channels::Rgb => {
                let alpha = mie[0] - transmittance[0] * mie_p[0];
                self.extrapolated_single_mie(&s, alpha)
            }
            Channels::Spectral => mie
                .iter()
                .zip(&mie_p)
                .zip(&transmittance)
                .map(|((m, mp), t)| m - t * mp)
                .collect(),
        };
        // His guard against artefacts when the sun is below the horizon.
        let fade = smoothstep(0.0, 0.01, mu_s);
        let (p_r, p_m) = (
            param::rayleigh_phase(nu),
            param::mie_phase(a.mie_phase_function_g, nu),
        );
        (
            s.iter()
                .zip(&mie)
                .map(|(s, m)| s * p_r + m * fade * p_m)
                .collect(),
            transmittance,
        )
    }

    /// His `GetSunAndSkyIrradiance`: the sun's and the sky's irradiance on a surface at `point`
    /// with `normal` (the sky's approximated for a tilted surface), in that order.
    pub fn sun_and_sky_irradiance(
        &self,
        point: Vec3,
        normal: Vec3,
        sun: Vec3,
    ) -> (Vec<f64>, Vec<f64>) {
        let a = self.a();
        let r = length(point);
        let mu_s = dot(point, sun) / r;
        let (u, v) = a.irradiance_uv(r, mu_s);
        let tilt = (1.0 + dot(normal, point) / r) * 0.5;
        let sky: Vec<f64> = sample2(&self.bundle.irradiance, u, v)
            .into_iter()
            .map(|e| e * tilt)
            .collect();
        let cos = dot(normal, sun).max(0.0);
        let direct = self
            .transmittance_to_sun(r, mu_s)
            .iter()
            .zip(&a.solar_irradiance)
            .map(|(t, e)| e * t * cos)
            .collect();
        (direct, sky)
    }
}
