//! The light from outside the cloud kept for the next frame of a sequence: the frames of a camera
//! path (a fly-around at a constant height, whose rays reach the ground bound) ask the engine for
//! the same products with the same inputs. [`Lighting::from_scene`] is a function of the inputs
//! it reads (the scene's sun, sky, ground, atmosphere, wavelengths, quality, lighting switches
//! and the camera's height, the cloud's altitude and the aerial product's reach) and of the
//! engine's tables, so a [`LightingMemo`] keyed by those inputs and the engine's identity
//! returns the lighting computed alone, bit for bit.

use crate::lighting::Lighting;
use crate::scene::FrameScene;
use crate::Result;
use skybake_engine::engine::Engine;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// Lightings a memo keeps (most recent first): a sequence's frames, in turn, at two camera
/// heights or two ground bounds.
const KEPT: usize = 2;

/// The lightings of the last frames, by their inputs (see the module's documentation).
#[derive(Default)]
pub struct LightingMemo {
    kept: Mutex<Vec<(String, Lighting)>>,
    reused: AtomicU64,
    computed: AtomicU64,
}

impl LightingMemo {
    pub fn new() -> Self {
        Self::default()
    }

    /// How many lightings were taken from the memo and how many were computed.
    pub fn counts(&self) -> (u64, u64) {
        (
            self.reused.load(Ordering::Relaxed),
            self.computed.load(Ordering::Relaxed),
        )
    }

    /// The lighting kept for equal inputs, or `make`'s (then kept). Without a key (an input
    /// that is not a number) nothing is kept.
    pub(crate) fn get_or(
        &self,
        key: Option<String>,
        make: impl FnOnce() -> Result<Lighting>,
    ) -> Result<Lighting> {
        let Some(key) = key else {
            self.computed.fetch_add(1, Ordering::Relaxed);
            return make();
        };
        if let Some(l) = self
            .lock()
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, l)| l.clone())
        {
            self.reused.fetch_add(1, Ordering::Relaxed);
            return Ok(l);
        }
        // Computed outside the lock (an error or a cancellation keeps nothing).
        let l = make()?;
        self.computed.fetch_add(1, Ordering::Relaxed);
        let mut kept = self.lock();
        kept.retain(|(k, _)| *k != key);
        kept.insert(0, (key, l.clone()));
        kept.truncate(KEPT);
        Ok(l)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(String, Lighting)>> {
        // A panic while holding the lock leaves only a cache behind: keep using it.
        self.kept.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The inputs [`Lighting::from_scene_unless`] reads, as text: `{:?}` writes each `f64` as the
/// shortest decimal that reads back to the same value, the sign of zero included, so equal text
/// means equal inputs. `None` when an input is not a number (NaN's payloads print alike).
pub(crate) fn key(
    scene: &FrameScene,
    engine: &Engine,
    cloud_altitude_m: f64,
    max_view_distance_m: f64,
) -> Option<String> {
    let key = format!(
        "{}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}",
        engine.id(),
        scene.wavelengths,
        scene.sun,
        scene.atmosphere,
        scene.sky,
        scene.ground,
        scene.quality,
        scene.lighting,
        scene.camera.position_m.z,
        cloud_altitude_m,
        max_view_distance_m,
    );
    (!key.contains("NaN")).then_some(key)
}
