//! The fast method's preparation and final image (Nishita et al. 1996, §3.4 step 3): per-voxel light (sun
//! optical path, sky elements through the cumulative lattice paths, multiple scattering), then
//! per pixel a ray march with single scattering of the sun at every sample from the stored sun
//! path, plus the interpolated sky and multiple-scattering terms; background, ground with cloud
//! shadows, aerial perspective and shafts of light (Dobashi et al. 2000, eq 13–14) in [`Prepared::composite`].

use super::light::{
    lattice_density_integrals, sun_density_integrals, SkyElements, LATTICE, VIEW_CAP_DEG,
    VIEW_ELEMENT,
};
use super::lighting::Lighting;
use super::multiple::{MsField, Truncation};
use super::pathtracer::PathTracer;
use super::peak::PeakSpread;
use super::scene::{CloudMsMethod, FrameScene, Projection};
use super::volume::CloudVolume;
use super::{Method, RenderSettings};
use glam::DVec3;
use rayon::prelude::*;
use skybake_engine::engine::Stages;
use skybake_physics::camera::Ray;
use skybake_physics::cloud::DensityGrid;
use std::f64::consts::PI;
use std::time::Instant;

/// The sun's shadow map on the plane of the box's bottom face (Dobashi et al. 2000, §5.2.1): density
/// integral towards the sun from each point of the plane.
pub struct ShadowMap {
    pub z_m: f64,
    pub origin_xy: [f64; 2],
    pub cell_m: f64,
    pub dims: [usize; 2],
    pub d: Vec<f32>,
}

impl ShadowMap {
    fn new(vol: &CloudVolume, sun: DVec3, step_m: f64) -> Option<Self> {
        if sun.z < 0.02 {
            return None;
        }
        let z = vol.lo.z;
        // Footprint: the box's corners projected along the sun onto the plane.
        let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for c in 0..8 {
            let p = DVec3::new(
                if c & 1 == 0 { vol.lo.x } else { vol.hi.x },
                if c & 2 == 0 { vol.lo.y } else { vol.hi.y },
                if c & 4 == 0 { vol.lo.z } else { vol.hi.z },
            );
            let q = p - sun * ((p.z - z) / sun.z);
            for a in 0..2 {
                min[a] = min[a].min(q[a]);
                max[a] = max[a].max(q[a]);
            }
        }
        let h = vol.grid.voxel_size_m;
        let extent = (max[0] - min[0]).max(max[1] - min[1]);
        let cell = h.max(extent / 1024.0);
        let dims = [
            ((max[0] - min[0]) / cell).ceil() as usize + 1,
            ((max[1] - min[1]) / cell).ceil() as usize + 1,
        ];
        let mut d = vec![0f32; dims[0] * dims[1]];
        d.par_chunks_mut(dims[0]).enumerate().for_each(|(j, row)| {
            for (i, v) in row.iter_mut().enumerate() {
                let p = DVec3::new(min[0] + i as f64 * cell, min[1] + j as f64 * cell, z);
                *v = vol.density_integral(p, sun, step_m) as f32;
            }
        });
        Some(Self {
            z_m: z,
            origin_xy: min,
            cell_m: cell,
            dims,
            d,
        })
    }

    /// Density integral towards the sun from `p` below the plane (bilinear).
    fn lookup(&self, p: DVec3, sun: DVec3) -> f64 {
        let q = p + sun * ((self.z_m - p.z) / sun.z);
        let u = (q.x - self.origin_xy[0]) / self.cell_m;
        let v = (q.y - self.origin_xy[1]) / self.cell_m;
        if !(u >= 0.0
            && v >= 0.0
            && u <= (self.dims[0] - 1) as f64
            && v <= (self.dims[1] - 1) as f64)
        {
            return 0.0;
        }
        let (i0, j0) = (u.floor() as usize, v.floor() as usize);
        let (i1, j1) = (
            (i0 + 1).min(self.dims[0] - 1),
            (j0 + 1).min(self.dims[1] - 1),
        );
        let (fu, fv) = (u - i0 as f64, v - j0 as f64);
        let g = |i: usize, j: usize| self.d[j * self.dims[0] + i] as f64;
        (g(i0, j0) * (1.0 - fu) + g(i1, j0) * fu) * (1.0 - fv)
            + (g(i0, j1) * (1.0 - fu) + g(i1, j1) * fu) * fv
    }
}

