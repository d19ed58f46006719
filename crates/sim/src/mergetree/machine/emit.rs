//! The hierarchy emitter and the toplevel SAH unit as kernel units.

use super::*;

pub(super) struct Emitter {
    pub(super) e: EmitUnit,
}

pub(super) const EMIT_STARVED: u8 = 0;
pub(super) const EMIT_WRITE_FULL: u8 = 1;
pub(super) const EMIT_ENCODER_FULL: u8 = 2;

/// The emitter's channels in the kernel world.
pub(super) struct KPorts<'c, 'w> {
    pub(super) cx: &'c mut Ctx,
    pub(super) input: &'w mut LatencyFifo<Elem>,
    pub(super) enc: Option<&'w mut LatencyFifo<cbvh::bottomup::InputNode>>,
    pub(super) col: Option<&'w mut LatencyFifo<bvh::EmittedNode>>,
    pub(super) nodes: &'w mut KBuf,
    pub(super) leaves: &'w mut KBuf,
    pub(super) hl: &'w mut KBuf,
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
    fn collapse_attached(&self) -> bool {
        self.col.is_some()
    }
    #[inline]
    fn node_room(&self) -> bool {
        match (&self.enc, &self.col) {
            (Some(f), _) => !f.is_full(self.cx),
            (None, Some(f)) => !f.is_full(self.cx),
            (None, None) => self.nodes.has_room(self.cx.now(), NODE_BYTES),
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
    fn node_free(&self) -> u64 {
        self.nodes.free(self.cx.now())
    }
    fn add_node_bytes(&mut self, bytes: u64) {
        self.nodes.add(self.cx, bytes);
    }
    fn push_encoder(&mut self, n: cbvh::bottomup::InputNode) {
        let f = self.enc.as_mut().expect("an encoder attached");
        if f.push(self.cx, n).is_err() {
            unreachable!("room in the encoder FIFO was checked before the step");
        }
    }
    fn push_collapse(&mut self, n: bvh::EmittedNode) {
        let f = self.col.as_mut().expect("a collapse unit attached");
        if f.push(self.cx, n).is_err() {
            unreachable!("room in the collapse FIFO was checked before the step");
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
        let collapsing = w.cfg.output.collapses_stream();
        let KWorld {
            emit_fifo,
            enc_fifo,
            col_fifo,
            nodes,
            leaves,
            hl,
            ..
        } = w;
        let mut io = KPorts {
            cx: &mut *cx,
            input: emit_fifo,
            enc: streaming.then_some(enc_fifo),
            col: collapsing.then_some(col_fifo),
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
                if self.e.finished() {
                    w.out.nodes = std::mem::take(&mut self.e.nodes);
                    w.out.roots = std::mem::take(&mut self.e.roots);
                    w.out.order = std::mem::take(&mut self.e.order);
                    w.out.max_stack_depth = self.e.max_stack_depth();
                    w.out.cbvh_ids = self.e.cbvh_ids.take();
                    w.out.points = match self.e.point_fault.take() {
                        Some(e) => Some(Err(e)),
                        None => self.e.points.take().map(Ok),
                    };
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

pub(super) struct Toplevel {
    pub(super) t: Option<TopUnit>,
    pub(super) busy: u64,
    pub(super) busy_until: Cycle,
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
