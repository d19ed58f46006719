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
//! - [`lpddr::LpddrPort`]: Arbor's event-driven model of DRAMsim3's controller, with the
//!   same commands at the same DRAM cycles as DRAMsim3 for the shipped configurations
//!   (cross-checked request by request) but several times faster: the default;
//! - [`dramsim3::Dramsim3Port`]: DRAMsim3 itself, the reference: cycle-accurate timing with
//!   row hits and misses, refresh and command counts.
//!
//! Both cycle-accurate backends share one memory port ([`port::BurstPort`]: staging per
//! channel and direction, clock crossing) and give energy from their command counts
//! ([`energy`]).
//!
//! [`open`] picks one by name: a bare system name (one of [`MEMORY_SYSTEMS`] or
//! [`WHAT_IF_SYSTEMS`]) gives Arbor's model with Arbor's configuration for it (its
//! `name()` is `lpddr(NAME)`); `dramsim3:NAME` gives DRAMsim3 with the same configuration
//! (`dramsim3(NAME)`); `lpddr:NAME` is the bare name spelled out; `simple:NAME` gives the
//! simple model with NAME's peak bandwidth; `simple:bw=BYTES_PER_S,lat=NS` (with optional
//! `burst=BYTES` and `queue=REQUESTS`) a simple model of any bandwidth;
//! `lpddr:NAME,KEY=VALUE,...` (or `NAME,KEY=VALUE,...`) Arbor's model with configuration
//! keys overridden, for what-ifs: any key of NAME's file and the policy keys only the model
//! reads ([`LPDDR_WHAT_IF_KEYS`]), each defaulting to DRAMsim3's behaviour.

#[cfg(test)]
mod crosscheck;
pub mod dramsim3;
pub mod energy;
pub mod lpddr;
pub mod port;
pub mod simple;
pub mod stream;

use serde::Serialize;

use crate::clock::PeriodFs;
use simple::{SimpleDram, SimpleDramConfig};

/// The named memory systems of the thesis, with their peak bandwidths in bytes per second:
/// \[P2\] 6.2 "slow", "medium" and "fast", and the 2x32-bit system of \[P3\] 5.3 and \[P4\] 3.2.
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

/// Memory systems for what-if studies that the thesis does not use, with their peak
/// bandwidths in bytes per second.
pub const WHAT_IF_SYSTEMS: &[(&str, u64, &str)] = &[(
    "lpddr4-3200-4x16",
    25_600_000_000,
    "four x16 LPDDR4-3200 channels, 25.6 GB/s (what-if)",
)];

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
    /// A `simple:` specification that cannot be parsed.
    #[error("bad simple memory specification '{spec}': {reason}")]
    BadSpec {
        /// The specification.
        spec: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A backend configuration that cannot be used.
    #[error("memory configuration: {0}")]
    Config(String),
    /// A file the backend needs could not be written or read.
    #[error("memory backend i/o: {0}")]
    Io(String),
}

/// Opens the memory system `name`, driven by a unit clock of period `unit_period_fs`.
///
/// A bare NAME (or `lpddr:NAME`) gives Arbor's controller model ([`lpddr`]) with Arbor's
/// configuration for that system; `dramsim3:NAME` gives DRAMsim3 with the same
/// configuration, the reference the model is checked against; `simple:NAME` gives the [`SimpleDram`] model with NAME's peak bandwidth;
/// `simple:bw=25.6e9,lat=40[,burst=64][,queue=32]` a simple model of that bandwidth in
/// bytes per second and latency in nanoseconds.
pub fn open(name: &str, unit_period_fs: PeriodFs) -> Result<Box<dyn MemoryPort>, DramError> {
    if unit_period_fs == 0 {
        return Err(DramError::Config("unit clock period of zero".into()));
    }
    if let Some(rest) = name.strip_prefix("simple:") {
        if rest.contains('=') {
            return Ok(Box::new(SimpleDram::new(simple_spec(
                rest,
                unit_period_fs,
            )?)));
        }
        let &(_, peak_bytes_per_s, _) = known_system(rest, name)?;
        let config = SimpleDramConfig {
            unit_period_fs,
            peak_bytes_per_s,
            ..SimpleDramConfig::lpddr3_1600_1x64_like()
        };
        return Ok(Box::new(SimpleDram::new(config)));
    }
    if let Some(rest) = name.strip_prefix("dramsim3:") {
        known_system(rest, name)?;
        return Ok(Box::new(dramsim3::Dramsim3Port::open(
            rest,
            unit_period_fs,
        )?));
    }
    let bare = name.strip_prefix("lpddr:").unwrap_or(name);
    if let Some((system, options)) = bare.split_once(',') {
        known_system(system, name)?;
        let config = what_if_config(system, options, name)?;
        return Ok(Box::new(lpddr::LpddrPort::with_config(
            config,
            unit_period_fs,
        )?));
    }
    known_system(bare, name)?;
    Ok(Box::new(lpddr::LpddrPort::open(bare, unit_period_fs)?))
}

