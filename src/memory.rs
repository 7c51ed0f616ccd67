//! The memory budget: how much a run may allocate (`--max-memory`, by default a share of the
//! machine's memory), and [`estimate_run`], the one place that says how much a pipeline run
//! will need, stage by stage, before anything large is allocated.
//!
//! Physical memory comes from `/proc/meminfo` (Linux) and the address-space limit from
//! `/proc/self/limits`: reading two small text files needs no dependency (a crate such as
//! `sysinfo` would pull in far more than these two numbers).

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// The default budget is this share of physical memory (and of the address-space limit,
/// when one is set).
pub const DEFAULT_SHARE: f64 = 0.5;

/// Budget used when the machine's memory cannot be read (not Linux): 8 GiB.
pub const FALLBACK_BUDGET: u64 = 8 << 30;

/// Bytes a point costs in the cloud: x, y, z (f64), class, return, returns (u8), intensity.
pub const POINT_BYTES: u64 = 29;

/// Bytes noise removal needs per point: its sorted key (8), the count flags (1), the
/// coarse flags (1), the keep flags while they are built and the result (2).
pub const DENOISE_BYTES_PER_POINT: u64 = 12;

/// Bytes noise removal needs per voxel column and per worker histogram (u32 counts), plus
/// the column starts.
pub const DENOISE_BYTES_PER_COLUMN: u64 = 4;

/// Bytes per low-layer column (span 8, open flag 1, profile 24, floor 4, rounded up).
pub const DENOISE_BYTES_PER_GROUP: u64 = 40;

/// Bytes per grid cell from resampling to the written tiles, measured: the per-cell sums
/// (8), heights (4), counts (4) and states (1) of the grid, hole filling's working arrays,
/// the tile set with its padding and quadtree metrics, and the tile meshes and images
/// being written. Calibrated against peak RSS: 38 bytes per cell measured on autzen_full.laz
/// at `cell_size = 0.5` (64 M cells), 20 on a sparse synthetic grid; 48 leaves a margin.
pub const GRID_BYTES_PER_CELL: u64 = 48;

/// Bytes per point of the resampling's cell index (u32 per point, with several workers).
pub const RESAMPLE_BYTES_PER_POINT: u64 = 4;

static BUDGET: AtomicU64 = AtomicU64::new(0);

/// Sets the budget in bytes (`--max-memory`).
pub fn set_budget(bytes: u64) {
    BUDGET.store(bytes.max(1), Relaxed);
}

/// True when `--max-memory` (or a library call to [`set_budget`]) set the budget.
pub fn budget_is_set() -> bool {
    BUDGET.load(Relaxed) != 0
}

/// The budget in bytes: what `--max-memory` set, else [`default_budget`].
pub fn budget() -> u64 {
    match BUDGET.load(Relaxed) {
        0 => default_budget(),
        b => b,
    }
}

/// [`DEFAULT_SHARE`] of the smaller of physical memory and the address-space limit
/// (`ulimit -v`), or [`FALLBACK_BUDGET`] when neither can be read.
pub fn default_budget() -> u64 {
    let phys = physical_memory();
    let limit = address_space_limit();
    match (phys, limit) {
        (None, None) => FALLBACK_BUDGET,
        (a, b) => {
            let m = a.unwrap_or(u64::MAX).min(b.unwrap_or(u64::MAX));
            (m as f64 * DEFAULT_SHARE) as u64
        }
    }
}

/// The figure `key` (e.g. `MemTotal:`) of a `/proc` file that gives sizes in kB, in bytes.
pub fn proc_kb(file: &str, key: &str) -> Option<u64> {
    let s = std::fs::read_to_string(file).ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Physical memory in bytes (`MemTotal` of `/proc/meminfo`).
pub fn physical_memory() -> Option<u64> {
    proc_kb("/proc/meminfo", "MemTotal:")
}

/// The soft address-space limit in bytes (`Max address space` of `/proc/self/limits`).
pub fn address_space_limit() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = s.lines().find(|l| l.starts_with("Max address space"))?;
    line["Max address space".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The number of worker threads a run may ask for: eight per core, at least 64.
pub fn max_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (cores * 8).max(64)
}

/// Parses a size such as `8GiB`, `512MiB`, `2G` (binary units; `GB`, `MB` are decimal) or a
/// plain number of bytes.
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num
        .parse()
        .map_err(|_| format!("`{s}` is not a size (e.g. 8GiB, 512MiB)"))?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kib" => 1024.0,
        "m" | "mib" => 1024.0 * 1024.0,
        "g" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tib" => 1024.0 * 1024.0 * 1024.0 * 1024.0,
        "kb" => 1e3,
        "mb" => 1e6,
        "gb" => 1e9,
        "tb" => 1e12,
        _ => {
            return Err(format!(
                "`{s}`: unknown unit `{unit}` (use KiB, MiB, GiB, TiB)"
            ))
        }
    };
    let bytes = v * mult;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("`{s}` is not a usable memory size"));
    }
    Ok(bytes as u64)
}

