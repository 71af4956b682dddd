//! The cloud part of the scene JSON: which density source to build and at what voxel size.
//!
//! ```json
//! {"voxel_size_m": 25.0,
//!  "source": {"type": "metaballs",
//!             "balls": [{"centre_m": [0, 0, 1500], "radius_m": 400, "density": 1.0}]}}
//! ```
//!
//! `source.type` is one of `"metaballs"`, `"fractal"`, `"satellite"`, `"grid"`, `"automaton"` and
//! `"spheres"`; each variant's fields, units, ranges and defaults are documented on its parameter
//! struct. A scene file (see `config/scenes/`) is an object whose `cloud` member is this section;
//! its other members (`name`, `description`, `doc`, …) are ignored here ([`parse_scene_file`]).
//! File paths inside a source (`image`, `path`, `header`) are passed verbatim to the caller's
//! loader, which resolves them (normally relative to the scene file) and enforces its own size
//! limit ([`MAX_GRID_FILE_BYTES`]), so this module does no I/O.

use super::automaton::{self, AutomatonParams};
use super::fractal::{self, FractalParams};
use super::grid::{checked_count, checked_voxel_count, MAX_VOXELS};
use super::import;
use super::metaballs::{box_dims, Metaball, MetaballField};
use super::satellite::{self, SatelliteParams};
use super::spheres::{SphereCloud, SphereCloudParams};
use super::vdb;
use super::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Largest grid file a loader needs to accept: the largest grid in float64 plus a header.
pub const MAX_GRID_FILE_BYTES: usize = MAX_VOXELS * 8 + import::MAX_HEADER_BYTES + 12;

/// Largest scene file a caller needs to read (an automaton height map of 2048² cells in JSON fits).
pub const MAX_SCENE_FILE_BYTES: usize = 64 << 20;

/// Smallest and largest accepted voxel edge, metres.
pub const VOXEL_SIZE_RANGE_M: (f64, f64) = (0.01, 10_000.0);

/// The cloud section of a scene. Defaults in brackets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CloudSection {
    /// Edge of the voxels the renderer uses, metres, in [0.01, 10 000] [50].
    #[serde(default = "default_voxel_size_m")]
    pub voxel_size_m: f64,
    /// Where the density comes from.
    pub source: CloudSource,
}

fn default_voxel_size_m() -> f64 {
    50.0
}

/// A cloud density source, tagged by `"type"`. Extend by adding a variant, its arm in
/// [`validate_source`] and [`voxelize`], and its name in [`CloudSource::kind`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
#[non_exhaustive]
pub enum CloudSource {
    /// Explicit metaballs (Nishita & Dobashi 2001, eq 3).
    Metaballs(MetaballsParams),
    /// Metaballs grown fractally on their isosurface (Nishita et al. 1996, §4).
    Fractal(FractalParams),
    /// Metaballs fitted to a satellite image (Nishita & Dobashi 2001, §3.1).
    Satellite(SatelliteParams),
    /// A density grid from a `.npy` or raw f32 file.
    Grid(GridParams),
    /// One frame of the cellular-automaton cloud animation (Dobashi et al. 2000, §4–5.1). Boxed: its
    /// parameters are much larger than the other variants'.
    Automaton(Box<AutomatonSource>),
    /// A hierarchy of spheres (Ostroushko et al.) sampled into voxels.
    Spheres(SpheresSource),
}

impl CloudSource {
    /// The `"type"` tag of the source.
    pub fn kind(&self) -> &'static str {
        match self {
            CloudSource::Metaballs(_) => "metaballs",
            CloudSource::Fractal(_) => "fractal",
            CloudSource::Satellite(_) => "satellite",
            CloudSource::Grid(_) => "grid",
            CloudSource::Automaton(_) => "automaton",
            CloudSource::Spheres(_) => "spheres",
        }
    }

    /// The files the source names, each with the field that names it: what [`voxelize`] asks
    /// its loader for (a satellite image; a grid's data and, for raw f32, its header).
    pub fn files(&self) -> Vec<(&'static str, String)> {
        match self {
            CloudSource::Satellite(p) => vec![("source.image", p.image.clone())],
            CloudSource::Grid(p) => {
                let mut files = vec![("source.path", p.path.clone())];
                if p.format() == GridFormat::RawF32 {
                    files.push(("source.header", p.header_path()));
                }
                files
            }
            _ => Vec::new(),
        }
    }
}

