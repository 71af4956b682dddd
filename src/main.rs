//! `skybake`: command-line front end. Parses flags, calls the library, prints JSON or writes files.

use clap::{Args, Parser, Subcommand, ValueEnum};
use skybake::engine::Engine;
use skybake::output::{dome_png, AerialJson, DomeJson, Projection};
use skybake::service::products::{
    ProductKind, ProductRequest, AERIAL_DISTANCE_COUNT, AERIAL_MAX_DISTANCE_M, AERIAL_SHAPE,
    GROUND_SHAPE, SKY_SHAPE,
};
use skybake::spec::RequestParams;
use skybake::{Error, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "skybake", version, about = "Spectral atmosphere and sky precomputation", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Sun attenuation: transmittance, direct normal, diffuse and global horizontal irradiance.
    ///
    /// Example: skybake sun --sun-elevation-deg 30 --wavelengths 440,550,680
    Sun(CommonArgs),
    /// Sky-dome radiance table (view elevation −90…90°, azimuth 0…180° from the sun).
    ///
    /// Example: skybake sky --sun-elevation-deg 10 -o sky.exr
    Sky(DomeArgs),
    /// Ground-reflected upward skylight at the observer (view zenith 90…180°).
    ///
    /// Example: skybake ground --observer-altitude-m 3000 --probe 120:0,180:0
    Ground(DomeArgs),
    /// Aerial perspective: transmittance and in-scattered radiance against distance.
    ///
    /// Example: skybake aerial --distance-count 32 --max-distance-m 50000
    Aerial(AerialArgs),
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
    /// Run named benchmarks in-process and print median times.
    ///
    /// Example: skybake bench sky-fast sun --format json
    Bench {
        /// Benchmarks to run (default: all). Known: sun, sky-fast, sky-precise, precise-tables, ca-step, spheres,
        /// metaballs, fractal, satellite, solar-position, store.
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
    /// Run the HTTP service (settings: config/default.toml ← --config FILE ← SKYBAKE_* ← flags).
    ///
    /// Example: skybake serve --bind 127.0.0.1:8080 --cache-dir /var/cache/skybake
    Serve(ServeArgs),
    /// Run a bake job file offline (the POST /v1/jobs format); resumable.
    ///
    /// Example: skybake bake job.json --out baked/
    Bake {
        /// Job file (JSON: {"products": [...], "grids": [...]}).
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

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Format {
    Json,
    Text,
}

#[derive(Args, Clone)]
struct CommonArgs {
    /// Neither load nor save shared tables in the cache directory (SKYBAKE_CACHE_DIR or the
    /// config's cache.dir); build them in this process only.
    #[arg(long)]
    no_table_cache: bool,
    /// Sun elevation above the horizon, degrees (sun: −10…90, others: −18…90) [default: 30].
    #[arg(long, allow_hyphen_values = true)]
    sun_elevation_deg: Option<String>,
    /// Latitude, degrees (with --longitude and --time instead of --sun-elevation-deg).
    #[arg(long, allow_hyphen_values = true)]
    latitude: Option<String>,
    /// Longitude, degrees east.
    #[arg(long, allow_hyphen_values = true)]
    longitude: Option<String>,
    /// UTC time, RFC 3339 (e.g. 2026-06-21T12:00:00Z).
    #[arg(long)]
    time: Option<String>,
    /// Observer altitude above the ground, m [default: 0].
    #[arg(long, allow_hyphen_values = true)]
    observer_altitude_m: Option<String>,
    /// Wavelengths in nm, comma-separated, 1–64 values in 360–830 [default: 380,405,…,755].
    #[arg(long, allow_hyphen_values = true)]
    wavelengths: Option<String>,
    /// Atmosphere: a preset name (earth, earth-hazy, rayleigh-only, mars) or a JSON file path.
    #[arg(long)]
    atmosphere: Option<String>,
    /// Ground albedo 0–1, overriding the atmosphere's.
    #[arg(long, allow_hyphen_values = true)]
    ground_albedo: Option<String>,
    /// Multiple scattering: precise, fast or none [default: precise].
    #[arg(long)]
    method: Option<String>,
    /// Quality: draft, standard, high, reference [default: standard].
    #[arg(long)]
    quality: Option<String>,
    /// Print JSON to stdout.
    #[arg(long, value_enum)]
    format: Option<Format>,
}

#[derive(Args, Clone)]
struct DomeArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Directions to evaluate exactly, VZ:VA pairs in degrees (view zenith, azimuth from the sun).
    #[arg(long, allow_hyphen_values = true)]
    probe: Option<String>,
    /// Table rows (view elevations, concentrated at the horizon) [default: 129, ground 65].
    #[arg(long, allow_hyphen_values = true)]
    elevation_count: Option<String>,
    /// Table columns (azimuths 0…180°) [default: 64].
    #[arg(long, allow_hyphen_values = true)]
    azimuth_count: Option<String>,
    /// Write the table: .png (preview) or .exr (spectral).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// PNG projection.
    #[arg(long, value_enum, default_value_t = ProjectionArg::Fisheye)]
    projection: ProjectionArg,
    /// PNG size in pixels (height).
    #[arg(long, default_value_t = 512)]
    size: usize,
}

#[derive(Args, Clone)]
struct AerialArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Rows (view elevations) [default: 33].
    #[arg(long, allow_hyphen_values = true)]
    elevation_count: Option<String>,
    /// Columns (azimuths 0…180°) [default: 16].
    #[arg(long, allow_hyphen_values = true)]
    azimuth_count: Option<String>,
    /// Distances per ray [default: 32].
    #[arg(long, allow_hyphen_values = true)]
    distance_count: Option<String>,
    /// Largest distance, m [default: 100000].
    #[arg(long, allow_hyphen_values = true)]
    max_distance_m: Option<String>,
    /// Write the table as a spectral EXR (layers S0 = in-scattered radiance, T = transmittance).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ProjectionArg {
    Fisheye,
    Latlong,
}

fn request_params(c: &CommonArgs) -> Result<RequestParams> {
    // `--atmosphere` may name a file: read it here (the library does no I/O).
    let atmosphere = match &c.atmosphere {
        Some(a) if Path::new(a).is_file() => Some(
            std::fs::read_to_string(a)
                .map_err(|e| Error::invalid("atmosphere", format!("cannot read {a}: {e}")))?,
        ),
        other => other.clone(),
    };
    Ok(RequestParams {
        sun_elevation_deg: c.sun_elevation_deg.clone(),
        latitude_deg: c.latitude.clone(),
        longitude_deg: c.longitude.clone(),
        time: c.time.clone(),
        observer_altitude_m: c.observer_altitude_m.clone(),
        wavelengths: c.wavelengths.clone(),
        atmosphere,
        ground_albedo: c.ground_albedo.clone(),
        method: c.method.clone(),
        quality: c.quality.clone(),
        ..Default::default()
    })
}

/// The engine of one CLI call: precise tables come from (and go to) the cache directory unless
/// `--no-table-cache`, so a second call with the same atmosphere and wavelengths skips the build.
fn cli_engine(c: &CommonArgs) -> Result<Engine> {
    if c.no_table_cache {
        return Ok(Engine::new());
    }
    let settings = load_settings(None)?;
    Ok(match skybake::store::tables::open_table_store(&settings) {
        Some(store) => Engine::with_table_store(store),
        None => Engine::new(),
    })
}

fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
    let text =
        serde_json::to_string_pretty(value).map_err(|e| Error::invalid("format", e.to_string()))?;
    println!("{text}");
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes)
        .map_err(|e| Error::invalid("output", format!("cannot write {}: {e}", path.display())))
}

