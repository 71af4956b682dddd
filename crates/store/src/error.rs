//! Errors of the storage layer: invalid input (the engine's [`crate::Error`]), I/O failures with the
//! path involved, and files that fail to decode or verify.

use std::path::PathBuf;

use thiserror::Error;

/// Errors from writing, reading and caching images.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum StoreError {
    /// The caller passed something invalid (an image, key or setting); maps to a client error.
    #[error(transparent)]
    Invalid(#[from] crate::Error),
    /// An operating-system I/O error on `path`.
    #[error("I/O error on {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not an OpenEXR file in the layout skybake writes (or the encoder failed).
    #[error("OpenEXR data: {0}")]
    Exr(String),
    /// The bytes failed the integrity check (checksum mismatch, missing checksum, truncation).
    #[error("integrity check failed: {0}")]
    Corrupt(String),
    /// The bucket did not answer after every retry (HTTP 503 with `Retry-After`).
    #[error("storage unavailable ({what}): {reason}")]
    Unavailable {
        what: String,
        reason: String,
        retry_after_s: u64,
    },
}

impl StoreError {
    /// Wraps an I/O error with the path it happened on.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        StoreError::Io {
            path: path.into(),
            source,
        }
    }
}

/// A store error as the engine's error: invalid input stays input; I/O failures, undecodable and
/// corrupt files are failures that are not the input's fault.
impl From<StoreError> for crate::Error {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::Invalid(e) => e,
            other => crate::Error::internal("store", other),
        }
    }
}