/// The march stops where the scaled transmittance T* of every wavelength is below this: the rest
/// of the ray adds at most this fraction of the brightest source behind it (and the background
/// seen through the cloud, T_c ≤ T*, at most this fraction of its radiance).
pub const MARCH_CUTOFF: f64 = 1e-3;

/// Everything precomputed for one scene, camera and lighting; renders any tile.
pub struct Prepared<'a> {
    pub scene: &'a FrameScene,
    pub lighting: &'a Lighting,
    pub settings: RenderSettings,
    pub vol: CloudVolume<'a>,
    /// Per voxel: `[D_sun, S_0 … S_{n-1}]` (sun density integral, m; the source per unit scaled
    /// extinction towards the camera, S = (ω/s)·Q_sky + ω*·J*: first-order sky radiance Q_sky
    /// and the orders ≥ 2 J* of the δ-M scaled problem, W m⁻² sr⁻¹ nm⁻¹; see [`Prepared::march`]).
    pub vox: Vec<f32>,
    pub stride: usize,
    pub shadow: Option<ShadowMap>,
    pub ms: Option<MsField>,
    pub stages: Stages,
    /// Stage timings, ms.
    pub timing_ms: Vec<(String, f64)>,
    /// Work counter: lattice density-integral grids computed for sky and ground light (14 when
    /// either lights the cloud, else 0).
    pub lattice_paths: usize,
    sun_on: bool,
    /// σ_t*/σ_t per wavelength (TMS, see `multiple`).
    ms_extinction_scale: Vec<f64>,
    /// The sky elements, for the view cap that each ray adds (`None` without sky or ground light).
    sky_elements: Option<SkyElements>,
    /// The truncated peak spread over the scaled sun beam (`None` without truncation).
    peak: Option<PeakSpread>,
    /// ω·f per wavelength (the peak's share of extinction; 0 without truncation).
    peak_rate: Vec<f64>,
}

