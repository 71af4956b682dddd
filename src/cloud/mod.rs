//! Cloud density sources. Every source produces a [`DensityGrid`] (and, where it helps, an
//! analytic evaluator) that the renderer consumes.

pub mod grid;

pub use grid::DensityGrid;
pub mod automaton;
pub mod spheres;
