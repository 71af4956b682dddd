//! The atmosphere engine: parameters, resolved media, geometry, transmittance, single and
//! multiple scattering, and the products built on them (sun, sky, ground, aerial).

pub mod geometry;
pub mod haze;
pub mod integrate;
pub mod irradiance;
pub mod kernels;
pub mod medium;
pub mod multiple_fast;
pub mod multiple_precise;
pub mod params;
pub mod presets;
pub mod quadrature;
pub mod quality;
pub mod shared;
pub mod sky;
pub mod sun_transmittance;
pub mod transmittance;

pub use medium::Medium;
pub use params::AtmosphereParams;
