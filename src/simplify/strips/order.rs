//! The strip of the full mesh built from the base mesh's strip down (our departure from the
//! progressive-strips paper, which stripifies the full mesh with STRIPE).
//!
//! DTFS draws, at every level, the triangles that survive there in the order of the full
//! strip, and joins two consecutive ones only when they share an edge. A strip of the full
//! mesh leaves the 5 % of triangles that survive to the base mesh scattered along it: on
//! bunny more than half of them start a strip, 2.9 indices per triangle. Here the order is
//! built coarse to fine instead, after the hierarchical strips of Velho, de Figueiredo and
//! Gomes (*Hierarchical generalized triangle strips*, The Visual Computer, 1999): the base
//! mesh is stripified, and each vertex split, replayed from the base up, inserts the
//! triangles it brings back next to a neighbour in the order, where they join the most
//! neighbours (typically between the two triangles the split separated, which it joins
//! again). Every level then draws its triangles in an order of about as few strips as the
//! base mesh's. The full strip is that order written as strips by DTFS's own rules; the
//! splits, their records and the filter are the paper's, unchanged.

use super::filter::rebuild_into;
use super::lists::MergeLists;
use super::stripify::{self, canonical, Join, StripParams};

const NONE: u32 = u32::MAX;

/// Whether two triangles with distinct corners share an edge (two corners).
#[inline]
fn adjacent(a: [u32; 3], b: [u32; 3]) -> bool {
    a.iter().filter(|v| b.contains(v)).count() == 2
}

#[inline]
fn distinct(t: [u32; 3]) -> bool {
    t[0] != t[1] && t[1] != t[2] && t[0] != t[2]
}

/// A triangle while the order is built: its corners at the current level, its neighbours
/// in the order (a doubly linked list), and the last split that touched it. One record of
/// 32 bytes, so that what a split reads of a triangle (corners, then links) comes in one
/// cache line: these reads, scattered over the mesh, are most of the order's time.
#[derive(Clone, Copy)]
#[repr(C, align(32))]
struct Tri {
    c: [u32; 3],
    prev: u32,
    next: u32,
    stamp: u32,
}

/// The triangles and the order.
struct Level {
    tri: Vec<Tri>,
    head: u32,
    tail: u32,
}

impl Level {
    /// Corners of `t`.
    #[inline]
    fn corners(&self, t: u32) -> [u32; 3] {
        self.tri[t as usize].c
    }

    /// Puts `t` right after `a` (at the front when `a` is NONE).
    fn insert_after(&mut self, a: u32, t: u32) {
        let b = if a == NONE {
            self.head
        } else {
            self.tri[a as usize].next
        };
        self.tri[t as usize].prev = a;
        self.tri[t as usize].next = b;
        if a == NONE {
            self.head = t;
        } else {
            self.tri[a as usize].next = t;
        }
        if b == NONE {
            self.tail = t;
        } else {
            self.tri[b as usize].prev = t;
        }
    }
}

/// How many splits ahead the coarse-to-fine pass reads the triangles a split touches.
const AHEAD: usize = 4;

/// The placed triangles around each vertex (those with distinct corners at the current
/// level), each a list that behaves as a `Vec` (push, and removal by moving the last
/// entry into the hole) but all in one buffer: a list starts with room for the vertex's
/// valence in the full mesh and moves to the end of the buffer, with twice the room, in
/// the rare case that it outgrows it (a vertex that stands for collapsed ones at a coarse
/// level). No allocation per vertex.
struct Fans {
    /// Per vertex: (start, length, room), together (one read).
    head: Vec<[u32; 3]>,
    data: Vec<u32>,
}

impl Fans {
    fn new(tris: &[[u32; 3]], vertices: usize) -> Fans {
        let mut head = vec![[0u32; 3]; vertices];
        for &v in tris.iter().flatten() {
            head[v as usize][2] += 1;
        }
        let mut sum = 0u32;
        for h in &mut head {
            h[0] = sum;
            sum += h[2];
        }
        Fans {
            head,
            data: vec![NONE; sum as usize],
        }
    }

    #[inline]
    fn get(&self, v: u32) -> &[u32] {
        let [s, n, _] = self.head[v as usize];
        &self.data[s as usize..(s + n) as usize]
    }

