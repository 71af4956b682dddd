//! The frame scene: what a lit cloud frame needs besides the density grid (the scene contract;
//! README.md "Cloud frames").
//!
//! World frame: metres, right-handed, **z up**; z is the altitude above sea level. Azimuths are
//! measured from +y ("north") towards +x ("east"), so a direction with elevation e and azimuth a
//! is `(sin a·cos e, cos a·cos e, sin e)`; the sun direction points from the scene towards the sun.
//!
//! ```json
//! {"name": "cumulus-noon",
//!  "cloud": {"voxel_size_m": 20, "source": {"type": "metaballs", "balls": [...]}},
//!  "optics": {"extinction_per_density_m": 0.05, "single_scattering_albedo": 1.0,
//!             "phase": {"henyey_greenstein": {"g": 0.85}}},
//!  "camera": {"type": "pinhole", "position_m": [0, -4000, 1000], "look_at_m": [0, 0, 1500],
//!             "up": [0, 0, 1], "fov_deg": 45, "fov_axis": "horizontal", "width": 640, "height": 480},
//!  "sun": {"elevation_deg": 30, "azimuth_deg": 135},
//!  "atmosphere": "earth", "sky": "atmosphere", "ground": {"albedo": 0.3, "height_m": 0},
//!  "wavelengths_nm": [440, 550, 680], "quality": "standard",
//!  "lighting": {"sky_light": true, "ground_light": true, "aerial_perspective": true,
//!               "shafts_of_light": true, "cloud_shadows": true, "multiple_scattering": true},
//!  "multiple_scattering_method": "all_orders"}
//! ```
//!
//! `multiple_scattering_method` picks the fast method's multiple scattering: `"all_orders"` (the
//! photon-transport field) or `"reference_pattern"` (orders 2 and 3 of sunlight by Nishita et al. 1996,
//! §3.4, for thin clouds; `render::pattern`).
//!
//! Every value is checked here, before anything is allocated; errors name the field (dotted
//! path, e.g. `optics.phase.g`) and its allowed range.

use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use skybake_physics::atmosphere::params::AtmosphereParams;
use skybake_physics::atmosphere::presets;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::scene::{CloudSection, MAX_SCENE_FILE_BYTES};
use skybake_physics::phase::Phase;
use skybake_physics::spectrum::Wavelengths;
use std::collections::BTreeMap;

/// How the fast method computes the cloud's multiple scattering (scene field
/// `multiple_scattering_method`). Not the atmosphere's multiple-scattering method
/// (`skybake_physics::atmosphere::sky::MsMethod`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CloudMsMethod {
    /// All orders from the photon-transport field (`render::multiple`).
    #[default]
    AllOrders,
    /// Orders 2 and 3 of the sun's light by the reference pattern of Nishita et al. 1996, §3.4
    /// (`render::pattern`).
    ReferencePattern,
}

/// Largest image, pixels.
pub const MAX_PIXELS: usize = 16_777_216;
/// Largest image in samples (pixels × wavelengths): 64 Mi f32 values, 256 MiB.
pub const MAX_FRAME_SAMPLES: usize = 64 << 20;
/// Largest |g| accepted: (−1, 1) open, kept 0.001 from the delta limit where sampling degenerates.
pub const MAX_ABS_G: f64 = 0.999;

/// A value that is either one number for all wavelengths or a table `{"440": v, "550": v}` (nm →
/// value), interpolated linearly and held constant beyond its ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Spectral {
    Constant(f64),
    Table(BTreeMap<String, f64>),
}

impl Spectral {
    /// The value at each wavelength, each checked to lie in `[lo, hi]` (named `field`).
    pub fn resolve(
        &self,
        field: &str,
        wavelengths_nm: &[f64],
        lo: f64,
        hi: f64,
    ) -> Result<Vec<f64>> {
        let check = |v: f64| -> Result<f64> {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(v)
            } else {
                Err(Error::out_of_range(field, v, format!("{lo} to {hi}")))
            }
        };
        match self {
            Spectral::Constant(v) => {
                check(*v)?;
                Ok(vec![*v; wavelengths_nm.len()])
            }
            Spectral::Table(t) => {
                if t.is_empty() || t.len() > 1000 {
                    return Err(Error::invalid(
                        field,
                        "a wavelength table needs 1 to 1000 entries",
                    ));
                }
                let mut pts = Vec::with_capacity(t.len());
                for (k, v) in t {
                    let nm: f64 = k.trim().parse().map_err(|_| {
                        Error::invalid(field, format!("table key '{k}' is not a wavelength in nm"))
                    })?;
                    if !(nm.is_finite() && nm > 0.0) {
                        return Err(Error::invalid(
                            field,
                            format!("table key '{k}' is not a wavelength in nm"),
                        ));
                    }
                    pts.push((nm, check(*v)?));
                }
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                Ok(wavelengths_nm
                    .iter()
                    .map(|&w| interpolate(&pts, w))
                    .collect())
            }
        }
    }
}

