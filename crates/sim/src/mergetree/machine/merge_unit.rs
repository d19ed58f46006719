//! The multi-merge unit as a kernel unit.

use super::*;

pub(super) struct MergeUnit {
    pub(super) m: Merger,
    pub(super) active: bool,
    pub(super) to_emitter: bool,
    pub(super) src: u8,
    /// Buffer halves to refill, collected in a step (allocated once).
    pub(super) refills: VecDeque<u32>,
}

pub(super) const MERGE_DRY: u8 = 0;
pub(super) const MERGE_FULL: u8 = 1;
pub(super) const MERGE_INIT: u8 = 2;

pub(super) struct KMergeOut<'c, 'w> {
    pub(super) cx: &'c mut Ctx,
    pub(super) out: &'w mut LatencyFifo<Elem>,
    pub(super) refills: &'w mut VecDeque<u32>,
}

impl MergeOut for KMergeOut<'_, '_> {
    #[inline]
    fn is_full(&self) -> bool {
        self.out.is_full(self.cx)
    }
    #[inline]
    fn push(&mut self, e: Elem) {
        let _ = self.out.push(self.cx, e);
    }
    #[inline]
    fn refill(&mut self, buf: u32) {
        self.refills.push_back(buf);
    }
}

impl MergeUnit {
    pub(super) fn push_refills(&mut self, w: &mut KWorld, cx: &mut Ctx) {
        // With forecasting, free buffers go to the runs the forecast heap names.
        self.m.forecast_issue(&mut self.refills);
        while let Some(buf) = self.refills.pop_front() {
            let (pos, count) = self.m.peek_fetch(buf);
            self.m.commit_fetch(buf, count);
            let f = Fetch {
                buf,
                region: self.src,
                pos,
                count,
            };
            if w.refill.push(cx, f).is_err() {
                unreachable!("the refill FIFO holds every buffer of the scratchpad");
            }
        }
    }
}

impl<'a> Unit<KWorld<'a>> for MergeUnit {
    fn name(&self) -> &str {
        "merge"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["queue dry", "output full", "init wait"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        while let Some(f) = w.fill.pop(cx) {
            let s = f.pos as usize;
            let src = &w.region[f.region as usize][s..s + f.count as usize];
            let (aabbs, codes) = (w.aabbs, &w.codes);
            self.m.fill_with(f.buf, src.len(), |k| {
                let r = src[k];
                match aabbs.get(r as usize) {
                    Some(&a) => Elem::new(codes[r as usize], r, a),
                    None => Elem::pad(r as u64),
                }
            });
        }
        if !self.active {
            let Some(c) = w.cmd.pop(cx) else {
                cx.set_state(State::Idle);
                return Wake::Done;
            };
            self.active = true;
            match c {
                MergeCmd::Partial {
                    first,
                    count,
                    to_emitter,
                } => {
                    std::mem::swap(&mut self.m.scratch, &mut w.scratch);
                    self.to_emitter = to_emitter;
                    let w = &*w;
                    self.m
                        .setup_partial((first..first + count).map(|s| w.sub_len(s)), now);
                }
                MergeCmd::Multi {
                    first,
                    last,
                    run_len,
                    src,
                    to_emitter,
                } => {
                    self.to_emitter = to_emitter;
                    self.src = src;
                    let npad = w.npad;
                    self.m.setup_multi(
                        (first..last).map(|r| (r * run_len, (npad - r * run_len).min(run_len))),
                        &mut self.refills,
                        now,
                    );
                    self.push_refills(w, cx);
                }
            }
            cx.set_state(State::Busy);
        }
        let before = self.m.outputs;
        let slot = {
            let out = if self.to_emitter {
                &mut w.emit_fifo
            } else {
                &mut w.run_fifo
            };
            let mut o = KMergeOut {
                cx: &mut *cx,
                out,
                refills: &mut self.refills,
            };
            self.m.tick_with(now, &mut o)
        };
        if self.m.outputs > before {
            w.trace.row(now).merge_outputs += self.m.outputs - before;
            w.worked(self.m.outputs - before);
        }
        self.push_refills(w, cx);
        if self.m.state == MergeState::Done {
            self.m.state = MergeState::Idle;
            self.active = false;
            w.merge_done
                .push(cx, ())
                .expect("the control took the last token");
            cx.set_state(State::Idle);
            return Wake::Next; // the next command may be there
        }
        match slot {
            Slot::Worked | Slot::Closed => {
                cx.set_state(State::Busy);
                Wake::At(self.m.next_op)
            }
            Slot::QueueDry => {
                cx.set_state(State::Stalled(MERGE_DRY));
                Wake::OnEvent
            }
            Slot::OutputFull => {
                cx.set_state(State::Stalled(MERGE_FULL));
                Wake::OnEvent
            }
            Slot::InitWait => {
                cx.set_state(State::Stalled(MERGE_INIT));
                Wake::OnEvent
            }
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let mut c = vec![("outputs", self.m.outputs), ("heap_ops", self.m.ops)];
        if let Some(f) = &self.m.forecast {
            c.push(("forecast_reads", f.reads));
            c.push(("forecast_evictions", f.evictions));
        }
        c
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{:?}, heap {} live, next op at {}",
            self.m.state,
            self.m.heap.live(),
            self.m.next_op
        )
    }
}