/// Keys of an `lpddr:NAME,KEY=VALUE,...` what-if that only Arbor's controller model reads
/// (see `lpddr`): `write_drain` (`dramsim3`, the default, or `watermark`),
/// `write_high_watermark` and `write_low_watermark` (percent, 80 and 20), `row_hit_cap`
/// (4), `bank_xor` (0; 1 XORs the bank with the row's low bits). Any key of the system's configuration file may be given too (for example
/// `trans_queue_size`, `cmd_queue_size`, `address_mapping`).
pub const LPDDR_WHAT_IF_KEYS: &[&str] = &[
    "write_drain",
    "write_high_watermark",
    "write_low_watermark",
    "row_hit_cap",
    "bank_xor",
];

/// The configuration of system `system` with the `KEY=VALUE` pairs of `options` (comma
/// separated) in front of its own lines, so that they take precedence. Leaked: a what-if
/// is opened once per run.
fn what_if_config(
    system: &str,
    options: &str,
    asked: &str,
) -> Result<&'static dramsim3::SystemConfig, DramError> {
    let base = dramsim3::system(system).ok_or_else(|| DramError::UnknownSystem {
        name: asked.to_string(),
        known: dramsim3::SYSTEMS
            .iter()
            .map(|s| s.name)
            .collect::<Vec<_>>()
            .join(", "),
    })?;
    let mut ini = String::new();
    for kv in options.split(',') {
        let (k, v) = kv
            .split_once('=')
            .map(|(k, v)| (k.trim(), v.trim()))
            .filter(|(k, v)| !k.is_empty() && !v.is_empty())
            .ok_or_else(|| DramError::Config(format!("{asked}: option '{kv}' is not KEY=VALUE")))?;
        if base.value(k).is_none() && !LPDDR_WHAT_IF_KEYS.contains(&k) {
            return Err(DramError::Config(format!(
                "{asked}: unknown key '{k}' (a key of {system}'s configuration or one of {})",
                LPDDR_WHAT_IF_KEYS.join(", ")
            )));
        }
        ini.push_str(&format!("{k} = {v}\n"));
    }
    ini.push_str(base.ini);
    Ok(Box::leak(Box::new(dramsim3::SystemConfig {
        name: base.name,
        ini: Box::leak(ini.into_boxed_str()),
        memspec: base.memspec,
    })))
}

/// `name` with the what-if option `key=value` of an `lpddr:NAME,KEY=VALUE,...` system
/// (see [`open`]), replacing an earlier value of `key`; a `simple:` or `dramsim3:` name
/// takes no options. An `address_mapping` must name the six fields `ch`, `ra`, `bg`,
/// `ba`, `ro` and `co` once each, most significant first (DRAMsim3's syntax).
pub fn with_option(name: &str, key: &str, value: &str) -> Result<String, DramError> {
    let (key, value) = (key.trim(), value.trim());
    if name.starts_with("simple:") || name.starts_with("dramsim3:") {
        return Err(DramError::Config(format!(
            "{name}: only Arbor's controller model takes the option '{key}'"
        )));
    }
    if key.is_empty() || value.is_empty() || key.contains([',', '=']) || value.contains([',', '='])
    {
        return Err(DramError::Config(format!(
            "bad memory option '{key}={value}'"
        )));
    }
    if key == "address_mapping" {
        let mut fields: Vec<&str> = (0..value.len() / 2)
            .filter_map(|i| value.get(2 * i..2 * i + 2))
            .collect();
        fields.sort_unstable();
        if value.len() != 12 || fields != ["ba", "bg", "ch", "co", "ra", "ro"] {
            return Err(DramError::Config(format!(
                "address mapping '{value}': expected the fields ch, ra, bg, ba, ro and co once \
                 each, most significant first (e.g. rorabgbacoch)"
            )));
        }
    }
    let mut parts = name.split(',');
    let system = parts.next().unwrap_or_default();
    let mut out = system.to_string();
    for kv in parts.filter(|kv| kv.split('=').next().map(str::trim) != Some(key)) {
        out.push(',');
        out.push_str(kv);
    }
    out.push_str(&format!(",{key}={value}"));
    Ok(out)
}

