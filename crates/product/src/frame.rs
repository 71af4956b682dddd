//! The `frame` product: scene JSON → voxelised cloud → lighting from the engine → rendered frame →
//! spectral image (the artifact). The CLI (`skybake render`), the service (`POST /v1/render`),
//! frame bake jobs and the cache all run this one path, so the `-o` file and the HTTP EXR of a
//! scene are the same.
//!
//! A frame is computed in [`TILE_SIZE`]² tiles in raster order. Each finished tile goes to a
//! [`TileSink`] (the service's and the bake's: [`skybake_store::FrameTiles`], one verified EXR per
//! tile); a later run of the same request takes the tiles it finds there and computes only the
//! others, so a crash, a kill or a cancellation loses only the tile in flight. Pixels do not
//! depend on the tiling (every pixel's rays and random stream are its own), so a resumed frame is
//! the frame an uninterrupted run gives.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use skybake_engine::engine::{Engine, Stages};
use skybake_engine::plan::{
    Budget, FrameFacts, FramePlan, FrameReason, FrameStage, RgbFacts, SphereFacts, WavelengthSubset,
};
use skybake_physics::cloud::DensityGrid;
use skybake_physics::spectrum::Wavelengths;
use skybake_render::{
    lighting_for, relative_noise, render_tile, FrameError, FrameMeta, FrameScene, Method, Prepared,
    RenderSettings, Tile, ERROR_BASIS,
};
use skybake_store::tiles::ATTR_TILE_OF;
use skybake_store::{decode_exr, encode_exr, SpectralImage, StoreError};
use std::time::Instant;

/// Edge of a render tile, pixels.
pub const TILE_SIZE: usize = 64;
/// Header attribute of a tile: its rectangle, the preparation's stages and timings, its own
/// pixel time ([`TileMeta`] as JSON).
const ATTR_TILE_META: &str = "skybakeTileMeta";
/// Header attribute of the assembled frame: how many tiles there are, how many this run
/// computed and how many it took from an earlier run.
pub const ATTR_FRAME_TILES: &str = "skybakeFrameTiles";

/// Header attribute of a frame artifact: its [`FrameMeta`] as JSON, the timings at a fixed width
/// ([`frame_meta_json`]).
pub const ATTR_FRAME_META: &str = "skybakeFrameMeta";

/// Width of a timing value in [`ATTR_FRAME_META`]: milliseconds to the microsecond, right-aligned
/// with spaces (JSON whitespace), capped at 99 999 999.999.
pub const FRAME_TIMING_WIDTH: usize = 12;

/// A frame's metadata as JSON whose `timing_ms` values all have [`FRAME_TIMING_WIDTH`] characters
/// (`["pixels",     1234.567]`), so the attribute's length and every byte outside those values
/// depend on the request only.
pub fn frame_meta_json(meta: &FrameMeta) -> Result<String> {
    fn json<T: Serialize + ?Sized>(v: &T) -> Result<String> {
        serde_json::to_string(v)
            .map_err(|e| Error::internal("frame", format!("JSON encoding: {e}")))
    }
    let text = json(&FrameMeta {
        timing_ms: Vec::new(),
        ..meta.clone()
    })?;
    let mut timings = Vec::with_capacity(meta.timing_ms.len());
    for (stage, ms) in &meta.timing_ms {
        let ms = if ms.is_finite() {
            ms.clamp(0.0, 99_999_999.999)
        } else {
            0.0
        };
        timings.push(format!(
            "[{},{:>w$.3}]",
            json(stage)?,
            ms,
            w = FRAME_TIMING_WIDTH
        ));
    }
    // `timing_ms` is serialised before the fields that hold free text (notes, plan).
    let empty = "\"timing_ms\":[]";
    if !text.contains(empty) {
        return Err(Error::internal("frame", "metadata without timing_ms"));
    }
    Ok(text.replacen(empty, &format!("\"timing_ms\":[{}]", timings.join(",")), 1))
}

/// The example scenes of `config/scenes/`, embedded in the binary: (name, scene JSON). Those with
/// a `camera` are frame scenes (`POST /v1/render`, frame jobs); the others are cloud sections
/// (`skybake clouds`).
pub const EXAMPLE_SCENES: &[(&str, &str)] = &[
    (
        "automaton-field",
        include_str!("../../../config/scenes/automaton-field.json"),
    ),
    (
        "cumulus-fractal",
        include_str!("../../../config/scenes/cumulus-fractal.json"),
    ),
    (
        "cumulus-frame",
        include_str!("../../../config/scenes/cumulus-frame.json"),
    ),
    (
        "cumulus-metaballs",
        include_str!("../../../config/scenes/cumulus-metaballs.json"),
    ),
    (
        "satellite-field",
        include_str!("../../../config/scenes/satellite-field.json"),
    ),
    (
        "sphere-cloud",
        include_str!("../../../config/scenes/sphere-cloud.json"),
    ),
    (
        "validation-frame",
        include_str!("../../../config/scenes/validation-frame.json"),
    ),
];

/// Files the example scenes name, embedded with them: (name as written in the scene, bytes).
const EXAMPLE_FILES: &[(&str, &[u8])] = &[(
    "satellite-field.png",
    include_bytes!("../../../config/scenes/satellite-field.png"),
)];

/// The example scene `name`'s JSON, if there is one.
pub fn example_scene(name: &str) -> Option<&'static str> {
    EXAMPLE_SCENES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, json)| *json)
}

/// The loader of scenes that arrive over the network (service, jobs): a scene may name only the
/// files of the example scenes (embedded), never a file of the machine it runs on.
pub fn example_file(name: &str) -> Result<Vec<u8>> {
    EXAMPLE_FILES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, bytes)| bytes.to_vec())
        .ok_or_else(|| {
            let known: Vec<&str> = EXAMPLE_FILES.iter().map(|(n, _)| *n).collect();
            Error::invalid(
                "path",
                format!(
                    "'{name}': a scene sent to the service can name only the example scenes' files ({}); send other clouds as a grid through skybake render",
                    known.join(", ")
                ),
            )
        })
}

/// A validated frame request: the scene (as parsed JSON, for the canonical form) and the method.
#[derive(Debug, Clone)]
pub struct FrameRequest {
    pub scene: FrameScene,
    scene_json: serde_json::Value,
    pub method: Method,
    /// The request's `max_rel_error` target ([`Self::with_max_rel_error`]): the frame plan's
    /// budget.
    pub max_rel_error: Option<f64>,
    /// The RGB image is the only output wanted (a PNG, [`Self::with_rgb_only`]): the planner
    /// may run fewer wavelengths.
    pub rgb_only: bool,
}

