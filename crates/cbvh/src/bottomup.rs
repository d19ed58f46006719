//! Streaming bottom-up compression: \[P3\] Algorithm 1 (§4.1) and treelet-based compression
//! (§4.3), as one step machine fed one BVH node at a time.
//!
//! Nodes arrive in depth-first bottom-up order (every node after both of its children, the
//! second child's subtree last), as the streaming hierarchy emitter of `bvh::Emitter`
//! outputs them. For each node the encoder
//! 1. pops the subtrees of its inner children from the context stack (child 1 first),
//! 2. estimates its context from its own box (`EstimateContext`: the finest grid that
//!    can hold it; its real context, known only once its parent is encoded, is never finer),
//! 3. encodes the treelet of not-yet-written nodes below it top-down from that estimate
//!    and writes the nodes that are `treelet_depth` levels down (with `treelet_depth = 1`,
//!    the node itself: plain Algorithm 1),
//! 4. compares, for each written node whose parent was just written, the context the
//!    parent's encoding gives it with the one it was encoded in, and on a mismatch
//!    **backtracks**: reads the node back, decodes its children with the old context,
//!    re-encodes those decoded boxes with the new one, writes it, and recurses into the
//!    children whose contexts changed (`Backtrack` of Algorithm 1),
//! 5. pushes the subtree on the context stack.
//!
//! A mismatch is a scale change, and for relative coordinates also a lower-bound change
//! (\[P3\] §4.2: modulo coordinates only depend on the scale). Backtracking re-encodes
//! decoded (already enlarged) boxes; rounding their upper bounds up rather than with Eq. 1's
//! `floor + 1` (see [`crate::coords::quantize`]) makes that exact, so the result encloses
//! top-down compression's boxes and in practice equals them (the report measures it).
//!
//! Treelets (§4.3): the top `treelet_depth - 1` levels of every subtree on the stack are
//! kept unwritten (on chip); each new node re-encodes its treelet top-down from its own
//! estimate and writes the level `treelet_depth` below it. A wrong estimate is then
//! repaired for free while its effect stays within the treelet, which removes the short
//! backtracks that dominate (\[P3\] Fig. 7).
//!
//! Hooks for a cycle model: [`StreamEncoder::push`] consumes one emitted node; with
//! [`StreamConfig::record_ops`] every DRAM access it makes is appended as a [`MemOp`] (the
//! node-pair writes, and per backtracking step one 64-byte read and one 64-byte write of
//! the line holding the pair), to be drained with [`StreamEncoder::drain_ops`].

use crate::codec::{check_box, decode_slots, encode_slots, slot_ptr, ChildPtr, Ctx};
use crate::error::CbvhError;
use crate::format::{node_bytes, NodePair, Slot, LEAF_END, MAX_PTR};
use crate::grid::Params;
use crate::tree::{prim_ids_of, Cbvh};
use crate::EncodeStats;
use bvh::{Bvh2, EmitRef, EmittedNode, Highlevel, HighlevelRoot};
use geom::Aabb;

/// \[P3\] §5.2: "a DRAM interface with a 64B access granularity".
pub const DRAM_LINE_BYTES: u64 = 64;

/// Configuration of the streaming encoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StreamConfig {
    /// Quantization parameters.
    pub params: Params,
    /// Treelet depth `M` (\[P3\] §4.3): 1 = plain Algorithm 1; 2, 3, 4 keep `M - 1` levels
    /// on chip.
    pub treelet_depth: u32,
    /// Record every DRAM access as a [`MemOp`].
    pub record_ops: bool,
    /// Byte address of node pair 0 (for the recorded accesses).
    pub base_addr_bytes: u64,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            params: Params::default(),
            treelet_depth: 1,
            record_ops: false,
            base_addr_bytes: 0,
        }
    }
}

/// Largest treelet depth accepted (the on-chip treelet has up to `2^M - 1` nodes).
pub const MAX_TREELET_DEPTH: u32 = 8;

/// A child of an input node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InChild {
    /// A leaf whose primitive ids start at index `first` of the primitive-id array.
    Leaf {
        /// First primitive-id index.
        first: u32,
    },
    /// An inner node: the subtree on top of the context stack.
    Node,
    /// No child.
    Empty,
}

/// One node of the bottom-up input stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputNode {
    /// Original (full-precision) boxes of child 0 and child 1.
    pub boxes: [Aabb; 2],
    /// Child 0 and child 1.
    pub children: [InChild; 2],
    /// Node-pair address to write to (refit: the existing one); `None` appends.
    pub addr: Option<u32>,
}

