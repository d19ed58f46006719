//! The CBVH outputs: the streaming encoder and the top-down pass as kernel units (see
//! [`super::super::cbvh_unit`] for the model).

use super::*;

/// The encoder a streaming CBVH unit drives: node pairs behind the emitter
/// (`cbvh-stream`), or 4-wide nodes behind the collapse unit (`cbvh4`).
pub(super) enum Encoder {
    Pair(cbvh::bottomup::StreamEncoder),
    Wide(cbvh::WideStreamEncoder),
}

impl Encoder {
    fn drain_ops(&mut self) -> Vec<cbvh::bottomup::MemOp> {
        match self {
            Encoder::Pair(e) => e.drain_ops(),
            Encoder::Wide(e) => e.drain_ops(),
        }
    }

    fn end_stream(&mut self) -> Result<(), cbvh::CbvhError> {
        match self {
            Encoder::Pair(e) => e.end_stream(),
            Encoder::Wide(e) => e.end_stream(),
        }
    }
}

pub(super) struct Stream {
    pub(super) enc: Option<Encoder>,
    pub(super) ops: VecDeque<cbvh::bottomup::MemOp>,
    pub(super) awaiting_read: bool,
    pub(super) flushing: bool,
    pub(super) ended: bool,
    pub(super) done: bool,
    pub(super) stats: StreamUnitStats,
    pub(super) flush_before_read: bool,
}

pub(super) const ST_STARVED: u8 = 0;
pub(super) const ST_READ_WAIT: u8 = 1;
pub(super) const ST_FLUSH_WAIT: u8 = 2;
pub(super) const ST_WRITE_FULL: u8 = 3;
pub(super) const ST_REQ_FULL: u8 = 4;

impl Stream {
    /// A streaming encoder unit around `enc`, idle; `flush_before_read` as
    /// `cbvh_flush_before_backtrack`.
    pub(super) fn new(enc: Encoder, flush_before_read: bool) -> Self {
        Self {
            enc: Some(enc),
            ops: VecDeque::new(),
            awaiting_read: false,
            flushing: false,
            ended: false,
            done: false,
            stats: StreamUnitStats::default(),
            flush_before_read,
        }
    }

    pub(super) fn read_returned(&mut self, latency: u64) {
        self.awaiting_read = false;
        self.stats.backtrack_read_latency_cycles += latency;
        let bucket = (63 - latency.max(1).leading_zeros()) as usize;
        let h = &mut self.stats.backtrack_read_latency_log2;
        if h.len() <= bucket {
            h.resize(bucket + 1, 0);
        }
        h[bucket] += 1;
    }

