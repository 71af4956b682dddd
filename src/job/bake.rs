//! A job run offline (`skybake bake JOB.json --out DIR`): each item becomes
//! `<out>/<index:06>-<product>-<key prefix>.exr`, the product's artifact (the same file the
//! service caches), written atomically; items whose file exists and passes its checksum are
//! reused, so a rerun after a crash resumes. `<out>/manifest.json` lists them at the end.

use super::run::MAX_KEPT_ERRORS;
use super::spec::JobSpec;
use super::store::ItemError;
use super::JobError;
use crate::engine::{Engine, ENGINE_VERSION};
use crate::product::params::Defaults;
use crate::store::{checksum, encode_exr, files, write_atomic};
use serde::Serialize;
use serde_json::json;
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

/// Runs the job `job_body` into `out` on `engine` (`store::tables::engine_for_settings` shares
/// the precise tables stored in the cache directory with the CLI and the server);
/// `progress(done, total, what)` is called per item. Every item is validated before anything is
/// computed.
pub fn bake(
    job_body: &[u8],
    out: &Path,
    defaults: &Defaults,
    max_products: usize,
    engine: &Engine,
    mut progress: impl FnMut(usize, usize, &str),
) -> Result<BakeSummary, JobError> {
    let spec = JobSpec::parse_body(job_body, max_products)?;
    spec.validate(defaults)?;
    files::create_dir_all(out)?;
    let mut summary = BakeSummary {
        total: spec.len(),
        computed: 0,
        reused: 0,
        failed: 0,
        errors: Vec::new(),
    };
    let mut manifest = Vec::new();
    for i in 0..spec.len() {
        let req = spec.request(i, defaults)?;
        let key = req.cache_key();
        let name = format!("{i:06}-{}-{}.exr", req.kind().name(), &key[..16]);
        let path = out.join(&name);
        let reusable = files::read_if_exists(&path)
            .ok()
            .flatten()
            .is_some_and(|b| checksum::verify(&b).is_ok());
        let outcome = if reusable {
            summary.reused += 1;
            Ok("reused")
        } else {
            req.compute(engine)
                .map_err(JobError::from)
                .and_then(|img| Ok(encode_exr(&img)?))
                .and_then(|bytes| Ok(write_atomic(&path, &bytes)?))
                .map(|()| {
                    summary.computed += 1;
                    "computed"
                })
        };
        match outcome {
            Ok(what) => {
                manifest.push(json!({"index": i, "product": req.kind().name(), "cache_key": key, "file": name}));
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
    let doc = json!({"engine_version": ENGINE_VERSION, "summary": summary, "artifacts": manifest});
    write_atomic(&out.join("manifest.json"), doc.to_string().as_bytes())?;
    Ok(summary)
}
