//! Cloud density sources. Every source produces a [`DensityGrid`] (and, where it helps, an
//! analytic evaluator) that the renderer consumes.

pub mod grid;

pub use grid::DensityGrid;
pub mod fractal;
pub mod import;
pub mod marching_cubes;
pub mod metaballs;
pub mod satellite;
pub mod scene;
pub mod wyvill;