/// Progress of a tiled render, reported after each tile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct TileProgress {
    /// Tiles finished (taken from the sink or computed now).
    pub done: usize,
    pub total: usize,
    /// Of `done`, tiles taken from an earlier run.
    pub reused: usize,
}

/// Where the tiles of a render are kept between runs (the library does no I/O itself).
pub trait TileSink: Sync {
    /// The bytes stored for tile `index` (verified), or `None`.
    fn get(&self, index: usize) -> Result<Option<Vec<u8>>>;
    /// Stores tile `index`.
    fn put(&self, index: usize, bytes: &[u8]) -> Result<()>;
    /// The binding a tile file carries, so a tile stored for another request or place is refused.
    fn binding(&self, index: usize) -> String;
}

/// No persistence: every tile is computed.
pub struct NoTiles;

impl TileSink for NoTiles {
    fn get(&self, _: usize) -> Result<Option<Vec<u8>>> {
        Ok(None)
    }
    fn put(&self, _: usize, _: &[u8]) -> Result<()> {
        Ok(())
    }
    fn binding(&self, index: usize) -> String {
        format!("-/{index}")
    }
}

fn store_error(e: StoreError) -> Error {
    match e {
        StoreError::Invalid(e) => e,
        other => Error::internal("tile store", other),
    }
}

impl TileSink for skybake_store::FrameTiles {
    fn get(&self, index: usize) -> Result<Option<Vec<u8>>> {
        skybake_store::FrameTiles::get(self, index).map_err(store_error)
    }
    fn put(&self, index: usize, bytes: &[u8]) -> Result<()> {
        skybake_store::FrameTiles::put(self, index, bytes).map_err(store_error)
    }
    fn binding(&self, index: usize) -> String {
        skybake_store::FrameTiles::binding(self, index)
    }
}

/// The stage list as stored in a tile (the preparation's, the same for every tile of a run).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct StoredStages {
    ran: Vec<String>,
    skipped: Vec<String>,
}

/// What a tile file carries besides its pixels.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct TileMeta {
    x0: usize,
    y0: usize,
    width: usize,
    height: usize,
    stages: StoredStages,
    /// The preparation's stage timings in the run that computed the tile, ms.
    preparation_ms: Vec<(String, f64)>,
    lighting_notes: Vec<String>,
    /// This tile's pixels, ms.
    pixels_ms: f64,
    /// The frame's typed plan (`plan::FramePlan` as JSON).
    #[serde(default)]
    plan: Option<serde_json::Value>,
}

/// The tiles of a `width` × `height` image in raster order.
pub fn tile_rects(width: usize, height: usize) -> Vec<Tile> {
    let mut rects = Vec::new();
    for y0 in (0..height).step_by(TILE_SIZE) {
        for x0 in (0..width).step_by(TILE_SIZE) {
            rects.push(Tile {
                x0,
                y0,
                width: TILE_SIZE.min(width - x0),
                height: TILE_SIZE.min(height - y0),
            });
        }
    }
    rects
}

/// Full-frame buffers the tiles are copied into.
struct Canvas {
    width: usize,
    n_l: usize,
    radiance: Vec<f32>,
    transmittance: Vec<f32>,
    variance: Vec<f32>,
}

impl Canvas {
    fn blit(&mut self, t: &Tile, radiance: &[f32], transmittance: &[f32], variance: &[f32]) {
        let n_l = self.n_l;
        for row in 0..t.height {
            let dst = (t.y0 + row) * self.width + t.x0;
            let src = row * t.width;
            self.radiance[dst * n_l..(dst + t.width) * n_l]
                .copy_from_slice(&radiance[src * n_l..(src + t.width) * n_l]);
            self.transmittance[dst..dst + t.width]
                .copy_from_slice(&transmittance[src..src + t.width]);
            if !self.variance.is_empty() && !variance.is_empty() {
                self.variance[dst * n_l..(dst + t.width) * n_l]
                    .copy_from_slice(&variance[src * n_l..(src + t.width) * n_l]);
            }
        }
    }
}

/// The planner's view of a scene and its voxelised cloud (the facts the planner's frame rules decide on): whether there is a
/// cloud and whether any pixel's ray can reach it, the smallest pixel footprint on it, a bound on
/// its optical path, and the predicted shares of sky and ground light.
///
/// - Occupied box: the voxels holding density, one voxel wider on every side (trilinear
///   interpolation reaches the next centre), within the grid's box.
/// - In view (conservative: `false` only when no ray can reach the box): pinhole, the box wholly
///   behind the camera or beyond one of the four side planes of the view frustum; orthographic,
///   beyond one of the four side planes or behind the image plane; fisheye, the box's bounding
///   sphere farther from the axis than the image circle's half angle.
/// - Pixel footprint at the box's nearest point (distance d): pinhole d·Δ·cos²θ_c, Δ the pixel
///   pitch at unit distance and θ_c the angle of the image corner (where the angular pitch is
///   smallest); orthographic the pixel pitch; fisheye d times the radians per pixel.
/// - Optical path bound: the largest extinction × the largest density × the box's diagonal.
/// - Shares (vacuum scenes, where the light is given): the light reaching a cloud point averaged
///   over directions, sun E/(4π), a constant sky L_s over the upper hemisphere L_s/2, the lit
///   Lambertian ground below L_g/2 with L_g = a/π·(E μ_s + π L_s); a share is its part of the sum,
///   largest over wavelengths. With an atmosphere the shares are not predicted (the stages run).
pub fn frame_facts(scene: &FrameScene, grid: &DensityGrid, method: Method) -> FrameFacts {
    frame_facts_with(scene, grid, method, &PlanInputs::default())
}

/// What the frame planner takes besides the scene and its grid.
#[derive(Debug, Clone, Copy, Default)]
pub struct PlanInputs<'a> {
    /// The request's `max_rel_error` target.
    pub max_rel_error: Option<f64>,
    /// The light at the cloud as computed for the scene: with an atmosphere the shares of sky
    /// and ground light are measured on it ([`measured_shares`]); without, they are not
    /// predicted (the stages run).
    pub lighting: Option<&'a skybake_render::Lighting>,
    /// A sphere-hierarchy cloud's levels ([`sphere_facts`]).
    pub sphere: Option<SphereFacts>,
    /// An RGB-only request's wavelengths and their subsets ([`skybake_render::rgb_only::rgb_facts`]).
    pub rgb: Option<&'a RgbFacts>,
}

