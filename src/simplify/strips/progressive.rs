//! Progressive strips: a base strip and the vertex splits that refine it, replayed from the
//! quadric engine's collapse sequence.
//!
//! A collapse of p into q rewrites p in the strip as q: the triangles on the edge become
//! degenerate and draw nothing (implicit removal). Its inverse, the vertex split, restores
//! p at the offsets it was rewritten at. Two forms of the record (the progressive-strips paper):
//!
//! - Naive-PS: the offsets of every slot that holds p, including the slots of vertices
//!   collapsed into p before. These pile up as the strip coarsens.
//! - E-PS: a slot of p whose neighbour at distance 1 or 2 shows q after the collapse is
//!   written as a reference to it (R−2, R−1, R+1, R+2) rather than as q; a slot that is a
//!   reference follows its target, so a later collapse of q rewrites only the slots that
//!   name q directly, and its split restores only those. The neighbour may be a slot that
//!   shows q already (the paper's six patterns, p and q in one triangle) or one that shows
//!   p, through references or another slot of p, as long as its chain of references does
//!   not come back to the slot: at most one slot named per group of p's slots that reach
//!   one another, none when the group touches q. The chains end at named slots, so they
//!   never form cycles.
//!
//! The collapses are half-edge collapses (the engine with endpoint placement): a split
//! restores one vertex and moves no other, as the record holds one position. The stream
//! numbers vertices as it sends them: the base mesh's first, then one per split.

use super::lists::MergeLists;
use super::stripify::{self, StripParams, RESTART};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::simplify::qem::{self, QemParams};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::ops::Range;

/// A strip slot that refers to the slot at offset k ∈ {−2, −1, 1, 2} from it:
/// `REF_BASE + (k + 2)`. Vertex ids stay below it.
pub const REF_BASE: u32 = 0xFFFF_FFF0;

/// The slot value of a reference to the slot `k` away.
#[inline]
pub const fn ref_slot(k: i32) -> u32 {
    REF_BASE + (k + 2) as u32
}

/// The offset a slot value refers by, if it is a reference.
#[inline]
pub const fn ref_offset(v: u32) -> Option<i32> {
    if v >= REF_BASE && v <= REF_BASE + 4 && v != REF_BASE + 2 {
        Some((v - REF_BASE) as i32 - 2)
    } else {
        None
    }
}

/// Which form of the vertex-split records a stream carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// Naive-PS: every offset restored is listed.
    Naive,
    /// E-PS: only the slots that name the vertex directly.
    #[default]
    Encoded,
}

/// How the strip of the full mesh is ordered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StripOrder {
    /// The paper's: the full mesh stripified on its own ([`ProgressiveParams::strip`]).
    /// Written `paper` in a configuration (`full` is read too).
    #[serde(rename = "paper", alias = "full")]
    Full,
    /// Ours (default): the base mesh stripified, each split's triangles inserted next to
    /// their neighbours from the base up ([`super::order`]), so that every level's
    /// survivors come in few strips.
    #[default]
    Hierarchical,
}

/// How to build progressive strips.
#[derive(Debug, Clone, PartialEq)]
pub struct ProgressiveParams {
    /// The base mesh's share of the triangles, in (0, 1); default 0.05 (as the paper).
    pub base_ratio: f64,
    /// How the original mesh is stripified: by default the global order (window 0, the
    /// longest strips whatever the file's order; the paper used STRIPE, a global greedy
    /// too) with restarts.
    pub strip: StripParams,
    /// The engine's error bound, in model units (none by default).
    pub max_error: Option<f64>,
    /// How the full strip is ordered (default [`StripOrder::Hierarchical`]; `strip`'s join
    /// applies to both).
    pub order: StripOrder,
}

impl Default for ProgressiveParams {
    fn default() -> ProgressiveParams {
        ProgressiveParams {
            base_ratio: 0.05,
            strip: StripParams {
                window: 0,
                ..StripParams::default()
            },
            max_error: None,
            order: StripOrder::default(),
        }
    }
}

/// One vertex split: vertex `base_vertices + i` (for split i) comes back. Its records are
/// ranges of two arrays shared by all splits ([`Progressive::naive`],
/// [`Progressive::encoded`]): no allocation per split.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Split {
    /// The vertex it was collapsed into (present at the coarser level).
    pub kept: u32,
    /// Naive-PS, in [`Progressive::naive_offsets`]: the offsets of every slot that shows
    /// `kept` at the coarser level and the restored vertex at the finer one, ascending.
    pub naive: Range<usize>,
    /// E-PS, in [`Progressive::encoded_slots`]: the offsets that name the restored vertex
    /// directly at the finer level, with what they hold at the coarser one (`kept` or a
    /// reference), ascending.
    pub encoded: Range<usize>,
}

