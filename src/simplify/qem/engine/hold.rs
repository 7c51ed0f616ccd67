//! Holding vertices still for part of a run (the saliency-weighted simplifier's two phases,
//! `simplify::saliency::phases`): the engine collapses only edges and pairs away from the
//! held vertices, then, after [`Collapse::release`], goes on over the whole mesh with fresh
//! quadrics of the mesh as it is and new weights, in the one engine (no second set-up on
//! the first phase's output: its welding, corner lists, manifold analysis and attribute
//! copies are all still valid).
//!
//! A held vertex is frozen ([`Collapse::candidate`] gives no candidate for its edges): the
//! heap engine drops such an edge when it comes up, as it drops a locked vertex's edge, and
//! the pass engine does not rank it. Release unfreezes the held vertices, recomputes the
//! quadrics and, for the heap engine, costs every edge again into a new heap, as the set-up
//! does, so the heap again holds every edge not known to be invalid and the run goes on in
//! the exact greedy order (the slow twin, which recomputes every edge each step, gives the
//! same sequence: tested in `simplify::saliency::phases`).

use super::super::edges::Edges;
use super::Collapse;
use crate::simplify::quadric::Quadric;
use glam::DVec3;

/// The vertices [`Collapse::hold`] froze, for [`Collapse::release`].
#[derive(Debug)]
pub struct Held(Vec<u32>);

impl Held {
    /// How many vertices are held.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl Collapse<'_> {
    /// Holds still every live, movable vertex whose input vertex `held` marks (indexed by
    /// input vertex; a welded vertex by its representative,
    /// [`crate::simplify::prep::Prepared::weld`]) until [`Collapse::release`].
    pub fn hold(&mut self, held: &[bool]) -> Held {
        let mut out = Vec::new();
        for (d, v) in self.vx.iter_mut().enumerate() {
            if self.alive[d] && !v.frozen && held[self.source[d] as usize] {
                v.frozen = true;
                out.push(d as u32);
            }
        }
        Held(out)
    }

    /// Lets the vertices of `held` move again and starts the rest of the run afresh on the
    /// mesh as it is: every live vertex's quadric becomes the area-weighted planes of its
    /// live triangles plus its border planes (the quadric a new engine set up on this mesh
    /// would give it), scaled by `weight` of its input vertex (or, with the weight in the
    /// cost, that weight), and every edge and pair is costed again into a new heap. The
    /// refusal marks are cleared with it (every edge is in the new heap).
    pub fn release(&mut self, held: Held, weight: impl Fn(u32) -> f64) {
        for &d in &held.0 {
            // Held vertices were never collapsed into, so never joined by a pair.
            self.vx[d as usize].frozen = false;
        }
        let span: Vec<(u32, u32)> = self.vx.iter().map(|v| (v.start, v.len)).collect();
        // The corner lists hold the live faces only: these are the live mesh's edges.
        let ef = Edges::new(&self.faces, &span, &self.pool);
        let mut quad = vec![Quadric::ZERO; self.vx.len()];
        let pos: Vec<DVec3> = self.vx.iter().map(|v| v.p).collect();
        for (t, _) in self.faces.iter().zip(&self.face_alive).filter(|x| *x.1) {
            let [p0, p1, p2] = t.map(|v| pos[v as usize]);
            let c = (p1 - p0).cross(p2 - p0);
            let len = c.length();
            if len > 0.0 {
                let n = c / len;
                let q = Quadric::plane(n, -n.dot(p0), 0.5 * len);
                for &v in t {
                    quad[v as usize] += q;
                }
            }
        }
        // The border planes at their full weight: the set-up's BORDER_WEIGHT − 1 of them
        // (`add_border_planes`) and the preparation's one more.
        let mut border = vec![Quadric::ZERO; self.vx.len()];
        super::add_border_planes(&mut border, &pos, &self.faces, &ef);
        let full = super::BORDER_WEIGHT / (super::BORDER_WEIGHT - 1.0);
        for (q, b) in quad.iter_mut().zip(border) {
            *q += b * full;
        }
        let in_cost = !self.weight.is_empty();
        for (d, (v, q)) in self.vx.iter_mut().zip(quad).enumerate() {
            if !self.alive[d] {
                continue;
            }
            let w = weight(self.source[d]);
            if in_cost {
                v.q = q;
                self.weight[d] = w;
            } else {
                v.q = q * w;
            }
        }
        if self.params.engine == super::super::Engine::Heap {
            for v in &mut self.vx {
                v.refused_at = 0;
            }
            self.seed_heap(&ef);
        }
    }
}
