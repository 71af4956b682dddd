//! The HTTP service: routes, conventions, limits, cancellation, connections, fuzzing and the process.

#[path = "../service_support/mod.rs"]
mod service_support;

mod service_cancel;
mod service_connections;
mod service_conventions;
mod service_frame_cost;
mod service_fuzz;
mod service_http;
mod service_lut;
mod service_process;
mod service_render;
mod service_replicas;
mod service_replicas_jobs;
mod service_router;
mod service_slow_clients;
