//! The light a frame receives from outside the cloud, gathered once (the renderer itself is pure):
//! the sun's transmitted irradiance at the cloud, sky radiance over the upper hemisphere (seed
//! 000 §3.5: the `sky` product at the cloud's altitude, a constant, or none), upward radiance from
//! below (the `ground` product, Nishita et al.'s (1996) "upward sky light"), the ground plane seen by the
//! camera, the sky behind the clouds seen from the camera, and the `aerial` product between
//! camera and cloud. [`Lighting::from_scene`] builds it from the public engine API, or without
//! any atmosphere for vacuum scenes.

use super::scene::{direction_from_deg, FrameScene, SkySpec};
use crate::Result;
use glam::DVec3;
use skybake_engine::engine::{AerialProduct, DomeShape, Engine};
use skybake_engine::spec::{CommonSpec, Quality, SunPosition};
use skybake_physics::atmosphere::sky::{DomeTable, MsMethod};
use std::f64::consts::PI;
use std::sync::Arc;

/// Radiance over view elevation × azimuth relative to the sun (0…180°, symmetric), bilinear.
#[derive(Debug, Clone, PartialEq)]
pub struct DirTable {
    pub elevation_deg: Vec<f64>,
    pub azimuth_deg: Vec<f64>,
    /// `[row][col][λ]`, W m⁻² sr⁻¹ nm⁻¹.
    pub radiance: Vec<f32>,
    pub n_l: usize,
    /// Sun azimuth in the world frame (from +y towards +x), degrees.
    pub sun_azimuth_deg: f64,
}

