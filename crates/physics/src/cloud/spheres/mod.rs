//! Hierarchical-sphere cloud model for ray tracing (Ostroushko, Bilous, Bugriy, Chagovets, "Mathematical Model of the Cloud for Ray Tracing").
//!
//! A base sphere is split K times into five smaller spheres placed inside it; every sphere bounds
//! its five children, so a ray descends only into spheres it hits. `model` builds the hierarchy,
//! `optics` turns the meteorological optical range into transmittance (eqs 1–3), `trace` walks
//! rays with level of detail and renders transmittance images, `voxel` samples the model into a
//! [`crate::cloud::DensityGrid`].
//!
//! Where this departs from the paper, and why:
//! - f_Δ(C, R) is printed as R² − C², which has the wrong units; its stated purpose ("calculating
//!   one coordinate from the known radius R and other coordinate C" to fit the child inside) is
//!   √(R² − C²). Child 5 uses C = (r − r₅)·s₅ like the others (the print has S₅ alone).
//! - Eq 3's d is read as the distance from the sphere centre to the ray when tracing; the
//!   voxelisation uses the distance of the sample point, the volumetric form of the same edge
//!   function.
//! - Bump mapping (eq 4) perturbs surface normals for shading and does not change transmittance,
//!   so it is not part of the density model.
//!
//! ```no_run
//! # use skybake_physics::cloud::spheres::{SphereCloud, SphereCloudParams};
//! let cloud = SphereCloud::new(&SphereCloudParams::cumulus(6, 42))?;
//! let grid = cloud.voxelize(25.0, None)?;
//! # Ok::<(), skybake_physics::Error>(())
//! ```

pub mod model;
pub mod optics;
pub mod trace;
pub mod voxel;

pub use model::{Sphere, SphereCloud, SphereCloudParams, MAX_LEVELS};
pub use optics::{edge_weight, extinction_from_mor_per_m, sphere_transmittance};
pub use trace::{Camera, Lod, Ray, TraceStats};
