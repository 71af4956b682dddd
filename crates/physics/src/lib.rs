//! skybake's physics: spectra, phase functions, the solar position, the atmosphere (media, the
//! transmittance and scattering tables, radiative transfer along rays) and the cloud density sources.
//!
//! Pure computation: nothing here reads a file, a clock (except timing) or the network. Every entry
//! point validates its input and returns [`Error`], which names the parameter. The in-memory spectral
//! image ([`image`]) and the content key ([`key`]) live here because the tables that the store keeps
//! between processes are written as such images under such keys.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod atmosphere;
pub mod camera;
pub mod cloud;
pub mod error;
pub mod image;
pub mod key;
pub mod phase;
pub mod solar;
pub mod solar_position;
pub mod spectrum;

pub use error::{Error, Result};
