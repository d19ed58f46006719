//! The unit interface and the context a unit steps in.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::stats::{State, Tracker};
use super::Cycle;

/// "Never": the wake time of a unit that sleeps until an event.
pub const NEVER: Cycle = Cycle::MAX;

/// Identifies a unit: its index in the [`super::Scheduler`], given by
/// [`super::Scheduler::add`]. Units step in ascending id order within a cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UnitId(pub u32);

impl UnitId {
    /// An end of a channel outside the kernel (a test harness): notifying it does nothing.
    pub const EXTERNAL: UnitId = UnitId(u32::MAX);

    /// The index as `usize`.
    #[inline]
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// When a unit next needs the clock, returned by [`Unit::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// Step me again in the next cycle.
    Next,
    /// Step me at this cycle (a cycle not after the current one means the next cycle).
    At(Cycle),
    /// I have work but wait for an input: sleep until an event (a push into a channel I
    /// consume, a pop from a channel I produce into that was full, a memory response, or
    /// an explicit [`Ctx::notify`]).
    OnEvent,
    /// I have no work left: sleep until an event, and count as finished. A run ends
    /// successfully when no unit is awake, nothing is pending, and every unit's last answer
    /// was `Done`; if one's was `OnEvent`, it is a deadlock.
    Done,
}

/// A simulated hardware unit of world type `W` (the struct holding the channels and shared
/// resources of a model).
///
/// # The contract that makes skipping exact
/// The scheduler steps a unit only in the cycles it asked for (and when an event reaches
/// it); in the no-skip mode ([`super::Options::skip`] false) it steps every unit in every
/// cycle. Both runs must give the same results, so a step in a cycle the unit did not ask
/// for must change nothing and report the same state and wake again: a unit decides only
/// from its inputs' visible state and the cycle number, never from how often it was
/// stepped. The equality tests of the kernel check this for their units; a model's tests
/// should run its system both ways.
pub trait Unit<W> {
    /// Name for reports and deadlock messages.
    fn name(&self) -> &str;

    /// Names of the unit's stall reasons: [`State::Stalled`]`(r)` is reason `names[r]`.
    fn stall_reasons(&self) -> &'static [&'static str] {
        &[]
    }

    /// Advances the unit at cycle `cx.now()`; says when it next needs the clock.
    fn step(&mut self, world: &mut W, cx: &mut Ctx) -> Wake;

    /// The unit's state in words, for a deadlock report (default: nothing more than the
    /// kernel's own view).
    fn describe(&self, _world: &W) -> String {
        String::new()
    }

    /// The unit's own counters, for the run report (collected once at the end).
    fn counters(&self) -> Vec<(&'static str, u64)> {
        Vec::new()
    }
}

/// What the scheduler lends a unit while it steps: the cycle, the unit's own id, the
/// event queue (channels notify their other end through it) and the unit's activity
/// tracker.
///
/// Events: a notification for unit `u` at cycle `t` makes `u` step at `t` (if it sleeps
/// longer). The earliest pending event of each unit is kept in an array; further distinct
/// times of the same unit (rare: two latency channels with items in flight) go into a
/// small heap, so no event is ever lost.
#[derive(Debug)]
pub struct Ctx {
    pub(crate) now: Cycle,
    pub(crate) me: UnitId,
    /// Earliest pending event per unit, or [`NEVER`].
    pub(crate) ev: Vec<Cycle>,
    /// Later pending events.
    pub(crate) overflow: BinaryHeap<Reverse<(Cycle, u32)>>,
    pub(crate) activity: Vec<Tracker>,
    /// Whether any notification was made since the flag was last cleared.
    pub(crate) notified: u64,
}

impl Ctx {
    /// A context for `units` units at cycle 0, for driving kernel pieces by hand (tests);
    /// the scheduler makes its own.
    pub fn new(units: usize) -> Self {
        Self {
            now: 0,
            me: UnitId(0),
            ev: vec![NEVER; units],
            overflow: BinaryHeap::new(),
            activity: (0..units).map(|_| Tracker::new(0)).collect(),
            notified: 0,
        }
    }

    /// The current cycle.
    #[inline]
    pub fn now(&self) -> Cycle {
        self.now
    }

    /// The unit stepping.
    #[inline]
    pub fn me(&self) -> UnitId {
        self.me
    }

    /// Sets the cycle and the stepping unit (for driving kernel pieces by hand).
    pub fn set_now(&mut self, now: Cycle, me: UnitId) {
        self.now = now;
        self.me = me;
    }

    /// Makes `unit` step at cycle `at` (at the next cycle if `at` is not after the current
    /// one: an event never reaches a unit in the cycle it happens, which keeps results
    /// independent of the step order).
    #[inline]
    pub fn notify(&mut self, unit: UnitId, at: Cycle) {
        let i = unit.index();
        if i >= self.ev.len() {
            return; // UnitId::EXTERNAL or a unit outside this context
        }
        let at = at.max(self.now + 1);
        self.notified += 1;
        let cur = self.ev[i];
        if at < cur {
            if cur != NEVER {
                self.overflow.push(Reverse((cur, unit.0)));
            }
            self.ev[i] = at;
        } else if at > cur {
            self.overflow.push(Reverse((at, unit.0)));
        }
    }

    /// The earliest event pending for `unit` in the array (tests).
    pub fn pending_event(&self, unit: UnitId) -> Option<Cycle> {
        self.ev.get(unit.index()).copied().filter(|&t| t != NEVER)
    }

    /// The stepping unit is in `state` from this cycle on (see [`super::stats`]).
    #[inline]
    pub fn set_state(&mut self, state: State) {
        if let Some(t) = self.activity.get_mut(self.me.index()) {
            t.set(state, self.now);
        }
    }

    /// The stepping unit's current state.
    pub fn state(&self) -> State {
        self.activity
            .get(self.me.index())
            .map_or(State::Idle, |t| t.state())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn notifications_keep_every_distinct_time() {
        let mut cx = Ctx::new(2);
        cx.set_now(10, UnitId(1));
        cx.notify(UnitId(0), 15);
        cx.notify(UnitId(0), 12);
        cx.notify(UnitId(0), 12);
        cx.notify(UnitId(0), 20);
        cx.notify(UnitId(0), 3); // in the past: next cycle
        cx.notify(UnitId::EXTERNAL, 3);
        assert_eq!(cx.pending_event(UnitId(0)), Some(11));
        let mut later: Vec<_> = cx.overflow.iter().map(|r| r.0).collect();
        later.sort();
        assert_eq!(later, vec![(12, 0), (15, 0), (20, 0)]);
        assert_eq!(cx.pending_event(UnitId(1)), None);
    }
}