    pub(super) fn step_inner(
        &mut self,
        w: &mut KWorld,
        cx: &mut Ctx,
    ) -> Result<Wake, cbvh::CbvhError> {
        use cbvh::bottomup::MemOp;
        let now = cx.now();
        while let Some(lat) = w.bt_data.pop(cx) {
            self.read_returned(lat);
        }
        if self.done {
            return Ok(Wake::Done);
        }
        if self.awaiting_read {
            cx.set_state(State::Stalled(ST_READ_WAIT));
            return Ok(Wake::OnEvent);
        }
        let enc = self.enc.as_mut().expect("encoder until done");
        match self.ops.front().copied() {
            Some(MemOp::WritePair { bytes, .. }) => {
                if !w.nodes.has_room(now, bytes as u64) {
                    cx.set_state(State::Stalled(ST_WRITE_FULL));
                    return Ok(Wake::OnEvent);
                }
                w.nodes.add(cx, bytes as u64);
                self.ops.pop_front();
                self.stats.pairs_written += 1;
                cx.set_state(State::Busy);
                Ok(Wake::Next)
            }
            Some(MemOp::BacktrackRead {
                addr_bytes, bytes, ..
            }) => {
                // A line with bytes still in the write buffer is written out first.
                let pending = self.flush_before_read
                    && w.nodes.start_pending(now) > 0
                    && w.nodes.start_next_addr(now) < addr_bytes + bytes as u64;
                if pending {
                    if !self.flushing {
                        self.flushing = true;
                        self.stats.backtrack_flushes += 1;
                        w.nodes.flush_through(cx, addr_bytes + bytes as u64);
                    }
                    cx.set_state(State::Stalled(ST_FLUSH_WAIT));
                    return Ok(Wake::OnEvent); // the buffer's writes wake us
                }
                let req = Req {
                    addr: addr_bytes,
                    bytes,
                    kind: AccessKind::Read,
                    dest: Dest::Backtrack,
                };
                if w.req_cbvh.push(cx, req).is_err() {
                    cx.set_state(State::Stalled(ST_REQ_FULL));
                    return Ok(Wake::OnEvent);
                }
                self.ops.pop_front();
                self.awaiting_read = true;
                self.flushing = false;
                self.stats.backtrack_reads += 1;
                cx.set_state(State::Stalled(ST_READ_WAIT));
                Ok(Wake::OnEvent)
            }
            Some(MemOp::BacktrackWrite {
                addr_bytes, bytes, ..
            }) => {
                let req = Req {
                    addr: addr_bytes,
                    bytes,
                    kind: AccessKind::Write,
                    dest: Dest::Buffer,
                };
                if w.req_cbvh.push(cx, req).is_err() {
                    cx.set_state(State::Stalled(ST_REQ_FULL));
                    return Ok(Wake::OnEvent);
                }
                self.ops.pop_front();
                self.stats.backtrack_writes += 1;
                cx.set_state(State::Busy);
                Ok(Wake::Next)
            }
            None => {
                let took = match enc {
                    Encoder::Pair(e) => w.enc_fifo.pop(cx).map(|n| e.push(n)),
                    Encoder::Wide(e) => w.wide_fifo.pop(cx).map(|n| e.push(n)),
                };
                // The emitter's, or behind the collapse unit the collapse's, last node.
                let upstream_finished = match enc {
                    Encoder::Pair(_) => w.emit_finished.get(now),
                    Encoder::Wide(_) => w.collapse_finished.get(now),
                };
                if let Some(r) = took {
                    r?;
                    self.ops.extend(enc.drain_ops());
                    self.stats.nodes_in += 1;
                    cx.set_state(State::Busy);
                    Ok(Wake::Next)
                } else if upstream_finished && !self.ended {
                    // The root's treelet (or the root itself) is written last.
                    enc.end_stream()?;
                    self.ops.extend(enc.drain_ops());
                    self.ended = true;
                    cx.set_state(State::Busy);
                    Ok(Wake::Next)
                } else if self.ended {
                    self.done = true;
                    match self.enc.take().expect("once") {
                        Encoder::Pair(e) => w.out.stream = Some((e, self.stats.clone())),
                        Encoder::Wide(e) => w.out.wide = Some((e, self.stats.clone())),
                    }
                    w.stream_done.push(cx, ()).expect("one done token");
                    cx.set_state(State::Idle);
                    Ok(Wake::Done)
                } else {
                    cx.set_state(State::Stalled(ST_STARVED));
                    Ok(Wake::OnEvent)
                }
            }
        }
    }
}

impl<'a> Unit<KWorld<'a>> for Stream {
    fn name(&self) -> &str {
        "cbvh encoder"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &[
            "input empty",
            "read wait",
            "flush wait",
            "write buffer full",
            "request slot full",
        ]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        if self.enc.is_none() && !self.done {
            return Wake::Done; // not attached
        }
        match self.step_inner(w, cx) {
            Ok(wake) => wake,
            Err(e) => {
                w.out.fault = Some(e);
                self.done = true;
                w.stream_done.push(cx, ()).expect("one done token");
                Wake::Done
            }
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{} nodes in, {} ops queued (front {:?}), awaiting read {}, ended {}, done {}",
            self.stats.nodes_in,
            self.ops.len(),
            self.ops.front(),
            self.awaiting_read,
            self.ended,
            self.done
        )
    }
}

// ---------------------------------------------------------------------------------------
// Top-down CBVH pass (see [`super::cbvh_unit`] for the model)

