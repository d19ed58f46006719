//! The MergeTree machine on the simulation kernel ([`crate::kernel`], `docs/sim-kernel.md`):
//! the units of \[P2\] Fig. 1 and the control FSM of \[P1\] Fig. 2 / \[P2\] Fig. 3 (partial
//! sorts, multi-merge passes, hierarchy emission, toplevel SAH, CBVH output) as kernel
//! [`Unit`]s over one world, `KWorld`, connected by latency FIFOs and a few explicit
//! shared resources. The kernel's scheduler steps only the units that are due and jumps
//! over cycles in which none is (exactly: a run with `fast_forward = false` steps every
//! unit in every cycle and gives the same results, tested).
//!
//! # DRAM layout
//! All regions start on 4 KiB boundaries, in this order:
//! - `input`: the N primitive AABBs, 32 bytes each (the unit's input, written by the host);
//! - `runs[0]`, `runs[1]`: two sort-run regions of Npad * 32 bytes (Npad = N rounded up to
//!   B). Partial sorts write their M-element runs to `runs[0]`; multi-merge pass `p` reads
//!   `runs[p % 2]` and writes `runs[(p + 1) % 2]` (double-buffered); the final pass is not
//!   written back but streamed into the hierarchy emitter;
//! - `nodes`: BVH nodes, 64 bytes each, in emission (bottom-up) order;
//! - `leaves`: the leaf table, one 4-byte primitive reference per sorted position;
//! - `highlevel`: 32-byte high-level roots (with a threshold) and the toplevel nodes;
//! - `cbvh`: the compressed tree's node pairs, in the CBVH output modes (\[P3\] §5.3), written
//!   by the streaming encoder (in its write order) or by the top-down pass (in its read
//!   order; see [`super::cbvh_unit`]). With the streaming encoder, `nodes` stays unused.
//!
//!
//!
//! # Units (in step order: their [`UnitId`]s)
//! | id | unit | owns | reads | writes |
//! |---|---|---|---|---|
//! | 0 | control FSM (\[P1\] Fig. 2) | phase, block / pass / group counters | `sub_ready`, `merge_done`, `emit_done`, `stream_done`, `top_done`, `td_done`; the arbiter's totals and the write buffers' levels (polled while a phase drains) | `cmd`, `top_start`, `td_start`; registers `scratch_open`, `emit_active`, the buffers' flush flags |
//! | 1 | hierarchy emitter | `EmitUnit` | `emit_fifo` | node (or `enc_fifo`) / leaf / high-level write buffers, `emit_done`, register `emit_finished` |
//! | 2 | multi-merge unit | `Merger` (heap, queues, its scratchpad) | `cmd`, `fill` | `emit_fifo` or `run_fifo`, `refill`, `merge_done` |
//! | 3 | reader | input position, ring credits | `ps_credit[p]`, `refill` | `req_read` |
//! | 4 | run writer | its B-element write register | `run_fifo` | `req_run`, run regions (functional) |
//! | 5 | memory arbiter | [`RoundRobin`] over 6 requesters (run writer, node / leaf / high-level buffers, reader, CBVH unit), read descriptors | their requests, memory responses | the port, `ps_data[p]`, `fill`, `bt_data`, `td_data`, its totals |
//! | 6 | presorter bank: presorters `0..P` (one kernel unit, `PresortBank`; each presorter keeps its own intervals) | per presorter a `Presorter` (ring, sort buffer) | `ps_data[p]`, `scratch_open` | the scratchpad's write side (one write port, taken in presorter order), `ps_credit[p]`, `sub_ready` |
//! | then | toplevel SAH unit (with `toplevel_sah`) | `TopUnit` | `top_start`, the published cell roots | high-level write buffer, `top_done` |
//! | then | streaming CBVH encoder (`cbvh-stream`) | the encoder, its queued accesses | `enc_fifo`, `bt_data`, `emit_finished` | node-pair write buffer, `req_cbvh`, `stream_done` |
//! | then | top-down CBVH pass (`cbvh-topdown`) | read / encode positions | `td_start`, `td_data` | node-pair write buffer, `req_cbvh`, `td_done` |
//!
//! Units a configuration does not use are not added. The control reads the arbiter's totals
//! and the buffers' levels only as they were at the start of the cycle.
//!
//! A new unit is one more [`Unit`] added to the scheduler with its channels in the world;
//! the scheduler does not change.
//!
//! # FIFOs and latencies
//! Every FIFO has latency 1: one register stage between the units, the pipeline register
//! of a hardware FIFO's output. An item pushed in cycle t is used from t + 1; the old
//! hand-wired loop (before the kernel) handed some of them over within the cycle (merge
//! output to the emitter, read data to the presorters and the merge queues, refill
//! requests to the reader, control commands), which is where its cycle counts differ from
//! this machine's: 0.1-1.1% more cycles on the shared scenes (preset `p2`, 2026-12-02):
//!
//! | scene, memory | hand-wired loop | kernel machine | difference |
//! |---|---|---|---|
//! | Bunny, `simple:lpddr3-1600-1x64` | 869,695 | 870,364 | +669 (+0.08%) |
//! | Bunny, `lpddr3-1600-1x64` (DRAMsim3) | 1,013,098 | 1,014,851 | +1,753 (+0.17%) |
//! | Crytek Sponza, simple | 2,809,818 | 2,839,623 | +29,805 (+1.06%) |
//! | Crytek Sponza, DRAMsim3 | 3,261,274 | 3,280,872 | +19,598 (+0.60%) |
//! | Dragon, simple | 10,232,795 | 10,241,788 | +8,993 (+0.09%) |
//! | Dragon, DRAMsim3 | 11,946,888 | 11,971,550 | +24,662 (+0.21%) |
//! The run writer stages B
//! elements in its write register before its request goes to the arbiter (the old loop
//! wrote straight from the run FIFO), so that path holds B elements more.
//!
//! | channel | capacity | from -> to |
//! |---|---|---|
//! | `emit_fifo` | `emit_fifo` | merger -> emitter |
//! | `run_fifo` | `run_write_fifo` | merger -> run writer |
//! | `refill` | M / B (two halves per queue) | merger -> reader (fetch descriptors) |
//! | `fill` | M / B | arbiter -> merger (completed run reads) |
//! | `ps_data[p]` | `presort_slots` | arbiter -> presorter p (completed input reads) |
//! | `ps_credit[p]` | `presort_slots` | presorter p -> reader (ring slots freed) |
//! | `req_read`, `req_run` | 2 | reader / run writer -> arbiter |
//! | `cmd` | 1 | control -> merger |
//! | `enc_fifo` | `cbvh_fifo` | emitter -> streaming encoder |
//! | `req_cbvh` | 2 | CBVH unit -> arbiter |
//! | `bt_data` | 1 | arbiter -> streaming encoder (backtracking read done) |
//! | `td_data` | nodes | arbiter -> top-down pass (node reads done) |
//! | `sub_ready`, `merge_done`, `emit_done`, `stream_done`, `top_start`, `top_done`, `td_start`, `td_done` | - | handshakes |
//!
//! The write buffers (`KBuf`) follow the same rule at byte granularity: bytes added in
//! cycle t may be written out from t + 1; bytes written out in cycle t free room from
//! t + 1. The control's registers (`Reg`) are visible from the cycle after they are set.
//! The arbiter's totals (`Count`) exclude the current cycle's additions.
//!
//! # Statistics
//! Each unit reports busy / stalled (with a reason) / idle intervals to the kernel (the
//! presorter bank also keeps one set per presorter); the [`StallReport`] fields are sums of
//! them (see `stall_report`).

use std::collections::VecDeque;

use geom::{Aabb, MortonQuantizer};

use super::cbvh_unit::{StreamUnitStats, TopdownStats};
use super::config::OutputMode;
use super::config::{MergeTreeConfig, ELEM_BYTES, HIGHLEVEL_BYTES, LEAF_ENTRY_BYTES, NODE_BYTES};
use super::emitter::{EmitPorts, EmitStatus, EmitUnit, EmitterStalls};
use super::merge::{MergeOut, MergeStalls, MergeState, Merger, Slot};
use super::presort::{PresortState, Presorter};
use super::report::{PhaseReport, StallReport, TraceRow};
use super::toplevel::TopUnit;
use super::{Elem, MergeTreeError};
use crate::dram::{AccessKind, MemRequest, MemoryPort};
use crate::fifo::FifoStats;
use crate::kernel::{
    Ctx, Cycle, LatencyFifo, Memory, Offer, Options, RoundRobin, RunReport, Scheduler, State, Unit,
    UnitId, Wake, World,
};

/// Alignment of the DRAM regions.
const REGION_ALIGN: u64 = 4096;

/// Base addresses of the DRAM regions (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct MemoryLayout {
    /// Input AABBs.
    pub input: u64,
    /// The two sort-run regions.
    pub runs: [u64; 2],
    /// BVH nodes.
    pub nodes: u64,
    /// Leaf table.
    pub leaves: u64,
    /// High-level roots and toplevel nodes.
    pub highlevel: u64,
    /// CBVH node pairs (CBVH output modes).
    pub cbvh: u64,
    /// First byte after the layout.
    pub end: u64,
}

impl MemoryLayout {
    /// The layout for `n` primitives padded to `npad` elements, with `run_gap` bytes after
    /// every run of `m` elements in the run regions ([`run_offset`]).
    pub fn new(n: u64, npad: u64, m: u64, run_gap: u64) -> Self {
        let up = |x: u64| x.div_ceil(REGION_ALIGN) * REGION_ALIGN;
        let input = 0;
        let run0 = up(input + n * ELEM_BYTES);
        let run_bytes = run_offset(npad, m.max(1), run_gap);
        let run1 = up(run0 + run_bytes);
        let nodes = up(run1 + run_bytes);
        let leaves = up(nodes + n.saturating_sub(1) * super::config::NODE_BYTES);
        let highlevel = up(leaves + n * super::config::LEAF_ENTRY_BYTES);
        let cbvh = up(highlevel + n * super::config::HIGHLEVEL_BYTES);
        let pair_max = cbvh::format::pair_bytes(cbvh::grid::MAX_BITS) as u64;
        let end = up(cbvh + n.max(1) * pair_max);
        Self {
            input,
            runs: [run0, run1],
            nodes,
            leaves,
            highlevel,
            cbvh,
            end,
        }
    }
}

/// Byte offset of element `at` in a run region: runs of `m` elements, each followed by
/// `run_gap` unused bytes (the `run_gap_bytes` layout what-if; 0 by default).
#[inline]
pub fn run_offset(at: u64, m: u64, run_gap: u64) -> u64 {
    at * ELEM_BYTES + at / m * run_gap
}

