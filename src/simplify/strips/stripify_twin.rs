//! The stripifier as first written (a Vec of triangle ids for the window, the triangles
//! read through their ids, the cache searched by value): the slow twin that the flat
//! [`super::stripify::stripify`] must match index for index.

use super::stripify::{Join, StripParams, RESTART};

/// Triangles by vertex (compressed rows: the corners 3t + k with t[k] = v, ascending), to
/// find the triangles of a directed edge by scanning the fan of its first vertex.
struct EdgeMap {
    start: Vec<u32>,
    corners: Vec<u32>,
}

impl EdgeMap {
    fn new(tris: &[[u32; 3]], vertices: usize) -> EdgeMap {
        let mut start = vec![0u32; vertices + 1];
        for t in tris {
            for &v in t {
                start[v as usize + 1] += 1;
            }
        }
        for v in 0..vertices {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut corners = vec![0u32; tris.len() * 3];
        for (t, tri) in tris.iter().enumerate() {
            for (k, &v) in tri.iter().enumerate() {
                corners[fill[v as usize] as usize] = (3 * t + k) as u32;
                fill[v as usize] += 1;
            }
        }
        EdgeMap { start, corners }
    }

    /// The corners of vertex `v`.
    #[inline]
    fn fan(&self, v: u32) -> &[u32] {
        &self.corners[self.start[v as usize] as usize..self.start[v as usize + 1] as usize]
    }

    /// The first unused triangle with directed edge (e0, e1), and its third vertex.
    #[inline]
    fn find(&self, tris: &[[u32; 3]], used: &[bool], e0: u32, e1: u32) -> Option<(u32, u32)> {
        self.fan(e0).iter().find_map(|&c| {
            let (t, k) = (c as usize / 3, c as usize % 3);
            (!used[t] && tris[t][(k + 1) % 3] == e1).then(|| (t as u32, tris[t][(k + 2) % 3]))
        })
    }
}

/// In `buffer` (triangle ids), the first triangle with directed edge (e0, e1): its
/// position in the buffer and its third vertex (meshoptimizer's `findStripNext`).
fn find_in(buffer: &[u32], tris: &[[u32; 3]], e0: u32, e1: u32) -> Option<(usize, u32)> {
    buffer.iter().enumerate().find_map(|(i, &t)| {
        let [a, b, c] = tris[t as usize];
        if e0 == a && e1 == b {
            Some((i, c))
        } else if e0 == b && e1 == c {
            Some((i, a))
        } else if e0 == c && e1 == a {
            Some((i, b))
        } else {
            None
        }
    })
}

/// The strips of `triangles` (triangles with a repeated vertex are left out: they draw
/// nothing). Every other triangle is drawn exactly once, with its orientation.
pub(super) fn stripify_twin(triangles: &[[u32; 3]], params: &StripParams) -> Vec<u32> {
    let tris: Vec<[u32; 3]> = triangles
        .iter()
        .copied()
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        .collect();
    let mut s = Stripper::new(&tris, params);
    s.run();
    s.out
}

struct Stripper<'t> {
    tris: &'t [[u32; 3]],
    join: Join,
    window: usize,
    edges: EdgeMap,
    used: Vec<bool>,
    valence: Vec<u32>,
    buffer: Vec<u32>,
    cursor: usize,
    /// Global order: triangles by their number of unused neighbours (0..=3), lazily.
    buckets: [Vec<u32>; 4],
    free_nb: Vec<u8>,
    /// A FIFO vertex cache over what was emitted: in the windowed order, a triangle
    /// outside the window continues a strip only when its new vertex is still cached.
    cache: [u32; CACHE],
    cache_at: usize,
    out: Vec<u32>,
}

/// Entries of the simulated vertex cache: 12, a little under the FIFO 16 that ACMR is
/// measured with, so that a vertex the fallback relies on is still cached when it is
/// fetched again (16 and 24 lengthened strips on dragon_10k after meshoptimizer's cache
/// optimisation by a hair less than they cost: 1.7266 and 1.7278 indices per triangle
/// against meshoptimizer's 1.7262; 12 gives 1.7260).
const CACHE: usize = 12;