/// A byte count for messages: `1.23 GiB`.
pub fn human(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= (1u64 << 30) as f64 {
        format!("{:.2} GiB", b / (1u64 << 30) as f64)
    } else if b >= (1u64 << 20) as f64 {
        format!("{:.1} MiB", b / (1u64 << 20) as f64)
    } else {
        format!("{bytes} bytes")
    }
}

/// One part of a run's memory: what it is for and which configuration key sizes it.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// What holds the memory (`points`, `denoise voxels`, `grid`).
    pub what: &'static str,
    /// The pipeline key to change to make it smaller.
    pub key: &'static str,
    /// Bytes.
    pub bytes: u64,
}

/// What a run will need, by part.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Estimate {
    /// The parts.
    pub parts: Vec<Part>,
}

impl Estimate {
    /// All parts together (their peaks are taken to coincide, so this errs high).
    pub fn total(&self) -> u64 {
        self.parts
            .iter()
            .fold(0u64, |a, p| a.saturating_add(p.bytes))
    }

    /// The largest part.
    pub fn largest(&self) -> Option<&Part> {
        self.parts.iter().max_by_key(|p| p.bytes)
    }

    /// Ok when the total is within `budget`; else a message with the estimate, the budget
    /// and the key to change.
    pub fn check(&self, budget: u64) -> Result<()> {
        let total = self.total();
        if total <= budget {
            return Ok(());
        }
        let p = self.largest().cloned().unwrap_or(Part {
            what: "run",
            key: "input.max_points",
            bytes: total,
        });
        Err(Error::key(
            p.key,
            format!(
                "the run needs about {} ({} of it for the {}), more than the memory budget of {}: \
                 change {} or raise --max-memory",
                human(total),
                human(p.bytes),
                p.what,
                human(budget),
                p.key
            ),
        ))
    }
}

/// What the run needs in memory before its grid stages allocate anything:
/// `points` points (`attributes`: with the LAS attribute columns) from `input_bytes` of
/// mapped files, noise removal over `voxel_columns` voxel columns (`None` when off) in
/// `groups` low-layer columns, a grid of `cells` cells and `threads` workers.
///
/// This is the one estimate of a run's memory; a later streaming mode decides from it.
pub fn estimate_run(
    points: u64,
    attributes: bool,
    input_bytes: u64,
    denoise: Option<(u64, u64)>,
    cells: u64,
    grid_key: &'static str,
    threads: u64,
) -> Estimate {
    let per_point = if attributes { POINT_BYTES } else { 24 };
    let mut parts = vec![Part {
        what: "points",
        key: "input.max_points",
        bytes: points.saturating_mul(per_point).saturating_add(input_bytes),
    }];
    if let Some((columns, groups)) = denoise {
        let hist = threads.clamp(1, 64) + 1;
        parts.push(Part {
            what: "noise removal's voxels",
            key: "denoise.voxel_size",
            bytes: points
                .saturating_mul(DENOISE_BYTES_PER_POINT)
                .saturating_add(
                    columns
                        .saturating_mul(DENOISE_BYTES_PER_COLUMN)
                        .saturating_mul(hist),
                )
                .saturating_add(groups.saturating_mul(DENOISE_BYTES_PER_GROUP)),
        });
    }
    parts.push(Part {
        what: "grid and tiles",
        key: grid_key,
        bytes: cells
            .saturating_mul(GRID_BYTES_PER_CELL)
            .saturating_add(points.saturating_mul(RESAMPLE_BYTES_PER_POINT)),
    });
    Estimate { parts }
}

/// Refuses to allocate `bytes` for `what` when that exceeds the budget: a usage error
/// naming `what` (which should name the file or option).
pub fn check_alloc(bytes: u64, what: impl FnOnce() -> String) -> Result<()> {
    let b = budget();
    if bytes > b {
        return Err(Error::Usage(format!(
            "{}: needs about {}, more than the memory budget of {} (raise --max-memory)",
            what(),
            human(bytes),
            human(b)
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("8GiB").unwrap(), 8 << 30);
        assert_eq!(parse_size("512 MiB").unwrap(), 512 << 20);
        assert_eq!(parse_size("2G").unwrap(), 2 << 30);
        assert_eq!(parse_size("1GB").unwrap(), 1_000_000_000);
        assert_eq!(parse_size("4096").unwrap(), 4096);
        assert!(parse_size("lots").is_err());
        assert!(parse_size("8XB").is_err());
        assert!(parse_size("0").is_err());
    }

    #[test]
    fn estimate_names_the_largest_part() {
        let e = estimate_run(2500, false, 0, None, 46000 * 46000, "resample.size", 2);
        let Error::Key { key, message: msg } = e.check(8 << 30).unwrap_err() else {
            panic!("not a key error");
        };
        assert_eq!(key, "resample.size");
        assert!(msg.contains("grid and tiles"), "{msg}");
        let small = estimate_run(2500, false, 0, Some((300, 300)), 2500, "resample.size", 2);
        assert!(small.check(8 << 30).is_ok());
    }
}
