//! Compressed 4-wide BVHs (issue 18 part 2): the \[P3\] node-pair compression carried over
//! to the 4-wide nodes of \[P4\] (`bvh::Mbvh4`), and its streaming encoder behind the
//! streaming collapse ([`bvh::StreamCollapse`]).
//!
//! # Format
//! A [`QuadNode`] holds the four children of one 4-wide node, each quantized on the grid
//! of the node's own decoded box, exactly as a node pair holds the two children of a
//! binary node (\[P3\] §3): per child slot six `N`-bit coordinates, a leaf bit and a 27-bit
//! pointer ([`crate::format::Slot`]), `W = 6N + 28` bits, slot `c` at bits `c W ..
//! (c + 1) W`. At `N = 6` a node is 32 bytes (four little-endian `u64`s), a quarter of the
//! 128-byte `bvh::Node4`. The slots are encoded and decoded by the code of the node pairs
//! ([`crate::codec::encode_slots`], [`crate::codec::decode_slot_boxes`]: the same grids,
//! relative, modulo or plane-sharing coordinates, outward rounding). The node's context
//! (its scale and decoded box) comes from its parent's slot, the root's is stored with the
//! tree. Pointers: an inner child indexes the node array, a leaf the primitive-id array
//! (last id of each leaf flagged [`LEAF_END`]); an empty slot is [`Slot::EMPTY`] and comes
//! after the used ones. Layout in `docs/cbvh-format.md`.
//!
//! Ylitie et al. 2017's compressed wide BVH stores each node's own origin and scale (12
//! bytes of `f32` origin and three exponents) and quantizes its children in that grid;
//! here, as in \[P3\], the grid is derived from the node's decoded box, which its parent's
//! slot gives, so a node stores nothing but its children, and a node's encoding depends
//! on its ancestors: the streaming problem \[P3\] Algorithm 1 solves.
//!
//! # Encoders
//! - [`compress4_topdown`]: the offline reference, root first, every node in the context
//!   its parent's encoding gives it.
//! - [`WideStreamEncoder`]: \[P3\] Algorithm 1 with 4-wide nodes (the engine of
//!   [`crate::bottomup`], treelets included): each node arrives after its children,
//!   is encoded in the context estimated from its own box, and a written child whose real
//!   context (from this encoding) invalidates the estimate is backtracked. Children are
//!   named by the index of the node in the input stream, since the streaming collapse
//!   does not write its wide nodes in stack order (a wide node closed from an open subtree
//!   below the top references nodes written before the top's).
//! - [`compress_stream_collapse`]: the streaming collapse of an emitter's stream with the
//!   encoder behind it, fed each wide node as the collapse writes it.
//! - [`compress4_bottomup`]: a finished `bvh::Mbvh4` streamed through the encoder in
//!   postorder (for comparisons with the top-down encoder on any wide tree).
//!
//! The streaming encoders decode to boxes that enclose the top-down encoder's (the
//! backtracking re-encodes decoded boxes with rounding that reproduces the top-down
//! quantization, see [`crate::coords::quantize`]), and in practice to the same boxes;
//! the tests check the enclosure on every input and the equality on the scenes.
//!
//! # Buffer
//! The encoder holds the subtrees whose parent has not arrived (each a written node's
//! address, context and box, or with treelets the unwritten top levels). Behind the
//! greedy streaming collapse these are the wide nodes referenced from the slots of the
//! collapse's open subtrees, so at most four per open subtree: `4 (D + 1)` for an emitter
//! stack of depth `D` ([`EncodeStats::max_stack`] reports the peak; tested).

use crate::bottomup::{Engine, MemOp, PRef, Pending, StreamConfig};
use crate::codec::{check_box, decode_slot_boxes, encode_slots, slot_ptr, ChildPtr, Ctx};
use crate::error::CbvhError;
use crate::format::{node_bytes, pack_slots, unpack_slots, Slot, LEAF_END, MAX_PTR};
use crate::grid::Params;
use crate::topdown::walk_topdown;
use crate::tree::leaf_range_in;
use crate::EncodeStats;
use bvh::{ChildRef, Highlevel, Mbvh4, Node4, StreamCollapse};
use geom::Aabb;

/// Children per node.
pub const WIDTH: usize = 4;

