//! The streaming MBVH4 collapse as a kernel unit (see [`super::super::mbvh4_unit`] for the
//! model). The collapse pass baseline is the `Topdown` unit of `cbvh_out`.

use super::*;

pub(super) struct Collapse {
    pub(super) sc: Option<bvh::StreamCollapse>,
    /// The first wide node closed and not yet handed on (to the write buffer, or to the
    /// wide encoder).
    pub(super) out_next: usize,
    /// `cbvh4`: the wide nodes go to the wide encoder instead of the write buffer.
    pub(super) encode: bool,
    /// Cycles of the windowed rule's cost update still to spend on the last node.
    pub(super) think: u64,
    /// Extra cycles per node of the windowed rule (its levels; 0 for the greedy rule).
    pub(super) levels: u64,
    pub(super) ended: bool,
    pub(super) done: bool,
    pub(super) stats: CollapseUnitStats,
}

pub(super) const CO_STARVED: u8 = 0;
pub(super) const CO_WRITE_FULL: u8 = 1;
pub(super) const CO_ENCODER_FULL: u8 = 2;

impl Collapse {
    fn step_inner(&mut self, w: &mut KWorld, cx: &mut Ctx) -> Result<Wake, bvh::CollapseError> {
        let now = cx.now();
        if self.done {
            return Ok(Wake::Done);
        }
        if self.think > 0 {
            self.think -= 1;
            cx.set_state(State::Busy);
            return Ok(Wake::Next);
        }
        let sc = self.sc.as_ref().expect("collapse until done");
        if let Some(n) = sc.written().get(self.out_next) {
            if self.encode {
                // `cbvh4`: the wide node goes to the encoder behind the unit.
                if w.wide_fifo.is_full(cx) {
                    cx.set_state(State::Stalled(CO_ENCODER_FULL));
                    return Ok(Wake::OnEvent);
                }
                if w.wide_fifo.push(cx, cbvh::wide::input_of_node4(n)).is_err() {
                    unreachable!("checked");
                }
            } else {
                if !w.nodes.has_room(now, MBVH4_NODE_BYTES) {
                    cx.set_state(State::Stalled(CO_WRITE_FULL));
                    return Ok(Wake::OnEvent);
                }
                w.nodes.add(cx, MBVH4_NODE_BYTES);
            }
            self.out_next += 1;
            self.stats.nodes_written += 1;
            cx.set_state(State::Busy);
            return Ok(Wake::Next);
        }
        let sc = self.sc.as_mut().expect("collapse until done");
        if let Some(n) = w.col_fifo.pop(cx) {
            sc.push(&n)?;
            self.think = self.levels;
            self.stats.nodes_in += 1;
            cx.set_state(State::Busy);
            Ok(Wake::Next)
        } else if w.emit_finished.get(now) && !self.ended {
            // The root's slots are written last, as the root node.
            sc.end(&w.out.roots)?;
            self.think = self.levels;
            self.ended = true;
            cx.set_state(State::Busy);
            Ok(Wake::Next)
        } else if self.ended {
            self.done = true;
            self.stats.max_open = sc.max_open() as u64;
            self.stats.max_treelet_nodes = sc.max_treelet_nodes() as u64;
            self.stats.max_window_bytes = sc.max_window_bytes() as u64;
            w.out.collapse = Some((self.sc.take().expect("once"), self.stats.clone()));
            if self.encode {
                // The wide encoder ends the stream (and signals the control).
                w.collapse_finished.set(now, true);
                cx.notify(w.ids.wide_enc, now + 1);
            } else {
                w.stream_done.push(cx, ()).expect("one done token");
            }
            cx.set_state(State::Idle);
            Ok(Wake::Done)
        } else {
            cx.set_state(State::Stalled(CO_STARVED));
            Ok(Wake::OnEvent)
        }
    }
}

impl<'a> Unit<KWorld<'a>> for Collapse {
    fn name(&self) -> &str {
        "mbvh4 collapse"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["input empty", "write buffer full", "encoder full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        match self.step_inner(w, cx) {
            Ok(wake) => wake,
            Err(e) => {
                w.out.collapse_fault = Some(e);
                self.done = true;
                if self.encode {
                    w.collapse_finished.set(cx.now(), true);
                    cx.notify(w.ids.wide_enc, cx.now() + 1);
                } else {
                    w.stream_done.push(cx, ()).expect("one done token");
                }
                Wake::Done
            }
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{} nodes in, {} written, next out {}, ended {}, done {}",
            self.stats.nodes_in, self.stats.nodes_written, self.out_next, self.ended, self.done
        )
    }
}
