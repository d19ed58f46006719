//! The MergeTree machine: the units of \[P2\] Fig. 1 wired together, the control FSM of
//! \[P1\] Fig. 2 / \[P2\] Fig. 3 (partial sorts, multi-merge passes, hierarchy emission),
//! the memory arbiter, and the cycle loop.
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
//! # Memory arbiter
//! Six requesters share the port: the run writer, the node (or, in the CBVH modes, node-pair)
//! leaf-table and high-level write buffers, the reader (input reads for the presorters,
//! refills for the merge queues) and the CBVH unit (backtracking reads and writes of the
//! streaming encoder, node reads of the top-down pass). One request may be issued per
//! cycle, granted round robin among the ready requesters; a request refused by a full
//! controller queue is retried.

use std::collections::VecDeque;

use geom::{Aabb, MortonQuantizer};

use super::cbvh_unit::{StreamUnit, TopdownUnit, STREAM_COUNTERS, TOPDOWN_COUNTERS};
use super::config::{MergeTreeConfig, OutputMode, ELEM_BYTES};
use super::emitter::{EmitUnit, NodeSink};
use super::merge::{MergeState, Merger};
use super::presort::{PresortState, Presorter};
use super::report::{PhaseReport, StallReport, TraceRow};
use super::toplevel::TopUnit;
use super::{Elem, MergeTreeError};
use crate::dram::{AccessKind, MemRequest, MemoryPort};
use crate::fifo::Fifo;

/// Cycles without progress of any unit and with no memory request outstanding after which
/// the machine reports a deadlock.
const DEADLOCK_CYCLES: u64 = 10_000;

/// Cycles without any progress, with requests outstanding, after which the memory is taken
/// to have stopped answering (a backend bug; far above any DRAM latency).
const MEMORY_TIMEOUT_CYCLES: u64 = 1_000_000;

/// Marks a write in a request tag; the low 32 bits hold the byte count.
const WRITE_TAG: u64 = 1 << 63;

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
        let run_bytes = run_offset(npad, m, run_gap);
        let run0 = up(input + n * ELEM_BYTES);
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
/// `run_gap` unused bytes.
#[inline]
pub fn run_offset(at: u64, m: u64, run_gap: u64) -> u64 {
    at * ELEM_BYTES + at / m * run_gap
}

/// The sort element of primitive `i` of `aabbs` (padding past the end): its box,
/// reference and the Morton code of its centroid on `quant`'s grid with `bits` bits.
#[inline]
fn elem_of(aabbs: &[Aabb], quant: &MortonQuantizer, bits: u32, i: u64) -> Elem {
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
    #[inline]
    fn ready(&self) -> Option<(u64, u32)> {
        let room = self.chunk - (self.next_addr - self.base) % self.chunk;
        if self.pending >= room
            || ((self.flush || self.next_addr < self.flush_until) && self.pending > 0)
        {
            Some((self.next_addr, self.pending.min(room) as u32))
        } else {
            None
        }
    }

    fn issued(&mut self, bytes: u32) {
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

/// Where a read's data goes.
#[derive(Clone, Copy, Debug)]
enum ReadDest {
    /// Ring slot `slot` of presorter `p` (input AABBs).
    Presort { p: u32, slot: u32 },
    /// Buffer half `buf` of the merge scratchpad (sort runs).
    Merge { buf: u32 },
    /// The streaming CBVH encoder's backtracking read.
    Backtrack,
    /// Node at stream position `j` of the top-down pass.
    Topdown { j: u64 },
}

/// An outstanding read.
#[derive(Clone, Copy, Debug)]
struct ReadDesc {
    dest: ReadDest,
    /// First element (input index or run-region position).
    src: u64,
    /// Elements delivered (padding included).
    count: u32,
    /// Bytes read.
    bytes: u32,
}

/// Control state (\[P1\] Fig. 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Reading, presorting and merging the N / M blocks.
    PartialSort,
    /// Multi-merge pass `p` (0-based).
    MergePass(u32),
    /// Waiting for the last writes of a phase before the next one reads them.
    Fence(u32),
    /// The final merge feeds the emitter; then the last writes drain.
    Emit,
    /// The toplevel binned SAH unit.
    Toplevel,
    /// The top-down CBVH compression pass.
    Topdown,
    /// Finished.
    Done,
}

/// Requesters of the memory arbiter.
const REQUESTERS: usize = 6;

/// Number of stall counters [`Machine::snapshot`] records.
const SNAP: usize = 10 + STREAM_COUNTERS + TOPDOWN_COUNTERS;

/// The whole unit. See the module documentation.
pub(super) struct Machine<'a> {
    cfg: MergeTreeConfig,
    aabbs: &'a [Aabb],
    quant: MortonQuantizer,
    n: u64,
    npad: u64,
    blocks: u64,
    pub passes_total: u32,
    pub layout: MemoryLayout,
    port: Box<dyn MemoryPort>,
    pub cycle: u64,
    phase: Phase,
    // Partial sort.
    presorters: Vec<Presorter>,
    in_next: u64,
    /// Presorter of the sub-block at `in_next`, and whether `in_next` is its second half.
    in_p: u32,
    in_second_half: bool,
    fill_block: u64,
    /// Sub-blocks of `fill_block`.
    fill_subs: u64,
    sub_ready: u64,
    /// Sub-blocks per partial-sort block: M / (2B).
    subs_per_block: u64,
    /// Sub-blocks in the scene.
    total_subs: u64,
    // Merge.
    merger: Merger,
    refill: VecDeque<u32>,
    emit_fifo: Fifo<Elem>,
    run_fifo: Fifo<Elem>,
    to_emitter: bool,
    run_flush: bool,
    /// Functional contents of the two run regions: the reference of the element at each
    /// position (a padding element's is its position). An element read back is rebuilt
    /// from its reference, its input box and the Morton code computed when it was read
    /// in (`codes`), which gives exactly the element written.
    region: [Vec<u32>; 2],
    /// Morton code of each primitive, recorded by the input stage for the run regions.
    codes: Vec<u64>,
    dst: usize,
    wr_pos: u64,
    pass_run_len: u64,
    pass_runs: u64,
    group: u64,
    // Emission.
    emit_active: bool,
    pub emit: EmitUnit,
    nodes_wb: WriteBuffer,
    leaves_wb: WriteBuffer,
    hl_wb: WriteBuffer,
    top: Option<TopUnit>,
    /// The streaming CBVH encoder (output = cbvh-stream).
    pub stream: Option<StreamUnit>,
    /// The top-down pass (output = cbvh-topdown, after the build).
    pub td: Option<TopdownUnit>,
    /// Cycle at which the hierarchy (and, streaming, the CBVH) was complete in DRAM.
    pub build_cycles: u64,
    // Memory.
    inflight: Vec<ReadDesc>,
    free_tags: Vec<u32>,
    rr: usize,
    outstanding_writes: u64,
    pub port_refusals: u64,
    pub reader_blocked_cycles: u64,
    // Report.
    pub phases: Vec<PhaseReport>,
    phase_start: u64,
    phase_read: u64,
    /// Reads completed in the phase and the sum of their latencies (accept to completion).
    phase_reads: u64,
    phase_read_latency: u64,
    phase_written: u64,
    pub trace: Vec<TraceRow>,
    win: TraceRow,
    idle: u64,
    /// Stall counters at the start of a probe cycle, and their change over it.
    snap_before: Vec<u64>,
    snap_after: Vec<u64>,
    /// The previous cycle was idle: snapshot this one to fast-forward if it is too.
    probe: bool,
    /// Presorters busy in the current cycle.
    presort_busy_now: u64,
    /// The presorters were frozen (or not in use) in the current cycle.
    presort_frozen_now: bool,
    /// An event may have changed a presorter's situation since its last full tick.
    presort_dirty: bool,
    /// Earliest end of an insertion at the last full tick.
    presort_wake: u64,
    /// Busy, starved and waiting presorters at the last full tick (counts of a frozen cycle).
    frozen: [u64; 3],
    /// Starved and waiting presorter-cycles added by frozen cycles (busy ones are counted
    /// when their insertion starts).
    frozen_totals: [u64; 2],
    /// Earliest end of a presorter's insertion in progress (`u64::MAX`: none).
    wake_at: u64,
    /// Cycles skipped by fast-forwarding.
    pub skipped_cycles: u64,
    /// Responses the port held after the last tick (popped at the next cycle's start).
    waiting: usize,
    progress_hook: Option<&'a mut dyn FnMut(u64, u64)>,
}