    #[inline]
    fn push(&mut self, v: u32, t: u32) {
        let [s, n, room] = self.head[v as usize];
        let (mut s, n) = (s as usize, n as usize);
        if n as u32 == room {
            let at = self.data.len();
            let room = (2 * n).max(4);
            self.data.extend_from_within(s..s + n);
            self.data.resize(at + room, NONE);
            s = at;
            self.head[v as usize] = [at as u32, n as u32, room as u32];
        }
        self.data[s + n] = t;
        self.head[v as usize][1] += 1;
    }

    /// Removes `t` from `v`'s list (the last entry takes its place), if it is there.
    #[inline]
    fn remove(&mut self, v: u32, t: u32) {
        let [s, n, _] = self.head[v as usize];
        let (s, n) = (s as usize, n as usize);
        let f = &mut self.data[s..s + n];
        if let Some(k) = f.iter().position(|&u| u == t) {
            f[k] = f[n - 1];
            self.head[v as usize][1] -= 1;
        }
    }
}

/// The full strip of `tris` (distinct corners, ids below `vertices`) in the coarse-to-fine
/// order, for the collapses `pairs` ((removed, kept), in the order they were made).
pub fn hierarchical(
    tris: &[[u32; 3]],
    vertices: usize,
    pairs: &[(u32, u32)],
    join: Join,
) -> Vec<u32> {
    let n = tris.len();
    // The corner slots each collapse rewrote (what its split restores: the slots that
    // showed the removed vertex then) beside the base mesh's order and the fans, which do
    // not need them.
    let (restore, (mut lv, mut fans)) = rayon::join(
        || {
            let flat: Vec<u32> = tris.iter().flatten().copied().collect();
            MergeLists::new(&flat, NONE, vertices, pairs)
        },
        || base_order(tris, vertices, pairs),
    );

    // The splits, coarse to fine.
    let mut touched: Vec<(u32, bool)> = Vec::new();
    let mut fresh: Vec<u32> = Vec::new();
    // The splits are known in advance but scattered over the mesh: what a split reads is
    // read early (folded into `early`, which keeps the reads), in two stages, so that the
    // cache misses of the few splits ahead overlap one another and the work in between
    // instead of each stalling the split that needs it: `2 * AHEAD` splits ahead, the head
    // of its restored slots and of the fans of both its vertices; `AHEAD` splits ahead,
    // the triangles those list and the start of the restored vertex's fan (which the
    // split fills).
    let mut early = 0u32;
    for (i, &(p, q)) in pairs.iter().enumerate().rev() {
        if let Some(&(r, k)) = i.checked_sub(2 * AHEAD).and_then(|j| pairs.get(j)) {
            early ^= restore.get(r).first().copied().unwrap_or(0)
                ^ fans.head[k as usize][0]
                ^ fans.head[r as usize][0];
        }
        if let Some(&(r, k)) = i.checked_sub(AHEAD).and_then(|j| pairs.get(j)) {
            for &s in restore.get(r) {
                early ^= lv.tri[(s / 3) as usize].stamp;
            }
            for &u in fans.get(k) {
                early ^= lv.tri[u as usize].stamp;
            }
            early ^= fans
                .data
                .get(fans.head[r as usize][0] as usize)
                .copied()
                .unwrap_or(0);
        }
        touched.clear();
        // Each triangle the split touches, whether it had distinct corners before (read at
        // its first slot, before any is rewritten), and p back in its slots.
        for &s in restore.get(p) {
            let t = s / 3;
            let tri = &mut lv.tri[t as usize];
            if tri.stamp != i as u32 {
                tri.stamp = i as u32;
                touched.push((t, distinct(tri.c)));
            }
            tri.c[(s % 3) as usize] = p;
        }
        fresh.clear();
        for &(t, was) in &touched {
            let c = lv.corners(t);
            if !distinct(c) {
                continue;
            }
            if was {
                fans.remove(q, t);
                fans.push(p, t);
            } else {
                for v in c {
                    fans.push(v, t);
                }
                fresh.push(t);
            }
        }
        for &t in &fresh {
            place(&mut lv, &fans, t);
        }
    }

    std::hint::black_box(early);
    let mut seq: Vec<[u32; 3]> = Vec::with_capacity(n);
    // Every split has been replayed: each triangle shows its own corners again, in the
    // record the walk reads anyway.
    let mut t = lv.head;
    while t != NONE {
        let tri = &lv.tri[t as usize];
        debug_assert_eq!(tri.c, tris[t as usize]);
        seq.push(tri.c);
        t = tri.next;
    }
    let mut out = Vec::with_capacity(2 * n);
    rebuild_into(&mut seq, join, 1, &mut out);
    out
}

