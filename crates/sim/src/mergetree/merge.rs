//! The multi-merge unit of \[P2\] §5.3 with its scratchpad, in both operating modes.
//!
//! The scratchpad of M elements is organised as M / (2B) double-buffered queues, one per
//! block (sorted run) being merged. The heap holds only (sort key, queue) entries; the
//! elements stay in the scratchpad. Steady state follows the even/odd schedule of
//! \[P2\] Fig. 4: on an even cycle the heap top's successor in its queue is read from the
//! scratchpad, on the odd cycle it replaces the heap top and the top element itself is
//! read, and on the next even cycle that element goes to the output FIFO. So one element
//! leaves per two cycles, and the heap sees one operation per two cycles (\[P2\] §5.2).
//! The model applies each element's output and heap replace in its even cycle; the fixed
//! one-cycle latency of the output write is not modelled.
//!
//! Stalls (\[P2\] §5.3): when the successor lies in the other half of a double buffer whose
//! read has not completed ("queue dry"), or when the output FIFO is full. When a buffer
//! half is consumed, its refill is queued to the reader; when a run's last element leaves,
//! the heap top is removed (replace with +inf). At the start of a merge, the head of each
//! queue is inserted (one insert per two cycles) as soon as its first buffer has arrived.
//!
//! Partial-sort mode (\[P2\] §5.5): each queue is one presorted sub-block of 2B elements
//! that is "the final one in its block": nothing is refilled.

use std::collections::VecDeque;

use super::heap::{MergeHeap, INF_KEY};
use super::Elem;

/// One double-buffered queue of the scratchpad.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Queue {
    /// Scratchpad offsets of the two buffer halves.
    pub base: [u32; 2],
    /// Elements in each half.
    pub count: [u32; 2],
    /// Data of each half present.
    pub valid: [bool; 2],
    /// Half being consumed.
    pub cur: usize,
    /// Next element inside the current half.
    pub idx: u32,
    /// First element of the run in the source region.
    pub run_start: u64,
    /// Elements of the run.
    pub run_len: u64,
    /// Elements of the run requested from DRAM so far.
    pub fetched: u64,
    /// Elements of the run output so far.
    pub consumed: u64,
}

/// State of the merge in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum MergeState {
    /// No merge set up.
    Idle,
    /// Inserting queue heads into the heap.
    Init,
    /// Steady state.
    Merge,
    /// Every element of the merge has left.
    Done,
}

/// Why the multi-merge unit did not output an element in an operation slot: its stall
/// cycles by reason, from its activity intervals (the machine fills it in).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MergeStalls {
    /// Operation slots lost because the successor's buffer half had not arrived.
    pub queue_dry_cycles: u64,
    /// Cycles lost because the output FIFO was full.
    pub output_full_cycles: u64,
    /// Cycles of heap initialization waiting for a queue's first buffer.
    pub init_wait_cycles: u64,
}

/// The multi-merge unit: scratchpad, queues and heap.
#[derive(Clone, Debug)]
pub(super) struct Merger {
    /// The scratchpad, M elements.
    pub scratch: Vec<Elem>,
    /// Queues of the current merge (capacity M / (2B)).
    pub queues: Vec<Queue>,
    /// The heap.
    pub heap: MergeHeap,
    /// State.
    pub state: MergeState,
    /// First cycle at which the next heap operation may start.
    pub next_op: u64,
    /// Next queue whose head is inserted during initialization.
    pub init_q: u32,
    /// Buffer length B.
    pub b: u32,
    /// Elements output.
    pub outputs: u64,
    /// Heap operations (inserts and replaces).
    pub ops: u64,
}

impl Merger {
    /// A merger with an M-element scratchpad and buffers of `b`.
    pub fn new(m: u32, b: u32) -> Self {
        let fan_in = (m / (2 * b)) as usize;
        Self {
            scratch: vec![Elem::PAD; m as usize],
            queues: Vec::with_capacity(fan_in),
            heap: MergeHeap::new(fan_in),
            state: MergeState::Idle,
            next_op: 0,
            init_q: 0,
            b,
            outputs: 0,
            ops: 0,
        }
    }

    /// Sets up a partial-sort merge of the sub-blocks `lens` (already in the scratchpad,
    /// sub-block `q` at offset `q * 2B`).
    pub fn setup_partial(&mut self, lens: impl Iterator<Item = u32>, cycle: u64) {
        self.queues.clear();
        self.heap.clear();
        for (q, len) in lens.enumerate() {
            let base = q as u32 * 2 * self.b;
            self.queues.push(Queue {
                base: [base, base + self.b],
                count: [len, 0],
                valid: [true, false],
                run_len: len as u64,
                fetched: len as u64,
                ..Queue::default()
            });
        }
        self.begin(cycle);
    }

    /// Sets up a multi-merge of the runs `(start, len)`; the initial reads are queued to
    /// `refill` (first halves of all queues, then second halves).
    pub fn setup_multi(
        &mut self,
        runs: impl Iterator<Item = (u64, u64)>,
        refill: &mut VecDeque<u32>,
        cycle: u64,
    ) {
        self.queues.clear();
        self.heap.clear();
        for (q, (start, len)) in runs.enumerate() {
            let base = q as u32 * 2 * self.b;
            self.queues.push(Queue {
                base: [base, base + self.b],
                run_start: start,
                run_len: len,
                ..Queue::default()
            });
        }
        for half in 0..2u64 {
            for (q, queue) in self.queues.iter().enumerate() {
                if queue.run_len > half * self.b as u64 {
                    refill.push_back(q as u32 * 2 + half as u32);
                }
            }
        }
        self.begin(cycle);
    }

