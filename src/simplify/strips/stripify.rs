//! Generalised triangle strips: the greedy of Evans, Skiena and Varshney ("Optimizing
//! Triangle Strips for Fast Rendering", 1996) in meshoptimizer's windowed form (Kapoulkine),
//! extended with an adjacency fallback.
//!
//! A strip s₀ s₁ s₂ … draws the triangles (sᵢ, sᵢ₊₁, sᵢ₊₂) for even i and (sᵢ₊₁, sᵢ, sᵢ₊₂)
//! for odd i (each relative to the start of its strip); triangles with a repeated vertex
//! draw nothing. A *swap* (the next triangle turns the other way) repeats a vertex; strips
//! are joined by a restart index ([`RESTART`]) or by repeating the last vertex of one and
//! the first of the next (degenerate triangles).
//!
//! The greedy: start a strip at a triangle of least valence, and extend it across its
//! outgoing edge, or, when no triangle is there, across the other free edge by a swap;
//! when neither exists, start a new strip. Two orders are offered:
//!
//! - the cache-aware window ([`StripParams::window`] > 0, the default 8, meshoptimizer's
//!   choice): candidates are looked for first among the next few not-yet-used triangles
//!   of the input order, so the strips follow that order (a vertex-cache-optimised order
//!   stays cache-friendly). Where meshoptimizer then ends the strip, we look across the
//!   edge in the whole mesh (an edge map): the strip continues with one new vertex per
//!   triangle, which is both shorter and, the triangle being adjacent, cache-friendly.
//! - the global order (window 0): the next strip starts at an unused triangle with the
//!   fewest unused neighbours (STRIPE's rule) and extends through the edge map only:
//!   the longest strips, whatever the input order, at a worse vertex-cache hit rate.
//!
//! We chose meshoptimizer's form of the greedy over STRIPE's (which the paper used) for its
//! cache awareness and speed (one pass, a window of 8), and write it here rather than call
//! meshoptimizer because the fallback changes its inner loop and the crate is C++ (kept as
//! the dev-dependency reference).

/// The index that ends a strip and starts the next (primitive restart).
pub const RESTART: u32 = u32::MAX;

/// How consecutive strips are joined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Join {
    /// A [`RESTART`] index between strips (primitive restart).
    #[default]
    Restart,
    /// Degenerate triangles: the last vertex of one strip and the first of the next repeated.
    Degenerate,
}

/// How to stripify.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StripParams {
    /// How strips are joined.
    pub join: Join,
    /// Look for the next triangle among this many unused triangles of the input order
    /// first (vertex-cache-aware); 0 for the global greedy.
    pub window: usize,
}

impl Default for StripParams {
    fn default() -> StripParams {
        StripParams {
            join: Join::Restart,
            window: 8,
        }
    }
}

/// Half-edges by their lower vertex (compressed rows, ascending triangle): row 2v holds
/// the half-edges (v, w) with w > v, row 2v + 1 those (w, v) with w > v, each as (w, the
/// apex of its triangle, its corner 3t + k where t[k] is its first vertex). A directed
/// edge and its reverse are thus in the two rows of the same vertex, a few entries each.
/// Built by a counting sort (two passes over the corners, no hashing).
struct EdgeMap {
    /// Row r: `rows[start[r]..start[r + 1]]`.
    start: Vec<u32>,
    /// (other vertex, apex, corner).
    rows: Vec<[u32; 3]>,
}

/// The row and the other vertex of the directed edge (a, b).
#[inline]
fn key(a: u32, b: u32) -> (usize, u32) {
    if a < b {
        (2 * a as usize, b)
    } else {
        (2 * b as usize + 1, a)
    }
}

