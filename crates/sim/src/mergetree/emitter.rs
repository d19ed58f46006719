//! The hierarchy emitter of \[P2\] §5.4 (Algorithm 1) as a unit.
//!
//! It drives the very same step machine as the software HLBVH builder
//! ([`bvh::Emitter`]), one step per cycle: each step is one stack operation, one leaf
//! enlargement or one high-level output. Sorted elements arrive through a FIFO from the
//! multi-merge unit; the emitter stalls when it needs an input and the FIFO is empty, or
//! when a write buffer has no room. The sort-key tie field of the software builder (the
//! chunk index inside a run of identical codes, or the sorted position) is computed on the
//! fly from the stream, as a counter. Every primitive read writes one 4-byte leaf-table
//! entry; every emitted node one 64-byte node; every high-level root one 32-byte record.
//! Padding elements (\[P2\] §5.3) sort after the scene and end the stream.
//!
//! With the streaming CBVH encoder attached (\[P3\] §5.3), emitted nodes go into the
//! encoder's input FIFO instead of the node write buffer (the emitter stalls while it is
//! full), and the leaf-table entry that ends each leaf carries the CBVH format's leaf-end
//! flag (set when the leaf's node is emitted, before the entry is written out; the write
//! buffer models bytes, so the flag costs no traffic).
//!
//! With the streaming MBVH4 collapse attached (issue 18 part 2, [`super::mbvh4_unit`]),
//! emitted nodes go into the collapse unit's input FIFO the same way.
//!
//! With the point writer attached (`output = kdtree-points`, issue 18 part 3), the sort
//! keys' tie field is the index inside each run of equal codes (every key distinct, one
//! point per leaf), every point read is handed to the writer ([`bvh::PointStream`]) and
//! every emitted node to it: a node the writer collapses into a leaf is not written, any
//! other costs one 64-byte node in the node write buffer, as a BVH node does. The writer
//! is combinational logic beside the emitter's stack (its own stack of subtree boxes and
//! first/last codes mirrors the emitter's), so it adds no cycles.

use bvh::{EmittedNode, Emitter, HighlevelRoot, Prim, Step};
use cbvh::bottomup::{input_of_emitted, input_of_root, InputNode};

use super::Elem;

/// Why the emitter did not step in a cycle: its stall cycles by reason, from its activity
/// intervals (the machine fills it in).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EmitterStalls {
    /// Cycles it needed an input and its FIFO was empty.
    pub starved_cycles: u64,
    /// Cycles a write buffer (nodes, leaf table, high-level) was full.
    pub write_full_cycles: u64,
    /// Cycles the input FIFO of the unit behind the emitter (the streaming CBVH encoder or
    /// the streaming MBVH4 collapse) was full.
    pub encoder_full_cycles: u64,
}

/// The hierarchy emitter unit and the tree it has produced so far.
#[derive(Clone, Debug)]
pub(super) struct EmitUnit {
    em: Emitter,
    /// Real primitives in the scene (the stream ends after them).
    total: u64,
    /// Primitives read so far.
    pub consumed: u64,
    prev_code: u64,
    run: u32,
    chunk: u32,
    combine: bool,
    max_leaf: u32,
    /// Emitted nodes in emission order.
    pub nodes: Vec<EmittedNode>,
    /// High-level roots.
    pub roots: Vec<HighlevelRoot>,
    /// Leaf table: primitive index at each sorted position.
    pub order: Vec<u32>,
    /// True once the step machine reported `Done`.
    pub done: bool,
    /// Steps performed.
    pub steps: u64,
    /// With the CBVH encoder attached: the primitive-id array (the leaf table with each
    /// leaf's last entry flagged).
    pub cbvh_ids: Option<Vec<u32>>,
    /// An error of the encoder-input conversion (cannot happen with a correct emitter).
    pub fault: Option<cbvh::CbvhError>,
    /// The point writer (`output = kdtree-points` or `octree-points`).
    pub points: Option<PointWriter>,
    /// An error of the point writer (cannot happen with a correct emitter).
    pub point_fault: Option<bvh::PointError>,
    /// Bytes of a written k-d node (`output = kdtree-points`): 64 with child boxes, 16
    /// plane-only ([`super::config::KdNode`]).
    pub kd_node_bytes: u64,
    /// Octree node bytes written by the writer and not yet in the node write buffer.
    pub backlog: u64,
    /// Octree node bytes produced so far.
    oct_bytes: u64,
}

/// The writer behind the emitter in the point modes.
#[derive(Clone, Debug)]
pub enum PointWriter {
    /// The k-d tree writer (64-byte nodes).
    Kd(bvh::PointStream),
    /// The octree writer (variable-size nodes, see [`super::config::OCT_CHILD_BYTES`]).
    Oct(bvh::OctreeStream),
}

