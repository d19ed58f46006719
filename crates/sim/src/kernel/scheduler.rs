//! The scheduler: steps awake units in id order and jumps over cycles in which none is.

use serde::Serialize;

use super::stats::{Activity, State, Tracker};
use super::unit::NEVER;
use super::{Ctx, Cycle, Memory, Unit, UnitId, Wake};

/// What the scheduler needs from a model's world: its memory port, if it has one, and its
/// state in words for a deadlock report.
pub trait World {
    /// The world's memory port (ticked by the scheduler), if any.
    fn memory(&mut self) -> Option<&mut Memory> {
        None
    }

    /// The world's channels and resources in words (deadlock reports).
    fn describe(&self) -> String {
        String::new()
    }
}

/// How to run.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Options {
    /// Step only awake units and jump over cycles in which none is (true), or step every
    /// unit in every cycle (false: the reference the skipping run must equal).
    pub skip: bool,
    /// Stop with [`KernelError::CycleLimit`] at this cycle.
    pub max_cycles: Cycle,
    /// With every unit asleep and requests in the memory, report a deadlock after this many
    /// cycles without a response (a memory that stopped answering).
    pub memory_timeout_cycles: Cycle,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            skip: true,
            max_cycles: Cycle::MAX - 1,
            memory_timeout_cycles: 1_000_000,
        }
    }
}

/// A unit's state when a run stopped without finishing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnitDump {
    /// Its name.
    pub name: String,
    /// Its last answer to the scheduler.
    pub last_wake: Wake,
    /// Its activity state (busy, stalled with the reason's name, idle).
    pub state: String,
    /// The unit's own description.
    pub detail: String,
}

/// Why a run did not finish.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum KernelError {
    /// No unit is awake, no event is pending, and work remains.
    #[error("deadlock at cycle {cycle}: {}", dump_text(.units, .world))]
    Deadlock {
        /// The cycle after the last one stepped.
        cycle: Cycle,
        /// Every unit's state.
        units: Vec<UnitDump>,
        /// The world's description (channels, memory).
        world: String,
    },
    /// The run reached [`Options::max_cycles`].
    #[error("cycle limit {0} reached")]
    CycleLimit(Cycle),
    /// The world's memory port was not at cycle 0 when the run started.
    #[error("memory port at cycle {0} at the start of a run (must be 0)")]
    MemoryNotAtStart(Cycle),
}

fn dump_text(units: &[UnitDump], world: &str) -> String {
    let mut s = String::new();
    for u in units {
        s += &format!("[{}: {:?}, {}", u.name, u.last_wake, u.state);
        if !u.detail.is_empty() {
            s += ", ";
            s += &u.detail;
        }
        s += "] ";
    }
    s + world
}

/// A unit's results over a run.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct UnitReport {
    /// Its name.
    pub name: String,
    /// Where its cycles went.
    pub activity: Activity,
    /// Its own counters ([`Unit::counters`]).
    pub counters: Vec<(&'static str, u64)>,
}

/// The results of a run. Equal, field for field, with and without skipping; only
/// [`Self::steps`] and [`Self::stepped_cycles`] (the kernel's own work) differ.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct RunReport {
    /// Cycles simulated: one past the last cycle in which a unit had something to do.
    pub cycles: Cycle,
    /// Per unit, in id order.
    pub units: Vec<UnitReport>,
    /// Steps the scheduler made, per unit.
    pub steps: Vec<u64>,
    /// Cycles in which at least one unit stepped.
    pub stepped_cycles: u64,
}

impl RunReport {
    /// True when the simulated results (cycles and per-unit reports) are equal.
    pub fn same_results(&self, other: &RunReport) -> bool {
        self.cycles == other.cycles && self.units == other.units
    }
}

/// Owns the units of a model and runs them over a world `W`.
///
/// # Order and time
/// Cycle `t` proceeds in three parts:
/// 1. every unit due at `t` steps, in ascending [`UnitId`] (registration order); a unit is
///    due if it asked for `t` ([`Wake::Next`] / [`Wake::At`]) or an event for `t` reached
///    it (in the no-skip mode every unit is due in every cycle);
/// 2. the memory port (if the world has one) ticks to `t + 1`; responses that complete are
///    routed to their units, which become due at `t + 1`;
/// 3. the next cycle is `t + 1` if the memory has requests in flight (it is ticked cycle by
///    cycle until a response arrives or a unit is due), else the earliest wake or event
///    time of any unit, jumped to at once with the memory's `tick_many`.
///
/// Nothing a unit does in cycle `t` is visible to another unit in cycle `t` through the
/// kernel's channels ([`super::LatencyFifo`]: pushes from `t + latency`, freed slots from
/// `t + 1`; events from `t + 1`). Shared resources a unit calls directly (an arbiter, a
/// cache, the memory port's queue) are used in step order.
pub struct Scheduler<W> {
    units: Vec<Box<dyn Unit<W>>>,
    options: Options,
}

impl<W: World> Scheduler<W> {
    /// A scheduler with no units.
    pub fn new(options: Options) -> Self {
        Self {
            units: Vec::new(),
            options,
        }
    }

    /// Adds a unit; returns its id (ids count up from 0 in the order of adding).
    pub fn add(&mut self, unit: Box<dyn Unit<W>>) -> UnitId {
        self.units.push(unit);
        UnitId((self.units.len() - 1) as u32)
    }

    /// The id the next [`Self::add`] will return (to wire channels before adding).
    pub fn next_id(&self) -> UnitId {
        UnitId(self.units.len() as u32)
    }

