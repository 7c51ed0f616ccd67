//! An indexed binary min-heap over a fixed set of slots (the engine's face corners, each
//! standing for the edge from its vertex to the next corner's): every slot is in the heap at
//! most once, with its current key, and a key can be changed or removed in place. The
//! collapse engine used a lazy heap before (a new entry per changed edge, stale ones
//! skipped when popped): nine in ten pops were stale and the pops were a third of the run.
//!
//! Hand-written: the crates with decrease-key (`priority-queue`, `keyed_priority_queue`)
//! hash their keys; the slots here are dense integers, so a flat position array does.
//!
//! Four children per node (half the levels of a binary heap: a pop's walk down, the larger
//! part of the heap's time, misses the cache at half as many levels, and a node's four
//! children are 64 contiguous bytes). Entries are totally ordered by (key, slot), so which
//! entry comes out first never depends on the heap's shape.

const NONE: u32 = u32::MAX;

/// Children per node.
const ARITY: usize = 4;

/// Per slot: its position in the heap (or NONE) and the low half of its key (the tie
/// break), side by side so that one cache line serves both.
#[derive(Debug, Clone, Copy)]
struct SlotInfo {
    tie: u64,
    at: u32,
}

/// A min-heap of (key, slot) with at most one entry per slot. Keys are u128; an entry
/// holds only the key's high half (the cost) and its slot, 16 bytes, and the low half (the
/// tie break) is read from the slot's record when two high halves are equal: half the
/// bytes per level of a sift of the 32-byte (u128, u32) entries before.
#[derive(Debug, Default)]
pub(crate) struct IndexedHeap {
    items: Vec<(u64, u32)>,
    slots: Vec<SlotInfo>,
}

impl IndexedHeap {
    /// A heap of the given entries (each slot below `slots`, at most once).
    pub(crate) fn from_entries(slots: usize, items: Vec<(u128, u32)>) -> IndexedHeap {
        let mut h = IndexedHeap {
            items: Vec::with_capacity(items.len()),
            slots: vec![SlotInfo { tie: 0, at: NONE }; slots],
        };
        for (i, &(k, s)) in items.iter().enumerate() {
            h.items.push(((k >> 64) as u64, s));
            h.slots[s as usize] = SlotInfo {
                tie: k as u64,
                at: i as u32,
            };
        }
        for i in (0..h.items.len().div_ceil(ARITY)).rev() {
            h.down(i);
        }
        h
    }

    /// Entries in the heap.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether entry x orders before entry y: by the key's high half, then its low half,
    /// then the slot.
    #[inline]
    fn less(&self, x: (u64, u32), y: (u64, u32)) -> bool {
        x.0 < y.0
            || (x.0 == y.0
                && (self.slots[x.1 as usize].tie, x.1) < (self.slots[y.1 as usize].tie, y.1))
    }

    /// Puts `slot` in with `key`, or changes its key.
    pub(crate) fn set(&mut self, slot: u32, key: u128) {
        let info = self.slots[slot as usize];
        let x = ((key >> 64) as u64, slot);
        if info.at == NONE {
            self.slots[slot as usize].tie = key as u64;
            self.items.push(x);
            let i = self.items.len() - 1;
            self.slots[slot as usize].at = i as u32;
            self.up(i);
        } else {
            let i = info.at as usize;
            // Same slot: the keys alone decide.
            let smaller = key < ((self.items[i].0 as u128) << 64 | info.tie as u128);
            self.slots[slot as usize].tie = key as u64;
            self.items[i].0 = x.0;
            self.sift(i, smaller);
        }
    }

    /// Takes `slot` out, if it is in.
    pub(crate) fn remove(&mut self, slot: u32) {
        let i = self.slots[slot as usize].at;
        if i == NONE {
            return;
        }
        let i = i as usize;
        self.slots[slot as usize].at = NONE;
        let last = self.items.pop().expect("a slot in the heap");
        if i < self.items.len() {
            let old = self.items[i];
            // `old` is out of the heap but its tie is still in its record.
            let smaller = self.less(last, old);
            self.place(i, last);
            self.sift(i, smaller);
        }
    }

    /// Whether `slot` is in the heap.
    #[inline]
    pub(crate) fn contains(&self, slot: u32) -> bool {
        self.slots[slot as usize].at != NONE
    }

