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
//!   order; see [`super::cbvh_unit`]); or the 128-byte MBVH4 nodes in the MBVH4 output
//!   modes, written by the streaming collapse or the collapse pass
//!   ([`super::mbvh4_unit`]). With the streaming encoder or collapse, `nodes` stays unused.
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
//! | then | streaming MBVH4 collapse (`mbvh4`, in the encoder's place) | the collapse, its open subtrees | `col_fifo`, `emit_finished` | wide-node write buffer, `stream_done` |
//! | then | wide CBVH encoder behind the collapse (`cbvh4`: the streaming encoder unit driving `cbvh::WideStreamEncoder`) | the encoder, its queued accesses | `wide_fifo`, `bt_data`, `collapse_finished` | compressed-node write buffer, `req_cbvh`, `stream_done` |
//! | then | top-down CBVH pass (`cbvh-topdown`), or the MBVH4 collapse pass (`mbvh4-collapse`) | read / encode positions | `td_start`, `td_data` | node-pair (wide-node) write buffer, `req_cbvh`, `td_done` |
//!
//! The units live in files of their own: `control` (the FSM), `emit` (hierarchy emitter
//! and toplevel SAH unit), `merge_unit`, `memory` (reader, run writer, arbiter),
//! `presort_bank` and `cbvh_out` (streaming encoder and top-down pass); this file has the
//! world they share, its registers and buffers, and the assembly of a run.
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
//! | `refill` | M / B (two halves per queue, or the forecast pool) | merger -> reader (fetch descriptors) |
//! | `fill` | M / B | arbiter -> merger (completed run reads) |
//! | `ps_data[p]` | `presort_slots` | arbiter -> presorter p (completed input reads) |
//! | `ps_credit[p]` | `presort_slots` | presorter p -> reader (ring slots freed) |
//! | `req_read`, `req_run` | 2 | reader / run writer -> arbiter |
//! | `cmd` | 1 | control -> merger |
//! | `enc_fifo` | `cbvh_fifo` | emitter -> streaming encoder |
//! | `col_fifo` | `cbvh_fifo` | emitter -> streaming MBVH4 collapse |
//! | `wide_fifo` | `cbvh_fifo` | streaming MBVH4 collapse -> wide encoder (`cbvh4`) |
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

mod cbvh_out;
mod control;
mod emit;
mod mbvh4_out;
mod memory;
mod merge_unit;
mod presort_bank;

use cbvh_out::*;
use control::*;
use emit::*;
use mbvh4_out::*;
use memory::*;
use merge_unit::*;
use presort_bank::*;

use std::collections::VecDeque;

use geom::{Aabb, MortonQuantizer};

use super::cbvh_unit::{StreamUnitStats, TopdownStats};
use super::config::{
    MergeTreeConfig, HIGHLEVEL_BYTES, LEAF_ENTRY_BYTES, MBVH4_NODE_BYTES, NODE_BYTES,
};
use super::config::{OutputMode, ReadSchedule};
use super::emitter::{EmitPorts, EmitStatus, EmitUnit, EmitterStalls, PointWriter};
use super::mbvh4_unit::CollapseUnitStats;
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
    /// CBVH node pairs (CBVH output modes), or MBVH4 nodes (MBVH4 output modes).
    pub cbvh: u64,
    /// First byte after the layout.
    pub end: u64,
}

