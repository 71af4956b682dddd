//! Hierarchical-sphere cloud model for ray tracing (seed 004, Ostroushko et al.).
//!
//! A base sphere is split K times into five smaller spheres placed inside it; every sphere bounds
//! its five children, so a ray descends only into spheres it hits. `model` builds the hierarchy,
//! `optics` turns the meteorological optical range into transmittance (eqs 1–3), `trace` walks
//! rays with level of detail and renders transmittance images, `voxel` samples the model into a
//! [`crate::cloud::DensityGrid`].
//!
//! ```no_run
//! # use skybake::cloud::spheres::{SphereCloud, SphereCloudParams};
//! let cloud = SphereCloud::new(&SphereCloudParams::cumulus(6, 42))?;
//! let grid = cloud.voxelize(25.0, None)?;
//! # Ok::<(), skybake::Error>(())
//! ```

pub mod model;
pub mod optics;
pub mod trace;
pub mod voxel;

pub use model::{Sphere, SphereCloud, SphereCloudParams, MAX_LEVELS};
pub use optics::{edge_weight, extinction_from_mor_per_m, sphere_transmittance};
pub use trace::{bench_spheres, Camera, Lod, Ray, SpheresBench, TraceStats};
