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

/// The kernel's accumulator for one unit: the open interval and the closed totals, and
/// optionally the totals per window of `window` cycles (for utilization plots over time).
#[derive(Clone, Debug)]
pub(crate) struct Tracker {
    state: State,
    since: Cycle,
    /// Cycles per state slot (see [`State::slot`]).
    totals: Vec<u64>,
    /// Window length in cycles (0: no windows).
    window: Cycle,
    /// Cycles per state slot in each window.
    windows: Vec<Vec<u64>>,
}

impl Tracker {
    pub(crate) fn new(reasons: usize) -> Self {
        Self::with_windows(reasons, 0)
    }

    /// A tracker that also splits the run into windows of `window` cycles (0: none).
    pub(crate) fn with_windows(reasons: usize, window: Cycle) -> Self {
        Self {
            state: State::Idle,
            since: 0,
            totals: vec![0; 2 + reasons],
            window,
            windows: Vec::new(),
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
        // Split the interval at window boundaries (one step per window it covers; no
        // windows when `window` is 0).
        let mut t = self.since;
        while t < now {
            let Some(k) = t.checked_div(self.window) else {
                break;
            };
            let k = k as usize;
            let end = ((k as Cycle + 1) * self.window).min(now);
            if k >= self.windows.len() {
                self.windows.resize_with(k + 1, Vec::new);
            }
            let w = &mut self.windows[k];
            if slot >= w.len() {
                w.resize(slot.max(1) + 1, 0);
            }
            w[slot] += end - t;
            t = end;
        }
        self.since = now;
    }

    pub(crate) fn state(&self) -> State {
        self.state
    }

    /// The totals over `[0, end)`, with the stall reasons named by `names`, and the
    /// totals per window (empty without windows).
    pub(crate) fn report(&self, end: Cycle, names: &[&'static str]) -> (Activity, Vec<Activity>) {
        let mut t = self.clone();
        t.close_at(end.max(t.since));
        let slots = t.totals.len();
        let activity = |totals: &[u64], cycles: Cycle| {
            let stalled = (2..slots)
                .map(|s| StallTime {
                    reason: names.get(s - 2).copied().unwrap_or("unnamed"),
                    cycles: totals.get(s).copied().unwrap_or(0),
                })
                .collect();
            Activity {
                cycles,
                idle_cycles: totals.first().copied().unwrap_or(0),
                busy_cycles: totals.get(1).copied().unwrap_or(0),
                stalled,
            }
        };
        let mut windows = Vec::new();
        if t.window > 0 {
            let n = end.div_ceil(t.window) as usize;
            for k in 0..n {
                let start = k as Cycle * t.window;
                let len = t.window.min(end - start);
                windows.push(activity(t.windows.get(k).map_or(&[][..], |w| w), len));
            }
        }
        (activity(&t.totals, end), windows)
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
        let (a, _) = t.report(25, &["in", "out"]);
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
        let (a, _) = t.report(4, &[]);
        assert_eq!(a.stalled_cycles(), 3);
        assert_eq!(a.accounted_cycles(), 4);
    }

    #[test]
    fn windows_split_intervals_at_their_boundaries() {
        let mut t = Tracker::with_windows(1, 10);
        t.set(State::Busy, 5);
        t.set(State::Stalled(0), 27); // busy 5..27 covers three windows
        t.set(State::Idle, 31);
        let (total, w) = t.report(34, &["x"]);
        assert_eq!(w.len(), 4);
        let busy: Vec<u64> = w.iter().map(|a| a.busy_cycles).collect();
        assert_eq!(busy, vec![5, 10, 7, 0]);
        assert_eq!(w[2].stalled[0].cycles, 3);
        assert_eq!(w[3].stalled[0].cycles, 1);
        assert_eq!(w[3].cycles, 4);
        for a in &w {
            assert_eq!(a.accounted_cycles(), a.cycles);
        }
        assert_eq!(
            w.iter().map(|a| a.busy_cycles).sum::<u64>(),
            total.busy_cycles
        );
    }
}