impl EdgeMap {
    fn new(tris: &[[u32; 3]], vertices: usize, valence: &mut [u32]) -> EdgeMap {
        let mut start = vec![0u32; 2 * vertices + 1];
        for &[a, b, c] in tris {
            for (x, y) in [(a, b), (b, c), (c, a)] {
                start[key(x, y).0] += 1;
                valence[x as usize] += 1;
            }
        }
        // Inclusive sums, then filled from the back: each row ends ascending and `start[r]`
        // ends at the row's first entry.
        let mut sum = 0u32;
        for s in start.iter_mut() {
            sum += *s;
            *s = sum;
        }
        let mut rows = vec![[0u32; 3]; tris.len() * 3];
        for (t, &[a, b, c]) in tris.iter().enumerate().rev() {
            for (k, x, y, z) in [(2, c, a, b), (1, b, c, a), (0, a, b, c)] {
                let (r, w) = key(x, y);
                let s = &mut start[r];
                *s -= 1;
                rows[*s as usize] = [w, z, 3 * t as u32 + k];
            }
        }
        EdgeMap { start, rows }
    }

    #[inline]
    fn row(&self, r: usize) -> &[[u32; 3]] {
        &self.rows[self.start[r] as usize..self.start[r + 1] as usize]
    }

    /// The first unused triangle with directed edge (e0, e1).
    #[inline]
    fn find(&self, used: &[bool], e0: u32, e1: u32) -> Option<u32> {
        let (r, w) = key(e0, e1);
        self.row(r)
            .iter()
            .find(|&&[x, _, c]| x == w && !used[c as usize / 3])
            .map(|&[_, _, c]| c / 3)
    }

    /// Per corner 3t + k: the triangle across edge (t[k], t[k + 1]), that is the one with
    /// the directed edge (t[k + 1], t[k]), and its apex; [`NONE`] if there is none,
    /// [`MANY`] if there are several (a non-manifold or doubly covered edge: those are
    /// looked up in the rows). An edge's reverse is in the other row of its lower vertex:
    /// one pass over the rows in order, each read once from memory, each entry compared
    /// with the few of the other row (about 3 on a closed mesh, where the rows by vertex
    /// held all 6 corners of both directions). The apex saves the strip a read of the
    /// triangle across, scattered in memory, for every edge it tries.
    fn twins(&self) -> Vec<[u32; 2]> {
        let mut twin = vec![[NONE, 0]; self.rows.len()];
        for v in 0..(self.start.len() - 1) / 2 {
            let (lo, hi) = (self.row(2 * v), self.row(2 * v + 1));
            for (this, other) in [(lo, hi), (hi, lo)] {
                for &[w, _, c] in this {
                    // Without branches in the loop (a match is unpredictable): the position
                    // of the last match and the number of them.
                    let (mut found, mut count) = (0usize, 0u32);
                    for (j, &[x, _, _]) in other.iter().enumerate() {
                        let m = x == w;
                        count += m as u32;
                        found = if m { j } else { found };
                    }
                    twin[c as usize] = match count {
                        0 => [NONE, 0],
                        1 => [other[found][2] / 3, other[found][1]],
                        _ => [MANY, 0],
                    };
                }
            }
        }
        twin
    }
}

/// No triangle across the edge.
const NONE: u32 = u32::MAX;
/// Several triangles across the edge.
const MANY: u32 = u32::MAX - 1;

/// The strips of `triangles` (triangles with a repeated vertex are left out: they draw
/// nothing). Every other triangle is drawn exactly once, with its orientation.
pub fn stripify(triangles: &[[u32; 3]], params: &StripParams) -> Vec<u32> {
    let distinct = |t: &[u32; 3]| t[0] != t[1] && t[1] != t[2] && t[0] != t[2];
    let kept: Vec<[u32; 3]>;
    // Triangle ids must stay below the markers of [`EdgeMap::twins`] and the simulated
    // cache's miss count (at most 5 per triangle) within a u32; so many triangles (10 GiB
    // of indices) are out of reach of this greedy anyway.
    assert!(
        triangles.len() <= (u32::MAX / 5) as usize,
        "too many triangles to stripify"
    );
    let tris = if triangles.iter().all(distinct) {
        triangles
    } else {
        kept = triangles.iter().copied().filter(distinct).collect();
        &kept
    };
    let mut s = Stripper::new(tris, params);
    s.run();
    s.out
}

