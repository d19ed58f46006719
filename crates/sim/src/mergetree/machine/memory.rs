//! The reader, the run writer and the memory arbiter: the units between the machine and its
//! memory port.

use super::*;

pub(super) struct Reader {
    pub(super) in_next: u64,
    pub(super) in_p: u32,
    pub(super) second_half: bool,
    /// Ring slots of each presorter allocated and not yet freed.
    pub(super) alloc: Vec<u32>,
    pub(super) tail: Vec<u32>,
    pub(super) slots: u32,
}

pub(super) const READER_RING_FULL: u8 = 0;
pub(super) const READER_REQ_FULL: u8 = 1;

impl<'a> Unit<KWorld<'a>> for Reader {
    fn name(&self) -> &str {
        "reader"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["presorter ring full", "request slot full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        for (a, f) in self.alloc.iter_mut().zip(w.ps_credit.iter_mut()) {
            while f.pop(cx).is_some() {
                *a -= 1;
            }
        }
        let input = self.in_next < w.npad;
        if !input && w.refill.peek(cx).is_none() {
            cx.set_state(State::Idle);
            return Wake::Done;
        }
        if input && self.alloc[self.in_p as usize] == self.slots {
            cx.set_state(State::Stalled(READER_RING_FULL));
            return Wake::OnEvent;
        }
        if w.req_read.is_full(cx) {
            cx.set_state(State::Stalled(READER_REQ_FULL));
            return Wake::OnEvent;
        }
        let req = if input {
            let b = w.cfg.b_elems();
            let p = self.in_p as usize;
            let slot = self.tail[p];
            self.tail[p] = if slot + 1 == self.slots { 0 } else { slot + 1 };
            self.alloc[p] += 1;
            let real = w.n.min(self.in_next + b) - self.in_next;
            let r = Req {
                addr: w.layout.input + self.in_next * w.cfg.elem_bytes(),
                bytes: (real * w.cfg.elem_bytes()) as u32,
                kind: AccessKind::Read,
                dest: Dest::Presort {
                    p: self.in_p,
                    read: InputRead {
                        slot,
                        src: self.in_next,
                        count: b as u32,
                    },
                },
            };
            self.in_next += b;
            // Two buffers make a sub-block; sub-blocks go round robin to presorters.
            self.second_half = !self.second_half;
            if !self.second_half {
                self.in_p += 1;
                if self.in_p == w.cfg.presorters {
                    self.in_p = 0;
                }
            }
            r
        } else {
            let f = w.refill.pop(cx).expect("peeked");
            Req {
                addr: w.layout.runs[f.region as usize]
                    + run_offset(
                        f.pos,
                        w.cfg.m_elems(),
                        w.cfg.run_gap_bytes as u64,
                        w.cfg.elem_bytes(),
                    ),
                bytes: f.count * w.cfg.elem_bytes() as u32,
                kind: AccessKind::Read,
                dest: Dest::Merge(f),
            }
        };
        if w.req_read.push(cx, req).is_err() {
            unreachable!("checked");
        }
        cx.set_state(State::Busy);
        Wake::Next
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!("input at {}, presorter {}", self.in_next, self.in_p)
    }
}

// ---------------------------------------------------------------------------------------
// Run writer

pub(super) struct RunWriter {
    pub(super) staged: u32,
    pub(super) written: u64,
    pub(super) b: u32,
    pub(super) npad: u64,
}

impl<'a> Unit<KWorld<'a>> for RunWriter {
    fn name(&self) -> &str {
        "run writer"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["request slot full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        while self.staged < self.b {
            let Some(e) = w.run_fifo.pop(cx) else { break };
            let c = self.written;
            let region = ((c / self.npad) % 2) as usize;
            w.region[region][(c % self.npad) as usize] = e.index;
            self.written += 1;
            self.staged += 1;
        }
        if self.staged < self.b {
            cx.set_state(State::Idle);
            return if self.staged == 0 {
                Wake::Done
            } else {
                Wake::OnEvent
            };
        }
        let start = self.written - self.b as u64;
        let region = ((start / self.npad) % 2) as usize;
        let bytes = self.b * w.cfg.elem_bytes() as u32;
        let req = Req {
            addr: w.layout.runs[region]
                + run_offset(
                    start % self.npad,
                    w.cfg.m_elems(),
                    w.cfg.run_gap_bytes as u64,
                    w.cfg.elem_bytes(),
                ),
            bytes,
            kind: AccessKind::Write,
            dest: Dest::Run { elems: self.b },
        };
        if w.req_run.push(cx, req).is_err() {
            cx.set_state(State::Stalled(0));
            return Wake::OnEvent;
        }
        self.staged = 0;
        cx.set_state(State::Busy);
        Wake::Next
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![("elements", self.written)]
    }
}

// ---------------------------------------------------------------------------------------
// Memory arbiter

/// Requesters of the arbiter, in round-robin order.
pub(super) const REQUESTERS: usize = 6;

