//! skybake: a spectral atmosphere-and-sky precomputation engine.
//!
//! The engine is pure computation (no I/O): parse a request into a validated spec, run it, get a
//! product. Only [`store`] touches the disk. See `ARCHITECTURE.md` for the map.

pub mod cloud;
pub mod error;
pub mod solar_position;

pub use error::{Error, Result};