/// Parameters of the `"automaton"` source: the simulation and the time of the frame.
///
/// ```json
/// {"type": "automaton", "frame_time_steps": 150.5, "params": {"dims": [256, 128, 20], …}}
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AutomatonSource {
    /// Time of the frame in automaton steps, in [0, 1e6]; fractional times interpolate linearly
    /// between the densities of the neighbouring steps (Dobashi et al. 2000, §5.1).
    pub frame_time_steps: f64,
    /// The simulation (documented on [`AutomatonParams`]). Its grid has one voxel per cell
    /// (`cell_size_m`); at another `voxel_size_m` it is resampled trilinearly over the same box.
    pub params: AutomatonParams,
}

/// Parameters of the `"spheres"` source.
///
/// ```json
/// {"type": "spheres", "level": null, "params": {"levels": 6, "size_m": [2000, 1200, 1000], …}}
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpheresSource {
    /// Level whose spheres are summed into the voxels, in 0..=`params.levels` [`params.levels`,
    /// the leaves]. A coarser level gives a smoother, cheaper cloud.
    #[serde(default)]
    pub level: Option<u32>,
    /// The hierarchy (documented on [`SphereCloudParams`]).
    pub params: SphereCloudParams,
}

/// Parameters of the `"metaballs"` source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MetaballsParams {
    /// The balls: `centre_m` [x, y, z] in metres (z up), `radius_m` > 0, `density` at the
    /// centre >= 0.
    pub balls: Vec<Metaball>,
}

/// File format of a `"grid"` source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GridFormat {
    /// NumPy `.npy`, float32 or float64, C order, shape (nz, ny, nx).
    Npy,
    /// Little-endian float32, x fastest, described by a JSON header
    /// (`{"dims": [nx, ny, nz], "voxel_size_m": …, "origin_m": [x, y, z]}`).
    RawF32,
    /// OpenVDB `.vdb`: one float grid (fog volume) of the file, over its active voxels, placed
    /// by the grid's transform (see [`super::vdb`] for what is read and what is refused).
    Vdb,
}

/// Parameters of the `"grid"` source. Defaults in brackets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridParams {
    /// Path of the data file.
    pub path: String,
    /// Format [from the extension: `.npy` is `npy`, `.vdb` is `vdb`, anything else `raw_f32`].
    #[serde(default)]
    pub format: Option<GridFormat>,
    /// Raw only: path of the JSON header [`path` with its extension replaced by `.json`].
    #[serde(default)]
    pub header: Option<String>,
    /// `.npy` only (the file has no geometry): voxel edge of the file, metres [the section's
    /// `voxel_size_m`].
    #[serde(default)]
    pub file_voxel_size_m: Option<f64>,
    /// `.npy` only: minimum corner of the box, metres [[0, 0, 0]].
    #[serde(default)]
    pub origin_m: Option<[f64; 3]>,
    /// `.vdb` only: name of the grid to read [`density`, else the file's only grid].
    #[serde(default)]
    pub grid_name: Option<String>,
    /// `.vdb` only: metres per unit of the file's world space, in [1e-6, 1e6] [1].
    #[serde(default)]
    pub file_unit_m: Option<f64>,
    /// Multiplies every density, in [0, 1e6] [1].
    #[serde(default = "default_scale")]
    pub density_scale: f64,
}

fn default_scale() -> f64 {
    1.0
}

