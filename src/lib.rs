//! terratile: an offline terrain pipeline for airborne LIDAR.
//!
//! Point clouds (LAS/LAZ/XYZ) are read through memory maps into a struct-of-arrays
//! [`points::PointCloud`]; the terrain stages (noise removal, resampling, hole filling,
//! Röttger quadtree error metrics) turn them into tiled heightfields that game engines load.
//! See `README.md` for the pipeline file, the algorithms and the papers they come from.
#![deny(missing_docs)]
#![deny(unsafe_code)]

pub mod assets;
pub mod bench;
pub mod classify;
pub mod config;
pub mod error;
pub mod fsutil;
pub mod generate;
pub mod memory;
pub mod mesh;
pub mod outnames;
pub mod output;
pub mod pipeline;
pub mod points;
pub mod progress;
pub mod rng;
pub mod simplify;
pub mod terrain;

pub use error::{Error, Result};
pub use points::{PointCloud, ReadOptions};
pub use progress::{NoProgress, Progress};
