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

use bvh::{EmittedNode, Emitter, HighlevelRoot, Prim, Step};
use cbvh::bottomup::{input_of_emitted, input_of_root, InputNode};

use super::config::{HIGHLEVEL_BYTES, LEAF_ENTRY_BYTES, NODE_BYTES};
use super::machine::WriteBuffer;
use super::Elem;
use crate::fifo::Fifo;

/// Why the emitter did not step in a cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EmitterStalls {
    /// Cycles it needed an input and its FIFO was empty.
    pub starved_cycles: u64,
    /// Cycles a write buffer (nodes, leaf table, high-level) was full.
    pub write_full_cycles: u64,
    /// Cycles the streaming CBVH encoder's input FIFO was full.
    pub encoder_full_cycles: u64,
}

/// Where the emitter's inner nodes go.
pub(super) enum NodeSink<'a> {
    /// 64-byte single-precision nodes into the node write buffer.
    Bvh(&'a mut WriteBuffer),
    /// Encoder inputs into the streaming CBVH encoder's FIFO.
    Cbvh(&'a mut Fifo<InputNode>),
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
    /// Stall counters.
    pub stalls: EmitterStalls,
    /// With the CBVH encoder attached: the primitive-id array (the leaf table with each
    /// leaf's last entry flagged).
    pub cbvh_ids: Option<Vec<u32>>,
    /// An error of the encoder-input conversion (cannot happen with a correct emitter).
    pub fault: Option<cbvh::CbvhError>,
}

impl EmitUnit {
    /// An emitter for `total` primitives.
    pub fn new(
        total: u64,
        threshold: Option<u32>,
        combine: bool,
        max_leaf: u32,
        cbvh: bool,
    ) -> Self {
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
            stalls: EmitterStalls::default(),
            cbvh_ids: cbvh.then(|| Vec::with_capacity(total as usize)),
            fault: None,
        }
    }

    /// Deepest stack seen.
    pub fn max_stack_depth(&self) -> usize {
        self.em.max_stack_depth()
    }

    /// One cycle. Returns true when a step was performed.
    pub fn tick(
        &mut self,
        input: &mut Fifo<Elem>,
        mut nodes_out: NodeSink<'_>,
        leaves_out: &mut WriteBuffer,
        highlevel_out: &mut WriteBuffer,
    ) -> bool {
        // Padding sorts after every real element: once the scene is read, drop it.
        if self.consumed == self.total {
            while input.front().is_some_and(|e| e.is_pad()) {
                input.pop();
            }
        }
        if self.done {
            return false;
        }
        // Room for whatever this step may write.
        let node_room = match &nodes_out {
            NodeSink::Bvh(wb) => wb.has_room(NODE_BYTES),
            NodeSink::Cbvh(f) => {
                if f.is_full() {
                    self.stalls.encoder_full_cycles += 1;
                    return false;
                }
                true
            }
        };
        if !node_room
            || !leaves_out.has_room(LEAF_ENTRY_BYTES)
            || !highlevel_out.has_room(HIGHLEVEL_BYTES)
        {
            self.stalls.write_full_cycles += 1;
            return false;
        }
        let mut prim = None;
        if self.em.needs_input() && self.consumed < self.total {
            let Some(e) = input.pop() else {
                self.stalls.starved_cycles += 1;
                return false;
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
            self.consumed += 1;
            leaves_out.add(LEAF_ENTRY_BYTES);
            prim = Some(Prim {
                code,
                tie,
                aabb: e.aabb,
            });
        }
        self.steps += 1;
        match self.em.step(prim) {
            Step::Emitted(n) => {
                self.nodes.push(n);
                match &mut nodes_out {
                    NodeSink::Bvh(wb) => wb.add(NODE_BYTES),
                    NodeSink::Cbvh(f) => {
                        let n = input_of_emitted_in(&n, &mut self.cbvh_ids);
                        self.send_to_encoder(f, n)
                    }
                }
            }
            Step::Highlevel(r) => {
                self.roots.push(r);
                highlevel_out.add(HIGHLEVEL_BYTES);
                if let NodeSink::Cbvh(f) = &mut nodes_out {
                    // A tree that is one leaf: the encoder gets that leaf as a node.
                    let ids = self.cbvh_ids.as_mut().expect("ids with the encoder");
                    match input_of_root(Some(&r), ids) {
                        Ok(Some(n)) => self.send_to_encoder(f, Ok(n)),
                        Ok(None) => {}
                        Err(e) => self.fault = Some(e),
                    }
                }
            }
            Step::Done => self.done = true,
            Step::Loaded | Step::Combined | Step::Pushed => {}
        }
        true
    }

    /// Hands one encoder input to the encoder's FIFO (room was checked before the step).
    fn send_to_encoder(&mut self, f: &mut Fifo<InputNode>, n: Result<InputNode, cbvh::CbvhError>) {
        match n {
            Ok(n) => {
                if f.push(n).is_err() {
                    unreachable!("room in the encoder FIFO was checked before the step");
                }
            }
            Err(e) => self.fault = Some(e),
        }
    }
}

/// [`input_of_emitted`] over the emitter's id array.
fn input_of_emitted_in(
    n: &EmittedNode,
    ids: &mut Option<Vec<u32>>,
) -> Result<InputNode, cbvh::CbvhError> {
    input_of_emitted(n, ids.as_mut().expect("ids with the encoder"))
}