    /// The unit `id`.
    pub fn unit(&self, id: UnitId) -> &dyn Unit<W> {
        &*self.units[id.index()]
    }

    /// Number of units.
    pub fn len(&self) -> usize {
        self.units.len()
    }

    /// True when no unit was added.
    pub fn is_empty(&self) -> bool {
        self.units.is_empty()
    }

    /// The options.
    pub fn options(&self) -> &Options {
        &self.options
    }

    /// Runs from cycle 0 until the run finishes (every unit done, nothing pending) or
    /// cannot progress.
    pub fn run(&mut self, world: &mut W) -> Result<RunReport, KernelError> {
        let n = self.units.len();
        let skip = self.options.skip;
        let mut cx = Ctx::new(n);
        cx.activity = self
            .units
            .iter()
            .map(|u| Tracker::new(u.stall_reasons().len()))
            .collect();
        if let Some(m) = world.memory() {
            if m.cycle() != 0 {
                return Err(KernelError::MemoryNotAtStart(m.cycle()));
            }
        }
        let mut wake: Vec<Cycle> = vec![0; n];
        let mut last = vec![Wake::Next; n];
        let mut due = vec![false; n];
        let mut steps = vec![0u64; n];
        let mut stepped_cycles = 0u64;
        let mut now: Cycle = 0;
        loop {
            if now >= self.options.max_cycles {
                return Err(KernelError::CycleLimit(now));
            }
            cx.now = now;
            // 1. Who is due: consume the events for this cycle first, so that events made
            //    while stepping (all for later cycles) land in an empty slot.
            for i in 0..n {
                let ev = cx.ev[i] <= now;
                if ev {
                    cx.ev[i] = NEVER;
                }
                due[i] = !skip || ev || wake[i] <= now;
            }
            while let Some(&std::cmp::Reverse((t, u))) = cx.overflow.peek() {
                if t > now {
                    break;
                }
                cx.overflow.pop();
                due[u as usize] = true;
            }
            let mut any = false;
            for i in 0..n {
                if !due[i] {
                    continue;
                }
                any = true;
                cx.me = UnitId(i as u32);
                let w = self.units[i].step(world, &mut cx);
                steps[i] += 1;
                last[i] = w;
                wake[i] = match w {
                    Wake::Next => now + 1,
                    Wake::At(c) => c.max(now + 1),
                    Wake::OnEvent | Wake::Done => NEVER,
                };
            }
            stepped_cycles += any as u64;
            // 3. The next cycle anything is due.
            let mut next = NEVER;
            for (w, e) in wake.iter().zip(&cx.ev) {
                next = next.min(*w).min(*e);
            }
            if let Some(&std::cmp::Reverse((t, _))) = cx.overflow.peek() {
                next = next.min(t);
            }
            let in_flight = world.memory().map_or(0, |m| m.in_flight());
            if next == NEVER && in_flight == 0 {
                let end = now + 1;
                if let Some(m) = world.memory() {
                    m.tick_many(1);
                }
                return self.finish(world, &cx, &last, end, steps, stepped_cycles);
            }
            // 2. The memory, up to the next cycle.
            // (Never past the cycle limit: a jump there is reported, not ticked through.)
            let target = if skip { next } else { now + 1 }.min(self.options.max_cycles);
            now = match world.memory() {
                None => target,
                Some(m) => {
                    let mut t = now;
                    let mut target = target;
                    loop {
                        if m.in_flight() == 0 {
                            // Nothing can complete: jump (target is finite here, since
                            // either a unit is due or a response was just routed).
                            m.tick_many(target - t);
                            break target;
                        }
                        t += 1;
                        if m.tick_and_route(&mut cx) {
                            target = target.min(t);
                        }
                        if t >= target {
                            break t;
                        }
                        if next == NEVER && t - cx.now > self.options.memory_timeout_cycles {
                            return Err(self.deadlock(world, &cx, &last, t));
                        }
                    }
                }
            };
        }
    }

    fn finish(
        &self,
        world: &mut W,
        cx: &Ctx,
        last: &[Wake],
        end: Cycle,
        steps: Vec<u64>,
        stepped_cycles: u64,
    ) -> Result<RunReport, KernelError> {
        let unread = world.memory().map_or(0, |m| m.outstanding());
        if unread > 0 || last.iter().any(|w| *w != Wake::Done) {
            return Err(self.deadlock(world, cx, last, end));
        }
        let units = self
            .units
            .iter()
            .zip(&cx.activity)
            .map(|(u, t)| UnitReport {
                name: u.name().to_string(),
                activity: t.report(end, u.stall_reasons()),
                counters: u.counters(),
            })
            .collect();
        Ok(RunReport {
            cycles: end,
            units,
            steps,
            stepped_cycles,
        })
    }

    fn deadlock(&self, world: &mut W, cx: &Ctx, last: &[Wake], cycle: Cycle) -> KernelError {
        let units = self
            .units
            .iter()
            .enumerate()
            .map(|(i, u)| {
                let state = match cx.activity[i].state() {
                    State::Idle => "idle".to_string(),
                    State::Busy => "busy".to_string(),
                    State::Stalled(r) => format!(
                        "stalled on {}",
                        u.stall_reasons().get(r as usize).copied().unwrap_or("?")
                    ),
                };
                UnitDump {
                    name: u.name().to_string(),
                    last_wake: last[i],
                    state,
                    detail: u.describe(world),
                }
            })
            .collect();
        let mut w = world.describe();
        if let Some(m) = world.memory() {
            if !w.is_empty() {
                w += "; ";
            }
            w += &format!("{m:?}");
        }
        KernelError::Deadlock {
            cycle,
            units,
            world: w,
        }
    }
}
