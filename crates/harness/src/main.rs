//! `skybake-harness`: the measurement harness's command line. `report` measures error against run
//! time for every product, method and preset (and the planner's cost rules with `--planner`);
//! `bench` runs the in-process benchmarks.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use skybake_physics::{Error, Result};

#[derive(Parser)]
#[command(name = "skybake-harness", version, about = "skybake's measurement harness: error against run time, benchmarks", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run named benchmarks in-process and print median times.
    ///
    /// Example: skybake-harness bench sky-fast sun --format json
    Bench {
        /// Benchmarks to run (default: all). Known: sun, sky-fast, sky-hillaire, sky-precise, precise-tables,
        /// ca-step, spheres, metaballs, fractal, satellite, solar-position, frame, frame-pattern,
        /// frame-sequence, frame-accuracy, store.
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
    /// Example: skybake-harness report --quick --out /tmp/report
    ///          skybake-harness report --only frames   (the cloud frames' part; the rest is kept)
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
}

/// The parts of `skybake-harness report`.
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

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Report {
            planner: true, out, ..
        } => run_planner_report(&out),
        Command::Report {
            quick,
            only,
            out,
            from_json,
            ..
        } => run_report(quick, only, &out, from_json.as_deref()),
        Command::Bench {
            names,
            format,
            cold_runs,
            warm_runs,
        } => {
            let results = skybake_harness::bench::run(&names, cold_runs.max(1), warm_runs.max(1))?;
            if format == Format::Json {
                let text = serde_json::to_string_pretty(&serde_json::json!({
                    "threads": rayon::current_num_threads(),
                    "benchmarks": results,
                }))
                .map_err(|e| Error::internal("bench", format!("JSON encoding: {e}")))?;
                println!("{text}");
            } else {
                for r in results {
                    println!(
                        "{:<14} {:<5} median {:>10.2} ms  min {:>10.2} ms  ({} runs)  {}",
                        r.name, r.variant, r.median_ms, r.min_ms, r.runs, r.description
                    );
                }
            }
            Ok(())
        }
    }
}

/// A report part's JSON at `path`, `None` when there is no such file (errors name `field`).
fn read_report_part<T: serde::de::DeserializeOwned>(
    path: &Path,
    field: &str,
) -> skybake_physics::Result<Option<T>> {
    if !path.exists() {
        return Ok(None);
    }
    let text = skybake_store::files::read_limited(path, field, 64 << 20)?;
    serde_json::from_slice(&text)
        .map(Some)
        .map_err(|e| Error::invalid(field, format!("{} is not a report: {e}", path.display())))
}

/// `skybake-harness report --planner`: measures the planner's cost rules and writes `planner.md`.
fn run_planner_report(out: &Path) -> Result<()> {
    let rows = skybake_harness::report::planner::run(&|done, total| {
        eprintln!("planner report: {done}/{total}")
    })?;
    let load = skybake_harness::process::load_average_1min();
    let md = skybake_harness::report::planner::markdown(
        &rows,
        rayon::current_num_threads(),
        load.as_deref(),
    );
    skybake_store::files::create_dir_all(out)?;
    let path = out.join("planner.md");
    skybake_store::write_atomic(&path, md.as_bytes())?;
    println!("{}", path.display());
    Ok(())
}

/// `skybake-harness report`: runs the sweep with a progress bar on a terminal and writes the files.
fn run_report(
    quick: bool,
    only: Option<ReportPart>,
    out: &Path,
    from_json: Option<&Path>,
) -> Result<()> {
    use skybake_harness::report::frames::FrameReport;
    use skybake_harness::report::Report;
    if let Some(path) = from_json {
        let report: Report = read_report_part(path, "from_json")?.ok_or_else(|| {
            Error::invalid("from_json", format!("{} does not exist", path.display()))
        })?;
        // The frame part, if there is one next to it.
        let frames: Option<FrameReport> =
            read_report_part(&path.with_file_name("frames.json"), "from_json")?;
        for path in skybake_harness::report::write(Some(&report), frames.as_ref(), out)? {
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
    let load = skybake_harness::process::load_average_1min;
    let report: Option<Report> = if only == Some(ReportPart::Frames) {
        read_report_part(&out.join("report.json"), "out")?
    } else {
        let mut r = skybake_harness::report::run(
            &skybake_harness::report::ReportOptions { quick },
            &progress,
        )?;
        r.machine_load = load();
        Some(r)
    };
    let frames: Option<FrameReport> = if only == Some(ReportPart::Atmosphere) {
        read_report_part(&out.join("frames.json"), "out")?
    } else {
        // A full run keeps its converged references next to the report (they take minutes).
        let mut f =
            skybake_harness::report::frames::run(quick, (!quick).then_some(out), &progress)?;
        f.machine_load = load();
        Some(f)
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    for path in skybake_harness::report::write(report.as_ref(), frames.as_ref(), out)? {
        println!("{}", path.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.is_input() => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("failed (not an input error): {e}");
            ExitCode::from(1)
        }
    }
}