impl<'a> Machine<'a> {
    /// A machine ready to sort and emit `aabbs` whose centroids lie in `centroid_bounds`.
    pub fn new(
        aabbs: &'a [Aabb],
        centroid_bounds: &Aabb,
        cfg: &MergeTreeConfig,
        port: Box<dyn MemoryPort>,
        progress_hook: Option<&'a mut dyn FnMut(u64, u64)>,
    ) -> Result<Self, MergeTreeError> {
        let n = aabbs.len() as u64;
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
        let presorters = (0..cfg.presorters)
            .map(|p| {
                let mut ps = Presorter::new(cfg.presort_slots, cfg.b, p as u64);
                if (p as u64) < subs {
                    ps.start(
                        p as u64,
                        Self::sub_len(npad, b, p as u64),
                        p as u64 * 2 * b / m,
                    );
                } else {
                    ps.state = PresortState::Finished;
                }
                ps
            })
            .collect();
        // Functional contents of the run regions: region 0 holds the partial-sort runs
        // when a merge pass follows; region 1 is written only by non-final passes.
        let region_len = |needed: bool| if needed { npad as usize } else { 0 };
        let streaming = cfg.output == OutputMode::CbvhStream;
        let stream = if streaming {
            let enc = cbvh::StreamEncoder::new(cfg.stream_config(layout.cbvh))?;
            Some(StreamUnit::new(
                enc,
                cfg.cbvh_fifo,
                cfg.cbvh_flush_before_backtrack,
            ))
        } else {
            None
        };
        Ok(Self {
            cfg: cfg.clone(),
            aabbs,
            quant: MortonQuantizer::with_grid(centroid_bounds, cfg.morton_grid),
            n,
            npad,
            blocks,
            passes_total,
            layout,
            port,
            cycle: 0,
            phase: Phase::PartialSort,
            presorters,
            in_next: 0,
            in_p: 0,
            in_second_half: false,
            fill_block: 0,
            fill_subs: (npad.min(m)).div_ceil(2 * b),
            sub_ready: 0,
            subs_per_block: m / (2 * b),
            total_subs: subs,
            merger: Merger::new(cfg.m, cfg.b),
            refill: VecDeque::with_capacity(2 * fan as usize),
            emit_fifo: Fifo::new("merge->emitter", cfg.emit_fifo as usize),
            run_fifo: Fifo::new("merge->run writer", cfg.run_write_fifo as usize),
            to_emitter: blocks == 1,
            run_flush: false,
            region: [
                vec![0; region_len(passes_total > 0)],
                vec![0; region_len(passes_total > 1)],
            ],
            codes: vec![0; if passes_total > 0 { n as usize } else { 0 }],
            dst: 0,
            wr_pos: 0,
            pass_run_len: m,
            pass_runs: blocks,
            group: 0,
            emit_active: blocks == 1,
            emit: EmitUnit::new(
                n,
                cfg.highlevel_threshold,
                cfg.combine_identical,
                cfg.max_leaf_size,
                streaming,
            ),
            nodes_wb: WriteBuffer::new(
                if streaming { layout.cbvh } else { layout.nodes },
                cfg.node_buffer_bytes as u64,
                cfg.write_chunk_bytes as u64,
            ),
            leaves_wb: WriteBuffer::new(
                layout.leaves,
                cfg.leaf_buffer_bytes as u64,
                cfg.write_chunk_bytes as u64,
            ),
            hl_wb: WriteBuffer::new(
                layout.highlevel,
                cfg.node_buffer_bytes as u64,
                cfg.write_chunk_bytes as u64,
            ),
            top: None,
            stream,
            td: None,
            build_cycles: 0,
            inflight: Vec::with_capacity(64),
            free_tags: Vec::with_capacity(64),
            rr: 0,
            outstanding_writes: 0,
            port_refusals: 0,
            reader_blocked_cycles: 0,
            phases: Vec::new(),
            phase_start: 0,
            phase_read: 0,
            phase_reads: 0,
            phase_read_latency: 0,
            phase_written: 0,
            trace: Vec::new(),
            win: TraceRow::default(),
            idle: 0,
            snap_before: vec![0; SNAP],
            snap_after: vec![0; SNAP],
            probe: false,
            wake_at: u64::MAX,
            presort_busy_now: 0,
            presort_dirty: true,
            presort_frozen_now: true,
            presort_wake: 0,
            frozen: [0; 3],
            frozen_totals: [0; 2],
            skipped_cycles: 0,
            waiting: 0,
            progress_hook,
        })
    }

