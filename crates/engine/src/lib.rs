//! skybake's atmosphere engine: the canonical specs of the sun, sky, ground and aerial products
//! ([`spec`]), the planner that decides which stages a request needs ([`plan`]), the engine that
//! executes plans on shared tables ([`engine`]), the compiled-in accuracy report ([`accuracy`]) and
//! the JSON and preview documents of its products ([`output`]).
//!
//! Pure computation: no I/O. Stored tables reach the engine through the
//! [`TableStore`](skybake_physics::atmosphere::shared::TableStore) hook that a caller supplies.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod accuracy;
pub mod engine;
pub mod output;
pub mod plan;
pub mod spec;

pub use skybake_physics::{Error, Result};