/// The sort element of primitive `i` of `aabbs` (padding past the end): its box,
/// reference and the Morton code of its centroid on `quant`'s grid with `bits` bits.
#[inline]
pub(super) fn elem_of(aabbs: &[Aabb], quant: &MortonQuantizer, bits: u32, i: u64) -> Elem {
    let Some(&a) = aabbs.get(i as usize) else {
        return Elem::pad(i);
    };
    // The same centroid expression as the software builder.
    let c = a.min * 0.5 + a.max * 0.5;
    let code = if bits == 30 {
        quant.code30(c) as u64
    } else {
        quant.code63(c)
    };
    Elem::new(code, i as u32, a)
}

/// A write-combining buffer in front of the port: a unit adds bytes, the arbiter writes
/// them out in chunks to consecutive addresses (chunks aligned to `chunk` from the base).
#[derive(Clone, Debug)]
pub struct WriteBuffer {
    base: u64,
    next_addr: u64,
    pending: u64,
    capacity: u64,
    chunk: u64,
    /// Write out a partial chunk (the producer has finished).
    pub flush: bool,
    /// Write out partial chunks until every byte below this address is written.
    flush_until: u64,
    /// Bytes handed to the port.
    pub written: u64,
}

impl WriteBuffer {
    /// A buffer of `capacity` bytes that writes `chunk`-byte requests from `base` on.
    pub fn new(base: u64, capacity: u64, chunk: u64) -> Self {
        Self {
            base,
            next_addr: base,
            pending: 0,
            capacity,
            chunk,
            flush: false,
            flush_until: 0,
            written: 0,
        }
    }

    /// A large buffer at address 0 for unit tests.
    #[cfg(test)]
    pub fn new_for_test(capacity: u64) -> Self {
        Self::new(0, capacity, 64)
    }

    /// True when `bytes` more fit.
    pub fn has_room(&self, bytes: u64) -> bool {
        self.pending + bytes <= self.capacity
    }

    /// Adds `bytes` produced by the unit.
    pub fn add(&mut self, bytes: u64) {
        debug_assert!(self.has_room(bytes));
        self.pending += bytes;
    }

    /// The write request ready to go, if any: the rest of the current chunk once it is
    /// full, or what is there when flushing.
    /// The write request ready to go if `pending` bytes are held and the flush flag is
    /// `flush`: the rest of the current chunk once it is full, or what is there when
    /// flushing.
    #[inline]
    pub(super) fn ready_with(&self, pending: u64, flush: bool) -> Option<(u64, u32)> {
        let room = self.chunk - (self.next_addr - self.base) % self.chunk;
        if pending >= room || ((flush || self.next_addr < self.flush_until) && pending > 0) {
            Some((self.next_addr, pending.min(room) as u32))
        } else {
            None
        }
    }

    /// Capacity in bytes.
    pub(super) fn capacity(&self) -> u64 {
        self.capacity
    }

    pub(super) fn issued(&mut self, bytes: u32) {
        self.pending -= bytes as u64;
        self.next_addr += bytes as u64;
        self.written += bytes as u64;
    }

    /// Bytes waiting.
    pub fn pending(&self) -> u64 {
        self.pending
    }

    /// Address of the first byte not yet handed to the port (the bytes below it are).
    pub fn next_addr(&self) -> u64 {
        self.next_addr
    }

    /// Writes out partial chunks until every byte held now below `addr` has gone to the
    /// port (bytes added later are written as usual).
    pub fn flush_through(&mut self, addr: u64) {
        let held_end = self.next_addr + self.pending;
        self.flush_until = self.flush_until.max(addr.min(held_end));
    }
}

const CONTROL: UnitId = UnitId(0);
const EMITTER: UnitId = UnitId(1);
const MERGER: UnitId = UnitId(2);
const READER: UnitId = UnitId(3);
const RUN_WRITER: UnitId = UnitId(4);
const ARBITER: UnitId = UnitId(5);
const PRESORTER0: u32 = 6;

/// Ids of the units a configuration may leave out (added after the presorters when they
/// are used; [`UnitId::EXTERNAL`] otherwise, whose notifications go nowhere).
#[derive(Clone, Copy, Debug)]
struct Optional {
    toplevel: UnitId,
    stream: UnitId,
    topdown: UnitId,
}

/// Scratchpad closed to the presorters (no block may be copied in).
const CLOSED: u64 = u64::MAX;

/// A register written by one unit: a value set in cycle t is read from t + 1 on.
#[derive(Clone, Copy, Debug)]
pub(super) struct Reg<T: Copy> {
    cur: T,
    prev: T,
    at: Cycle,
}

impl<T: Copy> Reg<T> {
    fn new(v: T) -> Self {
        Self {
            cur: v,
            prev: v,
            at: 0,
        }
    }

    #[inline]
    fn get(&self, now: Cycle) -> T {
        if now > self.at {
            self.cur
        } else {
            self.prev
        }
    }

    #[inline]
    fn set(&mut self, now: Cycle, v: T) {
        if self.at != now {
            self.prev = self.get(now);
            self.at = now;
        }
        self.cur = v;
    }
}

/// A running total: additions of cycle t are read from t + 1 on.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Count {
    v: u64,
    fresh: u64,
    at: Cycle,
}

impl Count {
    #[inline]
    fn add(&mut self, now: Cycle, k: u64) {
        if self.at != now {
            self.at = now;
            self.fresh = 0;
        }
        self.v += k;
        self.fresh += k;
    }

    #[inline]
    fn get(&self, now: Cycle) -> u64 {
        self.v - if self.at == now { self.fresh } else { 0 }
    }
}

/// A write-combining buffer as a kernel channel (see the module documentation).
pub(super) struct KBuf {
    wb: WriteBuffer,
    fresh: u64,
    fresh_at: Cycle,
    freed: u64,
    freed_at: Cycle,
    flush: Reg<bool>,
    /// Write out partial chunks until every byte below this address is written.
    flush_until: Reg<u64>,
    producers: [UnitId; 2],
}

impl KBuf {
    fn new(wb: WriteBuffer, producers: [UnitId; 2]) -> Self {
        Self {
            wb,
            fresh: 0,
            fresh_at: 0,
            freed: 0,
            freed_at: 0,
            flush: Reg::new(false),
            flush_until: Reg::new(0),
            producers,
        }
    }

    #[inline]
    fn has_room(&self, now: Cycle, bytes: u64) -> bool {
        let freed = if self.freed_at == now { self.freed } else { 0 };
        self.wb.pending() + freed + bytes <= self.wb.capacity()
    }

    #[inline]
    fn add(&mut self, cx: &mut Ctx, bytes: u64) {
        let now = cx.now();
        self.wb.add(bytes);
        if self.fresh_at != now {
            self.fresh_at = now;
            self.fresh = 0;
        }
        self.fresh += bytes;
        // The arbiter needs to look only once a write is ready (next cycle, when these
        // bytes are visible); a buffer becomes ready only by adding bytes, a flush flag
        // (which notifies) or an issue (made by the arbiter itself, which then looks again).
        let until = self.flush_until.get(now + 1);
        let flush = self.flush.get(now + 1) || self.wb.next_addr() < until;
        if self.wb.ready_with(self.wb.pending(), flush).is_some() {
            cx.notify(ARBITER, now + 1);
        }
    }

    /// The write ready at `now` (bytes added this cycle excluded).
    #[inline]
    fn ready(&self, now: Cycle) -> Option<(u64, u32)> {
        if self.wb.pending() == 0 {
            return None;
        }
        let fresh = if self.fresh_at == now { self.fresh } else { 0 };
        let pending = self.wb.pending() - fresh;
        let until = self.flush_until.get(now);
        self.wb
            .ready_with(pending, self.flush.get(now) || self.wb.next_addr() < until)
    }

    fn issued(&mut self, cx: &mut Ctx, bytes: u32) {
        let now = cx.now();
        self.wb.issued(bytes);
        if self.freed_at != now {
            self.freed_at = now;
            self.freed = 0;
        }
        self.freed += bytes as u64;
        for p in self.producers {
            cx.notify(p, now + 1);
        }
    }

    /// The first address not yet written out, at the start of cycle `now`.
    fn start_next_addr(&self, now: Cycle) -> u64 {
        let freed = if self.freed_at == now { self.freed } else { 0 };
        self.wb.next_addr() - freed
    }

    /// Bytes held at the start of cycle `now`.
    fn start_pending(&self, now: Cycle) -> u64 {
        let fresh = if self.fresh_at == now { self.fresh } else { 0 };
        let freed = if self.freed_at == now { self.freed } else { 0 };
        self.wb.pending() + freed - fresh
    }

    fn flush_through(&mut self, cx: &mut Ctx, addr: u64) {
        self.flush_until.set(cx.now(), addr);
        cx.notify(ARBITER, cx.now() + 1);
    }

    fn set_flush(&mut self, cx: &mut Ctx, on: bool) {
        self.flush.set(cx.now(), on);
        cx.notify(ARBITER, cx.now() + 1);
    }
}

/// A run read: buffer half `buf` of the merge scratchpad from run region `region`.
#[derive(Clone, Copy, Debug)]
struct Fetch {
    buf: u32,
    region: u8,
    pos: u64,
    count: u32,
}

/// An input read into ring slot `slot` of a presorter: `count` elements from `src`.
#[derive(Clone, Copy, Debug)]
struct InputRead {
    slot: u32,
    src: u64,
    count: u32,
}

/// Where a request's response goes.
#[derive(Clone, Copy, Debug)]
enum Dest {
    Presort { p: u32, read: InputRead },
    Merge(Fetch),
    Run { elems: u32 },
    Buffer,
    Backtrack,
    Topdown { j: u64 },
}

/// A memory request waiting for the arbiter.
#[derive(Clone, Copy, Debug)]
struct Req {
    addr: u64,
    bytes: u32,
    kind: AccessKind,
    dest: Dest,
}

/// A command of the control FSM to the multi-merge unit.
#[derive(Clone, Copy, Debug)]
enum MergeCmd {
    /// Merge the presorted sub-blocks `first..first + count` now in the scratchpad.
    Partial {
        first: u64,
        count: u64,
        to_emitter: bool,
    },
    /// Merge runs `first..last` of `run_len` elements from run region `src`.
    Multi {
        first: u64,
        last: u64,
        run_len: u64,
        src: u8,
        to_emitter: bool,
    },
}

/// The arbiter's totals, read by the control FSM.
#[derive(Clone, Copy, Debug, Default)]
struct Totals {
    read_bytes: Count,
    write_bytes: Count,
    reads: Count,
    read_latency: Count,
    run_acked: Count,
}

/// The time series, accounted by spans and events (no per-cycle code).
struct Trace {
    window: u64,
    rows: Vec<TraceRow>,
    /// The window of the last row looked up: its first cycle, first cycle after, index.
    cur: (Cycle, Cycle, usize),
}

impl Trace {
    fn new(window: u64) -> Self {
        Self {
            window,
            rows: Vec::new(),
            cur: (0, 0, 0),
        }
    }