    fn sub_len(npad: u64, b: u64, sub: u64) -> u32 {
        (npad - sub * 2 * b).min(2 * b) as u32
    }

    /// Sub-blocks (presorted queues) of partial-sort block `k`.
    fn subs_of_block(&self, k: u64) -> u64 {
        let len = (self.npad - k * self.cfg.m as u64).min(self.cfg.m as u64);
        len.div_ceil(2 * self.cfg.b as u64)
    }

    /// The element for input primitive `i` (padding past the end), with its Morton code
    /// computed as it streams in (\[P2\] §5.1).
    fn input_elem(&self, i: u64) -> Elem {
        elem_of(self.aabbs, &self.quant, self.cfg.morton_bits, i)
    }

    /// Runs to completion; returns the cycle count.
    pub fn run(&mut self) -> Result<u64, MergeTreeError> {
        if self.n == 0 {
            self.phase = Phase::Done;
            return Ok(0);
        }
        self.win.cycle_start = 0;
        loop {
            let probe = self.probe;
            if probe {
                let mut snap = std::mem::take(&mut self.snap_before);
                self.snapshot(&mut snap);
                self.snap_before = snap;
            }
            let mut progress = false;
            self.wake_at = u64::MAX;
            while self.waiting > 0 {
                let Some(r) = self.port.pop_response() else {
                    break;
                };
                self.waiting -= 1;
                progress = true;
                let latency = r.completed_cycle - r.accepted_cycle;
                if r.kind == AccessKind::Read {
                    self.phase_reads += 1;
                    self.phase_read_latency += latency;
                }
                self.on_response(r.tag, latency);
            }
            if self.control() {
                progress = true;
                self.presort_dirty = true;
            }
            if self.phase == Phase::Done {
                break;
            }
            if self.emit_active {
                let sink = match &mut self.stream {
                    Some(st) => NodeSink::Cbvh(&mut st.input),
                    None => NodeSink::Bvh(&mut self.nodes_wb),
                };
                let stepped = self.emit.tick(
                    &mut self.emit_fifo,
                    sink,
                    &mut self.leaves_wb,
                    &mut self.hl_wb,
                );
                if stepped {
                    self.win.emitter_steps += 1;
                }
                progress |= stepped;
                if let Some(e) = self.emit.fault.take() {
                    return Err(e.into());
                }
                if let Some(st) = &mut self.stream {
                    progress |= st.tick(&mut self.nodes_wb, self.emit.done)?;
                }
            }
            if let Some(td) = &mut self.td {
                progress |= td.tick(&mut self.nodes_wb);
            }
            if let Some(top) = &mut self.top {
                progress |= top.tick(&mut self.hl_wb);
                self.win.toplevel_busy += top.busy as u64;
            }
            let out = if self.to_emitter {
                &mut self.emit_fifo
            } else {
                &mut self.run_fifo
            };
            let before = self.merger.outputs;
            progress |= self.merger.tick(self.cycle, out, &mut self.refill);
            self.win.merge_outputs += self.merger.outputs - before;
            progress |= self.presort_tick();
            self.win.presort_busy += self.presort_busy_now;
            progress |= self.issue();
            let idle = !progress && self.cycle >= self.merger.next_op;
            if !idle {
                self.idle = 0;
                self.probe = false;
            } else {
                self.idle += 1;
                // Nothing outstanding: no unit can ever progress. Requests outstanding for
                // far longer than any DRAM latency: the memory has stopped answering.
                if (self.idle > DEADLOCK_CYCLES && self.port.outstanding() == 0)
                    || self.idle > MEMORY_TIMEOUT_CYCLES
                {
                    return Err(MergeTreeError::Deadlock(self.state_dump()));
                }
            }
            self.advance();
            if idle && probe && self.cfg.fast_forward {
                self.fast_forward();
            }
            self.probe = idle;
        }
        self.close_window();
        Ok(self.cycle)
    }

