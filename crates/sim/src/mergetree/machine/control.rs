//! The control FSM of \[P1\] Fig. 2 / \[P2\] Fig. 3: the phases of a build and the commands
//! it gives the other units.

use super::*;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Phase {
    PartialSort,
    MergePass(u32),
    Fence(u32),
    Emit,
    Toplevel,
    Topdown,
    Done,
}

pub(super) struct Control {
    pub(super) phase: Phase,
    pub(super) fill_block: u64,
    pub(super) subs_in: u64,
    pub(super) merging: bool,
    pub(super) group: u64,
    pub(super) pass_run_len: u64,
    pub(super) pass_runs: u64,
    pub(super) draining: bool,
    pub(super) stream_done: bool,
    pub(super) phase_start: Cycle,
    pub(super) snap: [u64; 4],
}

impl Control {
    pub(super) fn phase_name(&self, w: &KWorld) -> String {
        match self.phase {
            Phase::PartialSort => "partial_sort".into(),
            Phase::MergePass(p) | Phase::Fence(p) => format!("merge_pass_{}", p + 1),
            Phase::Emit => {
                if w.passes_total == 0 {
                    "sort_and_emit".into()
                } else {
                    format!("merge_pass_{}_and_emit", w.passes_total)
                }
            }
            Phase::Toplevel => "toplevel_sah".into(),
            Phase::Topdown => "topdown_compress".into(),
            Phase::Done => "done".into(),
        }
    }

    pub(super) fn set_phase(&mut self, w: &mut KWorld, now: Cycle, p: Phase) {
        self.phase = p;
        let name = self.phase_name(w);
        w.phase_log.push((now, name));
    }

    pub(super) fn end_phase(&mut self, w: &mut KWorld, now: Cycle) {
        let a = &w.acc;
        let t = [
            a.read_bytes.get(now),
            a.write_bytes.get(now),
            a.reads.get(now),
            a.read_latency.get(now),
        ];
        let reads = t[2] - self.snap[2];
        w.phases.push(PhaseReport {
            name: self.phase_name(w),
            start_cycle: self.phase_start,
            end_cycle: now,
            bytes_read: t[0] - self.snap[0],
            bytes_written: t[1] - self.snap[1],
            reads,
            read_latency_mean_cycles: if reads == 0 {
                0.0
            } else {
                (t[3] - self.snap[3]) as f64 / reads as f64
            },
        });
        self.snap = t;
        self.phase_start = now;
    }

    pub(super) fn start_pass(&mut self, w: &mut KWorld, cx: &mut Ctx, p: u32) {
        let fan = w.cfg.fan_in();
        self.pass_run_len = w.cfg.m_elems() * fan.pow(p);
        self.pass_runs = w.npad.div_ceil(self.pass_run_len);
        self.group = 0;
        let to_emitter = p + 1 == w.passes_total;
        if to_emitter {
            w.emit_active.set(cx.now(), true);
            cx.notify(EMITTER, cx.now() + 1);
        }
        let ph = if to_emitter {
            Phase::Emit
        } else {
            Phase::MergePass(p)
        };
        self.set_phase(w, cx.now(), ph);
        self.setup_group(w, cx, p);
    }

    pub(super) fn setup_group(&mut self, w: &mut KWorld, cx: &mut Ctx, p: u32) {
        let fan = w.cfg.fan_in();
        let first = self.group * fan;
        let last = (first + fan).min(self.pass_runs);
        let c = MergeCmd::Multi {
            first,
            last,
            run_len: self.pass_run_len,
            src: (p % 2) as u8,
            to_emitter: p + 1 == w.passes_total,
        };
        w.cmd
            .push(cx, c)
            .expect("the merger took the previous command");
        self.merging = true;
    }

    /// True when every write buffer was empty and no request was outstanding at the start
    /// of the cycle.
    pub(super) fn drained(w: &KWorld, now: Cycle) -> bool {
        w.nodes.start_pending(now) == 0
            && w.leaves.start_pending(now) == 0
            && w.hl.start_pending(now) == 0
            && w.inflight.get(now) == 0
    }
}

