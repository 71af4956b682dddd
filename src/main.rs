//! `skybake`: command-line front end. Parses flags, calls the library, prints JSON or writes files.

use clap::{Arg, ArgAction, ArgMatches, Args, FromArgMatches, Parser, Subcommand, ValueEnum};
use skybake::engine::Engine;
use skybake::output::{dome_png, Projection};
use skybake::product::params::{RequestParams, PARAMETERS};
use skybake::product::{artifact, Format as BodyFormat, ProductKind, ProductRequest};
use skybake::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Why the CLI stopped: bad input (exit code 2) or a failure that is not the input's fault (I/O,
/// internal; exit code 1).
#[derive(Debug)]
enum CliError {
    Input(Error),
    Failure(String),
}

impl From<Error> for CliError {
    fn from(e: Error) -> Self {
        if e.is_input() {
            CliError::Input(e)
        } else {
            CliError::Failure(e.to_string())
        }
    }
}

impl From<skybake::store::StoreError> for CliError {
    fn from(e: skybake::store::StoreError) -> Self {
        match e {
            skybake::store::StoreError::Invalid(e) => e.into(),
            other => CliError::Failure(other.to_string()),
        }
    }
}

type Result<T, E = CliError> = std::result::Result<T, E>;

#[derive(Parser)]
#[command(name = "skybake", version, about = "Spectral atmosphere and sky precomputation", long_about = None)]
struct Cli {
    /// Build shared tables in this process only: neither load nor save them in the cache
    /// directory (SKYBAKE_CACHE_DIR or the config's cache.dir, shared with `serve` and `bake`).
    #[arg(long, global = true)]
    no_table_cache: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Sun attenuation: transmittance, direct normal, diffuse and global horizontal irradiance.
    ///
    /// Example: skybake sun --sun-elevation-deg 30 --wavelengths 440,550,680
    Sun(SunArgs),
    /// Sky-dome radiance table (view elevation −90…90°, azimuth 0…180° from the sun).
    ///
    /// Example: skybake sky --sun-elevation-deg 10 -o sky.exr
    Sky(SkyArgs),
    /// Ground-reflected upward skylight at the observer (view zenith 90…180°).
    ///
    /// Example: skybake ground --observer-altitude-m 3000 --probe 120:0,180:0
    Ground(GroundArgs),
    /// Aerial perspective: transmittance and in-scattered radiance against distance.
    ///
    /// Example: skybake aerial --distance-count 32 --max-distance-m 50000
    Aerial(AerialArgs),
    /// The stages that would run for a product and those left out (and why), without computing.
    ///
    /// Example: skybake plan sky --sun-elevation-deg -5 --ground-albedo 0
    Plan(PlanArgs),
    /// Atmosphere presets: list them, or print one's resolved JSON to start from.
    Atmosphere {
        /// Print this preset's JSON.
        #[arg(long, value_name = "PRESET")]
        print: Option<String>,
        /// List preset names.
        #[arg(long)]
        list: bool,
    },
    /// Voxelise the cloud of a scene file and export the density grid.
    ///
    /// Example: skybake clouds config/scenes/cumulus-metaballs.json --voxels cumulus.npy
    Clouds {
        /// Scene JSON with a "cloud" section (see config/scenes/); files it names are read
        /// relative to the scene's directory.
        scene: PathBuf,
        /// Write the density grid as .npy (float32, shape (nz, ny, nx)).
        #[arg(long, value_name = "OUT.npy")]
        voxels: Option<PathBuf>,
        /// Summary format.
        #[arg(long, value_enum, default_value_t = Format::Json)]
        format: Format,
    },
    /// Render a lit cloud frame of a scene (sun, sky and ground light, multiple scattering).
    ///
    /// Example: skybake render config/scenes/cumulus-frame.json -o frame.png
    Render {
        /// Frame scene JSON (see config/scenes/*-frame.json); files it names are read relative to
        /// the scene's directory.
        scene: PathBuf,
        /// Write the frame: .exr (spectral + RGB, the cached artifact) or .png (tone-mapped; an
        /// RGB-only request, which the planner may run at fewer wavelengths).
        #[arg(short = 'o', long = "output", value_name = "FILE")]
        output: Option<PathBuf>,
        /// fast (per-voxel light + multiple-scattering field + ray march) or reference (path tracer).
        #[arg(long, default_value = "fast")]
        method: String,
        /// Target relative error of the frame (fast method), in [0.081, 1]: what it leaves over
        /// the fast method's measured 8.1 % is the budget of the planner's cost rules.
        #[arg(long, value_name = "E")]
        max_rel_error: Option<String>,
        /// Summary format.
        #[arg(long, value_enum, default_value_t = Format::Json)]
        format: Format,
    },
    /// Run named benchmarks in-process and print median times.
    ///
    /// Example: skybake bench sky-fast sun --format json
    Bench {
        /// Benchmarks to run (default: all). Known: sun, sky-fast, sky-precise, precise-tables,
        /// ca-step, spheres, metaballs, fractal, satellite, solar-position, frame, frame-pattern,
        /// frame-accuracy, store.
        names: Vec<String>,
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
        /// Cold repetitions (shared tables built each time).
        #[arg(long, default_value_t = 1)]
        cold_runs: usize,
        /// Warm repetitions (shared tables reused).
        #[arg(long, default_value_t = 5)]
        warm_runs: usize,
    },
    /// Measure error against run time for every product and method over the quality presets
    /// (against the precise method at the reference preset) and write report/ (JSON, markdown,
    /// PNG plots).
    ///
    /// Example: skybake report --quick --out /tmp/report
    ///          skybake report --only frames   (the cloud frames' part; the rest is kept)
    Report {
        /// One regime, three wavelengths, sun and sky only, one tiny frame (under 2 minutes; run
        /// by CI).
        #[arg(long)]
        quick: bool,
        /// Measure only this part and keep the other from OUT's existing report.json or
        /// frames.json (the README is rewritten with both).
        #[arg(long, value_enum)]
        only: Option<ReportPart>,
        /// Output directory.
        #[arg(long, default_value = "report")]
        out: PathBuf,
        /// Rewrite the markdown and plots from an existing report.json instead of measuring.
        #[arg(long, value_name = "REPORT_JSON")]
        from_json: Option<PathBuf>,
        /// Measure instead what each of the planner's cost rules saves and costs (time and error
        /// with and without it) and write `planner.md` into the output directory.
        #[arg(long, conflicts_with_all = ["quick", "from_json"])]
        planner: bool,
    },
    /// Run the HTTP service (settings: config/default.toml ← --config FILE ← SKYBAKE_* ← flags).
    ///
    /// Example: skybake serve --bind 127.0.0.1:8080 --cache-dir /var/cache/skybake
    Serve(ServeArgs),
    /// Run a bake job file offline (the POST /v1/jobs format); resumable.
    ///
    /// Example: skybake bake job.json --out baked/
    Bake {
        /// Job file (JSON: {"products": [...], "grids": [...], "frames": [...]}; see README "Bake jobs").
        job: PathBuf,
        /// Output directory (EXR per product + manifest.json); a rerun reuses finished files.
        #[arg(long)]
        out: PathBuf,
        /// Settings file (defaults for wavelengths and quality, job size limit).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Exit 0 when the service at ADDR answers GET /healthz with 200 (for container HEALTHCHECK).
    Healthcheck {
        /// Service address [default: the configured bind address].
        #[arg(long)]
        addr: Option<String>,
    },
}

#[derive(Args, Clone)]
struct ServeArgs {
    /// Address to listen on (overrides SKYBAKE_BIND and the config).
    #[arg(long)]
    bind: Option<String>,
    /// Cache directory (overrides SKYBAKE_CACHE_DIR and the config).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Settings file (TOML, any subset of config/default.toml).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// The parts of `skybake report`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ReportPart {
    /// The atmosphere products (sun, sky, ground, aerial).
    Atmosphere,
    /// The cloud frames.
    Frames,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Format {
    Json,
    Text,
}

const SUN: u8 = 0;
const SKY: u8 = 1;
const GROUND: u8 = 2;
const AERIAL: u8 = 3;
/// Every product's flags (`skybake plan`; the request then refuses those its product lacks).
const ANY: u8 = 4;

/// The product flags, built from the parameter table ([`PARAMETERS`]): one `--flag` per row that
/// the product `K` takes, with the row's doc, unit, range and default as help.
#[derive(Clone, Default)]
struct ProductFlags<const K: u8> {
    params: RequestParams,
}

fn kind_of(k: u8) -> Option<ProductKind> {
    match k {
        SUN => Some(ProductKind::Sun),
        SKY => Some(ProductKind::Sky),
        GROUND => Some(ProductKind::Ground),
        AERIAL => Some(ProductKind::Aerial),
        _ => None,
    }
}

fn flag_rows(
    k: u8,
) -> impl Iterator<Item = (&'static str, &'static skybake::product::params::Parameter)> {
    PARAMETERS.iter().filter_map(move |row| {
        let applies = kind_of(k).is_none_or(|kind| row.applies_to(kind));
        row.cli.filter(|_| applies).map(|flag| (flag, row))
    })
}

impl<const K: u8> FromArgMatches for ProductFlags<K> {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        let mut flags = Self::default();
        flags.update_from_arg_matches(m)?;
        Ok(flags)
    }

    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        for (_, row) in flag_rows(K) {
            if let (Some(v), Some(slot)) =
                (m.get_one::<String>(row.name), self.params.slot(row.name))
            {
                *slot = Some(v.clone());
            }
        }
        Ok(())
    }
}