    /// Ends the cycle: the memory and the trace advance.
    #[inline]
    fn advance(&mut self) {
        self.waiting = self.port.tick_and_count();
        self.cycle += 1;
        self.win.cycles += 1;
        if self.win.cycles == self.cfg.trace_window_cycles {
            self.close_window();
        }
    }

    /// The stall counters that an idle cycle with frozen presorters increments, into
    /// `out`.
    fn snapshot(&self, out: &mut [u64]) {
        let m = &self.merger.stalls;
        let e = &self.emit.stalls;
        out[..8].copy_from_slice(&[
            m.queue_dry_cycles,
            m.output_full_cycles,
            m.init_wait_cycles,
            e.starved_cycles,
            e.write_full_cycles,
            self.reader_blocked_cycles,
            self.port_refusals,
            e.encoder_full_cycles,
        ]);
        out[8..10].copy_from_slice(&self.frozen_totals);
        let (st, td) = out[10..].split_at_mut(STREAM_COUNTERS);
        if let Some(u) = &self.stream {
            st.copy_from_slice(&u.counters());
        }
        if let Some(u) = &self.td {
            td.copy_from_slice(&u.counters());
        }
    }

    /// After an idle probe cycle: no unit can change state until a memory response
    /// arrives or a presorter's insertion ends (`wake_at`): nothing was issued, the merge
    /// slot is open, the other units wait. Every cycle until then repeats the probe cycle
    /// exactly; skip them, adding the probe cycle's counts once per skipped cycle.
    fn fast_forward(&mut self) {
        // The presorters' own counters are not in the snapshot: skip only after a probe
        // cycle in which they were frozen (or idle outside the partial sorts).
        if !self.presort_frozen_now {
            return;
        }
        let mut after = std::mem::take(&mut self.snap_after);
        self.snapshot(&mut after);
        for (a, b) in after.iter_mut().zip(&self.snap_before) {
            *a -= b;
        }
        // A request refused in the probe cycle may be accepted in a later one without any
        // response arriving (DRAMsim3's staging drains into its controller): then the
        // cycles to come need not repeat the probe cycle, so none is skipped.
        if after[6] > 0 && !self.port.refusals_lift_only_with_responses() {
            self.snap_after = after;
            return;
        }
        let win_busy = self.presort_busy_now;
        let deadline = self.wake_at;
        // Nothing is sent or popped while skipping, so the count outstanding stays fixed.
        let outstanding = self.port.outstanding();
        let mut k = 0u64;
        while self.waiting == 0
            && (outstanding > 0 || deadline != u64::MAX)
            && self.cycle < deadline
            && self.idle + k < MEMORY_TIMEOUT_CYCLES
        {
            self.win.presort_busy += win_busy;
            self.advance();
            k += 1;
        }
        if k > 0 {
            let m = &mut self.merger.stalls;
            m.queue_dry_cycles += k * after[0];
            m.output_full_cycles += k * after[1];
            m.init_wait_cycles += k * after[2];
            let e = &mut self.emit.stalls;
            e.starved_cycles += k * after[3];
            e.write_full_cycles += k * after[4];
            self.reader_blocked_cycles += k * after[5];
            self.port_refusals += k * after[6];
            e.encoder_full_cycles += k * after[7];
            for (t, d) in self.frozen_totals.iter_mut().zip(&after[8..10]) {
                *t += k * d;
            }
            let (st, td) = after[10..].split_at(STREAM_COUNTERS);
            if let Some(u) = &mut self.stream {
                u.add_counters(st, k);
            }
            if let Some(u) = &mut self.td {
                u.add_counters(td, k);
            }

            self.idle += k;
            self.skipped_cycles += k;
        }
        self.snap_after = after;
    }

    fn close_window(&mut self) {
        if self.win.cycles > 0 {
            let mut w = std::mem::take(&mut self.win);
            w.phase = self.phase_name();
            self.trace.push(w);
            if let Some(h) = self.progress_hook.as_mut() {
                // Work: every merge output (partial sorts and passes) and every emitter read.
                let (td_done, td_total) = match &self.td {
                    Some(t) => t.progress(),
                    None if self.cfg.output == OutputMode::CbvhTopdown => (0, self.n),
                    None => (0, 0),
                };
                let total = self.npad * (self.passes_total as u64 + 1) + self.n + td_total;
                h(self.emit.consumed + self.merger.outputs + td_done, total);
            }
        }
        self.win.cycle_start = self.cycle;
    }

    fn phase_name(&self) -> String {
        match self.phase {
            Phase::PartialSort => "partial_sort".into(),
            Phase::MergePass(p) | Phase::Fence(p) => format!("merge_pass_{}", p + 1),
            Phase::Emit => {
                if self.passes_total == 0 {
                    "sort_and_emit".into()
                } else {
                    format!("merge_pass_{}_and_emit", self.passes_total)
                }
            }
            Phase::Toplevel => "toplevel_sah".into(),
            Phase::Topdown => "topdown_compress".into(),
            Phase::Done => "done".into(),
        }
    }

    /// Closes the current phase's report row.
    fn end_phase(&mut self) {
        self.phases.push(PhaseReport {
            name: self.phase_name(),
            start_cycle: self.phase_start,
            end_cycle: self.cycle,
            bytes_read: self.phase_read,
            bytes_written: self.phase_written,
            reads: self.phase_reads,
            read_latency_mean_cycles: if self.phase_reads == 0 {
                0.0
            } else {
                self.phase_read_latency as f64 / self.phase_reads as f64
            },
        });
        self.phase_start = self.cycle;
        self.phase_read = 0;
        self.phase_reads = 0;
        self.phase_read_latency = 0;
        self.phase_written = 0;
    }

