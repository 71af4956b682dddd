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
    lighting_for, relative_noise, render_tile, FrameError, FrameMeta, FrameScene, Method, Prepared,
    RenderSettings, Tile, ERROR_BASIS,
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
