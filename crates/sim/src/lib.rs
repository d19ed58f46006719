//! Cycle-level models of the hardware of the thesis, following the conventions of
//! `shared/DESIGN.md`: each unit implements the simulation kernel's [`kernel::Unit`] and says
//! when it next needs the clock, units talk through bounded [`kernel::LatencyFifo`]s whose
//! capacities are configuration, and every byte of memory traffic goes through one
//! [`dram::MemoryPort`], so it is counted in one place.
//!
//! - [`clock`]: exact crossing between two clock domains of any periods.
//! - [`fifo`]: the FIFO row of MergeTree's reports (name, capacity, statistics).
//! - [`kernel`]: the simulation kernel: units with wake times, the skipping scheduler,
//!   latency FIFOs, arbiter, tag pools and MSHRs, caches, interval statistics.
//! - [`dram`]: the memory-port interface and its backends.
//! - [`energy`]: energy, leakage and area of SRAMs and FPUs (CACTI, Horowitz).
//! - [`analytic`]: analytic models of the builders MergeTree is compared with.
//! - [`mergetree`]: the MergeTree HLBVH builder of \[P1\] and \[P2\].
//! - [`rtunit`]: the ray-tracing accelerator of \[P4\] (TRV and IST pipelines, caches).
//! - [`system`]: system energy per frame, build plus trace (\[P2\] §6.4), and tree
//!   update policies over animations.
//! - [`thesis`]: the thesis's published figures the models are compared with.
#![warn(missing_docs)]

pub mod analytic;
pub mod clock;
pub mod dram;
pub mod energy;
pub mod fifo;
pub mod kernel;
pub mod mergetree;
pub mod rtunit;
pub mod system;
pub mod thesis;

#[cfg(test)]
mod pinned;