impl<const K: u8> Args for ProductFlags<K> {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        cmd.args(flag_rows(K).map(|(flag, row)| {
            Arg::new(row.name)
                .long(flag)
                .help(row.help())
                .allow_hyphen_values(true)
                .action(ArgAction::Set)
        }))
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

#[derive(Args, Clone)]
struct SunArgs {
    #[command(flatten)]
    flags: ProductFlags<SUN>,
    /// Print JSON to stdout (the default).
    #[arg(long, value_enum)]
    format: Option<Format>,
}

#[derive(Args, Clone)]
struct DomeOutput {
    /// Write the table: .png (preview) or .exr (the spectral artifact, as the service stores it).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// PNG projection.
    #[arg(long, value_enum, default_value_t = ProjectionArg::Fisheye)]
    projection: ProjectionArg,
    /// PNG size in pixels (height).
    #[arg(long, default_value_t = 512)]
    size: usize,
    /// Print JSON to stdout as well when writing a file.
    #[arg(long, value_enum)]
    format: Option<Format>,
}

#[derive(Args, Clone)]
struct SkyArgs {
    #[command(flatten)]
    flags: ProductFlags<SKY>,
    #[command(flatten)]
    out: DomeOutput,
}

#[derive(Args, Clone)]
struct GroundArgs {
    #[command(flatten)]
    flags: ProductFlags<GROUND>,
    #[command(flatten)]
    out: DomeOutput,
}

#[derive(Args, Clone)]
struct AerialArgs {
    #[command(flatten)]
    flags: ProductFlags<AERIAL>,
    /// Write the table as a spectral EXR (layers S0 = in-scattered radiance, T = transmittance).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Print JSON to stdout as well when writing a file.
    #[arg(long, value_enum)]
    format: Option<Format>,
}

#[derive(Args, Clone)]
struct PlanArgs {
    /// The product: sun, sky, ground, aerial, or frame (with --scene; --method fast|reference).
    product: String,
    /// The frame scene (product `frame`).
    #[arg(long, value_name = "SCENE_JSON")]
    scene: Option<PathBuf>,
    /// Plan the frame as an RGB-only request (what `skybake render -o FRAME.png` and
    /// `POST /v1/render?format=png` run): the planner may leave wavelengths out.
    #[arg(long)]
    rgb_only: bool,
    #[command(flatten)]
    flags: ProductFlags<ANY>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ProjectionArg {
    Fisheye,
    Latlong,
}

/// The request parameters of the flags; `--atmosphere` may name a file, read here (the library
/// does no I/O).
fn request_params(mut p: RequestParams) -> Result<RequestParams> {
    if let Some(a) = &p.atmosphere {
        // A file, or what can only be meant as one (a path or a .json name): a missing or
        // unreadable file says so instead of "unknown preset".
        let meant_as_file = a.ends_with(".json") || a.contains('/') || a.contains('\\');
        if !a.trim_start().starts_with('{') && (Path::new(a).is_file() || meant_as_file) {
            p.atmosphere = Some(read_input(Path::new(a), "atmosphere")?);
        }
    }
    Ok(p)
}

/// Reads a file the user named: a missing file is bad input, other I/O errors are failures.
fn read_input(path: &Path, field: &str) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| io_error(e, field, path))
}