impl PointWriter {
    fn read(&mut self, code: u64, id: u32, p: geom::Vec3) {
        match self {
            PointWriter::Kd(w) => w.read(code, id, p),
            PointWriter::Oct(w) => w.read(code, id, p),
        }
    }

    fn end(&mut self) {
        match self {
            PointWriter::Kd(w) => w.end(),
            PointWriter::Oct(w) => w.end(),
        }
    }
}

/// Bytes of the octree nodes `w` has written so far.
fn oct_bytes(w: &bvh::OctreeStream) -> u64 {
    use super::config::{OCT_CHILD_BYTES, OCT_NODE_HEADER_BYTES};
    w.written() as u64 * OCT_NODE_HEADER_BYTES + w.written_children() as u64 * OCT_CHILD_BYTES
}

impl EmitUnit {
    /// An emitter for `total` primitives.
    pub fn new(
        total: u64,
        threshold: Option<u32>,
        combine: bool,
        max_leaf: u32,
        cbvh: bool,
        points: Option<PointWriter>,
    ) -> Self {
        // Points: ties are run indices (chunks of one point), so no keys are equal.
        let (combine, max_leaf) = if points.is_some() {
            (true, 1)
        } else {
            (combine, max_leaf)
        };
        Self {
            em: Emitter::new(threshold),
            total,
            consumed: 0,
            prev_code: 0,
            run: 0,
            chunk: 0,
            combine,
            max_leaf,
            nodes: Vec::with_capacity(total.saturating_sub(1) as usize),
            roots: Vec::new(),
            order: Vec::with_capacity(total as usize),
            done: false,
            steps: 0,
            cbvh_ids: cbvh.then(|| Vec::with_capacity(total as usize)),
            fault: None,
            points,
            point_fault: None,
            kd_node_bytes: super::config::NODE_BYTES,
            backlog: 0,
            oct_bytes: 0,
        }
    }

    /// Deepest stack seen.
    pub fn max_stack_depth(&self) -> usize {
        self.em.max_stack_depth()
    }

    /// One cycle with the channels behind `io`: what the emitter did.
    pub fn tick_with(&mut self, io: &mut impl EmitPorts) -> EmitStatus {
        // Padding sorts after every real element: once the scene is read, drop it.
        if self.consumed == self.total {
            io.drop_padding();
        }
        // Octree nodes queued in front of the node buffer go first.
        let had_backlog = self.backlog > 0;
        self.drain(io);
        if self.backlog > 0 {
            return EmitStatus::WriteFull;
        }
        if self.done {
            // The cycle that drained the last bytes counts as activity (the machine then
            // sees the unit done); nothing else happens.
            return if had_backlog {
                EmitStatus::Stepped
            } else {
                EmitStatus::Finished
            };
        }
        let octree = matches!(self.points, Some(PointWriter::Oct(_)));
        // Room for whatever this step may write.
        if octree {
            // Octree nodes go to the backlog, drained as the buffer has room.
        } else if io.encoder_attached() || io.collapse_attached() {
            if !io.node_room() {
                return EmitStatus::EncoderFull;
            }
        } else if !io.node_room() {
            return EmitStatus::WriteFull;
        }
        if !io.leaf_room() || !io.highlevel_room() {
            return EmitStatus::WriteFull;
        }
        let mut prim = None;
        if self.em.needs_input() && self.consumed < self.total {
            let Some(e) = io.pop() else {
                return EmitStatus::Starved;
            };
            debug_assert!(!e.is_pad(), "padding before the end of the scene");
            let code = e.code;
            // Tie counter: chunk index of `max_leaf` inside a run of identical codes.
            if self.consumed > 0 && code == self.prev_code {
                self.run += 1;
                if self.run == self.max_leaf {
                    self.run = 0;
                    self.chunk += 1;
                }
            } else {
                self.run = 0;
                self.chunk = 0;
            }
            self.prev_code = code;
            let tie = if self.combine {
                self.chunk
            } else {
                self.consumed as u32
            };
            self.order.push(e.index);
            if let Some(ids) = &mut self.cbvh_ids {
                ids.push(e.index);
            }
            if let Some(w) = &mut self.points {
                w.read(code, e.index, e.aabb.min);
            }
            self.consumed += 1;
            io.add_leaf();
            prim = Some(Prim {
                code,
                tie,
                aabb: e.aabb,
            });
        } else if self.em.needs_input() {
            // The end of the stream.
            if let Some(w) = &mut self.points {
                w.end();
            }
        }
        self.steps += 1;
        match self.em.step(prim) {
            Step::Emitted(n) => {
                self.nodes.push(n);
                if let Some(PointWriter::Kd(w)) = &mut self.points {
                    match w.join(&n) {
                        Ok(bvh::Joined::Written(_)) => io.add_node_bytes(self.kd_node_bytes),
                        Ok(bvh::Joined::Collapsed) => {}
                        Err(e) => self.point_fault = Some(e),
                    }
                } else if let Some(PointWriter::Oct(w)) = &mut self.points {
                    if let Err(e) = w.join(&n) {
                        self.point_fault = Some(e);
                    }
                    self.queue_oct(io);
                } else if io.encoder_attached() {
                    let n = input_of_emitted_in(&n, &mut self.cbvh_ids);
                    self.send_to_encoder(io, n)
                } else if io.collapse_attached() {
                    io.push_collapse(n);
                } else {
                    io.add_node();
                }
            }
            Step::Highlevel(r) => {
                self.roots.push(r);
                io.add_highlevel();
                if io.encoder_attached() {
                    // A tree that is one leaf: the encoder gets that leaf as a node.
                    let ids = self.cbvh_ids.as_mut().expect("ids with the encoder");
                    match input_of_root(Some(&r), ids) {
                        Ok(Some(n)) => self.send_to_encoder(io, Ok(n)),
                        Ok(None) => {}
                        Err(e) => self.fault = Some(e),
                    }
                }
            }
            Step::Done => {
                self.done = true;
                if let Some(PointWriter::Oct(w)) = &mut self.points {
                    // The root's node is written at the end of the stream.
                    if let Err(e) = w.close_root() {
                        self.point_fault = Some(e);
                    }
                    self.queue_oct(io);
                }
            }
            Step::Loaded | Step::Combined | Step::Pushed => {}
        }
        EmitStatus::Stepped
    }