/// Shares of sky light and of ground light (light from below) in all the light reaching the
/// cloud, averaged over directions, largest over wavelengths, measured on the scene's computed
/// light: the sun E/(4π), the sky's and the ground's radiance tables averaged over 4096
/// directions evenly spread over the sphere (a Fibonacci lattice), each hemisphere's mean
/// weighted by its half of the sphere.
pub fn measured_shares(lighting: &skybake_render::Lighting) -> (f64, f64) {
    use glam::DVec3;
    const N: usize = 4096;
    let n_l = lighting.wavelengths_nm.len();
    let (mut up, mut down) = (vec![0.0f64; n_l], vec![0.0f64; n_l]);
    let mut l = vec![0.0f64; n_l];
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..N {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / N as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * i as f64;
        let dir = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        lighting.env(dir, &mut l);
        let acc = if z >= 0.0 { &mut up } else { &mut down };
        for (a, v) in acc.iter_mut().zip(&l) {
            *a += v.max(0.0) / N as f64;
        }
    }
    let (mut sky, mut ground) = (0.0f64, 0.0f64);
    for i in 0..n_l {
        let sun = lighting
            .sun_irradiance
            .get(i)
            .copied()
            .unwrap_or(0.0)
            .max(0.0)
            / (4.0 * std::f64::consts::PI);
        let total = sun + up[i] + down[i];
        if total > 0.0 {
            sky = sky.max(up[i] / total);
            ground = ground.max(down[i] / total);
        }
    }
    (sky, ground)
}

/// Whether the camera sees a box, its smallest pixel footprint on it and its nearest distance
/// (see [`frame_facts`]).
fn view_of_box(
    cam: &skybake_render::scene::CameraSpec,
    lo: glam::DVec3,
    hi: glam::DVec3,
) -> (bool, f64, f64) {
    use glam::DVec3;
    use skybake_render::scene::Projection;
    let corners: Vec<DVec3> = (0..8)
        .map(|c| {
            DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            ) - cam.position_m
        })
        .collect();
    let local: Vec<(f64, f64, f64)> = corners
        .iter()
        .map(|v| (v.dot(cam.right), v.dot(cam.up), v.dot(cam.forward)))
        .collect();
    let all = |f: &dyn Fn(&(f64, f64, f64)) -> bool| local.iter().all(f);
    let nearest = (cam.position_m.clamp(lo, hi) - cam.position_m).length();
    let (in_view, footprint) = match cam.projection {
        Projection::Pinhole { half_w, half_h } => {
            let out = all(&|c| c.2 <= 0.0)
                || all(&|c| c.0 > half_w * c.2)
                || all(&|c| c.0 < -half_w * c.2)
                || all(&|c| c.1 > half_h * c.2)
                || all(&|c| c.1 < -half_h * c.2);
            let pitch = (2.0 * half_w / cam.width as f64).min(2.0 * half_h / cam.height as f64);
            let cos2 = 1.0 / (1.0 + half_w * half_w + half_h * half_h);
            (!out, nearest * pitch * cos2)
        }
        Projection::Orthographic { half_w, half_h } => {
            let out = all(&|c| c.2 <= 0.0)
                || all(&|c| c.0 > half_w)
                || all(&|c| c.0 < -half_w)
                || all(&|c| c.1 > half_h)
                || all(&|c| c.1 < -half_h);
            let pitch = (2.0 * half_w / cam.width as f64).min(2.0 * half_h / cam.height as f64);
            (!out, pitch)
        }
        Projection::Fisheye { rad_per_px } => {
            let centre = 0.5 * (lo + hi) - cam.position_m;
            let radius = 0.5 * (hi - lo).length();
            let dist = centre.length();
            let half_diagonal =
                0.5 * ((cam.width * cam.width + cam.height * cam.height) as f64).sqrt();
            let theta_max = (rad_per_px * half_diagonal).min(std::f64::consts::PI);
            let in_view = dist <= radius || {
                let axis = (centre.dot(cam.forward) / dist).clamp(-1.0, 1.0).acos();
                axis - (radius / dist).clamp(-1.0, 1.0).asin() <= theta_max
            };
            (in_view, nearest * rad_per_px)
        }
    };
    (in_view, footprint, nearest)
}

/// The sphere-hierarchy facts of a scene whose cloud source is `spheres` (`None` otherwise):
/// the pixel footprint on the base sphere's box (every level's spheres lie inside it) and the
/// deepest level whose mean sphere diameter is at least that footprint
/// (`SphereCloud::level_for_resolution`). The levels are built one at a time and only as deep
/// as needed (a parent's children come from its own random stream, so the first L levels of a
/// hierarchy of K ≥ L ≥ 1 levels are those of a hierarchy of L levels); no voxels.
pub fn sphere_facts(scene: &FrameScene) -> Result<Option<SphereFacts>> {
    use glam::DVec3;
    use skybake_physics::cloud::scene::CloudSource;
    use skybake_physics::cloud::spheres::SphereCloud;
    let CloudSource::Spheres(source) = &scene.cloud.source else {
        return Ok(None);
    };
    let k_max = source.params.levels;
    let requested_level = source.level.unwrap_or(k_max).min(k_max);
    let build = |levels: u32| {
        let mut params = source.params.clone();
        params.levels = levels;
        SphereCloud::new(&params).map_err(|e| e.prefixed("cloud.source.params."))
    };
    let mean_diameter = |model: &SphereCloud, k: u32| {
        let spheres = model.level(k);
        2.0 * spheres.iter().map(|s| s.radius as f64).sum::<f64>() / spheres.len().max(1) as f64
    };
    let base = build(k_max.min(1))?;
    let r0 = base.level(0)[0].radius as f64;
    let (lo, hi) = (
        base.centre_m() - DVec3::splat(r0),
        base.centre_m() + DVec3::splat(r0),
    );
    let (_, footprint, nearest) = view_of_box(&scene.camera, lo, hi);
    let (mut resolved_level, mut resolved_diameter_m) = (0, mean_diameter(&base, 0));
    for k in 1..=requested_level {
        let model = build(k)?;
        let d = mean_diameter(&model, k);
        if d < footprint {
            break;
        }
        (resolved_level, resolved_diameter_m) = (k, d);
    }
    Ok(Some(SphereFacts {
        requested_level,
        level_fixed: source.level.is_some(),
        resolved_level,
        resolved_diameter_m,
        pixel_footprint_m: footprint,
        nearest_distance_m: nearest,
    }))
}