fn io_error(e: std::io::Error, field: &str, path: &Path) -> CliError {
    let message = format!("cannot read {}: {e}", path.display());
    if e.kind() == std::io::ErrorKind::NotFound {
        CliError::Input(Error::invalid(field, message))
    } else {
        CliError::Failure(message)
    }
}

fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| CliError::Failure(format!("JSON encoding: {e}")))?;
    // A closed pipe (`| head`) ends the output quietly instead of panicking.
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}") {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(CliError::Failure(format!("cannot write to stdout: {e}")))
        }
        _ => Ok(()),
    }
}

/// Prints the JSON body rendered from the artifact (the service's `format=json`), indented.
fn print_body(kind: ProductKind, image: &skybake::store::SpectralImage) -> Result<()> {
    let body = artifact::render(kind, BodyFormat::Json, image)?;
    let value: serde_json::Value =
        serde_json::from_slice(&body).map_err(|e| CliError::Failure(format!("JSON body: {e}")))?;
    print_json(&value)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    // Through the store, the one place that writes (atomically).
    Ok(skybake::store::write_atomic(path, bytes)?)
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// `sky`/`ground`: the product's artifact (the EXR the service and bakes store), written with
/// `-o FILE.exr`, previewed with `-o FILE.png`, printed as the service's JSON body.
fn run_dome(
    kind: ProductKind,
    flags: &RequestParams,
    out: &DomeOutput,
    engine: &Engine,
) -> Result<()> {
    let ext = out.output.as_deref().map(extension);
    let mut params = flags.clone();
    if ext.as_deref() == Some("png") && out.format != Some(Format::Json) {
        // A PNG alone is RGB-only: the planner may run fewer wavelengths.
        params.format = Some(
            match out.projection {
                ProjectionArg::Fisheye => "png",
                ProjectionArg::Latlong => "png_latlong",
            }
            .into(),
        );
    }
    let req = ProductRequest::from_params(kind, &request_params(params)?)?;
    if let (Some(path), Some(ext)) = (&out.output, &ext) {
        if ext != "png" && ext != "exr" {
            return Err(Error::invalid(
                "output",
                format!("'{}': use a .exr or .png file name", path.display()),
            )
            .into());
        }
    }
    let image = req.compute(engine)?;
    if let (Some(path), Some(ext)) = (&out.output, &ext) {
        if ext == "png" {
            let projection = match out.projection {
                ProjectionArg::Fisheye => Projection::Fisheye,
                ProjectionArg::Latlong => Projection::LatLong,
            };
            let table = artifact::dome_table_of(&image)?;
            write_file(path, &dome_png(&table, projection, out.size)?)?;
        } else {
            write_file(path, &skybake::store::encode_exr(&image)?)?;
        }
    }
    if out.output.is_none() || out.format == Some(Format::Json) {
        print_body(kind, &image)?;
    }
    Ok(())
}

fn load_settings(config: Option<&Path>) -> Result<skybake::config::Settings> {
    Ok(skybake::config::Settings::load(config)?)
}

/// The engine of every product command (`sun`, `sky`, `ground`, `aerial`, `render`, `bake`): the
/// precise tables come from (and go to) the configured cache directory, so a second call with the
/// same atmosphere and wavelengths skips the build; `--no-table-cache` builds them in-process.
fn engine(no_table_cache: bool, config: Option<&Path>) -> Result<Engine> {
    if no_table_cache {
        return Ok(Engine::new());
    }
    Ok(skybake::store::tables::engine_for_settings(&load_settings(
        config,
    )?))
}

fn serve(args: ServeArgs) -> Result<()> {
    let mut settings = load_settings(args.config.as_deref())?;
    if let Some(bind) = args.bind {
        settings.server.bind = bind;
    }
    if let Some(dir) = args.cache_dir {
        settings.cache.dir = dir;
    }
    settings.validate()?;
    skybake::service::server::run(settings).map_err(CliError::Failure)
}

fn bake(job: &Path, out: &Path, config: Option<&Path>, no_table_cache: bool) -> Result<()> {
    let settings = load_settings(config)?;
    let engine = engine(no_table_cache, config)?;
    let body = std::fs::read(job).map_err(|e| io_error(e, "job", job))?;
    let start = std::time::Instant::now();
    // A progress bar on a terminal; plain progress lines in logs and pipes.
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let bar = indicatif::ProgressBar::new(0);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} ({eta} left) {msg}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar
    });
    let defaults = skybake::product::params::Defaults::from_settings(&settings);
    let summary = skybake::job::bake::bake(
        &body,
        out,
        &defaults,
        settings.jobs.max_products,
        &engine,
        |done, total, what| match &bar {
            Some(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(what.to_string());
            }
            None => eprintln!(
                "[{done}/{total}] {what} ({:.1} s)",
                start.elapsed().as_secs_f64()
            ),
        },
    )
    .map_err(|e| {
        if e.is_input() {
            CliError::Input(Error::invalid("job", e))
        } else {
            CliError::Failure(e.to_string())
        }
    })?;
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    print_json(&summary)?;
    if summary.failed > 0 {
        return Err(CliError::Failure(format!(
            "{} of {} products failed (see manifest.json)",
            summary.failed, summary.total
        )));
    }
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    let no_table_cache = cli.no_table_cache;
    match cli.command {
        Command::Serve(args) => serve(args),
        Command::Bake { job, out, config } => bake(&job, &out, config.as_deref(), no_table_cache),
        Command::Healthcheck { addr } => {
            let addr = match addr {
                Some(a) => a,
                None => load_settings(None)?.server.bind,
            };
            let addr = addr
                .parse()
                .map_err(|_| Error::invalid("addr", format!("'{addr}' is not HOST:PORT")))?;
            skybake::service::server::healthcheck(addr).map_err(CliError::Failure)
        }
        Command::Sun(a) => {
            let req = ProductRequest::from_params(
                ProductKind::Sun,
                &request_params(a.flags.params.clone())?,
            )?;
            print_body(
                ProductKind::Sun,
                &req.compute(&engine(no_table_cache, None)?)?,
            )
        }
        Command::Sky(a) => run_dome(
            ProductKind::Sky,
            &a.flags.params,
            &a.out,
            &engine(no_table_cache, None)?,
        ),
        Command::Ground(a) => run_dome(
            ProductKind::Ground,
            &a.flags.params,
            &a.out,
            &engine(no_table_cache, None)?,
        ),
        Command::Aerial(a) => {
            let req = ProductRequest::from_params(
                ProductKind::Aerial,
                &request_params(a.flags.params.clone())?,
            )?;
            if let Some(path) = &a.output {
                if extension(path) != "exr" {
                    return Err(Error::invalid(
                        "output",
                        format!("'{}': aerial tables are written as .exr", path.display()),
                    )
                    .into());
                }
            }
            let image = req.compute(&engine(no_table_cache, None)?)?;
            if let Some(path) = &a.output {
                write_file(path, &skybake::store::encode_exr(&image)?)?;
            }
            if a.output.is_none() || a.format == Some(Format::Json) {
                print_body(ProductKind::Aerial, &image)?;
            }
            Ok(())
        }
        Command::Plan(a) if a.product == "frame" => {
            let scene = a
                .scene
                .as_deref()
                .ok_or_else(|| Error::invalid("scene", "plan frame needs --scene SCENE.json"))?;
            let method = match a.flags.params.method.as_deref() {
                Some(m) => skybake::render::Method::parse(m)?,
                None => skybake::render::Method::Fast,
            };
            let text = read_limited(scene, "scene", skybake::cloud::scene::MAX_SCENE_FILE_BYTES)?;
            let request = skybake::render::FrameRequest::parse(&text, method)?
                .with_max_rel_error(a.flags.params.max_rel_error.as_deref())?
                .with_rgb_only(a.rgb_only);
            let dir = scene.parent().unwrap_or(Path::new("."));
            let loader = |name: &str| {
                read_limited(
                    &dir.join(name),
                    "path",
                    skybake::cloud::scene::MAX_GRID_FILE_BYTES,
                )
            };
            print_json(&serde_json::json!({
                "product": "frame",
                "cache_key": request.cache_key(),
                "engine_version": skybake::engine::ENGINE_VERSION,
                "method": method,
                "plan": request.plan(&engine(no_table_cache, None)?, &loader)?,
            }))
        }
        Command::Plan(a) => {
            if a.scene.is_some() {
                return Err(Error::invalid("scene", "only for plan frame").into());
            }
            if a.rgb_only {
                return Err(Error::invalid("rgb_only", "only for plan frame").into());
            }
            let kind = ProductKind::parse(&a.product)?;
            let req = ProductRequest::from_params(kind, &request_params(a.flags.params.clone())?)?;
            print_json(&serde_json::json!({
                "product": kind.name(),
                "cache_key": req.cache_key(),
                "engine_version": skybake::engine::ENGINE_VERSION,
                "plan": req.plan()?,
                "work_cells": req.work_cells(),
            }))
        }
        Command::Atmosphere { print, list } => {
            if let Some(name) = print {
                print_json(&skybake::atmosphere::presets::preset(&name)?)
            } else if list {
                for name in skybake::atmosphere::presets::preset_names() {
                    println!("{name}");
                }
                Ok(())
            } else {
                Err(Error::invalid("atmosphere", "use --print PRESET or --list").into())
            }
        }
        Command::Clouds {
            scene,
            voxels,
            format,
        } => run_clouds(&scene, voxels.as_deref(), format),
        Command::Render {
            scene,
            output,
            method,
            max_rel_error,
            format,
        } => run_render(
            &scene,
            output.as_deref(),
            &method,
            max_rel_error.as_deref(),
            format,
            &engine(no_table_cache, None)?,
        ),
        Command::Report {
            planner: true, out, ..
        } => Ok(run_planner_report(&out)?),
        Command::Report {
            quick,
            only,
            out,
            from_json,
            ..
        } => Ok(run_report(quick, only, &out, from_json.as_deref())?),
        Command::Bench {
            names,
            format,
            cold_runs,
            warm_runs,
        } => {
            let results = skybake::bench::run(&names, cold_runs.max(1), warm_runs.max(1))?;
            if format == Format::Json {
                print_json(&serde_json::json!({
                    "threads": rayon::current_num_threads(),
                    "benchmarks": results,
                }))
            } else {
                for r in results {
                    println!(
                        "{:<14} {:<5} median {:>10.2} ms  min {:>10.2} ms  ({} runs)  {}",
                        r.name, r.variant, r.median_ms, r.min_ms, r.runs, r.description
                    );
                }
                Ok(())
            }
        }
    }
}

