//! The CBVH output units of \[P3\] §5.3 attached to MergeTree: the streaming bottom-up
//! encoder behind the hierarchy emitter, and the top-down compression pass that runs after
//! a single-precision build.
//!
//! # Streaming encoder (\[P3\] Algorithm 1, §4.3, §5.3)
//! [`StreamUnit`] consumes the emitter's nodes from a FIFO (`cbvh_fifo` entries; the emitter
//! stalls while it is full) and drives the software encoder [`cbvh::StreamEncoder`], so the
//! CBVH it writes is, bit for bit, the one `cbvh::compress_hlbvh` makes from the same stream.
//! Each node takes one cycle to encode (the encoder is pipelined, \[P3\] §4.3); the DRAM
//! accesses the encoder reports for it ([`MemOp`]) are then carried out in order, one at a
//! time, before the next node is taken:
//! - a node-pair write adds the pair's bytes to the tree write buffer (stalling while it is
//!   full), which writes them out in chunks like the single-precision node writer;
//! - a backtracking step (\[P3\] §5.2: "a minimum-size DRAM read and write") is a 64-byte read
//!   of the line holding the pair, and, once its data is back, a 64-byte write of that line.
//!   Steps are sequential, the pessimistic assumption of \[P3\] §5.3: the read of the next
//!   step (a child of this pair, found by decoding it) is issued only after this step's
//!   read has returned. A line with bytes still waiting in the write buffer is first written
//!   out (the buffer is flushed through the line's end) and then read: the unit has no
//!   forwarding path from its write buffer, so every step stays a DRAM read and write, as
//!   \[P3\]'s traffic model counts it. (The memory controller may still answer such a read
//!   from its own write queue: DRAMsim3 and Ramulator both do.) The what-if
//!   `cbvh_flush_before_backtrack = false` skips the flush and reads DRAM at once, as a
//!   model that replays the encoder's accesses without tracking where the data is would;
//!   the tree is the same (the data comes from the encoder), only the timing changes.
//!
//! # Top-down pass (\[P3\] Fig. 2a, §5.3)
//! [`TopdownUnit`] runs after the single-precision build has written its 64-byte nodes. It
//! reads them from the end of the node array backwards (the root was emitted last), so in
//! its order every parent comes before its children (reverse postorder is a preorder): the
//! context a node is encoded in is always known by the time the node's data arrives, and
//! no read depends on another read's data, since the array's extent is known when the
//! build ends. \[P3\] §5.3 makes the postprocessing unit optimistic ("starts each memory
//! operation immediately after its dependencies are available"); here that means one
//! 64-byte node read is offered to the memory arbiter every cycle with no limit on reads in
//! flight (the controller's queues are the only limit), and a node is encoded (one per
//! cycle, in stream order) as soon as its data is back, its pair going to the same kind of
//! write buffer as the streaming encoder's. Pair `j` of the output is the `j`-th node of
//! that order, so writes are sequential too. The functional result is
//! `cbvh::compress_topdown` of the built tree, which numbers the pairs in the tree's own
//! preorder; the two numberings are the same tree, and only addresses differ.

use std::collections::VecDeque;

use cbvh::bottomup::{InputNode, MemOp, StreamEncoder};
use cbvh::CbvhError;
use serde::Serialize;

use super::config::NODE_BYTES;
use super::machine::WriteBuffer;
use crate::dram::AccessKind;
use crate::fifo::Fifo;