    /// The control FSM. Returns true when it changed state.
    fn control(&mut self) -> bool {
        match self.phase {
            Phase::PartialSort => {
                if self.merger.state == MergeState::Idle && self.sub_ready == self.fill_subs {
                    let k = self.fill_block;
                    let nsub = self.fill_subs;
                    let first = k * self.cfg.m as u64 / (2 * self.cfg.b as u64);
                    let (npad, b) = (self.npad, self.cfg.b as u64);
                    self.merger.setup_partial(
                        (first..first + nsub).map(|s| Self::sub_len(npad, b, s)),
                        self.cycle,
                    );
                    self.run_flush = false;
                    return true;
                }
                if self.merger.state == MergeState::Done {
                    self.merger.state = MergeState::Idle;
                    self.fill_block += 1;
                    self.sub_ready = 0;
                    if self.fill_block < self.blocks {
                        self.fill_subs = self.subs_of_block(self.fill_block);
                    }
                    self.run_flush = true;
                    if self.fill_block == self.blocks {
                        if self.passes_total == 0 {
                            self.phase = Phase::Emit;
                        } else {
                            self.end_phase();
                            self.phase = Phase::Fence(0);
                        }
                    }
                    return true;
                }
                false
            }
            Phase::Fence(p) => {
                if self.run_fifo.is_empty() && self.outstanding_writes == 0 {
                    self.start_pass(p);
                    return true;
                }
                false
            }
            Phase::MergePass(p) => {
                if self.merger.state != MergeState::Done {
                    return false;
                }
                self.group += 1;
                let groups = self.pass_runs.div_ceil(self.cfg.fan_in());
                if self.group < groups {
                    self.setup_group();
                } else {
                    self.merger.state = MergeState::Idle;
                    self.run_flush = true;
                    self.end_phase();
                    self.phase = Phase::Fence(p + 1);
                }
                true
            }
            Phase::Emit => {
                if self.emit.done {
                    // The streaming encoder writes node pairs until it is done.
                    let stream_done = self.stream.as_ref().is_none_or(|s| s.done);
                    self.nodes_wb.flush |= stream_done;
                    self.leaves_wb.flush = true;
                    self.hl_wb.flush = true;
                    if stream_done
                        && self.nodes_wb.pending() == 0
                        && self.leaves_wb.pending() == 0
                        && self.hl_wb.pending() == 0
                        && self.port.outstanding() == 0
                    {
                        self.end_phase();
                        self.build_cycles = self.cycle;
                        if self.cfg.toplevel_sah && self.emit.roots.len() > 1 {
                            self.top = Some(TopUnit::new(&self.emit.roots, &self.cfg));
                            self.hl_wb.flush = false;
                            self.phase = Phase::Toplevel;
                        } else if self.cfg.output == OutputMode::CbvhTopdown {
                            self.nodes_wb = WriteBuffer::new(
                                self.layout.cbvh,
                                self.cfg.node_buffer_bytes as u64,
                                self.cfg.write_chunk_bytes as u64,
                            );
                            let pair = cbvh::format::pair_bytes(self.cfg.cbvh_bits) as u64;
                            self.td = Some(TopdownUnit::new(
                                self.emit.nodes.len() as u64,
                                self.layout.nodes,
                                pair,
                            ));
                            self.phase = Phase::Topdown;
                        } else {
                            self.phase = Phase::Done;
                        }
                        return true;
                    }
                }
                false
            }
            Phase::Topdown => {
                let td = self.td.as_ref().expect("top-down unit in its phase");
                if td.done() {
                    self.nodes_wb.flush = true;
                    if self.nodes_wb.pending() == 0 && self.port.outstanding() == 0 {
                        self.end_phase();
                        self.phase = Phase::Done;
                        return true;
                    }
                }
                false
            }
            Phase::Toplevel => {
                let top = self.top.as_ref().expect("toplevel unit in its phase");
                if top.done() {
                    self.hl_wb.flush = true;
                    if self.hl_wb.pending() == 0 && self.port.outstanding() == 0 {
                        self.end_phase();
                        self.phase = Phase::Done;
                        return true;
                    }
                }
                false
            }
            Phase::Done => false,
        }
    }

    /// Starts multi-merge pass `p` (runs of `M * F^p` elements).
    fn start_pass(&mut self, p: u32) {
        let fan = self.cfg.fan_in();
        self.pass_run_len = self.cfg.m as u64 * fan.pow(p);
        self.pass_runs = self.npad.div_ceil(self.pass_run_len);
        self.group = 0;
        self.dst = (p as usize + 1) % 2;
        self.wr_pos = 0;
        self.to_emitter = p + 1 == self.passes_total;
        self.emit_active |= self.to_emitter;
        self.phase = if self.to_emitter {
            Phase::Emit
        } else {
            Phase::MergePass(p)
        };
        self.setup_group();
    }

    fn setup_group(&mut self) {
        let fan = self.cfg.fan_in();
        let first = self.group * fan;
        let last = (first + fan).min(self.pass_runs);
        let (len, npad) = (self.pass_run_len, self.npad);
        self.run_flush = false;
        self.merger.setup_multi(
            (first..last).map(|r| (r * len, (npad - r * len).min(len))),
            &mut self.refill,
            self.cycle,
        );
    }

