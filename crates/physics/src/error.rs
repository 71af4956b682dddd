//! The engine's error type: every public entry point validates its input and returns one of these.

use thiserror::Error;

/// Errors from parsing, validating and computing products.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum Error {
    /// A parameter lies outside its allowed range.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        field: String,
        value: String,
        allowed: String,
    },
    /// A parameter is malformed or inconsistent with others.
    #[error("{field}: {reason}")]
    Invalid { field: String, reason: String },
    /// A request exceeds a resource limit (table size, wavelength count, memory).
    #[error("{field}: {reason} (limit {limit})")]
    TooLarge {
        field: String,
        reason: String,
        limit: String,
    },
    /// Not the request's fault: stored data that fails to decode (a malformed cached artifact),
    /// an encoder failure. HTTP 500 (and the artifact is recomputed), CLI exit code 1.
    #[error("internal error in {what}: {reason}")]
    Internal { what: String, reason: String },
    /// The computation was stopped because nobody wants its result any more (every client that
    /// asked for it has gone). Not the request's fault; nobody is left to answer.
    #[error("computation cancelled: every client waiting for it has gone")]
    Cancelled,
}

impl Error {
    /// Shorthand for [`Error::OutOfRange`].
    pub fn out_of_range(field: &str, value: impl ToString, allowed: impl ToString) -> Self {
        Error::OutOfRange {
            field: field.to_string(),
            value: value.to_string(),
            allowed: allowed.to_string(),
        }
    }

    /// Shorthand for [`Error::Invalid`].
    pub fn invalid(field: &str, reason: impl ToString) -> Self {
        Error::Invalid {
            field: field.to_string(),
            reason: reason.to_string(),
        }
    }

    /// Shorthand for [`Error::TooLarge`].
    pub fn too_large(field: &str, reason: impl ToString, limit: impl ToString) -> Self {
        Error::TooLarge {
            field: field.to_string(),
            reason: reason.to_string(),
            limit: limit.to_string(),
        }
    }

    /// Shorthand for [`Error::Internal`].
    pub fn internal(what: &str, reason: impl ToString) -> Self {
        Error::Internal {
            what: what.to_string(),
            reason: reason.to_string(),
        }
    }

    /// Whether the fault lies with the request (bad input) rather than the server.
    pub fn is_input(&self) -> bool {
        !matches!(self, Error::Internal { .. } | Error::Cancelled)
    }

    /// The same error with `prefix` put before the parameter name (e.g. `products[3].`).
    pub fn prefixed(self, prefix: &str) -> Self {
        match self {
            Error::OutOfRange {
                field,
                value,
                allowed,
            } => Error::OutOfRange {
                field: format!("{prefix}{field}"),
                value,
                allowed,
            },
            Error::Invalid { field, reason } => Error::Invalid {
                field: format!("{prefix}{field}"),
                reason,
            },
            Error::TooLarge {
                field,
                reason,
                limit,
            } => Error::TooLarge {
                field: format!("{prefix}{field}"),
                reason,
                limit,
            },
            other @ (Error::Internal { .. } | Error::Cancelled) => other,
        }
    }

    /// The same error naming `field` instead (the CLI names its flags, not query names).
    pub fn renamed(self, field: &str) -> Self {
        match self {
            Error::OutOfRange { value, allowed, .. } => Error::OutOfRange {
                field: field.to_string(),
                value,
                allowed,
            },
            Error::Invalid { reason, .. } => Error::Invalid {
                field: field.to_string(),
                reason,
            },
            Error::TooLarge { reason, limit, .. } => Error::TooLarge {
                field: field.to_string(),
                reason,
                limit,
            },
            other @ (Error::Internal { .. } | Error::Cancelled) => other,
        }
    }

    /// The name of the offending parameter (for an internal error: what failed).
    pub fn field(&self) -> &str {
        match self {
            Error::OutOfRange { field, .. }
            | Error::Invalid { field, .. }
            | Error::TooLarge { field, .. } => field,
            Error::Internal { what, .. } => what,
            Error::Cancelled => "computation",
        }
    }
}

/// Result alias for the engine.
pub type Result<T, E = Error> = std::result::Result<T, E>;