fn interpolate(pts: &[(f64, f64)], x: f64) -> f64 {
    if x <= pts[0].0 {
        return pts[0].1;
    }
    for w in pts.windows(2) {
        if x <= w[1].0 {
            let f = (x - w[0].0) / (w[1].0 - w[0].0).max(1e-300);
            return w[0].1 + f * (w[1].1 - w[0].1);
        }
    }
    pts[pts.len() - 1].1
}

/// Cloud optics: extinction per unit density, single-scattering albedo, phase function.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpticsJson {
    /// σ_t = value · density, m⁻¹, in [0, 1000]: number or wavelength table.
    pub extinction_per_density_m: Spectral,
    /// In [0, 1]: number or wavelength table [1].
    #[serde(default = "one")]
    pub single_scattering_albedo: Spectral,
    /// Phase function [Henyey-Greenstein, g = 0.85].
    #[serde(default = "default_phase")]
    pub phase: PhaseJson,
}

fn one() -> Spectral {
    Spectral::Constant(1.0)
}

fn default_phase() -> PhaseJson {
    PhaseJson::HenyeyGreenstein {
        g: Spectral::Constant(0.85),
    }
}

/// `{"henyey_greenstein": {"g"}}`, `{"cornette_shanks": {"g"}}` (Nishita et al. 1996, eq 5) or
/// `{"mixture": {"g", "rayleigh_fraction"}}` (Nishita et al. 1996, eq 4: (1 − f)·CS(g) + f·Rayleigh).
/// `g` in (−1, 1) (|g| ≤ 0.999), number or wavelength table; `rayleigh_fraction` in [0, 1].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum PhaseJson {
    HenyeyGreenstein { g: Spectral },
    CornetteShanks { g: Spectral },
    Mixture { g: Spectral, rayleigh_fraction: f64 },
}

/// Field-of-view axis of a pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FovAxis {
    #[default]
    Horizontal,
    Vertical,
}

/// The camera, tagged by `"type"`. Pixel (0, 0) is the top-left; pixel centres at (i + ½, j + ½).
/// `width`, `height` in 1..=16384, width·height ≤ 16 Mi pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum CameraJson {
    /// Perspective: `fov_deg` in (0, 179] spans `fov_axis` [horizontal].
    Pinhole {
        position_m: [f64; 3],
        look_at_m: [f64; 3],
        #[serde(default = "z_up")]
        up: [f64; 3],
        fov_deg: f64,
        #[serde(default)]
        fov_axis: FovAxis,
        width: usize,
        height: usize,
    },
    /// Parallel projection: `view_width_m` (> 0) spans the image width.
    Orthographic {
        position_m: [f64; 3],
        look_at_m: [f64; 3],
        #[serde(default = "z_up")]
        up: [f64; 3],
        view_width_m: f64,
        width: usize,
        height: usize,
    },
    /// Equidistant fisheye: the angle from the view axis is proportional to the distance from the
    /// image centre; `fov_deg` in (0, 360] spans the smaller image side. Pixels outside the circle
    /// are black.
    Fisheye {
        position_m: [f64; 3],
        look_at_m: [f64; 3],
        #[serde(default = "z_up")]
        up: [f64; 3],
        fov_deg: f64,
        width: usize,
        height: usize,
    },
}

fn z_up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

/// The sun: a direction, a place and time, or a collimated beam of given normal irradiance
/// (no atmospheric attenuation applied).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SunJson {
    Collimated {
        collimated: CollimatedSun,
    },
    Direction {
        elevation_deg: f64,
        azimuth_deg: f64,
    },
    Place {
        latitude_deg: f64,
        longitude_deg: f64,
        time: String,
    },
}