/// [`frame_facts`] with the request's target, its measured light and its sphere levels.
pub fn frame_facts_with(
    scene: &FrameScene,
    grid: &DensityGrid,
    method: Method,
    inputs: &PlanInputs,
) -> FrameFacts {
    use glam::DVec3;
    use skybake_render::scene::SkySpec;
    let [nx, ny, nz] = grid.dims;
    let (mut lo_i, mut hi_i) = ([usize::MAX; 3], [0usize; 3]);
    for z in 0..nz {
        for y in 0..ny {
            let row = grid.index(0, y, z);
            for (x, v) in grid.data[row..row + nx].iter().enumerate() {
                if *v > 0.0 {
                    for (a, i) in [x, y, z].into_iter().enumerate() {
                        lo_i[a] = lo_i[a].min(i);
                        hi_i[a] = hi_i[a].max(i);
                    }
                }
            }
        }
    }
    let empty = lo_i[0] == usize::MAX;
    let h = grid.voxel_size_m;
    let (lo, hi) = if empty {
        (grid.origin_m, grid.max_corner_m())
    } else {
        let at = |i: [usize; 3], pad: f64| {
            grid.origin_m + DVec3::new(i[0] as f64, i[1] as f64, i[2] as f64) * h + pad * h
        };
        (
            at(lo_i, -1.0).max(grid.origin_m),
            at(hi_i, 2.0).min(grid.max_corner_m()),
        )
    };
    let (in_view, footprint, nearest) = view_of_box(&scene.camera, lo, hi);
    let optics = &scene.optics;
    let k_max = optics
        .extinction_per_density_m
        .iter()
        .copied()
        .fold(0.0, f64::max);
    let max_albedo = optics.albedo.iter().copied().fold(0.0, f64::max);
    let n_l = scene.wavelengths.len();
    let sky_l = match &scene.sky {
        SkySpec::Constant(v) => v.clone(),
        _ => vec![0.0; n_l],
    };
    let has_sky_light = match &scene.sky {
        SkySpec::Atmosphere => scene.atmosphere.is_some(),
        SkySpec::Constant(v) => v.iter().any(|&x| x > 0.0),
        SkySpec::None => false,
    };
    let has_ground_light = if scene.atmosphere.is_some() {
        // The `ground` product (ground and the air below) lights the cloud from below.
        !matches!(scene.sky, SkySpec::None)
    } else {
        scene
            .ground
            .as_ref()
            .is_some_and(|g| g.albedo.iter().any(|&a| a > 0.0))
    };
    let (mut sky_share, mut ground_share) = (None, None);
    let mut shares_measured = false;
    if scene.atmosphere.is_none() {
        let sun = scene
            .sun
            .collimated_irradiance
            .clone()
            .unwrap_or_else(|| vec![1.0; n_l]);
        let mu_s = scene.sun.direction().z.max(0.0);
        let sw = scene.lighting;
        let (mut s_max, mut g_max) = (0.0f64, 0.0f64);
        for l in 0..n_l {
            let sky = if sw.sky_light { sky_l[l] } else { 0.0 };
            let l_g = match (&scene.ground, sw.ground_light) {
                (Some(g), true) => {
                    g.albedo[l] / std::f64::consts::PI
                        * (sun[l] * mu_s + std::f64::consts::PI * sky_l[l])
                }
                _ => 0.0,
            };
            let total = sun[l] / (4.0 * std::f64::consts::PI) + 0.5 * sky + 0.5 * l_g;
            if total > 0.0 {
                s_max = s_max.max(0.5 * sky / total);
                g_max = g_max.max(0.5 * l_g / total);
            }
        }
        sky_share = Some(s_max);
        ground_share = Some(g_max);
    } else if let Some(lighting) = inputs.lighting {
        let (sky, ground) = measured_shares(lighting);
        sky_share = Some(sky);
        ground_share = Some(ground);
        shares_measured = true;
    }
    FrameFacts {
        reference: method == Method::Reference,
        cloud_empty: empty,
        cloud_in_view: in_view,
        sky_light_switch: scene.lighting.sky_light,
        ground_light_switch: scene.lighting.ground_light,
        multiple_scattering_switch: scene.lighting.multiple_scattering,
        has_sky_light,
        has_ground_light,
        sky_share,
        ground_share,
        shares_measured,
        max_optical_depth: k_max * grid.max_density() as f64 * (hi - lo).length(),
        max_albedo,
        voxel_size_m: h,
        grid_dims: grid.dims,
        ms_max_dim: match (method, scene.multiple_scattering_method) {
            (Method::Fast, skybake_render::CloudMsMethod::AllOrders) => {
                RenderSettings::for_quality(scene.quality, method)
                    .photons
                    .max_coarse_dim
            }
            _ => 0,
        },
        pixel_footprint_m: footprint,
        nearest_distance_m: nearest,
        budget: skybake_engine::plan::FRAME_MEASURED_ERROR,
        max_rel_error: inputs.max_rel_error,
        sphere: inputs.sphere,
        rgb: inputs.rgb.cloned(),
    }
}

/// The frame plan of a scene and its voxelised cloud (`plan::plan_frame` on [`frame_facts`]).
pub fn plan_frame(scene: &FrameScene, grid: &DensityGrid, method: Method) -> FramePlan {
    skybake_engine::plan::plan_frame(&frame_facts(scene, grid, method))
}

/// An RGB-only request's facts, the wavelength rule's decision and the budget it leaves
/// ([`FrameRequest::rgb_decision`]).
struct RgbDecision {
    facts: Option<RgbFacts>,
    subset: Option<WavelengthSubset>,
    budget: Budget,
}

impl RgbDecision {
    /// The wavelengths the frame runs at: the subset, or the scene's own.
    fn wavelengths(&self, scene: &FrameScene) -> Result<Wavelengths> {
        match &self.subset {
            Some(s) => Wavelengths::new(s.internal_nm.clone()),
            None => Ok(scene.wavelengths.clone()),
        }
    }
}

/// A frame planned and ready to render ([`FrameRequest::planned`]).
struct PlannedFrame {
    plan: FramePlan,
    scene: FrameScene,
    grid: DensityGrid,
    settings: RenderSettings,
    lighting: skybake_render::Lighting,
    /// voxelize, plan, lighting, ms.
    timing_ms: Vec<(String, f64)>,
}

/// What a frame runs with under its plan.
pub struct PlannedRun {
    /// The scene with the lighting switches the plan turns off (its JSON and cache key are the
    /// request's: the plan is a function of the request).
    pub scene: FrameScene,
    /// The coarsened grid, when the plan coarsens the cloud's detail.
    pub grid: Option<DensityGrid>,
    pub settings: RenderSettings,
}

