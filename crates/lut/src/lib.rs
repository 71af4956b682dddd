//! The real-time texture bundle of an atmosphere: transmittance, scattering and irradiance
//! textures in Bruneton 2017's exact layout and parameterisation ([`param`]), computed by
//! skybake's precise method ([`build`]), described by a manifest ([`manifest`]), and read back
//! with his shader functions ([`reader`]). Pure computation: the store writes the files.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod build;
pub mod load;
pub mod manifest;
mod ms_columns;
mod ms_directions;
mod ms_rows;
pub mod param;
pub mod reader;
pub mod skyview;

pub use build::{build, Bundle, Channels, Sample, Texture, TEXEL_REVISION, UNIT_SCALE};
pub use reader::Reader;
pub use skybake_physics::{Error, Result};
pub use skyview::{build_skyview, build_skyview_into, SkyViewBundle, SkyViewReader};
