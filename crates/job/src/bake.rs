//! A job run offline (`skybake bake JOB.json --out DIR`): each item becomes
//! `<out>/<index:06>-<product>-<key prefix>.exr`, the product's artifact (the same file the
//! service caches), written atomically; items whose file exists, passes its checksum and carries
//! the item's cache key are reused, so a rerun after a crash resumes. A frame item keeps its
//! finished tiles under `<out>/tiles/` until its EXR is written, so a rerun also resumes inside a
//! frame. A texture-bundle item (`"bundles"`, docs/lut.md) becomes its textures
//! `<index:06>-lut-<key prefix>-<texture>.exr` and, written last, its bundle manifest
//! `<index:06>-lut-<key prefix>.json` whose `links` name them; it is reused when that manifest
//! is for the same request and engine version and every texture it links passes its checksum.
//! `<out>/manifest.json` lists them at the end.
//!
//! `<out>` may be a folder in a bucket (`s3://bucket/prefix`), and the items may be shared among
//! processes ([`Shard`]: item `i` belongs to shard `i mod N`). Each shard writes
//! `shard-<I>-of-<N>.json` (its summary) when its share is done, and the shard that finds every
//! item present writes the manifest; [`status`] reports progress over all shards.

use super::run::MAX_KEPT_ERRORS;
use super::spec::{JobItem, JobSpec};
use super::store::ItemError;
use super::JobError;
use serde::Serialize;
use serde_json::json;
use skybake_engine::engine::{Engine, ENGINE_VERSION};
use skybake_physics::image::layout::ATTR_CACHE_KEY;
use skybake_product::cloud_light::CloudLightRequest;
use skybake_product::frame::FrameReuse;
use skybake_product::lut::LutRequest;
use skybake_product::params::Defaults;
use skybake_product::{AnyRequest, ComputeEnv};
use skybake_store::exr::header_text_attribute;
use skybake_store::{checksum, encode_exr, Location, TileStore};
use std::path::Path;

/// Most processes one bake can be shared among.
pub const MAX_SHARDS: usize = 10_000;

/// The share of a job's items one process bakes: item `i` belongs to shard `i mod count`
/// (round robin, so shares differ by at most one item and a grid's heavy corner is spread out).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// Every item, in one process.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Shard `index` of `count` (`0 <= index < count <= MAX_SHARDS`).
    pub fn new(index: usize, count: usize) -> Result<Self, JobError> {
        if !(1..=MAX_SHARDS).contains(&count) {
            return Err(crate::Error::out_of_range(
                "shard",
                count,
                format!("1 to {MAX_SHARDS} shards"),
            )
            .into());
        }
        if index >= count {
            return Err(crate::Error::out_of_range(
                "shard",
                index,
                format!("0 to {} (the shard count less one)", count - 1),
            )
            .into());
        }
        Ok(Self { index, count })
    }

    /// `I/N`, e.g. `3/8`.
    pub fn parse(text: &str) -> Result<Self, JobError> {
        let bad = || {
            JobError::from(crate::Error::invalid(
                "shard",
                format!("{text:?}: expected I/N, the shard index (from 0) and count, e.g. 0/4"),
            ))
        };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let i = i.trim().parse().map_err(|_| bad())?;
        let n = n.trim().parse().map_err(|_| bad())?;
        Self::new(i, n)
    }

    /// Whether item `i` is this shard's.
    pub fn owns(&self, i: usize) -> bool {
        i % self.count == self.index
    }

    /// The name of this shard's summary file.
    fn file_name(&self) -> String {
        format!("shard-{:04}-of-{:04}.json", self.index, self.count)
    }
}

/// Summary of an offline bake.
#[derive(Debug, Clone, Serialize)]
pub struct BakeSummary {
    /// This process's share (`0/1`: the whole job).
    pub shard: Shard,
    /// Items in this share.
    pub total: usize,
    /// Computed in this run.
    pub computed: usize,
    /// Already in the output directory (verified) from an earlier run.
    pub reused: usize,
    /// Stored files found corrupt, truncated or bound to another key (each recomputed).
    pub rejected: usize,
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
    progress: impl FnMut(usize, usize, &str),
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<BakeSummary, JobError> {
    let out = Location::Dir(out.to_path_buf());
    let env = BakeEnv {
        defaults,
        max_products,
        engine,
        cancel,
    };
    bake_share(job_body, &out, Shard::ALL, &env, progress)
}

/// What a bake runs with: the defaults and product limit of the settings, the engine, and a
/// cancellation poll (between items and between the tiles of a frame).
pub struct BakeEnv<'a> {
    pub defaults: &'a Defaults,
    pub max_products: usize,
    pub engine: &'a Engine,
    pub cancel: &'a (dyn Fn() -> bool + Sync),
}

