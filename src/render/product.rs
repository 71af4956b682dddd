//! The `frame` product: scene JSON → voxelised cloud → lighting from the engine → rendered frame →
//! spectral image (the artifact). The CLI (`skybake render`), the service (`POST /v1/render`) and
//! the cache all run this one path, so the `-o` file and the HTTP EXR of a scene are the same.

use super::{lighting_for, render_frame, FrameScene, Method, RenderSettings};
use crate::engine::Engine;
use crate::store::SpectralImage;
use crate::{Error, Result};

/// A validated frame request: the scene (as parsed JSON, for the canonical form) and the method.
#[derive(Debug, Clone)]
pub struct FrameRequest {
    pub scene: FrameScene,
    scene_json: serde_json::Value,
    pub method: Method,
}

impl FrameRequest {
    /// Parses and validates a scene file's bytes (errors name the field and its range).
    pub fn parse(scene_json: &[u8], method: Method) -> Result<Self> {
        let scene = FrameScene::parse(scene_json)?;
        let value: serde_json::Value = serde_json::from_slice(scene_json)
            .map_err(|e| Error::invalid("scene", e.to_string()))?;
        Ok(Self {
            scene,
            scene_json: value,
            method,
        })
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
        serde_json::json!({"product": "frame", "method": self.method, "scene": scene}).to_string()
    }

    /// The cache key: blake3 of the canonical request and the engine version.
    pub fn cache_key(&self) -> String {
        crate::store::cache_key(&self.canonical_json(), crate::engine::ENGINE_VERSION)
    }

    /// Renders the frame and encodes it as the product's spectral image. `loader` reads the files
    /// a cloud source names (the library does no I/O); `progress` gets the fraction done and
    /// `cancel` is polled between rows.
    pub fn compute(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        progress: &(dyn Fn(f64) + Sync),
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<SpectralImage> {
        let grid = self.scene.cloud.voxelize(loader)?;
        let lighting = lighting_for(&self.scene, &grid, engine)?;
        let settings = RenderSettings::for_quality(self.scene.quality, self.method);
        let frame = render_frame(
            &self.scene,
            &grid,
            &lighting,
            &settings,
            None,
            progress,
            cancel,
        )?;
        let mut image = crate::export::frame_image(&frame, &self.canonical_json())?;
        image.set_attribute(crate::store::layout::ATTR_CACHE_KEY, self.cache_key())?;
        Ok(image)
    }
}
