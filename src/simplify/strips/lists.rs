//! Lists of strip (or corner) slots per vertex in flat arrays.

const NONE: u32 = u32::MAX;

/// Per vertex, the slots that show it while vertices are merged one into another in a
/// sequence known in advance (a collapse of p into q moves p's slots to the end of q's
/// list, and p receives none afterwards), as one contiguous range of a single array.
///
/// Moving a whole list to the end of another keeps every list at every time contiguous in
/// the final concatenation: p's list lands right after q's slots of the moment, and a later
/// move of q carries both. So the lists are laid out once, by a counting sort (each
/// vertex's own slots, ascending, then the lists merged into it in the order of the
/// merges), and p's list when it is merged is a range read in memory order, where lists
/// linked through the slots (as a `Vec` per vertex would keep them, the same order) are
/// one scattered read per slot.
pub(crate) struct MergeLists {
    /// Per vertex: where its range starts.
    start: Vec<u32>,
    /// Per vertex: its list's length when it is merged (its final length for a vertex
    /// never merged).
    len: Vec<u32>,
    slots: Vec<u32>,
}

impl MergeLists {
    /// `slot_vertex[s]` is the vertex slot `s` shows at first (`skip` for a slot in no
    /// list, e.g. a restart); `merges` are the (p, q) in order, each p merged once and not
    /// before any merge into it. Every vertex is below `vertices`.
    pub(crate) fn new(
        slot_vertex: &[u32],
        skip: u32,
        vertices: usize,
        merges: &[(u32, u32)],
    ) -> MergeLists {
        let mut len = vec![0u32; vertices];
        for &v in slot_vertex {
            if v != skip {
                len[v as usize] += 1;
            }
        }
        // Where each p lands in its q's list, relative to q's start.
        let mut at = vec![NONE; vertices];
        for &(p, q) in merges {
            at[p as usize] = len[q as usize];
            len[q as usize] += len[p as usize];
        }
        let mut start = vec![0u32; vertices];
        let mut sum = 0u32;
        for v in 0..vertices {
            if at[v] == NONE {
                start[v] = sum;
                sum += len[v];
            }
        }
        for &(p, q) in merges.iter().rev() {
            start[p as usize] = start[q as usize] + at[p as usize];
        }
        // The own slots of each vertex at the head of its range, ascending.
        at.copy_from_slice(&start);
        let mut slots = vec![0u32; sum as usize];
        for (s, &v) in slot_vertex.iter().enumerate() {
            if v != skip {
                let a = &mut at[v as usize];
                slots[*a as usize] = s as u32;
                *a += 1;
            }
        }
        MergeLists { start, len, slots }
    }

    /// The slots of `v`'s list when it is merged (at the end for a vertex never merged),
    /// in the order the moves give them.
    #[inline]
    pub(crate) fn get(&self, v: u32) -> &[u32] {
        let s = self.start[v as usize] as usize;
        &self.slots[s..s + self.len[v as usize] as usize]
    }
}
