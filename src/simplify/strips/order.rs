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

/// A doubly linked order of triangles.
struct Order {
    prev: Vec<u32>,
    next: Vec<u32>,
    head: u32,
    tail: u32,
}

impl Order {
    fn new(n: usize) -> Order {
        Order {
            prev: vec![NONE; n],
            next: vec![NONE; n],
            head: NONE,
            tail: NONE,
        }
    }

    /// Puts `t` right after `a` (at the front when `a` is NONE).
    fn insert_after(&mut self, a: u32, t: u32) {
        let b = if a == NONE {
            self.head
        } else {
            self.next[a as usize]
        };
        self.prev[t as usize] = a;
        self.next[t as usize] = b;
        if a == NONE {
            self.head = t;
        } else {
            self.next[a as usize] = t;
        }
        if b == NONE {
            self.tail = t;
        } else {
            self.prev[b as usize] = t;
        }
    }
}

/// The current corners of triangle `t`.
#[inline]
fn corners(cur: &[u32], t: u32) -> [u32; 3] {
    let i = 3 * t as usize;
    [cur[i], cur[i + 1], cur[i + 2]]
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
    // The triangles as a list of corner slots, collapsed to the base mesh; per collapse,
    // the slots it rewrote (what its split restores).
    let mut cur: Vec<u32> = tris.iter().flatten().copied().collect();
    let mut shows: Vec<Vec<u32>> = vec![Vec::new(); vertices];
    for (s, &v) in cur.iter().enumerate() {
        shows[v as usize].push(s as u32);
    }
    let mut restore: Vec<Vec<u32>> = Vec::with_capacity(pairs.len());
    for &(p, q) in pairs {
        let moved = std::mem::take(&mut shows[p as usize]);
        for &s in &moved {
            cur[s as usize] = q;
        }
        shows[q as usize].extend_from_slice(&moved);
        restore.push(moved);
    }
    drop(shows);

    // The base mesh's triangles in the order of its own strip.
    let base: Vec<u32> = (0..n as u32)
        .filter(|&t| distinct(corners(&cur, t)))
        .collect();
    let base_tris: Vec<[u32; 3]> = base.iter().map(|&t| corners(&cur, t)).collect();
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
    let mut order = Order::new(n);
    let mut fans: Vec<Vec<u32>> = vec![Vec::new(); vertices];
    stripify::each_triangle(&strip, |c| {
        let key = canonical(c);
        let mut i = by_key.partition_point(|e| e.0 < key);
        while taken[i] {
            i += 1;
        }
        debug_assert_eq!(by_key[i].0, key);
        taken[i] = true;
        let t = by_key[i].1;
        order.insert_after(order.tail, t);
        for v in c {
            fans[v as usize].push(t);
        }
    });

    // The splits, coarse to fine.
    let mut stamp = vec![NONE; n];
    let mut touched: Vec<(u32, bool)> = Vec::new();
    let mut fresh: Vec<u32> = Vec::new();
    for (i, &(p, q)) in pairs.iter().enumerate().rev() {
        touched.clear();
        for &s in &restore[i] {
            let t = s / 3;
            if stamp[t as usize] != i as u32 {
                stamp[t as usize] = i as u32;
                touched.push((t, distinct(corners(&cur, t))));
            }
        }
        for &s in &restore[i] {
            cur[s as usize] = p;
        }
        fresh.clear();
        for &(t, was) in &touched {
            let c = corners(&cur, t);
            if !distinct(c) {
                continue;
            }
            if was {
                let f = &mut fans[q as usize];
                if let Some(k) = f.iter().position(|&u| u == t) {
                    f.swap_remove(k);
                }
                fans[p as usize].push(t);
            } else {
                for v in c {
                    fans[v as usize].push(t);
                }
                fresh.push(t);
            }
        }
        for &t in &fresh {
            place(&mut order, &fans, &cur, t);
        }
    }

    let mut seq: Vec<[u32; 3]> = Vec::with_capacity(n);
    let mut t = order.head;
    while t != NONE {
        seq.push(tris[t as usize]);
        t = order.next[t as usize];
    }
    let mut out = Vec::with_capacity(2 * n);
    rebuild_into(&mut seq, join, 1, &mut out);
    out
}

/// Inserts the new triangle `t` next to one of its neighbours (in the fans of its corners)
/// where it joins the most: +1 per neighbour in the order it comes next to, −1 when it
/// separates two that were joined. With no neighbour placed yet, at the end.
fn place(order: &mut Order, fans: &[Vec<u32>], cur: &[u32], t: u32) {
    let c = corners(cur, t);
    let joins =
        |a: u32, b: u32| a != NONE && b != NONE && adjacent(corners(cur, a), corners(cur, b));
    let mut best: Option<(i32, u32)> = None;
    for v in c {
        for &u in &fans[v as usize] {
            // Placed (in the order) and across an edge of t.
            let placed = order.head == u || order.prev[u as usize] != NONE;
            if u == t || !placed || !adjacent(c, corners(cur, u)) {
                continue;
            }
            let after = order.next[u as usize];
            let before = order.prev[u as usize];
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
        Some((_, a)) => order.insert_after(a, t),
        None => order.insert_after(order.tail, t),
    }
}