impl GridParams {
    fn format(&self) -> GridFormat {
        self.format.unwrap_or_else(|| {
            let path = self.path.to_ascii_lowercase();
            if path.ends_with(".npy") {
                GridFormat::Npy
            } else if path.ends_with(".vdb") {
                GridFormat::Vdb
            } else {
                GridFormat::RawF32
            }
        })
    }

    fn header_path(&self) -> String {
        self.header.clone().unwrap_or_else(|| {
            let stem = match self.path.rfind('.') {
                Some(dot) if !self.path[dot..].contains('/') => &self.path[..dot],
                _ => self.path.as_str(),
            };
            format!("{stem}.json")
        })
    }
}

/// Parses the cloud section of a scene, mapping JSON errors to [`Error::Invalid`] on `cloud`,
/// and validates every parameter.
pub fn parse_cloud_section(json: &[u8]) -> Result<CloudSection> {
    let section: CloudSection = serde_json::from_slice(json)
        .map_err(|e| Error::invalid("cloud", format!("invalid cloud section: {e}")))?;
    section.validate()?;
    Ok(section)
}

/// Parses a whole scene file (`{"name", "description", "cloud": {…}, …}`) and returns its
/// validated cloud section; members other than `cloud` are not read here.
pub fn parse_scene_file(json: &[u8]) -> Result<CloudSection> {
    if json.len() > MAX_SCENE_FILE_BYTES {
        return Err(Error::too_large(
            "scene",
            format!("{} bytes", json.len()),
            format!("{MAX_SCENE_FILE_BYTES} bytes"),
        ));
    }
    let scene: serde_json::Value = serde_json::from_slice(json)
        .map_err(|e| Error::invalid("scene", format!("invalid scene JSON: {e}")))?;
    let cloud = scene
        .get("cloud")
        .ok_or_else(|| Error::invalid("cloud", "the scene has no \"cloud\" section"))?;
    let section: CloudSection = CloudSection::deserialize(cloud)
        .map_err(|e| Error::invalid("cloud", format!("invalid cloud section: {e}")))?;
    section.validate()?;
    Ok(section)
}

impl CloudSection {
    /// Checks the voxel size and the source's parameters.
    pub fn validate(&self) -> Result<()> {
        check_voxel_size(self.voxel_size_m)?;
        validate_source(&self.source)
    }

    /// The dimensions of the grid [`Self::voxelize`] would build, found without building it or
    /// reading a file, for the sources whose box follows from their parameters: metaballs (the
    /// balls' box plus one voxel of margin) and the automaton (its cell box, resampled). `None`
    /// for the others, whose box comes from a file or a growth (grid, satellite, fractal, spheres).
    pub fn planned_dims(&self) -> Result<Option<[usize; 3]>> {
        planned_dims(&self.source, self.voxel_size_m)
    }

    /// Builds the density grid (see [`voxelize`]).
    pub fn voxelize(&self, loader: &dyn Fn(&str) -> Result<Vec<u8>>) -> Result<DensityGrid> {
        voxelize(&self.source, self.voxel_size_m, loader)
    }

    /// Builds the density grid, refusing one of more than `max_voxels` voxels before it is
    /// allocated (see [`voxelize_within`]).
    pub fn voxelize_within(
        &self,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        max_voxels: usize,
    ) -> Result<DensityGrid> {
        voxelize_within(&self.source, self.voxel_size_m, loader, max_voxels).map(|(g, _)| g)
    }

