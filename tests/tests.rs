//! terratile's integration tests: one test binary (`cargo test --release --test tests`), one
//! module per area, the shared helpers once. Most tests run the real binary in a temporary
//! directory (`common::Run`); real data comes from `../shared/data` when it is there.

// Shared helpers and inputs.
mod common;
mod mesh_corpus;
mod point_corpus;
mod tiles_support;

// The areas.
mod architecture;
mod baseline;
mod cli_mesh;
mod cli_read;
mod cli_terrain;
mod cli_tiles;
mod copc;
mod geo;
mod ground;
mod ground_fill;
mod intersect;
mod mesh_io;
mod outputs;
mod quadtree;
mod read;
mod read_fuzz;
mod shard_jobs;
mod shard_real;
mod simplify;
mod stream;
mod strips;
mod terrain_props;
mod terrain_real;

// One named test per defect fixed.
mod regression;