/// A collimated beam.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollimatedSun {
    /// Elevation in [−90, 90] degrees.
    pub elevation_deg: f64,
    /// Azimuth from +y towards +x, degrees (any finite value).
    pub azimuth_deg: f64,
    /// Irradiance on a surface normal to the beam, W m⁻² nm⁻¹, in [0, 1e6]: number or table.
    pub normal_irradiance_w_m2_nm: Spectral,
}

/// Lambertian ground plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundJson {
    /// In [0, 1]: number or wavelength table [0.3].
    #[serde(default = "default_albedo")]
    pub albedo: Spectral,
    /// Height of the plane above sea level, m, in [−500, 10 000] [0].
    #[serde(default)]
    pub height_m: f64,
}

fn default_albedo() -> Spectral {
    Spectral::Constant(0.3)
}

/// Switches for the parts of the lighting (all default true).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightingSwitches {
    pub sky_light: bool,
    pub ground_light: bool,
    pub aerial_perspective: bool,
    pub shafts_of_light: bool,
    pub cloud_shadows: bool,
    pub multiple_scattering: bool,
}

impl Default for LightingSwitches {
    fn default() -> Self {
        Self {
            sky_light: true,
            ground_light: true,
            aerial_perspective: true,
            shafts_of_light: true,
            cloud_shadows: true,
            multiple_scattering: true,
        }
    }
}

/// The scene file as written (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSceneJson {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    /// Free-form documentation, ignored.
    #[serde(default)]
    pub doc: Option<Value>,
    pub cloud: CloudSection,
    pub optics: OpticsJson,
    pub camera: CameraJson,
    pub sun: SunJson,
    /// Preset name, inline atmosphere JSON, or `null` for vacuum ["earth"].
    #[serde(default = "default_atmosphere")]
    pub atmosphere: Value,
    /// `"atmosphere"`, `{"constant_radiance_w_m2_sr_nm": v}` or `null` (no sky light) ["atmosphere"].
    #[serde(default = "default_sky")]
    pub sky: Value,
    /// Lambertian ground or `null` (no ground at all) [albedo 0.3 at 0 m].
    #[serde(default = "default_ground")]
    pub ground: Value,
    /// 1 to 64 wavelengths in 360–830 nm [440, 550, 680].
    #[serde(default = "default_wavelengths")]
    pub wavelengths_nm: Vec<f64>,
    /// draft | standard | high | reference [standard].
    #[serde(default = "default_quality")]
    pub quality: Quality,
    #[serde(default)]
    pub lighting: LightingSwitches,
    /// Multiple scattering of the fast method: `"all_orders"` (the photon-transport field) or
    /// `"reference_pattern"` (orders 2 and 3 of sunlight by Nishita et al. 1996, §3.4; thin clouds)
    /// ["all_orders"].
    #[serde(default)]
    pub multiple_scattering_method: CloudMsMethod,
}

fn default_atmosphere() -> Value {
    Value::String("earth".into())
}
fn default_sky() -> Value {
    Value::String("atmosphere".into())
}
fn default_ground() -> Value {
    serde_json::json!({"albedo": 0.3, "height_m": 0.0})
}
fn default_wavelengths() -> Vec<f64> {
    vec![440.0, 550.0, 680.0]
}
fn default_quality() -> Quality {
    Quality::Standard
}

/// Cloud optics resolved at the scene's wavelengths.
#[derive(Debug, Clone, PartialEq)]
pub struct Optics {
    /// σ_t per unit density, m⁻¹, per wavelength.
    pub extinction_per_density_m: Vec<f64>,
    /// Single-scattering albedo per wavelength.
    pub albedo: Vec<f64>,
    /// Phase function per wavelength.
    pub phase: Vec<Phase>,
}

impl Optics {
    /// Groups of wavelength indices sharing identical optics (a grey cloud is one group).
    pub fn groups(&self) -> Vec<Vec<usize>> {
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for l in 0..self.albedo.len() {
            let same = |g: &Vec<usize>| {
                let k = g[0];
                self.extinction_per_density_m[k] == self.extinction_per_density_m[l]
                    && self.albedo[k] == self.albedo[l]
                    && self.phase[k] == self.phase[l]
            };
            match groups.iter_mut().find(|g| same(g)) {
                Some(g) => g.push(l),
                None => groups.push(vec![l]),
            }
        }
        groups
    }
}