    /// [`Self::voxelize_within`], stopped with [`Error::Cancelled`] once `cancelled` returns true
    /// (see [`voxelize_unless`]).
    pub fn voxelize_unless(
        &self,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        max_voxels: usize,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<DensityGrid> {
        voxelize_unless(
            &self.source,
            self.voxel_size_m,
            loader,
            max_voxels,
            cancelled,
        )
        .map(|(g, _)| g)
    }

    /// Builds the density grid and the source's report (see [`voxelize_with_report`]).
    pub fn voxelize_with_report(
        &self,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    ) -> Result<(DensityGrid, SourceReport)> {
        voxelize_with_report(&self.source, self.voxel_size_m, loader)
    }
}

/// [`CloudSection::planned_dims`] of `source` at voxel edge `v`.
fn planned_dims(source: &CloudSource, v: f64) -> Result<Option<[usize; 3]>> {
    Ok(match source {
        CloudSource::Metaballs(p) => {
            let (lo, hi) = MetaballField::new(p.balls.clone())?.bounds_m();
            Some(box_dims(lo - v, hi + v, v)?.0)
        }
        CloudSource::Automaton(a) => {
            let (dims, cell) = (a.params.dims, a.params.cell_size_m);
            if same_size(cell, v) {
                Some(dims)
            } else {
                let hi = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * cell;
                Some(box_dims(DVec3::ZERO, hi, v)?.0)
            }
        }
        _ => None,
    })
}

fn check_voxel_size(v: f64) -> Result<()> {
    let (lo, hi) = VOXEL_SIZE_RANGE_M;
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        return Err(Error::out_of_range(
            "voxel_size_m",
            v,
            format!("[{lo}, {hi}] m"),
        ));
    }
    Ok(())
}

/// Validates a source's parameters without loading any file.
pub fn validate_source(source: &CloudSource) -> Result<()> {
    match source {
        CloudSource::Metaballs(p) => super::metaballs::validate_balls(&p.balls),
        CloudSource::Fractal(p) => p.validate(),
        CloudSource::Satellite(p) => p.validate(),
        CloudSource::Grid(p) => {
            if let Some(v) = p.file_voxel_size_m {
                check_voxel_size(v).map_err(|_| {
                    Error::out_of_range(
                        "file_voxel_size_m",
                        v,
                        format!("[{}, {}] m", VOXEL_SIZE_RANGE_M.0, VOXEL_SIZE_RANGE_M.1),
                    )
                })?;
            }
            if let Some(o) = p.origin_m {
                if !o.iter().all(|c| c.is_finite()) {
                    return Err(Error::invalid("origin_m", "must be finite"));
                }
            }
            let s = p.density_scale;
            if !(s.is_finite() && (0.0..=1e6).contains(&s)) {
                return Err(Error::out_of_range("density_scale", s, "[0, 1e6]"));
            }
            validate_grid_fields(p)
        }
        CloudSource::Automaton(a) => {
            let t = a.frame_time_steps;
            if !(0.0..=automaton::MAX_STEPS).contains(&t) {
                return Err(Error::out_of_range(
                    "frame_time_steps",
                    t,
                    format!("[0, {}]", automaton::MAX_STEPS),
                ));
            }
            a.params.validate()?;
            // Draws the random parcels and checks them (no simulation, no large allocation).
            a.params.all_ellipsoids().map(drop)
        }
        CloudSource::Spheres(s) => {
            s.params.validate()?;
            match s.level {
                Some(k) if k > s.params.levels => Err(Error::out_of_range(
                    "level",
                    k,
                    format!("0..={} (params.levels)", s.params.levels),
                )),
                _ => Ok(()),
            }
        }
    }
}

/// The fields of a `"grid"` source that a `.vdb` file's own geometry replaces are refused for it,
/// and its own fields for the other formats.
fn validate_grid_fields(p: &GridParams) -> Result<()> {
    let vdb = p.format() == GridFormat::Vdb;
    let not_for_vdb = [
        ("file_voxel_size_m", p.file_voxel_size_m.is_some()),
        ("origin_m", p.origin_m.is_some()),
        ("header", p.header.is_some()),
    ];
    let vdb_only = [
        ("grid_name", p.grid_name.is_some()),
        ("file_unit_m", p.file_unit_m.is_some()),
    ];
    for (field, set) in not_for_vdb {
        if vdb && set {
            return Err(Error::invalid(
                field,
                "does not apply to a .vdb grid (its transform gives the voxel size and position; \
                 file_unit_m scales them)",
            ));
        }
    }
    for (field, set) in vdb_only {
        if !vdb && set {
            return Err(Error::invalid(field, "applies to .vdb grids only"));
        }
    }
    if let Some(u) = p.file_unit_m {
        if !(u.is_finite() && (1e-6..=1e6).contains(&u)) {
            return Err(Error::out_of_range("file_unit_m", u, "[1e-6, 1e6]"));
        }
    }
    Ok(())
}