/// Bytes of a packed [`QuadNode`] at `bits` per coordinate: 32 at 6 bits (23, 26, 29, 32,
/// 35, 38 for 3..=8).
#[inline]
pub const fn quad_bytes(bits: u32) -> usize {
    node_bytes(WIDTH as u32, bits)
}

/// A compressed 4-wide node: four child slots quantized in the node's grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct QuadNode {
    /// Children 0..4; empty slots ([`Slot::EMPTY`]) after the used ones.
    pub slots: [Slot; WIDTH],
}

impl QuadNode {
    /// Packs the node into `quad_bytes(bits)` bytes appended to `out`.
    pub fn pack_into(&self, bits: u32, out: &mut Vec<u8>) -> Result<(), CbvhError> {
        pack_slots(&self.slots, bits, out)
    }

    /// Unpacks a node from the first `quad_bytes(bits)` bytes of `src`.
    #[inline]
    pub fn unpack(bits: u32, src: &[u8]) -> Result<Self, CbvhError> {
        Ok(Self {
            slots: unpack_slots::<WIDTH>(bits, src)?,
        })
    }

    /// The decoded boxes of the children in the node's context `ctx` (`None` for an empty
    /// slot): what a traversal tests per node visit.
    #[inline]
    pub fn decode_boxes(&self, ctx: &Ctx, p: &Params) -> [Option<Aabb>; WIDTH] {
        decode_slot_boxes(&self.slots, ctx, p)
    }
}

/// Where a decoded node's parent links to it: (parent node, child slot).
type Link = (usize, usize);

/// A compressed 4-wide BVH.
#[derive(Clone, Debug, PartialEq)]
pub struct Cbvh4 {
    /// Quantization parameters.
    pub params: Params,
    /// Nodes; inner pointers index this array.
    pub nodes: Vec<QuadNode>,
    /// Index of the root node.
    pub root: u32,
    /// Context of the root (stored at full precision beside the tree).
    pub root_ctx: Ctx,
    /// Primitive-id array: primitive indices, the last of each leaf flagged [`LEAF_END`].
    pub prim_ids: Vec<u32>,
}

impl Cbvh4 {
    /// Bytes of the packed nodes (32 per node at 6 bits).
    pub fn node_bytes(&self) -> u64 {
        (self.nodes.len() * quad_bytes(self.params.bits)) as u64
    }

    /// The nodes packed in the bit layout of the module doc.
    pub fn to_bytes(&self) -> Result<Vec<u8>, CbvhError> {
        let mut out = Vec::with_capacity(self.nodes.len() * quad_bytes(self.params.bits));
        for n in &self.nodes {
            n.pack_into(self.params.bits, &mut out)?;
        }
        Ok(out)
    }

    /// The leaf starting at primitive-id index `first`: `(first, count)`.
    pub fn leaf_range(&self, first: u32) -> Result<(u32, u32), CbvhError> {
        leaf_range_in(&self.prim_ids, first)
    }

    /// The tree with decoded boxes as a `bvh::Mbvh4` of the same topology (nodes in
    /// depth-first preorder, slot 0 first; leaves referencing the same primitive ids), to
    /// trace with the 4-wide kernel and to compare encoders node for node. Its child boxes
    /// are exactly the boxes a traversal of the compressed nodes decodes.
    pub fn decode_to_mbvh4(&self) -> Result<Mbvh4, CbvhError> {
        self.root_ctx.check()?;
        let prim_indices: Vec<u32> = self.prim_ids.iter().map(|&i| i & !LEAF_END).collect();
        let mut nodes: Vec<Node4> = Vec::with_capacity(self.nodes.len());
        // (node, its context, where its parent links to it)
        let mut stack: Vec<(u32, Ctx, Option<Link>)> = vec![(self.root, self.root_ctx, None)];
        let mut leaf_entries = 0usize;
        while let Some((idx, ctx, parent)) = stack.pop() {
            if nodes.len() >= self.nodes.len() {
                return Err(CbvhError::Corrupt("pointer cycle".into()));
            }
            let q = self
                .nodes
                .get(idx as usize)
                .ok_or_else(|| CbvhError::Corrupt(format!("pointer {idx} outside the tree")))?;
            let at = nodes.len();
            if let Some((p, c)) = parent {
                nodes[p].children[c] = ChildRef::inner(at as u32);
            }
            let mut node = Node4::EMPTY;
            let mut inner = Vec::new();
            for (c, b) in q.decode_boxes(&ctx, &self.params).into_iter().enumerate() {
                let Some(b) = b else { continue };
                node.set_child_aabb(c, &b);
                node.children[c] = match slot_ptr(&q.slots[c]) {
                    ChildPtr::Leaf(first) => {
                        let (f, n) = self.leaf_range(first)?;
                        leaf_entries += n as usize;
                        if leaf_entries > self.prim_ids.len() {
                            return Err(CbvhError::Corrupt(
                                "leaves cover more than the primitive ids (they overlap)".into(),
                            ));
                        }
                        ChildRef::leaf(f, n)
                    }
                    ChildPtr::Inner(k) => {
                        inner.push((k, Ctx::from_decoded(&b, &self.params), Some((at, c))));
                        ChildRef::EMPTY // linked when the child is numbered
                    }
                    ChildPtr::Empty => ChildRef::EMPTY,
                };
            }
            nodes.push(node);
            stack.extend(inner.into_iter().rev());
        }
        let bounds = nodes[0].aabb();
        Ok(Mbvh4 {
            nodes,
            prim_indices,
            bounds,
        })
    }
}

