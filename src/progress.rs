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

/// The label of a progress bar in at most `width` characters that keeps the file name: a
/// label `verb /long/path/file.las` becomes `verb …/file.las` (a fixed-width cut kept the
/// start of the path and lost the name); control characters are escaped.
pub fn bar_label(label: &str, width: usize) -> String {
    let label = crate::error::one_line(label);
    if label.chars().count() <= width {
        return label.into_owned();
    }
    let (verb, rest) = label.split_once(' ').unwrap_or(("", &label));
    let name = rest.rsplit(['/', '\\']).next().unwrap_or(rest);
    let short = if verb.is_empty() || name == rest {
        label.to_string()
    } else {
        format!("{verb} …/{name}")
    };
    let n = short.chars().count();
    if n <= width {
        short
    } else {
        // Still too long: keep the end, where a file name differs from its neighbours.
        let tail: String = short.chars().skip(n + 1 - width).collect();
        format!("…{tail}")
    }
}
