//! Units reach DRAM through the kernel: [`Memory`] wraps the one
//! [`crate::dram::MemoryPort`] of a model, lives in the world, and is ticked by the
//! scheduler, which routes each completed response to the unit that sent the request.

use std::collections::VecDeque;

use crate::dram::{MemRequest, MemResponse, MemoryPort};

use super::{Ctx, Cycle, UnitId};

/// The memory port of a world, as units see it.
///
/// Tags: a unit's request tag is kept for it and handed back in its response; the port
/// sees the index of a route slot instead (a slab with a free list: no hashing), which says
/// which unit the response goes to.
///
/// Time: a unit sends at cycle `t` (the port is at cycle `t`); the scheduler ticks the port
/// after every unit has stepped in the cycle; a response whose last burst completes while
/// the port advances to cycle `c` is handed to its unit's inbox at `c` and wakes the unit
/// at `c`. While requests are in flight the port is ticked every cycle (the interface does
/// not say when the next completion is); when none are, the scheduler jumps with
/// [`MemoryPort::tick_many`], whose result equals single ticks by the port contract.
pub struct Memory {
    port: Box<dyn MemoryPort>,
    /// (unit, the unit's tag) per route slot.
    routes: Vec<(u32, u64)>,
    free: Vec<u32>,
    inbox: Vec<VecDeque<MemResponse>>,
    in_inboxes: usize,
    refused: u64,
}

impl Memory {
    /// Wraps `port`, which must be at cycle 0 when the run starts.
    pub fn new(port: Box<dyn MemoryPort>) -> Self {
        Self {
            port,
            routes: Vec::with_capacity(64),
            free: Vec::with_capacity(64),
            inbox: Vec::new(),
            in_inboxes: 0,
            refused: 0,
        }
    }

    /// Offers `request` for the stepping unit at this cycle; gives it back when the port's
    /// queue is full.
    pub fn send(&mut self, cx: &Ctx, request: MemRequest) -> Result<(), MemRequest> {
        debug_assert_eq!(self.port.cycle(), cx.now(), "port and kernel out of step");
        let slot = match self.free.pop() {
            Some(s) => s,
            None => {
                self.routes.push((0, 0));
                (self.routes.len() - 1) as u32
            }
        };
        self.routes[slot as usize] = (cx.me().0, request.tag);
        let inner = MemRequest {
            tag: slot as u64,
            ..request
        };
        match self.port.send(inner) {
            Ok(()) => Ok(()),
            Err(_) => {
                self.free.push(slot);
                self.refused += 1;
                Err(request)
            }
        }
    }

    /// The stepping unit's next response (its own tag restored), if one has arrived.
    #[inline]
    pub fn pop(&mut self, cx: &Ctx) -> Option<MemResponse> {
        let r = self.inbox.get_mut(cx.me().index())?.pop_front()?;
        self.in_inboxes -= 1;
        Some(r)
    }

    /// True when a response waits for `unit`.
    pub fn has_response(&self, unit: UnitId) -> bool {
        self.inbox.get(unit.index()).is_some_and(|q| !q.is_empty())
    }

    /// The port (for its name and statistics).
    pub fn port(&self) -> &dyn MemoryPort {
        &*self.port
    }

    /// Requests sent and not yet popped by their unit.
    pub fn outstanding(&self) -> usize {
        self.port.outstanding() + self.in_inboxes
    }

    /// Sends the port refused.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Requests in the port (accepted, not yet routed).
    #[inline]
    pub(crate) fn in_flight(&self) -> usize {
        self.port.outstanding()
    }

    pub(crate) fn cycle(&self) -> Cycle {
        self.port.cycle()
    }

    #[inline]
    pub(crate) fn tick_many(&mut self, cycles: Cycle) {
        if cycles > 0 {
            self.port.tick_many(cycles);
        }
    }

    /// One tick; routes what completed and notifies its units for the new cycle.
    #[inline]
    pub(crate) fn tick_and_route(&mut self, cx: &mut Ctx) -> bool {
        if self.port.tick_and_count() == 0 {
            return false;
        }
        let now = self.port.cycle();
        while let Some(r) = self.port.pop_response() {
            let (unit, tag) = self.routes[r.tag as usize];
            self.free.push(r.tag as u32);
            let u = unit as usize;
            if u >= self.inbox.len() {
                self.inbox.resize_with(u + 1, VecDeque::new);
            }
            self.inbox[u].push_back(MemResponse { tag, ..r });
            self.in_inboxes += 1;
            cx.notify(UnitId(unit), now);
        }
        true
    }
}

impl std::fmt::Debug for Memory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "memory {} at cycle {}: {} in flight, {} responses not yet popped, {} sends refused",
            self.port.name(),
            self.port.cycle(),
            self.port.outstanding(),
            self.in_inboxes,
            self.refused
        )
    }
}
