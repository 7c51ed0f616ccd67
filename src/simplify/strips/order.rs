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
use super::lists::SlotLists;
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

/// The placed triangles around each vertex (those with distinct corners at the current
/// level), each a list that behaves as a `Vec` (push, and removal by moving the last
/// entry into the hole) but all in one buffer: a list starts with room for the vertex's
/// valence in the full mesh and moves to the end of the buffer, with twice the room, in
/// the rare case that it outgrows it (a vertex that stands for collapsed ones at a coarse
/// level). No allocation per vertex.
struct Fans {
    start: Vec<u32>,
    len: Vec<u32>,
    room: Vec<u32>,
    data: Vec<u32>,
}

impl Fans {
    fn new(tris: &[[u32; 3]], vertices: usize) -> Fans {
        let mut room = vec![0u32; vertices];
        for &v in tris.iter().flatten() {
            room[v as usize] += 1;
        }
        let mut start = Vec::with_capacity(vertices);
        let mut sum = 0u32;
        for &r in &room {
            start.push(sum);
            sum += r;
        }
        Fans {
            start,
            len: vec![0; vertices],
            room,
            data: vec![NONE; sum as usize],
        }
    }

    #[inline]
    fn get(&self, v: u32) -> &[u32] {
        let s = self.start[v as usize] as usize;
        &self.data[s..s + self.len[v as usize] as usize]
    }

    #[inline]
    fn push(&mut self, v: u32, t: u32) {
        let v = v as usize;
        let (s, n) = (self.start[v] as usize, self.len[v] as usize);
        if n as u32 == self.room[v] {
            let at = self.data.len();
            let room = (2 * n).max(4);
            self.data.extend_from_within(s..s + n);
            self.data.resize(at + room, NONE);
            self.start[v] = at as u32;
            self.room[v] = room as u32;
        }
        let s = self.start[v] as usize;
        self.data[s + n] = t;
        self.len[v] += 1;
    }

    /// Removes `t` from `v`'s list (the last entry takes its place), if it is there.
    #[inline]
    fn remove(&mut self, v: u32, t: u32) {
        let v = v as usize;
        let (s, n) = (self.start[v] as usize, self.len[v] as usize);
        let f = &mut self.data[s..s + n];
        if let Some(k) = f.iter().position(|&u| u == t) {
            f[k] = f[n - 1];
            self.len[v] -= 1;
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
    // The slots that show each vertex (in lists); the slots each collapse rewrote, in the
    // order of those lists, follow one another in `restore` (collapse i's from
    // `restore_at[i]`).
    let mut shows = SlotLists::new(vertices, cur.len());
    for (s, &v) in cur.iter().enumerate() {
        shows.push(v, s as u32);
    }
    let mut restore: Vec<u32> = Vec::with_capacity(cur.len());
    let mut restore_at: Vec<u32> = Vec::with_capacity(pairs.len() + 1);
    restore_at.push(0);
    for &(p, q) in pairs {
        for s in shows.iter(p) {
            cur[s as usize] = q;
            restore.push(s);
        }
        shows.append(p, q);
        restore_at.push(restore.len() as u32);
    }
    drop(shows);
    let restore = |i: usize| &restore[restore_at[i] as usize..restore_at[i + 1] as usize];

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
        order.insert_after(order.tail, t);
        for v in c {
            fans.push(v, t);
        }
    });

    // The splits, coarse to fine.
    let mut stamp = vec![NONE; n];
    let mut touched: Vec<(u32, bool)> = Vec::new();
    let mut fresh: Vec<u32> = Vec::new();
    for (i, &(p, q)) in pairs.iter().enumerate().rev() {
        touched.clear();
        for &s in restore(i) {
            let t = s / 3;
            if stamp[t as usize] != i as u32 {
                stamp[t as usize] = i as u32;
                touched.push((t, distinct(corners(&cur, t))));
            }
        }
        for &s in restore(i) {
            cur[s as usize] = p;
        }
        fresh.clear();
        for &(t, was) in &touched {
            let c = corners(&cur, t);
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
fn place(order: &mut Order, fans: &Fans, cur: &[u32], t: u32) {
    let c = corners(cur, t);
    let joins =
        |a: u32, b: u32| a != NONE && b != NONE && adjacent(corners(cur, a), corners(cur, b));
    let mut best: Option<(i32, u32)> = None;
    for (k, v) in c.into_iter().enumerate() {
        for &u in fans.get(v) {
            // Across an edge of t and placed (in the order). A neighbour is in the fans of
            // both corners it shares with t: it is weighed from the first (the second
            // would weigh the same places again, and only a greater gain counts).
            if u == t {
                continue;
            }
            let cu = corners(cur, u);
            if !adjacent(c, cu) || c[..k].iter().any(|w| cu.contains(w)) {
                continue;
            }
            let placed = order.head == u || order.prev[u as usize] != NONE;
            if !placed {
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
