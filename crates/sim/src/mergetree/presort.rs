//! The insertion presorters of the partial-sort mode (\[P2\] §5.5).
//!
//! Input data are streamed into a small number of presorters, each sorting one
//! double-buffer-sized sub-block (2B elements, one merge queue of the partial-sort merge)
//! by insertion sort "at a rate of one compare-and-swap per cycle, plus one cycle of
//! overhead for each inner loop". Inserting an element into a sorted prefix therefore takes
//! `compares + 1` cycles, where `compares` counts the compare-and-swaps of its inner loop;
//! insertion starts as soon as an element arrives, so sorting overlaps reading. A sorted
//! sub-block is copied into its scratchpad slot at one element per cycle through the
//! scratchpad's single write port (shared by all presorters), once the merge of the
//! previous block has released the scratchpad.
//!
//! Reads land in a ring of `presort_slots` buffers of B elements in front of each
//! presorter, consumed in the order they were requested, so responses that return out of
//! order (a cycle-accurate DRAM) cannot mix sub-blocks.

use super::Elem;

/// What a presorter is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum PresortState {
    /// Inserting the elements of its current sub-block.
    Sorting,
    /// Copying its sorted sub-block to the scratchpad; `pos` elements done.
    Draining {
        /// Elements copied so far.
        pos: u32,
    },
    /// No sub-blocks left.
    Finished,
}

/// One insertion presorter with its read ring.
#[derive(Clone, Debug)]
pub(super) struct Presorter {
    /// Ring of `slots` read buffers of `b` elements.
    pub ring: Vec<Elem>,
    /// Elements delivered into each slot (valid once the read completed).
    pub slot_count: Vec<u32>,
    /// Read of the slot completed.
    pub slot_valid: Vec<bool>,
    /// Slot consumed next.
    pub head: u32,
    /// Slots whose data arrived and is not yet consumed (the machine counts a slot when
    /// its read completes; the reader keeps its own count of requested slots).
    pub used: u32,
    /// Next element inside the head slot.
    pub head_pos: u32,
    /// Global index of the sub-block being sorted.
    pub sub: u64,
    /// Partial-sort block of that sub-block.
    pub block: u64,
    /// Its length.
    pub sub_len: u32,
    /// Elements inserted so far.
    pub inserted: u32,
    /// The sort buffer (sorted prefix of `inserted` elements).
    pub buf: Vec<Elem>,
    /// First cycle after the insertion in progress.
    pub busy_until: u64,
    /// State.
    pub state: PresortState,
    /// Cycles spent inserting (counted when an insertion starts) or copying.
    pub busy_cycles: u64,
    /// Cycles waiting for read data.
    pub starved_cycles: u64,
}

impl Presorter {
    /// A presorter with `slots` ring buffers of `b` elements, starting at sub-block `first`.
    pub fn new(slots: u32, b: u32, first: u64) -> Self {
        Self {
            ring: vec![Elem::PAD; (slots * b) as usize],
            slot_count: vec![0; slots as usize],
            slot_valid: vec![false; slots as usize],
            head: 0,
            used: 0,
            head_pos: 0,
            sub: first,
            block: 0,
            sub_len: 0,
            inserted: 0,
            buf: Vec::with_capacity(2 * b as usize),
            busy_until: 0,
            state: PresortState::Sorting,
            busy_cycles: 0,
            starved_cycles: 0,
        }
    }

    /// Number of ring slots.
    pub fn slots(&self) -> u32 {
        self.slot_count.len() as u32
    }

    /// Allocates the next ring slot for a read; `None` when the ring is full.
    #[cfg(test)]
    pub fn alloc_slot(&mut self) -> Option<u32> {
        if self.used == self.slots() {
            return None;
        }
        let s = (self.head + self.used) % self.slots();
        self.used += 1;
        self.slot_valid[s as usize] = false;
        Some(s)
    }

    /// Takes the next delivered element from the ring, in request order.
    pub fn take(&mut self, b: u32) -> Option<Elem> {
        if self.used == 0 || !self.slot_valid[self.head as usize] {
            return None;
        }
        let h = self.head as usize;
        let e = self.ring[h * b as usize + self.head_pos as usize];
        self.head_pos += 1;
        if self.head_pos == self.slot_count[h] {
            self.head_pos = 0;
            self.slot_valid[h] = false;
            self.head = if self.head + 1 == self.slots() {
                0
            } else {
                self.head + 1
            };
            self.used -= 1;
        }
        Some(e)
    }

