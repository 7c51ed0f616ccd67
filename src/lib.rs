//! terratile: an offline terrain pipeline for airborne LIDAR.
//!
//! Point clouds (LAS/LAZ/XYZ) are read through memory maps into a struct-of-arrays
//! [`PointCloud`]; the terrain stages (noise removal, resampling, hole filling, Röttger
//! quadtree error metrics, CLOD mesh extraction) turn them into tiled heightfields and meshes
//! that game engines load.
//!
//! The library's surface: the data types and their formats ([`points`], [`mesh`]), the
//! stages ([`terrain`], [`simplify`]), the encoders ([`output`]), the pipeline file
//! ([`config`]) and its run ([`pipeline`]), the asset stage ([`assets`]) and the survey
//! generator ([`generate`]). The helpers beneath them (safe file output, the seeded random
//! generator, the memory budget, the output-name check, progress reporting) are private
//! modules; what the binary needs of them is re-exported here by name. The slow twins the
//! fast paths are tested against (`terrain::reference`) and test support exist only with
//! the `testing` feature, which the tests and benchmarks turn on.
#![deny(missing_docs)]
#![deny(unsafe_code)]

pub mod assets;
pub mod classify;
pub mod config;
pub mod generate;
pub mod geo;
pub mod mesh;
pub mod output;
pub mod pipeline;
pub mod points;
pub mod shard;
pub mod simplify;
pub mod terrain;

mod chart;
mod error;
mod fsutil;
mod memory;
mod outnames;
mod progress;
mod rng;

/// The in-process measurements behind `terratile bench`: the binary's, not library API.
#[doc(hidden)]
pub mod bench;

pub use error::{one_line, Error, Result};
pub use fsutil::{check_file_output, clean_up_on_signals, remove_stale_temps};
pub use memory::{max_threads, parse_size, set_budget};
pub use points::{PointCloud, ReadOptions};
pub use progress::{bar_label, NoProgress, Progress};
/// Seeded randomness, bit-identical across releases (for tests and benchmarks).
#[cfg(feature = "testing")]
pub use rng::SplitMix64;

/// Support shared by the unit tests of every module.
#[cfg(test)]
mod testing;
