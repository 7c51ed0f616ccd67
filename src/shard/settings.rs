//! `[scale]`: how `terratile run` holds the points (in memory or streamed through the
//! shards) and how the streamed run reads them; the run itself is `pipeline::stream`.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// How `terratile run` holds the points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// In memory when the estimate fits the budget, else streamed.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always streamed.
    Stream,
}

/// How the streamed run's windows and shards get their points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ReadMode {
    /// Directly from the files when the inputs are uncompressed LAS tiles small enough that
    /// each point is decoded at most [`DIRECT_MAX_READS`] times, else through bricks.
    #[default]
    Auto,
    /// Always through temporary bricks.
    Bricks,
    /// Always directly from the input files, by their points' bounds.
    Direct,
}

/// Reads per point (estimated from the headers) up to which `read = "auto"` reads LAS tiles
/// directly: decoding a LAS record costs about what reading a brick record back costs, and
/// the bricks cost one write and at least two reads of every point.
pub const DIRECT_MAX_READS: f64 = 8.0;

/// `[scale]`
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScaleConfig {
    /// `auto` (default), `memory` or `stream`.
    #[serde(default)]
    pub mode: Mode,
    /// The memory budget of the choice and of the streaming run, e.g. `"4GiB"` (default:
    /// `--max-memory`, else half of the machine's memory). `--max-memory` wins.
    #[serde(default)]
    pub memory_budget: Option<String>,
    /// Directory for the temporary files (default: beside the output directory).
    #[serde(default)]
    pub temp_dir: Option<PathBuf>,
    /// `auto` (default), `bricks` or `direct`: how windows and shards read their points.
    #[serde(default)]
    pub read: ReadMode,
}

impl ScaleConfig {
    /// Checks `memory_budget`.
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = &self.memory_budget {
            crate::memory::parse_size(s)
                .map_err(|e| Error::param("scale", "memory_budget", s, e))?;
        }
        Ok(())
    }

    /// The budget in bytes: `--max-memory`, else `memory_budget`, else the default.
    pub fn budget(&self) -> u64 {
        match &self.memory_budget {
            Some(s) if !crate::memory::budget_is_set() => {
                crate::memory::parse_size(s).unwrap_or_else(|_| crate::memory::budget())
            }
            _ => crate::memory::budget(),
        }
    }
}