fn run_dome(args: &DomeArgs, ground: bool) -> Result<()> {
    // Same request → product path as the HTTP service (defaults, limits, validation).
    let params = RequestParams {
        elevation_count: args.elevation_count.clone(),
        azimuth_count: args.azimuth_count.clone(),
        probe: args.probe.clone(),
        ..request_params(&args.common)?
    };
    let kind = if ground {
        ProductKind::Ground
    } else {
        ProductKind::Sky
    };
    let req = ProductRequest::from_params(kind, &params)?;
    let (spec, probes) = (&req.spec, &req.probes);
    let shape = req
        .shape
        .unwrap_or(if ground { GROUND_SHAPE } else { SKY_SHAPE });
    let engine = cli_engine(&args.common)?;
    let product = if ground {
        engine.ground(spec, shape, probes)?
    } else {
        engine.sky(spec, shape, probes)?
    };
    if let Some(path) = &args.output {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        match ext.as_str() {
            "png" => {
                let projection = match args.projection {
                    ProjectionArg::Fisheye => Projection::Fisheye,
                    ProjectionArg::Latlong => Projection::LatLong,
                };
                write_file(path, &dome_png(&product.table, projection, args.size)?)?;
            }
            "exr" => write_file(
                path,
                &skybake::export::dome_exr(&product, spec, if ground { "ground" } else { "sky" })?,
            )?,
            _ => {
                return Err(Error::invalid(
                    "output",
                    format!("'{}': use a .exr or .png file name", path.display()),
                ))
            }
        }
    }
    if args.output.is_none() || args.common.format == Some(Format::Json) {
        print_json(&DomeJson::new(
            if ground { "ground" } else { "sky" },
            &product,
            spec,
        ))?;
    }
    Ok(())
}

