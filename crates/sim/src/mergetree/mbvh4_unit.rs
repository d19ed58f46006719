//! The MBVH4 outputs of MergeTree (issue 18 part 2): 128-byte 4-wide nodes (\[P4\] §3.1)
//! from the streaming collapse unit behind the hierarchy emitter, or from a collapse pass
//! after a build of 64-byte binary nodes (the baseline).
//!
//! # Streaming collapse unit (`output = mbvh4`)
//! The unit (`Collapse` in [`super::machine`]) consumes the emitter's binary nodes from a
//! FIFO (`cbvh_fifo` entries; the emitter stalls while it is full), exactly as the
//! streaming CBVH encoder does ([`super::cbvh_unit`]), and drives the software collapse
//! [`bvh::StreamCollapse`], so the tree it writes is, node for node, the one
//! [`bvh::stream_collapse`] makes from the same stream. Timing: one cycle to consume a
//! node (the open/close decision compares two slot counts and two box areas; the areas
//! are a few multiply-adds, pipelined), then one cycle per wide node the decision closes
//! (0, 1 or 2), each handing 128 bytes to the node write buffer (stalling while it is
//! full); at the end of the stream one cycle to take the root and one to write it. The
//! binary nodes are never written: the node traffic is 128 bytes per wide node instead of
//! 64 bytes per binary node. The unit holds one 128-byte node of slots per open subtree,
//! at most the emitter's deepest stack + 1 (see [`bvh::StreamCollapse`]; the report gives
//! the peak). With `mbvh4_window = L` the unit runs the windowed rule
//! ([`bvh::StreamCollapse::with_window`]) and spends L more cycles per node (and at the
//! end): a node's arrival changes the least-cost rows (four budgets, three splits each)
//! of the treelet nodes on its path, at most L + 1 of them, one row per cycle. Wide nodes
//! go to the output region (`cbvh` in [`super::MemoryLayout`]) in
//! write order, each after the nodes it references.
//!
//! # Compressed wide nodes (`output = cbvh4`)
//! The collapse unit above hands each wide node it closes to a FIFO (`cbvh_fifo` entries,
//! stalling while it is full) instead of writing it, and behind it the streaming CBVH unit
//! of [`super::cbvh_unit`] drives [`cbvh::WideStreamEncoder`] (\[P3\] Algorithm 1 over
//! 4-wide nodes): one cycle per wide node taken, one per compressed node (32 bytes at 6
//! bits) handed to the write buffer, and per backtracking step a read and a write of the
//! 64-byte lines holding the node, one step at a time. The tree equals
//! [`cbvh::compress_stream_collapse`] of the same stream bit for bit
//! ([`super::cbvh4_matches_software`]); [`Cbvh4RunReport`] has the counts.
//!
//! # Collapse pass (`output = mbvh4-collapse`)
//! The baseline builds as `output = bvh` (64-byte nodes in emission order), then a pass
//! reads the nodes back and writes the offline greedy collapse ([`bvh::collapse`] of the
//! built tree: what \[P4\]-style software does after a binary build). It is the top-down
//! pass unit of the CBVH baseline (`Topdown` in [`super::machine`], see
//! [`super::cbvh_unit`]) with another output: it reads the 64-byte nodes from the end of
//! the array backwards (a preorder: every parent before its children), with one read
//! offered per cycle and no limit on reads in flight, consumes one node per cycle in that
//! order, and writes a 128-byte wide node when it consumes the binary node that roots one
//! ([`bvh::Collapse::wide_roots`]). The bytes are exact (every binary node read once,
//! every wide node written once); the write times are optimistic, since a wide node is
//! complete only once the binary nodes it pulls up (children and grandchildren of its
//! root) have been read, a few reads later.

use serde::Serialize;

use super::cbvh_unit::TopdownStats;
use super::config::{OutputMode, MBVH4_NODE_BYTES};

/// Counters of the streaming collapse unit.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CollapseUnitStats {
    /// Binary nodes taken from the emitter.
    pub nodes_in: u64,
    /// Wide nodes handed to the write buffer (128 B each).
    pub nodes_written: u64,
    /// Peak number of open subtrees held (one 128-byte node of slots each with the greedy
    /// rule).
    pub max_open: u64,
    /// Peak unresolved binary nodes held over all open subtrees (windowed rule; 0 with
    /// the greedy rule).
    pub max_treelet_nodes: u64,
    /// Peak bytes of the windowed rule's treelets, rows and items
    /// ([`bvh::StreamCollapse::max_window_bytes`]; 0 with the greedy rule).
    pub max_window_bytes: u64,
    /// Cycles the unit consumed a node, took the root or wrote a wide node.
    pub busy_cycles: u64,
    /// Cycles it had nothing to do and the emitter had not finished.
    pub starved_cycles: u64,
    /// Cycles the write buffer had no room for a wide node.
    pub write_full_cycles: u64,
    /// Cycles the FIFO to the wide encoder was full (`cbvh4`).
    pub encoder_full_cycles: u64,
}