/// Counters of the streaming encoder unit.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct StreamUnitStats {
    /// Nodes taken from the emitter.
    pub nodes_in: u64,
    /// Node pairs handed to the write buffer.
    pub pairs_written: u64,
    /// Backtracking reads issued (64 B each).
    pub backtrack_reads: u64,
    /// Backtracking writes issued (64 B each).
    pub backtrack_writes: u64,
    /// Backtracking reads whose line still had bytes in the write buffer, which was first
    /// flushed through the line.
    pub backtrack_flushes: u64,
    /// Sum over backtracking reads of their latency in unit cycles (accept to data).
    pub backtrack_read_latency_cycles: u64,
    /// Backtracking reads by latency: entry `i` counts latencies in `[2^i, 2^(i+1))` unit
    /// cycles (entry 0 also holds latency 0).
    pub backtrack_read_latency_log2: Vec<u64>,
    /// Cycles the unit encoded a node or wrote a pair.
    pub busy_cycles: u64,
    /// Cycles it had nothing to do and the emitter had not finished.
    pub starved_cycles: u64,
    /// Cycles it waited for a backtracking read's data.
    pub read_wait_cycles: u64,
    /// Cycles it waited for the write buffer to write a line out before reading it.
    pub flush_wait_cycles: u64,
    /// Cycles the write buffer had no room for a pair.
    pub write_full_cycles: u64,
}

impl StreamUnitStats {
    /// Mean backtracking read latency in unit cycles.
    pub fn mean_backtrack_read_latency(&self) -> f64 {
        if self.backtrack_reads == 0 {
            0.0
        } else {
            self.backtrack_read_latency_cycles as f64 / self.backtrack_reads as f64
        }
    }
}

/// Number of per-cycle counters [`StreamUnit::counters`] returns.
pub(super) const STREAM_COUNTERS: usize = 4;

/// The streaming bottom-up encoder unit (see the module documentation).
pub(super) struct StreamUnit {
    enc: StreamEncoder,
    /// Nodes from the emitter.
    pub input: Fifo<InputNode>,
    /// DRAM accesses of the node being processed, in order.
    ops: VecDeque<MemOp>,
    /// A backtracking read is in flight: nothing further may be issued before its data.
    awaiting_read: bool,
    /// The write buffer was asked to write out the line at the front of `ops`.
    flushing: bool,
    /// `end_stream` has been called.
    ended: bool,
    /// Everything has been encoded and handed out.
    pub done: bool,
    /// Counters.
    pub stats: StreamUnitStats,
    /// Write out a line still in the write buffer before reading it back.
    flush_before_read: bool,
}

impl StreamUnit {
    /// A unit around `enc`, with an input FIFO of `fifo` nodes; `flush_before_read`: see the
    /// module documentation.
    pub fn new(enc: StreamEncoder, fifo: u32, flush_before_read: bool) -> Self {
        Self {
            flush_before_read,
            enc,
            input: Fifo::new("emitter->cbvh encoder", fifo as usize),
            ops: VecDeque::new(),
            awaiting_read: false,
            flushing: false,
            ended: false,
            done: false,
            stats: StreamUnitStats::default(),
        }
    }

    /// True when the line of the backtracking read at the front has bytes waiting in `wb`.
    fn line_pending(&self, wb: &WriteBuffer, line: u64, bytes: u32) -> bool {
        self.flush_before_read && wb.pending() > 0 && wb.next_addr() < line + bytes as u64
    }

    /// One cycle. `emitter_done`: the emitter has output its last node. Returns true when
    /// the unit changed state.
    pub fn tick(&mut self, wb: &mut WriteBuffer, emitter_done: bool) -> Result<bool, CbvhError> {
        if self.done {
            return Ok(false);
        }
        if self.awaiting_read {
            self.stats.read_wait_cycles += 1;
            return Ok(false);
        }
        match self.ops.front().copied() {
            Some(MemOp::WritePair { bytes, .. }) => {
                if !wb.has_room(bytes as u64) {
                    self.stats.write_full_cycles += 1;
                    return Ok(false);
                }
                wb.add(bytes as u64);
                self.ops.pop_front();
                self.stats.pairs_written += 1;
                self.stats.busy_cycles += 1;
                Ok(true)
            }
            Some(MemOp::BacktrackRead {
                addr_bytes, bytes, ..
            }) => {
                if self.line_pending(wb, addr_bytes, bytes) {
                    self.stats.flush_wait_cycles += 1;
                    if !self.flushing {
                        self.flushing = true;
                        self.stats.backtrack_flushes += 1;
                        wb.flush_through(addr_bytes + bytes as u64);
                        return Ok(true);
                    }
                }
                // Otherwise the arbiter issues it ([`Self::request`]).
                Ok(false)
            }
            // Issued by the arbiter once the read is back.
            Some(MemOp::BacktrackWrite { .. }) => Ok(false),
            None => {
                if let Some(n) = self.input.pop() {
                    self.enc.push(n)?;
                    self.ops.extend(self.enc.drain_ops());
                    self.stats.nodes_in += 1;
                    self.stats.busy_cycles += 1;
                    Ok(true)
                } else if emitter_done && !self.ended {
                    // The root's treelet (or the root itself) is written last.
                    self.enc.end_stream()?;
                    self.ops.extend(self.enc.drain_ops());
                    self.ended = true;
                    Ok(true)
                } else if self.ended {
                    self.done = true;
                    Ok(true)
                } else {
                    self.stats.starved_cycles += 1;
                    Ok(false)
                }
            }
        }
    }

