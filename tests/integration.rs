//! The integration tests, one test binary: each former `tests/<name>.rs` is a module here (one compile and
//! link of the library's dependants instead of 54: the test build was the largest stage of the test command).
//! A file keeps its own tests, helpers and documentation; `tests/common` holds what several share.
//!
//! Run one file's tests by its module path: `cargo test --release --test integration render_gradient::`
//! (`-- --nocapture` prints their measured figures); all of them: `cargo test --release --test integration`.
//! Tests of different files run in parallel in one process, so a test's scratch files live under a
//! per-file, per-process name (or a `tempfile` directory).
#[macro_use]
mod common;

mod bad_input;
mod bad_input_recon3;
mod bad_input_render_options;
mod bad_input_round2;
mod bad_input_round3;
mod bad_input_round5;
mod bad_input_round6;
mod bad_input_round7;
mod bad_input_round8;
mod bad_input_round9;
mod bad_input_round10;
mod bad_input_round11;
mod bad_input_round12;
mod bad_input_round14;
mod bad_input_round15;
mod bad_input_round16;
mod bad_input_round17_formats;
mod bad_input_round18;
mod bad_input_round18_catalogs;
mod bad_input_round18_interrupt;
mod bad_input_round19_agf;
mod bad_input_round19_ghosts;
mod bad_input_round19_memory_recon;
mod bad_input_round19_memory_render;
mod bad_input_round19_memory_rest;
mod bad_input_round20_optics;
mod bad_input_round20_shards;
mod bad_input_round20_tolerance;
mod bad_input_round21_ghosts_geometry;
mod bad_input_round21_ghosts_report;
mod bad_input_round21_jacobian;
mod calibration_round16;
mod concurrency_round16;
mod operators_round17;
mod cli;
mod cli_run;
mod csv_outputs;
mod dataset;
mod derivatives;
mod design;
mod dual_disperser;
mod embree;
mod embree_speed;
mod evaluate;
mod extremes;
mod f32;
mod fuzz;
mod ghosts_cli;
mod ghosts_mechanics;
mod ghosts_mesh;
mod gpu_launcher;
mod gpu_render;
mod gpu_twin;
mod infinity;
mod materials;
mod mechanics;
mod metrics;
mod noise;
mod nonseq;
mod nonseq_lens_files;
mod nonseq_mirrors;
mod output_policy;
mod presets;
mod recon_exact_vs_shift;
mod recon_import_graph;
mod recon_mapping;
mod recon_operators;
mod recon_pnp;
mod recon_solvers;
mod recon_sparse;
mod recon_stopping;
mod recon_unrolled;
mod reconstruct_study;
mod records_exact;
mod render;
mod render_ghosts;
mod render_gradient;
mod robust_importers;
mod robustness;
mod simd;
mod surfaces;
mod tracer;
mod tradeoff;
mod yaml_import;
mod zemax_reference;
mod zmx;
mod zmx_read;
mod zmx_round5;
mod zmx_round17;
mod zmx_round18;