/// A report part's JSON at `path`, `None` when there is no such file (errors name `field`).
fn read_report_part<T: serde::de::DeserializeOwned>(
    path: &Path,
    field: &str,
) -> skybake::Result<Option<T>> {
    if !path.exists() {
        return Ok(None);
    }
    let text = read_limited(path, field, 64 << 20)?;
    serde_json::from_slice(&text)
        .map(Some)
        .map_err(|e| Error::invalid(field, format!("{} is not a report: {e}", path.display())))
}

/// `skybake report --planner`: measures the planner's cost rules and writes `planner.md`.
fn run_planner_report(out: &Path) -> Result<()> {
    let rows =
        skybake::report::planner::run(&|done, total| eprintln!("planner report: {done}/{total}"))?;
    let load = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|l| l.split_whitespace().next().map(str::to_string));
    let md =
        skybake::report::planner::markdown(&rows, rayon::current_num_threads(), load.as_deref());
    let io = |e: std::io::Error| Error::invalid("out", format!("{}: {e}", out.display()));
    std::fs::create_dir_all(out).map_err(io)?;
    let path = out.join("planner.md");
    std::fs::write(&path, md).map_err(io)?;
    println!("{}", path.display());
    Ok(())
}

/// `skybake report`: runs the sweep with a progress bar on a terminal and writes the files.
fn run_report(
    quick: bool,
    only: Option<ReportPart>,
    out: &Path,
    from_json: Option<&Path>,
) -> Result<()> {
    use skybake::report::frames::FrameReport;
    use skybake::report::Report;
    if let Some(path) = from_json {
        let report: Report = read_report_part(path, "from_json")?.ok_or_else(|| {
            Error::invalid("from_json", format!("{} does not exist", path.display()))
        })?;
        // The frame part, if there is one next to it.
        let frames: Option<FrameReport> =
            read_report_part(&path.with_file_name("frames.json"), "from_json")?;
        for path in skybake::report::write(Some(&report), frames.as_ref(), out)? {
            println!("{}", path.display());
        }
        return Ok(());
    }
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} points, {elapsed} (ETA {eta})",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let progress = |done: usize, total: usize| {
        if let Some(bar) = &bar {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    };
    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .ok()
            .and_then(|s| s.split_whitespace().next().map(str::to_string))
    };
    let report: Option<Report> = if only == Some(ReportPart::Frames) {
        read_report_part(&out.join("report.json"), "out")?
    } else {
        let mut r = skybake::report::run(&skybake::report::ReportOptions { quick }, &progress)?;
        r.machine_load = load();
        Some(r)
    };
    let frames: Option<FrameReport> = if only == Some(ReportPart::Atmosphere) {
        read_report_part(&out.join("frames.json"), "out")?
    } else {
        // A full run keeps its converged references next to the report (they take minutes).
        let mut f = skybake::report::frames::run(quick, (!quick).then_some(out), &progress)?;
        f.machine_load = load();
        Some(f)
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    for path in skybake::report::write(report.as_ref(), frames.as_ref(), out)? {
        println!("{}", path.display());
    }
    Ok(())
}