/// The file of item `i`: its artifact, or a bundle's manifest.
fn item_file(i: usize, item: &JobItem, key: &str) -> String {
    match item {
        JobItem::Artifact(req) => format!("{i:06}-{}-{}.exr", req.name(), &key[..16]),
        JobItem::Bundle(_) => format!("{i:06}-lut-{}.json", &key[..16]),
        JobItem::CloudLight(_) => format!("{i:06}-cloud_light-{}.json", &key[..16]),
    }
}

/// The cache key and product name of an item.
fn item_key(item: &JobItem) -> (String, &'static str) {
    match item {
        JobItem::Artifact(req) => (req.cache_key(), req.name()),
        JobItem::Bundle(b) => (b.cache_key(), "lut"),
        JobItem::CloudLight(c) => (c.cache_key(), "cloud_light"),
    }
}

/// Whether the bundle manifest `bytes` in `out` is a finished bake of `req`: the same request
/// and engine version, and every texture it links is there and passes its checksum.
fn is_bundle_of(bytes: &[u8], req: &LutRequest, out: &Location) -> Result<bool, JobError> {
    is_files_of(bytes, &req.canonical(), out)
}

/// Whether the manifest `bytes` in `out` (a bundle's or a pre-lit cloud volume's) is a finished
/// bake of the canonical request `canonical`: the same request and engine version, and every
/// file it links is there and passes its checksum.
fn is_files_of(
    bytes: &[u8],
    canonical: &serde_json::Value,
    out: &Location,
) -> Result<bool, JobError> {
    let Ok(manifest) = serde_json::from_slice::<serde_json::Value>(bytes) else {
        return Ok(false);
    };
    if manifest["request"] != *canonical || manifest["engine_version"] != ENGINE_VERSION {
        return Ok(false);
    }
    let Some(links) = manifest["links"].as_object() else {
        return Ok(false);
    };
    for name in links.values() {
        let Some(name) = name.as_str() else {
            return Ok(false);
        };
        match out.get(name)? {
            Some(texture) if checksum::verify(&texture).is_ok() => {}
            _ => return Ok(false),
        }
    }
    Ok(true)
}

