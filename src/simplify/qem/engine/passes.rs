//! The pass engine ([`super::super::Engine::Passes`]), as meshoptimizer's simplifier orders
//! its collapses (Kapoulkine, meshoptimizer, `simplifier.cpp`): no heap and no
//! re-evaluation. Each pass
//!
//! 1. ranks every edge (and vertex pair) once: its cost as the heap engine computes it
//!    ([`Collapse::candidate`], in parallel), sorted by cost (a stable radix sort on the
//!    cost's high 32 bits: the order of the costs to about one part in a million, ties in
//!    the order of the faces, so the same on any thread count);
//! 2. takes an error goal: 1.5 × the cost of the edge at rank (triangles still to remove) / 2
//!    (most collapses remove two triangles; the rank moves up by one with every refused
//!    edge, and the slack allows for the edges a pass skips, as below);
//! 3. collapses in that order until the target, or until an edge costs more than the goal
//!    and more than any collapse of the pass so far once a sixth of the pass's triangles
//!    are gone. An edge one of whose vertices a collapse of this pass has moved is skipped:
//!    its ranked cost is stale. Every other ranked cost is still exact (an edge's cost reads
//!    only its endpoints' quadrics and positions), so a pass collapses a set of edges in the
//!    order of their current cost, each edge only while no neighbour it shares a vertex
//!    with has moved.
//!
//! The validity checks are not ranked: each runs on the collapse it decides, against the
//! mesh as it is at that moment (the engine applies each collapse at once, where
//! meshoptimizer remaps the index buffer at the end of the pass), so the link condition, the
//! flip, zero-area and fold checks, the error bound, the border bound, the two local
//! mappings and the intersection check hold exactly as in the heap engine. A pass that
//! collapses nothing under its goal is followed by one without a goal; a pass without a
//! goal that collapses nothing ends the run (no valid collapse is left).

use super::Collapse;
use rayon::prelude::*;

/// The slack of a pass's error goal over the cost at the rank its collapses would reach if
/// none were skipped (meshoptimizer's factor).
const GOAL_SLACK: f64 = 1.5;

/// An edge (or a vertex pair) as a pass ranks it: its cost and its vertices, a < b.
#[derive(Debug, Clone, Copy)]
struct Ranked {
    cost: f64,
    a: u32,
    b: u32,
    /// The edge's face corner, or `3 × faces + i` for vertex pair i.
    slot: u32,
    pair: bool,
}

/// The sort key of a cost: the high 32 bits of a non-negative f64 order as the numbers.
#[inline]
fn sort_key(cost: f64) -> u32 {
    (cost.max(0.0).to_bits() >> 32) as u32
}

/// Sorts `v` by [`sort_key`], stably: three counting passes over 11, 11 and 10 bits
/// (`tmp`: scratch). Hand-written: the radix-sort crates (`radsort`) sort an f64 key in
/// eight byte passes; the order needed here is that of the high 32 bits only.
fn radix_sort(v: &mut Vec<Ranked>, tmp: &mut Vec<Ranked>) {
    let Some(&first) = v.first() else { return };
    tmp.clear();
    tmp.resize(v.len(), first);
    let mut count = [0usize; 2048];
    for shift in [0, 11, 22] {
        count.fill(0);
        for r in v.iter() {
            count[(sort_key(r.cost) >> shift) as usize & 2047] += 1;
        }
        if count.contains(&v.len()) {
            // One bucket: this digit leaves the order as it is.
            continue;
        }
        let mut at = 0;
        for c in count.iter_mut() {
            let n = *c;
            *c = at;
            at += n;
        }
        for r in v.iter() {
            let d = (sort_key(r.cost) >> shift) as usize & 2047;
            tmp[count[d]] = *r;
            count[d] += 1;
        }
        std::mem::swap(v, tmp);
    }
}

