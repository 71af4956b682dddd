//! Cloud density sources. Every source produces a [`DensityGrid`] (and, where it helps, an
//! analytic evaluator) that the renderer consumes.
//!
//! - [`wyvill`]: Wyvill's metaball field and its (corrected) normalisation, Dobashi et al. 2000, app. B
//! - [`metaballs`]: metaball density fields with a bin grid, voxelised in parallel (Nishita & Dobashi 2001, eq 3)
//! - [`marching_cubes`]: isosurface triangles of a grid (used by fractal growth)
//! - [`fractal`]: fractal growth of metaballs on their isosurface (Nishita et al. 1996, §4)
//! - [`satellite`]: metaballs fitted to a satellite image (Nishita & Dobashi 2001, §3.1)
//! - [`import`]: `.npy` and raw f32 + JSON grids, parsed from bytes
//! - [`vdb`]: OpenVDB `.vdb` float grids, walked and bounded, then decoded by `vdb-rs`
//! - [`scene`]: the cloud section of the scene JSON and `voxelize` with an injected loader

pub mod fractal;
pub mod grid;
pub mod import;
pub mod marching_cubes;
pub mod metaballs;
pub mod satellite;
pub mod scene;
pub mod vdb;
pub mod wyvill;

pub use grid::DensityGrid;
pub mod automaton;
pub mod spheres;
