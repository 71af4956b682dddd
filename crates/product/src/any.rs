//! One interface for every product kind. The service, the CLI and bake jobs key, compute and
//! render every product (sun, sky, ground, aerial and the cloud frame) through [`AnyRequest`]:
//! one compute-to-artifact path ([`AnyRequest::compute`]) and one artifact-to-body path
//! ([`AnyRequest::body`]).

use std::sync::Arc;

use skybake_engine::engine::Engine;
use skybake_store::SpectralImage;

use crate::frame::{FrameRequest, TileProgress, TileSink};
use crate::{Format, ProductRequest, Result};

/// A validated request for any product.
#[derive(Debug, Clone)]
pub enum AnyRequest {
    /// Sun, sky, ground or aerial: a request of the parameter table.
    Atmosphere(Box<ProductRequest>),
    /// A cloud frame: a scene and a method.
    Frame(Arc<FrameRequest>),
}

/// What a computation uses besides the engine. Only a frame reads files (through `loader`: the
/// library does no I/O) and keeps tiles; every computation reports progress and stops with
/// [`crate::Error::Cancelled`] once `cancel` returns true.
pub struct ComputeEnv<'a> {
    /// Reads a file a frame's cloud source names.
    pub loader: &'a dyn Fn(&str) -> Result<Vec<u8>>,
    /// Where a frame's finished tiles are kept, and taken from by a later run.
    pub tiles: &'a dyn TileSink,
    /// Called with a frame's tiles done (once with those found, then once per tile computed).
    pub progress: &'a (dyn Fn(TileProgress) + Sync),
    /// Polled between stages, tiles and rows.
    pub cancel: &'a (dyn Fn() -> bool + Sync),
    /// What a frame shares with the frames computed before it (a sequence's grid and lit
    /// volume); `None`: computed alone.
    pub reuse: Option<&'a crate::frame::FrameReuse>,
}

impl AnyRequest {
    /// The product's name: `sun`, `sky`, `ground`, `aerial` or `frame`.
    pub fn name(&self) -> &'static str {
        match self {
            AnyRequest::Atmosphere(r) => r.kind().name(),
            AnyRequest::Frame(_) => "frame",
        }
    }

    /// The cache key: blake3 of the canonical request and the engine version.
    pub fn cache_key(&self) -> String {
        match self {
            AnyRequest::Atmosphere(r) => r.cache_key(),
            AnyRequest::Frame(r) => r.cache_key(),
        }
    }

    /// Computes the product's artifact: the spectral image with its request, response, plan,
    /// error estimate and timing attributes ([`crate::artifact`]). CPU-heavy: call from a
    /// blocking thread.
    pub fn compute(&self, engine: &Engine, env: &ComputeEnv) -> Result<SpectralImage> {
        match self {
            AnyRequest::Atmosphere(r) => r.compute_cancellable(engine, env.cancel),
            AnyRequest::Frame(r) => r.compute_tiled_with(
                engine,
                env.loader,
                env.tiles,
                env.progress,
                env.reuse,
                env.cancel,
            ),
        }
    }

    /// The response body in `format`, rendered from the artifact `image`.
    pub fn body(&self, format: Format, image: &SpectralImage) -> Result<Vec<u8>> {
        match self {
            AnyRequest::Atmosphere(r) => crate::artifact::render(r.kind(), format, image),
            AnyRequest::Frame(_) => crate::artifact::render_frame(format, image),
        }
    }
}