impl Collapse<'_> {
    /// The pass-driven loop: collapse until `target` triangles or no valid collapse is
    /// left (see the module above).
    pub fn run_passes(&mut self, target: usize) {
        let mut edges: Vec<(u32, u32, u32)> = Vec::new();
        self.refused_when = vec![0; self.pair_base() as usize + self.pair_ends.len()];
        self.changed = vec![0; self.vx.len()];
        let mut ranked: Vec<Ranked> = Vec::new();
        let mut tmp: Vec<Ranked> = Vec::new();
        let mut down: Vec<bool> = Vec::new();
        // The pass number stamps the vertices a pass moves; the records start at 0.
        let mut pass = 0u32;
        let mut open = false;
        while self.tris > target {
            pass += 1;
            self.gather(&mut edges, &mut down);
            let c = &*self;
            ranked.clear();
            ranked.par_extend(
                edges
                    .par_iter()
                    .with_min_len(4096)
                    .filter_map(|&(a, b, slot)| {
                        c.candidate(a, b).map(|x| Ranked {
                            cost: x.cost,
                            a,
                            b,
                            slot,
                            pair: slot >= c.pair_base(),
                        })
                    }),
            );
            if ranked.is_empty() {
                break;
            }
            radix_sort(&mut ranked, &mut tmp);
            let done = self.pass(pass, target, &ranked, open);
            if done == 0 && open {
                break;
            }
            open = done == 0;
        }
    }

    /// The live edges (a, b, slot), a < b, each once, and the vertex pairs, into `out`,
    /// but for those refused since neither end's fan changed. An inner edge of a
    /// consistently oriented surface runs a → b in one of its faces and b → a in the other:
    /// it is taken from the face where it runs up. An edge that runs down is taken only
    /// when no face has it running up (a border edge, or faces of opposite orientation):
    /// those slots are found first, per vertex ([`Collapse::lone_down`]). `down`: scratch.
    fn gather(&self, out: &mut Vec<(u32, u32, u32)>, down: &mut Vec<bool>) {
        down.clear();
        down.resize(3 * self.faces.len(), false);
        for s in self.lone_down() {
            down[s as usize] = true;
        }
        out.clear();
        for (f, t) in self.faces.iter().enumerate() {
            if !self.face_alive[f] {
                continue;
            }
            for k in 0..3 {
                let (u, v) = (t[k], t[(k + 1) % 3]);
                let slot = (3 * f + k) as u32;
                let (a, b) = (u.min(v), u.max(v));
                if (u < v || down[slot as usize]) && !self.still_refused(a, b, slot) {
                    out.push((a, b, slot));
                }
            }
        }
        let base = self.pair_base();
        for (i, &[u, v]) in self.pair_ends.iter().enumerate() {
            let slot = base + i as u32;
            let (a, b) = (u.min(v), u.max(v));
            if a != b && !self.still_refused(a, b, slot) {
                out.push((a, b, slot));
            }
        }
    }

    /// The slots of the live half-edges u → v with u > v that have no twin v → u, in
    /// vertex order. Each is found at v, from v's own fan: the half-edge entering v at a
    /// corner of v is lone when no corner of v leaves towards u. One walk of each fan (the
    /// faces stay in cache while it is searched) where asking, for every half-edge running
    /// down, whether its lower end has a face where it runs up walked about three per
    /// vertex, each a cache miss (that search was the larger part of a pass's own time).
    /// In parallel over the vertices; the slots are few (borders).
    fn lone_down(&self) -> Vec<u32> {
        (0..self.vx.len() as u32)
            .into_par_iter()
            .with_min_len(4096)
            .flat_map_iter(|v| {
                let cs = self.corners(v);
                cs.iter().filter_map(move |&c| {
                    let (f, k) = (c as usize / 3, c as usize % 3);
                    let before = (k + 2) % 3;
                    let u = self.faces[f][before];
                    let twin = |d: &u32| {
                        let (g, j) = (*d as usize / 3, *d as usize % 3);
                        self.faces[g][(j + 1) % 3] == u
                    };
                    (u > v && !cs.iter().any(twin)).then_some((3 * f + before) as u32)
                })
            })
            .collect()
    }

    /// Whether the edge (a, b) at `slot` was refused and no collapse has changed a face of
    /// a or of b since: its validity reads only those faces (the intersection check reads
    /// faces nearby too; like the heap engine's refusal marks, this leaves such an edge
    /// refused until its own fans change: it costs collapses, never a guarantee).
    #[inline]
    fn still_refused(&self, a: u32, b: u32, slot: u32) -> bool {
        let t = self.refused_when[slot as usize];
        t != 0 && self.changed[a as usize] < t && self.changed[b as usize] < t
    }

    /// Whether a live face of `u` has the edge u → v (v its next corner): the slow twin
    /// of [`Collapse::lone_down`].
    #[cfg(test)]
    fn runs_up(&self, u: u32, v: u32) -> bool {
        self.corners(u).iter().any(|&c| {
            let (f, k) = (c as usize / 3, c as usize % 3);
            self.faces[f][(k + 1) % 3] == v
        })
    }

    /// One pass over `ranked` (sorted by cost); the error goal is off when `open`. Returns
    /// the collapses done.
    fn pass(&mut self, pass: u32, target: usize, ranked: &[Ranked], open: bool) -> usize {
        let want = self.tris - target;
        let mut goal_at = want / 2;
        let (mut removed, mut done, mut worst) = (0, 0, 0.0f64);
        for r in ranked {
            if self.tris <= target {
                break;
            }
            if !open {
                let goal = ranked
                    .get(goal_at)
                    .map_or(f64::INFINITY, |x| GOAL_SLACK * x.cost);
                if r.cost > goal && r.cost > worst && removed > want / 6 {
                    break;
                }
            }
            let (a, b) = (r.a, r.b);
            if self.vx[a as usize].refused_at == pass || self.vx[b as usize].refused_at == pass {
                continue;
            }
            // Neither vertex has moved since the ranking: the same candidate, and the edge
            // still exists (faces die only on a collapsed edge, which has a moved vertex)
            // unless it is a vertex pair.
            let Some(mut c) = self.candidate(a, b) else {
                continue;
            };
            let ok = match r.pair {
                true => self.valid_pair(a, b, &c),
                false => self.valid(a, b, &mut c),
            };
            if !ok {
                self.rejected += 1;
                self.refused_when[r.slot as usize] = self.collapses as u32 + 1;
                goal_at += 1;
                continue;
            }
            let before = self.tris;
            self.collapse(a, b, &c);
            self.dead.clear();
            // The faces that changed are those of a now: stamp a and its neighbours.
            let now = self.collapses as u32;
            let mut ring = std::mem::take(&mut self.ring);
            self.neighbours(a, &mut ring);
            for &w in ring.iter().chain([a, b].iter()) {
                self.changed[w as usize] = now;
            }
            self.ring = ring;
            removed += before - self.tris;
            self.vx[a as usize].refused_at = pass;
            self.vx[b as usize].refused_at = pass;
            worst = worst.max(r.cost);
            done += 1;
        }
        done
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simplify::prep::Prepared;
    use crate::simplify::qem::{Engine, Placement, QemParams};

    /// The per-vertex search of lone half-edges running down equals its slow twin (every
    /// such half-edge, asking its lower end for a twin), at the start and in the middle of
    /// runs, on a bumpy open grid with a hole and faces turned against their neighbours.
    #[test]
    fn lone_half_edges_equal_their_slow_twin() {
        let mut m = crate::simplify::test_meshes::grid(14);
        m.indices.remove(100);
        for f in (0..m.indices.len()).step_by(17) {
            m.indices[f].swap(0, 1);
        }
        let prep = Prepared::new(&m);
        for target in [m.indices.len(), 300, 120, 40] {
            let p = QemParams {
                engine: Engine::Passes,
                ..QemParams::plain(target as u64, Placement::Optimal)
            };
            let mut c = Collapse::new(&prep, &p);
            c.run_passes(target);
            let mut slow = Vec::new();
            for (f, t) in c.faces.iter().enumerate() {
                for k in 0..3 {
                    let (u, v) = (t[k], t[(k + 1) % 3]);
                    if c.face_alive[f] && u > v && !c.runs_up(v, u) {
                        slow.push((3 * f + k) as u32);
                    }
                }
            }
            let mut fast = c.lone_down();
            fast.sort_unstable();
            assert!(!slow.is_empty(), "{target}");
            assert_eq!(fast, slow, "{target}");
        }
    }

    #[test]
    fn the_radix_sort_is_a_stable_sort_by_key() {
        let mut x = 12345u64;
        let mut v: Vec<Ranked> = (0..5000)
            .map(|i| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let cost = match i % 3 {
                    0 => (x >> 11) as f64 / (1u64 << 53) as f64 * 1e3,
                    1 => ((x >> 60) as f64) * 1e-9,
                    _ => 0.0,
                };
                Ranked {
                    cost,
                    a: i,
                    b: i + 1,
                    slot: i,
                    pair: false,
                }
            })
            .collect();
        let mut want = v.clone();
        want.sort_by_key(|r| sort_key(r.cost));
        radix_sort(&mut v, &mut Vec::new());
        let ids = |v: &[Ranked]| v.iter().map(|r| r.a).collect::<Vec<_>>();
        assert_eq!(ids(&v), ids(&want));
    }
}
