//! Filters that turn a simplified strip (full of degenerate triangles after collapses)
//! into a strip worth sending to the GPU.
//!
//! - DTFS, degenerate-triangle-free scanning (the progressive-strips paper's filter): scan
//!   the consecutive triples, keep only those with three distinct vertices, and rebuild
//!   strips from them: a triangle that continues the output through its last edge adds one
//!   vertex (the regular case {a, b, c, f}), one that continues through the other edge of
//!   the last vertex adds a swap and a vertex (the swap case {a, b, c, b, f}), any other
//!   starts a new strip (the split case). The cases are decided on oriented triangles, so
//!   each triangle is drawn with its orientation.
//! - STSS (after El-Sana, Azanli and Varshney's skip strips, the filter the paper compares
//!   against): keep the strip as it is but cut out each run of consecutive degenerate
//!   triangles where cutting saves indices (a restart, or two joining indices, instead of
//!   the run), keeping the orientation of what follows.

use super::stripify::{Join, RESTART};

/// Appends strips triangle by triangle: the regular, swap and split cases.
struct Builder {
    out: Vec<u32>,
    join: Join,
    /// The last two vertices of the current strip and the parity of its next triangle;
    /// None before the first strip.
    tail: Option<([u32; 2], u32)>,
}

/// Whether the oriented triangle `t` is drawn as (x, y, z) at `parity` for some z, and z.
#[inline]
fn follows(t: [u32; 3], x: u32, y: u32, parity: u32) -> Option<u32> {
    // Drawn as (x, y, z) at even parity, (y, x, z) at odd.
    let (p, q) = if parity == 0 { (x, y) } else { (y, x) };
    (0..3).find_map(|k| (t[k] == p && t[(k + 1) % 3] == q).then_some(t[(k + 2) % 3]))
}

impl Builder {
    fn new(join: Join, capacity: usize) -> Builder {
        Builder {
            out: Vec::with_capacity(capacity),
            join,
            tail: None,
        }
    }

    #[inline]
    fn push(&mut self, t: [u32; 3]) {
        if let Some(([x, y], parity)) = self.tail {
            if let Some(z) = follows(t, x, y, parity) {
                // Regular: one vertex.
                self.out.push(z);
                self.tail = Some(([y, z], parity ^ 1));
                return;
            }
            if let Some(z) = follows(t, y, x, parity ^ 1) {
                // Swap: x repeated, then the vertex.
                self.out.extend([x, z]);
                self.tail = Some(([x, z], parity));
                return;
            }
        }
        // Split: a new strip.
        let [a, b, c] = t;
        match (self.join, self.tail) {
            (_, None) => {
                self.out.extend([a, b, c]);
                self.tail = Some(([b, c], 1));
            }
            (Join::Restart, Some(_)) => {
                self.out.extend([RESTART, a, b, c]);
                self.tail = Some(([b, c], 1));
            }
            (Join::Degenerate, Some(([_, y], parity))) => {
                let (e0, e1) = if parity == 1 { (c, b) } else { (b, c) };
                self.out.extend([y, a, a, e0, e1]);
                self.tail = Some(([e0, e1], parity ^ 1));
            }
        }
    }
}

/// The strip's own join: restarts if it has any, else degenerate triangles.
pub fn join_of(strip: &[u32]) -> Join {
    if strip.contains(&RESTART) {
        Join::Restart
    } else {
        Join::Degenerate
    }
}

/// DTFS: the non-degenerate triangles of `strip`, in order, rebuilt into strips joined by
/// `join`. Writes into `out` (cleared), so that a renderer can reuse one buffer.
pub fn dtfs_into(strip: &[u32], join: Join, out: &mut Vec<u32>) {
    let mut b = Builder {
        out: std::mem::take(out),
        join,
        tail: None,
    };
    b.out.clear();
    super::stripify::each_triangle(strip, |t| b.push(t));
    *out = b.out;
}