/// The triangles collapsed to the base mesh (each corner shows the vertex its own was
/// collapsed into, transitively), those of the base mesh linked in the order of its own
/// strip, and their fans.
fn base_order(tris: &[[u32; 3]], vertices: usize, pairs: &[(u32, u32)]) -> (Level, Fans) {
    let n = tris.len();
    let mut root: Vec<u32> = (0..vertices as u32).collect();
    for &(p, q) in pairs.iter().rev() {
        root[p as usize] = root[q as usize];
    }
    let mut lv = Level {
        tri: tris
            .iter()
            .map(|t| Tri {
                c: t.map(|v| root[v as usize]),
                prev: NONE,
                next: NONE,
                stamp: NONE,
            })
            .collect(),
        head: NONE,
        tail: NONE,
    };
    drop(root);
    let base: Vec<u32> = (0..n as u32).filter(|&t| distinct(lv.corners(t))).collect();
    let base_tris: Vec<[u32; 3]> = base.iter().map(|&t| lv.corners(t)).collect();
    let strip = stripify::stripify(
        &base_tris,
        &StripParams {
            join: Join::Restart,
            window: 0,
        },
    );
    let mut by_key: Vec<([u32; 3], u32)> = base_tris
        .iter()
        .zip(&base)
        .map(|(&c, &t)| (canonical(c), t))
        .collect();
    by_key.sort_unstable();
    let mut taken = vec![false; by_key.len()];
    let mut fans = Fans::new(tris, vertices);
    stripify::each_triangle(&strip, |c| {
        let key = canonical(c);
        let mut i = by_key.partition_point(|e| e.0 < key);
        while taken[i] {
            i += 1;
        }
        debug_assert_eq!(by_key[i].0, key);
        taken[i] = true;
        let t = by_key[i].1;
        lv.insert_after(lv.tail, t);
        for v in c {
            fans.push(v, t);
        }
    });
    (lv, fans)
}

/// Inserts the new triangle `t` next to one of its neighbours (in the fans of its corners)
/// where it joins the most: +1 per neighbour in the order it comes next to, −1 when it
/// separates two that were joined. With no neighbour placed yet, at the end.
fn place(lv: &mut Level, fans: &Fans, t: u32) {
    let c = lv.corners(t);
    let joins = |a: u32, b: u32| a != NONE && b != NONE && adjacent(lv.corners(a), lv.corners(b));
    let mut best: Option<(i32, u32)> = None;
    // A neighbour shares two corners with t, so it is in the fan of c[0] or of c[1]: the
    // fan of c[2] adds none.
    for (k, v) in c.into_iter().take(2).enumerate() {
        for &u in fans.get(v) {
            // Across an edge of t and placed (in the order). A neighbour is in the fans of
            // both corners it shares with t: it is weighed from the first (the second
            // would weigh the same places again, and only a greater gain counts).
            if u == t {
                continue;
            }
            let tu = lv.tri[u as usize];
            let cu = tu.c;
            if !adjacent(c, cu) || c[..k].iter().any(|w| cu.contains(w)) {
                continue;
            }
            let placed = lv.head == u || tu.prev != NONE;
            if !placed {
                continue;
            }
            let (before, after) = (tu.prev, tu.next);
            // After u, and before u (inserted after its predecessor).
            for (a, b) in [(u, after), (before, u)] {
                let gain =
                    1 + i32::from(joins(t, if a == u { b } else { a })) - i32::from(joins(a, b));
                if best.is_none_or(|(g, _)| gain > g) {
                    best = Some((gain, a));
                }
            }
        }
    }
    match best {
        Some((_, a)) => lv.insert_after(a, t),
        None => lv.insert_after(lv.tail, t),
    }
}