impl MemoryLayout {
    /// The layout for `n` primitives padded to `npad` elements of `elem` bytes, with
    /// `run_gap` bytes after every run of `m` elements in the run regions ([`run_offset`]).
    pub fn new(n: u64, npad: u64, m: u64, run_gap: u64, elem: u64) -> Self {
        let up = |x: u64| x.div_ceil(REGION_ALIGN) * REGION_ALIGN;
        let input = 0;
        let run0 = up(input + n * elem);
        let run_bytes = run_offset(npad, m.max(1), run_gap, elem);
        let run1 = up(run0 + run_bytes);
        let nodes = up(run1 + run_bytes);
        let leaves = up(nodes + n.saturating_sub(1) * super::config::NODE_BYTES);
        let highlevel = up(leaves + n * super::config::LEAF_ENTRY_BYTES);
        let cbvh = up(highlevel + n * super::config::HIGHLEVEL_BYTES);
        // Room for a node pair of the widest coordinates or a 128-byte MBVH4 node per
        // primitive (a tree of n leaves has fewer of either).
        let out_max = (cbvh::format::pair_bytes(cbvh::grid::MAX_BITS) as u64).max(MBVH4_NODE_BYTES);
        let end = up(cbvh + n.max(1) * out_max);
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

/// Byte offset of element `at` in a run region: runs of `m` elements of `elem` bytes,
/// each followed by `run_gap` unused bytes (the `run_gap_bytes` layout what-if; 0 by
/// default).
#[inline]
pub fn run_offset(at: u64, m: u64, run_gap: u64, elem: u64) -> u64 {
    at * elem + at / m * run_gap
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
    /// The wide encoder behind the collapse unit (`cbvh4`).
    wide_enc: UnitId,
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

    /// Bytes that fit now (what [`Self::has_room`] accepts).
    fn free(&self, now: Cycle) -> u64 {
        let freed = if self.freed_at == now { self.freed } else { 0 };
        self.wb.capacity().saturating_sub(self.wb.pending() + freed)
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
    wide: Option<(cbvh::WideStreamEncoder, StreamUnitStats)>,
    topdown: Option<TopdownStats>,
    collapse: Option<(bvh::StreamCollapse, CollapseUnitStats)>,
    collapse_fault: Option<bvh::CollapseError>,
    points: Option<Result<PointWriter, bvh::PointError>>,
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
    /// Emitter -> streaming MBVH4 collapse.
    col_fifo: LatencyFifo<bvh::EmittedNode>,
    /// Streaming MBVH4 collapse -> wide encoder (`cbvh4`): the wide nodes it closes.
    wide_fifo: LatencyFifo<cbvh::wide::WideInput>,
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
    /// The collapse unit has handed over its last wide node (for the wide encoder).
    collapse_finished: Reg<bool>,
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
        let b = self.cfg.b_elems();
        (self.npad - sub * 2 * b).min(2 * b) as u32
    }

    fn subs_of_block(&self, k: u64) -> u64 {
        let m = self.cfg.m_elems();
        let len = (self.npad - k * m).min(m);
        len.div_ceil(2 * self.cfg.b_elems())
    }
}

fn fifo<T>(name: &'static str, cap: usize, from: UnitId, to: UnitId) -> LatencyFifo<T> {
    LatencyFifo::new(name, cap.max(1), 1, from, to).expect("capacity and latency are positive")
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
    pub wide: Option<(cbvh::WideStreamEncoder, StreamUnitStats)>,
    pub topdown: Option<TopdownStats>,
    pub collapse: Option<(bvh::StreamCollapse, CollapseUnitStats)>,
    /// The point writer, or its error (`output = kdtree-points`).
    pub points: Option<Result<PointWriter, bvh::PointError>>,
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
            wide: None,
            topdown: None,
            collapse: None,
            points: None,
            build_cycles: 0,
            passes_total: 0,
            layout: MemoryLayout::new(0, 0, 1, 0, cfg.elem_bytes()),
            mem: port.stats(),
            dram: port.name(),
            peak: port.peak_bytes_per_unit_cycle(),
        });
    }
    let b = cfg.b_elems();
    let m = cfg.m_elems();
    let npad = n.div_ceil(b) * b;
    let blocks = npad.div_ceil(m).max(1);
    let fan = cfg.fan_in();
    // Buffers of B in the scratchpad: every one may have a read outstanding.
    let bufs = (m / b) as usize;
    let mut passes_total = 0;
    let mut runs = blocks;
    while runs > 1 {
        runs = runs.div_ceil(fan);
        passes_total += 1;
    }
    let layout = MemoryLayout::new(n, npad, m, cfg.run_gap_bytes as u64, cfg.elem_bytes());
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
        // The streaming encoder or collapse behind the emitter; the pass after the build.
        stream: take(cfg.output == OutputMode::CbvhStream || cfg.output.collapses_stream()),
        topdown: take(matches!(
            cfg.output,
            OutputMode::CbvhTopdown | OutputMode::Mbvh4Collapse
        )),
        wide_enc: take(cfg.output == OutputMode::Cbvh4),
    };
    let (toplevel, stream, topdown) = (ids.toplevel, ids.stream, ids.topdown);
    let region_len = |needed: bool| if needed { npad as usize } else { 0 };
    let streaming = cfg.output == OutputMode::CbvhStream;
    let behind = streaming || cfg.output.collapses_stream();
    let wide = cfg.output == OutputMode::Cbvh4;
    // The unit that writes the output nodes and makes the CBVH unit's requests: the
    // streaming encoder, the collapse unit, the wide encoder behind it, or the pass.
    let writer = if wide { ids.wide_enc } else { stream };
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
        refill: fifo("merge->reader", bufs, MERGER, READER),
        fill: fifo("arbiter->merge", bufs, ARBITER, MERGER),
        ps_data: (0..cfg.presorters)
            .map(|p| fifo("arbiter->presorter", slots, ARBITER, presorter(p)))
            .collect(),
        ps_credit: (0..cfg.presorters)
            .map(|p| fifo("presorter->reader", slots, presorter(p), READER))
            .collect(),
        req_read: fifo("reader->arbiter", 2, READER, ARBITER),
        req_run: fifo("run writer->arbiter", 2, RUN_WRITER, ARBITER),
        nodes: if behind {
            KBuf::new(wb(layout.cbvh, cfg.node_buffer_bytes), [writer, writer])
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
        col_fifo: fifo(
            "emitter->mbvh4 collapse",
            cfg.cbvh_fifo as usize,
            EMITTER,
            stream,
        ),
        wide_fifo: fifo(
            "mbvh4 collapse->wide encoder",
            cfg.cbvh_fifo as usize,
            stream,
            ids.wide_enc,
        ),
        req_cbvh: fifo(
            "cbvh->arbiter",
            2,
            if streaming || wide { writer } else { topdown },
            ARBITER,
        ),
        bt_data: fifo("arbiter->cbvh encoder", 1, ARBITER, writer),
        td_data: fifo("arbiter->topdown", 1, ARBITER, topdown),
        stream_done: fifo("cbvh encoder->control", 1, writer, CONTROL),
        td_start: fifo("control->topdown", 1, CONTROL, topdown),
        td_done: fifo("topdown->control", 1, topdown, CONTROL),
        emit_finished: Reg::new(false),
        collapse_finished: Reg::new(false),
        ids,
        scratch_open: Reg::new(0),
        emit_active: Reg::new(blocks == 1),
        scratch: vec![Elem::PAD; cfg.m_elems() as usize],
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
    let mut e = EmitUnit::new(
        n,
        cfg.highlevel_threshold,
        cfg.combine_identical,
        cfg.max_leaf_size,
        streaming,
        match cfg.output {
            OutputMode::KdtreePoints => Some(PointWriter::Kd(
                bvh::PointStream::new(centroid_bounds, cfg.max_leaf_size)
                    .map_err(|e| MergeTreeError::Input(e.to_string()))?,
            )),
            OutputMode::OctreePoints => Some(PointWriter::Oct(
                bvh::OctreeStream::new(cfg.max_leaf_size)
                    .map_err(|e| MergeTreeError::Input(e.to_string()))?,
            )),
            _ => None,
        },
    );
    e.kd_node_bytes = cfg.kd_node_bytes();
    s.add(Box::new(Emitter { e }));
    s.add(Box::new(MergeUnit {
        m: match cfg.read_schedule {
            ReadSchedule::Double => Merger::new(m as u32, b as u32),
            ReadSchedule::Forecast => Merger::with_forecast(m as u32, b as u32, fan as u32),
        },
        active: false,
        to_emitter: false,
        src: 0,
        refills: VecDeque::with_capacity(bufs),
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
        b: b as u32,
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
        let mut ps = Presorter::new(cfg.presort_slots, b as u32, p as u64);
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
            b: b as u32,
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
        let id = s.add(Box::new(Stream::new(
            Encoder::Pair(enc),
            cfg.cbvh_flush_before_backtrack,
        )));
        debug_assert_eq!(id, stream);
    }
    if cfg.output.collapses_stream() {
        let id = s.add(Box::new(Collapse {
            sc: Some(cfg.stream_collapse()),
            out_next: 0,
            encode: wide,
            think: 0,
            levels: cfg.mbvh4_window.map_or(0, u64::from),
            ended: false,
            done: false,
            stats: CollapseUnitStats::default(),
        }));
        debug_assert_eq!(id, stream);
    }
    if wide {
        let enc = cbvh::WideStreamEncoder::new(cfg.stream_config(layout.cbvh))?;
        let id = s.add(Box::new(Stream::new(
            Encoder::Wide(enc),
            cfg.cbvh_flush_before_backtrack,
        )));
        debug_assert_eq!(id, ids.wide_enc);
    }
    if matches!(
        cfg.output,
        OutputMode::CbvhTopdown | OutputMode::Mbvh4Collapse
    ) {
        let id = s.add(Box::new(Topdown {
            started: false,
            nodes: 0,
            next_read: 0,
            arrived: Vec::new(),
            next_encode: 0,
            pairs: 0,
            bytes: Vec::new(),
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
    if let Some(f) = w.out.collapse_fault.take() {
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
    // A streaming CBVH encoder's counters with its activity (the pair or the wide one).
    let encoder_stats = |id: UnitId, mut st: StreamUnitStats| {
        let a = &rep.units[id.index()];
        st.busy_cycles = a.activity.busy_cycles;
        st.starved_cycles = stalled(a, ST_STARVED as usize);
        st.read_wait_cycles = stalled(a, ST_READ_WAIT as usize);
        st.flush_wait_cycles = stalled(a, ST_FLUSH_WAIT as usize);
        st.write_full_cycles = stalled(a, ST_WRITE_FULL as usize);
        st
    };
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
        points: w.out.points.take(),
        stream: w
            .out
            .stream
            .take()
            .map(|(e, st)| (e, encoder_stats(w.ids.stream, st))),
        wide: w
            .out
            .wide
            .take()
            .map(|(e, st)| (e, encoder_stats(w.ids.wide_enc, st))),
        collapse: w.out.collapse.take().map(|(c, mut st)| {
            let a = &rep.units[w.ids.stream.index()];
            st.busy_cycles = a.activity.busy_cycles;
            st.starved_cycles = stalled(a, CO_STARVED as usize);
            st.write_full_cycles = stalled(a, CO_WRITE_FULL as usize);
            st.encoder_full_cycles = stalled(a, CO_ENCODER_FULL as usize);
            (c, st)
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