    fn begin(&mut self, cycle: u64) {
        self.init_q = 0;
        self.state = MergeState::Init;
        self.next_op = self.next_op.max(cycle);
    }

    /// The next read for buffer half `buf` (queue `buf / 2`, half `buf % 2`): position in
    /// the source region and element count.
    pub fn peek_fetch(&self, buf: u32) -> (u64, u32) {
        let q = &self.queues[(buf / 2) as usize];
        let count = (q.run_len - q.fetched).min(self.b as u64) as u32;
        (q.run_start + q.fetched, count)
    }

    /// The read of [`Self::peek_fetch`] was issued.
    pub fn commit_fetch(&mut self, buf: u32, count: u32) {
        self.queues[(buf / 2) as usize].fetched += count as u64;
    }

    /// A read for buffer `buf` completed with `count` elements, element `k` being `elem(k)`.
    pub fn fill_with(&mut self, buf: u32, count: usize, mut elem: impl FnMut(usize) -> Elem) {
        let q = &mut self.queues[(buf / 2) as usize];
        let h = (buf % 2) as usize;
        let base = q.base[h] as usize;
        for (k, slot) in self.scratch[base..base + count].iter_mut().enumerate() {
            *slot = elem(k);
        }
        q.count[h] = count as u32;
        q.valid[h] = true;
    }

    /// One cycle with the outputs behind `out`: what happened in the operation slot.
    #[inline]
    pub fn tick_with(&mut self, cycle: u64, out: &mut impl MergeOut) -> Slot {
        if cycle < self.next_op || matches!(self.state, MergeState::Idle | MergeState::Done) {
            return Slot::Closed;
        }
        self.operate(cycle, out)
    }

    /// The operation slot at `cycle`, once it is open.
    fn operate(&mut self, cycle: u64, out: &mut impl MergeOut) -> Slot {
        match self.state {
            MergeState::Idle | MergeState::Done => Slot::Closed,
            MergeState::Init => {
                let nq = self.queues.len() as u32;
                if self.init_q == nq {
                    self.state = MergeState::Merge;
                    return self.operate(cycle, out);
                }
                let q = &self.queues[self.init_q as usize];
                if q.run_len == 0 {
                    self.init_q += 1;
                    return Slot::Worked;
                }
                if !q.valid[0] {
                    return Slot::InitWait;
                }
                let key = self.scratch[q.base[0] as usize].key();
                self.heap.insert(key, self.init_q);
                self.init_q += 1;
                self.ops += 1;
                self.next_op = cycle + 2;
                Slot::Worked
            }
            MergeState::Merge => {
                let Some((_, qi)) = self.heap.top() else {
                    self.state = MergeState::Done;
                    return Slot::Worked;
                };
                let q = self.queues[qi as usize];
                let pos = (q.base[q.cur] + q.idx) as usize;
                let succ_key = if q.idx + 1 < q.count[q.cur] {
                    self.scratch[pos + 1].key()
                } else if q.consumed + 1 < q.run_len {
                    let other = 1 - q.cur;
                    if !q.valid[other] {
                        return Slot::QueueDry;
                    }
                    self.scratch[q.base[other] as usize].key()
                } else {
                    INF_KEY
                };
                if out.is_full() {
                    return Slot::OutputFull;
                }
                out.push(self.scratch[pos]);
                self.heap.replace_top(succ_key, qi);
                self.outputs += 1;
                self.ops += 1;
                let q = &mut self.queues[qi as usize];
                q.consumed += 1;
                if q.idx + 1 < q.count[q.cur] {
                    q.idx += 1;
                } else {
                    // The half is used up: release it and refill it if the run has more.
                    q.valid[q.cur] = false;
                    if q.fetched < q.run_len {
                        out.refill(qi * 2 + q.cur as u32);
                    }
                    q.cur = 1 - q.cur;
                    q.idx = 0;
                }
                self.next_op = cycle + 2;
                if self.heap.live() == 0 {
                    self.state = MergeState::Done;
                }
                Slot::Worked
            }
        }
    }
}

/// What happened in an operation slot of the multi-merge unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Slot {
    /// No merge, or the slot is not open yet.
    Closed,
    /// An insert, a replace or a state change.
    Worked,
    /// The successor's buffer half has not arrived.
    QueueDry,
    /// The output FIFO is full.
    OutputFull,
    /// Initialization waits for a queue's first buffer.
    InitWait,
}

/// Where the multi-merge unit's elements and refill requests go.
pub(super) trait MergeOut {
    /// True when the output FIFO has no room.
    fn is_full(&self) -> bool;
    /// Outputs an element (room was checked).
    fn push(&mut self, e: Elem);
    /// Buffer half `buf` was used up and its run has more: refill it.
    fn refill(&mut self, buf: u32);
}
