//! Lists of strip (or corner) slots per vertex in flat arrays.

const NONE: u32 = u32::MAX;

/// Per vertex, a list of slots, each slot in at most one list: the first and last slot of
/// each list and the slot after each, in three flat arrays. Appending a slot and moving a
/// whole list to the end of another (a collapse of p into q) take O(1), with no
/// allocation per vertex or per move; the lists keep the order a `Vec` per vertex would
/// (appends at the end, a moved list after the receiving one's slots).
pub(crate) struct SlotLists {
    first: Vec<u32>,
    last: Vec<u32>,
    next: Vec<u32>,
}

impl SlotLists {
    /// Empty lists for `vertices` vertices over `slots` slots.
    pub(crate) fn new(vertices: usize, slots: usize) -> SlotLists {
        SlotLists {
            first: vec![NONE; vertices],
            last: vec![NONE; vertices],
            next: vec![NONE; slots],
        }
    }

    /// Appends slot `s` (in no list) to `v`'s list.
    #[inline]
    pub(crate) fn push(&mut self, v: u32, s: u32) {
        let v = v as usize;
        self.next[s as usize] = NONE;
        if self.first[v] == NONE {
            self.first[v] = s;
        } else {
            self.next[self.last[v] as usize] = s;
        }
        self.last[v] = s;
    }

    /// Moves `p`'s slots to the end of `q`'s list (p ≠ q).
    #[inline]
    pub(crate) fn append(&mut self, p: u32, q: u32) {
        let (p, q) = (p as usize, q as usize);
        if self.first[p] == NONE {
            return;
        }
        if self.first[q] == NONE {
            self.first[q] = self.first[p];
        } else {
            self.next[self.last[q] as usize] = self.first[p];
        }
        self.last[q] = self.last[p];
        self.first[p] = NONE;
        self.last[p] = NONE;
    }

    /// Empties `v`'s list (its slots are then in no list).
    #[inline]
    pub(crate) fn clear(&mut self, v: u32) {
        self.first[v as usize] = NONE;
        self.last[v as usize] = NONE;
    }

    /// The slots of `v`'s list, in order.
    #[inline]
    pub(crate) fn iter(&self, v: u32) -> impl Iterator<Item = u32> + '_ {
        let mut s = self.first[v as usize];
        std::iter::from_fn(move || {
            (s != NONE).then(|| {
                let x = s;
                s = self.next[x as usize];
                x
            })
        })
    }
}
