//! The optional exact intersection check of the collapse engine: a box hierarchy over the
//! engine's faces whose boxes only ever grow (refit upward when a collapse moves a face),
//! rebuilt from the live faces when half of them have gone. Boxes are f32, rounded outward
//! from the f64 positions (which with the check on are f32 already: exact), so that a node
//! is 32 bytes and a face's record 36: the walk is bound by their loads.
//!
//! Why this is correct: every node's box contains the current box of every live face below
//! it (a moved face's new box is merged into its leaf and ancestors before the next query;
//! boxes never shrink, a dead face's own box is emptied), so a box query returns a
//! superset of the live faces whose boxes meet the query box (and no dead face), and the exact
//! triangle–triangle test ([`crate::mesh::intersect::triangles_intersect`]) decides. The
//! rebuild only tightens boxes. Written here rather than reusing [`crate::mesh::Bvh`]: that
//! one is immutable (built once for closest-point queries) and has no refit.

use glam::{DVec3, Vec3};

const NONE: u32 = u32::MAX;
const LEAF_MAX: usize = 4;

#[derive(Debug, Clone, Copy)]
struct Node {
    min: Vec3,
    max: Vec3,
    /// Inner: right child (the left one follows); leaf: first slot in `items`.
    index: u32,
    /// Leaf: number of faces; inner: 0.
    count: u32,
}

/// A face as the guard keeps it: its current box (not grown; rounded outward) and its corners'
/// vertices, so that a query keeps only the faces whose own box meets it and the caller
/// can tell the faces sharing a vertex with a moved face without loading the face (a cache
/// miss per face found was most of the check's time). A dead face has an empty box.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Item {
    pub lo: Vec3,
    pub hi: Vec3,
    pub ids: [u32; 3],
}

/// Growing boxes over faces.
#[derive(Debug, Default)]
pub(crate) struct Guard {
    nodes: Vec<Node>,
    /// Per node: its parent (NONE at the root), apart: only a refit reads it.
    parent: Vec<u32>,
    items: Vec<u32>,
    /// Per item: its face's record (see [`Item`]).
    boxes: Vec<Item>,
    leaf_of: Vec<u32>,
    /// Per face: its index in `items`.
    item_of: Vec<u32>,
    /// Live faces when last built.
    built_with: usize,
    stack: Vec<u32>,
    scratch: Vec<(u32, Vec3, Vec3)>,
}

/// The box a face has once dead: it meets no box.
const DEAD: (Vec3, Vec3) = (Vec3::INFINITY, Vec3::NEG_INFINITY);

/// The f32 box holding the f64 box [lo, hi]: each bound rounded outward.
fn outward(lo: DVec3, hi: DVec3) -> (Vec3, Vec3) {
    let down = |x: f64| {
        let f = x as f32;
        if f as f64 > x {
            f.next_down()
        } else {
            f
        }
    };
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x {
            f.next_up()
        } else {
            f
        }
    };
    (
        Vec3::new(down(lo.x), down(lo.y), down(lo.z)),
        Vec3::new(up(hi.x), up(hi.y), up(hi.z)),
    )
}

impl Guard {
    /// (Re)builds over the faces `live` says are alive, with boxes from `tri_box` and
    /// corners from `corners`.
    pub(crate) fn build(
        &mut self,
        faces: usize,
        live: impl Fn(usize) -> bool,
        tri_box: impl Fn(usize) -> (DVec3, DVec3),
        corners: impl Fn(usize) -> [u32; 3],
    ) {
        self.nodes.clear();
        self.parent.clear();
        self.leaf_of.clear();
        self.leaf_of.resize(faces, NONE);
        self.item_of.clear();
        self.item_of.resize(faces, NONE);
        let mut items = std::mem::take(&mut self.scratch);
        items.clear();
        items.extend((0..faces).filter(|&f| live(f)).map(|f| {
            let (lo, hi) = tri_box(f);
            let (lo, hi) = outward(lo, hi);
            (f as u32, lo, hi)
        }));
        self.built_with = items.len();
        if !items.is_empty() {
            self.split(&mut items, 0, NONE);
        }
        self.items.clear();
        self.items.extend(items.iter().map(|t| t.0));
        self.boxes.clear();
        self.boxes.extend(items.iter().map(|t| Item {
            lo: t.1,
            hi: t.2,
            ids: corners(t.0 as usize),
        }));
        for (i, &f) in self.items.iter().enumerate() {
            self.item_of[f as usize] = i as u32;
        }
        for (n, node) in self.nodes.iter().enumerate() {
            if node.count > 0 {
                for s in node.index..node.index + node.count {
                    self.leaf_of[self.items[s as usize] as usize] = n as u32;
                }
            }
        }
        self.scratch = items;
    }

