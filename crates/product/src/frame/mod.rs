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

mod examples;
mod planning;
mod tiled;

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use skybake_engine::engine::{Engine, Stages};
use skybake_engine::plan::{FrameFacts, FramePlan, FrameReason, FrameStage, RgbFacts, SphereFacts};
use skybake_physics::cloud::DensityGrid;
use skybake_physics::spectrum::Wavelengths;
use skybake_render::{
    lighting_for_unless, relative_noise, render_tile, FrameError, FrameMeta, FrameScene, Method,
    Prepared, RenderSettings, Tile, ERROR_BASIS,
};
use skybake_store::tiles::ATTR_TILE_OF;
use skybake_store::{decode_exr, encode_exr, SpectralImage};
use std::time::Instant;

pub use examples::{example_file, example_scene, EXAMPLE_SCENES};
pub use planning::*;
pub use tiled::*;

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
    /// The caps a request is held to once its cloud is voxelised ([`Self::with_caps`]); not part
    /// of the request (its key).
    pub caps: Option<FrameCaps>,
}

/// The frame cost cap and memory cap of a request (`server.max_frame_cost`,
/// `server.max_request_memory_bytes`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameCaps {
    pub max_cost: u64,
    pub max_memory_bytes: u64,
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
            caps: None,
        })
    }

    /// Holds the request to `caps` once its grid is known: a cloud whose size only voxelising
    /// tells (grid file, satellite fit, fractal growth, sphere hierarchy) is refused after it is
    /// voxelised and before anything is lit or rendered ([`FrameCost::check`]).
    pub fn with_caps(mut self, caps: Option<FrameCaps>) -> Self {
        self.caps = caps;
        self
    }

    /// Marks the request RGB-only (`rgb_only`: its only output is the RGB image, a PNG): the
    /// planner may then run it at a subset of its wavelengths where the error budget allows
    /// (`plan::rgb_wavelengths_rule`). An RGB-only request has its own cache key (its artifact's
    /// spectral planes are at the wavelengths it ran at).
    pub fn with_rgb_only(mut self, rgb_only: bool) -> Self {
        self.rgb_only = rgb_only;
        self
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

    /// Checks that `loader` gives every file the scene's cloud names (before any work, e.g. at a
    /// job's submission); the error names the field (`cloud.source.path`).
    pub fn check_files(&self, loader: &dyn Fn(&str) -> Result<Vec<u8>>) -> Result<()> {
        for (field, path) in self.scene.cloud.source.files() {
            loader(&path)
                .map_err(|e| Error::invalid(&format!("cloud.{field}"), format!("'{path}': {e}")))?;
        }
        Ok(())
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
    /// A bound for job admission (`server.max_job_cost`), not a time prediction; an automaton's
    /// steps count too ([`FrameCost`]).
    pub fn estimated_cost(&self) -> u64 {
        self.request_cost().units
    }

    /// The cost of computing the frame, with the renderer's voxel limit for a cloud whose size
    /// is not known before voxelising (an upper bound; job admission), see [`FrameCost`].
    pub fn request_cost(&self) -> FrameCost {
        FrameCost::of(self, true, self.planned_voxels())
    }

    /// The cost of computing the frame as far as it is known before voxelising: a cloud whose
    /// size only voxelising tells counts no voxel here and is checked again once voxelised
    /// ([`Self::with_caps`]).
    pub fn admission_cost(&self) -> FrameCost {
        FrameCost::of(self, true, self.known_voxels())
    }

    /// The cost of planning the frame (`POST /v1/plan`: voxelising, the automaton's steps and the
    /// light at the cloud; no pixel), see [`FrameCost`].
    pub fn planning_cost(&self) -> FrameCost {
        FrameCost::of(self, false, self.known_voxels())
    }

    /// Voxels of the frame's grid when its parameters give them, else 0.
    fn known_voxels(&self) -> u64 {
        match self.scene.cloud.planned_dims() {
            Ok(Some(d)) => (d[0] as u64) * (d[1] as u64) * (d[2] as u64),
            _ => 0,
        }
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
}

/// Pixel-voxel-sample units one automaton cell-step is charged: the measured time of a step over
/// the measured time of one unit (release build, one core: the automaton-field scene's 655 360
/// cells take 0.36 ms a step, 1.8e9 cell-steps/s; 640×480 fast and 160×120 reference frames of
/// the cumulus-frame scene run 2.2e10–2.4e10 pixel-voxel-samples/s), rounded up.
pub const UNITS_PER_CELL_STEP: u64 = 12;

/// The estimated cost and peak memory of a frame request, before anything is voxelised:
/// `units = pixels × voxels × samples + UNITS_PER_CELL_STEP × automaton cells × steps` (the job
/// estimate's pixel-voxel-samples plus the simulation; planning counts no pixel), and
/// `memory_bytes` the peak of what the request holds at once (see [`Self::of`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct FrameCost {
    pub pixels: u64,
    pub voxels: u64,
    pub samples_per_pixel: u64,
    /// Cells × steps the automaton runs (0 for the other sources).
    pub automaton_cell_steps: u64,
    pub units: u64,
    pub memory_bytes: u64,
}

impl FrameCost {
    /// The estimate; `with_pixels` false for planning (no pixel is rendered). Memory, in 4-byte
    /// values: the image five times over (the tile canvas, the assembled spectral image, its EXR
    /// encoding in the cache, the response body and a decoded copy for PNG/JSON bodies), each
    /// `wavelengths + 4` planes (radiance, transmittance, RGB; the reference method's variance
    /// adds `wavelengths`); the grid with its per-voxel light, `3 × wavelengths + 2` values a voxel;
    /// the automaton's state and its density fields, 6 values a cell. An upper bound as
    /// measured: a 1024² fast frame of the cumulus-frame scene (3 wavelengths) peaks at 118 MB RSS
    /// in `skybake render` (estimate 159 MB), a 4096² one at 1.73 GB in the service (2.36 GB).
    pub fn of(req: &FrameRequest, with_pixels: bool, voxels: u64) -> Self {
        use skybake_physics::cloud::scene::CloudSource;
        let cam = &req.scene.camera;
        let pixels = if with_pixels {
            (cam.width as u64) * (cam.height as u64)
        } else {
            0
        };
        let spp = match req.method {
            Method::Reference => RenderSettings::for_quality(req.scene.quality, req.method).spp,
            Method::Fast => 1,
        }
        .max(1) as u64;
        let (cells, steps) = match &req.scene.cloud.source {
            CloudSource::Automaton(a) => {
                let d = a.params.dims;
                let cells = (d[0] as u64) * (d[1] as u64) * (d[2] as u64);
                // The steps run: to the frame's step and the next, plus the smoothing window.
                let steps =
                    a.frame_time_steps.max(0.0).ceil() as u64 + 1 + a.params.smoothing.t0 as u64;
                (cells, steps)
            }
            _ => (0, 0),
        };
        let automaton_cell_steps = cells.saturating_mul(steps);
        let units = pixels
            .saturating_mul(voxels)
            .saturating_mul(spp)
            .saturating_add(automaton_cell_steps.saturating_mul(UNITS_PER_CELL_STEP));
        let n_l = req.scene.wavelengths.len() as u64;
        let planes = n_l
            + 4
            + if req.method == Method::Reference {
                n_l
            } else {
                0
            };
        let memory_values = pixels
            .saturating_mul(planes)
            .saturating_mul(5)
            .saturating_add(voxels.saturating_mul(3 * n_l + 2))
            .saturating_add(cells.saturating_mul(6));
        FrameCost {
            pixels,
            voxels,
            samples_per_pixel: spp,
            automaton_cell_steps,
            units,
            memory_bytes: memory_values.saturating_mul(4),
        }
    }

    /// Refuses (too large) a cost over `caps.max_cost`, naming `request_cost`, or a peak memory
    /// over `caps.max_memory_bytes`, naming `request_memory`, with the terms and the limit.
    pub fn check(&self, caps: FrameCaps) -> Result<()> {
        if self.units > caps.max_cost {
            return Err(Error::too_large(
                "request_cost",
                format!(
                    "estimated cost {} pixel-voxel-samples (pixels {} × voxels {} × samples per pixel {} + {UNITS_PER_CELL_STEP} × automaton cell-steps {}) exceeds the budget server.max_frame_cost; lower the size, voxel count, quality or automaton steps, or submit it as a job (POST /v1/jobs)",
                    self.units, self.pixels, self.voxels, self.samples_per_pixel, self.automaton_cell_steps
                ),
                caps.max_cost,
            ));
        }
        if self.memory_bytes > caps.max_memory_bytes {
            return Err(Error::too_large(
                "request_memory",
                format!(
                    "estimated peak memory {} bytes (pixels {}, voxels {}) exceeds server.max_request_memory_bytes; lower the image size, wavelengths or voxel count",
                    self.memory_bytes, self.pixels, self.voxels
                ),
                caps.max_memory_bytes,
            ));
        }
        Ok(())
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