/// The greedy's state, in flat arrays sized once: the window is a small array of the
/// triangles themselves, the edge map rows hold what a lookup compares, and nothing is
/// allocated per triangle.
struct Stripper<'t> {
    tris: &'t [[u32; 3]],
    join: Join,
    window: usize,
    edges: EdgeMap,
    /// [`EdgeMap::twins`].
    twin: Vec<[u32; 2]>,
    used: Vec<bool>,
    /// Per vertex: unused triangles (the valence). Apart from `stamp` (the window's choice
    /// of a strip's first triangle reads only this, so it is kept small).
    vert: Vec<u8>,
    /// The exact valences, when some vertex has more than 255 triangles (`vert` then holds
    /// them capped at 255 and the window's choice reads these); None otherwise, the usual
    /// case, where the window's choice reads only `vert` (a quarter of the bytes, as
    /// meshoptimizer's 8-bit counters, but exact).
    big: Option<Vec<u32>>,
    /// Per vertex: when it last entered the simulated vertex cache (the number of cache
    /// misses then, 0 for never).
    stamp: Vec<u32>,
    /// The next `window` unused triangles of the input order, ascending: `[a, b, c, t]`.
    /// It holds exactly the unused triangles below `cursor`.
    buffer: Vec<[u32; 4]>,
    cursor: usize,
    /// Global order: triangles by their number of unused neighbours (0..=3), lazily.
    buckets: [Vec<u32>; 4],
    free_nb: Vec<u8>,
    /// A FIFO vertex cache over what was emitted, as the number of misses so far: a vertex
    /// is cached when it entered within the last [`CACHE`] misses (a FIFO evicts in the
    /// order of entry and a hit does not refresh). In the windowed order, a triangle
    /// outside the window continues a strip only when its new vertex is still cached.
    misses: u32,
    /// The same cache as the vertices it holds, oldest overwritten ([`RESTART`] for an
    /// empty entry): whether the new vertex of a triangle across an edge is cached is a
    /// compare of these few values, where `stamp` would be a scattered read for every
    /// edge tried (most fail).
    ring: [u32; CACHE],
    /// The entry of `ring` to overwrite next.
    ring_at: usize,
    out: Vec<u32>,
}

/// Entries of the simulated vertex cache: 12, a little under the FIFO 16 that ACMR is
/// measured with, so that a vertex the fallback relies on is still cached when it is
/// fetched again (16 and 24 lengthened strips on dragon_10k after meshoptimizer's cache
/// optimisation by a hair less than they cost: 1.7266 and 1.7278 indices per triangle
/// against meshoptimizer's 1.7262; 12 gives 1.7260).
const CACHE: usize = 12;

/// The rank of a triangle found outside the window: after every window position.
const OUTSIDE: u32 = u32::MAX;

