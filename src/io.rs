//! What the CLI reads and writes: the files a user names, stdout, and `-o` outputs through the
//! store's atomic write.

use std::path::Path;

use skybake_engine::engine::Engine;
use skybake_product::params::RequestParams;
use skybake_product::{artifact, Format as BodyFormat, ProductKind};

use crate::error::{io_error, CliError, Result};

/// The request parameters of the flags; `--atmosphere` may name a file, read here (the library
/// does no I/O).
pub fn request_params(mut p: RequestParams) -> Result<RequestParams> {
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
pub fn read_input(path: &Path, field: &str) -> Result<String> {
    String::from_utf8(read_input_bytes(path, field)?).map_err(|e| {
        CliError::Input(skybake_physics::Error::invalid(
            field,
            format!("{} is not UTF-8 text: {e}", path.display()),
        ))
    })
}

/// Reads a file the user named as bytes (errors as [`read_input`]).
pub fn read_input_bytes(path: &Path, field: &str) -> Result<Vec<u8>> {
    skybake_store::files::read(path).map_err(|e| match e {
        skybake_store::StoreError::Io { source, .. } => io_error(source, field, path),
        other => other.into(),
    })
}

pub fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
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
pub fn print_body(kind: ProductKind, image: &skybake_physics::image::SpectralImage) -> Result<()> {
    let body = artifact::render(kind, BodyFormat::Json, image)?;
    let value: serde_json::Value =
        serde_json::from_slice(&body).map_err(|e| CliError::Failure(format!("JSON body: {e}")))?;
    print_json(&value)
}

pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    // Through the store, the one place that writes (atomically).
    Ok(skybake_store::write_atomic(path, bytes)?)
}

pub fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

pub fn load_settings(config: Option<&Path>) -> Result<skybake_product::config::Settings> {
    Ok(skybake_product::config::Settings::load(config)?)
}

/// The engine of every product command (`sun`, `sky`, `ground`, `aerial`, `render`, `bake`): the
/// precise tables come from (and go to) the configured cache directory, so a second call with the
/// same atmosphere and wavelengths skips the build; `--no-table-cache` builds them in-process.
pub fn engine(no_table_cache: bool, config: Option<&Path>) -> Result<Engine> {
    if no_table_cache {
        return Ok(Engine::new());
    }
    Ok(skybake_product::engines::engine_for_settings(
        &load_settings(config)?,
    ))
}

/// Reads at most `limit` bytes of `path`, refusing larger files (errors name `field`).
pub fn read_limited(path: &Path, field: &str, limit: usize) -> skybake_physics::Result<Vec<u8>> {
    skybake_store::files::read_limited(path, field, limit)
}