/// Executes `plan`: multiple scattering of a thin cloud off, sky or ground light left out on the
/// cloud (settings hooks, the background unchanged; with an atmosphere the `sky` product at the
/// cloud or the `ground` product not computed), no per-voxel light for a cloud out of view,
/// no lighting products for the cloud when no cloud stage runs, the grid's block means at
/// the coarsened voxel size, and the multiple-scattering field at the coarsened cells per axis.
pub fn execute_plan(
    plan: &FramePlan,
    scene: &FrameScene,
    grid: &DensityGrid,
    method: Method,
) -> Result<PlannedRun> {
    use skybake_render::scene::SkySpec;
    let mut scene = scene.clone();
    let mut settings = RenderSettings::for_quality(scene.quality, method);
    let reason = |stage: FrameStage| {
        plan.left_out
            .iter()
            .find(|(s, _)| *s == stage)
            .map(|(_, r)| *r)
    };
    if let Some(FrameReason::ThinCloud { .. }) = reason(FrameStage::MultipleScattering) {
        scene.lighting.multiple_scattering = false;
    }
    let under_budget = |stage| matches!(reason(stage), Some(FrameReason::UnderBudget { .. }));
    settings.sky_light = !under_budget(FrameStage::SkyLight);
    settings.ground_light = !under_budget(FrameStage::GroundLight);
    // With an atmosphere the camera's background is its own `sky` product, so the products
    // that light only the cloud (`sky` at the cloud, `ground`) are not computed either.
    if matches!(scene.sky, SkySpec::Atmosphere) && scene.atmosphere.is_some() {
        scene.lighting.sky_light &= settings.sky_light;
        scene.lighting.ground_light &= settings.ground_light;
    }
    if let Some(r @ (FrameReason::CloudOutOfView | FrameReason::NoCloud)) =
        reason(FrameStage::CloudLight)
    {
        settings.cloud_in_view = r != FrameReason::CloudOutOfView;
        // Nothing lights a cloud nobody sees: the `sky` product at the cloud and the `ground`
        // product are not computed (the camera's background comes from its own `sky` product).
        if matches!(scene.sky, SkySpec::Atmosphere) && scene.atmosphere.is_some() {
            scene.lighting.sky_light = false;
            scene.lighting.ground_light = false;
        }
    }
    let k = plan.ms_grid_coarsening();
    if k > 1 {
        settings.photons.max_coarse_dim =
            (settings.photons.max_coarse_dim / k).max(skybake_engine::plan::MIN_MS_GRID_DIM);
    }
    let factor = plan.coarsening();
    let grid = if factor > 1 {
        Some(grid.block_mean(factor)?)
    } else {
        None
    };
    Ok(PlannedRun {
        scene,
        grid,
        settings,
    })
}

/// Interleaves per-wavelength planes into `[pixel][λ]`.
fn interleave(planes: &[Vec<f32>], pixels: usize) -> Vec<f32> {
    let n_l = planes.len();
    let mut out = vec![0f32; pixels * n_l];
    for (l, plane) in planes.iter().enumerate() {
        for (p, v) in plane.iter().enumerate().take(pixels) {
            out[p * n_l + l] = *v;
        }
    }
    out
}

fn planes_of(values: &[f32], n_l: usize, pixels: usize) -> Vec<Vec<f32>> {
    let mut planes = vec![vec![0f32; pixels]; n_l];
    for (p, spectrum) in values.chunks(n_l).enumerate().take(pixels) {
        for (plane, v) in planes.iter_mut().zip(spectrum) {
            plane[p] = *v;
        }
    }
    planes
}

impl FrameRequest {
    /// Parses and validates a scene file's bytes (errors name the field and its range).
    /// A cloud whose grid size follows from its parameters is checked against the renderer's
    /// voxel limit here, before anything is voxelised ([`Self::planned_voxels`]).
    pub fn parse(scene_json: &[u8], method: Method) -> Result<Self> {
        let scene = FrameScene::parse(scene_json)?;
        if let Some(dims) = scene
            .cloud
            .planned_dims()
            .map_err(|e| e.prefixed("cloud."))?
        {
            check_render_voxels(dims)?;
        }
        let value: serde_json::Value = serde_json::from_slice(scene_json)
            .map_err(|e| Error::invalid("scene", e.to_string()))?;
        Ok(Self {
            scene,
            scene_json: value,
            method,
            max_rel_error: None,
            rgb_only: false,
        })
    }

    /// Marks the request RGB-only (`rgb_only`: its only output is the RGB image, a PNG): the
    /// planner may then run it at a subset of its wavelengths where the error budget allows
    /// (`plan::rgb_wavelengths_rule`). An RGB-only request has its own cache key (its artifact's
    /// spectral planes are at the wavelengths it ran at).
    pub fn with_rgb_only(mut self, rgb_only: bool) -> Self {
        self.rgb_only = rgb_only;
        self
    }

    /// The RGB-only facts and the wavelength rule's decision on a fresh budget (the rule runs
    /// first, so the planner repeats the same decision); no facts and no subset for a request
    /// that wants the spectral image or for the reference method.
    fn rgb_decision(&self) -> Result<RgbDecision> {
        let reference = self.method == Method::Reference;
        let mut budget = skybake_engine::plan::frame_budget(
            reference,
            skybake_engine::plan::FRAME_MEASURED_ERROR,
            self.max_rel_error,
        );
        if !self.rgb_only || reference {
            return Ok(RgbDecision {
                facts: None,
                subset: None,
                budget,
            });
        }
        let facts = skybake_render::rgb_only::rgb_facts(&self.scene)?;
        let subset = skybake_engine::plan::rgb_wavelengths_rule(&facts, &mut budget);
        Ok(RgbDecision {
            facts: Some(facts),
            subset,
            budget,
        })
    }

    /// The wavelengths the frame runs at and its artifact holds: the requested ones, or an
    /// RGB-only request's subset of them.
    pub fn internal_wavelengths(&self) -> Result<Wavelengths> {
        self.rgb_decision()?.wavelengths(&self.scene)
    }

    /// Sets the request's `max_rel_error` target (CLI `--max-rel-error`, HTTP `max_rel_error`),
    /// a number in [1e-4, 1]: the frame plan's budget is then the target, of which the cost
    /// rules may spend what the fast method's measured error
    /// ([`skybake_engine::plan::FRAME_MEASURED_ERROR`]) leaves over. A target below that error is
    /// refused, naming the best achievable error; the reference method (the path tracer, whose
    /// error is its noise, set by `quality`) takes none.
    pub fn with_max_rel_error(mut self, target: Option<&str>) -> Result<Self> {
        let Some(text) = target else {
            self.max_rel_error = None;
            return Ok(self);
        };
        let target = crate::params::parameter("max_rel_error")
            .ok_or_else(|| Error::internal("max_rel_error", "not in the parameter table"))?
            .real(text)?;
        if self.method == Method::Reference {
            return Err(Error::invalid(
                "max_rel_error",
                "only for method fast: the reference method (the path tracer) is the reference, its noise is set by the scene's quality",
            ));
        }
        let best = skybake_engine::plan::FRAME_MEASURED_ERROR;
        if target < best {
            // Out of range (a 400), the allowed range starting at the best achievable error.
            return Err(Error::out_of_range(
                "max_rel_error",
                target,
                format!(
                    "{best:.4} to 1: {best:.4} is the best measured error of the frame by the fast method (block NRMSE against Mitsuba 3 and the path tracer, README \"Cloud frames\")"
                ),
            ));
        }
        self.max_rel_error = Some(target);
        Ok(self)
    }

