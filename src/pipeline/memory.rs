//! The run's memory: what it will need, estimated from the points read before the grid
//! stages allocate (refused beyond the budget, at the key that sizes the largest part), and
//! the probes of what it used (peak and current resident memory, from /proc) that the
//! baseline's report and the benchmarks read.

use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::memory::{estimate_run, proc_kb, Estimate};
use crate::points::PointCloud;

/// Peak resident set size of this process in bytes (`VmHWM`), if /proc says.
pub fn peak_rss() -> Option<u64> {
    proc_kb("/proc/self/status", "VmHWM:")
}

/// Current resident set size in bytes (`VmRSS`).
pub fn current_rss() -> Option<u64> {
    proc_kb("/proc/self/status", "VmRSS:")
}

/// Resets the peak resident set size to the current one (Linux `clear_refs` 5); false if
/// the kernel does not allow it, in which case peaks are over the whole process so far.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// [`estimate_run`] for `pipeline` on the points it read (`cloud`): the voxel lattice noise
/// removal will build and the grid resampling will make (over all the points' bounds, which
/// holds the denoised points' bounds). A stage parameter that cannot work on these points is
/// reported at its key. `bounds` are the tight bounds of all of `cloud`'s points (as the
/// reader measured them).
pub fn estimate_pipeline(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    bounds: &crate::points::Bounds,
) -> Result<Estimate> {
    let cfg = &pipeline.config;
    let n = cloud.len();
    let denoise = if cfg.denoise.enabled {
        let mpu = cloud.crs().map_or(1.0, |c| c.metres_per_unit());
        Some(
            crate::terrain::denoise::lattice_size(cloud, &cfg.denoise, mpu, Some(bounds))
                .map_err(|e| pipeline.param_error(e))?,
        )
    } else {
        None
    };
    let spec = crate::terrain::resample::GridSpec::new(&cfg.resample, bounds, n)
        .map_err(|e| pipeline.param_error(e))?;
    let grid_key = if cfg.resample.size.is_some() {
        "resample.size"
    } else {
        "resample.cell_size"
    };
    Ok(estimate_run(
        n as u64,
        !cloud.classification.is_empty(),
        0,
        denoise,
        (spec.cols as u64).saturating_mul(spec.rows as u64),
        grid_key,
        rayon::current_num_threads() as u64,
    ))
}

/// The error for a run whose inputs gave no points: which file is empty, or which filter
/// removed everything, at its key.
pub fn empty_input(pipeline: &LoadedPipeline, cloud: &PointCloud) -> Error {
    let input = &pipeline.config.input;
    let in_files: u64 = cloud.sources.iter().map(|s| s.points_in_file).sum();
    let names = || {
        cloud
            .sources
            .iter()
            .map(|s| s.path.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    if in_files == 0 {
        return pipeline.key_error(
            "input.paths",
            format!("the input holds no points ({}: 0 points)", names()),
        );
    }
    let key = if input.keep_classes.is_some() {
        "input.keep_classes"
    } else {
        "input.drop_classes"
    };
    pipeline.key_error(
        key,
        format!(
            "the class filter keeps none of the {in_files} points in {}",
            names()
        ),
    )
}