    /// The request the unit has ready for the memory arbiter: `(kind, address, bytes)`.
    #[inline]
    pub fn request(&self, wb: &WriteBuffer) -> Option<(AccessKind, u64, u32)> {
        if self.awaiting_read {
            return None;
        }
        match self.ops.front()? {
            MemOp::BacktrackRead {
                addr_bytes, bytes, ..
            } => (!self.line_pending(wb, *addr_bytes, *bytes)).then_some((
                AccessKind::Read,
                *addr_bytes,
                *bytes,
            )),
            MemOp::BacktrackWrite {
                addr_bytes, bytes, ..
            } => Some((AccessKind::Write, *addr_bytes, *bytes)),
            MemOp::WritePair { .. } => None,
        }
    }

    /// The arbiter issued the request of [`Self::request`].
    pub fn issued(&mut self) {
        match self.ops.pop_front() {
            Some(MemOp::BacktrackRead { .. }) => {
                self.awaiting_read = true;
                self.flushing = false;
                self.stats.backtrack_reads += 1;
            }
            Some(MemOp::BacktrackWrite { .. }) => self.stats.backtrack_writes += 1,
            other => unreachable!("the arbiter issued {other:?}"),
        }
    }

    /// A backtracking read's data arrived after `latency` unit cycles.
    pub fn read_returned(&mut self, latency: u64) {
        debug_assert!(self.awaiting_read);
        self.awaiting_read = false;
        self.stats.backtrack_read_latency_cycles += latency;
        let bucket = (63 - latency.max(1).leading_zeros()) as usize;
        let h = &mut self.stats.backtrack_read_latency_log2;
        if h.len() <= bucket {
            h.resize(bucket + 1, 0);
        }
        h[bucket] += 1;
    }

    /// The encoder, for its result once the unit is done.
    pub fn into_encoder(self) -> StreamEncoder {
        self.enc
    }

    /// Per-cycle stall counters an idle cycle may increment (for fast-forwarding).
    pub fn counters(&self) -> [u64; STREAM_COUNTERS] {
        let s = &self.stats;
        [
            s.starved_cycles,
            s.read_wait_cycles,
            s.flush_wait_cycles,
            s.write_full_cycles,
        ]
    }

    /// Adds `k` times the counter changes `d` of [`Self::counters`].
    pub fn add_counters(&mut self, d: &[u64], k: u64) {
        let s = &mut self.stats;
        s.starved_cycles += k * d[0];
        s.read_wait_cycles += k * d[1];
        s.flush_wait_cycles += k * d[2];
        s.write_full_cycles += k * d[3];
    }

    /// A one-line state description for deadlock reports.
    pub fn state(&self) -> String {
        format!(
            "cbvh encoder: {} nodes in, {} ops queued (front {:?}), awaiting read {}, ended {}, done {}; ",
            self.stats.nodes_in,
            self.ops.len(),
            self.ops.front(),
            self.awaiting_read,
            self.ended,
            self.done
        )
    }
}