    /// A request from a scene given as parsed JSON (a job item).
    pub fn from_value(scene: &serde_json::Value, method: Method) -> Result<Self> {
        let bytes = serde_json::to_vec(scene).map_err(|e| Error::invalid("scene", e))?;
        Self::parse(&bytes, method)
    }

    /// The scene as given (parsed JSON).
    pub fn scene_json(&self) -> &serde_json::Value {
        &self.scene_json
    }

    /// The canonical request: the scene JSON with sorted keys, minus the free-form `doc`, `name`
    /// and `description` (they change no pixel), plus the method.
    pub fn canonical_json(&self) -> String {
        let mut scene = self.scene_json.clone();
        if let Some(map) = scene.as_object_mut() {
            for key in ["doc", "name", "description"] {
                map.remove(key);
            }
        }
        let mut request =
            serde_json::json!({"product": "frame", "method": self.method, "scene": scene});
        // Only when given, so the keys of requests without a target stay as they were.
        if let Some(target) = self.max_rel_error {
            request["max_rel_error"] = serde_json::json!(target);
        }
        if self.rgb_only {
            request["output"] = serde_json::json!("rgb");
        }
        request.to_string()
    }

    /// The cache key: blake3 of the canonical request and the engine version.
    pub fn cache_key(&self) -> String {
        skybake_physics::key::cache_key(
            &self.canonical_json(),
            skybake_engine::engine::ENGINE_VERSION,
        )
    }

    /// The frame's plan (voxelises the cloud to measure it; lights and renders nothing): what
    /// `skybake plan frame` and `POST /v1/plan` with `"product": "frame"` answer.
    ///
    /// With an atmosphere the light at the cloud is computed (the `sky` and `ground` products
    /// at the cloud, tables kept in `engine`) to measure the shares of sky and ground light.
    pub fn plan(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    ) -> Result<FramePlan> {
        Ok(self.planned(engine, loader, self.rgb_decision()?)?.plan)
    }

    /// Voxelises (a sphere hierarchy at the level the plan chooses), measures, plans and
    /// executes the plan, and computes the light the frame runs with; `rgb` is the request's
    /// [`Self::rgb_decision`].
    fn planned(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        rgb: RgbDecision,
    ) -> Result<PlannedFrame> {
        let start = Instant::now();
        let reference = self.method == Method::Reference;
        // The sphere-level rule runs before voxelising (`plan_frame` repeats it first, with the
        // same budget, so it decides the same).
        let sphere = if reference {
            None
        } else {
            sphere_facts(&self.scene)?
        };
        // The wavelength rule first: an RGB-only request may run at a subset of its wavelengths.
        let RgbDecision {
            facts: rgb,
            subset,
            mut budget,
        } = rgb;
        let scene = match &subset {
            Some(s) => self.scene.at_wavelengths(&s.internal_nm)?,
            None => self.scene.clone(),
        };
        let level = sphere
            .as_ref()
            .and_then(|s| skybake_engine::plan::sphere_level_rule(s, &mut budget));
        let mut cloud = self.scene.cloud.clone();
        if let (Some(level), skybake_physics::cloud::scene::CloudSource::Spheres(source)) =
            (&level, &mut cloud.source)
        {
            // The hierarchy is built only to the level summed (see `sphere_facts`); level 0 of
            // a hierarchy of K ≥ 1 levels is another sphere than that of K = 0.
            if level.to_level >= 1 {
                source.params.levels = level.to_level;
                source.level = None;
            } else {
                source.level = Some(0);
            }
        }
        let grid = voxelize_cloud(&cloud, loader)?;
        let voxelize_ms = start.elapsed().as_secs_f64() * 1e3;
        skybake_render::check_grid(&grid)?;
        let start = Instant::now();
        let mut inputs = PlanInputs {
            max_rel_error: self.max_rel_error,
            lighting: None,
            sphere,
            rgb: rgb.as_ref(),
        };
        let facts = frame_facts_with(&scene, &grid, self.method, &inputs);
        // With an atmosphere the shares of sky and ground light are measured on the light the
        // scene computes anyway (kept for the frame when the plan does not change it).
        let measure = scene.atmosphere.is_some()
            && !reference
            && !facts.cloud_empty
            && facts.cloud_in_view
            && ((facts.sky_light_switch && facts.has_sky_light)
                || (facts.ground_light_switch && facts.has_ground_light));
        let mut lighting_ms = 0.0;
        let measured = if measure {
            let t = Instant::now();
            let l = lighting_for(&scene, &grid, engine)?;
            lighting_ms += t.elapsed().as_secs_f64() * 1e3;
            Some(l)
        } else {
            None
        };
        inputs.lighting = measured.as_ref();
        let plan = skybake_engine::plan::plan_frame(&frame_facts_with(
            &scene,
            &grid,
            self.method,
            &inputs,
        ));
        let run = execute_plan(&plan, &scene, &grid, self.method)?;
        let grid = match run.grid {
            Some(g) => g,
            None => grid,
        };
        let plan_ms = start.elapsed().as_secs_f64() * 1e3 - lighting_ms;
        let lighting = match measured {
            // The light measured is the frame's, less what the plan left out.
            Some(l) if plan.coarsening() == 1 => {
                let (sky, ground) = (
                    run.scene.lighting.sky_light,
                    run.scene.lighting.ground_light,
                );
                match l.masked(sky, ground) {
                    Some(mut masked) => {
                        masked.notes.retain(|n| {
                            (sky || !n.starts_with("sky product at"))
                                && (ground || !n.starts_with("ground product at"))
                        });
                        masked
                    }
                    None => l,
                }
            }
            _ => {
                let t = Instant::now();
                let l = lighting_for(&run.scene, &grid, engine)?;
                lighting_ms += t.elapsed().as_secs_f64() * 1e3;
                l
            }
        };
        Ok(PlannedFrame {
            plan,
            scene: run.scene,
            grid,
            settings: run.settings,
            lighting,
            timing_ms: vec![
                ("voxelize".to_string(), voxelize_ms),
                ("plan".to_string(), plan_ms),
                ("lighting".to_string(), lighting_ms),
            ],
        })
    }

    /// The scene's cloud as a grid within the renderer's limit: every source's grid size is
    /// checked against [`skybake_render::MAX_RENDER_VOXELS`] as soon as it is known and before the grid
    /// is allocated ([`skybake_physics::cloud::scene::voxelize_within`]); the error names the scene field
    /// that sets it, `cloud.voxel_size_m`.
    /// Voxels of the frame's grid when they are known before voxelising
    /// ([`skybake_physics::cloud::scene::CloudSection::planned_dims`]), else the renderer's limit
    /// [`skybake_render::MAX_RENDER_VOXELS`] (an upper bound).
    pub fn planned_voxels(&self) -> u64 {
        match self.scene.cloud.planned_dims() {
            Ok(Some(d)) => (d[0] as u64) * (d[1] as u64) * (d[2] as u64),
            _ => skybake_render::MAX_RENDER_VOXELS as u64,
        }
    }

