//! The presorter bank: the insertion presorters as one kernel unit.

use super::*;

/// One presorter of the bank, with its own busy / stall intervals.
pub(super) struct PresortUnit {
    pub(super) p: u32,
    pub(super) ps: Presorter,
    pub(super) acct: Acct,
    pub(super) b: u32,
    pub(super) subs_per_block: u64,
    pub(super) total_subs: u64,
    pub(super) count: u64,
}

pub(super) const PS_STARVED: u8 = 0;
pub(super) const PS_WAIT: u8 = 1;

impl PresortUnit {
    /// One presorter's step (the unit contract holds per presorter: a step it did not ask
    /// for changes nothing).
    pub(super) fn step(&mut self, w: &mut KWorld, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let b = self.b;
        let ps = &mut self.ps;
        while let Some(r) = w.ps_data[self.p as usize].pop(cx) {
            let base = r.slot as usize * b as usize;
            for i in 0..r.count as usize {
                let e = elem_of(w.aabbs, &w.quant, w.cfg.morton_bits, r.src + i as u64);
                if !e.is_pad() {
                    if let Some(c) = w.codes.get_mut(e.index as usize) {
                        *c = e.code;
                    }
                }
                ps.ring[base + i] = e;
            }
            ps.slot_count[r.slot as usize] = r.count;
            ps.slot_valid[r.slot as usize] = true;
            ps.used += 1;
        }
        match ps.state {
            PresortState::Finished => {
                self.acct.set(now, State::Idle);
                return Wake::Done;
            }
            PresortState::Sorting => {
                if now < ps.busy_until {
                    return Wake::At(ps.busy_until);
                }
                if ps.sorted(now) {
                    ps.state = PresortState::Draining { pos: 0 };
                } else {
                    let used = ps.used;
                    if !ps.insert_next(now, b) {
                        self.acct.set(now, State::Stalled(PS_STARVED));
                        return Wake::OnEvent;
                    }
                    if ps.used < used && w.ps_credit[self.p as usize].push(cx, ()).is_err() {
                        unreachable!("one credit per ring slot");
                    }
                    w.trace.span(now, ps.busy_until, |r| &mut r.presort_busy);
                    self.acct.set(now, State::Busy);
                    return Wake::At(ps.busy_until);
                }
            }
            PresortState::Draining { .. } => {}
        }
        let PresortState::Draining { pos } = ps.state else {
            unreachable!("draining")
        };
        if w.scratch_open.get(now) != ps.block {
            self.acct.set(now, State::Stalled(PS_WAIT));
            return Wake::OnEvent; // the control's register change wakes us
        }
        if w.scratch_port == now {
            self.acct.set(now, State::Stalled(PS_WAIT));
            return Wake::Next; // the write port is taken this cycle
        }
        w.scratch_port = now;
        let slot = (ps.sub % self.subs_per_block) * 2 * b as u64;
        w.scratch[(slot + pos as u64) as usize] = ps.buf[pos as usize];
        w.trace.row(now).presort_busy += 1;
        self.acct.set(now, State::Busy);
        if pos + 1 == ps.sub_len {
            if w.sub_ready.push(cx, ()).is_err() {
                unreachable!("room for every sub-block");
            }
            let next = ps.sub + self.count;
            if next < self.total_subs {
                let len = w.sub_len(next);
                ps.start(next, len, next / self.subs_per_block);
            } else {
                ps.state = PresortState::Finished;
            }
        } else {
            ps.state = PresortState::Draining { pos: pos + 1 };
        }
        Wake::Next
    }

    pub(super) fn describe(&self) -> String {
        let p = &self.ps;
        format!(
            "{:?}, sub-block {} {}/{} inserted, ring {}/{} used",
            p.state,
            p.sub,
            p.inserted,
            p.sub_len,
            p.used,
            p.slots()
        )
    }
}

/// Busy / stall intervals of one presorter (the kernel's interval accounting, per
/// presorter inside the bank).
#[derive(Clone, Copy, Debug)]
pub(super) struct Acct {
    pub(super) state: State,
    pub(super) since: Cycle,
    pub(super) busy: u64,
    pub(super) starved: u64,
    pub(super) wait: u64,
}

impl Acct {
    pub(super) fn new() -> Self {
        Self {
            state: State::Idle,
            since: 0,
            busy: 0,
            starved: 0,
            wait: 0,
        }
    }

    #[inline]
    pub(super) fn set(&mut self, now: Cycle, st: State) {
        if st == self.state {
            return;
        }
        let d = now - self.since;
        match self.state {
            State::Busy => self.busy += d,
            State::Stalled(PS_STARVED) => self.starved += d,
            State::Stalled(_) => self.wait += d,
            State::Idle => {}
        }
        self.state = st;
        self.since = now;
    }
}

/// The presorters as one kernel unit (one step for all that are due, fewer units for the
/// scheduler to scan): busy while any presorter is, else stalled on input while any is,
/// else waiting for the scratchpad while any is. Each presorter's own intervals are kept
/// in the bank (presorter-cycles for the stall report; every presorter ends idle, so its
/// intervals are closed when the run ends).
pub(super) struct PresortBank {
    pub(super) units: Vec<PresortUnit>,
}

impl<'a> Unit<KWorld<'a>> for PresortBank {
    fn name(&self) -> &str {
        "presorters"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["input empty", "scratchpad wait"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        let mut next = crate::kernel::NEVER;
        let mut all_done = true;
        let (mut busy, mut starved, mut wait) = (false, false, false);
        for u in &mut self.units {
            // Presorters that finished, or are inside an insertion (which nothing can
            // change before it ends; read data for their rings waits in their FIFO, which
            // they pop when they next need an element), are not stepped.
            let wake = match u.ps.state {
                PresortState::Finished => Wake::Done,
                PresortState::Sorting if now < u.ps.busy_until => Wake::At(u.ps.busy_until),
                _ => u.step(w, cx),
            };
            match wake {
                Wake::Next => next = next.min(now + 1),
                Wake::At(c) => next = next.min(c.max(now + 1)),
                Wake::OnEvent => all_done = false,
                Wake::Done => {}
            }
            match u.acct.state {
                State::Busy => busy = true,
                State::Stalled(PS_STARVED) => starved = true,
                State::Stalled(_) => wait = true,
                State::Idle => {}
            }
        }
        cx.set_state(if busy {
            State::Busy
        } else if starved {
            State::Stalled(PS_STARVED)
        } else if wait {
            State::Stalled(PS_WAIT)
        } else {
            State::Idle
        });
        if next != crate::kernel::NEVER {
            Wake::At(next)
        } else if all_done {
            Wake::Done
        } else {
            Wake::OnEvent
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let sum = |f: fn(&Acct) -> u64| self.units.iter().map(|u| f(&u.acct)).sum();
        vec![
            ("presorter_busy_cycles", sum(|a| a.busy)),
            ("presorter_starved_cycles", sum(|a| a.starved)),
            ("presorter_wait_cycles", sum(|a| a.wait)),
        ]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        self.units
            .iter()
            .map(|u| format!("presorter {}: {}", u.p, u.describe()))
            .collect::<Vec<_>>()
            .join("; ")
    }
}