/// Reads at most `limit` bytes of `path`, refusing larger files (errors name `field`).
fn read_limited(path: &Path, field: &str, limit: usize) -> skybake::Result<Vec<u8>> {
    use std::io::Read;
    let cannot =
        |e: std::io::Error| Error::invalid(field, format!("cannot read {}: {e}", path.display()));
    let too_large = |len: u64| {
        Error::too_large(
            field,
            format!("{} is {len} bytes", path.display()),
            format!("{limit} bytes"),
        )
    };
    let file = std::fs::File::open(path).map_err(cannot)?;
    let len = file.metadata().map_err(cannot)?.len();
    if len > limit as u64 {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limit as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(cannot)?;
    if bytes.len() > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// `skybake render`: reads the scene (the library does no I/O), renders it through the frame
/// product (the same path as `POST /v1/render`), writes the EXR or PNG and prints a summary.
fn run_render(
    scene: &Path,
    output: Option<&Path>,
    method: &str,
    max_rel_error: Option<&str>,
    format: Format,
    engine: &Engine,
) -> Result<()> {
    use skybake::cloud::scene as cloud_scene;
    use skybake::render::{FrameRequest, Method};
    let method = Method::parse(method)?;
    let ext = output
        .and_then(|o| o.extension())
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if let (Some(out), Some(ext)) = (output, ext.as_deref()) {
        if ext != "exr" && ext != "png" {
            return Err(Error::invalid(
                "output",
                format!("'{}': a frame is written as .exr or .png", out.display()),
            )
            .into());
        }
    } else if let Some(out) = output {
        return Err(Error::invalid(
            "output",
            format!("'{}': a frame is written as .exr or .png", out.display()),
        )
        .into());
    }
    let text = read_limited(scene, "scene", cloud_scene::MAX_SCENE_FILE_BYTES)?;
    // A PNG is the RGB image only: the planner may run fewer wavelengths.
    let request = FrameRequest::parse(&text, method)?
        .with_max_rel_error(max_rel_error)?
        .with_rgb_only(ext.as_deref() == Some("png"));
    let dir = scene.parent().unwrap_or(Path::new("."));
    let loader =
        |name: &str| read_limited(&dir.join(name), "path", cloud_scene::MAX_GRID_FILE_BYTES);
    // A progress bar on a terminal only: tiles done / total and the time left.
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let bar = indicatif::ProgressBar::new(request.tile_count() as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} tiles ({eta} left) {msg}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message("voxels, light, multiple scattering");
        bar
    });
    let progress = |p: skybake::render::product::TileProgress| {
        if let Some(bar) = &bar {
            if p.done > p.reused {
                bar.set_message("");
            }
            bar.set_position(p.done as u64);
        }
    };
    let image = request.compute_tiled(
        engine,
        &loader,
        &skybake::render::product::NoTiles,
        &progress,
        &|| false,
    )?;
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    match (output, ext.as_deref()) {
        (Some(out), Some("png")) => {
            let rgb = image
                .rgb()
                .ok_or_else(|| Error::invalid("frame", "has no RGB planes"))?;
            let bytes = skybake::output::frame_png(image.width(), image.height(), rgb)?;
            write_file(out, &bytes)?;
        }
        (Some(out), _) => {
            let bytes = skybake::store::encode_exr(&image)
                .map_err(|e| Error::invalid("output", e.to_string()))?;
            write_file(out, &bytes)?;
        }
        (None, _) => {}
    }
    let mut summary = skybake::render::product::frame_summary(&image);
    summary["scene"] = serde_json::json!(scene.display().to_string());
    summary["output"] = serde_json::json!(output.map(|p| p.display().to_string()));
    if format == Format::Json {
        print_json(&summary)
    } else {
        println!(
            "{} {}x{} ({:?}) -> {}",
            scene.display(),
            image.width(),
            image.height(),
            method,
            output
                .map(|p| p.display().to_string())
                .unwrap_or_else(|| "-".into())
        );
        Ok(())
    }
}

