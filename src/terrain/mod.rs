//! The terrain stages of seed 003 (Kim & Shin): noise removal, resampling to a regular grid,
//! hole filling, Röttger quadtree error metrics, CLOD mesh extraction and tiling, plus the
//! Delaunay baseline they are measured against. Each stage is a plain function with a
//! `…Params` struct; none reads files or prints.

pub mod extract;
pub mod heightfield;
pub mod quadtree;
pub mod tiles;

pub use heightfield::{CellState, Heightfield};
