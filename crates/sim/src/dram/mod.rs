//! The memory port: the one interface through which every simulated unit reaches DRAM.
//!
//! A unit sends [`MemRequest`]s of any size at its own clock; the port splits them into
//! the backend's bursts, runs the backend's clock in exact proportion to the unit's
//! ([`crate::clock::ClockCrossing`]), and hands back one [`MemResponse`] per request when
//! its last burst has completed. Every byte is counted in [`MemStats`].
//!
//! Backends (chosen by configuration, `shared/DESIGN.md`, after Ramulator 2's separation of
//! interface and implementations):
//! - [`simple::SimpleDram`]: a peak-bandwidth-plus-fixed-latency model for quick what-ifs
//!   and unit tests;
//! - a DRAMsim3 backend (cycle-accurate timing, row hits and misses, refresh, commands).

pub mod simple;

use serde::Serialize;

use crate::clock::PeriodFs;
use simple::{SimpleDram, SimpleDramConfig};

/// The named memory systems of the thesis, with their peak bandwidths in bytes per second:
/// [P2] 6.2 "slow", "medium" and "fast", and the 2x32-bit system of [P3] 5.3 and [P4] 3.2.
pub const MEMORY_SYSTEMS: &[(&str, u64, &str)] = &[
    (
        "lpddr3-1600-1x64",
        12_800_000_000,
        "one 64-bit LPDDR3-1600 channel, 12.8 GB/s ([P2] 6.2 slow)",
    ),
    (
        "lpddr3-1600-2x64",
        25_600_000_000,
        "two 64-bit LPDDR3-1600 channels, 25.6 GB/s ([P2] 6.2 medium)",
    ),
    (
        "lpddr3-1333-4x64",
        42_656_000_000,
        "four 64-bit LPDDR3-1333 channels, 42.7 GB/s ([P2] 6.2 fast)",
    ),
    (
        "lpddr3-1600-2x32",
        12_800_000_000,
        "two 32-bit LPDDR3-1600 channels, 12.8 GB/s ([P3] 5.3, [P4] 3.2)",
    ),
];

/// Errors from choosing or configuring a memory backend.
#[derive(Debug, thiserror::Error)]
pub enum DramError {
    /// The name matches no memory system.
    #[error("unknown memory system '{name}' (known: {known})")]
    UnknownSystem {
        /// The name asked for.
        name: String,
        /// The names that exist, comma-separated.
        known: String,
    },
}

/// Opens the memory system `name`, driven by a unit clock of period `unit_period_fs`.
///
/// `simple:NAME` gives the [`SimpleDram`] model with NAME's peak bandwidth. A bare NAME
/// gives the cycle-accurate backend for that system.
// The cycle-accurate (DRAMsim3) backend is not wired in yet; until it is, a bare NAME also
// gives the simple model.
pub fn open(name: &str, unit_period_fs: PeriodFs) -> Result<Box<dyn MemoryPort>, DramError> {
    let bare = name.strip_prefix("simple:").unwrap_or(name);
    let Some(&(_, peak_bytes_per_s, _)) = MEMORY_SYSTEMS.iter().find(|(n, _, _)| *n == bare) else {
        let known = MEMORY_SYSTEMS
            .iter()
            .map(|(n, _, _)| *n)
            .collect::<Vec<_>>()
            .join(", ");
        return Err(DramError::UnknownSystem {
            name: name.to_string(),
            known,
        });
    };
    let config = SimpleDramConfig {
        unit_period_fs,
        peak_bytes_per_s,
        ..SimpleDramConfig::lpddr3_1600_1x64_like()
    };
    Ok(Box::new(SimpleDram::new(config)))
}

/// Direction of a memory access.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub enum AccessKind {
    /// Data flows from DRAM to the unit.
    Read,
    /// Data flows from the unit to DRAM.
    Write,
}

/// A request from a unit: `bytes` starting at byte address `addr`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemRequest {
    /// Chosen by the unit; returned unchanged in the response.
    pub tag: u64,
    /// First byte address.
    pub addr: u64,
    /// Length in bytes (at least 1). The port splits it into bursts.
    pub bytes: u32,
    /// Read or write.
    pub kind: AccessKind,
}

/// A completed request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemResponse {
    /// The request's tag.
    pub tag: u64,
    /// Read or write.
    pub kind: AccessKind,
    /// Unit cycle at which the port accepted the request.
    pub accepted_cycle: u64,
    /// Unit cycle at which its last burst completed.
    pub completed_cycle: u64,
}

/// Traffic, command and timing counts of one run. Fields a backend cannot observe stay
/// zero (the simple model has no rows or commands).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MemStats {
    /// Bytes moved from DRAM (whole bursts).
    pub bytes_read: u64,
    /// Bytes moved to DRAM (whole bursts).
    pub bytes_written: u64,
    /// Read requests accepted.
    pub read_requests: u64,
    /// Write requests accepted.
    pub write_requests: u64,
    /// Read bursts completed.
    pub read_bursts: u64,
    /// Write bursts completed.
    pub write_bursts: u64,
    /// Bursts that found their row open.
    pub row_hits: u64,
    /// Bursts that needed an activation.
    pub row_misses: u64,
    /// ACT commands.
    pub act_commands: u64,
    /// RD commands.
    pub read_commands: u64,
    /// WR commands.
    pub write_commands: u64,
    /// REF commands.
    pub refresh_commands: u64,
    /// Unit clock cycles simulated.
    pub unit_cycles: u64,
    /// DRAM clock cycles simulated.
    pub dram_cycles: u64,
    /// DRAM energy in picojoules, where the backend has an energy model.
    pub energy_pj: Option<DramEnergy>,
}