/// A DRAM access made by the encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemOp {
    /// A node pair written for the first time (streaming output).
    WritePair {
        /// Node-pair index.
        pair: u32,
        /// Byte address.
        addr_bytes: u64,
        /// Bytes written.
        bytes: u32,
    },
    /// A backtracking read of the line holding a node pair.
    BacktrackRead {
        /// Node-pair index.
        pair: u32,
        /// Byte address of the line.
        addr_bytes: u64,
        /// Bytes read.
        bytes: u32,
    },
    /// A backtracking write of the line holding a node pair.
    BacktrackWrite {
        /// Node-pair index.
        pair: u32,
        /// Byte address of the line.
        addr_bytes: u64,
        /// Bytes written.
        bytes: u32,
    },
}

/// A subtree as the encoder holds it (`K` children per node: node pairs, or the 4-wide
/// nodes of [`crate::wide`]).
#[derive(Debug)]
pub(crate) enum PRef<const K: usize> {
    Leaf(u32),
    Empty,
    /// Not yet written (part of an on-chip treelet).
    Pending(Box<Pending<K>>),
    /// Written at `addr`, encoded in context `ctx`.
    Written {
        addr: u32,
        ctx: Ctx,
    },
}

#[derive(Debug)]
pub(crate) struct Pending<const K: usize> {
    pub(crate) boxes: [Aabb; K],
    pub(crate) children: [PRef<K>; K],
    pub(crate) addr: Option<u32>,
}

impl<const K: usize> PRef<K> {
    /// A leaf child whose primitive ids start at `first`.
    pub(crate) fn leaf(first: u32) -> Result<Self, CbvhError> {
        if first > MAX_PTR {
            return Err(CbvhError::TooLarge {
                what: "primitive-id index",
                count: first as usize,
            });
        }
        Ok(PRef::Leaf(first))
    }
}

/// The part of the streaming encoder that does not depend on how the input names a
/// node's children: \[P3\] Algorithm 1's encode, write and backtracking (with treelets)
/// over nodes of `K` child slots. [`StreamEncoder`] drives it with node pairs (children
/// from the context stack), [`crate::wide::WideStreamEncoder`] with 4-wide nodes (children
/// by reference).
#[derive(Debug)]
pub(crate) struct Engine<const K: usize> {
    pub(crate) cfg: StreamConfig,
    pub(crate) nodes: Vec<[Slot; K]>,
    pub(crate) next_addr: u32,
    pub(crate) stats: EncodeStats,
    pub(crate) ops: Vec<MemOp>,
}

impl<const K: usize> Engine<K> {
    /// An engine that appends nodes; checks the configuration.
    pub(crate) fn new(cfg: StreamConfig) -> Result<Self, CbvhError> {
        cfg.params.check()?;
        if !(1..=MAX_TREELET_DEPTH).contains(&cfg.treelet_depth) {
            return Err(CbvhError::InvalidParams(format!(
                "treelet depth must be 1..={MAX_TREELET_DEPTH}, got {}",
                cfg.treelet_depth
            )));
        }
        Ok(Self {
            cfg,
            nodes: Vec::new(),
            next_addr: 0,
            stats: EncodeStats::default(),
            ops: Vec::new(),
        })
    }

    /// Bytes of one packed node.
    pub(crate) fn node_bytes(&self) -> u64 {
        node_bytes(K as u32, self.cfg.params.bits) as u64
    }

    /// Encodes a new node `r` (original box `bx`) from its estimated context
    /// (`EstimateContext`) and writes the treelet level `treelet_depth` below it.
    pub(crate) fn push(&mut self, r: &mut PRef<K>, bx: &Aabb) -> Result<(), CbvhError> {
        let ctx = Ctx::estimate(bx, &self.cfg.params);
        self.visit(r, &ctx, 1, self.cfg.treelet_depth)
    }

    /// Ends the stream at the root `root` (original box `bx`): writes what is left of its
    /// treelet top-down from its estimated context; returns its address and context.
    pub(crate) fn end(&mut self, mut root: PRef<K>, bx: &Aabb) -> Result<(u32, Ctx), CbvhError> {
        let root_ctx = Ctx::estimate(bx, &self.cfg.params);
        self.visit(&mut root, &root_ctx, 1, 1)?;
        let PRef::Written { addr, .. } = root else {
            return Err(CbvhError::BadOrder(
                "the root of the stream is a leaf".into(),
            ));
        };
        Ok((addr, root_ctx))
    }