/// The camera, validated (directions normalised, an orthonormal frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    pub projection: Projection,
    pub position_m: DVec3,
    /// Unit view direction.
    pub forward: DVec3,
    /// Unit vector to the image's right.
    pub right: DVec3,
    /// Unit vector to the image's top.
    pub up: DVec3,
    pub width: usize,
    pub height: usize,
}

/// Projection of a [`CameraSpec`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    /// Half-extents of the image plane at unit distance (tan of the half angles).
    Pinhole { half_w: f64, half_h: f64 },
    /// Half-extents of the image in metres.
    Orthographic { half_w: f64, half_h: f64 },
    /// Radians per pixel from the centre.
    Fisheye { rad_per_px: f64 },
}

/// The sun, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct SunSpec {
    pub elevation_deg: f64,
    pub azimuth_deg: f64,
    /// Normal irradiance of a collimated beam (no atmosphere applied), per wavelength.
    pub collimated_irradiance: Option<Vec<f64>>,
}

impl SunSpec {
    /// Unit vector from the scene towards the sun.
    pub fn direction(&self) -> DVec3 {
        direction_from_deg(self.elevation_deg, self.azimuth_deg)
    }
}

/// `(sin a·cos e, cos a·cos e, sin e)`: elevation `e` and azimuth `a` from +y towards +x.
pub fn direction_from_deg(elevation_deg: f64, azimuth_deg: f64) -> DVec3 {
    let (e, a) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
    DVec3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin())
}

/// Sky light on the cloud.
#[derive(Debug, Clone, PartialEq)]
pub enum SkySpec {
    /// The sky product of the atmosphere above.
    Atmosphere,
    /// Constant radiance over the upper hemisphere, zero below, per wavelength.
    Constant(Vec<f64>),
    /// No sky light.
    None,
}

/// The ground, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundSpec {
    pub albedo: Vec<f64>,
    pub height_m: f64,
}

/// A validated frame scene.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameScene {
    pub name: Option<String>,
    pub cloud: CloudSection,
    pub optics: Optics,
    pub camera: CameraSpec,
    pub sun: SunSpec,
    /// `None`: vacuum (no aerial perspective, no attenuation).
    pub atmosphere: Option<AtmosphereParams>,
    pub sky: SkySpec,
    pub ground: Option<GroundSpec>,
    pub wavelengths: Wavelengths,
    pub quality: Quality,
    pub lighting: LightingSwitches,
    pub multiple_scattering_method: CloudMsMethod,
    /// The scene as given (for cache keys and metadata).
    pub source: FrameSceneJson,
}

impl FrameScene {
    /// Parses and validates a scene (at most [`MAX_SCENE_FILE_BYTES`]).
    pub fn parse(json: &[u8]) -> Result<Self> {
        if json.len() > MAX_SCENE_FILE_BYTES {
            return Err(Error::too_large(
                "scene",
                format!("{} bytes", json.len()),
                format!("{MAX_SCENE_FILE_BYTES} bytes"),
            ));
        }
        let raw: Value = serde_json::from_slice(json)
            .map_err(|e| Error::invalid("scene", format!("invalid scene JSON: {e}")))?;
        // Deserialise section by section so an error names the section.
        let obj = raw
            .as_object()
            .ok_or_else(|| Error::invalid("scene", "must be a JSON object"))?;
        for (key, field) in [
            ("cloud", "cloud"),
            ("optics", "optics"),
            ("camera", "camera"),
            ("sun", "sun"),
        ] {
            if !obj.contains_key(key) {
                return Err(Error::invalid(field, "missing (required)"));
            }
        }
        section::<CloudSection>(&raw, "cloud")?;
        section::<OpticsJson>(&raw, "optics")?;
        section::<CameraJson>(&raw, "camera")?;
        // Exactly one of the three forms: serde's untagged enum would ignore the members of
        // another form (a place and time next to a direction).
        let sun_members = |form: &[&str]| {
            obj.get("sun")
                .and_then(serde_json::Value::as_object)
                .is_some_and(|m| m.len() == form.len() && form.iter().all(|k| m.contains_key(*k)))
        };
        let one_form = [
            &["collimated"][..],
            &["elevation_deg", "azimuth_deg"],
            &["latitude_deg", "longitude_deg", "time"],
        ]
        .iter()
        .any(|form| sun_members(form));
        if !one_form || section::<SunJson>(&raw, "sun").is_err() {
            return Err(Error::invalid(
                "sun",
                "give exactly one of {\"elevation_deg\", \"azimuth_deg\"}, {\"latitude_deg\", \"longitude_deg\", \"time\"} or {\"collimated\": {\"elevation_deg\", \"azimuth_deg\", \"normal_irradiance_w_m2_nm\"}}",
            ));
        }
        let s: FrameSceneJson = serde_json::from_value(raw)
            .map_err(|e| Error::invalid("scene", format!("invalid scene: {e}")))?;
        Self::from_json(s)
    }