impl MemStats {
    /// Fraction of the unit cycles simulated in which the data bus could have carried the
    /// bytes moved: `(bytes_read + bytes_written) / (peak bytes per cycle * cycles)`.
    pub fn bus_utilization(&self, peak_bytes_per_unit_cycle: f64) -> f64 {
        if self.unit_cycles == 0 || peak_bytes_per_unit_cycle <= 0.0 {
            return 0.0;
        }
        (self.bytes_read + self.bytes_written) as f64
            / (peak_bytes_per_unit_cycle * self.unit_cycles as f64)
    }
}

/// DRAM energy by component, in picojoules.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DramEnergy {
    /// Activations and precharges.
    pub act_pre_pj: f64,
    /// Read bursts.
    pub read_pj: f64,
    /// Write bursts.
    pub write_pj: f64,
    /// Refreshes.
    pub refresh_pj: f64,
    /// Background (standby) power integrated over the run.
    pub background_pj: f64,
}

impl DramEnergy {
    /// Sum of all components.
    pub fn total_pj(&self) -> f64 {
        self.act_pre_pj + self.read_pj + self.write_pj + self.refresh_pj + self.background_pj
    }
}

/// The interface every DRAM backend implements, seen from a unit's clock domain.
///
/// The contract, which each backend's tests check:
/// - [`Self::send`] either accepts the request (it will complete later, exactly once) or
///   gives it back unchanged because the controller's queue is full (back-pressure);
/// - [`Self::tick`] advances one unit cycle; responses become visible through
///   [`Self::pop_response`] at the cycle their last burst completes, or later;
/// - the same sequence of calls gives the same responses and statistics (determinism).
pub trait MemoryPort {
    /// Short name of the backend and configuration, for reports.
    fn name(&self) -> String;

    /// Bytes in one burst (the transaction size); requests are split into these.
    fn burst_bytes(&self) -> u32;

    /// Peak data-bus bandwidth in bytes per unit cycle.
    fn peak_bytes_per_unit_cycle(&self) -> f64;

    /// Offers a request at the current cycle. `Err` gives it back when it cannot be
    /// accepted now.
    ///
    /// # Panics
    /// On a request of zero bytes (a unit bug, not a data condition).
    fn send(&mut self, request: MemRequest) -> Result<(), MemRequest>;

    /// Advances one unit clock cycle.
    fn tick(&mut self);

    /// The next completed request, if any.
    fn pop_response(&mut self) -> Option<MemResponse>;

    /// The current unit cycle (number of ticks so far).
    fn cycle(&self) -> u64;

    /// Requests accepted but not yet returned by [`Self::pop_response`].
    fn outstanding(&self) -> usize;

    /// Counts so far.
    fn stats(&self) -> MemStats;

    /// Advances `cycles` unit cycles. Backends may override this with a faster skip when
    /// nothing is outstanding; the result must equal `cycles` calls of [`Self::tick`].
    fn tick_many(&mut self, cycles: u64) {
        for _ in 0..cycles {
            self.tick();
        }
    }

    /// Ticks until every outstanding request has completed (responses stay queued for
    /// [`Self::pop_response`]); returns the number of cycles that took.
    fn drain(&mut self) -> u64 {
        let start = self.cycle();
        while self.outstanding() > self.completed_waiting() {
            self.tick();
        }
        self.cycle() - start
    }

    /// Completed responses not yet popped.
    fn completed_waiting(&self) -> usize;
}

/// Number of bursts of `burst_bytes` that a request touches (bursts are aligned).
pub fn bursts_of(addr: u64, bytes: u32, burst_bytes: u32) -> u64 {
    debug_assert!(bytes > 0 && burst_bytes > 0);
    let b = burst_bytes as u64;
    let first = addr / b;
    let last = (addr + bytes as u64 - 1) / b;
    last - first + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_knows_every_named_system_and_rejects_others() {
        for (name, bw, _) in MEMORY_SYSTEMS {
            let port = open(&format!("simple:{name}"), 1_000_000).unwrap();
            assert!((port.peak_bytes_per_unit_cycle() - *bw as f64 * 1e-9).abs() < 1e-9);
        }
        let err = open("ddr9", 1_000_000).err().unwrap().to_string();
        assert!(
            err.contains("ddr9") && err.contains("lpddr3-1600-1x64"),
            "{err}"
        );
    }

    #[test]
    fn bursts_count_alignment() {
        assert_eq!(bursts_of(0, 64, 64), 1);
        assert_eq!(bursts_of(32, 64, 64), 2);
        assert_eq!(bursts_of(0, 65, 64), 2);
        assert_eq!(bursts_of(63, 1, 64), 1);
        assert_eq!(bursts_of(0, 256, 32), 8);
    }
}
