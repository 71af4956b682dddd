//! `skybake bake`: a job file run offline into a directory, resumably.

use std::path::Path;

use crate::error::{CliError, Result};
use crate::io::{engine, load_settings, print_json, read_input_bytes};

pub fn bake(job: &Path, out: &Path, config: Option<&Path>, no_table_cache: bool) -> Result<()> {
    let settings = load_settings(config)?;
    let engine = engine(no_table_cache, config)?;
    let body = read_input_bytes(job, "job")?;
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
    let defaults = skybake_product::params::Defaults::from_settings(&settings);
    let summary = skybake_job::bake::bake(
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
    )?;
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