    /// The scene at `wavelengths_nm` instead of its own (an RGB-only frame's subset of them):
    /// every spectral value resolved again at those wavelengths.
    pub fn at_wavelengths(&self, wavelengths_nm: &[f64]) -> Result<Self> {
        let mut s = self.source.clone();
        s.wavelengths_nm = wavelengths_nm.to_vec();
        Self::from_json(s)
    }

    /// Validates a deserialised scene.
    pub fn from_json(s: FrameSceneJson) -> Result<Self> {
        s.cloud.validate().map_err(|e| e.prefixed("cloud."))?;
        let wavelengths = Wavelengths::new(s.wavelengths_nm.clone()).map_err(|e| {
            if e.field() == "wavelengths" {
                e
            } else {
                e.prefixed("wavelengths_nm.")
            }
        })?;
        let wl = wavelengths.as_nm().to_vec();
        let optics = resolve_optics(&s.optics, &wl)?;
        let camera = resolve_camera(&s.camera, wl.len())?;
        let atmosphere = match &s.atmosphere {
            Value::Null => None,
            Value::String(name) => {
                Some(presets::preset(name).map_err(|e| e.prefixed("atmosphere."))?)
            }
            v @ Value::Object(_) => Some(presets::parse_json("atmosphere", &v.to_string())?),
            _ => {
                return Err(Error::invalid(
                    "atmosphere",
                    "a preset name, an inline atmosphere object or null",
                ))
            }
        };
        let sun = resolve_sun(&s.sun, &wl, atmosphere.is_some())?;
        let sky = match &s.sky {
            Value::Null => SkySpec::None,
            Value::String(t) if t == "atmosphere" => {
                if atmosphere.is_none() {
                    return Err(Error::invalid(
                        "sky",
                        "\"atmosphere\" needs an atmosphere; in vacuum give {\"constant_radiance_w_m2_sr_nm\": …} or null",
                    ));
                }
                SkySpec::Atmosphere
            }
            Value::Object(o) if o.len() == 1 && o.contains_key("constant_radiance_w_m2_sr_nm") => {
                let v: Spectral = serde_json::from_value(o["constant_radiance_w_m2_sr_nm"].clone())
                    .map_err(|e| Error::invalid("sky.constant_radiance_w_m2_sr_nm", e))?;
                SkySpec::Constant(v.resolve("sky.constant_radiance_w_m2_sr_nm", &wl, 0.0, 1e6)?)
            }
            _ => {
                return Err(Error::invalid(
                    "sky",
                    "\"atmosphere\", {\"constant_radiance_w_m2_sr_nm\": value} or null",
                ))
            }
        };
        let ground = match &s.ground {
            Value::Null => None,
            v => {
                let g: GroundJson = serde_json::from_value(v.clone())
                    .map_err(|e| Error::invalid("ground", format!("{e}")))?;
                if !(g.height_m.is_finite() && (-500.0..=10_000.0).contains(&g.height_m)) {
                    return Err(Error::out_of_range(
                        "ground.height_m",
                        g.height_m,
                        "-500 to 10000 m",
                    ));
                }
                Some(GroundSpec {
                    albedo: g.albedo.resolve("ground.albedo", &wl, 0.0, 1.0)?,
                    height_m: g.height_m,
                })
            }
        };
        Ok(Self {
            name: s.name.clone(),
            cloud: s.cloud.clone(),
            optics,
            camera,
            sun,
            atmosphere,
            sky,
            ground,
            wavelengths,
            quality: s.quality,
            lighting: s.lighting,
            multiple_scattering_method: s.multiple_scattering_method,
            source: s,
        })
    }
}

fn section<T: serde::de::DeserializeOwned>(raw: &Value, key: &str) -> Result<T> {
    T::deserialize(&raw[key]).map_err(|e| Error::invalid(key, format!("{e}")))
}