/// The primitive-id array of a 4-wide tree: its leaf table `order` with the last entry of
/// every leaf of `nodes` flagged [`LEAF_END`].
pub fn prim_ids_of_nodes(mut order: Vec<u32>, nodes: &[Node4]) -> Result<Vec<u32>, CbvhError> {
    if order.len() >= LEAF_END as usize {
        return Err(CbvhError::TooLarge {
            what: "primitive",
            count: order.len(),
        });
    }
    for n in nodes {
        for c in n.children.iter().filter(|c| c.is_leaf()) {
            let last = (c.index as usize + c.count as usize).wrapping_sub(1);
            let id = order
                .get_mut(last)
                .filter(|_| c.count > 0)
                .ok_or_else(|| CbvhError::Corrupt("leaf outside the leaf table".into()))?;
            *id |= LEAF_END;
        }
    }
    Ok(order)
}

/// Compresses the 4-wide tree `m` top-down: the root in the context estimated from its box
/// (as the streaming encoder estimates its root's), every other node in the context its
/// parent's encoding gives it. Node `i` of the result encodes node `i` of `m`. Statistics:
/// one write per node, no backtracking.
pub fn compress4_topdown(m: &Mbvh4, params: &Params) -> Result<(Cbvh4, EncodeStats), CbvhError> {
    params.check()?;
    if m.nodes.len() > MAX_PTR as usize {
        return Err(CbvhError::TooLarge {
            what: "wide node",
            count: m.nodes.len(),
        });
    }
    let prim_ids = prim_ids_of_nodes(m.prim_indices.clone(), &m.nodes)?;
    let root = m
        .nodes
        .first()
        .ok_or_else(|| CbvhError::Corrupt("a 4-wide tree without a root".into()))?;
    let root_box = root.aabb();
    check_box(&root_box, 0)?;
    let root_ctx = Ctx::estimate(&root_box, params);
    let mut nodes = vec![QuadNode::default(); m.nodes.len()];
    let visited = walk_topdown(
        m.nodes.len(),
        "the 4-wide tree",
        root_ctx,
        |i| {
            m.nodes
                .get(i)
                .map(|n| (std::array::from_fn(|c| n.child_aabb(c)), n.children))
        },
        |i, boxes, ptrs, ctx| {
            let (slots, kids) = encode_slots(boxes, ptrs, ctx, params, false);
            nodes[i] = QuadNode { slots };
            kids
        },
    )?;
    let stats = EncodeStats {
        nodes_written: visited as u64,
        ..EncodeStats::default()
    };
    Ok((
        Cbvh4 {
            params: *params,
            nodes,
            root: 0,
            root_ctx,
            prim_ids,
        },
        stats,
    ))
}

/// A child of a wide input node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WideChild {
    /// A leaf whose primitive ids start at index `first` of the primitive-id array.
    Leaf {
        /// First primitive-id index.
        first: u32,
    },
    /// The wide node pushed as the `k`-th node of the stream (0-based), not yet taken by
    /// another node.
    Node(u32),
    /// No child.
    Empty,
}