/// `skybake clouds`: reads the scene (the library does no I/O), voxelises its cloud section with
/// files resolved relative to the scene's directory, writes the grid as `.npy` and prints a
/// summary.
fn run_clouds(scene: &Path, voxels: Option<&Path>, format: Format) -> Result<()> {
    use skybake::cloud::{import, scene as cloud_scene};
    use std::time::Instant;
    if let Some(out) = voxels {
        if out
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
            != Some("npy")
        {
            return Err(Error::invalid(
                "voxels",
                format!("'{}': the density grid is written as .npy", out.display()),
            )
            .into());
        }
    }
    let start = Instant::now();
    let text = read_limited(scene, "scene", cloud_scene::MAX_SCENE_FILE_BYTES)?;
    let section = cloud_scene::parse_scene_file(&text)?;
    let dir = scene.parent().unwrap_or(Path::new("."));
    let loader =
        |name: &str| read_limited(&dir.join(name), "path", cloud_scene::MAX_GRID_FILE_BYTES);
    let parsed = Instant::now();
    let (grid, report) = section.voxelize_with_report(&loader)?;
    let voxelized = Instant::now();
    let npy_bytes = match voxels {
        Some(out) => {
            let bytes = import::to_npy_bytes(&grid);
            write_file(out, &bytes)?;
            Some(bytes.len())
        }
        None => None,
    };
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    let summary = serde_json::json!({
        "scene": scene.display().to_string(),
        "source": section.source.kind(),
        "dims": grid.dims,
        "voxel_size_m": grid.voxel_size_m,
        "origin_m": grid.origin_m.to_array(),
        "max_density": grid.max_density(),
        "nonzero_voxels": grid.data.iter().filter(|v| **v > 0.0).count(),
        "voxels": voxels.map(|p| p.display().to_string()),
        "npy_bytes": npy_bytes,
        "report": report,
        "timing_ms": {
            "read_parse": ms(start, parsed),
            "voxelize": ms(parsed, voxelized),
            "write": ms(voxelized, Instant::now()),
        },
    });
    match format {
        Format::Json => print_json(&summary),
        Format::Text => {
            println!(
                "{} ({}): {:?} voxels of {} m from {:?} m, max density {}, {} non-zero, voxelised in {:.1} ms",
                scene.display(),
                summary["source"].as_str().unwrap_or(""),
                grid.dims,
                grid.voxel_size_m,
                grid.origin_m.to_array(),
                summary["max_density"],
                summary["nonzero_voxels"],
                ms(parsed, voxelized),
            );
            if let Some(error) = summary["report"]["fit_error"].as_f64() {
                println!(
                    "satellite fit: final relative error {error:.4}, {} balls, converged {}",
                    summary["report"]["fit_balls"], summary["report"]["fit_converged"]
                );
            }
            Ok(())
        }
    }
}

/// The error naming the command-line flag (`--sun-elevation-deg`) of the request parameter it
/// names (`sun_elevation_deg`), or the field of an inline atmosphere under `--atmosphere`.
fn flag_named(e: Error) -> Error {
    let field = e.field().to_string();
    let (head, rest) = match field.split_once('.') {
        Some((h, r)) => (h, Some(r)),
        None => (field.as_str(), None),
    };
    match skybake::product::params::parameter(head).and_then(|p| p.cli) {
        Some(flag) => match rest {
            Some(rest) => e.renamed(&format!("--{flag} {rest}")),
            None => e.renamed(&format!("--{flag}")),
        },
        None => e,
    }
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("SKYBAKE_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        .init();
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Input(e)) => {
            eprintln!("error: {}", flag_named(e));
            ExitCode::from(2)
        }
        Err(CliError::Failure(message)) => {
            eprintln!("failed (not an input error): {message}");
            ExitCode::from(1)
        }
    }
}
