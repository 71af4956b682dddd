//! Why the CLI stopped: bad input (exit code 2, the message naming the flag) or a failure that is
//! not the input's fault (I/O, internal; exit code 1).

use std::path::Path;

use skybake_physics::Error;

/// Why the CLI stopped: bad input (exit code 2) or a failure that is not the input's fault (I/O,
/// internal; exit code 1).
#[derive(Debug)]
pub enum CliError {
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

impl From<skybake_store::StoreError> for CliError {
    fn from(e: skybake_store::StoreError) -> Self {
        match e {
            skybake_store::StoreError::Invalid(e) => e.into(),
            other => CliError::Failure(other.to_string()),
        }
    }
}

pub type Result<T, E = CliError> = std::result::Result<T, E>;

impl From<skybake_job::JobError> for CliError {
    fn from(e: skybake_job::JobError) -> Self {
        if e.is_input() {
            CliError::Input(Error::invalid("job", e))
        } else {
            CliError::Failure(e.to_string())
        }
    }
}

pub fn io_error(e: std::io::Error, field: &str, path: &Path) -> CliError {
    let message = format!("cannot read {}: {e}", path.display());
    if e.kind() == std::io::ErrorKind::NotFound {
        CliError::Input(Error::invalid(field, message))
    } else {
        CliError::Failure(message)
    }
}

/// The error naming the command-line flag (`--sun-elevation-deg`) of the request parameter it
/// names (`sun_elevation_deg`), or the field of an inline atmosphere under `--atmosphere`.
pub fn flag_named(e: Error) -> Error {
    let field = e.field().to_string();
    let (head, rest) = match field.split_once('.') {
        Some((h, r)) => (h, Some(r)),
        None => (field.as_str(), None),
    };
    match skybake_product::params::parameter(head).and_then(|p| p.cli) {
        Some(flag) => match rest {
            Some(rest) => e.renamed(&format!("--{flag} {rest}")),
            None => e.renamed(&format!("--{flag}")),
        },
        None => e,
    }
}