    /// Cycle `cycle` of sorting. Returns true when an insertion started (a change of
    /// state); a cycle inside an insertion changes nothing until `busy_until` (its busy
    /// cycles were counted when it started), so the machine may skip it.
    #[cfg(test)]
    pub fn tick_sort(&mut self, cycle: u64, b: u32) -> bool {
        if cycle < self.busy_until {
            return false;
        }
        if self.inserted == self.sub_len {
            return false;
        }
        self.insert_next(cycle, b)
    }

    /// Starts inserting the next element, if it has arrived.
    pub fn insert_next(&mut self, cycle: u64, b: u32) -> bool {
        let Some(e) = self.take(b) else {
            self.starved_cycles += 1;
            return false;
        };
        // Insertion: one compare-and-swap per cycle, plus one cycle for the inner loop. The
        // inner loop walks down from the end while the elements are greater than `e`, so
        // it shifts every greater element and, unless it reaches the front, stops on one
        // compare with an element not greater: found here by a binary search over the
        // sorted prefix, with the same count.
        let i = self.buf.len();
        let key = e.key();
        let pos = self.buf.partition_point(|x| x.key() <= key);
        let compares = (i - pos) as u32 + (pos > 0) as u32;
        self.buf.insert(pos, e);
        self.inserted += 1;
        // This cycle is the first of the `compares + 1`, all counted busy now.
        self.busy_until = cycle + compares as u64 + 1;
        self.busy_cycles += compares as u64 + 1;
        true
    }

    /// True when the sub-block is sorted and ready to copy at `cycle`.
    pub fn sorted(&self, cycle: u64) -> bool {
        self.state == PresortState::Sorting
            && cycle >= self.busy_until
            && self.inserted == self.sub_len
    }

    /// Starts sorting sub-block `sub` of `len` elements, in partial-sort block `block`.
    pub fn start(&mut self, sub: u64, len: u32, block: u64) {
        self.sub = sub;
        self.block = block;
        self.sub_len = len;
        self.inserted = 0;
        self.buf.clear();
        self.state = PresortState::Sorting;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Aabb;

    fn elem(k: u128) -> Elem {
        Elem::new(k as u64, 0, Aabb::EMPTY)
    }

    #[test]
    fn insertion_sort_cost_counts_compares_plus_one() {
        // b = 4, a sub-block of 4: deliver 3 1 2 0.
        let mut p = Presorter::new(2, 4, 0);
        p.start(0, 4, 0);
        let s = p.alloc_slot().unwrap();
        for (i, k) in [3u128, 1, 2, 0].into_iter().enumerate() {
            p.ring[s as usize * 4 + i] = elem(k);
        }
        p.slot_count[s as usize] = 4;
        p.slot_valid[s as usize] = true;
        let mut cycles = 0;
        while !p.sorted(cycles) {
            p.tick_sort(cycles, 4);
            cycles += 1;
        }
        // 3: 0 compares (1 cycle); 1: 1 compare, swap to front (2); 2: 2 compares (3);
        // 0: 3 compares to the front (4). Total 10.
        assert_eq!(cycles, 10);
        let keys: Vec<u64> = p.buf.iter().map(|e| e.code).collect();
        assert_eq!(keys, vec![0, 1, 2, 3]);
        assert_eq!(p.busy_cycles, 10);
    }

    #[test]
    fn ring_is_consumed_in_request_order() {
        let mut p = Presorter::new(2, 2, 0);
        p.start(0, 4, 0);
        let a = p.alloc_slot().unwrap();
        let b = p.alloc_slot().unwrap();
        assert!(p.alloc_slot().is_none());
        // The second read completes first: nothing may be taken until the first has.
        p.ring[b as usize * 2] = elem(7);
        p.ring[b as usize * 2 + 1] = elem(8);
        p.slot_count[b as usize] = 2;
        p.slot_valid[b as usize] = true;
        assert!(!p.tick_sort(0, 2));
        assert_eq!(p.starved_cycles, 1);
        p.ring[a as usize * 2] = elem(5);
        p.ring[a as usize * 2 + 1] = elem(6);
        p.slot_count[a as usize] = 2;
        p.slot_valid[a as usize] = true;
        let mut c = 1;
        while !p.sorted(c) {
            p.tick_sort(c, 2);
            c += 1;
        }
        assert_eq!(p.buf[0].code, 5);
        assert_eq!(p.used, 0);
    }
}
