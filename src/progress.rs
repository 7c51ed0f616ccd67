//! Progress reporting from library code: stages call a [`Progress`]; the binary draws it with
//! indicatif, tests and library users pass [`NoProgress`].

/// Receives progress from long-running steps. Implementations must be cheap and thread-safe:
/// parallel workers call `advance`.
pub trait Progress: Sync {
    /// A step starts; `total` units of work (0 when unknown).
    fn start(&self, label: &str, total: u64);
    /// `n` more units are done.
    fn advance(&self, n: u64);
    /// The step is over.
    fn finish(&self);
}

/// Ignores progress.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
}