fn load_settings(config: Option<&Path>) -> Result<skybake::config::Settings> {
    skybake::config::Settings::load(config)
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
    skybake::service::server::run(settings).map_err(|e| Error::invalid("serve", e))
}

fn bake(job: &Path, out: &Path, config: Option<&Path>) -> Result<()> {
    let settings = load_settings(config)?;
    let body = std::fs::read(job)
        .map_err(|e| Error::invalid("job", format!("cannot read {}: {e}", job.display())))?;
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
    let summary =
        skybake::service::jobs::bake(&body, out, &settings, |done, total, what| match &bar {
            Some(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(what.to_string());
            }
            None => eprintln!(
                "[{done}/{total}] {what} ({:.1} s)",
                start.elapsed().as_secs_f64()
            ),
        })
        .map_err(|e| Error::invalid("bake", e))?;
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    print_json(&summary)?;
    if summary.failed > 0 {
        return Err(Error::invalid(
            "bake",
            format!(
                "{} of {} products failed (see manifest.json)",
                summary.failed, summary.total
            ),
        ));
    }
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Serve(args) => serve(args),
        Command::Bake { job, out, config } => bake(&job, &out, config.as_deref()),
        Command::Healthcheck { addr } => {
            let addr = match addr {
                Some(a) => a,
                None => load_settings(None)?.server.bind,
            };
            let addr = addr
                .parse()
                .map_err(|_| Error::invalid("addr", format!("'{addr}' is not HOST:PORT")))?;
            skybake::service::server::healthcheck(addr)
                .map_err(|e| Error::invalid("healthcheck", e))
        }
        Command::Sun(c) => {
            let req = ProductRequest::from_params(ProductKind::Sun, &request_params(&c)?)?;
            print_json(&cli_engine(&c)?.sun(&req.spec)?)
        }
        Command::Sky(a) => run_dome(&a, false),
        Command::Ground(a) => run_dome(&a, true),
        Command::Aerial(a) => {
            let params = RequestParams {
                elevation_count: a.elevation_count.clone(),
                azimuth_count: a.azimuth_count.clone(),
                distance_count: a.distance_count.clone(),
                max_distance_m: a.max_distance_m.clone(),
                ..request_params(&a.common)?
            };
            let req = ProductRequest::from_params(ProductKind::Aerial, &params)?;
            let spec = req.spec.clone();
            let shape = req.shape.unwrap_or(AERIAL_SHAPE);
            let n_d = req.distance_count.unwrap_or(AERIAL_DISTANCE_COUNT);
            let max_d = req.max_distance_m.unwrap_or(AERIAL_MAX_DISTANCE_M);
            let product = cli_engine(&a.common)?.aerial(&spec, shape, n_d, max_d)?;
            if let Some(path) = &a.output {
                if path
                    .extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase)
                    .as_deref()
                    != Some("exr")
                {
                    return Err(Error::invalid(
                        "output",
                        format!("'{}': aerial tables are written as .exr", path.display()),
                    ));
                }
                write_file(path, &skybake::export::aerial_exr(&product, &spec)?)?;
            }
            if a.output.is_none() || a.common.format == Some(Format::Json) {
                print_json(&AerialJson::new(&product, &spec))?;
            }
            Ok(())
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
                Err(Error::invalid("atmosphere", "use --print PRESET or --list"))
            }
        }
        Command::Clouds {
            scene,
            voxels,
            format,
        } => run_clouds(&scene, voxels.as_deref(), format),
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

/// Reads at most `limit` bytes of `path`, refusing larger files (errors name `field`).
fn read_limited(path: &Path, field: &str, limit: usize) -> Result<Vec<u8>> {
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
            ));
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
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}
