//! One module per command.

pub mod atmosphere;
pub mod bake;
pub mod cloud_light;
pub mod clouds;
pub mod lut;
pub mod lut_eval;
pub mod plan;
pub mod product;
pub mod render;
pub mod serve;