impl<'t> Stripper<'t> {
    fn new(tris: &'t [[u32; 3]], params: &StripParams) -> Stripper<'t> {
        let vertices = tris.iter().flatten().max().map_or(0, |&v| v as usize + 1);
        let edges = EdgeMap::new(tris, vertices);
        let mut valence = vec![0u32; vertices];
        for t in tris {
            for &v in t {
                valence[v as usize] += 1;
            }
        }
        let mut s = Stripper {
            tris,
            join: params.join,
            window: params.window,
            edges,
            used: vec![false; tris.len()],
            valence,
            buffer: Vec::with_capacity(params.window),
            cursor: 0,
            buckets: Default::default(),
            free_nb: Vec::new(),
            cache: [RESTART; CACHE],
            cache_at: 0,
            out: Vec::with_capacity(tris.len() * 2),
        };
        if s.window == 0 {
            s.free_nb = (0..tris.len()).map(|t| s.neighbours(t as u32)).collect();
            for t in (0..tris.len()).rev() {
                s.buckets[s.free_nb[t] as usize].push(t as u32);
            }
        }
        s
    }

    /// Unused triangles across the edges of `t` (capped at 3).
    fn neighbours(&self, t: u32) -> u8 {
        let [a, b, c] = self.tris[t as usize];
        let n = [(b, a), (c, b), (a, c)]
            .iter()
            .filter(|&&(x, y)| self.edges.find(self.tris, &self.used, x, y).is_some())
            .count();
        n as u8
    }

    /// Marks `t` used: out of the window, valences and neighbour counts down.
    fn take(&mut self, t: u32) {
        self.used[t as usize] = true;
        if let Some(i) = self.buffer.iter().position(|&x| x == t) {
            self.buffer.remove(i);
        }
        let tri = self.tris[t as usize];
        for v in tri {
            self.valence[v as usize] -= 1;
        }
        if self.window == 0 {
            let [a, b, c] = tri;
            for (x, y) in [(b, a), (c, b), (a, c)] {
                for &cnr in self.edges.fan(x) {
                    let (u, k) = (cnr as usize / 3, cnr as usize % 3);
                    if !self.used[u] && self.tris[u][(k + 1) % 3] == y {
                        let n = &mut self.free_nb[u];
                        *n = n.saturating_sub(1);
                        self.buckets[*n as usize].push(u as u32);
                    }
                }
            }
        }
    }

    /// The triangle with directed edge (e0, e1): in the window first, then anywhere (in
    /// the windowed order, only one whose new vertex is cached).
    /// Returns (rank, triangle, third vertex); the rank orders window hits before others.
    fn find(&self, e0: u32, e1: u32) -> Option<(usize, u32, u32)> {
        if let Some((i, v)) = find_in(&self.buffer, self.tris, e0, e1) {
            return Some((i, self.buffer[i], v));
        }
        self.edges
            .find(self.tris, &self.used, e0, e1)
            .filter(|&(_, v)| self.window == 0 || self.cache.contains(&v))
            .map(|(t, v)| (self.window, t, v))
    }

    /// Emits `v`, through the simulated vertex cache.
    #[inline]
    fn emit(&mut self, v: u32) {
        self.out.push(v);
        if v != RESTART && !self.cache.contains(&v) {
            self.cache[self.cache_at] = v;
            self.cache_at = (self.cache_at + 1) % CACHE;
        }
    }

    fn fill(&mut self) {
        while self.buffer.len() < self.window && self.cursor < self.tris.len() {
            let t = self.cursor as u32;
            self.cursor += 1;
            if !self.used[t as usize] {
                self.buffer.push(t);
            }
        }
    }

    /// The first triangle of a new strip, or None when all are used.
    fn first(&mut self) -> Option<u32> {
        if self.window > 0 {
            // meshoptimizer's findStripFirst: least valence of a corner in the window.
            let mut best: Option<(u32, u32)> = None;
            for &t in &self.buffer {
                let v = self.tris[t as usize]
                    .iter()
                    .map(|&v| self.valence[v as usize])
                    .min()
                    .unwrap_or(0);
                if best.is_none_or(|b| v < b.0) {
                    best = Some((v, t));
                }
            }
            return best.map(|b| b.1);
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
                    self.find(strip[1], v)
                } else {
                    self.find(v, strip[1])
                };
                let swap = if cont.is_none() {
                    if parity == 1 {
                        self.find(v, strip[0])
                    } else {
                        self.find(strip[0], v)
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
            let ea = self.find(c, b);
            let eb = self.find(a, c);
            let ec = self.find(b, a);
            let mine = [ea, eb, ec].iter().flatten().map(|x| x.0).min();
            if ea.is_some_and(|x| Some(x.0) == mine) {
                next = ea.map(|x| (x.1, x.2));
            } else if eb.is_some_and(|x| Some(x.0) == mine) {
                (a, b, c) = (b, c, a);
                next = eb.map(|x| (x.1, x.2));
            } else if ec.is_some_and(|x| Some(x.0) == mine) {
                (a, b, c) = (c, a, b);
                next = ec.map(|x| (x.1, x.2));
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
