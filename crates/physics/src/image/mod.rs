//! The in-memory spectral image and its layout (the spectral OpenEXR channel and attribute names of
//! Fichet, Pacanowski & Wilkie 2021). Encoding to and decoding from bytes is the store's.

pub mod layout;
pub mod spectral_image;

pub use spectral_image::{SpectralImage, SpectralLayer};