/// Index and fraction of `x` on an increasing axis (clamped to its ends).
pub fn axis_lookup(axis: &[f64], x: f64) -> (usize, usize, f64) {
    let n = axis.len();
    if n == 1 || x <= axis[0] {
        return (0, 0, 0.0);
    }
    if x >= axis[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    let hi = axis.partition_point(|&a| a <= x).clamp(1, n - 1);
    let lo = hi - 1;
    let f = (x - axis[lo]) / (axis[hi] - axis[lo]).max(1e-300);
    (lo, hi, f)
}

/// [`axis_lookup`] (the same result) for `x` at or above the previous look-up's on the same
/// sorted axis: the search goes on from `hint`, which it updates (0 to start).
pub fn axis_lookup_from(axis: &[f64], x: f64, hint: &mut usize) -> (usize, usize, f64) {
    let n = axis.len();
    if n == 1 || x <= axis[0] {
        return (0, 0, 0.0);
    }
    if x >= axis[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    // The first node above x, as `partition_point` finds it.
    let mut hi = (*hint).max(1);
    if hi > n - 1 || axis[hi - 1] > x {
        hi = axis.partition_point(|&a| a <= x);
    } else {
        while hi < n && axis[hi] <= x {
            hi += 1;
        }
    }
    *hint = hi;
    let hi = hi.clamp(1, n - 1);
    let lo = hi - 1;
    let f = (x - axis[lo]) / (axis[hi] - axis[lo]).max(1e-300);
    (lo, hi, f)
}

/// Elevation and azimuth (from +y towards +x) of a unit direction, degrees.
pub fn elevation_azimuth_deg(dir: DVec3) -> (f64, f64) {
    let e = dir.z.clamp(-1.0, 1.0).asin().to_degrees();
    let a = dir.x.atan2(dir.y).to_degrees();
    (e, a)
}

impl DirTable {
    /// From an engine dome table (azimuth relative to the sun).
    pub fn from_dome(t: &DomeTable, sun_azimuth_deg: f64) -> Self {
        Self {
            elevation_deg: t.elevation_deg.clone(),
            azimuth_deg: t.azimuth_deg.clone(),
            radiance: t.radiance.clone(),
            n_l: t.wavelengths_nm.len(),
            sun_azimuth_deg,
        }
    }

    /// The 4 nodes round a direction of [`elevation_azimuth_deg`] `(e, a)` and their weights.
    #[inline]
    fn cell_at(&self, (e, a): (f64, f64)) -> [(usize, f64); 4] {
        let rel = (a - self.sun_azimuth_deg).rem_euclid(360.0);
        let rel = if rel > 180.0 { 360.0 - rel } else { rel };
        let (r0, r1, fr) = axis_lookup(&self.elevation_deg, e);
        let (c0, c1, fc) = axis_lookup(&self.azimuth_deg, rel);
        let na = self.azimuth_deg.len();
        [
            (r0 * na + c0, (1.0 - fr) * (1.0 - fc)),
            (r0 * na + c1, (1.0 - fr) * fc),
            (r1 * na + c0, fr * (1.0 - fc)),
            (r1 * na + c1, fr * fc),
        ]
    }

    /// Radiance arriving from direction `dir` (unit, pointing away from the observer).
    pub fn eval(&self, dir: DVec3, out: &mut [f64]) {
        self.eval_at(elevation_azimuth_deg(dir), out)
    }

    /// [`Self::eval`] from the direction's [`elevation_azimuth_deg`] (the same values).
    pub fn eval_at(&self, angles: (f64, f64), out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        for (idx, w) in self.cell_at(angles) {
            let base = idx * self.n_l;
            for (l, o) in out.iter_mut().enumerate() {
                *o += w * self.radiance[base + l] as f64;
            }
        }
    }
}

/// Radiance over one hemisphere of incoming directions.
#[derive(Debug, Clone, PartialEq)]
pub enum Hemisphere {
    Zero,
    /// The same radiance in every direction of the hemisphere, per wavelength.
    Constant(Vec<f64>),
    Table(Arc<DirTable>),
}

impl Hemisphere {
    fn eval(&self, dir: DVec3, out: &mut [f64]) {
        match self {
            Hemisphere::Zero => out.iter_mut().for_each(|o| *o = 0.0),
            Hemisphere::Constant(v) => out.copy_from_slice(v),
            Hemisphere::Table(t) => t.eval(dir, out),
        }
    }

    /// [`Self::eval`] with the direction's [`elevation_azimuth_deg`] known (the same values).
    fn eval_at(&self, angles: (f64, f64), out: &mut [f64]) {
        match self {
            Hemisphere::Zero => out.iter_mut().for_each(|o| *o = 0.0),
            Hemisphere::Constant(v) => out.copy_from_slice(v),
            Hemisphere::Table(t) => t.eval_at(angles, out),
        }
    }

    pub fn is_zero(&self) -> bool {
        match self {
            Hemisphere::Zero => true,
            Hemisphere::Constant(v) => v.iter().all(|&x| x == 0.0),
            Hemisphere::Table(t) => t.radiance.iter().all(|&x| x == 0.0),
        }
    }
}

/// The Lambertian ground plane as the camera sees it and as the path tracer reflects on it.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundSurface {
    pub height_m: f64,
    pub albedo: Vec<f64>,
    /// Sun irradiance normal to the beam at the ground, W m⁻² nm⁻¹.
    pub sun_normal_irradiance: Vec<f64>,
    /// Sky irradiance on the horizontal ground (clouds not included), W m⁻² nm⁻¹.
    pub diffuse_horizontal: Vec<f64>,
    /// The path tracer bounces light off this plane (vacuum scenes); with an atmosphere the
    /// light from below the cloud is the `ground` product instead.
    pub explicit: bool,
}

/// An [`AerialTable`]'s elevation and azimuth nodes and weights for one direction.
#[derive(Debug, Clone, Copy)]
pub struct AerialDirection {
    elevation: (usize, usize, f64),
    azimuth: (usize, usize, f64),
}

/// Aerial perspective from the camera: transmittance and in-scattered radiance against distance.
#[derive(Debug, Clone, PartialEq)]
pub struct AerialTable {
    pub product: AerialProduct,
    pub sun_azimuth_deg: f64,
}

impl AerialTable {
    /// Transmittance and in-scattered radiance from the camera to `distance_m` along `dir`.
    pub fn eval(&self, dir: DVec3, distance_m: f64, t_out: &mut [f64], s_out: &mut [f64]) {
        self.eval_along(&self.direction(dir), distance_m, t_out, s_out);
    }

    /// The table's nodes and weights for direction `dir` (what [`Self::eval`] computes once per
    /// direction: a ray looks up several distances along the same direction).
    pub fn direction(&self, dir: DVec3) -> AerialDirection {
        self.direction_at(elevation_azimuth_deg(dir))
    }

    /// [`Self::direction`] from the direction's [`elevation_azimuth_deg`] (the same nodes).
    pub fn direction_at(&self, (e, a): (f64, f64)) -> AerialDirection {
        let p = &self.product;
        let rel = (a - self.sun_azimuth_deg).rem_euclid(360.0);
        let rel = if rel > 180.0 { 360.0 - rel } else { rel };
        AerialDirection {
            elevation: axis_lookup(&p.elevation_deg, e),
            azimuth: axis_lookup(&p.azimuth_deg, rel),
        }
    }

    /// [`Self::eval`] along a direction from [`Self::direction`] (the same values).
    pub fn eval_along(
        &self,
        dir: &AerialDirection,
        distance_m: f64,
        t_out: &mut [f64],
        s_out: &mut [f64],
    ) {
        let node = axis_lookup(&self.product.distance_m, distance_m);
        self.eval_nodes(dir, node, t_out, s_out);
    }

    /// [`Self::eval_along`] for distances that do not decrease from one call to the next
    /// (`hint`: 0 at the first), the same values.
    pub fn eval_along_from(
        &self,
        dir: &AerialDirection,
        distance_m: f64,
        hint: &mut usize,
        t_out: &mut [f64],
        s_out: &mut [f64],
    ) {
        let node = axis_lookup_from(&self.product.distance_m, distance_m, hint);
        self.eval_nodes(dir, node, t_out, s_out);
    }

    /// The in-scattered radiance alone of [`Self::eval_along_from`] (the same values: the same
    /// operations, without the transmittance's), for the shafts of light, which use only it.
    #[inline]
    pub fn inscatter_along_from(
        &self,
        dir: &AerialDirection,
        distance_m: f64,
        hint: &mut usize,
        s_out: &mut [f64],
    ) {
        let node = axis_lookup_from(&self.product.distance_m, distance_m, hint);
        let (p, n_l) = (&self.product, self.product.wavelengths_nm.len());
        s_out.iter_mut().for_each(|v| *v = 0.0);
        self.for_corners(dir, node, |base, w| {
            for l in 0..n_l {
                s_out[l] += w * p.inscatter[base + l] as f64;
            }
        });
    }

    fn eval_nodes(
        &self,
        dir: &AerialDirection,
        node: (usize, usize, f64),
        t_out: &mut [f64],
        s_out: &mut [f64],
    ) {
        let (p, n_l) = (&self.product, self.product.wavelengths_nm.len());
        t_out.iter_mut().for_each(|v| *v = 0.0);
        s_out.iter_mut().for_each(|v| *v = 0.0);
        self.for_corners(dir, node, |base, w| {
            for l in 0..n_l {
                t_out[l] += w * p.transmittance[base + l] as f64;
                s_out[l] += w * p.inscatter[base + l] as f64;
            }
        });
    }

    /// Calls `f` with each trilinear corner (elevation, azimuth, distance) of a look-up that
    /// has a non-zero weight: the corner's first index into the per-wavelength arrays and its
    /// weight.
    #[inline(always)]
    fn for_corners(
        &self,
        dir: &AerialDirection,
        (d0, d1, fd): (usize, usize, f64),
        mut f: impl FnMut(usize, f64),
    ) {
        let p = &self.product;
        let n_l = p.wavelengths_nm.len();
        let (r0, r1, fr) = dir.elevation;
        let (c0, c1, fc) = dir.azimuth;
        let (na, nd) = (p.azimuth_deg.len(), p.distance_m.len());
        for (r, wr) in [(r0, 1.0 - fr), (r1, fr)] {
            for (c, wc) in [(c0, 1.0 - fc), (c1, fc)] {
                for (d, wd) in [(d0, 1.0 - fd), (d1, fd)] {
                    let w = wr * wc * wd;
                    if w != 0.0 {
                        f(((r * na + c) * nd + d) * n_l, w);
                    }
                }
            }
        }
    }

    /// Largest distance in the table, m.
    pub fn max_distance_m(&self) -> f64 {
        self.product.distance_m.last().copied().unwrap_or(0.0)
    }
}

/// Everything outside the cloud that lights it or is seen around it.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    pub wavelengths_nm: Vec<f64>,
    /// Unit vector towards the sun.
    pub sun_dir: DVec3,
    /// Sun irradiance normal to the beam at the cloud, W m⁻² nm⁻¹ (0 below the horizon).
    pub sun_irradiance: Vec<f64>,
    /// Radiance arriving at the cloud from above the horizontal.
    pub sky: Hemisphere,
    /// Radiance arriving at the cloud from below the horizontal (ground light).
    pub below: Hemisphere,
    /// The ground plane, if any.
    pub ground: Option<GroundSurface>,
    /// Radiance seen by the camera where no cloud or ground is (`None`: `sky` / `below`).
    pub background: Option<Arc<DirTable>>,
    /// Aerial perspective from the camera (`None` in vacuum or when switched off).
    pub aerial: Option<Arc<AerialTable>>,
    /// Which engine products were used, and the stages they ran.
    pub notes: Vec<String>,
}

