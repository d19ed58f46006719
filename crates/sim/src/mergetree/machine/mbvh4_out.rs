//! The streaming MBVH4 collapse as a kernel unit (see [`super::super::mbvh4_unit`] for the
//! model). The collapse pass baseline is the `Topdown` unit of `cbvh_out`.

use super::*;

pub(super) struct Collapse {
    pub(super) sc: Option<bvh::StreamCollapse>,
    /// Wide nodes closed and not yet handed to the write buffer.
    pub(super) writes: u64,
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
        if self.writes > 0 {
            if !w.nodes.has_room(now, MBVH4_NODE_BYTES) {
                cx.set_state(State::Stalled(CO_WRITE_FULL));
                return Ok(Wake::OnEvent);
            }
            w.nodes.add(cx, MBVH4_NODE_BYTES);
            self.writes -= 1;
            self.stats.nodes_written += 1;
            cx.set_state(State::Busy);
            return Ok(Wake::Next);
        }
        let sc = self.sc.as_mut().expect("collapse until done");
        if let Some(n) = w.col_fifo.pop(cx) {
            self.writes = sc.push(&n)? as u64;
            self.think = self.levels;
            self.stats.nodes_in += 1;
            cx.set_state(State::Busy);
            Ok(Wake::Next)
        } else if w.emit_finished.get(now) && !self.ended {
            // The root's slots are written last, as the root node.
            self.writes = sc.end(&w.out.roots)? as u64;
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
            w.stream_done.push(cx, ()).expect("one done token");
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
        &["input empty", "write buffer full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        match self.step_inner(w, cx) {
            Ok(wake) => wake,
            Err(e) => {
                w.out.collapse_fault = Some(e);
                self.done = true;
                w.stream_done.push(cx, ()).expect("one done token");
                Wake::Done
            }
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{} nodes in, {} written, {} writes queued, ended {}, done {}",
            self.stats.nodes_in, self.stats.nodes_written, self.writes, self.ended, self.done
        )
    }
}
