//! `skybake bake`: a job file run offline into a directory or a bucket folder, resumably, whole
//! or as one shard of several processes (`--shard I/N`, or a Kubernetes Indexed Job's
//! `JOB_COMPLETION_INDEX` / `JOB_COMPLETIONS`); `--status` reports progress over all shards.

use std::path::Path;

use skybake_job::bake::{BakeEnv, Shard};
use skybake_store::Location;

use crate::error::{CliError, Result};
use crate::io::{load_settings, print_json, read_input_bytes};

/// What `skybake bake` was asked to do.
pub struct BakeArgs<'a> {
    pub job: &'a Path,
    pub out: &'a str,
    pub shard: Option<&'a str>,
    pub status: bool,
    pub cache_url: Option<&'a str>,
    pub config: Option<&'a Path>,
    pub no_table_cache: bool,
}

/// The shard of this process: `--shard I/N`, else the Indexed Job's variables, else the whole job.
fn shard(flag: Option<&str>) -> Result<Shard> {
    if let Some(text) = flag {
        return Ok(Shard::parse(text)?);
    }
    let var = |name: &str| std::env::var(name).ok().filter(|v| !v.trim().is_empty());
    match (var("JOB_COMPLETION_INDEX"), var("JOB_COMPLETIONS")) {
        (None, None) => Ok(Shard::ALL),
        (Some(index), Some(count)) => Ok(Shard::parse(&format!("{index}/{count}"))
            .map_err(|e| CliError::Input(skybake_physics::Error::invalid("JOB_COMPLETION_INDEX", e)))?),
        (Some(_), None) => Err(CliError::Input(skybake_physics::Error::invalid(
            "JOB_COMPLETIONS",
            "JOB_COMPLETION_INDEX is set but JOB_COMPLETIONS is not: set it to the Job's completions (the shard count)",
        ))),
        (None, Some(_)) => Err(CliError::Input(skybake_physics::Error::invalid(
            "JOB_COMPLETION_INDEX",
            "JOB_COMPLETIONS is set but JOB_COMPLETION_INDEX is not",
        ))),
    }
}

pub fn bake(args: BakeArgs) -> Result<()> {
    let mut settings = load_settings(args.config)?;
    if let Some(url) = args.cache_url {
        settings.cache.url = url.to_string();
        settings.validate()?;
    }
    let shard = shard(args.shard)?;
    let engine = if args.no_table_cache {
        skybake_engine::engine::Engine::new()
    } else {
        skybake_product::engines::engine_for_settings(&settings)
    };
    let body = read_input_bytes(args.job, "job")?;
    let out = Location::parse(args.out).map_err(|e| match e {
        skybake_store::StoreError::Invalid(e) => CliError::Input(e.renamed("out")),
        other => other.into(),
    })?;
    let defaults = skybake_product::params::Defaults::from_settings(&settings);
    if args.status {
        let status = skybake_job::bake::status(&body, &out, &defaults, settings.jobs.max_products)?;
        return print_json(&status);
    }
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
    let env = BakeEnv {
        defaults: &defaults,
        max_products: settings.jobs.max_products,
        engine: &engine,
        cancel: &|| false,
    };
    let summary =
        skybake_job::bake::bake_share(&body, &out, shard, &env, |done, total, what| match &bar {
            Some(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(what.to_string());
            }
            None => eprintln!(
                "[{done}/{total}] {what} ({:.1} s)",
                start.elapsed().as_secs_f64()
            ),
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