/// Computes bundle `req` and writes its textures, then its manifest `name` (with `links` to
/// them), into `out`. `cancel` is polled inside the tables' build and once per texture row.
fn bake_bundle(
    req: &LutRequest,
    engine: &Engine,
    out: &Location,
    name: &str,
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<(), JobError> {
    let (files, _) = req.compute_files_unless(engine, cancel)?;
    put_linked(files, None, out, name)
}

/// Computes the pre-lit cloud volume `req` (files the scene names: the example scenes' only,
/// as for frames) and writes its textures, then its manifest `name` with the request, the
/// engine version and `links` to them, into `out`.
fn bake_cloud_light(
    req: &CloudLightRequest,
    engine: &Engine,
    out: &Location,
    name: &str,
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<(), JobError> {
    let computed = req.compute(engine, &skybake_product::frame::example_file, cancel)?;
    put_linked(computed.light.files()?, Some(req.canonical()), out, name)
}

/// Writes `files` (textures, then `manifest.json`) into `out`: each texture as `<stem>-<file>`,
/// then the manifest as `name` with `links` to them (and `request`, `engine_version` when
/// `request` is given).
fn put_linked(
    files: Vec<(&'static str, Vec<u8>)>,
    request: Option<serde_json::Value>,
    out: &Location,
    name: &str,
) -> Result<(), JobError> {
    let stem = name.trim_end_matches(".json");
    let mut links = serde_json::Map::new();
    let mut manifest = None;
    for (file, bytes) in files {
        if file == skybake_product::lut::MANIFEST_FILE {
            manifest = Some(bytes);
            continue;
        }
        let stored = format!("{stem}-{file}");
        out.put(&stored, &bytes)?;
        links.insert(file.into(), stored.into());
    }
    let manifest = manifest.ok_or_else(|| JobError::Failure("bundle without a manifest".into()))?;
    let mut manifest: serde_json::Value = serde_json::from_slice(&manifest)
        .map_err(|e| JobError::Failure(format!("bundle manifest: {e}")))?;
    manifest["links"] = links.into();
    if let Some(request) = request {
        manifest["request"] = request;
        manifest["engine_version"] = ENGINE_VERSION.into();
    }
    let text = serde_json::to_vec_pretty(&manifest)
        .map_err(|e| JobError::Failure(format!("bundle manifest: {e}")))?;
    Ok(out.put(name, &text)?)
}

/// Whether `bytes` are a stored artifact of `key`: the whole-file checksum holds and the file
/// carries the key.
fn is_artifact_of(bytes: &[u8], key: &str) -> bool {
    checksum::verify(bytes).is_ok()
        && header_text_attribute(bytes, ATTR_CACHE_KEY)
            .ok()
            .flatten()
            .is_some_and(|k| k == key)
}

/// Bakes `shard`'s share of the job into `out` (a directory or a bucket folder); see the module
/// documentation. `progress(done, total, what)` counts this share's items.
pub fn bake_share(
    job_body: &[u8],
    out: &Location,
    shard: Shard,
    env: &BakeEnv,
    mut progress: impl FnMut(usize, usize, &str),
) -> Result<BakeSummary, JobError> {
    bake_share_with(job_body, out, shard, env, &mut progress)
}

/// [`bake_share`] with the progress callback as a trait object: the bake is compiled once, here,
/// not once per caller's closure.
fn bake_share_with(
    job_body: &[u8],
    out: &Location,
    shard: Shard,
    env: &BakeEnv,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<BakeSummary, JobError> {
    let (defaults, engine, cancel) = (env.defaults, env.engine, env.cancel);
    let spec = JobSpec::parse_body(job_body, env.max_products)?;
    spec.validate(defaults)?;
    out.create()?;
    let tiles = out.tiles()?;
    // Consecutive frame items share their grid and lit cloud (a camera path, a sun sweep).
    let reuse = FrameReuse::default();
    let share: Vec<usize> = (0..spec.len()).filter(|&i| shard.owns(i)).collect();
    let mut summary = BakeSummary {
        shard,
        total: share.len(),
        computed: 0,
        reused: 0,
        rejected: 0,
        failed: 0,
        errors: Vec::new(),
    };
    let mut manifest = Vec::new();
    for (n, &i) in share.iter().enumerate() {
        if cancel() {
            return Err(JobError::Failure(format!(
                "bake cancelled before item {i}; a rerun resumes"
            )));
        }
        let item = spec.item_request(i, defaults)?;
        let (key, product) = item_key(&item);
        let name = item_file(i, &item, &key);
        let stored = out.get(&name)?;
        let reusable = match (&item, stored.as_deref()) {
            (_, None) => false,
            (JobItem::Artifact(_), Some(b)) => is_artifact_of(b, &key),
            (JobItem::Bundle(b), Some(bytes)) => is_bundle_of(bytes, b, out)?,
            (JobItem::CloudLight(c), Some(bytes)) => is_files_of(bytes, &c.canonical(), out)?,
        };
        if stored.is_some() && !reusable {
            tracing::warn!(
                file = name,
                "stored artifact failed verification; recomputing it"
            );
            summary.rejected += 1;
        }
        let outcome = if reusable {
            summary.reused += 1;
            Ok("reused")
        } else {
            match &item {
                JobItem::Artifact(req) => compute(req, engine, &tiles, &key, &reuse, cancel)
                    .and_then(|img| Ok(encode_exr(&img)?))
                    .and_then(|bytes| Ok(out.put(&name, &bytes)?)),
                JobItem::Bundle(req) => bake_bundle(req, engine, out, &name, cancel),
                JobItem::CloudLight(req) => bake_cloud_light(req, engine, out, &name, cancel),
            }
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
            if let JobItem::Artifact(AnyRequest::Frame(_)) = item {
                tiles.frame(&key)?.remove_all()?;
            }
        }
        match outcome {
            Ok(what) => {
                manifest
                    .push(json!({"index": i, "product": product, "cache_key": key, "file": name}));
                progress(n + 1, share.len(), what);
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
                progress(n + 1, share.len(), "failed");
            }
        }
    }
    tiles.remove_empty()?;
    if shard.count == 1 {
        let doc =
            json!({"engine_version": ENGINE_VERSION, "summary": summary, "artifacts": manifest});
        out.put("manifest.json", doc.to_string().as_bytes())?;
        return Ok(summary);
    }
    let text = serde_json::to_vec_pretty(&summary)
        .map_err(|e| JobError::Failure(format!("encoding the shard summary: {e}")))?;
    out.put(&shard.file_name(), &text)?;
    // The shard that finds every item present writes the manifest (from the job, so any two
    // such shards write the same one).
    let items = items(&spec, defaults)?;
    let present: std::collections::HashSet<String> = out.names()?.into_iter().collect();
    if items.iter().all(|item| present.contains(&item.file)) {
        let doc = json!({
            "engine_version": ENGINE_VERSION,
            "summary": {"total": items.len(), "shards": shard.count},
            "artifacts": items,
        });
        out.put("manifest.json", doc.to_string().as_bytes())?;
    }
    Ok(summary)
}

/// One item of a job as the manifest lists it.
#[derive(Debug, Clone, Serialize)]
pub struct ManifestItem {
    pub index: usize,
    pub product: &'static str,
    pub cache_key: String,
    pub file: String,
}

fn items(spec: &JobSpec, defaults: &Defaults) -> Result<Vec<ManifestItem>, JobError> {
    (0..spec.len())
        .map(|i| {
            let item = spec.item_request(i, defaults)?;
            let (key, product) = item_key(&item);
            Ok(ManifestItem {
                index: i,
                product,
                file: item_file(i, &item, &key),
                cache_key: key,
            })
        })
        .collect()
}

/// Progress of a bake over all its shards ([`status`]).
#[derive(Debug, Clone, Serialize)]
pub struct BakeStatus {
    /// Items in the job.
    pub total: usize,
    /// Items whose file is present (listed; each is verified when a shard reuses it).
    pub present: usize,
    /// Indices of the items not yet present (the first 100).
    pub missing: Vec<usize>,
    /// Whether the manifest has been written (every item present).
    pub manifest: bool,
    /// The summaries of the shards that finished their share, by file name.
    pub shards: std::collections::BTreeMap<String, serde_json::Value>,
}

/// The progress of the bake of `job_body` in `out`, over every shard: which items are present,
/// and the summaries the shards left.
pub fn status(
    job_body: &[u8],
    out: &Location,
    defaults: &Defaults,
    max_products: usize,
) -> Result<BakeStatus, JobError> {
    let spec = JobSpec::parse_body(job_body, max_products)?;
    spec.validate(defaults)?;
    let items = items(&spec, defaults)?;
    let names = out.names()?;
    let present: std::collections::HashSet<&str> = names.iter().map(String::as_str).collect();
    let missing: Vec<usize> = items
        .iter()
        .filter(|item| !present.contains(item.file.as_str()))
        .map(|item| item.index)
        .collect();
    let mut shards = std::collections::BTreeMap::new();
    for name in names
        .iter()
        .filter(|n| n.starts_with("shard-") && n.ends_with(".json"))
    {
        if let Some(bytes) = out.get(name)? {
            let value = serde_json::from_slice(&bytes)
                .unwrap_or_else(|e| json!({"unreadable": e.to_string()}));
            shards.insert(name.clone(), value);
        }
    }
    Ok(BakeStatus {
        total: items.len(),
        present: items.len() - missing.len(),
        missing: missing.into_iter().take(100).collect(),
        manifest: present.contains("manifest.json"),
        shards,
    })
}

/// The artifact of one item; a frame renders tile by tile into `tiles` (scenes may name only the
/// example scenes' embedded files, as in the service).
fn compute(
    req: &AnyRequest,
    engine: &Engine,
    tiles: &TileStore,
    key: &str,
    reuse: &FrameReuse,
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<skybake_physics::image::SpectralImage, JobError> {
    let frame_tiles = tiles.frame(key)?;
    let env = ComputeEnv {
        loader: &skybake_product::frame::example_file,
        tiles: &frame_tiles,
        progress: &|_| {},
        cancel,
        reuse: Some(reuse),
    };
    Ok(req.compute(engine, &env)?)
}
