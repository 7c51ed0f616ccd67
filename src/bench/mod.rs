//! In-process measurements behind `terratile bench`: each compares terratile against a
//! reference measured in the same run, so the ratio means something on a noisy machine.

pub(crate) mod plot;
mod read;
mod table1;
mod terrain;

pub use plot::plot_table1;
pub use read::{copy_file_bytes, read, read_with_las_rs, ReadBench};
pub use table1::{
    paper_counts, table1, table1_memory, MemoryProbe, Table1, Table1Row, PAPER, PAPER_DELAUNAY_S,
};
pub use terrain::{terrain, TerrainBench};

/// Median of a non-empty list of seconds.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