/// One wide node of the encoder's input: its children's original boxes and references.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WideInput {
    /// Original (full-precision) boxes of the four children (empty slots: the empty box).
    pub boxes: [Aabb; WIDTH],
    /// The four children.
    pub children: [WideChild; WIDTH],
}

/// The encoder input for a wide node the streaming collapse wrote
/// ([`StreamCollapse::written`]): its inner references are write indices, which are the
/// stream indices when the encoder takes the nodes in write order.
pub fn input_of_node4(n: &Node4) -> WideInput {
    WideInput {
        boxes: std::array::from_fn(|c| n.child_aabb(c)),
        children: n.children.map(|c| {
            if c.is_leaf() {
                WideChild::Leaf { first: c.index }
            } else if c.is_inner() {
                WideChild::Node(c.index)
            } else {
                WideChild::Empty
            }
        }),
    }
}

/// A held subtree: its stream index, the subtree, its original box.
type Held = (u32, PRef<WIDTH>, Aabb);

/// \[P3\] Algorithm 1 over 4-wide nodes (see the module doc): the streaming encoder of
/// [`crate::bottomup`] with wide nodes whose children are named by stream index.
#[derive(Debug)]
pub struct WideStreamEncoder {
    eng: Engine<WIDTH>,
    held: Vec<Held>,
    pushed: u32,
    root: Option<(u32, Ctx)>,
}

impl WideStreamEncoder {
    /// An encoder before its first node.
    pub fn new(cfg: StreamConfig) -> Result<Self, CbvhError> {
        Ok(Self {
            eng: Engine::new(cfg)?,
            held: Vec::new(),
            pushed: 0,
            root: None,
        })
    }

    /// Counts so far (`max_stack`: the peak of held subtrees).
    pub fn stats(&self) -> &EncodeStats {
        &self.eng.stats
    }

    /// Subtrees held now (waiting for their parent).
    pub fn held(&self) -> usize {
        self.held.len()
    }

    /// Bytes of one packed node.
    pub fn node_bytes(&self) -> u64 {
        self.eng.node_bytes()
    }

    /// The DRAM accesses recorded since the last call (empty unless `record_ops`; the
    /// `pair` fields are node indices, and a backtracking step reads and writes every
    /// 64-byte line the node touches).
    pub fn drain_ops(&mut self) -> Vec<MemOp> {
        std::mem::take(&mut self.eng.ops)
    }

    /// Consumes the next wide node (after every node it references).
    pub fn push(&mut self, n: WideInput) -> Result<(), CbvhError> {
        if self.root.is_some() {
            return Err(CbvhError::BadOrder(
                "a node after the end of the stream".into(),
            ));
        }
        let index = self.pushed;
        for (c, b) in n.boxes.iter().enumerate() {
            check_box(b, WIDTH * index as usize + c)?;
        }
        let mut children: [PRef<WIDTH>; WIDTH] = std::array::from_fn(|_| PRef::Empty);
        for (child, input) in children.iter_mut().zip(n.children) {
            *child = match input {
                WideChild::Leaf { first } => PRef::leaf(first)?,
                WideChild::Empty => PRef::Empty,
                WideChild::Node(k) => {
                    let at = self.held.iter().rposition(|h| h.0 == k).ok_or_else(|| {
                        CbvhError::BadOrder(format!(
                            "node {index} references node {k}, which is not a subtree waiting \
                             for its parent"
                        ))
                    })?;
                    self.held.remove(at).1
                }
            };
        }
        self.pushed += 1;
        let bx = n.boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        let mut r = PRef::Pending(Box::new(Pending {
            boxes: n.boxes,
            children,
            addr: None,
        }));
        self.eng.push(&mut r, &bx)?;
        self.held.push((index, r, bx));
        self.eng.stats.max_stack = self.eng.stats.max_stack.max(self.held.len());
        Ok(())
    }

    /// Ends the stream at its one remaining subtree, the root (a stream of no node gives
    /// a root of four empty slots): writes what is left of its treelet (the accesses are
    /// recorded; a cycle model drains them, then calls [`WideStreamEncoder::finish`]).
    /// Calling it again does nothing.
    pub fn end_stream(&mut self) -> Result<(), CbvhError> {
        if self.root.is_some() {
            return Ok(());
        }
        if self.pushed == 0 {
            self.push(WideInput {
                boxes: [Aabb::EMPTY; WIDTH],
                children: [WideChild::Empty; WIDTH],
            })?;
        }
        if self.held.len() != 1 {
            return Err(CbvhError::BadOrder(format!(
                "{} subtrees left at the end of the stream (expected one root)",
                self.held.len()
            )));
        }
        let (_, root, bx) = self.held.pop().expect("one entry");
        self.root = Some(self.eng.end(root, &bx)?);
        Ok(())
    }