    /// Takes `old` (which must be in the heap) out and puts `slot` (which must not be) in
    /// with `key`, in `old`'s place: one sift where [`IndexedHeap::remove`] and
    /// [`IndexedHeap::set`] take two. The entries are those of the two calls, so what comes
    /// out, and in which order, is the same.
    pub(crate) fn replace(&mut self, old: u32, slot: u32, key: u128) {
        let i = self.slots[old as usize].at;
        debug_assert!(i != NONE && !self.contains(slot));
        let i = i as usize;
        self.slots[old as usize].at = NONE;
        let was = self.items[i];
        self.slots[slot as usize].tie = key as u64;
        let x = ((key >> 64) as u64, slot);
        // `was` is out of the heap but its tie is still in its record.
        let smaller = self.less(x, was);
        self.place(i, x);
        self.sift(i, smaller);
    }

    /// Takes out the entry of least key.
    pub(crate) fn pop(&mut self) -> Option<(u128, u32)> {
        let top = *self.items.first()?;
        let key = (top.0 as u128) << 64 | self.slots[top.1 as usize].tie as u128;
        self.remove(top.1);
        Some((key, top.1))
    }

    fn up(&mut self, mut i: usize) {
        let x = self.items[i];
        while i > 0 {
            let p = (i - 1) / ARITY;
            if !self.less(x, self.items[p]) {
                break;
            }
            self.place(i, self.items[p]);
            i = p;
        }
        self.place(i, x);
    }

    fn down(&mut self, mut i: usize) {
        let x = self.items[i];
        let n = self.items.len();
        loop {
            let first = ARITY * i + 1;
            if first >= n {
                break;
            }
            let mut c = first;
            for j in first + 1..(first + ARITY).min(n) {
                if self.less(self.items[j], self.items[c]) {
                    c = j;
                }
            }
            if !self.less(self.items[c], x) {
                break;
            }
            self.place(i, self.items[c]);
            i = c;
        }
        self.place(i, x);
    }

    /// Stores entry `x` at position `i` and records where its slot now is.
    #[inline]
    fn place(&mut self, i: usize, x: (u64, u32)) {
        self.items[i] = x;
        self.slots[x.1 as usize].at = i as u32;
    }

    /// Restores the heap order at `i` after its key changed: up when it got smaller.
    fn sift(&mut self, i: usize, smaller: bool) {
        if smaller {
            self.up(i);
        } else {
            self.down(i);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::IndexedHeap;
    use proptest::prelude::*;
    use std::collections::BTreeMap;

    proptest! {
        /// Against the obvious twin: a map slot → key, popping the least (key, slot).
        #[test]
        fn the_heap_equals_a_sorted_map(
            init in proptest::collection::btree_map(0u32..64, 0u128..50, 0..40),
            ops in proptest::collection::vec((0u8..4, 0u32..64, 0u128..50), 0..200),
        ) {
            // Keys with both halves in play: the high one decides, the low one breaks ties.
            let spread = |k: u128| (k / 10) << 64 | (k % 10);
            let init: BTreeMap<u32, u128> = init.into_iter().map(|(s, k)| (s, spread(k))).collect();
            let mut twin: BTreeMap<u32, u128> = init.clone();
            let mut h = IndexedHeap::from_entries(64, init.iter().map(|(&s, &k)| (k, s)).collect());
            for (op, slot, key) in ops {
                let key = spread(key);
                match op {
                    0 => { h.set(slot, key); twin.insert(slot, key); }
                    3 => {
                        // Replace the least slot in the heap by `slot`, when it is not in.
                        if let Some(&old) = twin.keys().nth(key as usize % twin.len().max(1)) {
                            if !twin.contains_key(&slot) {
                                h.replace(old, slot, key);
                                twin.remove(&old);
                                twin.insert(slot, key);
                            }
                        }
                    }
                    1 => { h.remove(slot); twin.remove(&slot); }
                    _ => {
                        // Equal keys come out in slot order: the least (key, slot).
                        let want = twin.iter().map(|(&s, &k)| (k, s)).min();
                        let got = h.pop();
                        prop_assert_eq!(got, want);
                        if let Some((_, s)) = got {
                            twin.remove(&s);
                        }
                    }
                }
                prop_assert_eq!(h.len(), twin.len());
            }
        }
    }
}