/// Counters of the top-down compression pass.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TopdownStats {
    /// Single-precision nodes read (64 B each).
    pub node_reads: u64,
    /// Sum of their latencies in unit cycles.
    pub read_latency_cycles: u64,
    /// Node pairs handed to the write buffer.
    pub pairs_written: u64,
    /// Cycles the next node to encode had not arrived.
    pub read_wait_cycles: u64,
    /// Cycles the write buffer had no room for a pair.
    pub write_full_cycles: u64,
}

/// Number of per-cycle counters [`TopdownUnit::counters`] returns.
pub(super) const TOPDOWN_COUNTERS: usize = 2;

/// The top-down compression pass (see the module documentation).
pub(super) struct TopdownUnit {
    /// Nodes in the single-precision tree (emission order).
    nodes: u64,
    /// Byte address of emitted node 0.
    nodes_base: u64,
    /// Stream position of the next read: node `nodes - 1 - j`.
    next_read: u64,
    /// Whether the node at each stream position has arrived.
    arrived: Vec<bool>,
    /// Stream position of the next node to encode.
    next_encode: u64,
    /// Pairs to write: one per node, or one for a tree that is a single leaf.
    pairs: u64,
    pair_bytes: u64,
    /// Counters.
    pub stats: TopdownStats,
}

impl TopdownUnit {
    /// A pass over `nodes` emitted nodes at `nodes_base`, writing pairs of `pair_bytes`.
    pub fn new(nodes: u64, nodes_base: u64, pair_bytes: u64) -> Self {
        Self {
            nodes,
            nodes_base,
            next_read: 0,
            arrived: vec![false; nodes as usize],
            next_encode: 0,
            pairs: nodes.max(1),
            pair_bytes,
            stats: TopdownStats::default(),
        }
    }

    /// True once every pair has been handed to the write buffer.
    pub fn done(&self) -> bool {
        self.next_encode == self.pairs
    }

    /// One cycle: encodes the next node if its data is here. Returns true on progress.
    pub fn tick(&mut self, wb: &mut WriteBuffer) -> bool {
        if self.done() {
            return false;
        }
        // A tree that is one leaf has no node to read: its box is the root record.
        let here = self.nodes == 0 || self.arrived[self.next_encode as usize];
        if !here {
            self.stats.read_wait_cycles += 1;
            return false;
        }
        if !wb.has_room(self.pair_bytes) {
            self.stats.write_full_cycles += 1;
            return false;
        }
        wb.add(self.pair_bytes);
        self.next_encode += 1;
        self.stats.pairs_written += 1;
        true
    }

    /// The next node read for the arbiter: `(stream position, address, bytes)`.
    #[inline]
    pub fn request(&self) -> Option<(u64, u64, u32)> {
        (self.next_read < self.nodes).then(|| {
            let k = self.nodes - 1 - self.next_read;
            (
                self.next_read,
                self.nodes_base + k * NODE_BYTES,
                NODE_BYTES as u32,
            )
        })
    }

    /// The arbiter issued the read of [`Self::request`].
    pub fn issued(&mut self) {
        self.next_read += 1;
        self.stats.node_reads += 1;
    }

    /// The node at stream position `j` arrived after `latency` cycles.
    pub fn arrived(&mut self, j: u64, latency: u64) {
        self.arrived[j as usize] = true;
        self.stats.read_latency_cycles += latency;
    }

    /// Per-cycle stall counters an idle cycle may increment (for fast-forwarding).
    pub fn counters(&self) -> [u64; TOPDOWN_COUNTERS] {
        [self.stats.read_wait_cycles, self.stats.write_full_cycles]
    }

    /// Adds `k` times the counter changes `d` of [`Self::counters`].
    pub fn add_counters(&mut self, d: &[u64], k: u64) {
        self.stats.read_wait_cycles += k * d[0];
        self.stats.write_full_cycles += k * d[1];
    }

    /// Work done and total, for the progress hook.
    pub fn progress(&self) -> (u64, u64) {
        (self.next_encode, self.pairs)
    }

    /// A one-line state description for deadlock reports.
    pub fn state(&self) -> String {
        format!(
            "top-down pass: {}/{} read, {}/{} encoded; ",
            self.next_read, self.nodes, self.next_encode, self.pairs
        )
    }
}
