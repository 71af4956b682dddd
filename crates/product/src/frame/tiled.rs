//! A frame computed tile by tile: each finished tile goes to a [`TileSink`] and a later run of the
//! same request takes the tiles it finds there, so a crash, a kill or a cancellation loses only the
//! tile in flight.

use super::*;
use crate::artifact::FrameTileCounts;

/// Edge of a render tile, pixels.
pub const TILE_SIZE: usize = 64;
/// Header attribute of a tile: its rectangle, the preparation's stages and timings, its own
/// pixel time ([`TileMeta`] as JSON).
const ATTR_TILE_META: &str = "skybakeTileMeta";

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

impl TileSink for skybake_store::FrameTiles {
    fn get(&self, index: usize) -> Result<Option<Vec<u8>>> {
        skybake_store::FrameTiles::get(self, index).map_err(Error::from)
    }
    fn put(&self, index: usize, bytes: &[u8]) -> Result<()> {
        skybake_store::FrameTiles::put(self, index, bytes).map_err(Error::from)
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
    encode_exr(&img).map_err(Error::from)
}

impl FrameRequest {
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
            } = self.planned(engine, loader, rgb, cancel)?;
            // Now that the grid is known, a cloud whose size voxelising told is held to the caps.
            if let Some(caps) = self.caps {
                FrameCost::of(self, true, grid.data.len() as u64).check(caps)?;
            }
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
                    return Err(Error::Cancelled);
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
        let tiles = FrameTileCounts {
            tile_size: TILE_SIZE,
            total,
            computed,
            reused,
        };
        let image = crate::artifact::frame_artifact(
            &frame,
            &self.canonical_json(),
            &self.cache_key(),
            tiles,
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
