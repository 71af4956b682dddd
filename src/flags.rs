//! The command-line flags: the product flags generated from the parameter table ([`PARAMETERS`]),
//! and the arguments of each command.

use std::path::PathBuf;

use clap::{Arg, ArgAction, ArgMatches, Args, FromArgMatches, ValueEnum};
use skybake_product::params::{RequestParams, PARAMETERS};
use skybake_product::ProductKind;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    Json,
    Text,
}

pub const SUN: u8 = 0;
pub const SKY: u8 = 1;
pub const GROUND: u8 = 2;
pub const AERIAL: u8 = 3;
/// Every product's flags (`skybake plan`; the request then refuses those its product lacks).
pub const ANY: u8 = 4;
/// The texture bundle's flags (`skybake lut`): the atmosphere's rows of the table.
pub const LUT: u8 = 5;

/// The product flags, built from the parameter table ([`PARAMETERS`]): one `--flag` per row that
/// the product `K` takes, with the row's doc, unit, range and default as help.
#[derive(Clone, Default)]
pub struct ProductFlags<const K: u8> {
    pub params: RequestParams,
}

pub fn kind_of(k: u8) -> Option<ProductKind> {
    match k {
        SUN => Some(ProductKind::Sun),
        SKY => Some(ProductKind::Sky),
        GROUND => Some(ProductKind::Ground),
        AERIAL => Some(ProductKind::Aerial),
        _ => None,
    }
}

pub fn flag_rows(
    k: u8,
) -> impl Iterator<Item = (&'static str, &'static skybake_product::params::Parameter)> {
    PARAMETERS.iter().filter_map(move |row| {
        let applies = if k == LUT {
            skybake_product::lut::takes(row.name)
        } else {
            kind_of(k).is_none_or(|kind| row.applies_to(kind))
        };
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
pub struct SunArgs {
    #[command(flatten)]
    pub flags: ProductFlags<SUN>,
    /// Print JSON to stdout (the default).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
}

#[derive(Args, Clone)]
pub struct DomeOutput {
    /// Write the table: .png (preview) or .exr (the spectral artifact, as the service stores it).
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// PNG projection.
    #[arg(long, value_enum, default_value_t = ProjectionArg::Fisheye)]
    pub projection: ProjectionArg,
    /// PNG size in pixels (height).
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Print JSON to stdout as well when writing a file.
    #[arg(long, value_enum)]
    pub format: Option<Format>,
}

#[derive(Args, Clone)]
pub struct SkyArgs {
    #[command(flatten)]
    pub flags: ProductFlags<SKY>,
    #[command(flatten)]
    pub out: DomeOutput,
}

#[derive(Args, Clone)]
pub struct GroundArgs {
    #[command(flatten)]
    pub flags: ProductFlags<GROUND>,
    #[command(flatten)]
    pub out: DomeOutput,
}

#[derive(Args, Clone)]
pub struct AerialArgs {
    #[command(flatten)]
    pub flags: ProductFlags<AERIAL>,
    /// Write the table as a spectral EXR (layers S0 = in-scattered radiance, T = transmittance).
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// Print JSON to stdout as well when writing a file.
    #[arg(long, value_enum)]
    pub format: Option<Format>,
}

#[derive(Args, Clone)]
pub struct LutArgs {
    #[command(flatten)]
    pub flags: ProductFlags<LUT>,
    /// Directory to write the bundle to (created if missing): transmittance.exr, scattering.exr,
    /// irradiance.exr (+ single_mie_scattering.exr in spectral form) and manifest.json; with
    /// --layout skyview: transmittance.exr, skyview_rayleigh.exr, skyview_mie.exr,
    /// skyview_scale.exr, skyview_irradiance.exr and manifest.json.
    #[arg(short = 'o', long = "output", value_name = "DIR")]
    pub output: PathBuf,
    /// The bundle's layout: bruneton2017 (his textures, read by his shader functions) or
    /// skyview (skybake's sky-view layout, within the accuracy targets; docs/lut.md).
    #[arg(long, value_name = "NAME", default_value = "bruneton2017")]
    pub layout: String,
}

#[derive(Args, Clone)]
pub struct PlanArgs {
    /// The product: sun, sky, ground, aerial, or frame (with --scene; --method fast|reference).
    pub product: String,
    /// The frame scene (product `frame`).
    #[arg(long, value_name = "SCENE_JSON")]
    pub scene: Option<PathBuf>,
    /// Plan the frame as an RGB-only request (what `skybake render -o FRAME.png` and
    /// `POST /v1/render?format=png` run): the planner may leave wavelengths out.
    #[arg(long)]
    pub rgb_only: bool,
    #[command(flatten)]
    pub flags: ProductFlags<ANY>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ProjectionArg {
    Fisheye,
    Latlong,
}

#[derive(Args, Clone)]
pub struct ServeArgs {
    /// Address to listen on (overrides SKYBAKE_BIND and the config).
    #[arg(long)]
    pub bind: Option<String>,
    /// Cache directory (overrides SKYBAKE_CACHE_DIR and the config).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Bucket shared with other replicas, s3://bucket/prefix (overrides SKYBAKE_CACHE_URL and
    /// the config; credentials and endpoint from the AWS_* variables).
    #[arg(long)]
    pub cache_url: Option<String>,
    /// Settings file (TOML, any subset of config/default.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
}