/// A mesh as progressive strips.
#[derive(Debug, Clone)]
pub struct Progressive {
    /// Every vertex in stream order (the base mesh's, then one per split), with the
    /// input's attributes; no triangles.
    pub vertices: TriMesh,
    /// Vertices of the base mesh.
    pub base_vertices: u32,
    /// The base strip as drawn (vertex ids and restarts): the Naive-PS state.
    pub base: Vec<u32>,
    /// The base strip with E-PS references.
    pub base_slots: Vec<u32>,
    /// The splits, coarse to fine.
    pub splits: Vec<Split>,
    /// The Naive-PS records of all splits (each split's a range, [`Progressive::naive`]).
    pub naive_offsets: Vec<u32>,
    /// The E-PS records of all splits (each split's a range, [`Progressive::encoded`]).
    pub encoded_slots: Vec<(u32, u32)>,
    /// Triangles of the full mesh (with three distinct vertices).
    pub triangles: usize,
}

/// The input with exact duplicate vertices (same position and attributes) merged, unused
/// vertices dropped, and triangles with a repeated position left out (they draw nothing).
fn canonical_mesh(mesh: &TriMesh) -> TriMesh {
    // The key holds the position and the attributes the mesh has: 3 values for positions
    // alone (the usual case: a quarter of the bytes to hash and store), else 12.
    if mesh.normals.is_none() && mesh.colors.is_none() && mesh.uvs.is_none() {
        merge_duplicates::<3>(mesh)
    } else {
        merge_duplicates::<12>(mesh)
    }
}