    /// One cycle of the presorters and of the scratchpad write port.
    ///
    /// After a cycle in which no presorter changed state, they stay frozen (each counting
    /// the same busy, starved or waiting cycle) until an insertion ends (`presort_wake`)
    /// or an event reaches them (`presort_dirty`: data for a ring, a control-state
    /// change); such cycles only add the frozen counts.
    fn presort_tick(&mut self) -> bool {
        self.presort_busy_now = 0;
        self.presort_frozen_now = true;
        if self.phase != Phase::PartialSort {
            return false;
        }
        if !self.presort_dirty && self.cycle < self.presort_wake {
            let f = self.frozen;
            // Busy presorters of a frozen cycle are inside insertions, whose cycles were
            // counted when they started: only the trace adds them per cycle.
            self.presort_busy_now = f[0];
            self.frozen_totals[0] += f[1];
            self.frozen_totals[1] += f[2];
            self.wake_at = self.wake_at.min(self.presort_wake);
            return false;
        }
        self.presort_frozen_now = false;
        let (mut n_starved, mut n_wait) = (0u64, 0u64);
        let mut wake = u64::MAX;
        let b = self.cfg.b as u64;
        let subs_per_block = self.subs_per_block;
        let total_subs = self.total_subs;
        let mut progress = false;
        let mut port_free = true;
        let p_count = self.presorters.len() as u64;
        let cycle = self.cycle;
        for ps in self.presorters.iter_mut() {
            match ps.state {
                PresortState::Finished => {}
                PresortState::Sorting => {
                    if cycle < ps.busy_until {
                        // Inside an insertion: nothing changes before it ends.
                        self.presort_busy_now += 1;
                        wake = wake.min(ps.busy_until);
                        continue;
                    }
                    if ps.sorted(cycle) {
                        ps.state = PresortState::Draining { pos: 0 };
                    } else {
                        let starved = ps.starved_cycles;
                        progress |= ps.tick_sort(cycle, self.cfg.b);
                        n_starved += ps.starved_cycles - starved;
                        if ps.busy_at(cycle) {
                            self.presort_busy_now += 1;
                            wake = wake.min(ps.busy_until);
                        }
                        continue;
                    }
                }
                PresortState::Draining { .. } => {}
            }
            if let PresortState::Draining { pos } = ps.state {
                let can = port_free
                    && ps.block == self.fill_block
                    && self.merger.state == MergeState::Idle;
                if !can {
                    ps.wait_scratchpad_cycles += 1;
                    n_wait += 1;
                    continue;
                }
                port_free = false;
                let slot = (ps.sub % subs_per_block) * 2 * b;
                self.merger.scratch[(slot + pos as u64) as usize] = ps.buf[pos as usize];
                ps.busy_cycles += 1;
                self.presort_busy_now += 1;
                progress = true;
                if pos + 1 == ps.sub_len {
                    self.sub_ready += 1;
                    let next = ps.sub + p_count;
                    if next < total_subs {
                        ps.start(
                            next,
                            Self::sub_len(self.npad, b, next),
                            next / subs_per_block,
                        );
                    } else {
                        ps.state = PresortState::Finished;
                    }
                } else {
                    ps.state = PresortState::Draining { pos: pos + 1 };
                }
            }
        }
        self.wake_at = self.wake_at.min(wake);
        self.presort_wake = wake;
        self.frozen = [self.presort_busy_now, n_starved, n_wait];
        self.presort_dirty = progress;
        progress
    }

    fn new_tag(&mut self, d: ReadDesc) -> u64 {
        match self.free_tags.pop() {
            Some(t) => {
                self.inflight[t as usize] = d;
                t as u64
            }
            None => {
                self.inflight.push(d);
                (self.inflight.len() - 1) as u64
            }
        }
    }

    /// The read the reader wants to issue now, if any.
    fn next_read(&self) -> Option<(ReadDesc, u64)> {
        let b = self.cfg.b as u64;
        if self.phase == Phase::PartialSort {
            if self.in_next >= self.npad {
                return None;
            }
            let p = self.in_p;
            let ps = &self.presorters[p as usize];
            if ps.used == ps.slots() {
                return None;
            }
            let real = self.n.min(self.in_next + b) - self.in_next;
            let d = ReadDesc {
                dest: ReadDest::Presort { p, slot: ps.tail },
                src: self.in_next,
                count: b as u32,
                bytes: (real * ELEM_BYTES) as u32,
            };
            return Some((d, self.layout.input + self.in_next * ELEM_BYTES));
        }
        let &buf = self.refill.front()?;
        let (at, count) = self.merger.peek_fetch(buf);
        let src_region = 1 - self.dst;
        let d = ReadDesc {
            dest: ReadDest::Merge { buf },
            src: at,
            count,
            bytes: count * ELEM_BYTES as u32,
        };
        let (m, gap) = (self.cfg.m as u64, self.cfg.run_gap_bytes as u64);
        Some((d, self.layout.runs[src_region] + run_offset(at, m, gap)))
    }

    /// The memory arbiter: issues at most one request. Returns true when it did.
    fn issue(&mut self) -> bool {
        // Most cycles no requester is ready: find out with cheap checks before trying any.
        let mask = self.ready_mask();
        if mask == 0 {
            self.count_reader_blocked();
            return false;
        }
        let mut who = self.rr;
        for _ in 0..REQUESTERS {
            if who == REQUESTERS {
                who = 0;
            }
            if mask & (1 << who) == 0 {
                if who == 4 {
                    self.count_reader_blocked();
                }
                who += 1;
                continue;
            }
            let ok = match who {
                0 => self.try_run_write(),
                1 => Self::try_buffer_write(
                    &mut self.nodes_wb,
                    &mut *self.port,
                    &mut self.outstanding_writes,
                ),
                2 => Self::try_buffer_write(
                    &mut self.leaves_wb,
                    &mut *self.port,
                    &mut self.outstanding_writes,
                ),
                3 => Self::try_buffer_write(
                    &mut self.hl_wb,
                    &mut *self.port,
                    &mut self.outstanding_writes,
                ),
                4 => self.try_read(),
                _ => self.try_cbvh(),
            };
            match ok {
                None => {
                    who += 1;
                    continue;
                }
                Some(Ok((bytes, read))) => {
                    if read {
                        self.phase_read += bytes;
                    } else {
                        self.phase_written += bytes;
                    }
                    self.rr = who + 1;
                    return true;
                }
                Some(Err(())) => {
                    // Refused (its staging queue is full): try the next ready requester.
                    self.port_refusals += 1;
                    who += 1;
                }
            }
        }
        false
    }

