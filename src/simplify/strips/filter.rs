//! Filters that turn a simplified strip (full of degenerate triangles after collapses)
//! into a strip worth sending to the GPU.
//!
//! - DTFS, degenerate-triangle-free scanning (the progressive-strips paper's filter): scan
//!   the consecutive triples, keep only those with three distinct vertices, and rebuild
//!   strips from them. A triangle across the output's last edge [b c] continues it: the
//!   regular case {a, b, c, f} leaves the edge [c f], the swap case {a, b, c, b, f} the
//!   edge [b f], chosen by the triangle after it (the paper tells the two apart by the
//!   triples' parity in the input; on oriented triangles the same triangle is drawn either
//!   way and only the outgoing edge differs). Any other triangle starts a new strip (the
//!   split case), in the rotation and parity that let the most of the next few triangles
//!   continue it, joined by a single repeated vertex where the output ends with one of its
//!   corners (our addition: the paper always ends the strip). Each triangle is drawn with
//!   its orientation.
//! - STSS (after El-Sana, Azanli and Varshney's skip strips, the filter the paper compares
//!   against): keep the strip as it is but cut out each run of consecutive degenerate
//!   triangles where cutting saves indices (a restart, or two joining indices, instead of
//!   the run), keeping the orientation of what follows.

use super::stripify::{Join, RESTART};

/// How many of the following triangles a split looks at to choose how the new strip starts.
const START_LOOKAHEAD: usize = 8;

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

/// A strip's end: its last two vertices and the parity of its next triangle.
type Tail = ([u32; 2], u32);

/// Whether `t` can be the strip's next triangle: it lies across the last edge, oriented.
#[inline]
fn takes(t: [u32; 3], ([x, y], parity): Tail) -> Option<u32> {
    follows(t, x, y, parity)
}

/// The indices that continue a strip ending in `tail` with `t`, and the new end; None for
/// a split. `t` lies across the last edge [x y] and adds z. The regular case writes z and
/// leaves the edge [y z]; the swap case writes x z (x repeated) and leaves [x z]: the same
/// triangle, the other outgoing edge. The swap is taken when `next` lies across [x z] and
/// not across [y z].
#[inline]
fn continue_with(t: [u32; 3], tail: Tail, next: Option<[u32; 3]>) -> Option<(Tail, usize)> {
    let ([x, y], parity) = tail;
    let z = takes(t, tail)?;
    let regular = ([y, z], parity ^ 1);
    let swap = ([x, z], parity);
    let swapped = next.is_some_and(|n| takes(n, regular).is_none() && takes(n, swap).is_some());
    Some(if swapped { (swap, 2) } else { (regular, 1) })
}

impl Builder {
    fn new(join: Join, capacity: usize) -> Builder {
        Builder {
            out: Vec::with_capacity(capacity),
            join,
            tail: None,
        }
    }

    /// Appends `t`; `ahead` are the triangles that follow it (they choose between the
    /// regular and the swap case, and how a new strip starts).
    #[inline]
    fn push(&mut self, t: [u32; 3], ahead: &[[u32; 3]]) {
        if let Some(tail) = self.tail {
            if let Some((next, n)) = continue_with(t, tail, ahead.first().copied()) {
                if n == 2 {
                    // Swap: the strip's second-last vertex repeated.
                    self.out.push(tail.0[0]);
                }
                self.out.push(next.0[1]);
                self.tail = Some(next);
                return;
            }
        }
        self.split(t, ahead);
    }

