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
//!
//! Forecasting (`read_schedule = forecast`, the alternative \[P1\] §4.2 and \[P2\] §7
//! propose; Knuth's forecasting for external merge sort): in the multi-merge passes the
//! scratchpad is a pool of M / B buffers of B elements, one per run being merged plus
//! `forecast_spares` spares. Each run holds a chain of buffers in run order (the front one
//! is being consumed). A second heap, the forecast heap, holds for each run with elements
//! left in DRAM the key of the last element of its newest buffer: the run with the
//! smallest such key is the one whose buffered elements run out first, so whenever a
//! buffer is free it is given to that run's next block (one read in flight per run: a
//! run leaves the forecast heap when its read is issued and comes back when the data
//! arrives, keyed by the new block's last element). A buffer is freed when its last
//! element leaves. The merge heap and the even/odd schedule are those of double
//! buffering; the merge stalls ("queue dry") when a run's front buffer is used up and its
//! next one has not arrived. Reads take hundreds of cycles, so the forecast is made with
//! the runs whose reads are in flight missing from it, and a free buffer can go to a run
//! needed later than one of those; should the merge then wait on a run with no block
//! coming while every buffer holds data, the prefetched block needed last is dropped and
//! read again later (`Forecast::evictions`, extra traffic the report counts).

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

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

/// The buffer pool and the forecast heap of forecasting read scheduling.
#[derive(Clone, Debug)]
pub(super) struct Forecast {
    /// Free buffers (a stack; the pool's buffer `i` is scratchpad offset `i * B`).
    pub free: Vec<u32>,
    /// Elements in each buffer once its read has completed.
    pub count: Vec<u32>,
    /// Data of each buffer present.
    pub valid: Vec<bool>,
    /// The queue each buffer belongs to.
    pub owner: Vec<u32>,
    /// Per queue, its buffers in run order (front: being consumed), arrived or in flight.
    pub chain: Vec<VecDeque<u32>>,
    /// The forecast heap: (last key of the queue's newest buffer, queue) for each queue
    /// with elements left in DRAM and no read in flight.
    pub heap: BinaryHeap<Reverse<(u128, u32)>>,
    /// Reads issued in the multi-merge passes (first blocks included).
    pub reads: u64,
    /// Prefetched blocks dropped to break a mis-forecast (read again later).
    pub evictions: u64,
    /// Refills (reads past each run's first block) in issue order: (queue, buffer), kept
    /// only when `log` is set (tests).
    pub log: Option<Vec<(u32, u32)>>,
}

impl Forecast {
    fn new(buffers: u32) -> Self {
        Self {
            free: Vec::with_capacity(buffers as usize),
            count: vec![0; buffers as usize],
            valid: vec![false; buffers as usize],
            owner: vec![0; buffers as usize],
            chain: Vec::new(),
            heap: BinaryHeap::with_capacity(buffers as usize),
            reads: 0,
            evictions: 0,
            log: None,
        }
    }