    /// Queues the octree bytes the writer produced in this step and drains what fits.
    fn queue_oct(&mut self, io: &mut impl EmitPorts) {
        if let Some(PointWriter::Oct(w)) = &self.points {
            let b = oct_bytes(w);
            self.backlog += b - self.oct_bytes;
            self.oct_bytes = b;
        }
        self.drain(io);
    }

    /// Moves queued octree bytes into the node write buffer as far as it has room.
    fn drain(&mut self, io: &mut impl EmitPorts) {
        if self.backlog > 0 {
            let k = self.backlog.min(io.node_free());
            if k > 0 {
                io.add_node_bytes(k);
                self.backlog -= k;
            }
        }
    }

    /// True once the step machine is done and every node byte is in the write buffer.
    pub fn finished(&self) -> bool {
        self.done && self.backlog == 0
    }

    /// Hands one encoder input to the encoder's FIFO (room was checked before the step).
    fn send_to_encoder(&mut self, io: &mut impl EmitPorts, n: Result<InputNode, cbvh::CbvhError>) {
        match n {
            Ok(n) => io.push_encoder(n),
            Err(e) => self.fault = Some(e),
        }
    }
}

/// What the emitter did in a cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum EmitStatus {
    /// One step of the step machine.
    Stepped,
    /// It needed an input and the FIFO had none.
    Starved,
    /// A write buffer had no room.
    WriteFull,
    /// The input FIFO of the CBVH encoder or MBVH4 collapse unit was full.
    EncoderFull,
    /// The step machine has finished.
    Finished,
}

/// The channels around the emitter.
pub(super) trait EmitPorts {
    /// Pops the padding elements at the front of the input.
    fn drop_padding(&mut self);
    /// The next input element.
    fn pop(&mut self) -> Option<Elem>;
    /// Inner nodes go to the streaming CBVH encoder (else to the node write buffer).
    fn encoder_attached(&self) -> bool;
    /// Inner nodes go to the streaming MBVH4 collapse unit.
    fn collapse_attached(&self) -> bool;
    /// Room for one inner node (node buffer bytes, or an encoder or collapse FIFO slot).
    fn node_room(&self) -> bool;
    /// Room for one leaf-table entry.
    fn leaf_room(&self) -> bool;
    /// Room for one high-level record.
    fn highlevel_room(&self) -> bool;
    /// Adds a node's bytes to the node write buffer.
    fn add_node(&mut self);
    /// Free bytes in the node write buffer.
    fn node_free(&self) -> u64;
    /// Adds `bytes` (octree node bytes) to the node write buffer (at most its free bytes).
    fn add_node_bytes(&mut self, bytes: u64);
    /// Pushes an encoder input (room was checked).
    fn push_encoder(&mut self, n: InputNode);
    /// Pushes an emitted node to the collapse unit (room was checked).
    fn push_collapse(&mut self, n: EmittedNode);
    /// Adds a leaf-table entry's bytes.
    fn add_leaf(&mut self);
    /// Adds a high-level record's bytes.
    fn add_highlevel(&mut self);
}

/// [`input_of_emitted`] over the emitter's id array.
fn input_of_emitted_in(
    n: &EmittedNode,
    ids: &mut Option<Vec<u32>>,
) -> Result<InputNode, cbvh::CbvhError> {
    input_of_emitted(n, ids.as_mut().expect("ids with the encoder"))
}