    /// Checks that the written addresses cover the node array and hands it over.
    pub(crate) fn take_nodes(&mut self) -> Result<Vec<[Slot; K]>, CbvhError> {
        if self.next_addr as usize != self.nodes.len() {
            return Err(CbvhError::Corrupt(
                "node addresses do not cover the node array".into(),
            ));
        }
        Ok(std::mem::take(&mut self.nodes))
    }

    /// The DRAM line (address, bytes) a backtracking step reads and writes for the node at
    /// `addr`. A node pair: the 64-byte line holding its first byte (\[P3\] §5.2, one
    /// minimum-size access; at 6 bits a pair never straddles lines). A wider node: every
    /// line it touches (at 6 bits a 32-byte 4-wide node sits in one line).
    fn line_of(&self, addr: u32) -> (u64, u32) {
        let start = self.cfg.base_addr_bytes + addr as u64 * self.node_bytes();
        let first = start & !(DRAM_LINE_BYTES - 1);
        if K == 2 {
            return (first, DRAM_LINE_BYTES as u32);
        }
        let last = (start + self.node_bytes() - 1) & !(DRAM_LINE_BYTES - 1);
        (first, (last - first + DRAM_LINE_BYTES) as u32)
    }

    /// Writes a fresh node at `addr` (or the next free address) and returns the address.
    fn write(&mut self, addr: Option<u32>, node: [Slot; K]) -> Result<u32, CbvhError> {
        let a = match addr {
            Some(a) => {
                if a as usize >= self.nodes.len() {
                    return Err(CbvhError::Corrupt(format!("node address {a} out of range")));
                }
                a
            }
            None => {
                if self.next_addr > MAX_PTR {
                    return Err(CbvhError::TooLarge {
                        what: if K == 2 { "node pair" } else { "wide node" },
                        count: self.next_addr as usize,
                    });
                }
                self.nodes.push([Slot::default(); K]);
                self.next_addr += 1;
                self.next_addr - 1
            }
        };
        self.nodes[a as usize] = node;
        self.stats.nodes_written += 1;
        if self.cfg.record_ops {
            let bytes = self.node_bytes();
            self.ops.push(MemOp::WritePair {
                pair: a,
                addr_bytes: self.cfg.base_addr_bytes + a as u64 * bytes,
                bytes: bytes as u32,
            });
        }
        Ok(a)
    }

    /// Encodes subtree `r` in context `ctx` at treelet depth `depth`; writes it when
    /// `depth >= limit`, and checks (backtracks) written nodes below written ones.
    // The loops walk the child slots of parallel arrays (children, contexts, pointers).
    #[allow(clippy::needless_range_loop)]
    fn visit(
        &mut self,
        r: &mut PRef<K>,
        ctx: &Ctx,
        depth: u32,
        limit: u32,
    ) -> Result<(), CbvhError> {
        let written = match r {
            PRef::Leaf(_) | PRef::Empty => return Ok(()),
            PRef::Written { addr, ctx: stored } => {
                if stored.invalidates(ctx, &self.cfg.params) {
                    self.backtrack(*addr, *stored, *ctx, 1)?;
                }
                *stored = *ctx;
                return Ok(());
            }
            PRef::Pending(p) => {
                let ptrs = p.children.each_ref().map(|c| match c {
                    PRef::Leaf(f) => ChildPtr::Leaf(*f),
                    PRef::Empty => ChildPtr::Empty,
                    PRef::Written { addr, .. } => ChildPtr::Inner(*addr),
                    PRef::Pending(_) => ChildPtr::Inner(0),
                });
                let (mut node, kids) = encode_slots(&p.boxes, ptrs, ctx, &self.cfg.params, false);
                if depth < limit {
                    // Still on chip: place the treelet's lower levels.
                    for c in 0..K {
                        if matches!(p.children[c], PRef::Pending(_)) {
                            self.visit(&mut p.children[c], &kids[c], depth + 1, limit)?;
                        }
                    }
                    return Ok(());
                }
                // Write this node: unwritten children first (only at the end of the
                // stream), so that every pointer is known.
                let was_written = p
                    .children
                    .each_ref()
                    .map(|c| matches!(c, PRef::Written { .. }));
                for c in 0..K {
                    if matches!(p.children[c], PRef::Pending(_)) {
                        self.visit(&mut p.children[c], &kids[c], depth + 1, limit)?;
                        if let PRef::Written { addr, .. } = p.children[c] {
                            node[c].ptr = addr;
                        }
                    }
                }
                let addr = self.write(p.addr, node)?;
                // Children written earlier: did this encoding invalidate them?
                for c in 0..K {
                    if was_written[c] {
                        self.visit(&mut p.children[c], &kids[c], depth + 1, limit)?;
                    }
                }
                addr
            }
        };
        *r = PRef::Written {
            addr: written,
            ctx: *ctx,
        };
        Ok(())
    }