    #[inline]
    fn row(&mut self, c: Cycle) -> &mut TraceRow {
        if c < self.cur.0 || c >= self.cur.1 {
            let i = (c / self.window) as usize;
            if i >= self.rows.len() {
                self.rows.resize_with(i + 1, TraceRow::default);
            }
            let start = i as u64 * self.window;
            self.cur = (start, start + self.window, i);
        }
        &mut self.rows[self.cur.2]
    }

    #[inline]
    fn span(&mut self, start: Cycle, end: Cycle, f: fn(&mut TraceRow) -> &mut u64) {
        let mut c = start;
        while c < end {
            let e = end.min((c / self.window + 1) * self.window);
            *f(self.row(c)) += e - c;
            c = e;
        }
    }
}

/// What units publish when they finish (the functional outputs).
#[derive(Default)]
struct Outputs {
    nodes: Vec<bvh::EmittedNode>,
    roots: Vec<bvh::HighlevelRoot>,
    order: Vec<u32>,
    max_stack_depth: usize,
    top: Option<TopUnit>,
    fault: Option<cbvh::CbvhError>,
    cbvh_ids: Option<Vec<u32>>,
    stream: Option<(cbvh::bottomup::StreamEncoder, StreamUnitStats)>,
    topdown: Option<TopdownStats>,
}

/// The world of the kernel-based machine: channels, shared resources, outputs.
pub(super) struct KWorld<'a> {
    cfg: MergeTreeConfig,
    aabbs: &'a [Aabb],
    quant: MortonQuantizer,
    n: u64,
    npad: u64,
    blocks: u64,
    passes_total: u32,
    layout: MemoryLayout,
    mem: Memory,
    cmd: LatencyFifo<MergeCmd>,
    merge_done: LatencyFifo<()>,
    sub_ready: LatencyFifo<()>,
    emit_done: LatencyFifo<()>,
    top_start: LatencyFifo<()>,
    top_done: LatencyFifo<()>,
    emit_fifo: LatencyFifo<Elem>,
    run_fifo: LatencyFifo<Elem>,
    refill: LatencyFifo<Fetch>,
    fill: LatencyFifo<Fetch>,
    ps_data: Vec<LatencyFifo<InputRead>>,
    ps_credit: Vec<LatencyFifo<()>>,
    req_read: LatencyFifo<Req>,
    req_run: LatencyFifo<Req>,
    nodes: KBuf,
    leaves: KBuf,
    hl: KBuf,
    /// Emitter -> streaming CBVH encoder.
    enc_fifo: LatencyFifo<cbvh::bottomup::InputNode>,
    /// Streaming encoder's and top-down pass's requests to the arbiter.
    req_cbvh: LatencyFifo<Req>,
    /// Arbiter -> streaming encoder: a backtracking read's latency.
    bt_data: LatencyFifo<u64>,
    /// Arbiter -> top-down pass: stream position and latency of each node read.
    td_data: LatencyFifo<(u64, u64)>,
    stream_done: LatencyFifo<()>,
    td_start: LatencyFifo<()>,
    td_done: LatencyFifo<()>,
    /// The emitter has output its last node (for the streaming encoder).
    emit_finished: Reg<bool>,
    ids: Optional,
    /// Partial-sort block whose sub-blocks the presorters may copy into the scratchpad.
    scratch_open: Reg<u64>,
    /// The emitter consumes the merge output (the final merge has started).
    emit_active: Reg<bool>,
    /// Write side of the scratchpad in the partial sorts (handed to the merger with each
    /// block: a functional double buffer, the hardware's one scratchpad).
    scratch: Vec<Elem>,
    /// Cycle the scratchpad's write port was last used.
    scratch_port: Cycle,
    /// Functional contents of the run regions (element references), and the Morton codes
    /// recorded as the input streams in (see [`super::machine`]).
    region: [Vec<u32>; 2],
    codes: Vec<u64>,
    /// Requests sent and not yet answered, at the start of each cycle.
    inflight: Reg<u64>,
    acc: Totals,
    trace: Trace,
    out: Outputs,
    phases: Vec<PhaseReport>,
    /// Phase names with the cycle each started (for the trace rows).
    phase_log: Vec<(Cycle, String)>,
    build_cycles: Cycle,
    /// Work done (merge outputs and emitter inputs) and in all, for the progress callback.
    work: u64,
    work_total: u64,
    progress: Option<&'a mut dyn FnMut(u64, u64)>,
}

/// Work between two calls of the progress callback.
const PROGRESS_EVERY: u64 = 1 << 16;

impl KWorld<'_> {
    /// One unit of work done: calls the progress callback every [`PROGRESS_EVERY`].
    #[inline]
    fn worked(&mut self, k: u64) {
        let before = self.work / PROGRESS_EVERY;
        self.work += k;
        if self.work / PROGRESS_EVERY != before {
            if let Some(h) = self.progress.as_mut() {
                h(self.work.min(self.work_total), self.work_total);
            }
        }
    }
}

impl World for KWorld<'_> {
    fn memory(&mut self) -> Option<&mut Memory> {
        Some(&mut self.mem)
    }

    fn describe(&self) -> String {
        let mut s = String::new();
        for f in [&self.emit_fifo, &self.run_fifo] {
            s += &format!("{} {}/{}; ", f.name(), f.len(), f.capacity());
        }
        s += &format!(
            "refill {}, fill {}, read requests {}, run writes {}; write buffers: nodes {}, leaves {}, highlevel {} bytes",
            self.refill.len(),
            self.fill.len(),
            self.req_read.len(),
            self.req_run.len(),
            self.nodes.wb.pending(),
            self.leaves.wb.pending(),
            self.hl.wb.pending()
        );
        s
    }
}

impl KWorld<'_> {
    fn sub_len(&self, sub: u64) -> u32 {
        let b = self.cfg.b as u64;
        (self.npad - sub * 2 * b).min(2 * b) as u32
    }

    fn subs_of_block(&self, k: u64) -> u64 {
        let m = self.cfg.m as u64;
        let len = (self.npad - k * m).min(m);
        len.div_ceil(2 * self.cfg.b as u64)
    }
}

fn fifo<T>(name: &'static str, cap: usize, from: UnitId, to: UnitId) -> LatencyFifo<T> {
    LatencyFifo::new(name, cap.max(1), 1, from, to).expect("capacity and latency are positive")
}

// ---------------------------------------------------------------------------------------
// Control

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    PartialSort,
    MergePass(u32),
    Fence(u32),
    Emit,
    Toplevel,
    Topdown,
    Done,
}

struct Control {
    phase: Phase,
    fill_block: u64,
    subs_in: u64,
    merging: bool,
    group: u64,
    pass_run_len: u64,
    pass_runs: u64,
    draining: bool,
    stream_done: bool,
    phase_start: Cycle,
    snap: [u64; 4],
}

impl Control {
    fn phase_name(&self, w: &KWorld) -> String {
        match self.phase {
            Phase::PartialSort => "partial_sort".into(),
            Phase::MergePass(p) | Phase::Fence(p) => format!("merge_pass_{}", p + 1),
            Phase::Emit => {
                if w.passes_total == 0 {
                    "sort_and_emit".into()
                } else {
                    format!("merge_pass_{}_and_emit", w.passes_total)
                }
            }
            Phase::Toplevel => "toplevel_sah".into(),
            Phase::Topdown => "topdown_compress".into(),
            Phase::Done => "done".into(),
        }
    }

    fn set_phase(&mut self, w: &mut KWorld, now: Cycle, p: Phase) {
        self.phase = p;
        let name = self.phase_name(w);
        w.phase_log.push((now, name));
    }

    fn end_phase(&mut self, w: &mut KWorld, now: Cycle) {
        let a = &w.acc;
        let t = [
            a.read_bytes.get(now),
            a.write_bytes.get(now),
            a.reads.get(now),
            a.read_latency.get(now),
        ];
        let reads = t[2] - self.snap[2];
        w.phases.push(PhaseReport {
            name: self.phase_name(w),
            start_cycle: self.phase_start,
            end_cycle: now,
            bytes_read: t[0] - self.snap[0],
            bytes_written: t[1] - self.snap[1],
            reads,
            read_latency_mean_cycles: if reads == 0 {
                0.0
            } else {
                (t[3] - self.snap[3]) as f64 / reads as f64
            },
        });
        self.snap = t;
        self.phase_start = now;
    }

    fn start_pass(&mut self, w: &mut KWorld, cx: &mut Ctx, p: u32) {
        let fan = w.cfg.fan_in();
        self.pass_run_len = w.cfg.m as u64 * fan.pow(p);
        self.pass_runs = w.npad.div_ceil(self.pass_run_len);
        self.group = 0;
        let to_emitter = p + 1 == w.passes_total;
        if to_emitter {
            w.emit_active.set(cx.now(), true);
            cx.notify(EMITTER, cx.now() + 1);
        }
        let ph = if to_emitter {
            Phase::Emit
        } else {
            Phase::MergePass(p)
        };
        self.set_phase(w, cx.now(), ph);
        self.setup_group(w, cx, p);
    }

    fn setup_group(&mut self, w: &mut KWorld, cx: &mut Ctx, p: u32) {
        let fan = w.cfg.fan_in();
        let first = self.group * fan;
        let last = (first + fan).min(self.pass_runs);
        let c = MergeCmd::Multi {
            first,
            last,
            run_len: self.pass_run_len,
            src: (p % 2) as u8,
            to_emitter: p + 1 == w.passes_total,
        };
        w.cmd
            .push(cx, c)
            .expect("the merger took the previous command");
        self.merging = true;
    }

    /// True when every write buffer was empty and no request was outstanding at the start
    /// of the cycle.
    fn drained(w: &KWorld, now: Cycle) -> bool {
        w.nodes.start_pending(now) == 0
            && w.leaves.start_pending(now) == 0
            && w.hl.start_pending(now) == 0
            && w.inflight.get(now) == 0
    }
}