    /// The estimated cost of the frame, in pixel-voxel-sample units: pixels × voxels × samples
    /// per pixel (the reference method's paths; one ray march per pixel for the fast method).
    /// A bound for job admission (`server.max_job_cost`), not a time prediction.
    pub fn estimated_cost(&self) -> u64 {
        let pixels = (self.scene.camera.width as u64) * (self.scene.camera.height as u64);
        let spp = match self.method {
            Method::Reference => RenderSettings::for_quality(self.scene.quality, self.method).spp,
            Method::Fast => 1,
        } as u64;
        pixels
            .saturating_mul(self.planned_voxels())
            .saturating_mul(spp.max(1))
    }

    /// Number of tiles of the frame.
    pub fn tile_count(&self) -> usize {
        tile_rects(self.scene.camera.width, self.scene.camera.height).len()
    }

    /// Renders the frame without keeping tiles and encodes it as the product's spectral image.
    /// `loader` reads the files a cloud source names (the library does no I/O); `progress` gets
    /// the fraction done and `cancel` is polled between tiles and rows.
    pub fn compute(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        progress: &(dyn Fn(f64) + Sync),
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<SpectralImage> {
        let progress = |p: TileProgress| progress(p.done as f64 / p.total.max(1) as f64);
        self.compute_tiled(engine, loader, &NoTiles, &progress, cancel)
    }

    /// Renders the frame tile by tile, taking the tiles `tiles` already holds and storing each
    /// new one there as soon as it is done, then assembles the product's spectral image. When
    /// every tile is there nothing is voxelised or lit. `cancel` is polled between tiles (and
    /// between rows inside one): a cancelled render returns an error and keeps its finished tiles.
    pub fn compute_tiled(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        tiles: &dyn TileSink,
        progress: &(dyn Fn(TileProgress) + Sync),
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<SpectralImage> {
        let cam = &self.scene.camera;
        let (w, h) = (cam.width, cam.height);
        let rgb = self.rgb_decision()?;
        let wavelengths = rgb.wavelengths(&self.scene)?;
        let n_l = wavelengths.len();
        let reference = self.method == Method::Reference;
        let rects = tile_rects(w, h);
        let total = rects.len();
        let mut canvas = Canvas {
            width: w,
            n_l,
            radiance: vec![0f32; w * h * n_l],
            transmittance: vec![0f32; w * h],
            variance: if reference {
                vec![0f32; w * h * n_l]
            } else {
                Vec::new()
            },
        };
        let mut pixels_ms = 0.0;
        let mut stored: Option<TileMeta> = None;
        let mut missing = Vec::new();
        for (i, rect) in rects.iter().enumerate() {
            match tiles
                .get(i)?
                .map(|b| self.decode_tile(&b, rect, &tiles.binding(i), &wavelengths))
            {
                Some(Some((meta, rad, tr, var))) => {
                    canvas.blit(rect, &rad, &tr, &var);
                    pixels_ms += meta.pixels_ms;
                    stored.get_or_insert(meta);
                }
                _ => missing.push(i),
            }
        }
        let reused = total - missing.len();
        progress(TileProgress {
            done: reused,
            total,
            reused,
        });
        let mut computed = 0;
        let mut this_run: Option<TileMeta> = None;
        if !missing.is_empty() {
            let PlannedFrame {
                plan,
                scene,
                grid,
                settings,
                lighting,
                timing_ms: mut preparation_ms,
            } = self.planned(engine, loader, rgb)?;
            let prepared = Prepared::new(&scene, &grid, &lighting, settings, cancel)?;
            preparation_ms.extend(prepared.timing_ms.iter().cloned());
            let meta = TileMeta {
                x0: 0,
                y0: 0,
                width: 0,
                height: 0,
                stages: StoredStages {
                    ran: prepared.stages.ran.clone(),
                    skipped: prepared.stages.skipped.clone(),
                },
                preparation_ms,
                lighting_notes: lighting.notes.clone(),
                pixels_ms: 0.0,
                plan: serde_json::to_value(&plan).ok(),
            };
            for i in missing {
                if cancel() {
                    return Err(Error::invalid("render", "cancelled"));
                }
                let rect = rects[i];
                let frame = render_tile(&prepared, Some(rect), &|_| {}, cancel)?;
                let tile_ms = frame
                    .meta
                    .timing_ms
                    .iter()
                    .rev()
                    .find(|(name, _)| name == "pixels")
                    .map_or(0.0, |(_, ms)| *ms);
                let tile_meta = TileMeta {
                    x0: rect.x0,
                    y0: rect.y0,
                    width: rect.width,
                    height: rect.height,
                    pixels_ms: tile_ms,
                    ..meta.clone()
                };
                let bytes = encode_tile(&frame, &tile_meta, &tiles.binding(i))?;
                tiles.put(i, &bytes)?;
                canvas.blit(
                    &rect,
                    &frame.radiance,
                    &frame.transmittance,
                    &frame.variance,
                );
                pixels_ms += tile_ms;
                computed += 1;
                progress(TileProgress {
                    done: reused + computed,
                    total,
                    reused,
                });
            }
            this_run = Some(meta);
        }
        let meta = this_run
            .or(stored)
            .ok_or_else(|| Error::internal("render", "a frame without tiles"))?;
        let mut timing_ms = meta.preparation_ms.clone();
        timing_ms.push(("pixels".into(), pixels_ms));
        let noise = reference.then(|| {
            relative_noise(
                &canvas.radiance,
                &canvas.variance,
                &canvas.transmittance,
                n_l,
            )
        });
        let frame = skybake_render::Frame {
            tile: Tile {
                x0: 0,
                y0: 0,
                width: w,
                height: h,
            },
            image_width: w,
            image_height: h,
            wavelengths_nm: wavelengths.as_nm().to_vec(),
            radiance: canvas.radiance,
            transmittance: canvas.transmittance,
            variance: Vec::new(),
            meta: FrameMeta {
                method: self.method,
                stages: Stages {
                    ran: meta.stages.ran,
                    skipped: meta.stages.skipped,
                },
                timing_ms,
                error_estimate: FrameError {
                    path_tracer_relative_noise: noise,
                    basis: ERROR_BASIS,
                },
                lighting_notes: meta.lighting_notes,
                plan: meta.plan,
            },
        };
        let mut image = crate::export::frame_image(&frame, &self.canonical_json())?;
        // The metadata again with its timings at a fixed width, so two computations of a request
        // (CLI, service, bake) differ only in those values' bytes.
        image.set_attribute(ATTR_FRAME_META, frame_meta_json(&frame.meta)?)?;
        image.set_attribute(
            skybake_physics::image::layout::ATTR_CACHE_KEY,
            self.cache_key(),
        )?;
        image.set_attribute(
            ATTR_FRAME_TILES,
            serde_json::json!({"tile_size": TILE_SIZE, "total": total, "computed": computed, "reused": reused})
                .to_string(),
        )?;
        Ok(image)
    }

    /// A stored tile's metadata and pixels (`[pixel][λ]` radiance, transmittance, variance), or
    /// `None` when it is not the tile `rect` of this request (then it is computed again).
    #[allow(clippy::type_complexity)]
    fn decode_tile(
        &self,
        bytes: &[u8],
        rect: &Tile,
        binding: &str,
        wavelengths: &Wavelengths,
    ) -> Option<(TileMeta, Vec<f32>, Vec<f32>, Vec<f32>)> {
        let img = decode_exr(bytes).ok()?;
        if img.attribute(ATTR_TILE_OF) != Some(binding)
            || img.wavelengths_nm() != wavelengths.as_nm()
        {
            return None;
        }
        let meta: TileMeta = serde_json::from_str(img.attribute(ATTR_TILE_META)?).ok()?;
        if (meta.x0, meta.y0, meta.width, meta.height)
            != (rect.x0, rect.y0, rect.width, rect.height)
            || (img.width(), img.height()) != (rect.width, rect.height)
        {
            return None;
        }
        let pixels = rect.width * rect.height;
        let rad = interleave(img.layer("S0")?.planes(), pixels);
        let tr = img.layer("T")?.plane(0)?.to_vec();
        let var = match (self.method, img.layer("V")) {
            (Method::Reference, Some(v)) => interleave(v.planes(), pixels),
            (Method::Reference, None) => return None,
            (Method::Fast, _) => Vec::new(),
        };
        Some((meta, rad, tr, var))
    }
}

/// Refuses a grid of more than [`skybake_render::MAX_RENDER_VOXELS`] voxels, naming the scene field that
/// sets its size.
fn check_render_voxels(dims: [usize; 3]) -> Result<()> {
    let n = (dims[0] as u64) * (dims[1] as u64) * (dims[2] as u64);
    if n > skybake_render::MAX_RENDER_VOXELS as u64 {
        return Err(Error::too_large(
            "cloud.voxel_size_m",
            format!("the grid at this voxel size is {dims:?} = {n} voxels to render"),
            format!(
                "{} voxels (use a larger voxel_size_m)",
                skybake_render::MAX_RENDER_VOXELS
            ),
        ));
    }
    Ok(())
}

/// The JSON summary of a frame artifact (`skybake render --format json`, `POST /v1/render`
/// with `format=json`): size, wavelengths, cache key, method, the stages that ran and those left
/// out, the time of each stage and in total, the error estimate and the tiles.
pub fn frame_summary(image: &SpectralImage) -> serde_json::Value {
    use serde_json::{json, Value};
    let attr = |name: &str| -> Value {
        image
            .attribute(name)
            .and_then(|t| serde_json::from_str(t).ok())
            .unwrap_or(Value::Null)
    };
    let meta = attr(ATTR_FRAME_META);
    let stages: Vec<Value> = meta["timing_ms"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|pair| json!({"stage": pair[0], "ms": pair[1]}))
                .collect()
        })
        .unwrap_or_default();
    let total_ms: f64 = stages.iter().filter_map(|s| s["ms"].as_f64()).sum();
    json!({
        "product": "frame",
        "width": image.width(),
        "height": image.height(),
        "wavelengths_nm": image.wavelengths_nm(),
        "cache_key": image.attribute(skybake_physics::image::layout::ATTR_CACHE_KEY),
        "method": meta["method"],
        "stages": meta["stages"],
        "plan": meta["plan"],
        "timing_ms": total_ms,
        "timing_ms_by_stage": stages,
        "error_estimate": meta["error_estimate"],
        "lighting_notes": meta["lighting_notes"],
        "tiles": attr(ATTR_FRAME_TILES),
    })
}

