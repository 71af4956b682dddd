//! The bucket's client in a build without the `s3` feature: there is none, so opening a bucket
//! is an error that says how to build skybake with one, and no [`Client`] value can exist.

use std::time::Duration;

use super::{Failure, Listing, Outcome, Versioned, Write};
use crate::StoreError;

pub(super) enum Client {}

impl Client {
    pub(super) fn open(
        url: &str,
        _bucket: &str,
        _overrides: &[(&str, &str)],
        _request_timeout: Duration,
    ) -> Result<Self, StoreError> {
        Err(crate::Error::invalid(
            "cache_url",
            format!(
                "{url}: this skybake was built without the S3 backend; build it with \
                 `cargo build --release --features s3` (the container image has it), or use a directory"
            ),
        )
        .into())
    }

    pub(super) fn get(&self, _key: &str, _max_bytes: u64) -> Result<Outcome<Versioned>, Failure> {
        match *self {}
    }

    pub(super) fn put(
        &self,
        _key: &str,
        _bytes: &[u8],
        _mode: &Write,
    ) -> Result<Outcome<String>, Failure> {
        match *self {}
    }

    pub(super) fn delete(&self, _key: &str) -> Result<Outcome<()>, Failure> {
        match *self {}
    }

    pub(super) fn list(&self, _key: &str) -> Result<Outcome<Listing>, Failure> {
        match *self {}
    }
}
