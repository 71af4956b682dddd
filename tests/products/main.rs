//! The product core, the store, jobs and the CLI: artifacts, frame plans, caches, tables and the `skybake` binary.

#[path = "../service_support/mod.rs"]
mod service_support;

mod bake_shards;
mod cli_atmosphere;
mod cli_cloud_light;
mod cli_clouds;
mod cli_lut_eval;
mod cli_render;
mod cloud_render_limits;
mod frame_artifact;
mod frame_sequence;
mod frame_vdb;
mod job_frames;
mod parser_props;
mod plan_frame;
mod plan_rgb_only;
mod product_artifact;
mod store_bucket;
mod store_cache;
mod store_exr;
mod store_tables;