    /// Bit `i` set when requester `i` of [`Self::issue`] has a request ready (the
    /// conditions under which its `try_*` function returns `Some`).
    #[inline]
    fn ready_mask(&self) -> u32 {
        let len = self.run_fifo.len() as u64;
        let run = len > 0 && (len >= self.cfg.b as u64 || self.run_flush);
        let read = if self.phase == Phase::PartialSort {
            self.in_next < self.npad && {
                let ps = &self.presorters[self.in_p as usize];
                ps.used < ps.slots()
            }
        } else {
            !self.refill.is_empty()
        };
        let cbvh = match (&self.stream, &self.td) {
            (Some(s), _) => s.request(&self.nodes_wb).is_some(),
            (None, Some(t)) => t.request().is_some(),
            (None, None) => false,
        };
        let mut mask = run as u32 | (read as u32) << 4 | (cbvh as u32) << 5;
        // Only the emitter and the toplevel unit fill the write buffers: before emission
        // starts they are empty.
        if self.emit_active || self.top.is_some() {
            mask |= (self.nodes_wb.ready().is_some() as u32) << 1
                | (self.leaves_wb.ready().is_some() as u32) << 2
                | (self.hl_wb.ready().is_some() as u32) << 3;
        }
        mask
    }

    /// The reader was visited by the arbiter with nothing to issue.
    #[inline]
    fn count_reader_blocked(&mut self) {
        if self.phase == Phase::PartialSort && self.in_next < self.npad {
            self.reader_blocked_cycles += 1;
        }
    }

    /// Bytes as the port counts them (whole bursts).
    fn burst_bytes(port: &dyn MemoryPort, addr: u64, bytes: u32) -> u64 {
        let bb = port.burst_bytes();
        crate::dram::bursts_of(addr, bytes, bb) * bb as u64
    }

    /// The CBVH unit's request: a backtracking read or write of the streaming encoder, or a
    /// node read of the top-down pass. Returns the bytes and whether it was a read.
    fn try_cbvh(&mut self) -> Option<Result<(u64, bool), ()>> {
        let (kind, addr, bytes, dest) = if let Some(st) = &self.stream {
            let (kind, addr, bytes) = st.request(&self.nodes_wb)?;
            (kind, addr, bytes, ReadDest::Backtrack)
        } else {
            let (j, addr, bytes) = self.td.as_ref()?.request()?;
            (AccessKind::Read, addr, bytes, ReadDest::Topdown { j })
        };
        let tag = match kind {
            AccessKind::Read => self.new_tag(ReadDesc {
                dest,
                src: 0,
                count: 0,
                bytes,
            }),
            AccessKind::Write => WRITE_TAG | bytes as u64,
        };
        let req = MemRequest {
            tag,
            addr,
            bytes,
            kind,
        };
        if self.port.send(req).is_err() {
            if kind == AccessKind::Read {
                self.free_tags.push(tag as u32);
            }
            return Some(Err(()));
        }
        match (&mut self.stream, &mut self.td) {
            (Some(st), _) => st.issued(),
            (None, Some(td)) => td.issued(),
            (None, None) => unreachable!("a CBVH request without a CBVH unit"),
        }
        if kind == AccessKind::Write {
            self.outstanding_writes += 1;
        }
        let read = kind == AccessKind::Read;
        Some(Ok((Self::burst_bytes(&*self.port, addr, bytes), read)))
    }

    fn try_read(&mut self) -> Option<Result<(u64, bool), ()>> {
        let Some((d, addr)) = self.next_read() else {
            if self.phase == Phase::PartialSort && self.in_next < self.npad {
                self.reader_blocked_cycles += 1;
            }
            return None;
        };
        let tag = self.new_tag(d);
        let req = MemRequest {
            tag,
            addr,
            bytes: d.bytes,
            kind: AccessKind::Read,
        };
        if self.port.send(req).is_err() {
            self.free_tags.push(tag as u32);
            return Some(Err(()));
        }
        match d.dest {
            ReadDest::Presort { p, .. } => {
                self.presorters[p as usize].alloc_slot();
                self.in_next += self.cfg.b as u64;
                // Two buffers make a sub-block; sub-blocks go round robin to presorters.
                self.in_second_half = !self.in_second_half;
                if !self.in_second_half {
                    self.in_p += 1;
                    if self.in_p == self.cfg.presorters {
                        self.in_p = 0;
                    }
                }
            }
            ReadDest::Merge { buf } => {
                self.refill.pop_front();
                self.merger.commit_fetch(buf, d.count);
            }
            ReadDest::Backtrack | ReadDest::Topdown { .. } => {
                unreachable!("the reader issues input and run reads only")
            }
        }
        Some(Ok((Self::burst_bytes(&*self.port, addr, d.bytes), true)))
    }

    fn try_run_write(&mut self) -> Option<Result<(u64, bool), ()>> {
        let len = self.run_fifo.len() as u64;
        let b = self.cfg.b as u64;
        if len == 0 || (len < b && !self.run_flush) {
            return None;
        }
        let count = len.min(b);
        let bytes = (count * ELEM_BYTES) as u32;
        let (m, gap) = (self.cfg.m as u64, self.cfg.run_gap_bytes as u64);
        let addr = self.layout.runs[self.dst] + run_offset(self.wr_pos, m, gap);
        let req = MemRequest {
            tag: WRITE_TAG | bytes as u64,
            addr,
            bytes,
            kind: AccessKind::Write,
        };
        if self.port.send(req).is_err() {
            return Some(Err(()));
        }
        for _ in 0..count {
            let e = self.run_fifo.pop().expect("counted");
            self.region[self.dst][self.wr_pos as usize] = e.index;
            self.wr_pos += 1;
        }
        self.outstanding_writes += 1;
        Some(Ok((Self::burst_bytes(&*self.port, addr, bytes), false)))
    }