/// What building a source's grid found out besides the grid (printed by `skybake clouds`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SourceReport {
    /// Satellite: final relative image error of the fit, `‖T − M‖ / ‖T‖` (Nishita & Dobashi 2001, §3.1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit_error: Option<f64>,
    /// Satellite: whether the error fell below `error_threshold` (else `max_balls` stopped it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit_converged: Option<bool>,
    /// Satellite: metaballs placed by the fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit_balls: Option<usize>,
}

/// Builds the density grid of `source` at `voxel_size_m`, reading files through `loader`
/// (given a path from the scene, it returns the file's bytes). Imported grids and automaton
/// frames at another voxel size are resampled trilinearly over the same box.
pub fn voxelize(
    source: &CloudSource,
    voxel_size_m: f64,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
) -> Result<DensityGrid> {
    voxelize_with_report(source, voxel_size_m, loader).map(|(grid, _)| grid)
}

/// [`voxelize`], also returning the source's [`SourceReport`] (the satellite fit's final error).
pub fn voxelize_with_report(
    source: &CloudSource,
    voxel_size_m: f64,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
) -> Result<(DensityGrid, SourceReport)> {
    voxelize_within(source, voxel_size_m, loader, MAX_VOXELS)
}

/// [`voxelize_with_report`], refusing a grid of more than `max_voxels` voxels (too large on
/// `dims`) as soon as its dimensions are known and before it is allocated: from the parameters
/// (metaballs, automaton: before the simulation), from the file's header (grid: before the data
/// are decoded or resampled), from the grown or fitted balls (fractal, satellite) and from the
/// built sphere hierarchy (spheres). The renderer passes its own limit
/// (`render::MAX_RENDER_VOXELS`).
pub fn voxelize_within(
    source: &CloudSource,
    voxel_size_m: f64,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    max_voxels: usize,
) -> Result<(DensityGrid, SourceReport)> {
    voxelize_unless(source, voxel_size_m, loader, max_voxels, &|| false)
}