    /// The split case: a new strip drawing `t`. Any rotation of `t` may start it, at either
    /// parity (the odd one costs a repeated first vertex); the paper rebuilds the new strip
    /// from the triple as it stands in the input, which keeps the input's own continuation.
    /// Trying the six starts against the next few triangles finds that one and the others.
    fn split(&mut self, t: [u32; 3], ahead: &[[u32; 3]]) {
        let ahead = &ahead[..ahead.len().min(START_LOOKAHEAD)];
        let mut best: Option<(usize, usize, [u32; 3], u32)> = None;
        for k in 0..3 {
            let r = [t[k], t[(k + 1) % 3], t[(k + 2) % 3]];
            for q in 0..2 {
                let seq = if q == 0 {
                    [r[0], r[1], r[2]]
                } else {
                    [r[1], r[0], r[2]]
                };
                let mut cost = self.pads(seq[0], q).1;
                let mut tail = ([seq[1], seq[2]], q ^ 1);
                let mut covered = 0;
                for (i, &a) in ahead.iter().enumerate() {
                    match continue_with(a, tail, ahead.get(i + 1).copied()) {
                        Some((next, n)) => {
                            tail = next;
                            cost += n;
                            covered += 1;
                        }
                        None => break,
                    }
                }
                // Most triangles continued, then fewest indices.
                let better = best
                    .is_none_or(|(c, k, _, _)| (covered, usize::MAX - cost) > (c, usize::MAX - k));
                if better {
                    best = Some((covered, cost, seq, q));
                }
            }
        }
        let (_, _, seq, q) = best.expect("six starts tried");
        let (pads, n) = self.pads(seq[0], q);
        self.out.extend_from_slice(&pads[..n]);
        self.out.extend(seq);
        self.tail = Some(([seq[1], seq[2]], q ^ 1));
    }

    /// The indices written before a new strip whose first triangle `first, …` is drawn at
    /// parity `q`, and how many: a restart or two repeated indices to join it (none when the
    /// strip already ends with `first`), and a repeated first vertex where the parity needs
    /// one.
    fn pads(&self, first: u32, q: u32) -> ([u32; 4], usize) {
        let mut pads = [0; 4];
        let mut n = 0;
        // The parity the new strip's first triangle lands at without a repeated first vertex.
        let lands = match (self.join, self.tail) {
            (_, None) => 0,
            // The strip ends with the new one's first vertex: written once more, it makes
            // the joining triangles degenerate by itself (no restart, no second index).
            (_, Some(([_, y], parity))) if y == first => parity,
            (Join::Restart, Some(_)) => {
                pads[0] = RESTART;
                n = 1;
                0
            }
            (Join::Degenerate, Some(([_, y], parity))) => {
                pads[..2].copy_from_slice(&[y, first]);
                n = 2;
                parity
            }
        };
        if lands != q {
            pads[n] = first;
            n += 1;
        }
        (pads, n)
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
    dtfs_window_into(strip, join, 1, &mut Vec::new(), out);
}

/// DTFS with a look-ahead: the next triangle is the first of the next `window` surviving
/// ones that continues the output, else the next one starts a new strip. Window 1 is
/// [`dtfs_into`].
pub fn dtfs_window_into(
    strip: &[u32],
    join: Join,
    window: usize,
    scratch: &mut Vec<[u32; 3]>,
    out: &mut Vec<u32>,
) {
    scratch.clear();
    super::stripify::each_triangle(strip, |t| scratch.push(t));
    rebuild_into(scratch, join, window, out);
}

/// Strips of the oriented triangles `tris` in their order, by DTFS's rules (regular, swap
/// and split cases; with `window` > 1 the look-ahead reorders them). Every triangle is
/// drawn once, with its orientation.
pub fn rebuild_into(tris: &mut [[u32; 3]], join: Join, window: usize, out: &mut Vec<u32>) {
    let mut b = Builder {
        out: std::mem::take(out),
        join,
        tail: None,
    };
    b.out.clear();
    let window = window.max(1);
    let mut i = 0;
    while i < tris.len() {
        let end = (i + window).min(tris.len());
        let pick = b
            .tail
            .and_then(|tail| tris[i..end].iter().position(|&t| takes(t, tail).is_some()));
        // Keep the order of the others: move the pick to the front of the window.
        if let Some(k) = pick {
            tris[i..=i + k].rotate_right(1);
        }
        b.push(tris[i], &tris[i + 1..]);
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