impl Lighting {
    /// This lighting without the sky light (`sky` false) and/or the ground light (`ground`
    /// false) on the cloud, for the planner's rules; `None` when both stay.
    pub fn masked(&self, sky: bool, ground: bool) -> Option<Self> {
        if sky && ground {
            return None;
        }
        let mut l = self.clone();
        if !sky {
            l.sky = Hemisphere::Zero;
        }
        if !ground {
            l.below = Hemisphere::Zero;
        }
        Some(l)
    }

    /// Radiance arriving at the cloud from direction `dir` (sky above, ground light below).
    pub fn env(&self, dir: DVec3, out: &mut [f64]) {
        if dir.z >= 0.0 {
            self.sky.eval(dir, out)
        } else {
            self.below.eval(dir, out)
        }
    }

    /// Radiance the camera sees along `dir` where nothing else is hit.
    pub fn background(&self, dir: DVec3, out: &mut [f64]) {
        match &self.background {
            Some(t) => t.eval(dir, out),
            None => self.env(dir, out),
        }
    }

    /// [`Self::background`] with the direction's [`elevation_azimuth_deg`] known (the same
    /// values; the compositing has them from the aerial table's look-up).
    pub fn background_at(&self, dir: DVec3, angles: (f64, f64), out: &mut [f64]) {
        match &self.background {
            Some(t) => t.eval_at(angles, out),
            None if dir.z >= 0.0 => self.sky.eval_at(angles, out),
            None => self.below.eval_at(angles, out),
        }
    }