impl<'a> Prepared<'a> {
    /// Builds the per-voxel light (fast method) or only what the path tracer needs.
    pub fn new(
        scene: &'a FrameScene,
        grid: &'a DensityGrid,
        lighting: &'a Lighting,
        settings: RenderSettings,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> crate::Result<Self> {
        let n_l = scene.wavelengths.len();
        let stride = 1 + n_l;
        let mut stages = Stages::default();
        let mut timing_ms = Vec::new();
        let mut clock = Instant::now();
        let mut lap = |name: &str, timing: &mut Vec<(String, f64)>| {
            timing.push((name.to_string(), clock.elapsed().as_secs_f64() * 1e3));
            clock = Instant::now();
        };
        let vol = CloudVolume::new(grid);
        lap("volume", &mut timing_ms);
        let sun_on = lighting.sun_irradiance.iter().any(|&e| e > 0.0);
        let optics = &scene.optics;
        let sw = scene.lighting;
        // The planner's hooks: sky or ground light left out on the cloud (not the background).
        let masked = lighting.masked(settings.sky_light, settings.ground_light);
        let cloud_lighting = masked.as_ref().unwrap_or(lighting);
        let env_on = !(cloud_lighting.sky.is_zero() && cloud_lighting.below.is_zero());
        let scattering = settings.method == Method::Fast
            && vol.rho_max > 0.0
            && sw.multiple_scattering
            && optics.albedo.iter().any(|&a| a > 0.0);
        // Orders 2–3 of sunlight by the reference pattern (Nishita et al. 1996, §3.4), with the true phase
        // function and no δ-M scaling; or the all-order field.
        let pattern_on =
            scattering && scene.multiple_scattering_method == CloudMsMethod::ReferencePattern;
        let ms_on = scattering && !pattern_on && (sun_on || env_on);
        // δ-M scaling (f = g₁²) when the multiple-scattering field runs; none otherwise.
        let trunc: Vec<Truncation> = optics
            .phase
            .iter()
            .zip(&optics.albedo)
            .map(|(p, &a)| {
                let power = if ms_on {
                    settings.photons.truncation_power
                } else {
                    0.0
                };
                Truncation::new(p.mean_cosine(), a, power)
            })
            .collect();
        let ms_extinction_scale: Vec<f64> = trunc.iter().map(|t| t.extinction_scale).collect();
        let ms_albedo: Vec<f64> = trunc.iter().map(|t| t.albedo_scaled).collect();
        let peak_rate: Vec<f64> = trunc
            .iter()
            .map(|t| settings.photons.peak_spread * t.albedo * t.fraction)
            .collect();
        let peak =
            if sun_on && settings.method == Method::Fast && settings.photons.peak_spread > 0.0 {
                PeakSpread::new(&optics.phase, &trunc)
            } else {
                None
            };
        let mut vox = Vec::new();
        let mut ms = None;
        let mut lattice_paths = 0;
        let mut sky_elements = None;
        if settings.method == Method::Fast && vol.rho_max > 0.0 && settings.cloud_in_view {
            vox = vec![0f32; grid.data.len() * stride];
            // The sky element round the sun uses the sun's path too.
            if sun_on || env_on {
                let d = sun_density_integrals(grid, lighting.sun_dir);
                for (v, s) in vox.chunks_mut(stride).zip(&d) {
                    v[0] = *s;
                }
                stages.ran.push(
                    "sun optical path per voxel (cumulative, Nishita et al. 1996, §3.2)".into(),
                );
            } else {
                stages
                    .skipped
                    .push("direct sun: the sun gives no light at the cloud".into());
            }
            lap("sun_paths", &mut timing_ms);
            check(cancel)?;
            let mask = dilated_mask(grid);
            let view = |p: DVec3| -> DVec3 {
                match scene.camera.projection {
                    Projection::Orthographic { .. } => scene.camera.forward,
                    _ => (p - scene.camera.position_m).normalize_or(scene.camera.forward),
                }
            };
            if env_on {
                let truncated: Vec<f64> = trunc.iter().map(|t| t.fraction).collect();
                let elements = SkyElements::new(
                    cloud_lighting,
                    &optics.phase,
                    &truncated,
                    settings.sky_quadrature,
                    settings.sky_table[0],
                    settings.sky_table[1],
                );
                let paths: Vec<Vec<f32>> = LATTICE
                    .par_iter()
                    .map(|e| lattice_density_integrals(grid, *e))
                    .collect();
                lattice_paths = paths.len();
                check(cancel)?;
                // Scaled extinction on the paths to the sky (TMS: Nakajima & Tanaka 1988).
                let k: Vec<f64> = optics
                    .extinction_per_density_m
                    .iter()
                    .zip(&ms_extinction_scale)
                    .map(|(k, s)| k * s)
                    .collect();
                let [nx, ny, _] = grid.dims;
                vox.par_chunks_mut(nx * ny * stride)
                    .enumerate()
                    .for_each(|(z, slab)| {
                        let mut il = vec![0.0; elements.elements * n_l];
                        for (i, v) in slab.chunks_mut(stride).enumerate() {
                            let idx = z * nx * ny + i;
                            if !mask[idx] {
                                continue;
                            }
                            let p = grid.voxel_centre(i % nx, i / nx, z);
                            elements.lookup(view(p), &mut il);
                            let d_sun = v[0] as f64;
                            for l in 0..n_l {
                                let mut q = il[l] * (-k[l] * d_sun).exp();
                                for (e, path) in paths.iter().enumerate() {
                                    q += il[(e + 1) * n_l + l] * (-k[l] * path[idx] as f64).exp();
                                }
                                v[1 + l] += (optics.albedo[l] / ms_extinction_scale[l] * q) as f32;
                            }
                        }
                    });
                let what = match (
                    sw.sky_light && !cloud_lighting.sky.is_zero(),
                    sw.ground_light && !cloud_lighting.below.is_zero(),
                ) {
                    (true, true) => "sky and ground light",
                    (true, false) => "sky light",
                    _ => "ground light",
                };
                stages.ran.push(format!(
                    "{what}: {} sky elements (sun cap + 6 axes + 8 diagonals with cumulative t/t_d paths, Nishita et al. 1996, eq 7; a {VIEW_CAP_DEG}° cap round the view direction along the view ray)",
                    VIEW_ELEMENT + 1
                ));
                sky_elements = Some(elements);
            } else {
                stages
                    .skipped
                    .push("sky and ground light: none in this scene (or switched off)".into());
            }
            lap("sky_light", &mut timing_ms);
            check(cancel)?;
            if pattern_on {
                let field = super::pattern::compute(
                    scene,
                    grid,
                    cloud_lighting,
                    &settings.pattern,
                    &mask,
                    cancel,
                )?;
                for (v, q) in vox.chunks_mut(stride).zip(field.q.chunks(n_l)) {
                    for l in 0..n_l {
                        v[1 + l] += q[l];
                    }
                }
                stages.ran.push(field.describe());
                lap("reference_pattern", &mut timing_ms);
            } else if ms_on {
                let field = MsField::compute(grid, optics, cloud_lighting, &settings.photons);
                lap("multiple_scattering", &mut timing_ms);
                let [nx, ny, _] = grid.dims;
                vox.par_chunks_mut(nx * ny * stride)
                    .enumerate()
                    .for_each(|(z, slab)| {
                        let mut j = vec![0.0; n_l];
                        for (i, v) in slab.chunks_mut(stride).enumerate() {
                            if !mask[z * nx * ny + i] {
                                continue;
                            }
                            let p = grid.voxel_centre(i % nx, i / nx, z);
                            field.inscatter(p, view(p), &mut j);
                            for l in 0..n_l {
                                v[1 + l] += (ms_albedo[l] * j[l]) as f32;
                            }
                        }
                    });
                stages.ran.push(format!(
                    "multiple scattering, all orders: photon transport on a {}x{}x{} grid, {}, P{} angular reconstruction",
                    field.dims[0], field.dims[1], field.dims[2],
                    if settings.photons.truncation_power > 0.0 { "delta-M truncated forward peak with the TMS single-scattering correction" } else { "untruncated phase function" },
                    settings.photons.angular_order
                ));
                ms = Some(field);
                lap("ms_to_voxels", &mut timing_ms);
            } else {
                stages
                    .skipped
                    .push("multiple scattering: switched off, albedo 0 or no light".into());
            }
        } else if settings.method == Method::Reference {
            stages.ran.push(format!(
                "path tracer: delta tracking, ratio-tracked sun rays, all orders, {} samples per pixel",
                settings.spp
            ));
        }
        let needs_shadow = sun_on
            && vol.rho_max > 0.0
            && ((sw.cloud_shadows && lighting.ground.is_some())
                || (sw.shafts_of_light && lighting.aerial.is_some()));
        let shadow = if needs_shadow {
            ShadowMap::new(&vol, lighting.sun_dir, grid.voxel_size_m)
        } else {
            None
        };
        if shadow.is_some() {
            stages
                .ran
                .push("sun shadow map (cloud shadows, shafts of light)".into());
        }
        lap("shadow_map", &mut timing_ms);
        if lighting.aerial.is_some() {
            stages
                .ran
                .push("aerial perspective between camera and cloud".into());
            if sw.shafts_of_light && shadow.is_some() {
                stages.ran.push(
                    "shafts of light below the cloud base (Dobashi et al. 2000, eq 13-14)".into(),
                );
            }
        } else {
            stages
                .skipped
                .push("aerial perspective: vacuum or switched off".into());
        }
        if peak.is_some() {
            stages.ran.push(
                "sun single scattering with the truncated peak spread over the scaled beam (Goudsmit & Saunderson 1940)".into(),
            );
        }
        lap("peak_spread", &mut timing_ms);
        Ok(Self {
            ms_extinction_scale,
            sky_elements,
            peak,
            peak_rate,
            scene,
            lighting,
            settings,
            vol,
            vox,
            stride,
            shadow,
            ms,
            stages,
            timing_ms,
            lattice_paths,
            sun_on,
        })
    }

    /// Fast method: cloud radiance I_a, cloud transmittance T_c per wavelength and the distance
    /// of the cloud's front along the ray.
    ///
    /// The TMS method (Nakajima & Tanaka 1988, eqs 13–15) with the δ-M scaling of `multiple`:
    /// the cloud's radiance is attenuated with the scaled extinction σ_t* = σ_t(1 − ω f) along
    /// the view ray and along the paths to the sun and sky; single scattering keeps the true
    /// phase function and σ_s, multiple scattering is ω*·J*. Without multiple scattering f = 0 and
    /// this is exact single scattering. The cloud's transmittance T_c of the background uses the
    /// true extinction. Each step integrates exactly for a density constant within it.
    pub fn march(&self, ray: &Ray, ia: &mut [f64], tc: &mut [f64]) -> Option<f64> {
        ia.iter_mut().for_each(|v| *v = 0.0);
        tc.iter_mut().for_each(|v| *v = 1.0);
        if self.vox.is_empty() {
            // No per-voxel light: an empty cloud, or one the plan found outside the view.
            return None;
        }
        let mut tcs = [1.0f64; 64];
        let (t0, t1) = self.vol.interval(ray.origin_m, ray.dir)?;
        let optics = &self.scene.optics;
        let n_l = ia.len();
        let lt = self.lighting;
        let step = self.settings.step_voxels * self.vol.grid.voxel_size_m;
        let cos_sun = lt.sun_dir.dot(ray.dir);
        // Per wavelength: ω/s · E_sun · p(Θ) and the scaled and true extinctions per density.
        let mut sun_src = [0.0f64; 64];
        let mut ks = [0.0f64; 64];
        let mut kt = [0.0f64; 64];
        let mut rows = [None; 64];
        for l in 0..n_l {
            rows[l] = self.peak.as_ref().map(|p| p.row(l, cos_sun));
            let sc = self.ms_extinction_scale[l];
            sun_src[l] = if self.sun_on {
                optics.albedo[l] / sc * lt.sun_irradiance[l] * optics.phase[l].eval(cos_sun)
            } else {
                0.0
            };
            kt[l] = optics.extinction_per_density_m[l];
            ks[l] = kt[l] * sc;
        }
        let mut t = t0;
        let mut front = None;
        let (o, d) = (ray.origin_m, ray.dir);
        let data = &self.vol.grid.data;
        // The sun's density integral at the current step's start (carried from the previous
        // step's end; `None` after a skip).
        let mut d_start: Option<f64> = None;
        while t < t1 {
            let p = o + d * t;
            if let Some(skip) = self.vol.empty_skip(p, d) {
                t += skip + 1e-6 * step;
                d_start = None;
                continue;
            }
            let dt = step.min(t1 - t);
            let pm = o + d * (t + 0.5 * dt);
            let d0 = match d_start {
                Some(v) => v,
                None if self.sun_on => self.sun_path_at(p),
                None => 0.0,
            };
            t += dt;
            let d1 = if self.sun_on {
                self.sun_path_at(o + d * t)
            } else {
                0.0
            };
            d_start = Some(d1);
            let Some(w) = self.vol.weights(pm) else {
                continue;
            };
            let mut rho = 0.0;
            for (i, wi) in w {
                rho += wi * data[i] as f64;
            }
            if rho <= 0.0 {
                continue;
            }
            front.get_or_insert(t - dt);
            let mut buf = [0.0f64; 65];
            for (i, wi) in w {
                if wi == 0.0 {
                    continue;
                }
                let v = &self.vox[i * self.stride..(i + 1) * self.stride];
                for (b, x) in buf.iter_mut().zip(v) {
                    *b += wi * *x as f64;
                }
            }
            let mut alive = false;
            // Wavelengths with equal extinction (grey clouds) share their exponentials.
            let (mut a, mut a_ms, mut sun_t) = (0.0, 0.0, 0.0);
            for l in 0..n_l {
                if l == 0 || kt[l] != kt[l - 1] || ks[l] != ks[l - 1] {
                    a = -(-kt[l] * rho * dt).exp_m1();
                    a_ms = -(-ks[l] * rho * dt).exp_m1();
                    sun_t = if self.sun_on {
                        let (weight, d_eff) =
                            sun_step(ks[l] * rho, ks[l] * (d1 - d0), dt, ks[l] * d0);
                        let spread = match (&self.peak, rows[l]) {
                            (Some(p), Some(row)) => {
                                p.ratio(row, self.peak_rate[l] * kt[l] * (d0 + (d1 - d0) * d_eff))
                            }
                            _ => 1.0,
                        };
                        weight * spread
                    } else {
                        0.0
                    };
                }
                ia[l] += tcs[l] * (sun_src[l] * sun_t + a_ms * buf[1 + l]);
                tc[l] *= 1.0 - a;
                tcs[l] *= 1.0 - a_ms;
                alive |= tcs[l] > MARCH_CUTOFF;
            }
            if !alive {
                break;
            }
        }
        if front.is_some() {
            self.add_view_cap(ray.dir, ia, tc, &tcs[..n_l]);
        }
        front
    }

    /// The sun's density integral D (m) at `p`, trilinear in the per-voxel values.
    #[inline]
    fn sun_path_at(&self, p: DVec3) -> f64 {
        self.vol
            .weights(p)
            .map(|w| {
                w.iter()
                    .map(|&(i, wi)| wi * self.vox[i * self.stride] as f64)
                    .sum()
            })
            .unwrap_or(0.0)
    }

    /// The sky light from behind each point along the ray, whose path to the sky is the view
    /// ray itself (the view cap of [`SkyElements`]): a source S_cap per unit scaled extinction,
    /// the same at every point, attenuated by e^{−τ*} over the whole line through the cloud
    /// whatever the point, sums to S_cap·τ*·e^{−τ*}. The forward peak f·δ that the δ-M scaling
    /// takes out of the phase function stays in the scaled direct beam: the radiance from
    /// behind scattered only within the peak, L(d)·(e^{−τ*} − e^{−τ}) with τ* = (1 − ωf)τ
    /// (Poisson sum over the number of peak scatterings), is added here, as the background seen
    /// through the cloud keeps the true transmittance e^{−τ} (`tc`).
    fn add_view_cap(&self, d: DVec3, ia: &mut [f64], tc: &[f64], tcs: &[f64]) {
        let Some(elements) = &self.sky_elements else {
            return;
        };
        let n_l = ia.len();
        let mut cap = [0.0f64; 64];
        let mut radiance = [0.0f64; 64];
        elements.lookup_view(d, &mut cap[..n_l], &mut radiance[..n_l]);
        let albedo = &self.scene.optics.albedo;
        for l in 0..n_l {
            let t_scaled = tcs[l];
            if t_scaled <= 0.0 {
                continue;
            }
            let tau_scaled = -t_scaled.ln();
            let s_cap = albedo[l] / self.ms_extinction_scale[l] * cap[l];
            // The cap's share F − f·δ may be negative for a bright sky straight behind a
            // thick point; the sum with the peak's direct light is not.
            ia[l] =
                (ia[l] + s_cap * tau_scaled * t_scaled + radiance[l] * (t_scaled - tc[l])).max(0.0);
        }
    }

    /// Transmittance of the sun's light from the cloud to point `p` (cloud shadows, shafts).
    fn sun_visibility(&self, p: DVec3, l: usize) -> f64 {
        let k = self.scene.optics.extinction_per_density_m[l];
        match &self.shadow {
            Some(s) if p.z <= s.z_m => (-k * s.lookup(p, self.lighting.sun_dir)).exp(),
            _ => 1.0,
        }
    }

    /// Pixel radiance from the cloud terms: background or ground behind, aerial perspective and
    /// shafts in front: L = S_eff(t_a) + T(t_a)·I_a + T_c·(B − S(t_a)) (Nishita et al. 1996, eq 3 with the
    /// atmosphere between cloud and viewer; Dobashi et al. 2000, eq 14 for S_eff).
    pub fn composite(
        &self,
        ray: &Ray,
        ia: &[f64],
        tc: &[f64],
        front: Option<f64>,
        out: &mut [f64],
    ) {
        let n_l = out.len();
        let lt = self.lighting;
        let sw = self.scene.lighting;
        let (o, d) = (ray.origin_m, ray.dir);
        let mut b = vec![0.0; n_l];
        let t_ground = lt
            .ground
            .as_ref()
            .filter(|g| d.z < 0.0 && o.z > g.height_m)
            .map(|g| (g.height_m - o.z) / d.z);
        let mut ta = vec![1.0; n_l];
        let mut sa = vec![0.0; n_l];
        match (t_ground, &lt.ground) {
            (Some(tg), Some(g)) => {
                let p = o + d * tg;
                let mu_s = lt.sun_dir.z.max(0.0);
                for l in 0..n_l {
                    let vis = if sw.cloud_shadows {
                        self.sun_visibility(p, l)
                    } else {
                        1.0
                    };
                    b[l] = g.albedo[l] / PI
                        * (g.sun_normal_irradiance[l] * mu_s * vis + g.diffuse_horizontal[l]);
                }
                if let Some(a) = &lt.aerial {
                    a.eval(d, tg, &mut ta, &mut sa);
                    for l in 0..n_l {
                        b[l] = ta[l] * b[l] + sa[l];
                    }
                }
            }
            _ => lt.background(d, &mut b),
        }
        let Some(aerial) = &lt.aerial else {
            for l in 0..n_l {
                out[l] = ia[l] + tc[l] * b[l];
            }
            return;
        };
        let tx = front.or(t_ground).unwrap_or(aerial.max_distance_m());
        aerial.eval(d, tx, &mut ta, &mut sa);
        // Shafts of light: air in-scattering along the ray weighted by the sun's visibility
        // through the cloud, only below the cloud base (Dobashi et al. 2000, eq 14, γ = 1 above z_c).
        let mut s_eff = sa.clone();
        if sw.shafts_of_light && self.sun_on && self.shadow.is_some() {
            let n = self.settings.shaft_steps.max(1);
            let mut s_prev = vec![0.0; n_l];
            let mut s_next = vec![0.0; n_l];
            let mut t_tmp = vec![0.0; n_l];
            // Where the sun is visible along the whole ray (the usual case above the cloud base or
            // outside its shadow) S_eff = S: skip the table look-ups.
            let shadowed = (0..n).any(|kstep| {
                let p = o + d * (tx * (kstep as f64 + 0.5) / n as f64);
                (0..n_l).any(|l| self.sun_visibility(p, l) < 1.0)
            });
            if shadowed {
                s_eff.iter_mut().for_each(|v| *v = 0.0);
                for kstep in 0..n {
                    let t_next = tx * (kstep + 1) as f64 / n as f64;
                    let t_mid = tx * (kstep as f64 + 0.5) / n as f64;
                    aerial.eval(d, t_next, &mut t_tmp, &mut s_next);
                    let p = o + d * t_mid;
                    for l in 0..n_l {
                        s_eff[l] += self.sun_visibility(p, l) * (s_next[l] - s_prev[l]);
                    }
                    std::mem::swap(&mut s_prev, &mut s_next);
                }
            }
        }
        for l in 0..n_l {
            out[l] = s_eff[l] + ta[l] * ia[l] + tc[l] * (b[l] - sa[l]).max(0.0);
        }
    }

    /// Reference method for one pixel: `spp` path-traced samples (jittered over the pixel),
    /// composited like the fast method; returns the mean and the variance of the mean.
    pub fn path_trace_pixel(
        &self,
        pt: &PathTracer,
        x: usize,
        y: usize,
        out: &mut [f64],
        var: &mut [f64],
    ) {
        let n_l = out.len();
        let spp = self.settings.spp.max(1);
        let mut rng = pt.rng(x, y, 0);
        let mut sum = vec![0.0; n_l];
        let mut sum2 = vec![0.0; n_l];
        let mut px = vec![0.0; n_l];
        let centre = super::camera::primary_ray(&self.scene.camera, x as f64 + 0.5, y as f64 + 0.5);
        let front = centre.as_ref().and_then(|r| {
            self.vol
                .first_occupied(r.origin_m, r.dir, 0.5 * self.vol.grid.voxel_size_m)
        });
        for _ in 0..spp {
            use rand::Rng;
            let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
            let Some(ray) =
                super::camera::primary_ray(&self.scene.camera, x as f64 + jx, y as f64 + jy)
            else {
                continue;
            };
            let s = pt.sample(&ray, &mut rng);
            // Composite each sample so the variance covers the background term too.
            self.composite(&ray, &s.radiance, &s.transmitted, front, &mut px);
            for l in 0..n_l {
                sum[l] += px[l];
                sum2[l] += px[l] * px[l];
            }
        }
        let n = spp as f64;
        for l in 0..n_l {
            out[l] = sum[l] / n;
            var[l] = ((sum2[l] / n - out[l] * out[l]).max(0.0)) / (n - 1.0).max(1.0);
        }
    }
}

/// One step's weight of the sun's single scattering, for a density constant over the step and
/// an optical depth towards the sun linear along it: with a = σ_t* (view attenuation rate) and
/// b = dτ*_sun/ds, ∫₀^Δ a e^{−a u} e^{−b u} du = a/(a + b)·(1 − e^{−(a + b)Δ}), relative to the
/// times the sun's transmittance e^{−τ₀} at the step's start (exact, where the midpoint rule fails for steps of
/// many optical depths: a lit surface inside a thick voxel). Also the mean of u/Δ under the
/// weight (where the scattering happens, for the peak spread's depth).
#[inline]
fn sun_step(a: f64, b_total: f64, dt: f64, tau0: f64) -> (f64, f64) {
    let x = a * dt + b_total;
    if x.abs() < 1e-6 {
        return ((-tau0).exp() * a * dt * (1.0 - 0.5 * x), 0.5 - x / 12.0);
    }
    // e^{−τ₀}·(1 − e^{−x})/x, written so neither factor overflows (τ₀ + x ≥ 0).
    let weight = a
        * dt
        * if x > 0.0 {
            (-tau0).exp() * (-(-x).exp_m1()) / x
        } else {
            (-tau0 - x).exp() * x.exp_m1() / x
        };
    // Mean of u/Δ under e^{−x u/Δ} on [0, 1]: 1/x − 1/(e^x − 1).
    let mean = if x > 700.0 {
        1.0 / x
    } else {
        1.0 / x - 1.0 / x.exp_m1()
    };
    (weight, mean.clamp(0.0, 1.0))
}

fn check(cancel: &(dyn Fn() -> bool + Sync)) -> crate::Result<()> {
    if cancel() {
        Err(crate::Error::Cancelled)
    } else {
        Ok(())
    }
}

/// Voxels whose 3×3×3 neighbourhood holds any density (where per-voxel light is needed).
fn dilated_mask(grid: &DensityGrid) -> Vec<bool> {
    let [nx, ny, nz] = grid.dims;
    let mut m = vec![false; grid.data.len()];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                if grid.at(x, y, z) <= 0.0 {
                    continue;
                }
                for zz in z.saturating_sub(1)..=(z + 1).min(nz - 1) {
                    for yy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                        for xx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                            m[grid.index(xx, yy, zz)] = true;
                        }
                    }
                }
            }
        }
    }
    m
}
