//! Products → spectral OpenEXR bytes (layout of DESIGN.md "Storage"), via `store::exr`.

use crate::engine::DomeProduct;
use crate::spec::CommonSpec;
use crate::{Error, Result};

/// Encodes a sky or ground table as a tiled spectral EXR.
pub fn dome_exr(_p: &DomeProduct, _spec: &CommonSpec, product: &str) -> Result<Vec<u8>> {
    Err(Error::invalid(
        "output",
        format!("{product}: EXR output arrives with the store module"),
    ))
}
