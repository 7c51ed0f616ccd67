//! Runs a pipeline file: reads the inputs, runs the configured stages in order, writes the
//! outputs into a staged directory that replaces the previous output only when everything
//! succeeded, and returns a summary of what each stage did.
//!
//! - [`plan`](Plan): the pipeline file checked in one pass before any work;
//! - `run`: the stage order, the one place that spells it ([`run`], [`grid_stages`],
//!   [`tile_stages`]);
//! - `report`: [`RunSummary`] and each stage's figures;
//! - `memory`: the run's memory estimate and the probes of what it used.

pub mod jobs;
mod memory;
mod plan;
mod report;
mod run;
mod spill;
pub mod stream;

pub use crate::outnames::NOISE_FILE;
pub use memory::{current_rss, empty_input, estimate_pipeline, peak_rss, reset_peak_rss};
pub use plan::Plan;
pub use report::{stage_seconds, BaselineMeasurements, RunSummary, StageReport};
pub use run::read_columns;
pub use run::{
    grid_stages, grid_stages_with_bounds, run, run_with_context, tile_stages, GridStages,
    RunContext, RunOutput, TileStages,
};
pub use run::{product_stages, quadtree_report, tiles_report, tiles_report_with, with_input_crs};