    /// `Backtrack` of Algorithm 1: re-encodes the written node `addr` from context `old`
    /// to context `new`, recursing into children whose contexts change.
    fn backtrack(&mut self, addr: u32, old: Ctx, new: Ctx, depth: usize) -> Result<(), CbvhError> {
        self.stats.record_backtrack(depth);
        if self.cfg.record_ops {
            let (addr_bytes, bytes) = self.line_of(addr);
            let pair = addr;
            self.ops.push(MemOp::BacktrackRead {
                pair,
                addr_bytes,
                bytes,
            });
            self.ops.push(MemOp::BacktrackWrite {
                pair,
                addr_bytes,
                bytes,
            });
        }
        let p = self.cfg.params;
        let p = &p;
        let node = *self
            .nodes
            .get(addr as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("pointer {addr} outside the tree")))?;
        let olds = decode_slots(&node, &old, p);
        let boxes = olds.map(|o| o.map_or(Aabb::EMPTY, |c| c.aabb()));
        let ptrs = node.map(|s| slot_ptr(&s));
        let (fresh, kids) = encode_slots(&boxes, ptrs, &new, p, true);
        if fresh == node {
            self.stats.backtrack_unchanged += 1;
        }
        self.nodes[addr as usize] = fresh;
        for c in 0..K {
            if let (ChildPtr::Inner(k), Some(o)) = (ptrs[c], olds[c]) {
                if o.invalidates(&kids[c], p) {
                    self.backtrack(k, o, kids[c], depth + 1)?;
                }
            }
        }
        Ok(())
    }
}

/// The streaming bottom-up encoder of node pairs (see the module doc).
#[derive(Debug)]
pub struct StreamEncoder {
    eng: Engine<2>,
    stack: Vec<(PRef<2>, Aabb)>,
    pushed: u64,
    /// The root's address and context once the stream has ended.
    root: Option<(u32, Ctx)>,
}

impl StreamEncoder {
    /// An encoder that appends node pairs (construction).
    pub fn new(cfg: StreamConfig) -> Result<Self, CbvhError> {
        Ok(Self {
            eng: Engine::new(cfg)?,
            stack: Vec::new(),
            pushed: 0,
            root: None,
        })
    }

    /// An encoder that overwrites an existing array of `pairs` node pairs in place
    /// (refit: every input node names its address).
    pub fn in_place(cfg: StreamConfig, pairs: usize) -> Result<Self, CbvhError> {
        let mut e = Self::new(cfg)?;
        e.eng.nodes = vec![[Slot::default(); 2]; pairs];
        e.eng.next_addr = pairs as u32;
        Ok(e)
    }

    /// Counts so far.
    pub fn stats(&self) -> &EncodeStats {
        &self.eng.stats
    }

    /// The DRAM accesses recorded since the last call (empty unless `record_ops`).
    pub fn drain_ops(&mut self) -> Vec<MemOp> {
        std::mem::take(&mut self.eng.ops)
    }

    /// `BUCompressNode` of Algorithm 1 (with treelets): consumes the next node.
    pub fn push(&mut self, node: InputNode) -> Result<(), CbvhError> {
        if self.root.is_some() {
            return Err(CbvhError::BadOrder(
                "a node after the end of the stream".into(),
            ));
        }
        let index = self.pushed as usize;
        self.pushed += 1;
        for (c, b) in node.boxes.iter().enumerate() {
            check_box(b, 2 * index + c)?;
        }
        let mut children = [PRef::Empty, PRef::Empty];
        for c in (0..2).rev() {
            children[c] = match node.children[c] {
                InChild::Leaf { first } => PRef::leaf(first)?,
                InChild::Empty => PRef::Empty,
                InChild::Node => {
                    self.stack
                        .pop()
                        .ok_or_else(|| {
                            CbvhError::BadOrder(format!(
                                "node {index} has an inner child but the context stack is empty"
                            ))
                        })?
                        .0
                }
            };
        }
        let bx = node.boxes[0].union(node.boxes[1]);
        let mut r = PRef::Pending(Box::new(Pending {
            boxes: node.boxes,
            children,
            addr: node.addr,
        }));
        self.eng.push(&mut r, &bx)?;
        self.stack.push((r, bx));
        self.eng.stats.max_stack = self.eng.stats.max_stack.max(self.stack.len());
        Ok(())
    }

