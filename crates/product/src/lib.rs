//! skybake's product core: a request (CLI flags, query string, JSON body or job item) becomes a
//! validated spec, the spec a plan, the plan a computed product, and the product an artifact (the
//! spectral EXR image with its request, response, plan and timing attributes) kept in the store.
//! Every product kind (sun, sky, ground, aerial and the cloud frame) takes that one road.
//!
//! - [`AnyRequest`]: the one interface of every product kind (key, compute, body).
//! - [`params`]: the one parameter table (name, flag, unit, range, default, doc).
//! - [`ProductRequest`]: an atmosphere product's request; [`frame::FrameRequest`]: a frame's.
//! - [`artifact`]: compute → artifact; JSON, PNG and EXR bodies rendered from it.
//! - [`cost`]: a request's and a job's cost estimate; [`config`]: the deployment settings.
//! - [`engines`]: the engine of every product path, on the store's stored tables.
//! - [`lut`]: the real-time texture bundle of an atmosphere (Bruneton 2017's layout).
//! - [`cloud_light`]: pre-lit cloud volumes for real-time clients, and their reference marcher.

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

mod any;
pub mod artifact;
pub mod cloud_light;
pub mod config;
pub mod cost;
pub mod engines;
pub mod export;
pub mod frame;
pub mod lut;
pub mod params;
mod request;

pub use any::{AnyRequest, ComputeEnv};
pub use request::*;
pub use skybake_physics::{Error, Result};
