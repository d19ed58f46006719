//! The CBVH output units of \[P3\] §5.3 attached to MergeTree: the streaming bottom-up
//! encoder behind the hierarchy emitter, and the top-down compression pass that runs after
//! a single-precision build.
//!
//! # Streaming encoder (\[P3\] Algorithm 1, §4.3, §5.3)
//! The streaming encoder unit (`Stream` in [`super::machine`]) consumes the emitter's nodes from a FIFO (`cbvh_fifo` entries; the emitter
//! stalls while it is full) and drives the software encoder [`cbvh::StreamEncoder`], so the
//! CBVH it writes is, bit for bit, the one `cbvh::compress_hlbvh` makes from the same stream.
//! Each node takes one cycle to encode (the encoder is pipelined, \[P3\] §4.3); the DRAM
//! accesses the encoder reports for it ([`cbvh::bottomup::MemOp`]) are then carried out in order, one at a
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
//! The top-down pass (`Topdown` in [`super::machine`]) runs after the single-precision build has written its 64-byte nodes. It
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

use serde::Serialize;

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

/// Counters of the top-down compression pass.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TopdownStats {
    /// Single-precision nodes read (64 B each).
    pub node_reads: u64,
    /// Sum of their latencies in unit cycles.
    pub read_latency_cycles: u64,
    /// Node pairs handed to the write buffer (wide nodes, in the MBVH4 collapse pass).
    pub pairs_written: u64,
    /// Cycles the next node to encode had not arrived.
    pub read_wait_cycles: u64,
    /// Cycles the write buffer had no room for a pair.
    pub write_full_cycles: u64,
}
