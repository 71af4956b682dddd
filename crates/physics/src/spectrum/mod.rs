//! Wavelengths, tabulated spectra, the embedded data tables and colour conversion.

pub mod colour;
pub mod data;
pub mod photometry;
pub mod subsets;
pub mod tabulated;
pub mod wavelengths;

pub use colour::{spectrum_to_xyz, xyz_to_linear_srgb};
pub use tabulated::Tabulated;
pub use wavelengths::Wavelengths;