/// What the MBVH4 output of a run did.
#[derive(Clone, Debug, Serialize)]
pub struct Mbvh4RunReport {
    /// `mbvh4` or `mbvh4-collapse`.
    pub mode: OutputMode,
    /// Wide nodes written.
    pub wide_nodes: u64,
    /// Bytes of one wide node (128).
    pub node_bytes: u64,
    /// Binary nodes the emitter produced (written and read back by the collapse pass;
    /// never written by the streaming unit).
    pub binary_nodes: u64,
    /// SAH of the MBVH4 with 4-wide nodes costing `2 C_i` ([`bvh::Mbvh4::normalized_sah`]).
    pub sah: f64,
    /// Mean used slots per wide node.
    pub mean_children: f64,
    /// Cycles until the build's output was complete in DRAM: for the collapse pass, the
    /// binary build before the pass; for streaming, the whole run.
    pub build_cycles: u64,
    /// `build_cycles` in milliseconds.
    pub build_ms: f64,
    /// Cycles of the collapse pass (0 for streaming).
    pub collapse_cycles: u64,
    /// Streaming unit counters.
    pub stream: Option<CollapseUnitStats>,
    /// Collapse pass counters (`pairs_written` counts the wide nodes written).
    pub pass: Option<TopdownStats>,
    /// The MBVH4 written (depth-first preorder).
    #[serde(skip)]
    pub tree: bvh::Mbvh4,
}

/// What the compressed 4-wide output of a run did (`output = cbvh4`): the collapse unit's
/// and the wide encoder's counts, and the trees.
#[derive(Clone, Debug, Serialize)]
pub struct Cbvh4RunReport {
    /// Quantization parameters.
    pub params: cbvh::Params,
    /// Treelet depth of the wide encoder (1 = none).
    pub treelet_depth: u32,
    /// The collapse's window (`None`: the greedy rule).
    pub mbvh4_window: Option<u32>,
    /// Compressed wide nodes written.
    pub wide_nodes: u64,
    /// Bytes of one compressed wide node (32 at 6 bits).
    pub node_bytes: u64,
    /// Binary nodes the emitter produced (never written).
    pub binary_nodes: u64,
    /// Backtracking steps of the wide encoder.
    pub backtrack_steps: u64,
    /// Backtracking steps by depth.
    pub backtrack_depth_hist: Vec<u64>,
    /// Peak subtrees the wide encoder held (waiting for their parent).
    pub max_held: u64,
    /// SAH of the exact (uncompressed) 4-wide tree ([`bvh::Mbvh4::normalized_sah`]).
    pub sah: f64,
    /// SAH of the tree the compressed nodes decode to.
    pub sah_decoded: f64,
    /// Mean used slots per wide node.
    pub mean_children: f64,
    /// Cycles of the whole run (the output is complete in DRAM at its end).
    pub build_cycles: u64,
    /// `build_cycles` in milliseconds.
    pub build_ms: f64,
    /// Collapse unit counters (`nodes_written`: wide nodes handed to the encoder).
    pub collapse: Option<CollapseUnitStats>,
    /// Wide encoder unit counters (`pairs_written`: compressed wide nodes written).
    pub stream: Option<super::cbvh_unit::StreamUnitStats>,
    /// The encoder's own counts.
    #[serde(skip)]
    pub encode: cbvh::EncodeStats,
    /// The compressed tree written.
    #[serde(skip)]
    pub tree: cbvh::Cbvh4,
    /// The exact 4-wide tree the collapse made (depth-first preorder).
    #[serde(skip)]
    pub exact: bvh::Mbvh4,
}

/// The emission (postorder) index of every node of a tree in the preorder that
/// [`bvh::Highlevel::to_bvh2`] lays the emitted nodes out in: child 0's subtree, child 1's
/// subtree, then the node.
pub fn emission_index(bvh: &bvh::Bvh2) -> Vec<u32> {
    let n = bvh.nodes.len();
    let mut rank = vec![0u32; n];
    let mut next = 0u32;
    let mut stack: Vec<(usize, bool)> = Vec::with_capacity(64);
    if n > 0 {
        stack.push((0, false));
    }
    while let Some((i, expanded)) = stack.pop() {
        if expanded {
            rank[i] = next;
            next += 1;
            continue;
        }
        stack.push((i, true));
        for c in bvh.nodes[i].children.iter().rev() {
            if c.is_inner() && (c.index as usize) < n {
                stack.push((c.index as usize, false));
            }
        }
    }
    rank
}

/// Bytes the collapse pass writes after consuming each binary node, in its read order
/// (emitted node `nodes - 1 - j` at position `j`): 128 for the binary nodes that root a
/// wide node of the offline collapse, 0 for the others. A scene that is one leaf has no
/// binary node and one position, the root node.
pub fn collapse_pass_writes(hl: &bvh::Highlevel) -> Result<Vec<u64>, bvh::CollapseError> {
    let m = hl.nodes.len();
    if m == 0 {
        return Ok(vec![MBVH4_NODE_BYTES]);
    }
    let bvh = hl.to_bvh2();
    let rank = emission_index(&bvh);
    let mut bytes = vec![0; m];
    for r in bvh::Collapse::default().wide_roots(&bvh)? {
        bytes[m - 1 - rank[r as usize] as usize] = MBVH4_NODE_BYTES;
    }
    Ok(bytes)
}