    /// Ends the stream and returns the tree over the primitive-id array `prim_ids` (see
    /// [`prim_ids_of_nodes`]), with the counts.
    pub fn finish(mut self, prim_ids: Vec<u32>) -> Result<(Cbvh4, EncodeStats), CbvhError> {
        self.end_stream()?;
        let (root, root_ctx) = self.root.expect("end_stream sets the root");
        let nodes = self
            .eng
            .take_nodes()?
            .into_iter()
            .map(|slots| QuadNode { slots })
            .collect();
        Ok((
            Cbvh4 {
                params: self.eng.cfg.params,
                nodes,
                root,
                root_ctx,
                prim_ids,
            },
            self.eng.stats,
        ))
    }
}

fn collapse_error(e: bvh::CollapseError) -> CbvhError {
    CbvhError::BadOrder(format!("streaming collapse: {e}"))
}

/// The streaming collapse `sc` of the emitter's stream `hl` (one root: no high-level
/// threshold) with the wide encoder behind it, fed every wide node as the collapse writes
/// it: the compressed tree, the encoder's counts, and the uncompressed tree the collapse
/// made (`bvh::StreamCollapse::tree`, the same topology in preorder).
pub fn compress_stream_collapse(
    hl: &Highlevel,
    mut sc: StreamCollapse,
    cfg: &StreamConfig,
) -> Result<(Cbvh4, EncodeStats, Mbvh4), CbvhError> {
    let mut enc = WideStreamEncoder::new(*cfg)?;
    let mut fed = 0;
    let mut feed = |sc: &StreamCollapse, enc: &mut WideStreamEncoder| -> Result<(), CbvhError> {
        for n in &sc.written()[fed..] {
            enc.push(input_of_node4(n))?;
        }
        fed = sc.written().len();
        Ok(())
    };
    for n in &hl.nodes {
        sc.push(n).map_err(collapse_error)?;
        feed(&sc, &mut enc)?;
    }
    sc.end(&hl.roots).map_err(collapse_error)?;
    feed(&sc, &mut enc)?;
    let ids = prim_ids_of_nodes(hl.order.clone(), sc.written())?;
    let (tree, stats) = enc.finish(ids)?;
    let exact = sc.tree(hl.order.clone()).map_err(collapse_error)?;
    Ok((tree, stats, exact))
}

/// Streams a finished 4-wide tree through the wide encoder in depth-first postorder (slot
/// 0's subtree first, the node after its children), as a streaming builder would output
/// it.
pub fn compress4_bottomup(
    m: &Mbvh4,
    cfg: &StreamConfig,
) -> Result<(Cbvh4, EncodeStats), CbvhError> {
    let prim_ids = prim_ids_of_nodes(m.prim_indices.clone(), &m.nodes)?;
    let mut enc = WideStreamEncoder::new(*cfg)?;
    // Stream index of every node once pushed.
    let mut index = vec![u32::MAX; m.nodes.len()];
    let mut stack = vec![(0u32, false)];
    let mut steps = 0usize;
    while let Some((i, expanded)) = stack.pop() {
        steps += 1;
        if steps > 2 * m.nodes.len() {
            return Err(CbvhError::Corrupt("cycle in the 4-wide tree".into()));
        }
        let n = m
            .nodes
            .get(i as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("node {i} outside the tree")))?;
        if expanded {
            let mut input = input_of_node4(n);
            for c in input.children.iter_mut() {
                if let WideChild::Node(k) = c {
                    *k = *index
                        .get(*k as usize)
                        .ok_or_else(|| CbvhError::Corrupt(format!("node {k} outside the tree")))?;
                }
            }
            index[i as usize] = enc.pushed;
            enc.push(input)?;
        } else {
            stack.push((i, true));
            for c in n.children.iter().rev() {
                if c.is_inner() {
                    stack.push((c.index, false));
                }
            }
        }
    }
    enc.finish(prim_ids)
}

#[cfg(test)]
mod tests;