/// A rendered tile as a spectral EXR: `S0` radiance, `T` transmittance, `V` the variance of
/// each pixel's mean (reference method), the binding and the [`TileMeta`].
fn encode_tile(frame: &skybake_render::Frame, meta: &TileMeta, binding: &str) -> Result<Vec<u8>> {
    let (w, h) = (frame.tile.width, frame.tile.height);
    let n_l = frame.wavelengths_nm.len();
    let pixels = w * h;
    let mut img = SpectralImage::emissive(
        w,
        h,
        &frame.wavelengths_nm,
        planes_of(&frame.radiance, n_l, pixels),
    )?;
    img.add_layer("T", vec![frame.transmittance.clone(); n_l])?;
    if !frame.variance.is_empty() {
        img.add_layer("V", planes_of(&frame.variance, n_l, pixels))?;
    }
    img.set_attribute(ATTR_TILE_OF, binding)?;
    img.set_attribute(
        ATTR_TILE_META,
        serde_json::to_string(meta).map_err(|e| Error::internal("tile", e))?,
    )?;
    encode_exr(&img).map_err(store_error)
}

/// Voxelises a frame's cloud within the renderer's limit, checked before the grid is allocated;
/// a grid too large names the scene field that sets its size.
fn voxelize_cloud(
    cloud: &skybake_physics::cloud::scene::CloudSection,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
) -> Result<DensityGrid> {
    cloud
        .voxelize_within(loader, skybake_render::MAX_RENDER_VOXELS)
        .map_err(|e| match e {
            Error::TooLarge {
                field,
                reason,
                limit,
            } if field == "dims" => Error::TooLarge {
                field: "cloud.voxel_size_m".into(),
                reason: format!("the grid at this voxel size: {reason}"),
                limit: format!("{limit} (use a larger voxel_size_m)"),
            },
            other => other,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_image_once() {
        for (w, h) in [(1, 1), (64, 64), (65, 130), (640, 480)] {
            let rects = tile_rects(w, h);
            let mut seen = vec![0u8; w * h];
            for t in &rects {
                assert!(t.width >= 1 && t.width <= TILE_SIZE && t.height <= TILE_SIZE);
                for y in t.y0..t.y0 + t.height {
                    for x in t.x0..t.x0 + t.width {
                        seen[y * w + x] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{w}x{h}");
            assert_eq!(rects.len(), w.div_ceil(TILE_SIZE) * h.div_ceil(TILE_SIZE));
        }
    }
}
