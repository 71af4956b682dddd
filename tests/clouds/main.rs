//! Cloud density sources and the frame renderer, against Mitsuba 3, DISORT slabs and the path tracer.

mod cloud_automaton;
mod cloud_fractal_growth;
mod cloud_import_grids;
mod cloud_import_vdb;
mod cloud_light;
mod cloud_marching_cubes_surface;
mod cloud_metaballs_field;
mod cloud_satellite_fit;
mod cloud_scene_examples;
mod cloud_spheres;
mod render_frame;
mod render_pattern;
mod render_prop;
mod render_stability;
mod render_validation;
