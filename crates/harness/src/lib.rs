//! skybake's measurement harness: the error-against-run-time report ([`report`]), in-process
//! benchmarks ([`bench`], [`frame_bench`], [`physics_bench`], [`store_bench`]) and their plots. It depends on every
//! layer and nothing depends on it, so the server and the CLI link none of it.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod bench;
pub mod frame_bench;
pub mod physics_bench;
pub mod process;
pub mod report;
pub mod store_bench;

pub use skybake_physics::{Error, Result};
