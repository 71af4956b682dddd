//! What frames of a sequence share: a camera path (fly-around, approach) lights the cloud once,
//! a sun sweep voxelises it once. [`FrameReuse`] keeps the last voxelised grids (keyed by the
//! cloud section, the sphere level the plan chose and the bytes of the files it names) and the
//! last lit volumes ([`LitVolume`]: the renderer's camera-independent per-voxel light, found by
//! equal [`LitInputs`]), within a byte budget. Both are functions of their keys alone, so a
//! frame computed with reuse is the frame computed alone, bit for bit (tests/products/
//! frame_sequence.rs); the CLI's bakes, the service's renders and its job items each hold one.

use crate::Result;
use skybake_engine::engine::Engine;
use skybake_physics::cloud::DensityGrid;
use skybake_render::{
    FrameScene, Lighting, LightingMemo, LitInputs, LitVolume, Prepared, RenderSettings,
};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

/// Default byte budget of a [`FrameReuse`] (grids and lit volumes held between frames): the
/// bench cumulus's lit volume (128³ voxels, sky light and multiple scattering) takes 186 MB
/// with the sky light's transmittances its later cameras read (measured, `skybake-harness
/// bench frame-sequence`); the largest grid the renderer accepts lit with sky light about 0.5 GB, and is then
/// used for its frame without being kept.
pub const DEFAULT_REUSE_BYTES: usize = 384 << 20;

/// Grids and lit volumes kept at most, each.
const MAX_ENTRIES: usize = 2;

/// Counters of a [`FrameReuse`] (what was shared and what was computed).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ReuseCounts {
    pub grids_reused: u64,
    pub grids_computed: u64,
    pub lit_reused: u64,
    pub lit_computed: u64,
    /// The light from outside the cloud (the engine's products), taken from an earlier frame
    /// with the same inputs, or computed.
    pub lighting_reused: u64,
    pub lighting_computed: u64,
}

#[derive(Default)]
struct State {
    grids: VecDeque<(String, Arc<DensityGrid>)>,
    lit: VecDeque<Arc<LitVolume>>,
    counts: ReuseCounts,
}

/// The shared state of a sequence of frames (see the module's documentation).
pub struct FrameReuse {
    state: Mutex<State>,
    budget_bytes: usize,
    lighting: LightingMemo,
}

impl Default for FrameReuse {
    fn default() -> Self {
        Self::new(DEFAULT_REUSE_BYTES)
    }
}

impl FrameReuse {
    /// Keeps at most `budget_bytes` between frames (0: nothing is kept, every frame computes
    /// everything).
    pub fn new(budget_bytes: usize) -> Self {
        Self {
            state: Mutex::new(State::default()),
            budget_bytes,
            lighting: LightingMemo::new(),
        }
    }

    /// What was shared so far.
    pub fn counts(&self) -> ReuseCounts {
        let (lighting_reused, lighting_computed) = self.lighting.counts();
        ReuseCounts {
            lighting_reused,
            lighting_computed,
            ..self.lock().counts
        }
    }

    /// The light from outside the cloud for `scene`, kept from an earlier frame with the same
    /// inputs (the engine's products are functions of them: the same values).
    pub(super) fn lighting(
        &self,
        scene: &FrameScene,
        grid: &DensityGrid,
        engine: &Engine,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<Lighting> {
        skybake_render::lighting_for_memo_unless(scene, grid, engine, &self.lighting, cancel)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // A panic while holding the lock leaves only caches behind: keep using them.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The grid kept under `key`, or `make`'s (kept when within the budget).
    pub(super) fn grid(
        &self,
        key: &str,
        make: impl FnOnce() -> Result<DensityGrid>,
    ) -> Result<Arc<DensityGrid>> {
        {
            let mut s = self.lock();
            if let Some(g) = s
                .grids
                .iter()
                .find(|(k, _)| k == key)
                .map(|(_, g)| g.clone())
            {
                s.counts.grids_reused += 1;
                return Ok(g);
            }
        }
        let grid = Arc::new(make()?);
        let mut s = self.lock();
        s.counts.grids_computed += 1;
        if 4 * grid.data.len() <= self.budget_bytes / 2 {
            s.grids.push_front((key.to_string(), grid.clone()));
            s.grids.truncate(MAX_ENTRIES);
        }
        Ok(grid)
    }

    /// The frame's preparation on a lit volume kept for equal inputs, or on a new one (kept
    /// when within the budget). `cancel` is polled between stages.
    pub fn prepare<'a>(
        &self,
        scene: &'a FrameScene,
        grid: Arc<DensityGrid>,
        lighting: &'a Lighting,
        settings: RenderSettings,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<Prepared<'a>> {
        let inputs = LitInputs::new(scene, grid, lighting, settings);
        let found = {
            let mut s = self.lock();
            let found = s.lit.iter().find(|l| l.inputs.same_as(&inputs)).cloned();
            if found.is_some() {
                s.counts.lit_reused += 1;
            }
            found
        };
        let (lit, shared) = match found {
            Some(lit) => (lit, true),
            None => {
                let lit = Arc::new(LitVolume::new(inputs, cancel)?);
                let mut s = self.lock();
                s.counts.lit_computed += 1;
                if lit.bytes <= self.budget_bytes {
                    s.lit.push_front(lit.clone());
                    s.lit.truncate(MAX_ENTRIES);
                    // Oldest out until the kept volumes fit the budget.
                    while s.lit.iter().map(|l| l.bytes).sum::<usize>() > self.budget_bytes {
                        s.lit.pop_back();
                    }
                }
                (lit, false)
            }
        };
        Prepared::with_lit(scene, lighting, settings, lit, shared, cancel)
    }
}

/// The key of a voxelised grid: the cloud section as given (canonical JSON), the sphere level the
/// plan chose and the blake3 of each file the cloud names, as `loader` gives it now.
pub(super) fn grid_key(
    cloud_json: &serde_json::Value,
    sphere_level: &str,
    files: &[(&'static str, String)],
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
) -> Result<String> {
    let mut h = blake3::Hasher::new();
    h.update(b"skybake frame grid v1\0");
    let cloud = cloud_json.to_string();
    for part in [cloud.as_str(), sphere_level] {
        h.update(&(part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    for (field, path) in files {
        let bytes = loader(path).map_err(|e| {
            crate::Error::invalid(&format!("cloud.{field}"), format!("'{path}': {e}"))
        })?;
        h.update(&(path.len() as u64).to_le_bytes());
        h.update(path.as_bytes());
        h.update(blake3::hash(&bytes).as_bytes());
    }
    Ok(h.finalize().to_hex().to_string())
}