/// DTFS with a look-ahead: the next triangle is the first of the next `window` surviving
/// ones that continues the output (regular, then swap), else the next one starts a new
/// strip. Window 1 is [`dtfs_into`].
pub fn dtfs_window_into(
    strip: &[u32],
    join: Join,
    window: usize,
    scratch: &mut Vec<[u32; 3]>,
    out: &mut Vec<u32>,
) {
    scratch.clear();
    super::stripify::each_triangle(strip, |t| scratch.push(t));
    let mut b = Builder {
        out: std::mem::take(out),
        join,
        tail: None,
    };
    b.out.clear();
    let window = window.max(1);
    let mut i = 0;
    while i < scratch.len() {
        let end = (i + window).min(scratch.len());
        let pick = b.tail.and_then(|([x, y], parity)| {
            let w = &scratch[i..end];
            w.iter()
                .position(|&t| follows(t, x, y, parity).is_some())
                .or_else(|| {
                    w.iter()
                        .position(|&t| follows(t, y, x, parity ^ 1).is_some())
                })
        });
        // Keep the order of the others: move the pick to the front of the window.
        if let Some(k) = pick {
            scratch[i..=i + k].rotate_right(1);
        }
        b.push(scratch[i]);
        i += 1;
    }
    *out = b.out;
}

/// [`dtfs_into`] into a new vector.
pub fn dtfs(strip: &[u32], join: Join) -> Vec<u32> {
    let mut out = Builder::new(join, strip.len()).out;
    dtfs_into(strip, join, &mut out);
    out
}

/// Whether triple i of a strip (relative position `i`) is degenerate.
#[inline]
fn degenerate(s: &[u32], i: usize) -> bool {
    s[i] == s[i + 1] || s[i + 1] == s[i + 2] || s[i] == s[i + 2]
}

/// STSS: `strip` with every run of consecutive degenerate triangles cut out where that
/// saves indices (strips that draw nothing are dropped whole).
pub fn stss(strip: &[u32], join: Join) -> Vec<u32> {
    let mut out = Vec::with_capacity(strip.len());
    let cost = match join {
        Join::Restart => 1,
        Join::Degenerate => 2,
    };
    // Appends a piece of a strip that starts a new strip (after a restart if need be).
    let start = |out: &mut Vec<u32>, part: &[u32]| {
        if join == Join::Restart && !out.is_empty() {
            out.push(RESTART);
        }
        out.extend_from_slice(part);
    };
    for piece in strip.split(|&v| v == RESTART) {
        let tri = piece.len().saturating_sub(2);
        // piece[from..] is still to be written; positions keep their parity (from is even,
        // or, after a degenerate join, of the parity that keeps the orientations).
        let mut from = 0;
        let mut i = 0;
        let mut any = false; // a non-degenerate triangle in piece[from..i + 2]
        let mut open = false; // piece[from..] continues what `out` ends with
        while i < tri {
            if !degenerate(piece, i) {
                any = true;
                i += 1;
                continue;
            }
            let run = i;
            while i < tri && degenerate(piece, i) {
                i += 1;
            }
            if i == tri {
                // Trailing run: end the strip before it.
                if any {
                    let part = &piece[from..run + 2];
                    if open {
                        out.extend_from_slice(part);
                    } else {
                        start(&mut out, part);
                    }
                }
                from = piece.len();
                open = false;
                break;
            }
            if !any {
                // Leading run: start at i or i − 1 (an even position).
                if !open {
                    from = i - (i & 1);
                }
                continue;
            }
            let j = match join {
                Join::Restart => i - (i & 1),
                Join::Degenerate => i - ((i - run) & 1),
            };
            if j as isize - (run + 2) as isize > cost {
                let part = &piece[from..run + 2];
                if open {
                    out.extend_from_slice(part);
                } else {
                    start(&mut out, part);
                }
                match join {
                    Join::Restart => open = false,
                    Join::Degenerate => {
                        out.extend([piece[run + 1], piece[j]]);
                        open = true;
                    }
                }
                from = j;
                any = false;
            }
        }
        if from < piece.len() && any {
            let part = &piece[from..];
            if open {
                out.extend_from_slice(part);
            } else {
                start(&mut out, part);
            }
        }
    }
    out
}
