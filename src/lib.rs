//! skybake: a spectral atmosphere-and-sky precomputation engine.
//!
//! The engine is pure computation (no I/O): parse a request into a validated spec, run it, get a
//! product. Only [`store`] touches the disk. See `ARCHITECTURE.md` for the map.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod accuracy;
pub mod atmosphere;
pub mod bench;
pub mod camera;
pub mod cloud;
pub mod config;
pub mod cost;
pub mod engine;
pub mod error;
pub mod export;
pub mod job;
pub mod output;
pub mod phase;
pub mod plan;
pub mod product;
pub mod render;
pub mod report;
pub mod service;
pub mod solar;
pub mod solar_position;
pub mod spec;
pub mod spectrum;
pub mod store;

pub use error::{Error, Result};