impl<'a> Unit<KWorld<'a>> for Control {
    fn name(&self) -> &str {
        "control"
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        match self.phase {
            Phase::PartialSort => {
                while w.sub_ready.pop(cx).is_some() {
                    self.subs_in += 1;
                }
                if self.merging {
                    if w.merge_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.merging = false;
                    self.fill_block += 1;
                    if self.fill_block == w.blocks {
                        if w.passes_total == 0 {
                            self.set_phase(w, now, Phase::Emit);
                            return Wake::Next;
                        }
                        self.end_phase(w, now);
                        self.set_phase(w, now, Phase::Fence(0));
                        return Wake::Next;
                    }
                    w.scratch_open.set(now, self.fill_block);
                    cx.notify(UnitId(PRESORTER0), now + 1);
                    return Wake::OnEvent;
                }
                let nsub = w.subs_of_block(self.fill_block);
                if self.subs_in < nsub {
                    return Wake::OnEvent;
                }
                self.subs_in -= nsub;
                let first = self.fill_block * w.cfg.m as u64 / (2 * w.cfg.b as u64);
                let c = MergeCmd::Partial {
                    first,
                    count: nsub,
                    to_emitter: w.blocks == 1,
                };
                w.cmd.push(cx, c).expect("the merger is idle");
                w.scratch_open.set(now, CLOSED);
                self.merging = true;
                cx.set_state(State::Busy);
                Wake::OnEvent
            }
            Phase::Fence(p) => {
                if w.acc.run_acked.get(now) < w.npad * (p as u64 + 1) {
                    return Wake::Next; // polls the arbiter's total
                }
                self.start_pass(w, cx, p);
                Wake::Next
            }
            Phase::MergePass(p) => {
                if w.merge_done.pop(cx).is_none() {
                    return Wake::OnEvent;
                }
                self.merging = false;
                self.group += 1;
                if self.group < self.pass_runs.div_ceil(w.cfg.fan_in()) {
                    self.setup_group(w, cx, p);
                    return Wake::OnEvent;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Fence(p + 1));
                Wake::Next
            }
            Phase::Emit => {
                // The final merge's done token is not needed: the emitter ends the phase.
                let _ = w.merge_done.pop(cx);
                let streaming = w.cfg.output == OutputMode::CbvhStream;
                if !self.draining {
                    if w.emit_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    // The streaming encoder writes node pairs until it is done.
                    if !streaming {
                        w.nodes.set_flush(cx, true);
                    }
                    w.leaves.set_flush(cx, true);
                    w.hl.set_flush(cx, true);
                    return Wake::Next;
                }
                if streaming && !self.stream_done {
                    if w.stream_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.stream_done = true;
                    w.nodes.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.draining = false;
                self.end_phase(w, now);
                w.build_cycles = now + 1;
                if w.cfg.toplevel_sah && w.out.roots.len() > 1 {
                    w.top_start.push(cx, ()).expect("one start");
                    w.hl.set_flush(cx, false);
                    self.set_phase(w, now, Phase::Toplevel);
                    return Wake::OnEvent;
                }
                if w.cfg.output == OutputMode::CbvhTopdown {
                    w.nodes = KBuf::new(
                        WriteBuffer::new(
                            w.layout.cbvh,
                            w.cfg.node_buffer_bytes as u64,
                            w.cfg.write_chunk_bytes as u64,
                        ),
                        [w.ids.topdown, w.ids.topdown],
                    );
                    w.td_start.push(cx, ()).expect("one start");
                    self.set_phase(w, now, Phase::Topdown);
                    return Wake::OnEvent;
                }
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Toplevel => {
                if !self.draining {
                    if w.top_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    w.hl.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Topdown => {
                if !self.draining {
                    if w.td_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    w.nodes.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Done => Wake::Done,
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "phase {:?}, block {}, {} sub-blocks in, merging {}, group {}, draining {}",
            self.phase, self.fill_block, self.subs_in, self.merging, self.group, self.draining
        )
    }
}

// ---------------------------------------------------------------------------------------
// Hierarchy emitter

struct Emitter {
    e: EmitUnit,
}

const EMIT_STARVED: u8 = 0;
const EMIT_WRITE_FULL: u8 = 1;
const EMIT_ENCODER_FULL: u8 = 2;

/// The emitter's channels in the kernel world.
struct KPorts<'c, 'w> {
    cx: &'c mut Ctx,
    input: &'w mut LatencyFifo<Elem>,
    enc: Option<&'w mut LatencyFifo<cbvh::bottomup::InputNode>>,
    nodes: &'w mut KBuf,
    leaves: &'w mut KBuf,
    hl: &'w mut KBuf,
}

impl EmitPorts for KPorts<'_, '_> {
    #[inline]
    fn drop_padding(&mut self) {
        while self.input.peek(self.cx).is_some_and(|e| e.is_pad()) {
            self.input.pop(self.cx);
        }
    }
    #[inline]
    fn pop(&mut self) -> Option<Elem> {
        self.input.pop(self.cx)
    }
    #[inline]
    fn encoder_attached(&self) -> bool {
        self.enc.is_some()
    }
    #[inline]
    fn node_room(&self) -> bool {
        match &self.enc {
            Some(f) => !f.is_full(self.cx),
            None => self.nodes.has_room(self.cx.now(), NODE_BYTES),
        }
    }
    #[inline]
    fn leaf_room(&self) -> bool {
        self.leaves.has_room(self.cx.now(), LEAF_ENTRY_BYTES)
    }
    #[inline]
    fn highlevel_room(&self) -> bool {
        self.hl.has_room(self.cx.now(), HIGHLEVEL_BYTES)
    }
    #[inline]
    fn add_node(&mut self) {
        self.nodes.add(self.cx, NODE_BYTES);
    }
    fn push_encoder(&mut self, n: cbvh::bottomup::InputNode) {
        let f = self.enc.as_mut().expect("an encoder attached");
        if f.push(self.cx, n).is_err() {
            unreachable!("room in the encoder FIFO was checked before the step");
        }
    }
    #[inline]
    fn add_leaf(&mut self) {
        self.leaves.add(self.cx, LEAF_ENTRY_BYTES);
    }
    #[inline]
    fn add_highlevel(&mut self) {
        self.hl.add(self.cx, HIGHLEVEL_BYTES);
    }
}

impl<'a> Unit<KWorld<'a>> for Emitter {
    fn name(&self) -> &str {
        "emitter"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["input empty", "write buffer full", "encoder full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if !w.emit_active.get(now) {
            return Wake::Done;
        }
        let streaming = w.cfg.output == OutputMode::CbvhStream;
        let KWorld {
            emit_fifo,
            enc_fifo,
            nodes,
            leaves,
            hl,
            ..
        } = w;
        let mut io = KPorts {
            cx: &mut *cx,
            input: emit_fifo,
            enc: streaming.then_some(enc_fifo),
            nodes,
            leaves,
            hl,
        };
        let consumed = self.e.consumed;
        let st = self.e.tick_with(&mut io);
        if let Some(f) = self.e.fault.take() {
            w.out.fault = Some(f);
        }
        match st {
            EmitStatus::Stepped => {
                cx.set_state(State::Busy);
                w.trace.row(now).emitter_steps += 1;
                if self.e.consumed > consumed {
                    w.worked(1);
                }
                if self.e.done {
                    w.out.nodes = std::mem::take(&mut self.e.nodes);
                    w.out.roots = std::mem::take(&mut self.e.roots);
                    w.out.order = std::mem::take(&mut self.e.order);
                    w.out.max_stack_depth = self.e.max_stack_depth();
                    w.out.cbvh_ids = self.e.cbvh_ids.take();
                    w.emit_finished.set(now, true);
                    cx.notify(w.ids.stream, now + 1);
                    w.emit_done.push(cx, ()).expect("one done token");
                    cx.set_state(State::Idle);
                    return Wake::Done;
                }
                Wake::Next
            }
            EmitStatus::Starved => {
                cx.set_state(State::Stalled(EMIT_STARVED));
                Wake::OnEvent
            }
            EmitStatus::WriteFull => {
                cx.set_state(State::Stalled(EMIT_WRITE_FULL));
                Wake::OnEvent
            }
            EmitStatus::EncoderFull => {
                cx.set_state(State::Stalled(EMIT_ENCODER_FULL));
                Wake::OnEvent
            }
            EmitStatus::Finished => {
                cx.set_state(State::Idle);
                Wake::Done
            }
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("steps", self.e.steps), ("consumed", self.e.consumed)]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!("{} read, done {}", self.e.consumed, self.e.done)
    }
}

// ---------------------------------------------------------------------------------------
// Toplevel SAH unit

struct Toplevel {
    t: Option<TopUnit>,
    busy: u64,
    busy_until: Cycle,
}

impl<'a> Unit<KWorld<'a>> for Toplevel {
    fn name(&self) -> &str {
        "toplevel"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["write buffer full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if now < self.busy_until {
            return Wake::At(self.busy_until);
        }
        if self.t.is_none() {
            if w.top_start.pop(cx).is_none() {
                return Wake::Done;
            }
            self.t = Some(TopUnit::new(&w.out.roots, &w.cfg));
        }
        let t = self.t.as_mut().expect("started");
        if !t.done() {
            let k = t.left();
            if k > 0 {
                w.trace.span(now, now + k, |r| &mut r.toplevel_busy);
                t.spend(k);
                self.busy += k;
                self.busy_until = now + k;
                cx.set_state(State::Busy);
                return Wake::At(now + k);
            }
            if !w.hl.has_room(now, NODE_BYTES) {
                cx.set_state(State::Stalled(0));
                return Wake::OnEvent;
            }
            w.hl.add(cx, NODE_BYTES);
            t.finish_sweep();
            if !t.done() {
                cx.set_state(State::Busy);
                return Wake::Next;
            }
        }
        w.out.top = self.t.take();
        w.top_done.push(cx, ()).expect("one done token");
        cx.set_state(State::Idle);
        Wake::Done
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("busy_cycles", self.busy)]
    }
}

// ---------------------------------------------------------------------------------------
// Multi-merge unit

struct MergeUnit {
    m: Merger,
    active: bool,
    to_emitter: bool,
    src: u8,
    /// Buffer halves to refill, collected in a step (allocated once).
    refills: VecDeque<u32>,
}

const MERGE_DRY: u8 = 0;
const MERGE_FULL: u8 = 1;
const MERGE_INIT: u8 = 2;

struct KMergeOut<'c, 'w> {
    cx: &'c mut Ctx,
    out: &'w mut LatencyFifo<Elem>,
    refills: &'w mut VecDeque<u32>,
}

impl MergeOut for KMergeOut<'_, '_> {
    #[inline]
    fn is_full(&self) -> bool {
        self.out.is_full(self.cx)
    }
    #[inline]
    fn push(&mut self, e: Elem) {
        let _ = self.out.push(self.cx, e);
    }
    #[inline]
    fn refill(&mut self, buf: u32) {
        self.refills.push_back(buf);
    }
}

impl MergeUnit {
    fn push_refills(&mut self, w: &mut KWorld, cx: &mut Ctx) {
        while let Some(buf) = self.refills.pop_front() {
            let (pos, count) = self.m.peek_fetch(buf);
            self.m.commit_fetch(buf, count);
            let f = Fetch {
                buf,
                region: self.src,
                pos,
                count,
            };
            if w.refill.push(cx, f).is_err() {
                unreachable!("the refill FIFO holds two halves per queue");
            }
        }
    }
}

impl<'a> Unit<KWorld<'a>> for MergeUnit {
    fn name(&self) -> &str {
        "merge"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["queue dry", "output full", "init wait"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        while let Some(f) = w.fill.pop(cx) {
            let s = f.pos as usize;
            let src = &w.region[f.region as usize][s..s + f.count as usize];
            let (aabbs, codes) = (w.aabbs, &w.codes);
            self.m.fill_with(f.buf, src.len(), |k| {
                let r = src[k];
                match aabbs.get(r as usize) {
                    Some(&a) => Elem::new(codes[r as usize], r, a),
                    None => Elem::pad(r as u64),
                }
            });
        }
        if !self.active {
            let Some(c) = w.cmd.pop(cx) else {
                cx.set_state(State::Idle);
                return Wake::Done;
            };
            self.active = true;
            match c {
                MergeCmd::Partial {
                    first,
                    count,
                    to_emitter,
                } => {
                    std::mem::swap(&mut self.m.scratch, &mut w.scratch);
                    self.to_emitter = to_emitter;
                    let w = &*w;
                    self.m
                        .setup_partial((first..first + count).map(|s| w.sub_len(s)), now);
                }
                MergeCmd::Multi {
                    first,
                    last,
                    run_len,
                    src,
                    to_emitter,
                } => {
                    self.to_emitter = to_emitter;
                    self.src = src;
                    let npad = w.npad;
                    self.m.setup_multi(
                        (first..last).map(|r| (r * run_len, (npad - r * run_len).min(run_len))),
                        &mut self.refills,
                        now,
                    );
                    self.push_refills(w, cx);
                }
            }
            cx.set_state(State::Busy);
        }
        let before = self.m.outputs;
        let slot = {
            let out = if self.to_emitter {
                &mut w.emit_fifo
            } else {
                &mut w.run_fifo
            };
            let mut o = KMergeOut {
                cx: &mut *cx,
                out,
                refills: &mut self.refills,
            };
            self.m.tick_with(now, &mut o)
        };
        if self.m.outputs > before {
            w.trace.row(now).merge_outputs += self.m.outputs - before;
            w.worked(self.m.outputs - before);
        }
        self.push_refills(w, cx);
        if self.m.state == MergeState::Done {
            self.m.state = MergeState::Idle;
            self.active = false;
            w.merge_done
                .push(cx, ())
                .expect("the control took the last token");
            cx.set_state(State::Idle);
            return Wake::Next; // the next command may be there
        }
        match slot {
            Slot::Worked | Slot::Closed => {
                cx.set_state(State::Busy);
                Wake::At(self.m.next_op)
            }
            Slot::QueueDry => {
                cx.set_state(State::Stalled(MERGE_DRY));
                Wake::OnEvent
            }
            Slot::OutputFull => {
                cx.set_state(State::Stalled(MERGE_FULL));
                Wake::OnEvent
            }
            Slot::InitWait => {
                cx.set_state(State::Stalled(MERGE_INIT));
                Wake::OnEvent
            }
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("outputs", self.m.outputs), ("heap_ops", self.m.ops)]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{:?}, heap {} live, next op at {}",
            self.m.state,
            self.m.heap.live(),
            self.m.next_op
        )
    }
}

// ---------------------------------------------------------------------------------------
// Reader

struct Reader {
    in_next: u64,
    in_p: u32,
    second_half: bool,
    /// Ring slots of each presorter allocated and not yet freed.
    alloc: Vec<u32>,
    tail: Vec<u32>,
    slots: u32,
}

const READER_RING_FULL: u8 = 0;
const READER_REQ_FULL: u8 = 1;

impl<'a> Unit<KWorld<'a>> for Reader {
    fn name(&self) -> &str {
        "reader"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["presorter ring full", "request slot full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        for (a, f) in self.alloc.iter_mut().zip(w.ps_credit.iter_mut()) {
            while f.pop(cx).is_some() {
                *a -= 1;
            }
        }
        let input = self.in_next < w.npad;
        if !input && w.refill.peek(cx).is_none() {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        if input && self.alloc[self.in_p as usize] == self.slots {
            cx.set_state(State::Stalled(READER_RING_FULL));
            return Wake::OnEvent;
        }
        if w.req_read.is_full(cx) {
            cx.set_state(State::Stalled(READER_REQ_FULL));
            return Wake::OnEvent;
        }
        let req = if input {
            let b = w.cfg.b as u64;
            let p = self.in_p as usize;
            let slot = self.tail[p];
            self.tail[p] = if slot + 1 == self.slots { 0 } else { slot + 1 };
            self.alloc[p] += 1;
            let real = w.n.min(self.in_next + b) - self.in_next;
            let r = Req {
                addr: w.layout.input + self.in_next * ELEM_BYTES,
                bytes: (real * ELEM_BYTES) as u32,
                kind: AccessKind::Read,
                dest: Dest::Presort {
                    p: self.in_p,
                    read: InputRead {
                        slot,
                        src: self.in_next,
                        count: b as u32,
                    },
                },
            };
            self.in_next += b;
            // Two buffers make a sub-block; sub-blocks go round robin to presorters.
            self.second_half = !self.second_half;
            if !self.second_half {
                self.in_p += 1;
                if self.in_p == w.cfg.presorters {
                    self.in_p = 0;
                }
            }
            r
        } else {
            let f = w.refill.pop(cx).expect("peeked");
            Req {
                addr: w.layout.runs[f.region as usize]
                    + run_offset(f.pos, w.cfg.m as u64, w.cfg.run_gap_bytes as u64),
                bytes: f.count * ELEM_BYTES as u32,
                kind: AccessKind::Read,
                dest: Dest::Merge(f),
            }
        };
        if w.req_read.push(cx, req).is_err() {
            unreachable!("checked");
        }
        cx.set_state(State::Busy);
        Wake::Next
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!("input at {}, presorter {}", self.in_next, self.in_p)
    }
}

// ---------------------------------------------------------------------------------------
// Run writer

struct RunWriter {
    staged: u32,
    written: u64,
    b: u32,
    npad: u64,
}

impl<'a> Unit<KWorld<'a>> for RunWriter {
    fn name(&self) -> &str {
        "run writer"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["request slot full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        while self.staged < self.b {
            let Some(e) = w.run_fifo.pop(cx) else { break };
            let c = self.written;
            let region = ((c / self.npad) % 2) as usize;
            w.region[region][(c % self.npad) as usize] = e.index;
            self.written += 1;
            self.staged += 1;
        }
        if self.staged < self.b {
            cx.set_state(State::Idle);
            return if self.staged == 0 {
                Wake::Done
            } else {
                Wake::OnEvent
            };
        }
        let start = self.written - self.b as u64;
        let region = ((start / self.npad) % 2) as usize;
        let bytes = self.b * ELEM_BYTES as u32;
        let req = Req {
            addr: w.layout.runs[region]
                + run_offset(
                    start % self.npad,
                    w.cfg.m as u64,
                    w.cfg.run_gap_bytes as u64,
                ),
            bytes,
            kind: AccessKind::Write,
            dest: Dest::Run { elems: self.b },
        };
        if w.req_run.push(cx, req).is_err() {
            cx.set_state(State::Stalled(0));
            return Wake::OnEvent;
        }
        self.staged = 0;
        cx.set_state(State::Busy);
        Wake::Next
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("elements", self.written)]
    }
}

// ---------------------------------------------------------------------------------------
// Memory arbiter

/// Requesters of the arbiter, in round-robin order.
const REQUESTERS: usize = 6;

struct Arbiter {
    rr: RoundRobin,
    slab: Vec<(Dest, u32)>,
    free: Vec<u32>,
    inflight: u64,
    burst: u32,
    /// The port accepts a refused request only after a response (then a refused arbiter
    /// sleeps until one arrives: the memory wakes it).
    lift_only_with_responses: bool,
}

impl Arbiter {
    #[inline]
    fn head(w: &KWorld, cx: &Ctx, i: usize) -> Option<Req> {
        let now = cx.now();
        let buf = |b: &KBuf| {
            b.ready(now).map(|(addr, bytes)| Req {
                addr,
                bytes,
                kind: AccessKind::Write,
                dest: Dest::Buffer,
            })
        };
        match i {
            0 => w.req_run.peek(cx).copied(),
            1 => buf(&w.nodes),
            2 => buf(&w.leaves),
            3 => buf(&w.hl),
            4 => w.req_read.peek(cx).copied(),
            _ => w.req_cbvh.peek(cx).copied(),
        }
    }
}

impl<'a> Unit<KWorld<'a>> for Arbiter {
    fn name(&self) -> &str {
        "memory arbiter"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["port refused"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        while let Some(r) = w.mem.pop(cx) {
            self.inflight -= 1;
            let (d, bytes) = self.slab[r.tag as usize];
            self.free.push(r.tag as u32);
            let latency = r.completed_cycle - r.accepted_cycle;
            if r.kind == AccessKind::Read {
                w.acc.reads.add(now, 1);
                w.acc.read_latency.add(now, latency);
            }
            match d {
                Dest::Run { elems } => w.acc.run_acked.add(now, elems as u64),
                Dest::Buffer => {}
                Dest::Presort { p, read } => {
                    if w.ps_data[p as usize].push(cx, read).is_err() {
                        unreachable!("one entry per ring slot");
                    }
                }
                Dest::Merge(f) => {
                    if w.fill.push(cx, f).is_err() {
                        unreachable!("one entry per buffer half");
                    }
                }
                Dest::Backtrack => {
                    if w.bt_data.push(cx, latency).is_err() {
                        unreachable!("one backtracking read at a time");
                    }
                }
                Dest::Topdown { j } => {
                    if w.td_data.push(cx, (j, latency)).is_err() {
                        unreachable!("one entry per node");
                    }
                }
            }
            w.trace.row(now).bus_bytes += bytes as u64;
        }
        let Arbiter {
            rr,
            slab,
            free,
            inflight,
            burst,
            ..
        } = self;
        let mut refused = false;
        if !(0..REQUESTERS).any(|i| Self::head(w, cx, i).is_some()) {
            // Nothing to issue: no arbitration.
            w.inflight.set(now, *inflight);
            cx.set_state(State::Idle);
            return if *inflight > 0 {
                Wake::OnEvent
            } else {
                Wake::Done
            };
        }
        let granted = rr.arbitrate(|i| {
            let Some(req) = Self::head(w, cx, i) else {
                return Offer::Nothing;
            };
            let tag = match free.pop() {
                Some(t) => {
                    slab[t as usize] = (req.dest, req.bytes);
                    t
                }
                None => {
                    slab.push((req.dest, req.bytes));
                    (slab.len() - 1) as u32
                }
            };
            let m = MemRequest {
                tag: tag as u64,
                addr: req.addr,
                bytes: req.bytes,
                kind: req.kind,
            };
            if w.mem.send(cx, m).is_err() {
                free.push(tag);
                refused = true;
                return Offer::Refused;
            }
            *inflight += 1;
            match i {
                0 => {
                    w.req_run.pop(cx);
                }
                1 => w.nodes.issued(cx, req.bytes),
                2 => w.leaves.issued(cx, req.bytes),
                3 => w.hl.issued(cx, req.bytes),
                4 => {
                    w.req_read.pop(cx);
                }
                _ => {
                    w.req_cbvh.pop(cx);
                }
            }
            let bb = *burst;
            let b = crate::dram::bursts_of(req.addr, req.bytes, bb) * bb as u64;
            match req.kind {
                AccessKind::Read => w.acc.read_bytes.add(now, b),
                AccessKind::Write => w.acc.write_bytes.add(now, b),
            }
            Offer::Granted
        });
        w.inflight.set(now, self.inflight);
        cx.set_state(if granted > 0 {
            State::Busy
        } else if refused {
            State::Stalled(0)
        } else {
            State::Idle
        });
        // After a grant, step once more to end the busy cycle. Refused with nothing granted:
        // retry in the next cycle, or, when only a response can make room, at the response.
        if granted == 0 && refused && self.lift_only_with_responses {
            Wake::OnEvent
        } else if granted > 0 || (0..REQUESTERS).any(|i| Self::head(w, cx, i).is_some()) {
            Wake::Next
        } else if self.inflight > 0 {
            Wake::OnEvent
        } else {
            Wake::Done
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let s = self.rr.stats();
        vec![
            ("grants", s.grants.iter().sum()),
            ("refusal_episodes", s.refusals.iter().sum()),
        ]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!("{} requests in flight", self.inflight)
    }
}

// ---------------------------------------------------------------------------------------
// Streaming CBVH encoder (see [`super::cbvh_unit`] for the model)

struct Stream {
    enc: Option<cbvh::bottomup::StreamEncoder>,
    ops: VecDeque<cbvh::bottomup::MemOp>,
    awaiting_read: bool,
    flushing: bool,
    ended: bool,
    done: bool,
    stats: StreamUnitStats,
    flush_before_read: bool,
}

const ST_STARVED: u8 = 0;
const ST_READ_WAIT: u8 = 1;
const ST_FLUSH_WAIT: u8 = 2;
const ST_WRITE_FULL: u8 = 3;
const ST_REQ_FULL: u8 = 4;

impl Stream {
    fn read_returned(&mut self, latency: u64) {
        self.awaiting_read = false;
        self.stats.backtrack_read_latency_cycles += latency;
        let bucket = (63 - latency.max(1).leading_zeros()) as usize;
        let h = &mut self.stats.backtrack_read_latency_log2;
        if h.len() <= bucket {
            h.resize(bucket + 1, 0);
        }
        h[bucket] += 1;
    }

    fn step_inner(&mut self, w: &mut KWorld, cx: &mut Ctx) -> Result<Wake, cbvh::CbvhError> {
        use cbvh::bottomup::MemOp;
        let now = cx.now();
        while let Some(lat) = w.bt_data.pop(cx) {
            self.read_returned(lat);
        }
        if self.done {
            return Ok(Wake::Done);
        }
        if self.awaiting_read {
            cx.set_state(State::Stalled(ST_READ_WAIT));
            return Ok(Wake::OnEvent);
        }
        let enc = self.enc.as_mut().expect("encoder until done");
        match self.ops.front().copied() {
            Some(MemOp::WritePair { bytes, .. }) => {
                if !w.nodes.has_room(now, bytes as u64) {
                    cx.set_state(State::Stalled(ST_WRITE_FULL));
                    return Ok(Wake::OnEvent);
                }
                w.nodes.add(cx, bytes as u64);
                self.ops.pop_front();
                self.stats.pairs_written += 1;
                cx.set_state(State::Busy);
                Ok(Wake::Next)
            }
            Some(MemOp::BacktrackRead {
                addr_bytes, bytes, ..
            }) => {
                // A line with bytes still in the write buffer is written out first.
                let pending = self.flush_before_read
                    && w.nodes.start_pending(now) > 0
                    && w.nodes.start_next_addr(now) < addr_bytes + bytes as u64;
                if pending {
                    if !self.flushing {
                        self.flushing = true;
                        self.stats.backtrack_flushes += 1;
                        w.nodes.flush_through(cx, addr_bytes + bytes as u64);
                    }
                    cx.set_state(State::Stalled(ST_FLUSH_WAIT));
                    return Ok(Wake::OnEvent); // the buffer's writes wake us
                }
                let req = Req {
                    addr: addr_bytes,
                    bytes,
                    kind: AccessKind::Read,
                    dest: Dest::Backtrack,
                };
                if w.req_cbvh.push(cx, req).is_err() {
                    cx.set_state(State::Stalled(ST_REQ_FULL));
                    return Ok(Wake::OnEvent);
                }
                self.ops.pop_front();
                self.awaiting_read = true;
                self.flushing = false;
                self.stats.backtrack_reads += 1;
                cx.set_state(State::Stalled(ST_READ_WAIT));
                Ok(Wake::OnEvent)
            }
            Some(MemOp::BacktrackWrite {
                addr_bytes, bytes, ..
            }) => {
                let req = Req {
                    addr: addr_bytes,
                    bytes,
                    kind: AccessKind::Write,
                    dest: Dest::Buffer,
                };
                if w.req_cbvh.push(cx, req).is_err() {
                    cx.set_state(State::Stalled(ST_REQ_FULL));
                    return Ok(Wake::OnEvent);
                }
                self.ops.pop_front();
                self.stats.backtrack_writes += 1;
                cx.set_state(State::Busy);
                Ok(Wake::Next)
            }
            None => {
                if let Some(n) = w.enc_fifo.pop(cx) {
                    enc.push(n)?;
                    self.ops.extend(enc.drain_ops());
                    self.stats.nodes_in += 1;
                    cx.set_state(State::Busy);
                    Ok(Wake::Next)
                } else if w.emit_finished.get(now) && !self.ended {
                    // The root's treelet (or the root itself) is written last.
                    enc.end_stream()?;
                    self.ops.extend(enc.drain_ops());
                    self.ended = true;
                    cx.set_state(State::Busy);
                    Ok(Wake::Next)
                } else if self.ended {
                    self.done = true;
                    w.out.stream = Some((self.enc.take().expect("once"), self.stats.clone()));
                    w.stream_done.push(cx, ()).expect("one done token");
                    cx.set_state(State::Idle);
                    Ok(Wake::Done)
                } else {
                    cx.set_state(State::Stalled(ST_STARVED));
                    Ok(Wake::OnEvent)
                }
            }
        }
    }
}

impl<'a> Unit<KWorld<'a>> for Stream {
    fn name(&self) -> &str {
        "cbvh encoder"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &[
            "input empty",
            "read wait",
            "flush wait",
            "write buffer full",
            "request slot full",
        ]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        if self.enc.is_none() && !self.done {
            return Wake::Done; // not attached
        }
        match self.step_inner(w, cx) {
            Ok(wake) => wake,
            Err(e) => {
                w.out.fault = Some(e);
                self.done = true;
                w.stream_done.push(cx, ()).expect("one done token");
                Wake::Done
            }
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{} nodes in, {} ops queued (front {:?}), awaiting read {}, ended {}, done {}",
            self.stats.nodes_in,
            self.ops.len(),
            self.ops.front(),
            self.awaiting_read,
            self.ended,
            self.done
        )
    }
}

// ---------------------------------------------------------------------------------------
// Top-down CBVH pass (see [`super::cbvh_unit`] for the model)

struct Topdown {
    started: bool,
    nodes: u64,
    next_read: u64,
    arrived: Vec<bool>,
    next_encode: u64,
    pairs: u64,
    pair_bytes: u64,
    stats: TopdownStats,
}

const TD_READ_WAIT: u8 = 0;
const TD_WRITE_FULL: u8 = 1;

impl<'a> Unit<KWorld<'a>> for Topdown {
    fn name(&self) -> &str {
        "topdown pass"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["read wait", "write buffer full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if !self.started {
            if w.td_start.pop(cx).is_none() {
                return Wake::Done;
            }
            self.started = true;
            self.nodes = w.out.nodes.len() as u64;
            self.arrived = vec![false; self.nodes as usize];
            self.pairs = self.nodes.max(1);
            w.td_data = fifo(
                "arbiter->topdown",
                self.nodes as usize,
                ARBITER,
                w.ids.topdown,
            );
        }
        if self.next_encode == self.pairs {
            return Wake::Done;
        }
        while let Some((j, lat)) = w.td_data.pop(cx) {
            self.arrived[j as usize] = true;
            self.stats.read_latency_cycles += lat;
        }
        // One node read offered per cycle, from the end of the node array backwards.
        let mut issued = false;
        if self.next_read < self.nodes && !w.req_cbvh.is_full(cx) {
            let k = self.nodes - 1 - self.next_read;
            let req = Req {
                addr: w.layout.nodes + k * NODE_BYTES,
                bytes: NODE_BYTES as u32,
                kind: AccessKind::Read,
                dest: Dest::Topdown { j: self.next_read },
            };
            if w.req_cbvh.push(cx, req).is_err() {
                unreachable!("checked");
            }
            self.next_read += 1;
            self.stats.node_reads += 1;
            issued = true;
        }
        // A tree that is one leaf has no node to read: its box is the root record.
        let here = self.nodes == 0 || self.arrived[self.next_encode as usize];
        let wake = if !here {
            cx.set_state(State::Stalled(TD_READ_WAIT));
            Wake::OnEvent
        } else if !w.nodes.has_room(now, self.pair_bytes) {
            cx.set_state(State::Stalled(TD_WRITE_FULL));
            Wake::OnEvent
        } else {
            w.nodes.add(cx, self.pair_bytes);
            self.next_encode += 1;
            self.stats.pairs_written += 1;
            cx.set_state(State::Busy);
            if self.next_encode == self.pairs {
                w.out.topdown = Some(self.stats.clone());
                w.td_done.push(cx, ()).expect("one done token");
                cx.set_state(State::Idle);
                return Wake::Done;
            }
            Wake::Next
        };
        if issued || (self.next_read < self.nodes && !w.req_cbvh.is_full(cx)) {
            Wake::Next
        } else {
            wake
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{}/{} read, {}/{} encoded",
            self.next_read, self.nodes, self.next_encode, self.pairs
        )
    }
}

// ---------------------------------------------------------------------------------------
// Presorters

/// One presorter of the bank, with its own busy / stall intervals.
struct PresortUnit {
    p: u32,
    ps: Presorter,
    acct: Acct,
    b: u32,
    subs_per_block: u64,
    total_subs: u64,
    count: u64,
}

const PS_STARVED: u8 = 0;
const PS_WAIT: u8 = 1;

impl PresortUnit {
    /// One presorter's step (the unit contract holds per presorter: a step it did not ask
    /// for changes nothing).
    fn step(&mut self, w: &mut KWorld, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let b = self.b;
        let ps = &mut self.ps;
        while let Some(r) = w.ps_data[self.p as usize].pop(cx) {
            let base = r.slot as usize * b as usize;
            for i in 0..r.count as usize {
                let e = elem_of(w.aabbs, &w.quant, w.cfg.morton_bits, r.src + i as u64);
                if !e.is_pad() {
                    if let Some(c) = w.codes.get_mut(e.index as usize) {
                        *c = e.code;
                    }
                }
                ps.ring[base + i] = e;
            }
            ps.slot_count[r.slot as usize] = r.count;
            ps.slot_valid[r.slot as usize] = true;
            ps.used += 1;
        }
        match ps.state {
            PresortState::Finished => {
                self.acct.set(now, State::Idle);
                return Wake::Done;
            }
            PresortState::Sorting => {
                if now < ps.busy_until {
                    return Wake::At(ps.busy_until);
                }
                if ps.sorted(now) {
                    ps.state = PresortState::Draining { pos: 0 };
                } else {
                    let used = ps.used;
                    if !ps.insert_next(now, b) {
                        self.acct.set(now, State::Stalled(PS_STARVED));
                        return Wake::OnEvent;
                    }
                    if ps.used < used && w.ps_credit[self.p as usize].push(cx, ()).is_err() {
                        unreachable!("one credit per ring slot");
                    }
                    w.trace.span(now, ps.busy_until, |r| &mut r.presort_busy);
                    self.acct.set(now, State::Busy);
                    return Wake::At(ps.busy_until);
                }
            }
            PresortState::Draining { .. } => {}
        }
        let PresortState::Draining { pos } = ps.state else {
            unreachable!("draining")
        };
        if w.scratch_open.get(now) != ps.block {
            self.acct.set(now, State::Stalled(PS_WAIT));
            return Wake::OnEvent; // the control's register change wakes us
        }
        if w.scratch_port == now {
            self.acct.set(now, State::Stalled(PS_WAIT));
            return Wake::Next; // the write port is taken this cycle
        }
        w.scratch_port = now;
        let slot = (ps.sub % self.subs_per_block) * 2 * b as u64;
        w.scratch[(slot + pos as u64) as usize] = ps.buf[pos as usize];
        w.trace.row(now).presort_busy += 1;
        self.acct.set(now, State::Busy);
        if pos + 1 == ps.sub_len {
            if w.sub_ready.push(cx, ()).is_err() {
                unreachable!("room for every sub-block");
            }
            let next = ps.sub + self.count;
            if next < self.total_subs {
                let len = w.sub_len(next);
                ps.start(next, len, next / self.subs_per_block);
            } else {
                ps.state = PresortState::Finished;
            }
        } else {
            ps.state = PresortState::Draining { pos: pos + 1 };
        }
        Wake::Next
    }

    fn describe(&self) -> String {
        let p = &self.ps;
        format!(
            "{:?}, sub-block {} {}/{} inserted, ring {}/{} used",
            p.state,
            p.sub,
            p.inserted,
            p.sub_len,
            p.used,
            p.slots()
        )
    }
}

/// Busy / stall intervals of one presorter (the kernel's interval accounting, per
/// presorter inside the bank).
#[derive(Clone, Copy, Debug)]
struct Acct {
    state: State,
    since: Cycle,
    busy: u64,
    starved: u64,
    wait: u64,
}

impl Acct {
    fn new() -> Self {
        Self {
            state: State::Idle,
            since: 0,
            busy: 0,
            starved: 0,
            wait: 0,
        }
    }

    #[inline]
    fn set(&mut self, now: Cycle, st: State) {
        if st == self.state {
            return;
        }
        let d = now - self.since;
        match self.state {
            State::Busy => self.busy += d,
            State::Stalled(PS_STARVED) => self.starved += d,
            State::Stalled(_) => self.wait += d,
            State::Idle => {}
        }
        self.state = st;
        self.since = now;
    }
}

/// The presorters as one kernel unit (one step for all that are due, fewer units for the
/// scheduler to scan): busy while any presorter is, else stalled on input while any is,
/// else waiting for the scratchpad while any is. Each presorter's own intervals are kept
/// in the bank (presorter-cycles for the stall report; every presorter ends idle, so its
/// intervals are closed when the run ends).
struct PresortBank {
    units: Vec<PresortUnit>,
}

impl<'a> Unit<KWorld<'a>> for PresortBank {
    fn name(&self) -> &str {
        "presorters"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["input empty", "scratchpad wait"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let mut next = crate::kernel::NEVER;
        let mut all_done = true;
        let (mut busy, mut starved, mut wait) = (false, false, false);
        for u in &mut self.units {
            // Presorters that finished, or are inside an insertion (which nothing can
            // change before it ends; read data for their rings waits in their FIFO, which
            // they pop when they next need an element), are not stepped.
            let wake = match u.ps.state {
                PresortState::Finished => Wake::Done,
                PresortState::Sorting if now < u.ps.busy_until => Wake::At(u.ps.busy_until),
                _ => u.step(w, cx),
            };
            match wake {
                Wake::Next => next = next.min(now + 1),
                Wake::At(c) => next = next.min(c.max(now + 1)),
                Wake::OnEvent => all_done = false,
                Wake::Done => {}
            }
            match u.acct.state {
                State::Busy => busy = true,
                State::Stalled(PS_STARVED) => starved = true,
                State::Stalled(_) => wait = true,
                State::Idle => {}
            }
        }
        cx.set_state(if busy {
            State::Busy
        } else if starved {
            State::Stalled(PS_STARVED)
        } else if wait {
            State::Stalled(PS_WAIT)
        } else {
            State::Idle
        });
        if next != crate::kernel::NEVER {
            Wake::At(next)
        } else if all_done {
            Wake::Done
        } else {
            Wake::OnEvent
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let sum = |f: fn(&Acct) -> u64| self.units.iter().map(|u| f(&u.acct)).sum();
        vec![
            ("presorter_busy_cycles", sum(|a| a.busy)),
            ("presorter_starved_cycles", sum(|a| a.starved)),
            ("presorter_wait_cycles", sum(|a| a.wait)),
        ]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        self.units
            .iter()
            .map(|u| format!("presorter {}: {}", u.p, u.describe()))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

// ---------------------------------------------------------------------------------------
// Assembly

/// What a run of the kernel machine gives back.
pub(super) struct KRun {
    pub cycles: u64,
    pub run: RunReport,
    pub stalls: StallReport,
    pub phases: Vec<PhaseReport>,
    pub trace: Vec<TraceRow>,
    pub nodes: Vec<bvh::EmittedNode>,
    pub roots: Vec<bvh::HighlevelRoot>,
    pub order: Vec<u32>,
    pub max_stack_depth: usize,
    pub top: Option<TopUnit>,
    pub cbvh_ids: Option<Vec<u32>>,
    pub stream: Option<(cbvh::bottomup::StreamEncoder, StreamUnitStats)>,
    pub topdown: Option<TopdownStats>,
    pub build_cycles: u64,
    pub passes_total: u32,
    pub layout: MemoryLayout,
    pub mem: crate::dram::MemStats,
    pub dram: String,
    pub peak: f64,
}

/// Runs the kernel machine on `aabbs` (with at least one primitive; plain BVH output).
pub(super) fn run<'a>(
    aabbs: &'a [Aabb],
    centroid_bounds: &Aabb,
    cfg: &MergeTreeConfig,
    port: Box<dyn MemoryPort>,
    progress: Option<&'a mut dyn FnMut(u64, u64)>,
) -> Result<KRun, MergeTreeError> {
    let n = aabbs.len() as u64;
    if n == 0 {
        // Nothing to sort: the unit does not start.
        return Ok(KRun {
            cycles: 0,
            run: RunReport {
                cycles: 0,
                units: Vec::new(),
                steps: Vec::new(),
                stepped_cycles: 0,
            },
            stalls: StallReport::default(),
            phases: Vec::new(),
            trace: Vec::new(),
            nodes: Vec::new(),
            roots: Vec::new(),
            order: Vec::new(),
            max_stack_depth: 0,
            top: None,
            cbvh_ids: None,
            stream: None,
            topdown: None,
            build_cycles: 0,
            passes_total: 0,
            layout: MemoryLayout::new(0, 0, 1, 0),
            mem: port.stats(),
            dram: port.name(),
            peak: port.peak_bytes_per_unit_cycle(),
        });
    }
    let b = cfg.b as u64;
    let m = cfg.m as u64;
    let npad = n.div_ceil(b) * b;
    let blocks = npad.div_ceil(m).max(1);
    let fan = cfg.fan_in();
    let mut passes_total = 0;
    let mut runs = blocks;
    while runs > 1 {
        runs = runs.div_ceil(fan);
        passes_total += 1;
    }
    let layout = MemoryLayout::new(n, npad, m, cfg.run_gap_bytes as u64);
    let subs = npad.div_ceil(2 * b);
    let np = cfg.presorters as usize;
    let slots = cfg.presort_slots as usize;
    // The presorters are one unit, the bank.
    let presorter = |_p: u32| UnitId(PRESORTER0);
    let mut next = PRESORTER0 + 1;
    let mut take = |used: bool| {
        if used {
            next += 1;
            UnitId(next - 1)
        } else {
            UnitId::EXTERNAL
        }
    };
    let ids = Optional {
        toplevel: take(cfg.toplevel_sah),
        stream: take(cfg.output == OutputMode::CbvhStream),
        topdown: take(cfg.output == OutputMode::CbvhTopdown),
    };
    let (toplevel, stream, topdown) = (ids.toplevel, ids.stream, ids.topdown);
    let region_len = |needed: bool| if needed { npad as usize } else { 0 };
    let streaming = cfg.output == OutputMode::CbvhStream;
    let wb = |base: u64, cap: u32| WriteBuffer::new(base, cap as u64, cfg.write_chunk_bytes as u64);
    let mut w = KWorld {
        cfg: cfg.clone(),
        aabbs,
        quant: MortonQuantizer::with_grid(centroid_bounds, cfg.morton_grid),
        n,
        npad,
        blocks,
        passes_total,
        layout,
        mem: Memory::new(port),
        cmd: fifo("control->merge", 1, CONTROL, MERGER),
        merge_done: fifo("merge->control", 1, MERGER, CONTROL),
        sub_ready: fifo(
            "presorters->control",
            subs as usize + 1,
            UnitId::EXTERNAL,
            CONTROL,
        ),
        emit_done: fifo("emitter->control", 1, EMITTER, CONTROL),
        top_start: fifo("control->toplevel", 1, CONTROL, toplevel),
        top_done: fifo("toplevel->control", 1, toplevel, CONTROL),
        emit_fifo: fifo("merge->emitter", cfg.emit_fifo as usize, MERGER, EMITTER),
        run_fifo: fifo(
            "merge->run writer",
            cfg.run_write_fifo as usize,
            MERGER,
            RUN_WRITER,
        ),
        refill: fifo("merge->reader", 2 * fan as usize, MERGER, READER),
        fill: fifo("arbiter->merge", 2 * fan as usize, ARBITER, MERGER),
        ps_data: (0..cfg.presorters)
            .map(|p| fifo("arbiter->presorter", slots, ARBITER, presorter(p)))
            .collect(),
        ps_credit: (0..cfg.presorters)
            .map(|p| fifo("presorter->reader", slots, presorter(p), READER))
            .collect(),
        req_read: fifo("reader->arbiter", 2, READER, ARBITER),
        req_run: fifo("run writer->arbiter", 2, RUN_WRITER, ARBITER),
        nodes: if streaming {
            KBuf::new(wb(layout.cbvh, cfg.node_buffer_bytes), [stream, stream])
        } else {
            KBuf::new(wb(layout.nodes, cfg.node_buffer_bytes), [EMITTER, EMITTER])
        },
        leaves: KBuf::new(wb(layout.leaves, cfg.leaf_buffer_bytes), [EMITTER, EMITTER]),
        hl: KBuf::new(
            wb(layout.highlevel, cfg.node_buffer_bytes),
            [EMITTER, toplevel],
        ),
        enc_fifo: fifo(
            "emitter->cbvh encoder",
            cfg.cbvh_fifo as usize,
            EMITTER,
            stream,
        ),
        req_cbvh: fifo(
            "cbvh->arbiter",
            2,
            if streaming { stream } else { topdown },
            ARBITER,
        ),
        bt_data: fifo("arbiter->cbvh encoder", 1, ARBITER, stream),
        td_data: fifo("arbiter->topdown", 1, ARBITER, topdown),
        stream_done: fifo("cbvh encoder->control", 1, stream, CONTROL),
        td_start: fifo("control->topdown", 1, CONTROL, topdown),
        td_done: fifo("topdown->control", 1, topdown, CONTROL),
        emit_finished: Reg::new(false),
        ids,
        scratch_open: Reg::new(0),
        emit_active: Reg::new(blocks == 1),
        scratch: vec![Elem::PAD; cfg.m as usize],
        scratch_port: Cycle::MAX,
        region: [
            vec![0; region_len(passes_total > 0)],
            vec![0; region_len(passes_total > 1)],
        ],
        codes: vec![0; if passes_total > 0 { n as usize } else { 0 }],
        inflight: Reg::new(0),
        acc: Totals::default(),
        trace: Trace::new(cfg.trace_window_cycles.max(1)),
        out: Outputs::default(),
        phases: Vec::new(),
        phase_log: vec![(0, "partial_sort".to_string())],
        build_cycles: 0,
        work: 0,
        // Every merge output (partial sorts and passes) and every emitter input.
        work_total: npad * (passes_total as u64 + 1) + n,
        progress,
    };
    let mut s: Scheduler<KWorld> = Scheduler::new(Options {
        skip: cfg.fast_forward,
        ..Options::default()
    });
    s.add(Box::new(Control {
        phase: Phase::PartialSort,
        fill_block: 0,
        subs_in: 0,
        merging: false,
        group: 0,
        pass_run_len: m,
        pass_runs: blocks,
        draining: false,
        stream_done: false,
        phase_start: 0,
        snap: [0; 4],
    }));
    s.add(Box::new(Emitter {
        e: EmitUnit::new(
            n,
            cfg.highlevel_threshold,
            cfg.combine_identical,
            cfg.max_leaf_size,
            streaming,
        ),
    }));
    s.add(Box::new(MergeUnit {
        m: Merger::new(cfg.m, cfg.b),
        active: false,
        to_emitter: false,
        src: 0,
        refills: VecDeque::with_capacity(2 * fan as usize),
    }));
    s.add(Box::new(Reader {
        in_next: 0,
        in_p: 0,
        second_half: false,
        alloc: vec![0; np],
        tail: vec![0; np],
        slots: cfg.presort_slots,
    }));
    s.add(Box::new(RunWriter {
        staged: 0,
        written: 0,
        b: cfg.b,
        npad,
    }));
    s.add(Box::new(Arbiter {
        rr: RoundRobin::new(REQUESTERS, 1).expect("five requesters"),
        slab: Vec::with_capacity(64),
        free: Vec::with_capacity(64),
        inflight: 0,
        burst: w.mem.port().burst_bytes(),
        lift_only_with_responses: w.mem.port().refusals_lift_only_with_responses(),
    }));
    let mut bank = Vec::with_capacity(np);
    for p in 0..cfg.presorters {
        let mut ps = Presorter::new(cfg.presort_slots, cfg.b, p as u64);
        if (p as u64) < subs {
            let len = w.sub_len(p as u64);
            ps.start(p as u64, len, p as u64 * 2 * b / m);
        } else {
            ps.state = PresortState::Finished;
        }
        bank.push(PresortUnit {
            p,
            ps,
            acct: Acct::new(),
            b: cfg.b,
            subs_per_block: m / (2 * b),
            total_subs: subs,
            count: cfg.presorters as u64,
        });
    }
    let id = s.add(Box::new(PresortBank { units: bank }));
    debug_assert_eq!(id, presorter(0));
    if cfg.toplevel_sah {
        let id = s.add(Box::new(Toplevel {
            t: None,
            busy: 0,
            busy_until: 0,
        }));
        debug_assert_eq!(id, toplevel);
    }
    let enc = if streaming {
        Some(cbvh::StreamEncoder::new(cfg.stream_config(layout.cbvh))?)
    } else {
        None
    };
    if let Some(enc) = enc {
        let id = s.add(Box::new(Stream {
            enc: Some(enc),
            ops: VecDeque::new(),
            awaiting_read: false,
            flushing: false,
            ended: false,
            done: false,
            stats: StreamUnitStats::default(),
            flush_before_read: cfg.cbvh_flush_before_backtrack,
        }));
        debug_assert_eq!(id, stream);
    }
    if cfg.output == OutputMode::CbvhTopdown {
        let id = s.add(Box::new(Topdown {
            started: false,
            nodes: 0,
            next_read: 0,
            arrived: Vec::new(),
            next_encode: 0,
            pairs: 0,
            pair_bytes: cbvh::format::pair_bytes(cfg.cbvh_bits) as u64,
            stats: TopdownStats::default(),
        }));
        debug_assert_eq!(id, topdown);
    }
    let rep = s
        .run(&mut w)
        .map_err(|e| MergeTreeError::Deadlock(e.to_string()))?;
    if let Some(f) = w.out.fault.take() {
        return Err(f.into());
    }
    let cycles = rep.cycles;
    let stalls = stall_report(&rep, &w);
    // Trace rows: one per window up to the end, each with the phase at its last cycle.
    let window = w.trace.window;
    let nrows = cycles.div_ceil(window) as usize;
    let mut trace = std::mem::take(&mut w.trace.rows);
    trace.resize_with(nrows, TraceRow::default);
    for (i, r) in trace.iter_mut().enumerate() {
        r.cycle_start = i as u64 * window;
        r.cycles = window.min(cycles - r.cycle_start);
        let last = r.cycle_start + r.cycles - 1;
        let k = w.phase_log.partition_point(|(c, _)| *c <= last);
        r.phase = w.phase_log[k.max(1) - 1].1.clone();
    }
    let port = w.mem.port();
    Ok(KRun {
        cycles,
        stalls,
        phases: std::mem::take(&mut w.phases),
        trace,
        nodes: std::mem::take(&mut w.out.nodes),
        roots: std::mem::take(&mut w.out.roots),
        order: std::mem::take(&mut w.out.order),
        max_stack_depth: w.out.max_stack_depth,
        top: w.out.top.take(),
        cbvh_ids: w.out.cbvh_ids.take(),
        stream: w.out.stream.take().map(|(e, mut st)| {
            let a = &rep.units[w.ids.stream.index()];
            st.busy_cycles = a.activity.busy_cycles;
            st.starved_cycles = stalled(a, ST_STARVED as usize);
            st.read_wait_cycles = stalled(a, ST_READ_WAIT as usize);
            st.flush_wait_cycles = stalled(a, ST_FLUSH_WAIT as usize);
            st.write_full_cycles = stalled(a, ST_WRITE_FULL as usize);
            (e, st)
        }),
        topdown: w.out.topdown.take().map(|mut t| {
            let a = &rep.units[w.ids.topdown.index()];
            t.read_wait_cycles = stalled(a, TD_READ_WAIT as usize);
            t.write_full_cycles = stalled(a, TD_WRITE_FULL as usize);
            t
        }),
        build_cycles: w.build_cycles,
        passes_total,
        layout,
        mem: port.stats(),
        dram: port.name(),
        peak: port.peak_bytes_per_unit_cycle(),
        run: rep,
    })
}

fn counter(u: &crate::kernel::UnitReport, name: &str) -> u64 {
    u.counters.iter().find(|c| c.0 == name).map_or(0, |c| c.1)
}

fn stalled(u: &crate::kernel::UnitReport, r: usize) -> u64 {
    u.activity.stalled.get(r).map_or(0, |s| s.cycles)
}

/// The [`StallReport`] of a run, from its units' activity intervals and counters:
/// - `presort_*`: the presorters' busy / "input empty" / "scratchpad wait" cycles, summed
///   over the presorters of the bank (presorter-cycles, as before);
/// - `merge`: the merge unit's stall cycles by reason (queue dry, output full, init wait);
/// - `emitter`: the emitter's "input empty" and "write buffer full" cycles (counted from
///   the start of the final merge, when the emitter becomes active);
/// - `reader_blocked_cycles`: the reader's "presorter ring full" cycles;
/// - `port_refusals`: cycles the arbiter had a request refused and granted none (the old
///   machine counted refused attempts, one per cycle at most: the same count);
/// - `fifos`: the merge output FIFOs.
fn stall_report(rep: &RunReport, w: &KWorld) -> StallReport {
    let u = &rep.units;
    let ps = &u[PRESORTER0 as usize];
    let merge = &u[MERGER.index()];
    let emit = &u[EMITTER.index()];
    let fs = |f: &LatencyFifo<Elem>| {
        let s = f.stats(rep.cycles);
        FifoStats {
            name: s.name,
            capacity: s.capacity,
            len: s.len,
            pushes: s.pushes,
            refused_pushes: s.refused_pushes,
            peak: s.peak,
        }
    };
    StallReport {
        presort_busy_cycles: counter(ps, "presorter_busy_cycles"),
        presort_starved_cycles: counter(ps, "presorter_starved_cycles"),
        presort_wait_scratchpad_cycles: counter(ps, "presorter_wait_cycles"),
        merge: MergeStalls {
            queue_dry_cycles: stalled(merge, MERGE_DRY as usize),
            output_full_cycles: stalled(merge, MERGE_FULL as usize),
            init_wait_cycles: stalled(merge, MERGE_INIT as usize),
        },
        merge_outputs: counter(merge, "outputs"),
        heap_ops: counter(merge, "heap_ops"),
        emitter: EmitterStalls {
            starved_cycles: stalled(emit, EMIT_STARVED as usize),
            write_full_cycles: stalled(emit, EMIT_WRITE_FULL as usize),
            encoder_full_cycles: stalled(emit, EMIT_ENCODER_FULL as usize),
        },
        emitter_steps: counter(emit, "steps"),
        reader_blocked_cycles: stalled(&u[READER.index()], READER_RING_FULL as usize),
        port_refusals: stalled(&u[ARBITER.index()], 0),
        fifos: vec![fs(&w.emit_fifo), fs(&w.run_fifo)],
    }
}
