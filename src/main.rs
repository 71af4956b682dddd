//! `skybake`: the command-line front end. Parses flags, calls the library, prints JSON or writes
//! files; one module per command under `commands/`.

mod commands;
mod error;
mod flags;
mod io;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use commands::{
    atmosphere, bake, cloud_light, clouds, lut, lut_eval, plan, product, render, serve,
};
use error::{flag_named, CliError, Result};
use flags::{AerialArgs, Format, GroundArgs, LutArgs, PlanArgs, ServeArgs, SkyArgs, SunArgs};
use io::engine;
use skybake_product::ProductKind;

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
    /// Real-time texture bundle (Bruneton 2017 layout: transmittance, scattering, irradiance +
    /// manifest.json) for every observer and sun; RGB at 680/550/440 nm, or spectral with
    /// --wavelengths. See docs/lut.md.
    ///
    /// Example: skybake lut --atmosphere earth-hazy -o bundle/
    Lut(LutArgs),
    /// Evaluate a bundle written by `skybake lut` (or downloaded from GET /v1/lut) with the
    /// reference reader of its layout (Bruneton 2017's GetSkyRadiance, GetSkyRadianceToPoint,
    /// GetSunAndSkyIrradiance; the same three on the skyview layout) at the queries of a JSON
    /// file; prints the values. See docs/lut.md.
    ///
    /// Example: skybake lut-eval bundle/ queries.json
    LutEval {
        /// Bundle directory (manifest.json and its textures).
        bundle: PathBuf,
        /// Queries: {"queries": [{"function": "sky_radiance", "camera": [x, y, z], "view": [...],
        /// "sun": [...]}, ...]}, positions in m from the planet's centre (docs/lut.md).
        queries: PathBuf,
    },
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
    /// Export the pre-lit cloud volume of a frame scene for real-time clients: the fast
    /// method's per-voxel light (sun and sky paths, multiple-scattering moments) and the
    /// direction tables as OpenEXR 3-D textures + manifest.json. See docs/cloud-light.md.
    ///
    /// Example: skybake cloud-light config/scenes/cumulus-frame.json -o cumulus-light/
    CloudLight {
        /// Frame scene JSON (its camera is not used); files it names are read relative to the
        /// scene's directory.
        scene: PathBuf,
        /// Directory to write the textures and manifest.json into (created if missing).
        #[arg(short = 'o', long = "output", value_name = "DIR")]
        output: PathBuf,
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
    /// Run the HTTP service (settings: config/default.toml ← --config FILE ← SKYBAKE_* ← flags).
    ///
    /// Example: skybake serve --bind 127.0.0.1:8080 --cache-dir /var/cache/skybake
    Serve(ServeArgs),
    /// Run a bake job file offline (the POST /v1/jobs format); resumable, and shardable over
    /// processes sharing the output (e.g. a bucket).
    ///
    /// Example: skybake bake job.json --out baked/
    /// Example: skybake bake job.json --out s3://assets/bakes/job1 --shard 2/8
    Bake {
        /// Job file (JSON: {"products": [...], "grids": [...], "frames": [...], "bundles": [...]}; see README "Bake jobs").
        job: PathBuf,
        /// Output directory or bucket folder (s3://bucket/prefix; AWS_* credentials and
        /// endpoint): an EXR per product + manifest.json; a rerun reuses finished files.
        #[arg(long)]
        out: String,
        /// This process's share, I/N: items i with i mod N = I. Default: the Kubernetes Indexed
        /// Job's JOB_COMPLETION_INDEX / JOB_COMPLETIONS when set, else the whole job.
        #[arg(long)]
        shard: Option<String>,
        /// Print the progress of the bake over all shards (JSON) and exit.
        #[arg(long)]
        status: bool,
        /// Bucket for the shared precise tables, s3://bucket/prefix (overrides SKYBAKE_CACHE_URL).
        #[arg(long)]
        cache_url: Option<String>,
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

fn run(cli: Cli) -> Result<()> {
    let no_table_cache = cli.no_table_cache;
    let engine = || engine(no_table_cache, None);
    match cli.command {
        Command::Serve(args) => serve::serve(args),
        Command::Healthcheck { addr } => serve::healthcheck(addr),
        Command::Bake {
            job,
            out,
            shard,
            status,
            cache_url,
            config,
        } => bake::bake(bake::BakeArgs {
            job: &job,
            out: &out,
            shard: shard.as_deref(),
            status,
            cache_url: cache_url.as_deref(),
            config: config.as_deref(),
            no_table_cache,
        }),
        Command::Sun(a) => product::sun(&a.flags.params, &engine()?),
        Command::Sky(a) => product::run_dome(ProductKind::Sky, &a.flags.params, &a.out, &engine()?),
        Command::Ground(a) => {
            product::run_dome(ProductKind::Ground, &a.flags.params, &a.out, &engine()?)
        }
        Command::Aerial(a) => {
            product::aerial(&a.flags.params, a.output.as_ref(), a.format, &engine()?)
        }
        Command::Lut(a) => lut::lut(&a.flags.params, &a.layout, &a.output, &engine()?),
        Command::LutEval { bundle, queries } => lut_eval::lut_eval(&bundle, &queries),
        Command::Plan(a) => plan::plan(&a, engine),
        Command::Atmosphere { print, list } => atmosphere::atmosphere(print.as_deref(), list),
        Command::Clouds {
            scene,
            voxels,
            format,
        } => clouds::run_clouds(&scene, voxels.as_deref(), format),
        Command::CloudLight {
            scene,
            output,
            format,
        } => cloud_light::cloud_light(&scene, &output, format, &engine()?),
        Command::Render {
            scene,
            output,
            method,
            max_rel_error,
            format,
        } => render::run_render(
            &scene,
            output.as_deref(),
            &method,
            max_rel_error.as_deref(),
            format,
            &engine()?,
        ),
    }
}

/// Logs to stderr, filtered by `SKYBAKE_LOG`: comma-separated `target=level` directives and a bare
/// default level (`info`, `skybake=debug,warn`); `warn` when unset. A value that does not parse is
/// reported and the default kept.
fn init_logging() {
    use tracing_subscriber::filter::{LevelFilter, Targets};
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let default = Targets::new().with_default(LevelFilter::WARN);
    let filter = match std::env::var("SKYBAKE_LOG") {
        Ok(text) => text.parse::<Targets>().unwrap_or_else(|e| {
            eprintln!("warning: SKYBAKE_LOG={text:?} is not a list of target=level directives ({e}); logging warnings");
            default
        }),
        Err(_) => default,
    };
    tracing_subscriber::registry()
        .with(tracing_subscriber::fmt::layer().with_writer(std::io::stderr))
        .with(filter)
        .init();
}

fn main() -> ExitCode {
    init_logging();
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
