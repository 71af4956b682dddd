//! The atmosphere engine: parameters, resolved media, geometry, transmittance, single and
//! multiple scattering, and the products built on them (sun, sky, ground, aerial).

pub mod geometry;
pub mod medium;
pub mod params;
pub mod presets;
pub mod transmittance;

pub use medium::Medium;
pub use params::AtmosphereParams;