impl<'t> Stripper<'t> {
    fn new(tris: &'t [[u32; 3]], params: &StripParams) -> Stripper<'t> {
        let vertices = tris
            .iter()
            .map(|t| t[0].max(t[1]).max(t[2]))
            .max()
            .map_or(0, |v| v as usize + 1);
        // A vertex numbered RESTART could not be told from a restart in the strip (and
        // `ring` marks empty entries with it).
        assert!(
            vertices <= RESTART as usize,
            "a vertex index equals RESTART"
        );
        let mut vert = vec![0u32; vertices];
        let edges = EdgeMap::new(tris, vertices, &mut vert);
        let twin = edges.twins();
        let mut s = Stripper {
            tris,
            join: params.join,
            window: params.window,
            edges,
            twin,
            used: vec![false; tris.len()],
            vert: vert.iter().map(|&v| v.min(255) as u8).collect(),
            big: vert.iter().any(|&v| v > 255).then_some(vert),
            stamp: vec![0; vertices],
            buffer: Vec::with_capacity(params.window),
            cursor: 0,
            buckets: Default::default(),
            free_nb: Vec::new(),
            misses: 0,
            ring: [RESTART; CACHE],
            ring_at: 0,
            // At most 4 indices per triangle with restarts (a restart and a strip of
            // one), 5 with degenerate joins: never reallocated.
            out: Vec::with_capacity(match params.join {
                Join::Restart => tris.len() * 4,
                Join::Degenerate => tris.len() * 5,
            }),
        };
        if s.window == 0 {
            s.free_nb = (0..tris.len()).map(|t| s.neighbours(t)).collect();
            for t in (0..tris.len()).rev() {
                s.buckets[s.free_nb[t] as usize].push(t as u32);
            }
        }
        s
    }

    /// Unused triangles across the edges of `t` (capped at 3).
    fn neighbours(&self, t: usize) -> u8 {
        let [a, b, c] = self.tris[t];
        [(b, a), (c, b), (a, c)]
            .iter()
            .enumerate()
            .filter(|&(k, &(x, y))| match self.twin[3 * t + k][0] {
                NONE => false,
                MANY => self.edges.find(&self.used, x, y).is_some(),
                u => !self.used[u as usize],
            })
            .count() as u8
    }

    /// Marks `t` used: out of the window, valences and neighbour counts down.
    // Always inlined: the compiler otherwise calls it (a few times per triangle, each
    // call reloading the state it reads).
    #[inline(always)]
    fn take(&mut self, t: u32) {
        self.used[t as usize] = true;
        if (t as usize) < self.cursor {
            if let Some(i) = self.buffer.iter().position(|x| x[3] == t) {
                self.buffer.remove(i);
            }
        }
        let tri = self.tris[t as usize];
        match &mut self.big {
            None => {
                for v in tri {
                    self.vert[v as usize] -= 1;
                }
            }
            Some(big) => {
                for v in tri {
                    big[v as usize] -= 1;
                    self.vert[v as usize] = big[v as usize].min(255) as u8;
                }
            }
        }
        if self.window == 0 {
            let [a, b, c] = tri;
            for (k, (x, y)) in [(b, a), (c, b), (a, c)].into_iter().enumerate() {
                match self.twin[3 * t as usize + k][0] {
                    NONE => {}
                    MANY => {
                        let (r, w) = key(x, y);
                        for i in 0..self.edges.row(r).len() {
                            let [o, _, c] = self.edges.row(r)[i];
                            let u = c / 3;
                            if o == w && !self.used[u as usize] {
                                self.drop_neighbour(u);
                            }
                        }
                    }
                    u => {
                        if !self.used[u as usize] {
                            self.drop_neighbour(u);
                        }
                    }
                }
            }
        }
    }

    /// One neighbour of `u` fewer unused (global order).
    #[inline]
    fn drop_neighbour(&mut self, u: u32) {
        let n = &mut self.free_nb[u as usize];
        *n = n.saturating_sub(1);
        self.buckets[*n as usize].push(u);
    }

    /// The first unused triangle with directed edge (e0, e1), where `t` has the edge
    /// (e1, e0): in the window first, then anywhere (in the windowed order, only one whose
    /// new vertex is cached). Returns (rank, triangle, third vertex); the rank orders
    /// window hits (by their triangle, as the window is ascending) before others
    /// ([`OUTSIDE`]).
    ///
    /// The window holds exactly the unused triangles below the cursor, so the first one in
    /// the window is the first unused one overall when it is below the cursor, and the
    /// edge's twin (or, for an edge with several, its row) gives that without scanning the
    /// window.
    // Always inlined: the compiler otherwise calls it (a few times per triangle, each
    // call reloading the state it reads).
    #[inline(always)]
    fn find(&self, t: u32, e0: u32, e1: u32) -> Option<(u32, u32, u32)> {
        let [a, b, c] = self.tris[t as usize];
        let k = if a == e1 && b == e0 {
            0
        } else if b == e1 && c == e0 {
            1
        } else if c == e1 && a == e0 {
            2
        } else {
            // Not an edge of t turned around (an inconsistently oriented neighbour).
            3
        };
        let [u, v] = if k < 3 {
            self.twin[3 * t as usize + k]
        } else {
            [MANY, 0]
        };
        let (u, v) = match u {
            NONE => return None,
            MANY => {
                let u = self.edges.find(&self.used, e0, e1)?;
                let [x, y, z] = self.tris[u as usize];
                (u, x ^ y ^ z ^ e0 ^ e1)
            }
            u => (u, v),
        };
        if (u as usize) < self.cursor {
            (!self.used[u as usize]).then_some((u, u, v))
        } else {
            ((self.window == 0 || self.cached(v)) && !self.used[u as usize])
                .then_some((OUTSIDE, u, v))
        }
    }

    /// Whether vertex `v` is in the simulated cache (`v` is not [`RESTART`]).
    #[inline]
    fn cached(&self, v: u32) -> bool {
        self.ring.iter().fold(false, |a, &x| a | (x == v))
    }

    /// Emits `v`, through the simulated vertex cache (its own vertices are read through
    /// `stamp`, whose entry the strip has just touched, rather than by a scan of `ring`
    /// right after writing it).
    #[inline]
    fn emit(&mut self, v: u32) {
        self.out.push(v);
        if v == RESTART {
            return;
        }
        let at = self.stamp[v as usize];
        if at == 0 || self.misses - at >= CACHE as u32 {
            self.misses += 1;
            self.stamp[v as usize] = self.misses;
            self.ring[self.ring_at] = v;
            self.ring_at = if self.ring_at + 1 == CACHE {
                0
            } else {
                self.ring_at + 1
            };
        }
    }

    #[inline]
    fn fill(&mut self) {
        while self.buffer.len() < self.window && self.cursor < self.tris.len() {
            let t = self.cursor;
            self.cursor += 1;
            if !self.used[t] {
                let [a, b, c] = self.tris[t];
                self.buffer.push([a, b, c, t as u32]);
            }
        }
    }

    /// The first triangle of a new strip, or None when all are used.
    fn first(&mut self) -> Option<u32> {
        if self.window > 0 {
            // meshoptimizer's findStripFirst: least valence of a corner in the window.
            return match &self.big {
                None => least(&self.buffer, &self.vert),
                Some(big) => least(&self.buffer, big),
            };
        }
        for k in 0..4 {
            while let Some(t) = self.buckets[k].pop() {
                if !self.used[t as usize] && self.free_nb[t as usize] as usize == k {
                    return Some(t);
                }
            }
        }
        None
    }

    fn run(&mut self) {
        let mut strip = [0u32; 2];
        let mut parity = 0u32;
        let mut next: Option<(u32, u32)> = None;
        loop {
            self.fill();
            if let Some((t, v)) = next {
                self.take(t);
                // The default outgoing edge of [a b c] is [b c]; a swap uses [a c].
                let cont = if parity == 1 {
                    self.find(t, strip[1], v)
                } else {
                    self.find(t, v, strip[1])
                };
                let swap = if cont.is_none() {
                    if parity == 1 {
                        self.find(t, v, strip[0])
                    } else {
                        self.find(t, strip[0], v)
                    }
                } else {
                    None
                };
                if let (None, Some((_, u, w))) = (cont, swap) {
                    // [a b c] => [a b a c]: the next triangle has the same winding.
                    self.emit(strip[0]);
                    self.emit(v);
                    strip[1] = v;
                    next = Some((u, w));
                } else {
                    self.emit(v);
                    strip[0] = strip[1];
                    strip[1] = v;
                    parity ^= 1;
                    next = cont.map(|(_, u, w)| (u, w));
                }
                continue;
            }
            let Some(t) = self.first() else {
                break;
            };
            self.take(t);
            let [mut a, mut b, mut c] = self.tris[t as usize];
            // Rotate so that the outgoing edge leads to a triangle (the nearest in rank).
            let ea = self.find(t, c, b);
            let eb = self.find(t, a, c);
            let ec = self.find(t, b, a);
            // The first of the least rank.
            let mut best: Option<(u32, usize, u32, u32)> = None;
            for (i, e) in [ea, eb, ec].into_iter().enumerate() {
                if let Some((rank, u, w)) = e {
                    if best.is_none_or(|b| rank < b.0) {
                        best = Some((rank, i, u, w));
                    }
                }
            }
            if let Some((_, i, u, w)) = best {
                if i == 1 {
                    (a, b, c) = (b, c, a);
                } else if i == 2 {
                    (a, b, c) = (c, a, b);
                }
                next = Some((u, w));
            }
            match self.join {
                Join::Restart => {
                    if !self.out.is_empty() {
                        self.emit(RESTART);
                    }
                    for x in [a, b, c] {
                        self.emit(x);
                    }
                    strip = [b, c];
                    parity = 1;
                }
                Join::Degenerate => {
                    if !self.out.is_empty() {
                        self.emit(strip[1]);
                        self.emit(a);
                    }
                    // Flip the first triangle by parity: the outgoing edge is "c b".
                    let (e0, e1) = if parity == 1 { (c, b) } else { (b, c) };
                    for x in [a, e0, e1] {
                        self.emit(x);
                    }
                    strip = [e0, e1];
                    parity ^= 1;
                }
            }
        }
    }
}

/// meshoptimizer's findStripFirst: the triangle of `buffer` (`[a, b, c, t]`) with a corner
/// of least valence, the first of them.
#[inline]
fn least<V: Copy + Ord>(buffer: &[[u32; 4]], valence: &[V]) -> Option<u32> {
    let mut best: Option<(V, u32)> = None;
    for &[a, b, c, t] in buffer {
        let v = valence[a as usize]
            .min(valence[b as usize])
            .min(valence[c as usize]);
        if best.is_none_or(|b| v < b.0) {
            best = Some((v, t));
        }
    }
    best.map(|b| b.1)
}

/// The triangles a strip draws (degenerate ones dropped), with their orientation;
/// [`RESTART`] starts a new strip.
pub fn unstripify(strip: &[u32]) -> Vec<[u32; 3]> {
    let mut out = Vec::with_capacity(strip.len());
    each_triangle(strip, |t| out.push(t));
    out
}

/// Calls `f` on every non-degenerate triangle of `strip`, in order, oriented.
#[inline]
pub fn each_triangle(strip: &[u32], mut f: impl FnMut([u32; 3])) {
    let mut start = 0;
    for i in 0..strip.len() {
        if strip[i] == RESTART {
            start = i + 1;
        } else if i - start >= 2 {
            let (mut a, mut b, c) = (strip[i - 2], strip[i - 1], strip[i]);
            if (i - start) & 1 == 1 {
                std::mem::swap(&mut a, &mut b);
            }
            if a != b && a != c && b != c {
                f([a, b, c]);
            }
        }
    }
}

/// Average cache miss ratio: vertex fetches missing a FIFO cache of `size` entries per
/// triangle drawn, over the index sequence as given ([`RESTART`] fetches nothing).
pub fn acmr(indices: &[u32], size: usize, triangles: usize) -> f64 {
    let mut fifo: std::collections::VecDeque<u32> = std::collections::VecDeque::with_capacity(size);
    let mut misses = 0usize;
    for &v in indices {
        if v == RESTART || fifo.contains(&v) {
            continue;
        }
        misses += 1;
        if fifo.len() == size {
            fifo.pop_front();
        }
        fifo.push_back(v);
    }
    misses as f64 / triangles.max(1) as f64
}

/// A triangle rotated so that its least vertex comes first (orientation kept), for
/// comparing triangle sets.
#[inline]
pub fn canonical(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

/// The triangles with three distinct vertices, canonical and sorted (a multiset).
pub fn triangle_set(tris: impl IntoIterator<Item = [u32; 3]>) -> Vec<[u32; 3]> {
    let mut v: Vec<[u32; 3]> = tris
        .into_iter()
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        .map(canonical)
        .collect();
    v.sort_unstable();
    v
}