    fn try_buffer_write(
        wb: &mut WriteBuffer,
        port: &mut dyn MemoryPort,
        outstanding: &mut u64,
    ) -> Option<Result<(u64, bool), ()>> {
        let (addr, bytes) = wb.ready()?;
        let req = MemRequest {
            tag: WRITE_TAG | bytes as u64,
            addr,
            bytes,
            kind: AccessKind::Write,
        };
        if port.send(req).is_err() {
            return Some(Err(()));
        }
        wb.issued(bytes);
        *outstanding += 1;
        Some(Ok((Self::burst_bytes(port, addr, bytes), false)))
    }

    fn on_response(&mut self, tag: u64, latency: u64) {
        if tag & WRITE_TAG != 0 {
            self.outstanding_writes -= 1;
            self.win.bus_bytes += tag & 0xffff_ffff;
            return;
        }
        let d = self.inflight[tag as usize];
        self.free_tags.push(tag as u32);
        self.win.bus_bytes += d.bytes as u64;
        match d.dest {
            ReadDest::Presort { p, slot } => {
                let b = self.cfg.b as usize;
                for i in 0..d.count as usize {
                    let e = self.input_elem(d.src + i as u64);
                    if let Some(c) = self.codes.get_mut(e.index as usize) {
                        if !e.is_pad() {
                            *c = e.code;
                        }
                    }
                    self.presorters[p as usize].ring[slot as usize * b + i] = e;
                }
                let ps = &mut self.presorters[p as usize];
                ps.slot_count[slot as usize] = d.count;
                ps.slot_valid[slot as usize] = true;
                self.presort_dirty = true;
            }
            ReadDest::Backtrack => {
                if let Some(st) = &mut self.stream {
                    st.read_returned(latency);
                }
            }
            ReadDest::Topdown { j } => {
                if let Some(td) = &mut self.td {
                    td.arrived(j, latency);
                }
            }
            ReadDest::Merge { buf } => {
                let s = d.src as usize;
                let src = &self.region[1 - self.dst][s..s + d.count as usize];
                let (aabbs, codes) = (self.aabbs, &self.codes);
                self.merger.fill_with(buf, src.len(), |k| {
                    let r = src[k];
                    match aabbs.get(r as usize) {
                        Some(&a) => Elem::new(codes[r as usize], r, a),
                        None => Elem::pad(r as u64),
                    }
                });
            }
        }
    }

    /// Every FIFO and unit state, for a deadlock report.
    fn state_dump(&self) -> String {
        let mut s = format!(
            "no unit progressed for {} cycles at cycle {} in phase {:?} ({} memory requests outstanding); ",
            self.idle,
            self.cycle,
            self.phase,
            self.port.outstanding()
        );
        for f in [self.emit_fifo.stats(), self.run_fifo.stats()] {
            s += &format!(
                "FIFO {}: {}/{} (peak {}, {} pushes); ",
                f.name, f.len, f.capacity, f.peak, f.pushes
            );
        }
        for (i, p) in self.presorters.iter().enumerate() {
            s += &format!(
                "presorter {i}: {:?}, sub-block {} {}/{} inserted, ring {}/{} used; ",
                p.state,
                p.sub,
                p.inserted,
                p.sub_len,
                p.used,
                p.slots()
            );
        }
        s += &format!(
            "merge: {:?}, heap {} live, refill queue {}; emitter: {} read, done {}; \
             write buffers: nodes {}, leaves {}, highlevel {} bytes pending; \
             {} writes outstanding",
            self.merger.state,
            self.merger.heap.live(),
            self.refill.len(),
            self.emit.consumed,
            self.emit.done,
            self.nodes_wb.pending(),
            self.leaves_wb.pending(),
            self.hl_wb.pending(),
            self.outstanding_writes
        );
        if let Some(u) = &self.stream {
            s += "; ";
            s += &u.state();
        }
        if let Some(u) = &self.td {
            s += "; ";
            s += &u.state();
        }
        s
    }

    /// Stall and busy counters of every unit.
    pub fn stall_report(&self) -> StallReport {
        let p = &self.presorters;
        StallReport {
            presort_busy_cycles: p.iter().map(|x| x.busy_cycles).sum::<u64>(),
            presort_starved_cycles: p.iter().map(|x| x.starved_cycles).sum::<u64>()
                + self.frozen_totals[0],
            presort_wait_scratchpad_cycles: p.iter().map(|x| x.wait_scratchpad_cycles).sum::<u64>()
                + self.frozen_totals[1],
            merge: self.merger.stalls,
            merge_outputs: self.merger.outputs,
            heap_ops: self.merger.ops,
            emitter: self.emit.stalls,
            emitter_steps: self.emit.steps,
            reader_blocked_cycles: self.reader_blocked_cycles,
            port_refusals: self.port_refusals,
            fifos: vec![self.emit_fifo.stats(), self.run_fifo.stats()],
        }
    }

    /// The memory port (for its statistics).
    pub fn port(&self) -> &dyn MemoryPort {
        &*self.port
    }

    /// The toplevel unit, if it ran.
    pub fn toplevel(&self) -> Option<&TopUnit> {
        self.top.as_ref()
    }
}