/// [`canonical_mesh`] with keys of `N` values: the position and the attributes the mesh
/// has, in a fixed array (the same attributes for every vertex, so the unused tail is zero
/// for all): no allocation per vertex. The vertices with equal keys are grouped by a
/// parallel sort (a class per key); then one pass over the triangles in order numbers the
/// classes as it first meets them, as a hash map filled in that pass would (the sort runs
/// on both cores where the map could not, and each corner is then two array reads).
fn merge_duplicates<const N: usize>(mesh: &TriMesh) -> TriMesh {
    let bits = |x: f32| (x + 0.0).to_bits();
    let mut keyed: Vec<([u32; N], u32)> = (0..mesh.vertex_count())
        .into_par_iter()
        .map(|v| {
            let mut key = [0u32; N];
            let mut at = 0;
            vertex_floats(mesh, v, |xs| {
                for &x in xs {
                    key[at] = bits(x);
                    at += 1;
                }
            });
            (key, v as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    // Each vertex's class: the first vertex of its run of equal keys.
    let mut class = vec![0u32; mesh.vertex_count()];
    for (i, &(key, v)) in keyed.iter().enumerate() {
        class[v as usize] = if i > 0 && keyed[i - 1].0 == key {
            class[keyed[i - 1].1 as usize]
        } else {
            v
        };
    }
    drop(keyed);
    let mut id = vec![u32::MAX; mesh.vertex_count()];
    let mut out = TriMesh {
        normals: mesh.normals.as_ref().map(|_| Vec::new()),
        colors: mesh.colors.as_ref().map(|_| Vec::new()),
        uvs: mesh.uvs.as_ref().map(|_| Vec::new()),
        ..TriMesh::default()
    };
    for t in &mesh.indices {
        let p = t.map(|v| mesh.positions[v as usize]);
        if p[0] == p[1] || p[1] == p[2] || p[0] == p[2] {
            continue;
        }
        let mut tri = [0u32; 3];
        for (k, &v) in t.iter().enumerate() {
            let c = class[v as usize] as usize;
            if id[c] == u32::MAX {
                id[c] = out.positions.len() as u32;
                out.positions.push(mesh.positions[v as usize]);
                push_attributes(&mut out, mesh, v as usize);
            }
            tri[k] = id[c];
        }
        if tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2] {
            out.indices.push(tri);
        }
    }
    out
}

/// Calls `f` on vertex `v`'s position, then on each attribute the mesh has (normal,
/// colour, UV): the order of a duplicate's key and of a vertex in the stream.
pub(crate) fn vertex_floats(m: &TriMesh, v: usize, mut f: impl FnMut(&[f32])) {
    f(&m.positions[v].to_array());
    if let Some(a) = &m.normals {
        f(&a[v].to_array());
    }
    if let Some(a) = &m.colors {
        f(&a[v]);
    }
    if let Some(a) = &m.uvs {
        f(&a[v].to_array());
    }
}

fn push_attributes(out: &mut TriMesh, mesh: &TriMesh, v: usize) {
    if let (Some(o), Some(a)) = (&mut out.normals, &mesh.normals) {
        o.push(a[v]);
    }
    if let (Some(o), Some(a)) = (&mut out.colors, &mesh.colors) {
        o.push(a[v]);
    }
    if let (Some(o), Some(a)) = (&mut out.uvs, &mesh.uvs) {
        o.push(a[v]);
    }
}

/// How many collapses ahead [`Progressive::from_full`] reads the slots a collapse rewrites.
const AHEAD: usize = 4;

/// The strip state while collapses are replayed.
struct Replay {
    /// As drawn.
    resolved: Vec<u32>,
    /// With E-PS references.
    slots: Vec<u32>,
    /// Per vertex: the offsets that show it when it is collapsed (Naive-PS). Those of
    /// them that are not references name it (E-PS): a slot of the vertex collapsed turns
    /// into a reference, or names the kept vertex, and moves to its list.
    shows: MergeLists,
    /// Scratch for [`Replay::collapse`]: the offsets that name the vertex removed, and a
    /// state per offset.
    named: Vec<u32>,
    state: Vec<u8>,
}

impl Replay {
    /// `collapses`: (removed, kept), in the order they will be replayed.
    fn new(strip: Vec<u32>, vertices: usize, collapses: &[(u32, u32)]) -> Replay {
        let shows = MergeLists::new(&strip, RESTART, vertices, collapses);
        Replay {
            slots: strip.clone(),
            resolved: strip,
            shows,
            named: Vec::new(),
            state: Vec::new(),
        }
    }

    /// Collapses `p` into `q` (the next of the collapses given to [`Replay::new`]);
    /// returns the split that undoes it, its records appended to `naive` and `encoded`.
    fn collapse(
        &mut self,
        p: u32,
        q: u32,
        naive: &mut Vec<u32>,
        encoded: &mut Vec<(u32, u32)>,
    ) -> Split {
        let len = self.resolved.len() as i64;
        // E-PS, against the strip before the collapse. A slot that names p becomes a
        // reference to a neighbour at distance 1 or 2 that shows p or q, as every slot
        // showing either shows q once the collapse is done, provided that the neighbour
        // does not lean on the slot itself: the neighbour's chain of references must end at
        // a slot that names q, or at a slot of p settled to name q. Slots that can refer
        // are turned into references (each pass may enable more); when none can, one slot
        // of p is settled to name q, and the passes go on. So each group of p's slots that
        // reach one another through neighbours costs at most one named slot, and none when
        // one of them is next to q.
        let mut names = std::mem::take(&mut self.named);
        names.clear();
        let shows = self.shows.get(p);
        names.extend(
            shows
                .iter()
                .copied()
                .filter(|&o| ref_offset(self.slots[o as usize]).is_none()),
        );
        // Per slot of p: 0 undecided, 1 a reference, 2 settled to name q.
        let mut state = std::mem::take(&mut self.state);
        state.clear();
        state.resize(names.len(), 0);
        let root = |slots: &[u32], mut j: usize| {
            while let Some(k) = ref_offset(slots[j]) {
                j = (j as i64 + k as i64) as usize;
            }
            j
        };
        loop {
            let mut changed = false;
            for i in 0..names.len() {
                if state[i] != 0 {
                    continue;
                }
                let o = names[i] as i64;
                let near = [-1i32, 1, -2, 2].into_iter().find(|&k| {
                    let j = o + k as i64;
                    if !(0..len).contains(&j) {
                        return false;
                    }
                    let r = self.resolved[j as usize];
                    if r != q && r != p {
                        return false;
                    }
                    let n = root(&self.slots, j as usize);
                    self.slots[n] == q
                        || names
                            .iter()
                            .position(|&x| x as usize == n)
                            .is_some_and(|m| state[m] == 2)
                });
                if let Some(k) = near {
                    self.slots[o as usize] = ref_slot(k);
                    state[i] = 1;
                    changed = true;
                }
            }
            if !changed {
                match state.iter().position(|&x| x == 0) {
                    Some(i) => state[i] = 2,
                    None => break,
                }
            }
        }
        let e0 = encoded.len();
        for (i, &o) in names.iter().enumerate() {
            if state[i] == 2 {
                self.slots[o as usize] = q;
            }
            encoded.push((o, self.slots[o as usize]));
        }
        self.state = state;
        self.named = names;
        let n0 = naive.len();
        naive.extend_from_slice(self.shows.get(p));
        for &o in &naive[n0..] {
            self.resolved[o as usize] = q;
        }
        naive[n0..].sort_unstable();
        encoded[e0..].sort_unstable();
        Split {
            kept: q,
            naive: n0..naive.len(),
            encoded: e0..encoded.len(),
        }
    }
}

/// Builds the progressive strips of `mesh`: stripify, simplify to the base mesh with the
/// quadric engine (endpoint placement), replay the collapses on the strip.
pub fn progressive(mesh: &TriMesh, params: &ProgressiveParams) -> Result<Progressive> {
    mesh.validate("the input mesh")?;
    let r = params.base_ratio;
    if !(r > 0.0 && r < 1.0) {
        return Err(Error::param(
            "strips",
            "base_ratio",
            r,
            "must be a number in (0, 1)",
        ));
    }
    let canon = canonical_mesh(mesh);
    if canon.vertex_count() >= REF_BASE as usize {
        return Err(Error::Data {
            stage: "strips",
            message: format!("{} vertices are too many for a strip", canon.vertex_count()),
        });
    }
    if canon.indices.is_empty() {
        return Err(Error::Data {
            stage: "strips",
            message: "the mesh has no triangles with three distinct corners".into(),
        });
    }
    let (_, steps) = qem::simplify_logged(&canon, &qem_params(&canon, params))?;
    let n = canon.vertex_count();
    // The strip id standing for each engine vertex: the engine's survivor keeps its id
    // but, with endpoint placement, may take the other endpoint's position; then that
    // endpoint is the one kept.
    let mut alias: Vec<u32> = (0..n as u32).collect();
    let mut removed = vec![false; n];
    let mut pairs = Vec::with_capacity(steps.len());
    for s in &steps {
        let (a, b) = (alias[s.kept as usize], alias[s.removed as usize]);
        let at = s.position.as_vec3();
        let (q, p) = if at == canon.positions[b as usize] && at != canon.positions[a as usize] {
            (b, a)
        } else {
            (a, b)
        };
        alias[s.kept as usize] = q;
        removed[p as usize] = true;
        pairs.push((p, q));
    }
    // The strip's order and the stream's numbering of the vertices are independent.
    let (strip, (stream, base_vertices, vertices)) = rayon::join(
        || match params.order {
            StripOrder::Full => stripify::stripify(&canon.indices, &params.strip),
            StripOrder::Hierarchical => {
                super::order::hierarchical(&canon.indices, n, &pairs, params.strip.join)
            }
        },
        || stream_vertices(&canon, &removed, &pairs),
    );
    let full: Vec<u32> = strip
        .iter()
        .map(|&v| if v == RESTART { v } else { stream[v as usize] })
        .collect();
    let kept: Vec<u32> = pairs
        .iter()
        .rev()
        .map(|&(_, q)| stream[q as usize])
        .collect();
    Ok(Progressive::from_full(
        vertices,
        base_vertices,
        full,
        &kept,
        canon.triangle_count(),
    ))
}

/// The stream's id of each vertex (the base mesh's ascending, then the removed ones, last
/// collapse first), the base mesh's vertex count, and the vertices in stream order.
fn stream_vertices(
    canon: &TriMesh,
    removed: &[bool],
    pairs: &[(u32, u32)],
) -> (Vec<u32>, u32, TriMesh) {
    let n = canon.vertex_count();
    let mut stream = vec![u32::MAX; n];
    let mut next = 0u32;
    for v in 0..n {
        if !removed[v] {
            stream[v] = next;
            next += 1;
        }
    }
    let base_vertices = next;
    for &(p, _) in pairs.iter().rev() {
        stream[p as usize] = next;
        next += 1;
    }
    let mut vertices = TriMesh {
        positions: vec![Vec3::ZERO; n],
        normals: canon.normals.as_ref().map(|_| vec![Vec3::ZERO; n]),
        colors: canon.colors.as_ref().map(|_| vec![[0.0; 4]; n]),
        uvs: canon.uvs.as_ref().map(|_| vec![Vec2::ZERO; n]),
        indices: Vec::new(),
    };
    for v in 0..n {
        let s = stream[v] as usize;
        vertices.positions[s] = canon.positions[v];
        if let (Some(o), Some(a)) = (&mut vertices.normals, &canon.normals) {
            o[s] = a[v];
        }
        if let (Some(o), Some(a)) = (&mut vertices.colors, &canon.colors) {
            o[s] = a[v];
        }
        if let (Some(o), Some(a)) = (&mut vertices.uvs, &canon.uvs) {
            o[s] = a[v];
        }
    }
    (stream, base_vertices, vertices)
}

/// The engine's parameters for `params` on the canonical mesh.
fn qem_params(canon: &TriMesh, params: &ProgressiveParams) -> QemParams {
    let t = canon.triangle_count() as f64 * params.base_ratio;
    QemParams {
        max_error: params.max_error,
        ..QemParams::plain((t.ceil() as u64).max(1), qem::Placement::Endpoint)
    }
}

/// The mesh the progressive strips are built on (duplicates merged) and the engine's
/// parameters: for tests that compare a level with the engine's own result.
pub fn engine_input(mesh: &TriMesh, params: &ProgressiveParams) -> (TriMesh, QemParams) {
    let canon = canonical_mesh(mesh);
    let q = qem_params(&canon, params);
    (canon, q)
}

/// Sets slot `o` of the drawn `strip` to `v`, and every slot that refers to it through
/// the E-PS `slots`, transitively; returns the number of slots written.
#[inline]
pub(crate) fn show(slots: &[u32], strip: &mut [u32], stack: &mut Vec<u32>, o: u32, v: u32) -> u64 {
    strip[o as usize] = v;
    let mut n = 1;
    stack.clear();
    stack.push(o);
    let len = slots.len() as i64;
    while let Some(x) = stack.pop() {
        for k in [-2i64, -1, 1, 2] {
            let j = x as i64 - k;
            if (0..len).contains(&j) && slots[j as usize] == ref_slot(k as i32) {
                strip[j as usize] = v;
                n += 1;
                stack.push(j as u32);
            }
        }
    }
    n
}

/// Applies splits to the base strip, in place, in either direction.
#[derive(Debug, Clone)]
pub struct Decoder<'p> {
    p: &'p Progressive,
    encoding: Encoding,
    level: usize,
    strip: Vec<u32>,
    slots: Vec<u32>,
    stack: Vec<u32>,
    /// Strip indices written so far (the drawn strip's, not the references').
    pub updates: u64,
}

impl<'p> Decoder<'p> {
    /// At the base level.
    pub fn new(p: &'p Progressive, encoding: Encoding) -> Decoder<'p> {
        Decoder {
            p,
            encoding,
            level: 0,
            strip: p.base.clone(),
            slots: match encoding {
                Encoding::Naive => Vec::new(),
                Encoding::Encoded => p.base_slots.clone(),
            },
            stack: Vec::new(),
            updates: 0,
        }
    }

    /// Splits applied.
    pub fn level(&self) -> usize {
        self.level
    }

    /// The strip at this level, as drawn.
    pub fn strip(&self) -> &[u32] {
        &self.strip
    }

    /// Vertices present at this level (the first ones of [`Progressive::vertices`]).
    pub fn vertex_count(&self) -> usize {
        self.p.base_vertices as usize + self.level
    }

    #[inline]
    fn show(&mut self, o: u32, v: u32) {
        self.updates += show(&self.slots, &mut self.strip, &mut self.stack, o, v);
    }

    /// Applies the next split; false at the full level.
    pub fn refine(&mut self) -> bool {
        let p = self.p;
        let Some(s) = p.splits.get(self.level) else {
            return false;
        };
        let v = p.base_vertices + self.level as u32;
        match self.encoding {
            Encoding::Naive => {
                let naive = &p.naive_offsets[s.naive.clone()];
                for &o in naive {
                    self.strip[o as usize] = v;
                }
                self.updates += naive.len() as u64;
            }
            Encoding::Encoded => {
                for &(o, _) in &p.encoded_slots[s.encoded.clone()] {
                    self.slots[o as usize] = v;
                    self.show(o, v);
                }
            }
        }
        self.level += 1;
        true
    }

    /// Undoes the last split; false at the base level.
    pub fn coarsen(&mut self) -> bool {
        if self.level == 0 {
            return false;
        }
        self.level -= 1;
        let p = self.p;
        let s = &p.splits[self.level];
        match self.encoding {
            Encoding::Naive => {
                let naive = &p.naive_offsets[s.naive.clone()];
                for &o in naive {
                    self.strip[o as usize] = s.kept;
                }
                self.updates += naive.len() as u64;
            }
            Encoding::Encoded => {
                for &(o, was) in &p.encoded_slots[s.encoded.clone()] {
                    self.slots[o as usize] = was;
                    self.show(o, s.kept);
                }
            }
        }
        true
    }

    /// Goes to `level` splits (clamped to the full level).
    pub fn set_level(&mut self, level: usize) {
        let level = level.min(self.p.splits.len());
        while self.level < level {
            self.refine();
        }
        while self.level > level {
            self.coarsen();
        }
    }
}

impl Progressive {
    /// Progressive strips from the full strip (stream ids) and the kept vertex of each
    /// split (`kept[i]`, for vertex `base_vertices + i`): the collapses are replayed from
    /// the last split to the first.
    pub fn from_full(
        vertices: TriMesh,
        base_vertices: u32,
        full: Vec<u32>,
        kept: &[u32],
        triangles: usize,
    ) -> Progressive {
        let collapses: Vec<(u32, u32)> = (0..kept.len())
            .rev()
            .map(|i| (base_vertices + i as u32, kept[i]))
            .collect();
        let mut replay = Replay::new(full, vertices.vertex_count(), &collapses);
        // The slots of the collapse `AHEAD` places on are read early (folded into
        // `early`, which keeps the reads): the collapses are scattered over the strip, and
        // so their cache misses overlap the work in between instead of stalling each one.
        let mut early = 0u32;
        let mut out: Vec<Split> = Vec::with_capacity(collapses.len());
        // The records in collapse order (fine to coarse); each split holds its ranges.
        let (mut naive, mut encoded) = (Vec::new(), Vec::new());
        for (i, &(p, q)) in collapses.iter().enumerate() {
            if let Some(&(r, _)) = collapses.get(i + AHEAD) {
                for &o in replay.shows.get(r) {
                    early ^= replay.slots[o as usize];
                }
            }
            out.push(replay.collapse(p, q, &mut naive, &mut encoded));
        }
        std::hint::black_box(early);
        out.reverse();
        Progressive {
            vertices,
            base_vertices,
            base: replay.resolved,
            base_slots: replay.slots,
            splits: out,
            naive_offsets: naive,
            encoded_slots: encoded,
            triangles,
        }
    }

    /// The Naive-PS record of split `i`: the offsets it restores, ascending.
    #[inline]
    pub fn naive(&self, i: usize) -> &[u32] {
        &self.naive_offsets[self.splits[i].naive.clone()]
    }

    /// The E-PS record of split `i`: the offsets that name its vertex, with what each holds
    /// at the coarser level, ascending.
    #[inline]
    pub fn encoded(&self, i: usize) -> &[(u32, u32)] {
        &self.encoded_slots[self.splits[i].encoded.clone()]
    }

    /// The mesh at `level` splits: the vertices present and the triangles drawn.
    pub fn mesh_at(&self, level: usize, encoding: Encoding) -> TriMesh {
        let mut d = Decoder::new(self, encoding);
        d.set_level(level);
        let n = d.vertex_count();
        let v = &self.vertices;
        TriMesh {
            positions: v.positions[..n].to_vec(),
            indices: stripify::unstripify(d.strip()),
            normals: v.normals.as_ref().map(|a| a[..n].to_vec()),
            colors: v.colors.as_ref().map(|a| a[..n].to_vec()),
            uvs: v.uvs.as_ref().map(|a| a[..n].to_vec()),
        }
    }

    /// Mean strip slots updated per split: (Naive-PS, E-PS).
    pub fn mean_updates(&self) -> (f64, f64) {
        let n = self.splits.len().max(1) as f64;
        let (naive, enc) = (self.naive_offsets.len(), self.encoded_slots.len());
        (naive as f64 / n, enc as f64 / n)
    }

    /// The records' size as the paper counts it: a 24-byte position, a 2-byte id and
    /// 2 bytes per offset: (Naive-PS, E-PS) bytes.
    pub fn paper_record_bytes(&self) -> (usize, usize) {
        let naive: usize = self.splits.iter().map(|s| 26 + 2 * s.naive.len()).sum();
        let enc: usize = self.splits.iter().map(|s| 26 + 2 * s.encoded.len()).sum();
        (naive, enc)
    }
}