/// [`voxelize_within`], stopped with [`Error::Cancelled`] once `cancelled` returns true: asked
/// before every step of an automaton, every ball of a satellite fit and every z-slice of a grid
/// that is evaluated or resampled, so an abandoned request stops within a step or a slice.
pub fn voxelize_unless(
    source: &CloudSource,
    voxel_size_m: f64,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    max_voxels: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<(DensityGrid, SourceReport)> {
    check_voxel_size(voxel_size_m)?;
    validate_source(source)?;
    if let Some(dims) = planned_dims(source, voxel_size_m)? {
        checked_count(dims, max_voxels, "voxels")?;
    }
    let grid = match source {
        CloudSource::Metaballs(p) => MetaballField::new(p.balls.clone())?.voxelize_within_unless(
            voxel_size_m,
            voxel_size_m,
            max_voxels,
            cancelled,
        ),
        CloudSource::Fractal(p) => fractal::voxelize_unless(p, voxel_size_m, max_voxels, cancelled),
        CloudSource::Satellite(p) => {
            let png = loader(&p.image)?;
            let (grid, fit) =
                satellite::voxelize_with_fit_unless(&png, p, voxel_size_m, max_voxels, cancelled)?;
            let report = SourceReport {
                fit_error: Some(fit.error),
                fit_converged: Some(fit.converged),
                fit_balls: Some(fit.blobs.len()),
            };
            return Ok((grid, report));
        }
        CloudSource::Grid(p) => {
            let bytes = loader(&p.path)?;
            let (file_dims, header, layout) = match p.format() {
                GridFormat::Npy => (import::npy_dims(&bytes)?, None, None),
                GridFormat::RawF32 => {
                    let header = import::parse_raw_header(&loader(&p.header_path())?)?;
                    (header.dims, Some(header), None)
                }
                GridFormat::Vdb => {
                    let layout = vdb::inspect(&bytes, p.grid_name.as_deref())?;
                    (layout.dims, None, Some(layout))
                }
            };
            let unit_m = p.file_unit_m.unwrap_or(1.0);
            let (file_voxel_m, origin_m) = match (&header, &layout) {
                (Some(h), _) => (h.voxel_size_m, DVec3::from_array(h.origin_m)),
                (_, Some(l)) => (l.voxel_size * unit_m, l.origin() * unit_m),
                (None, None) => (
                    p.file_voxel_size_m.unwrap_or(voxel_size_m),
                    DVec3::from_array(p.origin_m.unwrap_or([0.0; 3])),
                ),
            };
            // The grid at the section's voxel size, before the data are decoded (a header's bad
            // voxel size or origin is reported by the decoding below).
            if file_voxel_m.is_finite() && file_voxel_m > 0.0 && origin_m.is_finite() {
                let dims = if same_size(file_voxel_m, voxel_size_m) {
                    file_dims
                } else {
                    let n = DVec3::new(
                        file_dims[0] as f64,
                        file_dims[1] as f64,
                        file_dims[2] as f64,
                    );
                    box_dims(origin_m, origin_m + n * file_voxel_m, voxel_size_m)?.0
                };
                checked_count(dims, max_voxels, "voxels")?;
            }
            let mut grid = match (&header, &layout) {
                (Some(h), _) => import::from_raw_f32(h, &bytes)?,
                (_, Some(l)) => vdb::decode(&bytes, l, unit_m)?,
                (None, None) => import::from_npy_bytes(&bytes, file_voxel_m, origin_m)?,
            };
            if p.density_scale != 1.0 {
                let s = p.density_scale as f32;
                grid.data.iter_mut().for_each(|v| *v *= s);
            }
            at_voxel_size(grid, voxel_size_m, cancelled)
        }
        CloudSource::Automaton(a) => at_voxel_size(
            automaton::automaton_density_unless(&a.params, a.frame_time_steps, cancelled)?,
            voxel_size_m,
            cancelled,
        ),
        CloudSource::Spheres(s) => {
            let cloud = SphereCloud::new(&s.params)?;
            let (dims, _, _) = cloud.grid_box(voxel_size_m, s.level)?;
            checked_count(dims, max_voxels, "voxels")?;
            cloud.voxelize_unless(voxel_size_m, s.level, cancelled)
        }
    }?;
    Ok((grid, SourceReport::default()))
}

/// `grid` itself when its voxel size is `voxel_size_m`, else [`resample`]d (no copy in the common
/// case of matching sizes).
fn at_voxel_size(
    grid: DensityGrid,
    voxel_size_m: f64,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<DensityGrid> {
    if same_size(grid.voxel_size_m, voxel_size_m) {
        Ok(grid)
    } else {
        let (dims, origin_m) = box_dims(grid.origin_m, grid.max_corner_m(), voxel_size_m)?;
        checked_voxel_count(dims)?;
        DensityGrid::from_fn_unless(dims, voxel_size_m, origin_m, |p| grid.sample(p), cancelled)
    }
}

fn same_size(a_m: f64, b_m: f64) -> bool {
    (a_m - b_m).abs() <= 1e-9 * b_m
}

/// The grid resampled (trilinear, cell-centred) at `voxel_size_m` over the same box; the grid
/// itself when the size already matches.
pub fn resample(grid: &DensityGrid, voxel_size_m: f64) -> Result<DensityGrid> {
    if same_size(grid.voxel_size_m, voxel_size_m) {
        return Ok(grid.clone());
    }
    let (dims, origin_m) = box_dims(grid.origin_m, grid.max_corner_m(), voxel_size_m)?;
    checked_voxel_count(dims)?;
    DensityGrid::from_fn(dims, voxel_size_m, origin_m, |p| grid.sample(p))
}