fn resolve_optics(o: &OpticsJson, wl: &[f64]) -> Result<Optics> {
    let k =
        o.extinction_per_density_m
            .resolve("optics.extinction_per_density_m", wl, 0.0, 1000.0)?;
    let albedo =
        o.single_scattering_albedo
            .resolve("optics.single_scattering_albedo", wl, 0.0, 1.0)?;
    let g_range = |g: &Spectral| g.resolve("optics.phase.g", wl, -MAX_ABS_G, MAX_ABS_G);
    let phase = match &o.phase {
        PhaseJson::HenyeyGreenstein { g } => g_range(g)?
            .into_iter()
            .map(|g| Phase::HenyeyGreenstein { g })
            .collect(),
        PhaseJson::CornetteShanks { g } => g_range(g)?
            .into_iter()
            .map(|g| Phase::CornetteShanks { g })
            .collect(),
        PhaseJson::Mixture {
            g,
            rayleigh_fraction,
        } => {
            let f = *rayleigh_fraction;
            if !(f.is_finite() && (0.0..=1.0).contains(&f)) {
                return Err(Error::out_of_range(
                    "optics.phase.rayleigh_fraction",
                    f,
                    "0 to 1",
                ));
            }
            g_range(g)?
                .into_iter()
                .map(|g| Phase::Mixture {
                    g,
                    rayleigh_fraction: f,
                })
                .collect()
        }
    };
    Ok(Optics {
        extinction_per_density_m: k,
        albedo,
        phase,
    })
}

fn vec3(field: &str, v: [f64; 3]) -> Result<DVec3> {
    let d = DVec3::from_array(v);
    if !d.is_finite() || d.abs().max_element() > 1e8 {
        return Err(Error::out_of_range(
            field,
            format!("{v:?}"),
            "finite coordinates within ±1e8 m",
        ));
    }
    Ok(d)
}

fn resolve_camera(c: &CameraJson, n_wavelengths: usize) -> Result<CameraSpec> {
    let (position, look_at, up, width, height) = match c {
        CameraJson::Pinhole {
            position_m,
            look_at_m,
            up,
            width,
            height,
            ..
        }
        | CameraJson::Orthographic {
            position_m,
            look_at_m,
            up,
            width,
            height,
            ..
        }
        | CameraJson::Fisheye {
            position_m,
            look_at_m,
            up,
            width,
            height,
            ..
        } => (*position_m, *look_at_m, *up, *width, *height),
    };
    for (f, v) in [("camera.width", width), ("camera.height", height)] {
        if !(1..=16384).contains(&v) {
            return Err(Error::out_of_range(f, v, "1 to 16384 pixels"));
        }
    }
    let pixels = width * height;
    if pixels > MAX_PIXELS {
        return Err(Error::too_large(
            "camera.width",
            format!("{width}x{height} pixels"),
            format!("{MAX_PIXELS} pixels"),
        ));
    }
    if pixels.saturating_mul(n_wavelengths) > MAX_FRAME_SAMPLES {
        return Err(Error::too_large(
            "camera.width",
            format!("{width}x{height} pixels x {n_wavelengths} wavelengths"),
            format!("{MAX_FRAME_SAMPLES} pixel-wavelength samples"),
        ));
    }
    let position_m = vec3("camera.position_m", position)?;
    let look = vec3("camera.look_at_m", look_at)?;
    let up_v = vec3("camera.up", up)?;
    let fwd = look - position_m;
    if fwd.length() < 1e-9 {
        return Err(Error::invalid(
            "camera.look_at_m",
            "equals camera.position_m: the camera looks nowhere",
        ));
    }
    let forward = fwd.normalize();
    let right = forward.cross(up_v);
    if up_v.length() < 1e-12 || right.length() < 1e-9 * up_v.length() {
        return Err(Error::invalid(
            "camera.up",
            "must be non-zero and not parallel to the view direction",
        ));
    }
    let right = right.normalize();
    let up = right.cross(forward);
    let aspect = width as f64 / height as f64;
    let projection = match c {
        CameraJson::Pinhole {
            fov_deg, fov_axis, ..
        } => {
            if !(fov_deg.is_finite() && *fov_deg > 0.0 && *fov_deg <= 179.0) {
                return Err(Error::out_of_range(
                    "camera.fov_deg",
                    fov_deg,
                    "0 < fov <= 179 deg",
                ));
            }
            let t = (0.5 * fov_deg.to_radians()).tan();
            match fov_axis {
                FovAxis::Horizontal => Projection::Pinhole {
                    half_w: t,
                    half_h: t / aspect,
                },
                FovAxis::Vertical => Projection::Pinhole {
                    half_w: t * aspect,
                    half_h: t,
                },
            }
        }
        CameraJson::Orthographic { view_width_m, .. } => {
            if !(view_width_m.is_finite() && *view_width_m > 0.0 && *view_width_m <= 1e7) {
                return Err(Error::out_of_range(
                    "camera.view_width_m",
                    view_width_m,
                    "0 < width <= 1e7 m",
                ));
            }
            Projection::Orthographic {
                half_w: 0.5 * view_width_m,
                half_h: 0.5 * view_width_m / aspect,
            }
        }
        CameraJson::Fisheye { fov_deg, .. } => {
            if !(fov_deg.is_finite() && *fov_deg > 0.0 && *fov_deg <= 360.0) {
                return Err(Error::out_of_range(
                    "camera.fov_deg",
                    fov_deg,
                    "0 < fov <= 360 deg",
                ));
            }
            Projection::Fisheye {
                rad_per_px: fov_deg.to_radians() / width.min(height) as f64,
            }
        }
    };
    Ok(CameraSpec {
        projection,
        position_m,
        forward,
        right,
        up,
        width,
        height,
    })
}