pub(super) struct Arbiter {
    pub(super) rr: RoundRobin,
    pub(super) slab: Vec<(Dest, u32)>,
    pub(super) free: Vec<u32>,
    pub(super) inflight: u64,
    pub(super) burst: u32,
    /// The port accepts a refused request only after a response (then a refused arbiter
    /// sleeps until one arrives: the memory wakes it).
    pub(super) lift_only_with_responses: bool,
}

impl Arbiter {
    #[inline]
    pub(super) fn head(w: &KWorld, cx: &Ctx, i: usize) -> Option<Req> {
        let now = cx.now();
        let buf = |b: &KBuf| {
            b.ready(now).map(|(addr, bytes)| Req {
                addr,
                bytes,
                kind: AccessKind::Write,
                dest: Dest::Buffer,
            })
        };
        match i {
            0 => w.req_run.peek(cx).copied(),
            1 => buf(&w.nodes),
            2 => buf(&w.leaves),
            3 => buf(&w.hl),
            4 => w.req_read.peek(cx).copied(),
            _ => w.req_cbvh.peek(cx).copied(),
        }
    }
}

impl<'a> Unit<KWorld<'a>> for Arbiter {
    fn name(&self) -> &str {
        "memory arbiter"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["port refused"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        while let Some(r) = w.mem.pop(cx) {
            self.inflight -= 1;
            let (d, bytes) = self.slab[r.tag as usize];
            self.free.push(r.tag as u32);
            let latency = r.completed_cycle - r.accepted_cycle;
            if r.kind == AccessKind::Read {
                w.acc.reads.add(now, 1);
                w.acc.read_latency.add(now, latency);
            }
            match d {
                Dest::Run { elems } => w.acc.run_acked.add(now, elems as u64),
                Dest::Buffer => {}
                Dest::Presort { p, read } => {
                    if w.ps_data[p as usize].push(cx, read).is_err() {
                        unreachable!("one entry per ring slot");
                    }
                }
                Dest::Merge(f) => {
                    if w.fill.push(cx, f).is_err() {
                        unreachable!("one entry per buffer half");
                    }
                }
                Dest::Backtrack => {
                    if w.bt_data.push(cx, latency).is_err() {
                        unreachable!("one backtracking read at a time");
                    }
                }
                Dest::Topdown { j } => {
                    if w.td_data.push(cx, (j, latency)).is_err() {
                        unreachable!("one entry per node");
                    }
                }
            }
            w.trace.row(now).bus_bytes += bytes as u64;
        }
        let Arbiter {
            rr,
            slab,
            free,
            inflight,
            burst,
            ..
        } = self;
        let mut refused = false;
        if !(0..REQUESTERS).any(|i| Self::head(w, cx, i).is_some()) {
            // Nothing to issue: no arbitration.
            w.inflight.set(now, *inflight);
            cx.set_state(State::Idle);
            return if *inflight > 0 {
                Wake::OnEvent
            } else {
                Wake::Done
            };
        }
        let granted = rr.arbitrate(|i| {
            let Some(req) = Self::head(w, cx, i) else {
                return Offer::Nothing;
            };
            let tag = match free.pop() {
                Some(t) => {
                    slab[t as usize] = (req.dest, req.bytes);
                    t
                }
                None => {
                    slab.push((req.dest, req.bytes));
                    (slab.len() - 1) as u32
                }
            };
            let m = MemRequest {
                tag: tag as u64,
                addr: req.addr,
                bytes: req.bytes,
                kind: req.kind,
            };
            if w.mem.send(cx, m).is_err() {
                free.push(tag);
                refused = true;
                return Offer::Refused;
            }
            *inflight += 1;
            match i {
                0 => {
                    w.req_run.pop(cx);
                }
                1 => w.nodes.issued(cx, req.bytes),
                2 => w.leaves.issued(cx, req.bytes),
                3 => w.hl.issued(cx, req.bytes),
                4 => {
                    w.req_read.pop(cx);
                }
                _ => {
                    w.req_cbvh.pop(cx);
                }
            }
            let bb = *burst;
            let b = crate::dram::bursts_of(req.addr, req.bytes, bb) * bb as u64;
            match req.kind {
                AccessKind::Read => w.acc.read_bytes.add(now, b),
                AccessKind::Write => w.acc.write_bytes.add(now, b),
            }
            Offer::Granted
        });
        w.inflight.set(now, self.inflight);
        cx.set_state(if granted > 0 {
            State::Busy
        } else if refused {
            State::Stalled(0)
        } else {
            State::Idle
        });
        // After a grant, step once more to end the busy cycle. Refused with nothing granted:
        // retry in the next cycle, or, when only a response can make room, at the response.
        if granted == 0 && refused && self.lift_only_with_responses {
            Wake::OnEvent
        } else if granted > 0 || (0..REQUESTERS).any(|i| Self::head(w, cx, i).is_some()) {
            Wake::Next
        } else if self.inflight > 0 {
            Wake::OnEvent
        } else {
            Wake::Done
        }
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let s = self.rr.stats();
        vec![
            ("grants", s.grants.iter().sum()),
            ("refusal_episodes", s.refusals.iter().sum()),
        ]
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!("{} requests in flight", self.inflight)
    }
}
