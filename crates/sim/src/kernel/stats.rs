//! Busy / stall / idle intervals of a unit.
//!
//! A unit does not count cycles; it reports *changes* of its state through
//! [`super::Ctx::set_state`], and the kernel adds the length of each closed interval to the
//! state it was in. Cycles the scheduler skips therefore belong to the state the unit was
//! last in, with no per-cycle code, and a run with skipping accounts exactly the same
//! cycles as a run that steps every unit every cycle.

use serde::Serialize;

use super::Cycle;

/// What a unit is doing, from the cycle it reports the state until it reports another.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum State {
    /// Nothing to do (the initial state of every unit).
    Idle,
    /// Doing useful work.
    Busy,
    /// Has work but cannot proceed, for reason number `r`: an index into the unit's
    /// [`super::Unit::stall_reasons`].
    Stalled(u8),
}

impl State {
    /// Slot of the state in an accumulator: idle 0, busy 1, stall reason r at 2 + r.
    #[inline]
    fn slot(self) -> usize {
        match self {
            State::Idle => 0,
            State::Busy => 1,
            State::Stalled(r) => 2 + r as usize,
        }
    }
}

/// The kernel's accumulator for one unit: the open interval and the closed totals.
#[derive(Clone, Debug)]
pub(crate) struct Tracker {
    state: State,
    since: Cycle,
    /// Cycles per state slot (see [`State::slot`]).
    totals: Vec<u64>,
}

impl Tracker {
    pub(crate) fn new(reasons: usize) -> Self {
        Self {
            state: State::Idle,
            since: 0,
            totals: vec![0; 2 + reasons],
        }
    }

    /// The unit is in `state` from cycle `now` on.
    #[inline]
    pub(crate) fn set(&mut self, state: State, now: Cycle) {
        if state == self.state {
            return;
        }
        self.close_at(now);
        self.state = state;
    }

    /// Adds the open interval up to `now` to its state and restarts it at `now`.
    fn close_at(&mut self, now: Cycle) {
        let slot = self.state.slot();
        if slot >= self.totals.len() {
            self.totals.resize(slot + 1, 0);
        }
        self.totals[slot] += now - self.since;
        self.since = now;
    }

    pub(crate) fn state(&self) -> State {
        self.state
    }

    /// The totals over `[0, end)`, with the stall reasons named by `names`.
    pub(crate) fn report(&self, end: Cycle, names: &[&'static str]) -> Activity {
        let mut t = self.clone();
        t.close_at(end.max(t.since));
        let stalled = t.totals[2..]
            .iter()
            .enumerate()
            .map(|(r, &c)| StallTime {
                reason: names.get(r).copied().unwrap_or("unnamed"),
                cycles: c,
            })
            .collect();
        Activity {
            cycles: end,
            idle_cycles: t.totals[0],
            busy_cycles: t.totals[1],
            stalled,
        }
    }
}

/// Cycles a unit spent stalled for one reason.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct StallTime {
    /// The reason, as the unit names it in [`super::Unit::stall_reasons`].
    pub reason: &'static str,
    /// Cycles stalled for it.
    pub cycles: u64,
}

/// Where a unit's cycles went over a run: every cycle of `[0, cycles)` is in exactly one
/// of idle, busy, or stalled for one reason. These are the activity factors of the energy
/// models and the bars of the thesis's utilization plots.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Activity {
    /// Length of the run in cycles.
    pub cycles: u64,
    /// Cycles with nothing to do.
    pub idle_cycles: u64,
    /// Cycles doing work.
    pub busy_cycles: u64,
    /// Cycles stalled, by reason (one entry per declared reason, in declaration order).
    pub stalled: Vec<StallTime>,
}

impl Activity {
    fn frac(&self, c: u64) -> f64 {
        if self.cycles == 0 {
            0.0
        } else {
            c as f64 / self.cycles as f64
        }
    }

    /// Fraction of the run busy.
    pub fn busy_fraction(&self) -> f64 {
        self.frac(self.busy_cycles)
    }

    /// Fraction of the run idle.
    pub fn idle_fraction(&self) -> f64 {
        self.frac(self.idle_cycles)
    }

    /// Fraction of the run stalled for `reason` (0 for an unknown reason).
    pub fn stall_fraction(&self, reason: &str) -> f64 {
        self.frac(
            self.stalled
                .iter()
                .filter(|s| s.reason == reason)
                .map(|s| s.cycles)
                .sum(),
        )
    }

    /// Cycles stalled for any reason.
    pub fn stalled_cycles(&self) -> u64 {
        self.stalled.iter().map(|s| s.cycles).sum()
    }

    /// Idle + busy + stalled cycles: equal to [`Self::cycles`] for every run.
    pub fn accounted_cycles(&self) -> u64 {
        self.idle_cycles + self.busy_cycles + self.stalled_cycles()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intervals_are_closed_at_each_change_and_at_the_end() {
        let mut t = Tracker::new(2);
        t.set(State::Busy, 3);
        t.set(State::Busy, 5); // no change
        t.set(State::Stalled(1), 10);
        t.set(State::Idle, 12);
        t.set(State::Stalled(0), 20);
        let a = t.report(25, &["in", "out"]);
        assert_eq!(a.idle_cycles, 3 + 8);
        assert_eq!(a.busy_cycles, 7);
        assert_eq!(
            a.stalled[0],
            StallTime {
                reason: "in",
                cycles: 5
            }
        );
        assert_eq!(
            a.stalled[1],
            StallTime {
                reason: "out",
                cycles: 2
            }
        );
        assert_eq!(a.accounted_cycles(), 25);
        let sum = a.busy_fraction()
            + a.idle_fraction()
            + a.stall_fraction("in")
            + a.stall_fraction("out");
        assert!((sum - 1.0).abs() < 1e-12);
        // An undeclared reason still gets its cycles.
        let mut t = Tracker::new(0);
        t.set(State::Stalled(3), 1);
        let a = t.report(4, &[]);
        assert_eq!(a.stalled_cycles(), 3);
        assert_eq!(a.accounted_cycles(), 4);
    }
}