    /// Gives a free buffer to queue `q`'s next block and queues its read.
    fn issue(&mut self, q: u32, refill: &mut VecDeque<u32>) -> bool {
        let Some(buf) = self.free.pop() else {
            return false;
        };
        self.owner[buf as usize] = q;
        self.valid[buf as usize] = false;
        self.chain[q as usize].push_back(buf);
        self.reads += 1;
        refill.push_back(buf);
        true
    }
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
    /// The buffer pool of forecasting read scheduling (`None`: double buffering).
    pub forecast: Option<Forecast>,
    /// The merge in progress schedules its reads by forecasting (multi-merges only).
    pub forecasting: bool,
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
            forecast: None,
            forecasting: false,
        }
    }

    /// A merger whose multi-merge passes schedule reads by forecasting over the M / B
    /// buffers of its scratchpad, merging at most `fan_in` runs.
    pub fn with_forecast(m: u32, b: u32, fan_in: u32) -> Self {
        let mut s = Self::new(m, b);
        s.heap = MergeHeap::new(fan_in.max(m / (2 * b)) as usize);
        s.forecast = Some(Forecast::new(m / b));
        s
    }

    /// Queue of buffer `buf`: the pool buffer's owner with forecasting, else the double
    /// buffer `buf / 2`.
    #[inline]
    fn queue_of(&self, buf: u32) -> usize {
        match &self.forecast {
            Some(f) if self.forecasting => f.owner[buf as usize] as usize,
            _ => (buf / 2) as usize,
        }
    }

    /// Sets up a partial-sort merge of the sub-blocks `lens` (already in the scratchpad,
    /// sub-block `q` at offset `q * 2B`).
    pub fn setup_partial(&mut self, lens: impl Iterator<Item = u32>, cycle: u64) {
        self.queues.clear();
        self.heap.clear();
        self.forecasting = false;
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
        if let Some(f) = &mut self.forecast {
            // Forecasting: the first block of every run, then the spares by forecast.
            self.forecasting = true;
            let bufs = f.count.len() as u32;
            f.free.clear();
            f.free.extend((0..bufs).rev());
            f.heap.clear();
            f.chain.resize_with(self.queues.len(), VecDeque::new);
            for (q, queue) in self.queues.iter().enumerate() {
                f.chain[q].clear();
                if queue.run_len > 0 {
                    let issued = f.issue(q as u32, refill);
                    assert!(issued, "more runs than buffers");
                }
            }
            self.begin(cycle);
            return;
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
        let q = &self.queues[self.queue_of(buf)];
        let count = (q.run_len - q.fetched).min(self.b as u64) as u32;
        (q.run_start + q.fetched, count)
    }

    /// The read of [`Self::peek_fetch`] was issued.
    pub fn commit_fetch(&mut self, buf: u32, count: u32) {
        let q = self.queue_of(buf);
        self.queues[q].fetched += count as u64;
    }

    /// With forecasting, gives every free buffer to the run the forecast heap names (the
    /// run whose buffered elements end lowest), queuing the reads to `refill`.
    pub fn forecast_issue(&mut self, refill: &mut VecDeque<u32>) {
        if !self.forecasting {
            return;
        }
        loop {
            let f = self.forecast.as_mut().expect("forecasting");
            while !f.free.is_empty() {
                let Some(Reverse((_, q))) = f.heap.pop() else {
                    break;
                };
                f.issue(q, refill);
                if let Some(log) = &mut f.log {
                    log.push((q, *f.chain[q as usize].back().expect("issued")));
                }
            }
            if !f.free.is_empty() || !self.evict_for_starved() {
                return;
            }
        }
    }

    /// Breaks a mis-forecast. A run leaves the forecast heap while its read is in flight,
    /// so buffers handed out meanwhile may go to runs needed later than it; if the merge
    /// then waits on a run that has no next block coming while every buffer holds data,
    /// nothing would ever be freed. The prefetched block needed last (the newest block of
    /// a run, with the largest last key) is dropped and its run re-keyed; the block is read
    /// again when the forecast names it. Returns true when a buffer was freed.
    fn evict_for_starved(&mut self) -> bool {
        let Some(f) = &mut self.forecast else {
            return false;
        };
        if !self.forecasting || self.state != MergeState::Merge {
            return false;
        }
        let Some((_, qi)) = self.heap.top() else {
            return false;
        };
        let q = &self.queues[qi as usize];
        let chain = &f.chain[qi as usize];
        let front = chain[0];
        let starved = chain.len() == 1
            && f.valid[front as usize]
            && q.idx + 1 == f.count[front as usize]
            && q.consumed + 1 < q.run_len;
        if !starved {
            return false;
        }
        let b = self.b;
        let last_key = |buf: u32, count: &[u32], scratch: &[Elem]| {
            scratch[(buf * b + count[buf as usize] - 1) as usize].key()
        };
        let victim = (0..f.chain.len())
            .filter(|&r| f.chain[r].len() >= 2)
            .filter_map(|r| {
                let back = *f.chain[r].back().expect("two buffers");
                f.valid[back as usize].then(|| (last_key(back, &f.count, &self.scratch), r as u32))
            })
            .max();
        let Some((_, r)) = victim else {
            return false; // the prefetched blocks are still in flight: wait for them
        };
        let buf = f.chain[r as usize].pop_back().expect("two buffers");
        self.queues[r as usize].fetched -= f.count[buf as usize] as u64;
        f.valid[buf as usize] = false;
        f.free.push(buf);
        f.evictions += 1;
        // The run is now due when its new newest block ends.
        f.heap.retain(|e| e.0 .1 != r);
        let newest = *f.chain[r as usize].back().expect("the front stays");
        f.heap
            .push(Reverse((last_key(newest, &f.count, &self.scratch), r)));
        true
    }

    /// A read for buffer `buf` completed with `count` elements, element `k` being `elem(k)`.
    pub fn fill_with(&mut self, buf: u32, count: usize, mut elem: impl FnMut(usize) -> Elem) {
        if self.forecasting {
            let f = self.forecast.as_mut().expect("forecasting");
            let base = (buf * self.b) as usize;
            for (k, slot) in self.scratch[base..base + count].iter_mut().enumerate() {
                *slot = elem(k);
            }
            f.count[buf as usize] = count as u32;
            f.valid[buf as usize] = true;
            let qi = f.owner[buf as usize];
            let q = &self.queues[qi as usize];
            if q.fetched < q.run_len && count > 0 {
                // The run's next block is due when its last buffered element leaves.
                f.heap
                    .push(Reverse((self.scratch[base + count - 1].key(), qi)));
            }
            return;
        }
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
                let (valid, base) = match &self.forecast {
                    Some(f) if self.forecasting => {
                        let b0 = f.chain[self.init_q as usize][0];
                        (f.valid[b0 as usize], b0 * self.b)
                    }
                    _ => (q.valid[0], q.base[0]),
                };
                if !valid {
                    return Slot::InitWait;
                }
                let key = self.scratch[base as usize].key();
                self.heap.insert(key, self.init_q);
                self.init_q += 1;
                self.ops += 1;
                self.next_op = cycle + 2;
                Slot::Worked
            }
            MergeState::Merge if self.forecasting => self.operate_forecast(cycle, out),
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

impl Merger {
    /// A steady-state operation slot with forecasting: as with double buffering, but the
    /// successor of a buffer's last element is the first of the next buffer in the run's
    /// chain, and a used-up buffer returns to the pool.
    fn operate_forecast(&mut self, cycle: u64, out: &mut impl MergeOut) -> Slot {
        let Some((_, qi)) = self.heap.top() else {
            self.state = MergeState::Done;
            return Slot::Worked;
        };
        let f = self.forecast.as_mut().expect("forecasting");
        let q = self.queues[qi as usize];
        let chain = &f.chain[qi as usize];
        let cur = chain[0];
        let count = f.count[cur as usize];
        let pos = (cur * self.b + q.idx) as usize;
        let succ_key = if q.idx + 1 < count {
            self.scratch[pos + 1].key()
        } else if q.consumed + 1 < q.run_len {
            match chain.get(1) {
                Some(&next) if f.valid[next as usize] => {
                    self.scratch[(next * self.b) as usize].key()
                }
                _ => return Slot::QueueDry,
            }
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
        if q.idx + 1 < count {
            q.idx += 1;
        } else {
            // The buffer is used up: it returns to the pool (the unit then hands free
            // buffers out by forecast, `forecast_issue`).
            f.valid[cur as usize] = false;
            f.chain[qi as usize].pop_front();
            f.free.push(cur);
            q.idx = 0;
        }
        self.next_op = cycle + 2;
        if self.heap.live() == 0 {
            self.state = MergeState::Done;
        }
        Slot::Worked
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

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Aabb;

    /// Outputs and refill requests of a merge driven by hand.
    struct Sink {
        out: Vec<Elem>,
        refills: VecDeque<u32>,
    }

    impl MergeOut for Sink {
        fn is_full(&self) -> bool {
            false
        }
        fn push(&mut self, e: Elem) {
            self.out.push(e);
        }
        fn refill(&mut self, buf: u32) {
            self.refills.push_back(buf);
        }
    }

    /// Completes every queued read at once from `src` (reads of zero latency, so the
    /// order of the reads is the scheduler's alone); returns the buffers filled.
    fn serve(m: &mut Merger, sink: &mut Sink, src: &[Elem]) -> Vec<u32> {
        let mut filled = Vec::new();
        m.forecast_issue(&mut sink.refills);
        while let Some(buf) = sink.refills.pop_front() {
            let (pos, count) = m.peek_fetch(buf);
            m.commit_fetch(buf, count);
            m.fill_with(buf, count as usize, |k| src[pos as usize + k]);
            filled.push(buf);
            m.forecast_issue(&mut sink.refills);
        }
        filled
    }

    /// `runs` (sorted keys) laid out one after another in memory: the elements (each
    /// tagged with its position) and each run's (start, length).
    fn layout<R: AsRef<[u64]>>(runs: &[R]) -> (Vec<Elem>, Vec<(u64, u64)>) {
        let src = runs
            .iter()
            .flat_map(|r| r.as_ref().iter())
            .enumerate()
            .map(|(i, &k)| Elem::new(k, i as u32, Aabb::EMPTY))
            .collect();
        let mut start = 0u64;
        let spans = runs
            .iter()
            .map(|r| {
                let n = r.as_ref().len() as u64;
                start += n;
                (start - n, n)
            })
            .collect();
        (src, spans)
    }

    /// Runs a multi-merge of `runs` (sorted keys) to the end; returns the output keys and
    /// the reads in order (buffer ids).
    fn merge_all(mut m: Merger, runs: &[&[u64]]) -> (Merger, Vec<u64>, Vec<u32>) {
        let (src, spans) = layout(runs);
        let mut sink = Sink {
            out: Vec::new(),
            refills: VecDeque::new(),
        };
        m.setup_multi(spans.into_iter(), &mut sink.refills, 0);
        let mut reads = serve(&mut m, &mut sink, &src);
        for cycle in 0..10_000 {
            let slot = m.tick_with(cycle, &mut sink);
            assert_ne!(slot, Slot::QueueDry, "zero-latency reads never run dry");
            reads.extend(serve(&mut m, &mut sink, &src));
            if m.state == MergeState::Done {
                break;
            }
        }
        assert_eq!(m.state, MergeState::Done);
        let keys = sink.out.iter().map(|e| e.code).collect();
        (m, keys, reads)
    }

    /// A hand-derived forecast schedule. M = 8, B = 2: four buffers; with one spare, three
    /// runs (double buffering: M / (2B) = 2). The first block of each run is read
    /// (buffers 0, 1, 2); the forecast heap then holds run 0 keyed 2, run 1 keyed 6,
    /// run 2 keyed 14, so the spare (buffer 3) goes to run 0's block [3, 4]. Run 0 is
    /// then keyed 4: when 1, 2 leave, buffer 0 gets run 0's last block [9, 10] (run 0
    /// leaves the forecast heap); when 3, 4 leave, buffer 3 gets run 1's [7, 8] (key 6 is
    /// now the smallest); when 5, 6 leave, buffer 1 gets run 1's [11, 12]; when 7, 8
    /// leave, buffer 3 gets run 2's [15, 16]. Eight reads in all, one per block, and
    /// never a dry queue with reads of zero latency.
    #[test]
    fn forecast_refills_in_hand_derived_order() {
        let runs: [&[u64]; 3] = [
            &[1, 2, 3, 4, 9, 10],
            &[5, 6, 7, 8, 11, 12],
            &[13, 14, 15, 16],
        ];
        let mut m = Merger::with_forecast(8, 2, 3);
        m.forecast.as_mut().unwrap().log = Some(Vec::new());
        let (m, keys, reads) = merge_all(m, &runs);
        assert_eq!(keys, (1..=16).collect::<Vec<u64>>());
        let f = m.forecast.as_ref().unwrap();
        assert_eq!(
            f.log.as_deref().unwrap(),
            &[(0, 3), (0, 0), (1, 3), (1, 1), (2, 3)]
        );
        assert_eq!(reads, [0, 1, 2, 3, 0, 3, 1, 3]);
        assert_eq!(f.reads, 8);
        assert_eq!(f.free.len(), 4, "every buffer back in the pool");
        assert_eq!(m.outputs, 16);
    }

    /// The same scratchpad double-buffered holds two runs; the merge of two runs is the
    /// same with both schedules.
    #[test]
    fn forecast_and_double_merge_alike() {
        let runs: [&[u64]; 2] = [&[1, 4, 5, 8, 20, 21], &[2, 3, 6, 7, 9, 30, 31, 32]];
        let (_, double, _) = merge_all(Merger::new(8, 2), &runs);
        let (m, forecast, reads) = merge_all(Merger::with_forecast(8, 2, 3), &runs);
        assert_eq!(double, forecast);
        assert_eq!(reads.len(), 7, "one read per block");
        assert_eq!(m.forecast.unwrap().reads, 7);
    }

    /// Merges `runs` with reads of random latency (1..=`max_lat` cycles, completing out of
    /// order); returns the output keys and the merger.
    fn merge_with_latency(
        mut m: Merger,
        runs: &[Vec<u64>],
        seed: u64,
        max_lat: u64,
    ) -> (Merger, Vec<u64>) {
        let (src, spans) = layout(runs);
        let mut sink = Sink {
            out: Vec::new(),
            refills: VecDeque::new(),
        };
        let mut rng = seed;
        let mut next = move || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            rng >> 33
        };
        m.setup_multi(spans.into_iter(), &mut sink.refills, 0);
        let mut flight: Vec<(u64, u32, u64, u32)> = Vec::new();
        for cycle in 0..1_000_000u64 {
            let mut k = 0;
            while k < flight.len() {
                if flight[k].0 <= cycle {
                    let (_, buf, pos, count) = flight.remove(k);
                    m.fill_with(buf, count as usize, |j| src[pos as usize + j]);
                } else {
                    k += 1;
                }
            }
            m.tick_with(cycle, &mut sink);
            m.forecast_issue(&mut sink.refills);
            while let Some(buf) = sink.refills.pop_front() {
                let (pos, count) = m.peek_fetch(buf);
                m.commit_fetch(buf, count);
                flight.push((cycle + 1 + next() % max_lat, buf, pos, count));
            }
            if m.state == MergeState::Done {
                break;
            }
        }
        assert_eq!(
            m.state,
            MergeState::Done,
            "seed {seed}: the merge did not finish"
        );
        let keys = sink.out.iter().map(|e| e.code).collect();
        (m, keys)
    }

    /// With reads of long, random latency the forecast is made without the runs whose
    /// reads are in flight and can go wrong; the merge still finishes in order (a
    /// prefetched block is dropped and read again), and it does happen.
    #[test]
    fn forecast_survives_mis_forecasts() {
        let mut evictions = 0;
        for seed in 0..40u64 {
            let mut rng = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
            let mut next = move || {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng
            };
            // M = 32, B = 2: 16 buffers; 1 + seed % 4 spares.
            let spares = 1 + (seed % 4) as u32;
            let nruns = 16 - spares as usize;
            let runs: Vec<Vec<u64>> = (0..nruns)
                .map(|_| {
                    let len = 2 * (1 + next() % 8) as usize;
                    let mut r: Vec<u64> = (0..len).map(|_| next() % 200).collect();
                    r.sort();
                    r
                })
                .collect();
            let mut all: Vec<u64> = runs.concat();
            all.sort();
            let (m, keys) =
                merge_with_latency(Merger::with_forecast(32, 2, nruns as u32), &runs, seed, 60);
            assert_eq!(keys, all, "seed {seed}");
            let f = m.forecast.as_ref().unwrap();
            assert_eq!(f.free.len(), 16, "seed {seed}");
            let blocks: u64 = runs.iter().map(|r| r.len() as u64 / 2).sum();
            assert_eq!(
                f.reads,
                blocks + f.evictions,
                "seed {seed}: one read per block and eviction"
            );
            evictions += f.evictions;
            // Double buffering merges the first eight runs alike.
            let (_, d) = merge_with_latency(Merger::new(32, 2), &runs[..8], seed, 60);
            let mut first: Vec<u64> = runs[..8].concat();
            first.sort();
            assert_eq!(d, first);
        }
        assert!(evictions > 0, "no mis-forecast in 40 merges");
    }
}