fn resolve_sun(s: &SunJson, wl: &[f64], has_atmosphere: bool) -> Result<SunSpec> {
    let check_az = |a: f64, field: &str| -> Result<f64> {
        if a.is_finite() && a.abs() <= 3600.0 {
            Ok(a.rem_euclid(360.0))
        } else {
            Err(Error::out_of_range(
                field,
                a,
                "finite degrees (|a| <= 3600)",
            ))
        }
    };
    match s {
        SunJson::Collimated { collimated: c } => {
            if !(c.elevation_deg.is_finite() && (-90.0..=90.0).contains(&c.elevation_deg)) {
                return Err(Error::out_of_range(
                    "sun.collimated.elevation_deg",
                    c.elevation_deg,
                    "-90 to 90 deg",
                ));
            }
            Ok(SunSpec {
                elevation_deg: c.elevation_deg,
                azimuth_deg: check_az(c.azimuth_deg, "sun.collimated.azimuth_deg")?,
                collimated_irradiance: Some(c.normal_irradiance_w_m2_nm.resolve(
                    "sun.collimated.normal_irradiance_w_m2_nm",
                    wl,
                    0.0,
                    1e6,
                )?),
            })
        }
        SunJson::Direction {
            elevation_deg,
            azimuth_deg,
        } => {
            let lo = if has_atmosphere { -18.0 } else { -90.0 };
            if !(elevation_deg.is_finite() && (lo..=90.0).contains(elevation_deg)) {
                return Err(Error::out_of_range(
                    "sun.elevation_deg",
                    elevation_deg,
                    format!("{lo} to 90 deg"),
                ));
            }
            Ok(SunSpec {
                elevation_deg: *elevation_deg,
                azimuth_deg: check_az(*azimuth_deg, "sun.azimuth_deg")?,
                collimated_irradiance: None,
            })
        }
        SunJson::Place {
            latitude_deg,
            longitude_deg,
            time,
        } => {
            if !(latitude_deg.is_finite() && latitude_deg.abs() <= 90.0) {
                return Err(Error::out_of_range(
                    "sun.latitude_deg",
                    latitude_deg,
                    "-90 to 90 deg",
                ));
            }
            if !(longitude_deg.is_finite() && longitude_deg.abs() <= 180.0) {
                return Err(Error::out_of_range(
                    "sun.longitude_deg",
                    longitude_deg,
                    "-180 to 180 deg",
                ));
            }
            let (e, a) = skybake_physics::solar::sun_elevation_azimuth_deg(
                *latitude_deg,
                *longitude_deg,
                time,
            )
            .map_err(|e| e.prefixed("sun."))?;
            if has_atmosphere && e < -18.0 {
                return Err(Error::out_of_range(
                    "sun.time",
                    format!("{time} (sun elevation {e:.2} deg)"),
                    "times when the sun is at least -18 deg high",
                ));
            }
            Ok(SunSpec {
                elevation_deg: e,
                azimuth_deg: a.rem_euclid(360.0),
                collimated_irradiance: None,
            })
        }
    }
}
