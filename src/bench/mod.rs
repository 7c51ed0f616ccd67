//! In-process measurements behind `terratile bench`: each compares terratile against a
//! reference measured in the same run, so the ratio means something on a noisy machine.

mod read;

pub use read::{copy_file_bytes, read, read_with_las_rs, ReadBench};

/// Median of a non-empty list of seconds.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
