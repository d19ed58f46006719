//! The merge heap of \[P2\] §5.2: a pipelined heap (Bhagwan and Lin; Ioannou and Katevenis)
//! supporting insert and replace, with remove as a replace by +inf.
//!
//! Functionally it is a sequential binary min-heap of (sort key, queue) entries: the
//! pipelined hardware gives the same answers, only its timing differs, and the timing
//! (one operation per two cycles, \[P2\] §5.2) is enforced by the multi-merge unit that
//! issues the operations ([`super::merge`]). The capacity is the merge width M / (2B).

/// Key of a removed entry: above every element key, so it sinks to the bottom.
pub const INF_KEY: u128 = u128::MAX;

/// A binary min-heap of (key, queue) with a fixed capacity (no allocation after `new`).
#[derive(Clone, Debug)]
pub struct MergeHeap {
    entries: Vec<(u128, u32)>,
    /// Entries whose key is not [`INF_KEY`].
    live: usize,
}

impl MergeHeap {
    /// An empty heap with room for `capacity` entries.
    pub fn new(capacity: usize) -> Self {
        Self {
            entries: Vec::with_capacity(capacity),
            live: 0,
        }
    }

    /// Empties the heap (between merges).
    pub fn clear(&mut self) {
        self.entries.clear();
        self.live = 0;
    }

    /// Entries with a finite key.
    pub fn live(&self) -> usize {
        self.live
    }

    /// The smallest live entry.
    pub fn top(&self) -> Option<(u128, u32)> {
        match self.entries.first() {
            Some(&e) if e.0 != INF_KEY => Some(e),
            _ => None,
        }
    }

    /// Inserts an entry (sift up).
    pub fn insert(&mut self, key: u128, queue: u32) {
        debug_assert!(key != INF_KEY);
        self.entries.push((key, queue));
        self.live += 1;
        let mut i = self.entries.len() - 1;
        while i > 0 {
            let p = (i - 1) / 2;
            if self.entries[p].0 <= self.entries[i].0 {
                break;
            }
            self.entries.swap(p, i);
            i = p;
        }
    }

    /// Replaces the top entry by (key, queue) and restores the order (sift down).
    /// `key == INF_KEY` removes the top (\[P2\] §5.2: remove as replace with +inf).
    pub fn replace_top(&mut self, key: u128, queue: u32) {
        debug_assert!(self.live > 0);
        if key == INF_KEY {
            self.live -= 1;
        }
        let n = self.entries.len();
        self.entries[0] = (key, queue);
        let mut i = 0;
        loop {
            let l = 2 * i + 1;
            if l >= n {
                break;
            }
            let r = l + 1;
            let c = if r < n && self.entries[r].0 < self.entries[l].0 {
                r
            } else {
                l
            };
            if self.entries[i].0 <= self.entries[c].0 {
                break;
            }
            self.entries.swap(i, c);
            i = c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Merging sorted lists through the heap gives the globally sorted sequence.
        #[test]
        fn heap_merges_sorted_lists(mut lists in proptest::collection::vec(
            proptest::collection::vec(0u128..1000, 0..20), 1..12)) {
            for l in &mut lists { l.sort(); }
            let mut h = MergeHeap::new(lists.len());
            let mut pos = vec![0usize; lists.len()];
            for (q, l) in lists.iter().enumerate() {
                if let Some(&k) = l.first() { h.insert(k, q as u32); pos[q] = 1; }
            }
            let mut out = Vec::new();
            while let Some((k, q)) = h.top() {
                out.push(k);
                let q = q as usize;
                let next = lists[q].get(pos[q]).copied().unwrap_or(INF_KEY);
                pos[q] += 1;
                h.replace_top(next, q as u32);
            }
            let mut all: Vec<u128> = lists.concat();
            all.sort();
            prop_assert_eq!(out, all);
            prop_assert_eq!(h.live(), 0);
        }
    }
}