    /// Ends the stream: writes the remaining treelet top-down from the root's estimated
    /// context (the accesses it makes are recorded, so a cycle model calls this, drains the
    /// ops, then calls [`StreamEncoder::finish`]). Calling it again does nothing.
    pub fn end_stream(&mut self) -> Result<(), CbvhError> {
        if self.root.is_some() {
            return Ok(());
        }
        if self.stack.len() != 1 {
            return Err(CbvhError::BadOrder(format!(
                "{} subtrees left at the end of the stream (expected one root)",
                self.stack.len()
            )));
        }
        let (root, bx) = self.stack.pop().expect("one entry");
        self.root = Some(self.eng.end(root, &bx)?);
        Ok(())
    }

    /// Ends the stream (see [`StreamEncoder::end_stream`]) and returns the tree over the
    /// primitive-id array `prim_ids`, with the counts.
    pub fn finish(mut self, prim_ids: Vec<u32>) -> Result<(Cbvh, EncodeStats), CbvhError> {
        self.end_stream()?;
        let (addr, root_ctx) = self.root.expect("end_stream sets the root");
        let pairs = self
            .eng
            .take_nodes()?
            .into_iter()
            .map(|slots| NodePair { slots })
            .collect();
        Ok((
            Cbvh {
                params: self.eng.cfg.params,
                pairs,
                root: addr,
                root_ctx,
                prim_ids,
            },
            self.eng.stats,
        ))
    }
}

/// The encoder input for a leaf of the emitter's stream: flags the leaf's last entry of
/// the primitive-id array `ids` with [`LEAF_END`] (as the CBVH format needs) and returns
/// the child reference.
fn leaf_child(ids: &mut [u32], first: u32, count: u32) -> Result<InChild, CbvhError> {
    let last = (first as usize + count as usize).wrapping_sub(1);
    let id = ids
        .get_mut(last)
        .filter(|_| count > 0)
        .ok_or_else(|| CbvhError::Corrupt("leaf outside the primitive order".into()))?;
    *id |= LEAF_END;
    Ok(InChild::Leaf { first })
}

/// The encoder input for node `n` of the emitter's stream (`bvh::Step::Emitted`), flagging
/// the last primitive id of each leaf child in `ids` (the leaf table so far). A cycle model
/// calls this once per emitted node, as [`compress_hlbvh`] does.
#[allow(clippy::needless_range_loop)] // two child slots of parallel arrays
pub fn input_of_emitted(n: &EmittedNode, ids: &mut [u32]) -> Result<InputNode, CbvhError> {
    let mut children = [InChild::Node; 2];
    for c in 0..2 {
        if let EmitRef::Leaf { first, count } = n.children[c] {
            children[c] = leaf_child(ids, first, count)?;
        }
    }
    Ok(InputNode {
        boxes: n.aabbs,
        children,
        addr: None,
    })
}

/// The encoder input that a stream's root needs before its nodes: when the whole tree is
/// one leaf (no inner node is emitted), a node holding that leaf and an empty child; for
/// an inner root, nothing. With no root (an empty scene), an empty node.
pub fn input_of_root(
    root: Option<&HighlevelRoot>,
    ids: &mut [u32],
) -> Result<Option<InputNode>, CbvhError> {
    match root {
        None => Ok(Some(InputNode {
            boxes: [Aabb::EMPTY; 2],
            children: [InChild::Empty; 2],
            addr: None,
        })),
        Some(r) => match r.root {
            EmitRef::Leaf { first, count } => Ok(Some(InputNode {
                boxes: [r.aabb, Aabb::EMPTY],
                children: [leaf_child(ids, first, count)?, InChild::Empty],
                addr: None,
            })),
            EmitRef::Node(_) => Ok(None),
        },
    }
}