pub(super) struct Topdown {
    pub(super) started: bool,
    pub(super) nodes: u64,
    pub(super) next_read: u64,
    pub(super) arrived: Vec<bool>,
    pub(super) next_encode: u64,
    pub(super) pairs: u64,
    /// Bytes written after consuming each position (a node pair each for the CBVH; a
    /// wide node at the wide roots for the MBVH4 collapse pass).
    pub(super) bytes: Vec<u64>,
    pub(super) pair_bytes: u64,
    pub(super) stats: TopdownStats,
}

pub(super) const TD_READ_WAIT: u8 = 0;
pub(super) const TD_WRITE_FULL: u8 = 1;

impl<'a> Unit<KWorld<'a>> for Topdown {
    fn name(&self) -> &str {
        "topdown pass"
    }

    fn stall_reasons(&self) -> &'static [&'static str] {
        &["read wait", "write buffer full"]
    }

    fn step(&mut self, w: &mut KWorld<'a>, cx: &mut Ctx) -> Wake {
        let now = cx.now();
        if !self.started {
            if w.td_start.pop(cx).is_none() {
                return Wake::Done;
            }
            self.started = true;
            self.nodes = w.out.nodes.len() as u64;
            self.arrived = vec![false; self.nodes as usize];
            self.pairs = self.nodes.max(1);
            self.bytes = if w.cfg.output == OutputMode::Mbvh4Collapse {
                let hl = bvh::Highlevel {
                    nodes: w.out.nodes.clone(),
                    roots: w.out.roots.clone(),
                    order: w.out.order.clone(),
                };
                match crate::mergetree::mbvh4_unit::collapse_pass_writes(&hl) {
                    Ok(b) => b,
                    Err(e) => {
                        w.out.collapse_fault = Some(e);
                        vec![0; self.pairs as usize]
                    }
                }
            } else {
                vec![self.pair_bytes; self.pairs as usize]
            };
            w.td_data = fifo(
                "arbiter->topdown",
                self.nodes as usize,
                ARBITER,
                w.ids.topdown,
            );
        }
        if self.next_encode == self.pairs {
            return Wake::Done;
        }
        while let Some((j, lat)) = w.td_data.pop(cx) {
            self.arrived[j as usize] = true;
            self.stats.read_latency_cycles += lat;
        }
        // One node read offered per cycle, from the end of the node array backwards.
        let mut issued = false;
        if self.next_read < self.nodes && !w.req_cbvh.is_full(cx) {
            let k = self.nodes - 1 - self.next_read;
            let req = Req {
                addr: w.layout.nodes + k * NODE_BYTES,
                bytes: NODE_BYTES as u32,
                kind: AccessKind::Read,
                dest: Dest::Topdown { j: self.next_read },
            };
            if w.req_cbvh.push(cx, req).is_err() {
                unreachable!("checked");
            }
            self.next_read += 1;
            self.stats.node_reads += 1;
            issued = true;
        }
        // A tree that is one leaf has no node to read: its box is the root record.
        let here = self.nodes == 0 || self.arrived[self.next_encode as usize];
        let bytes = self.bytes[self.next_encode as usize];
        let wake = if !here {
            cx.set_state(State::Stalled(TD_READ_WAIT));
            Wake::OnEvent
        } else if !w.nodes.has_room(now, bytes) {
            cx.set_state(State::Stalled(TD_WRITE_FULL));
            Wake::OnEvent
        } else {
            if bytes > 0 {
                w.nodes.add(cx, bytes);
                self.stats.pairs_written += 1;
            }
            self.next_encode += 1;
            cx.set_state(State::Busy);
            if self.next_encode == self.pairs {
                w.out.topdown = Some(self.stats.clone());
                w.td_done.push(cx, ()).expect("one done token");
                cx.set_state(State::Idle);
                return Wake::Done;
            }
            Wake::Next
        };
        if issued || (self.next_read < self.nodes && !w.req_cbvh.is_full(cx)) {
            Wake::Next
        } else {
            wake
        }
    }

    fn describe(&self, _w: &KWorld<'a>) -> String {
        format!(
            "{}/{} read, {}/{} encoded",
            self.next_read, self.nodes, self.next_encode, self.pairs
        )
    }
}
