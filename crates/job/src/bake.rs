//! A job run offline (`skybake bake JOB.json --out DIR`): each item becomes
//! `<out>/<index:06>-<product>-<key prefix>.exr`, the product's artifact (the same file the
//! service caches), written atomically; items whose file exists and passes its checksum are
//! reused, so a rerun after a crash resumes. A frame item keeps its finished tiles under
//! `<out>/tiles/` until its EXR is written, so a rerun also resumes inside a frame.
//! `<out>/manifest.json` lists them at the end.

use super::run::MAX_KEPT_ERRORS;
use super::spec::JobSpec;
use super::store::ItemError;
use super::JobError;
use serde::Serialize;
use serde_json::json;
use skybake_engine::engine::{Engine, ENGINE_VERSION};
use skybake_product::params::Defaults;
use skybake_product::{AnyRequest, ComputeEnv};
use skybake_store::{checksum, encode_exr, files, write_atomic, TileStore};
use std::path::Path;

/// Summary of an offline bake.
#[derive(Debug, Clone, Serialize)]
pub struct BakeSummary {
    pub total: usize,
    /// Computed in this run.
    pub computed: usize,
    /// Already in the output directory (verified) from an earlier run.
    pub reused: usize,
    pub failed: usize,
    pub errors: Vec<ItemError>,
}

/// Runs the job `job_body` into `out` on `engine` (`skybake_product::engines::engine_for_settings` shares
/// the precise tables stored in the cache directory with the CLI and the server);
/// `progress(done, total, what)` is called per item. Every item is validated before anything is
/// computed.
pub fn bake(
    job_body: &[u8],
    out: &Path,
    defaults: &Defaults,
    max_products: usize,
    engine: &Engine,
    progress: impl FnMut(usize, usize, &str),
) -> Result<BakeSummary, JobError> {
    bake_with_cancel(
        job_body,
        out,
        defaults,
        max_products,
        engine,
        progress,
        &|| false,
    )
}

/// [`bake`] that stops when `cancel` returns true (polled between items and between the tiles of
/// a frame): what is finished stays in `out` and a rerun resumes from it.
pub fn bake_with_cancel(
    job_body: &[u8],
    out: &Path,
    defaults: &Defaults,
    max_products: usize,
    engine: &Engine,
    mut progress: impl FnMut(usize, usize, &str),
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<BakeSummary, JobError> {
    let spec = JobSpec::parse_body(job_body, max_products)?;
    spec.validate(defaults)?;
    files::create_dir_all(out)?;
    let tiles = TileStore::open(&out.join("tiles"))?;
    let mut summary = BakeSummary {
        total: spec.len(),
        computed: 0,
        reused: 0,
        failed: 0,
        errors: Vec::new(),
    };
    let mut manifest = Vec::new();
    for i in 0..spec.len() {
        if cancel() {
            return Err(JobError::Failure(format!(
                "bake cancelled before item {i}; a rerun resumes"
            )));
        }
        let req = spec.request(i, defaults)?;
        let key = req.cache_key();
        let name = format!("{i:06}-{}-{}.exr", req.name(), &key[..16]);
        let path = out.join(&name);
        let reusable = files::read_if_exists(&path)
            .ok()
            .flatten()
            .is_some_and(|b| checksum::verify(&b).is_ok());
        let outcome = if reusable {
            summary.reused += 1;
            Ok("reused")
        } else {
            compute(&req, engine, &tiles, &key, cancel)
                .and_then(|img| Ok(encode_exr(&img)?))
                .and_then(|bytes| Ok(write_atomic(&path, &bytes)?))
                .map(|()| {
                    summary.computed += 1;
                    "computed"
                })
        };
        if outcome.is_err() && cancel() {
            return Err(JobError::Failure(format!(
                "bake cancelled in item {i}; its finished tiles are kept and a rerun resumes"
            )));
        }
        if outcome.is_ok() {
            if let AnyRequest::Frame(_) = req {
                tiles.frame(&key)?.remove_all()?;
            }
        }
        match outcome {
            Ok(what) => {
                manifest.push(
                    json!({"index": i, "product": req.name(), "cache_key": key, "file": name}),
                );
                progress(i + 1, spec.len(), what);
            }
            Err(e) => {
                summary.failed += 1;
                if summary.errors.len() < MAX_KEPT_ERRORS {
                    summary.errors.push(ItemError {
                        index: i,
                        parameter: e.parameter(),
                        detail: e.to_string(),
                    });
                }
                progress(i + 1, spec.len(), "failed");
            }
        }
    }
    tiles.remove_empty()?;
    let doc = json!({"engine_version": ENGINE_VERSION, "summary": summary, "artifacts": manifest});
    write_atomic(&out.join("manifest.json"), doc.to_string().as_bytes())?;
    Ok(summary)
}

/// The artifact of one item; a frame renders tile by tile into `tiles` (scenes may name only the
/// example scenes' embedded files, as in the service).
fn compute(
    req: &AnyRequest,
    engine: &Engine,
    tiles: &TileStore,
    key: &str,
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<skybake_physics::image::SpectralImage, JobError> {
    let frame_tiles = tiles.frame(key)?;
    let env = ComputeEnv {
        loader: &skybake_product::frame::example_file,
        tiles: &frame_tiles,
        progress: &|_| {},
        cancel,
    };
    Ok(req.compute(engine, &env)?)
}