/// The memory system of `name` without its what-if options (`lpddr3-1600-2x64` for
/// `lpddr:lpddr3-1600-2x64,address_mapping=...`).
pub fn base_system(name: &str) -> &str {
    let system = name.split(',').next().unwrap_or_default();
    system.strip_prefix("lpddr:").unwrap_or(system)
}

/// Every system name [`open`] accepts bare, with peak bandwidth and description.
pub fn all_systems() -> impl Iterator<Item = &'static (&'static str, u64, &'static str)> {
    MEMORY_SYSTEMS.iter().chain(WHAT_IF_SYSTEMS)
}

fn known_system(
    bare: &str,
    asked: &str,
) -> Result<&'static (&'static str, u64, &'static str), DramError> {
    all_systems()
        .find(|(n, _, _)| *n == bare)
        .ok_or_else(|| DramError::UnknownSystem {
            name: asked.to_string(),
            known: all_systems()
                .map(|(n, _, _)| *n)
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// Parses `bw=...,lat=...[,burst=...][,queue=...]` into a simple-model configuration.
fn simple_spec(spec: &str, unit_period_fs: PeriodFs) -> Result<SimpleDramConfig, DramError> {
    let bad = |reason: String| DramError::BadSpec {
        spec: format!("simple:{spec}"),
        reason,
    };
    let mut config = SimpleDramConfig {
        unit_period_fs,
        ..SimpleDramConfig::lpddr3_1600_1x64_like()
    };
    let mut have_bw = false;
    for part in spec.split(',') {
        let (key, value) = part
            .split_once('=')
            .ok_or_else(|| bad(format!("'{part}' is not key=value")))?;
        let number: f64 = value
            .trim()
            .parse()
            .map_err(|_| bad(format!("'{value}' is not a number")))?;
        if !number.is_finite() || number <= 0.0 || number > 1e15 {
            return Err(bad(format!("{key} must be positive and finite")));
        }
        match key.trim() {
            "bw" => {
                config.peak_bytes_per_s = number.round() as u64;
                have_bw = true;
            }
            "lat" => config.latency_ns = number.round() as u64,
            "burst" => config.burst_bytes = number.round().min(u32::MAX as f64) as u32,
            "queue" => config.queue_capacity = number.round() as usize,
            other => {
                return Err(bad(format!(
                    "unknown key '{other}' (bw, lat, burst, queue)"
                )))
            }
        }
    }
    if !have_bw {
        return Err(bad("bw=BYTES_PER_S is required".into()));
    }
    if config.peak_bytes_per_s == 0 || config.burst_bytes == 0 || config.queue_capacity == 0 {
        return Err(bad("values round to zero".into()));
    }
    Ok(config)
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
    /// What an idle memory draws over the same time: precharged standby on every rank
    /// plus the same refreshes. Part of the components above, not in addition to them.
    /// \[P2\] §6.2 subtracts this "static power term computed from an idle memory
    /// transaction trace" from all its memory power figures; [`Self::above_idle_pj`] is
    /// that figure.
    pub idle_pj: f64,
}

impl DramEnergy {
    /// Sum of all components.
    pub fn total_pj(&self) -> f64 {
        self.act_pre_pj + self.read_pj + self.write_pj + self.refresh_pj + self.background_pj
    }

    /// The energy the traffic added over an idle memory (\[P2\] §6.2): the total less
    /// [`Self::idle_pj`].
    pub fn above_idle_pj(&self) -> f64 {
        (self.total_pj() - self.idle_pj).max(0.0)
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

    /// Counts so far. May be expensive: the DRAMsim3 backend has DRAMsim3 write and then
    /// parses its statistics file (about 3 ms a call, measured), so call it at the end of a
    /// run or rarely, not every cycle.
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

    /// True when a refused [`Self::send`] can only be accepted after some request has
    /// completed (a response is waiting): then a unit that was refused and waits for
    /// nothing else may skip cycles until the next response. False (the safe default) for
    /// backends whose queues drain without a response, such as DRAMsim3's staging.
    fn refusals_lift_only_with_responses(&self) -> bool {
        false
    }

    /// Advances one unit clock cycle, as [`Self::tick`], and returns
    /// [`Self::completed_waiting`]: a unit that calls this can skip [`Self::pop_response`]
    /// in the cycles nothing completed (one call through a `dyn MemoryPort` instead of
    /// two).
    #[inline]
    fn tick_and_count(&mut self) -> usize {
        self.tick();
        self.completed_waiting()
    }
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
        assert!(open("simple:ddr9", 1_000_000).is_err());
        assert!(open("dramsim3:ddr9", 1_000_000).is_err());
    }

    #[test]
    fn bare_names_open_the_model_and_prefixes_pick_the_backend() {
        for (name, bw, _) in all_systems() {
            for (spec, backend) in [
                (name.to_string(), "lpddr"),
                (format!("lpddr:{name}"), "lpddr"),
                (format!("dramsim3:{name}"), "dramsim3"),
            ] {
                let port = open(&spec, 1_000_000).unwrap();
                assert_eq!(port.name(), format!("{backend}({name})"), "{spec}");
                assert_eq!(
                    port.burst_bytes(),
                    if name.ends_with("x32") || name.ends_with("x16") {
                        32
                    } else {
                        64
                    }
                );
                // Peak from the configuration's clock and bus: equal to the table's figure
                // up to the table's rounding of 1333.3 MT/s to 1333.
                let rel = (port.peak_bytes_per_unit_cycle() - *bw as f64 * 1e-9).abs()
                    / (*bw as f64 * 1e-9);
                assert!(rel < 1e-3, "{spec}: {}", port.peak_bytes_per_unit_cycle());
            }
        }
        for bad in [
            "dramsim3:ddr9",
            "lpddr:ddr9",
            "dramsim3:",
            "lpddr:simple:lpddr3-1600-1x64",
        ] {
            let err = open(bad, 1_000_000).err().unwrap().to_string();
            assert!(err.contains(bad), "{err}");
        }
    }

    #[test]
    fn simple_what_if_specs() {
        let port = open("simple:bw=25.6e9,lat=40", 1_000_000).unwrap();
        assert!((port.peak_bytes_per_unit_cycle() - 25.6).abs() < 1e-9);
        assert_eq!(port.burst_bytes(), 64);
        let port = open("simple:bw=1e9,lat=10,burst=32,queue=4", 500_000).unwrap();
        assert!((port.peak_bytes_per_unit_cycle() - 0.5).abs() < 1e-9);
        assert_eq!(port.burst_bytes(), 32);
        for bad in [
            "simple:lat=40",
            "simple:bw=x",
            "simple:bw=-1",
            "simple:bw=1e9,foo=2",
            "simple:bw",
        ] {
            let err = open(bad, 1_000_000).err().map(|e| e.to_string());
            assert!(err.is_some(), "{bad} accepted");
        }
        assert!(open("lpddr3-1600-1x64", 0).is_err());
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

#[cfg(test)]
mod contract_tests {
    //! The [`MemoryPort`] contract, on random request sequences, for every backend.
    use super::*;

    /// What-if options: appended, replaced, checked; the base system is what remains.
    #[test]
    fn with_option_appends_replaces_and_checks() {
        let a = with_option("lpddr3-1600-2x64", "address_mapping", "rorabgbachco").unwrap();
        assert_eq!(a, "lpddr3-1600-2x64,address_mapping=rorabgbachco");
        let b = with_option(&a, "write_drain", "watermark").unwrap();
        let c = with_option(&b, "address_mapping", "rorabgbacoch").unwrap();
        assert_eq!(
            c,
            "lpddr3-1600-2x64,write_drain=watermark,address_mapping=rorabgbacoch"
        );
        assert_eq!(base_system(&c), "lpddr3-1600-2x64");
        assert_eq!(
            base_system("lpddr:lpddr3-1600-1x64,bank_xor=1"),
            "lpddr3-1600-1x64"
        );
        // The option opens, and the mapping changes where bursts go.
        assert!(open(&a, 1_000_000).is_ok());
        for bad in ["rorabgbaco", "rorabgbachch", "xxrabgbacoch"] {
            let e = with_option("lpddr3-1600-2x64", "address_mapping", bad).unwrap_err();
            assert!(e.to_string().contains("address mapping"), "{e}");
        }
        assert!(with_option("simple:lpddr3-1600-2x64", "address_mapping", "x").is_err());
        assert!(with_option("lpddr3-1600-2x64", "a=b", "c").is_err());
    }
    use proptest::prelude::*;

    fn requests() -> impl Strategy<Value = Vec<(u64, u32, bool, u8)>> {
        // (address, bytes, is_write, idle cycles before the next send)
        prop::collection::vec((0u64..1 << 26, 1u32..300, any::<bool>(), 0u8..4), 1..60)
    }

    fn check(
        port: &mut dyn MemoryPort,
        work: &[(u64, u32, bool, u8)],
    ) -> Result<Vec<u64>, TestCaseError> {
        let burst = port.burst_bytes();
        let mut accepted = Vec::new();
        for (i, &(addr, bytes, write, idle)) in work.iter().enumerate() {
            let kind = if write {
                AccessKind::Write
            } else {
                AccessKind::Read
            };
            let mut r = MemRequest {
                tag: i as u64,
                addr,
                bytes,
                kind,
            };
            loop {
                match port.send(r) {
                    Ok(()) => break,
                    Err(back) => {
                        prop_assert_eq!(back, r);
                        r = back;
                        port.tick();
                    }
                }
            }
            accepted.push((i as u64, port.cycle(), bursts_of(addr, bytes, burst), write));
            port.tick_many(idle as u64);
        }
        port.drain();
        let mut seen: Vec<MemResponse> = std::iter::from_fn(|| port.pop_response()).collect();
        prop_assert_eq!(port.outstanding(), 0);
        seen.sort_by_key(|r| r.tag);
        prop_assert_eq!(seen.len(), work.len());
        let (mut rb, mut wb) = (0, 0);
        for (r, &(tag, at, bursts, write)) in seen.iter().zip(&accepted) {
            prop_assert_eq!(r.tag, tag);
            prop_assert_eq!(r.accepted_cycle, at);
            prop_assert!(r.completed_cycle > r.accepted_cycle);
            prop_assert!(r.completed_cycle <= port.cycle());
            prop_assert_eq!(r.kind == AccessKind::Write, write);
            if write {
                wb += bursts;
            } else {
                rb += bursts;
            }
        }
        let s = port.stats();
        prop_assert_eq!((s.read_bursts, s.write_bursts), (rb, wb));
        prop_assert_eq!(s.bytes_read + s.bytes_written, (rb + wb) * burst as u64);
        prop_assert_eq!(s.unit_cycles, port.cycle());
        Ok(seen.iter().map(|r| r.completed_cycle).collect())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        #[test]
        fn every_request_completes_once_and_is_counted(work in requests(), system in 0usize..5) {
            let name = all_systems().nth(system).unwrap().0;
            check(open(name, 1_000_000).unwrap().as_mut(), &work)?;
            check(open(&format!("dramsim3:{name}"), 1_000_000).unwrap().as_mut(), &work)?;
            check(open(&format!("simple:{name}"), 1_000_000).unwrap().as_mut(), &work)?;
            let wm = format!(
                "lpddr:{name},write_drain=watermark,trans_queue_size=8,row_hit_cap=16,bank_xor=1"
            );
            check(open(&wm, 1_000_000).unwrap().as_mut(), &work)?;
        }

        /// The what-if keys at their defaults give the shipped model's timing exactly.
        #[test]
        fn what_if_defaults_change_nothing(work in requests(), system in 0usize..5) {
            let name = all_systems().nth(system).unwrap().0;
            let spec = format!(
                "lpddr:{name},write_drain=dramsim3,row_hit_cap=4,write_high_watermark=80,bank_xor=0"
            );
            let run = |spec: &str| -> Result<_, TestCaseError> {
                let mut port = open(spec, 1_000_000).unwrap();
                let done = check(port.as_mut(), &work)?;
                let s = port.stats();
                Ok((done, port.cycle(), s.row_hits, s.act_commands))
            };
            prop_assert_eq!(run(name)?, run(&spec)?);
        }
    }

    #[test]
    fn what_if_options_are_checked() {
        for bad in [
            "lpddr:lpddr3-1333-4x64,foo=1",
            "lpddr:lpddr3-1333-4x64,write_drain=never",
            "lpddr:lpddr3-1333-4x64,write_drain=watermark,write_low_watermark=90",
            "lpddr:lpddr3-1333-4x64,trans_queue_size",
            "lpddr:lpddr3-1333-4x64,bank_xor=2",
            "lpddr:ddr9,row_hit_cap=4",
            // Queues that accept nothing and clocks of no period are errors, not hangs or
            // panics.
            "lpddr3-1600-1x64,trans_queue_size=0",
            "lpddr3-1600-1x64,cmd_queue_size=0",
            "lpddr3-1600-1x64,tCK=0",
            "lpddr3-1600-1x64,tCK=nan",
        ] {
            assert!(open(bad, 1_000_000).is_err(), "{bad}");
        }
        let port = open("lpddr3-1333-4x64,address_mapping=rorabgbachco", 1_000_000).unwrap();
        assert_eq!(port.name(), "lpddr(lpddr3-1333-4x64)");
    }
}