/// Checks that a stream of the emitter (`roots` and a leaf table of `prims` entries) can
/// be compressed: one root at most (no high-level threshold), ids below [`LEAF_END`].
pub fn check_stream(roots: usize, prims: usize) -> Result<(), CbvhError> {
    if roots > 1 {
        return Err(CbvhError::BadOrder(format!(
            "{roots} high-level roots: build without a high-level threshold"
        )));
    }
    if prims >= LEAF_END as usize {
        return Err(CbvhError::TooLarge {
            what: "primitive",
            count: prims,
        });
    }
    Ok(())
}

/// Compresses the streaming emitter's output (`bvh::HlbvhBuilder::build_highlevel`
/// without a threshold: one root) bottom-up, in emission order.
pub fn compress_hlbvh(
    hl: &Highlevel,
    cfg: &StreamConfig,
) -> Result<(Cbvh, EncodeStats), CbvhError> {
    check_stream(hl.roots.len(), hl.order.len())?;
    let mut ids = hl.order.clone();
    let mut enc = StreamEncoder::new(*cfg)?;
    if let Some(n) = input_of_root(hl.roots.first(), &mut ids)? {
        enc.push(n)?;
    }
    if !hl.roots.is_empty() {
        for n in &hl.nodes {
            enc.push(input_of_emitted(n, &mut ids)?)?;
        }
    }
    enc.finish(ids)
}

