//! The simulation kernel every cycle-level model shares (`shared/DESIGN.md`, "Simulator
//! conventions"): units that step at a cycle and say when they next need the clock, a
//! scheduler that jumps over cycles in which no unit is awake (exactly: a run with jumping
//! equals one that steps every unit every cycle), latency FIFOs with back-pressure, a
//! round-robin arbiter, tag pools and MSHRs, a non-blocking set-associative cache,
//! busy/stall interval statistics, and the memory port reached through the kernel.
//!
//! One concept per file:
//! - [`unit`]: the [`Unit`] trait, [`Wake`], [`UnitId`], the step context [`Ctx`];
//! - [`scheduler`]: [`Scheduler`], [`World`], [`Options`], [`RunReport`], [`KernelError`];
//! - [`fifo`]: the latency FIFO [`LatencyFifo`];
//! - [`arbiter`]: the round-robin arbiter [`RoundRobin`];
//! - [`tags`]: tag pools [`TagPool`] and MSHRs [`MshrFile`];
//! - [`cache`]: the [`Cache`] and its [`CacheConfig`];
//! - [`stats`]: unit [`State`]s and [`Activity`];
//! - [`memory`]: the world's memory port, [`Memory`].
//!
//! `docs/sim-kernel.md` describes the model of time, the step order and visibility rules,
//! how to write a unit, the cache's semantics and every statistic.

pub mod arbiter;
pub mod cache;
pub mod fifo;
pub mod memory;
pub mod scheduler;
pub mod stats;
pub mod tags;
pub mod unit;

#[cfg(test)]
pub(crate) mod tests;

pub use arbiter::{ArbiterStats, Offer, RoundRobin};
pub use cache::{Access, Cache, CacheConfig, CacheStats, Refusal, WritePolicy};
pub use fifo::{LatencyFifo, LatencyFifoStats};
pub use memory::Memory;
pub use scheduler::{KernelError, Options, RunReport, Scheduler, UnitDump, UnitReport, World};
pub use stats::{Activity, StallTime, State};
pub use tags::{MshrFile, MshrRefusal, MshrStats, TagPool, TagPoolStats};
pub use unit::{Ctx, Unit, UnitId, Wake, NEVER};

/// The code in `docs/sim-kernel.md`, compiled and run as a doctest
/// (`cargo test -p sim --doc`).
#[cfg(doctest)]
#[doc = include_str!("../../../../docs/sim-kernel.md")]
pub struct SimKernelDoc;

/// A cycle number of the kernel's clock.
pub type Cycle = u64;

/// A kernel component configured with values it cannot work with.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{what}: {reason}")]
pub struct ConfigError {
    /// The component.
    pub what: String,
    /// What is wrong.
    pub reason: String,
}

impl ConfigError {
    pub(crate) fn new(what: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            what: what.into(),
            reason: reason.into(),
        }
    }
}