    fn split(&mut self, items: &mut [(u32, Vec3, Vec3)], first: u32, parent: u32) -> u32 {
        let me = self.nodes.len() as u32;
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for t in items.iter() {
            lo = lo.min(t.1);
            hi = hi.max(t.2);
        }
        self.nodes.push(Node {
            min: lo,
            max: hi,
            index: first,
            count: items.len() as u32,
        });
        self.parent.push(parent);
        if items.len() <= LEAF_MAX {
            return me;
        }
        // Median split on the longest axis of the box (deterministic: ties by face id).
        let axis = (hi - lo).max_position();
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |x, y| {
            (x.1[axis] + x.2[axis])
                .total_cmp(&(y.1[axis] + y.2[axis]))
                .then(x.0.cmp(&y.0))
        });
        let (l, r) = items.split_at_mut(mid);
        self.split(l, first, me);
        let right = self.split(r, first + mid as u32, me);
        let n = &mut self.nodes[me as usize];
        n.index = right;
        n.count = 0;
        me
    }

    /// Whether half of the faces built over have died since (then a rebuild pays).
    pub(crate) fn stale(&self, live: usize) -> bool {
        live * 2 < self.built_with
    }

    /// Face `f` died: no query returns it again.
    pub(crate) fn kill(&mut self, f: usize) {
        if let Some(&i) = self.item_of.get(f).filter(|&&i| i != NONE) {
            (self.boxes[i as usize].lo, self.boxes[i as usize].hi) = DEAD;
        }
    }

    /// Face `f` now spans [lo, hi] with corners `ids`: grow its leaf and the ancestors until
    /// one holds it.
    pub(crate) fn grow(&mut self, f: usize, lo: DVec3, hi: DVec3, ids: [u32; 3]) {
        let (lo, hi) = outward(lo, hi);
        if let Some(&i) = self.item_of.get(f).filter(|&&i| i != NONE) {
            self.boxes[i as usize] = Item { lo, hi, ids };
        }
        let mut n = self.leaf_of.get(f).copied().unwrap_or(NONE);
        while n != NONE {
            let node = &mut self.nodes[n as usize];
            if node.min.cmple(lo).all() && node.max.cmpge(hi).all() {
                break;
            }
            node.min = node.min.min(lo);
            node.max = node.max.max(hi);
            n = self.parent[n as usize];
        }
    }

    /// Every live face whose own box meets [lo, hi], with its record, into `out` (cleared
    /// first): one walk for a whole fan of moved faces instead of one per face.
    pub(crate) fn collect(&mut self, lo: DVec3, hi: DVec3, out: &mut Vec<(u32, Item)>) {
        out.clear();
        let (lo, hi) = outward(lo, hi);
        let boxes = std::mem::take(&mut self.boxes);
        let items = std::mem::take(&mut self.items);
        self.any(lo, hi, |i| {
            let it = boxes[i as usize];
            if !(it.lo.cmpgt(hi).any() || lo.cmpgt(it.hi).any()) {
                out.push((items[i as usize], it));
            }
            false
        });
        self.boxes = boxes;
        self.items = items;
    }

    /// Calls `f` with the item index of every face in a leaf whose box meets [lo, hi] until
    /// `f` says stop (returns true); returns whether it stopped.
    fn any(&mut self, lo: Vec3, hi: Vec3, mut f: impl FnMut(u32) -> bool) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let mut stack = std::mem::take(&mut self.stack);
        stack.clear();
        stack.push(0);
        let mut found = false;
        'walk: while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            if node.min.cmpgt(hi).any() || lo.cmpgt(node.max).any() {
                continue;
            }
            if node.count > 0 {
                for s in node.index..node.index + node.count {
                    if f(s) {
                        found = true;
                        break 'walk;
                    }
                }
            } else {
                stack.push(node.index);
                stack.push(n + 1);
            }
        }
        self.stack = stack;
        found
    }
}