/// Streams a finished [`Bvh2`] through the bottom-up encoder in depth-first postorder
/// (child 0's subtree, child 1's subtree, the node), as an emitter would have output it.
pub fn compress_bottomup(bvh: &Bvh2, cfg: &StreamConfig) -> Result<(Cbvh, EncodeStats), CbvhError> {
    let prim_ids = prim_ids_of(bvh)?;
    let mut enc = StreamEncoder::new(*cfg)?;
    let mut stack = vec![(0u32, false)];
    let mut steps = 0usize;
    while let Some((i, expanded)) = stack.pop() {
        steps += 1;
        if steps > 2 * bvh.nodes.len() {
            return Err(CbvhError::Corrupt("cycle in the BVH".into()));
        }
        let n = bvh
            .nodes
            .get(i as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("node {i} outside the tree")))?;
        if expanded {
            let children = n.children.map(|c| {
                if c.is_leaf() {
                    InChild::Leaf { first: c.index }
                } else if c.is_empty() {
                    InChild::Empty
                } else {
                    InChild::Node
                }
            });
            enc.push(InputNode {
                boxes: [n.child_aabb(0), n.child_aabb(1)],
                children,
                addr: None,
            })?;
        } else {
            stack.push((i, true));
            for c in (0..2).rev() {
                if n.children[c].is_inner() {
                    stack.push((n.children[c].index, false));
                }
            }
        }
    }
    enc.finish(prim_ids)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::topdown::compress_topdown;
    use crate::tree::{boxes_not_enclosing, enclosure_violations};
    use crate::Coords;
    use bvh::{HlbvhBuilder, LbvhBuilder};
    use geom::Vec3;
    use proptest::prelude::*;

    pub(crate) fn soup(n: usize, seed: u64, flat: bool) -> Vec<Aabb> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut f = move || {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            ((s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32) / (1u64 << 24) as f32
        };
        (0..n)
            .map(|_| {
                let a = Vec3::new(
                    f() * 100.0 - 50.0,
                    f() * 100.0 - 50.0,
                    if flat { -0.4 } else { f() * 100.0 },
                );
                let d = Vec3::new(f(), f(), if flat { 0.0 } else { f() }) * 2.0;
                Aabb::new(a, a + d)
            })
            .collect()
    }

    fn cfg(coords: Coords, bits: u32, m: u32) -> StreamConfig {
        StreamConfig {
            params: Params {
                bits,
                coords,
                ..Params::default()
            },
            treelet_depth: m,
            ..StreamConfig::default()
        }
    }

    /// The checks every bottom-up result must pass against the top-down one.
    fn check_against_topdown(bvh: &Bvh2, prims: &[Aabb], c: &StreamConfig) -> EncodeStats {
        let (td, _) = compress_topdown(bvh, &c.params).unwrap();
        let (bu, st) = compress_bottomup(bvh, c).unwrap();
        let dtd = td.decode_to_bvh2().unwrap();
        let dbu = bu.decode_to_bvh2().unwrap();
        assert_eq!(dbu.nodes.len(), bvh.nodes.len());
        assert_eq!(enclosure_violations(&dtd, prims).unwrap(), 0);
        assert_eq!(enclosure_violations(&dbu, prims).unwrap(), 0);
        // Same topology as the input, boxes at least as large as top-down's. Not with
        // plane sharing: which child is outermost can differ between the two encoders'
        // grids (a tie in one, strict in the other), and the child that shares in one
        // keeps its own, finer bound in the other (both enclose the original). In 400
        // small soups at 3 and 4 bits, 170 of the 187 smaller bottom-up bounds were such
        // flips; the other 17 sit under a node whose own (shared) plane came out finer.
        if !c.params.coords.shares_planes() {
            assert_eq!(boxes_not_enclosing(&dbu, &dtd).unwrap(), 0);
        }
        assert_eq!(st.nodes_written as usize, bvh.nodes.len());
        st
    }

    #[test]
    fn hlbvh_stream_matches_bvh2_stream() {
        let prims = soup(3000, 5, false);
        let b = HlbvhBuilder {
            max_leaf_size: 64,
            ..HlbvhBuilder::default()
        };
        let hl = b.build_highlevel(&prims).unwrap();
        let bvh = hl.to_bvh2();
        for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
            for m in 1..=4 {
                let c = cfg(coords, 6, m);
                let (a, sa) = compress_hlbvh(&hl, &c).unwrap();
                let (b, sb) = compress_bottomup(&bvh, &c).unwrap();
                assert_eq!(sa, sb);
                assert_eq!(a.decode_to_bvh2().unwrap(), b.decode_to_bvh2().unwrap());
                check_against_topdown(&bvh, &prims, &c);
            }
        }
    }

    #[test]
    fn modulo_and_treelets_reduce_backtracking() {
        let prims = soup(20000, 9, false);
        let bvh = LbvhBuilder::default().build(&prims).unwrap();
        let steps =
            |coords, m| check_against_topdown(&bvh, &prims, &cfg(coords, 6, m)).backtrack_steps;
        let rel: Vec<u64> = (1..=4).map(|m| steps(Coords::Relative, m)).collect();
        let modu: Vec<u64> = (1..=4).map(|m| steps(Coords::Modulo, m)).collect();
        assert!(rel[0] > 0);
        assert!(modu[0] < rel[0], "{modu:?} {rel:?}");
        for w in rel.windows(2).chain(modu.windows(2)) {
            assert!(w[1] <= w[0], "{rel:?} {modu:?}");
        }
        assert!(rel[3] < rel[0] / 4, "{rel:?}");
    }

    #[test]
    fn recorded_ops_match_the_counts() {
        // The emitter's stream fed by hand, one node at a time, as a cycle model would.
        let prims = soup(2000, 3, false);
        let mut c = cfg(Coords::Relative, 6, 1);
        c.record_ops = true;
        c.base_addr_bytes = 4096;
        let hl = HlbvhBuilder {
            combine_identical: false,
            ..HlbvhBuilder::default()
        }
        .build_highlevel(&prims)
        .unwrap();
        let mut enc = StreamEncoder::new(c).unwrap();
        let mut writes = 0u64;
        let mut reads = 0u64;
        let mut bt_writes = 0u64;
        for n in &hl.nodes {
            let children = n.children.map(|r| match r {
                EmitRef::Leaf { first, .. } => InChild::Leaf { first },
                EmitRef::Node(_) => InChild::Node,
            });
            enc.push(InputNode {
                boxes: n.aabbs,
                children,
                addr: None,
            })
            .unwrap();
            for op in enc.drain_ops() {
                match op {
                    MemOp::WritePair {
                        addr_bytes,
                        bytes,
                        pair,
                    } => {
                        assert_eq!(bytes, 16);
                        assert_eq!(addr_bytes, 4096 + 16 * pair as u64);
                        writes += 1;
                    }
                    MemOp::BacktrackRead {
                        addr_bytes, bytes, ..
                    } => {
                        assert_eq!((addr_bytes % 64, bytes), (0, 64));
                        reads += 1;
                    }
                    MemOp::BacktrackWrite { .. } => bt_writes += 1,
                }
            }
        }
        enc.end_stream().unwrap();
        for op in enc.drain_ops() {
            match op {
                MemOp::WritePair { .. } => writes += 1,
                MemOp::BacktrackRead { .. } => reads += 1,
                MemOp::BacktrackWrite { .. } => bt_writes += 1,
            }
        }
        let steps = enc.stats().backtrack_steps;
        assert_eq!(writes, hl.nodes.len() as u64);
        assert_eq!((reads, bt_writes), (steps, steps));
        assert!(steps > 0);
    }

    #[test]
    fn degenerate_and_tiny_trees() {
        for prims in [
            vec![],
            vec![Aabb::new(Vec3::ONE, Vec3::ONE)],
            soup(2, 1, true),
            soup(50, 2, true),
        ] {
            let bvh = LbvhBuilder::default().build(&prims).unwrap();
            for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
                for m in [1, 3] {
                    check_against_topdown(&bvh, &prims, &cfg(coords, 6, m));
                }
            }
        }
    }

    #[test]
    fn bad_order_is_an_error() {
        let mut enc = StreamEncoder::new(StreamConfig::default()).unwrap();
        let r = enc.push(InputNode {
            boxes: [Aabb::new(Vec3::ZERO, Vec3::ONE); 2],
            children: [InChild::Node, InChild::Leaf { first: 0 }],
            addr: None,
        });
        assert!(matches!(r, Err(CbvhError::BadOrder(_))));
        let mut enc = StreamEncoder::new(StreamConfig::default()).unwrap();
        let leaf = InputNode {
            boxes: [Aabb::new(Vec3::ZERO, Vec3::ONE); 2],
            children: [InChild::Leaf { first: 0 }, InChild::Leaf { first: 1 }],
            addr: None,
        };
        enc.push(leaf).unwrap();
        enc.push(leaf).unwrap();
        assert!(matches!(enc.finish(vec![]), Err(CbvhError::BadOrder(_))));
        let mut bad = leaf;
        bad.boxes[0].min.x = f32::NAN;
        let mut enc = StreamEncoder::new(StreamConfig::default()).unwrap();
        assert!(matches!(enc.push(bad), Err(CbvhError::BadBox { .. })));
    }

    fn any_coords() -> impl Strategy<Value = Coords> {
        prop_oneof![
            Just(Coords::Relative),
            Just(Coords::Modulo),
            Just(Coords::PlaneSharing)
        ]
    }

    fn any_prims() -> impl Strategy<Value = Vec<Aabb>> {
        proptest::collection::vec(crate::codec::tests::any_box(), 1..120)
    }

    /// Boxes on a coarse dyadic grid with many degenerate axes: architectural geometry,
    /// where bounds fall exactly on grid lines (the hard case for modulo coordinates).
    fn grid_prims() -> impl Strategy<Value = Vec<Aabb>> {
        let b = (
            proptest::array::uniform3(-64i32..64),
            proptest::array::uniform3(0i32..3),
            0i32..12,
        )
            .prop_map(|(a, w, sh)| {
                let k = (1u64 << sh) as f32;
                let lo = Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32) / k;
                let hi = lo + Vec3::new(w[0] as f32, w[1] as f32, w[2] as f32) / k;
                Aabb::new(lo, hi)
            });
        proptest::collection::vec(b, 1..400)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn every_encoder_encloses_grid_geometry(prims in grid_prims(), bits in 3u32..=8, m in 1u32..=3, coords in any_coords()) {
            let bvh = LbvhBuilder::default().build(&prims).unwrap();
            check_against_topdown(&bvh, &prims, &cfg(coords, bits, m));
            let hl = crate::study::paper_lbvh().build_highlevel(&prims).unwrap();
            let (t, _) = compress_hlbvh(&hl, &cfg(coords, bits, m)).unwrap();
            prop_assert_eq!(enclosure_violations(&t.decode_to_bvh2().unwrap(), &prims).unwrap(), 0);
        }

        /// Every encoder, on random boxes of every magnitude, gives trees whose decoded
        /// boxes enclose the originals, and the bottom-up ones enclose top-down's.
        #[test]
        fn every_encoder_encloses(prims in any_prims(), bits in 3u32..=8, m in 1u32..=4, coords in any_coords(), min_e in prop_oneof![Just(-30i32), Just(-126), Just(-8)]) {
            let mut c = cfg(coords, bits, m);
            c.params.min_scale_exp = min_e;
            let bvh = LbvhBuilder::default().build(&prims).unwrap();
            check_against_topdown(&bvh, &prims, &c);
            let bvh = bvh::BinnedSahBuilder { max_leaf_size: 3, ..Default::default() }.build(&prims).unwrap();
            check_against_topdown(&bvh, &prims, &c);
        }
    }
}