impl<'a> Unit<KWorld<'a>> for Control {
    fn name(&self) -> &str {
        "control"
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        match self.phase {
            Phase::PartialSort => {
                while w.sub_ready.pop(cx).is_some() {
                    self.subs_in += 1;
                }
                if self.merging {
                    if w.merge_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.merging = false;
                    self.fill_block += 1;
                    if self.fill_block == w.blocks {
                        if w.passes_total == 0 {
                            self.set_phase(w, now, Phase::Emit);
                            return Wake::Next;
                        }
                        self.end_phase(w, now);
                        self.set_phase(w, now, Phase::Fence(0));
                        return Wake::Next;
                    }
                    w.scratch_open.set(now, self.fill_block);
                    cx.notify(UnitId(PRESORTER0), now + 1);
                    return Wake::OnEvent;
                }
                let nsub = w.subs_of_block(self.fill_block);
                if self.subs_in < nsub {
                    return Wake::OnEvent;
                }
                self.subs_in -= nsub;
                let first = self.fill_block * w.cfg.m_elems() / (2 * w.cfg.b_elems());
                let c = MergeCmd::Partial {
                    first,
                    count: nsub,
                    to_emitter: w.blocks == 1,
                };
                w.cmd.push(cx, c).expect("the merger is idle");
                w.scratch_open.set(now, CLOSED);
                self.merging = true;
                cx.set_state(State::Busy);
                Wake::OnEvent
            }
            Phase::Fence(p) => {
                if w.acc.run_acked.get(now) < w.npad * (p as u64 + 1) {
                    return Wake::Next; // polls the arbiter's total
                }
                self.start_pass(w, cx, p);
                Wake::Next
            }
            Phase::MergePass(p) => {
                if w.merge_done.pop(cx).is_none() {
                    return Wake::OnEvent;
                }
                self.merging = false;
                self.group += 1;
                if self.group < self.pass_runs.div_ceil(w.cfg.fan_in()) {
                    self.setup_group(w, cx, p);
                    return Wake::OnEvent;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Fence(p + 1));
                Wake::Next
            }
            Phase::Emit => {
                // The final merge's done token is not needed: the emitter ends the phase.
                let _ = w.merge_done.pop(cx);
                // A streaming encoder or collapse writes nodes until it is done.
                let streaming =
                    w.cfg.output == OutputMode::CbvhStream || w.cfg.output.collapses_stream();
                if !self.draining {
                    if w.emit_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    // The streaming encoder writes node pairs until it is done.
                    if !streaming {
                        w.nodes.set_flush(cx, true);
                    }
                    w.leaves.set_flush(cx, true);
                    w.hl.set_flush(cx, true);
                    return Wake::Next;
                }
                if streaming && !self.stream_done {
                    if w.stream_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.stream_done = true;
                    w.nodes.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.draining = false;
                self.end_phase(w, now);
                w.build_cycles = now + 1;
                if w.cfg.toplevel_sah && w.out.roots.len() > 1 {
                    w.top_start.push(cx, ()).expect("one start");
                    w.hl.set_flush(cx, false);
                    self.set_phase(w, now, Phase::Toplevel);
                    return Wake::OnEvent;
                }
                if matches!(
                    w.cfg.output,
                    OutputMode::CbvhTopdown | OutputMode::Mbvh4Collapse
                ) {
                    w.nodes = KBuf::new(
                        WriteBuffer::new(
                            w.layout.cbvh,
                            w.cfg.node_buffer_bytes as u64,
                            w.cfg.write_chunk_bytes as u64,
                        ),
                        [w.ids.topdown, w.ids.topdown],
                    );
                    w.td_start.push(cx, ()).expect("one start");
                    self.set_phase(w, now, Phase::Topdown);
                    return Wake::OnEvent;
                }
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Toplevel => {
                if !self.draining {
                    if w.top_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    w.hl.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Topdown => {
                if !self.draining {
                    if w.td_done.pop(cx).is_none() {
                        return Wake::OnEvent;
                    }
                    self.draining = true;
                    w.nodes.set_flush(cx, true);
                    return Wake::Next;
                }
                if !Self::drained(w, now) {
                    return Wake::Next;
                }
                self.end_phase(w, now);
                self.set_phase(w, now, Phase::Done);
                cx.set_state(State::Idle);
                Wake::Done
            }
            Phase::Done => Wake::Done,
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "phase {:?}, block {}, {} sub-blocks in, merging {}, group {}, draining {}",
            self.phase, self.fill_block, self.subs_in, self.merging, self.group, self.draining
        )
    }
}