    /// Lighting for a scene: vacuum scenes need no engine; scenes with an atmosphere call the
    /// engine's `sun`, `sky`, `ground` and `aerial` products. `cloud_altitude_m` is the height of
    /// the cloud's centre, `max_view_distance_m` the farthest distance the camera needs aerial
    /// perspective for.
    pub fn from_scene(
        scene: &FrameScene,
        engine: &Engine,
        cloud_altitude_m: f64,
        max_view_distance_m: f64,
    ) -> Result<Self> {
        Self::from_scene_unless(
            scene,
            engine,
            cloud_altitude_m,
            max_view_distance_m,
            &|| false,
        )
    }

    /// [`Self::from_scene`], stopped with [`crate::Error::Cancelled`] once `cancelled` returns
    /// true (the engine asks between table rows, orders and dome rows).
    pub fn from_scene_unless(
        scene: &FrameScene,
        engine: &Engine,
        cloud_altitude_m: f64,
        max_view_distance_m: f64,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<Self> {
        let wl = scene.wavelengths.as_nm().to_vec();
        let n_l = wl.len();
        let sun_dir = scene.sun.direction();
        let sw = scene.lighting;
        let mut notes = Vec::new();
        let Some(atmosphere) = &scene.atmosphere else {
            // Vacuum: a collimated beam (or, for a sun given by direction, unit irradiance).
            let sun_irradiance = scene
                .sun
                .collimated_irradiance
                .clone()
                .unwrap_or_else(|| vec![1.0; n_l]);
            let sky_l = match &scene.sky {
                SkySpec::Constant(v) => v.clone(),
                _ => vec![0.0; n_l],
            };
            let sky = if sw.sky_light && sky_l.iter().any(|&v| v > 0.0) {
                Hemisphere::Constant(sky_l.clone())
            } else {
                Hemisphere::Zero
            };
            let mu_s = sun_dir.z.max(0.0);
            let ground = scene.ground.as_ref().map(|g| GroundSurface {
                height_m: g.height_m,
                albedo: g.albedo.clone(),
                sun_normal_irradiance: sun_irradiance.clone(),
                diffuse_horizontal: sky_l.iter().map(|l| PI * l).collect(),
                explicit: true,
            });
            // Nishita et al. 1996, §3.5: the ground seen from the cloud as upward light of uniform radiance
            // a/π·(E_sun μ_s + E_sky) (the ground's shadowing by the cloud is not in this term).
            let below = match (&ground, sw.ground_light) {
                (Some(g), true) => Hemisphere::Constant(
                    (0..n_l)
                        .map(|l| {
                            g.albedo[l] / PI * (sun_irradiance[l] * mu_s + g.diffuse_horizontal[l])
                        })
                        .collect(),
                ),
                _ => Hemisphere::Zero,
            };
            notes.push("vacuum: no atmospheric attenuation, no aerial perspective".into());
            return Ok(Self {
                wavelengths_nm: wl,
                sun_dir,
                sun_irradiance,
                sky,
                below,
                ground,
                background: None,
                aerial: None,
                notes,
            });
        };
        // The atmosphere's light: the precise tables, at the coarse preset a retired `fast`
        // atmosphere request runs at (`skybake_engine::plan::fast_preset`: draft in clear air,
        // standard in haze) for draft and standard frames, at the frame's own preset above.
        let (method, atmosphere_quality) = match scene.quality {
            Quality::Draft | Quality::Standard => (
                MsMethod::Precise,
                skybake_engine::plan::fast_preset(atmosphere),
            ),
            q @ (Quality::High | Quality::Reference) => (MsMethod::Precise, q),
        };
        let ground_albedo = scene
            .ground
            .as_ref()
            .map(|g| g.albedo.iter().sum::<f64>() / n_l as f64)
            .unwrap_or(0.0);
        let spec_at = |altitude_m: f64| CommonSpec {
            atmosphere: atmosphere.clone(),
            wavelengths_nm: scene.wavelengths.clone(),
            sun: SunPosition {
                sun_elevation_deg: scene.sun.elevation_deg,
                from_location: None,
            },
            observer_altitude_m: altitude_m.clamp(0.0, 1e6),
            ground_albedo: Some(ground_albedo),
            method,
            quality: atmosphere_quality,
        };
        let az = scene.sun.azimuth_deg;
        let cloud_spec = spec_at(cloud_altitude_m);
        let sun_irradiance = match &scene.sun.collimated_irradiance {
            Some(e) => e.clone(),
            None => {
                engine
                    .sun_unless(&cloud_spec, cancelled)?
                    .direct_normal_irradiance_w_m2_nm
            }
        };
        let shape = DomeShape {
            elevation_count: 33,
            azimuth_count: 19,
        };
        let sky = match (&scene.sky, sw.sky_light) {
            (SkySpec::Atmosphere, true) => {
                let t = engine.sky_unless(&cloud_spec, shape, &[], cancelled)?;
                notes.push(format!(
                    "sky product at {:.0} m",
                    cloud_spec.observer_altitude_m
                ));
                Hemisphere::Table(Arc::new(DirTable::from_dome(&t.table, az)))
            }
            (SkySpec::Constant(v), true) => Hemisphere::Constant(v.clone()),
            _ => Hemisphere::Zero,
        };
        let below = if sw.ground_light && !matches!(scene.sky, SkySpec::None) {
            let t = engine.ground_unless(&cloud_spec, shape, &[], cancelled)?;
            notes.push(format!(
                "ground product at {:.0} m",
                cloud_spec.observer_altitude_m
            ));
            Hemisphere::Table(Arc::new(DirTable::from_dome(&t.table, az)))
        } else {
            Hemisphere::Zero
        };
        let ground = match &scene.ground {
            Some(g) => {
                let s = engine.sun_unless(&spec_at(g.height_m), cancelled)?;
                Some(GroundSurface {
                    height_m: g.height_m,
                    albedo: g.albedo.clone(),
                    sun_normal_irradiance: s.direct_normal_irradiance_w_m2_nm,
                    diffuse_horizontal: s.diffuse_horizontal_irradiance_w_m2_nm,
                    explicit: false,
                })
            }
            None => None,
        };
        let cam_spec = spec_at(scene.camera.position_m.z);
        let background = if matches!(scene.sky, SkySpec::Atmosphere) {
            let t = engine.sky_unless(
                &cam_spec,
                DomeShape {
                    elevation_count: 65,
                    azimuth_count: 33,
                },
                &[],
                cancelled,
            )?;
            Some(Arc::new(DirTable::from_dome(&t.table, az)))
        } else {
            None
        };
        let aerial = if sw.aerial_perspective {
            let a = engine.aerial_unless(
                &cam_spec,
                DomeShape {
                    elevation_count: 33,
                    azimuth_count: 13,
                },
                32,
                max_view_distance_m.clamp(100.0, 400_000.0),
                cancelled,
            )?;
            notes.push(format!(
                "aerial product from the camera to {:.0} m",
                max_view_distance_m.clamp(100.0, 400_000.0)
            ));
            Some(Arc::new(AerialTable {
                product: a,
                sun_azimuth_deg: az,
            }))
        } else {
            None
        };
        Ok(Self {
            wavelengths_nm: wl,
            sun_dir: direction_from_deg(scene.sun.elevation_deg, az),
            sun_irradiance,
            sky,
            below,
            ground,
            background,
            aerial,
            notes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The search from a hint finds what the binary search finds, for rising values (the
    /// shafts' distances along a ray), below, between, on and above the nodes, and for a hint
    /// past the value (it starts again).
    #[test]
    fn axis_lookup_from_matches_axis_lookup() {
        let axis = [0.0, 10.0, 25.0, 25.0, 60.0, 100.0, 400.0];
        let mut hint = 0;
        let mut x = -5.0;
        while x < 450.0 {
            assert_eq!(
                axis_lookup_from(&axis, x, &mut hint),
                axis_lookup(&axis, x),
                "x {x}"
            );
            x += 2.5;
        }
        let mut late = 6;
        assert_eq!(
            axis_lookup_from(&axis, 12.0, &mut late),
            axis_lookup(&axis, 12.0)
        );
        assert_eq!(axis_lookup_from(&[5.0], 7.0, &mut 0), (0, 0, 0.0));
    }
}
