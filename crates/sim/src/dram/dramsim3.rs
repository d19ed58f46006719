//! The cycle-accurate backend: DRAMsim3 (through the `dramsim3` crate) behind the
//! [`super::MemoryPort`] interface.
//!
//! DRAMsim3 (umd-memsys, a standard cycle-accurate DRAM simulator) models each channel's
//! controller, banks, row buffers, command timing and refresh. It is the reference that
//! Arbor's own, faster controller model ([`super::lpddr`], the default for bare system
//! names) is checked against; `dram::open("dramsim3:NAME", ..)` selects it. What a unit
//! sees is the shared memory port ([`super::port::BurstPort`], `shared/DESIGN.md`):
//! - requests of any size are split into DRAMsim3 transactions of one burst each
//!   (`bus_width / 8 * BL` bytes, 64 B on a 64-bit LPDDR3 channel) and staged per channel
//!   and direction ([`STAGING_BURSTS`] each); a burst enters DRAMsim3 when its controller
//!   accepts it (`can_add`), and the port refuses a request whose bursts do not fit in the
//!   staging queues they go to, so back-pressure comes from DRAMsim3's transaction queues;
//! - each unit cycle advances DRAMsim3 by exactly the DRAM cycles that fit in it
//!   ([`ClockCrossing`], integer femtoseconds, no rounding drift: 1 GHz against 800 MHz is
//!   0, 1, 1, 1, 1, ... DRAM cycles per unit cycle); DRAMsim3 ticks every DRAM cycle;
//! - a request completes at the unit cycle in which DRAMsim3 returned its last burst.
//!   DRAMsim3 posts writes: a write returns one DRAM cycle after its controller buffered
//!   it, and its DRAM time shows in the bandwidth and latency of what follows. A read of an
//!   address with a buffered write is served from the buffer, as in DRAMsim3.
//!   Completions for the same address are matched to requests in the order they entered.
//!
//! Statistics. The crate's safe wrapper exposes no statistics, so this module declares the
//! crate's C entry points (`ds3_*`, compiled into the crate's static library) itself and,
//! beside them, DRAMsim3's own `MemorySystem::PrintStats` and `MemorySystem::ResetStats`
//! (by their Itanium C++ ABI symbol names, which is how g++ and clang export them on the
//! platforms CI uses). `MemoryPort::stats` on the port asks DRAMsim3 to write its per-channel
//! statistics JSON into the port's private temporary directory, parses the command counts
//! (`num_act_cmds`, `num_pre_cmds`, `num_read_cmds`, `num_write_cmds`, `num_ref_cmds`,
//! `num_read_row_hits`, `num_write_row_hits`) and the per-rank cycle split
//! (`rank_active_cycles`, `all_bank_idle_cycles`), adds them to running totals and resets
//! DRAMsim3's counters (DRAMsim3's final-statistics routine is not idempotent). A row hit
//! is a RD/WR issued to an open row; a row miss is a RD/WR that needed an ACT. This costs a
//! file write and parse (about 3.4 ms per call, measured in a release build on the shared
//! development machine), so call `stats` at the end of a run or rarely, not every cycle;
//! repeated calls without DRAM cycles in between reuse the last reading.
//! Energy comes from those counts with DRAMPower's formulas ([`super::energy`]).
//!
//! Files. DRAMsim3 reads its configuration from a file and writes its outputs into a
//! directory; the configurations are compiled into the binary (`configs/dram/*.ini`) and
//! written, with the outputs, into a fresh temporary directory that is removed when the
//! port is dropped. Nothing is written to the working directory.

// Linked for its static library (libdramsim3.a, built by the crate's cmake build script).
extern crate dramsim3 as _;

use std::cell::{RefCell, UnsafeCell};
use std::collections::{HashMap, VecDeque};
use std::ffi::{c_void, CString};

use super::energy::{self, CommandCounts, MemSpec};
use super::lpddr::AddressMap;
use super::port::{Backend, BurstPort};
use super::{DramError, MemStats};
use crate::clock::PeriodFs;

pub use super::port::STAGING_BURSTS;

mod ffi {
    use std::ffi::{c_char, c_double, c_int, c_void};

    extern "C" {
        pub fn ds3_create(
            data: *mut c_void,
            config_path: *const c_char,
            sim_path: *const c_char,
            callback: extern "C" fn(*mut c_void, u64, bool),
        ) -> *mut c_void;
        pub fn ds3_tick(sys: *mut c_void);
        pub fn ds3_can_add(sys: *mut c_void, addr: u64, is_write: bool) -> bool;
        pub fn ds3_add(sys: *mut c_void, addr: u64, is_write: bool) -> bool;
        pub fn ds3_drop(sys: *mut c_void);
        pub fn ds3_get_tck(sys: *const c_void) -> c_double;
        pub fn ds3_get_bus_bits(sys: *const c_void) -> c_int;
        pub fn ds3_get_burst_length(sys: *const c_void) -> c_int;
        /// `dramsim3::MemorySystem::PrintStats() const`.
        #[link_name = "_ZNK8dramsim312MemorySystem10PrintStatsEv"]
        pub fn ds3_print_stats(sys: *const c_void);
        /// `dramsim3::MemorySystem::ResetStats()`.
        #[link_name = "_ZN8dramsim312MemorySystem10ResetStatsEv"]
        pub fn ds3_reset_stats(sys: *mut c_void);
    }
}

/// One memory system Arbor ships a DRAMsim3 configuration for.
#[derive(Debug)]
pub struct SystemConfig {
    /// The name `dram::open` knows it by.
    pub name: &'static str,
    /// The DRAMsim3 configuration file's text.
    pub ini: &'static str,
    /// The die whose currents give the energy.
    pub memspec: &'static MemSpec,
}

/// The systems with a DRAMsim3 configuration: the thesis's four LPDDR3 systems and one
/// LPDDR4 what-if system.
pub static SYSTEMS: &[SystemConfig] = &[
    SystemConfig {
        name: "lpddr3-1600-1x64",
        ini: include_str!("../../configs/dram/lpddr3-1600-1x64.ini"),
        memspec: &energy::MICRON_4GB_LPDDR3_1600_X32,
    },
    SystemConfig {
        name: "lpddr3-1600-2x64",
        ini: include_str!("../../configs/dram/lpddr3-1600-2x64.ini"),
        memspec: &energy::MICRON_4GB_LPDDR3_1600_X32,
    },
    SystemConfig {
        name: "lpddr3-1333-4x64",
        ini: include_str!("../../configs/dram/lpddr3-1333-4x64.ini"),
        memspec: &energy::MICRON_4GB_LPDDR3_1600_X32,
    },
    SystemConfig {
        name: "lpddr3-1600-2x32",
        ini: include_str!("../../configs/dram/lpddr3-1600-2x32.ini"),
        memspec: &energy::MICRON_4GB_LPDDR3_1600_X32,
    },
    SystemConfig {
        name: "lpddr4-3200-4x16",
        ini: include_str!("../../configs/dram/lpddr4-3200-4x16.ini"),
        memspec: &energy::JEDEC_8GB_LPDDR4_3200_X16,
    },
];

impl SystemConfig {
    /// The value of `key` in the configuration text (first match in any section).
    pub fn value(&self, key: &str) -> Option<&'static str> {
        self.ini.lines().find_map(|line| {
            let line = line.trim();
            if line.starts_with(';') || line.starts_with('#') {
                return None;
            }
            let (k, v) = line.split_once('=')?;
            (k.trim() == key).then(|| v.trim())
        })
    }

    /// The integer value of `key`, or an error naming the key.
    pub fn int(&self, key: &str) -> Result<u64, DramError> {
        self.value(key)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| DramError::Config(format!("{}: no integer '{key}'", self.name)))
    }

    /// The DRAM clock period in nanoseconds.
    pub fn tck_ns(&self) -> Result<f64, DramError> {
        let tck: f64 = self
            .value("tCK")
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| DramError::Config(format!("{}: no tCK", self.name)))?;
        // A clock of at most 1 s and at least 1 fs (the clock crossing's unit).
        if !(1e-6..=1e9).contains(&tck) {
            return Err(DramError::Config(format!(
                "{}: tCK = {tck} ns (1e-6 to 1e9)",
                self.name
            )));
        }
        Ok(tck)
    }
}

/// Finds the shipped configuration of `name`.
pub fn system(name: &str) -> Option<&'static SystemConfig> {
    SYSTEMS.iter().find(|s| s.name == name)
}

/// Running totals of DRAMsim3's statistics, taken at `at_dram_cycle`.
#[derive(Clone, Copy, Debug, Default)]
struct Snapshot {
    at_dram_cycle: Option<u64>,
    counts: CommandCounts,
    row_hits: u64,
}

/// The DRAMsim3 memory port: DRAMsim3 behind the shared [`BurstPort`]. See the module
/// documentation.
pub type Dramsim3Port = BurstPort<Dramsim3System>;

/// A DRAMsim3 memory system as a [`Backend`] of the shared memory port: ticks every DRAM
/// cycle and matches DRAMsim3's completions (by address) to the bursts given to it.
pub struct Dramsim3System {
    sys: *mut c_void,
    /// Completions `(address, is_write)` written by the callback during `ds3_tick`.
    sink: Box<UnsafeCell<Vec<(u64, bool)>>>,
    dir: tempfile::TempDir,
    config: &'static SystemConfig,
    map: AddressMap,
    channels: usize,
    tck_ns: f64,
    dies_per_rank: u32,
    dram_cycle: u64,
    /// Bursts in DRAMsim3 by (address, is_write), in the order they entered.
    waiting: HashMap<(u64, bool), VecDeque<u32>>,
    snapshot: RefCell<Snapshot>,
}

extern "C" fn on_complete(data: *mut c_void, addr: u64, is_write: bool) {
    // SAFETY: `data` is the system's `sink` (a live, boxed vector), and DRAMsim3 calls
    // this only from inside `ds3_tick`, which the system calls while holding `&mut self`
    // and without any other reference into `sink`.
    let sink = unsafe { &mut *(data as *mut Vec<(u64, bool)>) };
    sink.push((addr, is_write));
}

impl BurstPort<Dramsim3System> {
    /// Opens the shipped system `name` driven by a unit clock of period `unit_period_fs`.
    pub fn open(name: &str, unit_period_fs: PeriodFs) -> Result<Self, DramError> {
        let config = super::port::shipped_system(name)?;
        Self::with_config(config, unit_period_fs)
    }

    /// Opens a system from its configuration.
    ///
    /// DRAMsim3 ends the process on a configuration it cannot use; the shipped ones are
    /// tested, so build others by editing a copy of one of them.
    pub fn with_config(
        config: &'static SystemConfig,
        unit_period_fs: PeriodFs,
    ) -> Result<Self, DramError> {
        if unit_period_fs == 0 {
            return Err(DramError::Config("unit clock period of zero".into()));
        }
        let system = Dramsim3System::new(config)?;
        let tck_ns = system.tck_ns;
        BurstPort::for_system(system, config, tck_ns, unit_period_fs)
    }

    /// The configuration this port runs.
    pub fn config(&self) -> &'static SystemConfig {
        self.backend.config
    }

    /// DRAM clock period in nanoseconds.
    pub fn tck_ns(&self) -> f64 {
        self.backend.tck_ns
    }

    /// The directory DRAMsim3 writes into (removed when the port is dropped).
    pub fn output_dir(&self) -> &std::path::Path {
        self.backend.dir.path()
    }

    /// Command counts and row hits so far, read from DRAMsim3 (see the module docs).
    pub fn command_counts(&self) -> (CommandCounts, u64) {
        self.backend.command_counts()
    }
}

impl Dramsim3System {
    /// Creates DRAMsim3's memory system for `config`.
    pub fn new(config: &'static SystemConfig) -> Result<Self, DramError> {
        // Check what DRAMsim3 would otherwise reject by exiting the process.
        let channels = config.int("channels")?;
        let bus_bits = config.int("bus_width")?;
        let device_bits = config.int("device_width")?;
        let bl = config.int("BL")?;
        let tck_ns = config.tck_ns()?;
        if channels == 0
            || !channels.is_power_of_two()
            || device_bits == 0
            || bus_bits % device_bits != 0
        {
            return Err(DramError::Config(format!(
                "{}: bad channel organisation",
                config.name
            )));
        }
        let map = AddressMap::from_config(config)?;
        let dir = tempfile::Builder::new()
            .prefix("arbor-dramsim3-")
            .tempdir()
            .map_err(|e| DramError::Io(format!("temporary directory: {e}")))?;
        let ini_path = dir.path().join(format!("{}.ini", config.name));
        std::fs::write(&ini_path, config.ini)
            .map_err(|e| DramError::Io(format!("{}: {e}", ini_path.display())))?;
        let c_ini = CString::new(ini_path.as_os_str().as_encoded_bytes())
            .map_err(|_| DramError::Io("NUL in temporary path".into()))?;
        let c_dir = CString::new(dir.path().as_os_str().as_encoded_bytes())
            .map_err(|_| DramError::Io("NUL in temporary path".into()))?;
        let sink: Box<UnsafeCell<Vec<(u64, bool)>>> = Box::new(UnsafeCell::new(Vec::new()));
        // SAFETY: both strings are valid NUL-terminated paths that outlive the call; the
        // sink pointer stays valid for the system's life (the box is dropped after it).
        let sys = unsafe {
            ffi::ds3_create(
                sink.get() as *mut c_void,
                c_ini.as_ptr(),
                c_dir.as_ptr(),
                on_complete,
            )
        };
        if sys.is_null() {
            return Err(DramError::Config(format!(
                "{}: DRAMsim3 refused the configuration",
                config.name
            )));
        }
        // SAFETY: `sys` is a live memory system.
        let (got_tck, got_bus, got_bl) = unsafe {
            (
                ffi::ds3_get_tck(sys),
                ffi::ds3_get_bus_bits(sys),
                ffi::ds3_get_burst_length(sys),
            )
        };
        debug_assert!((got_tck - tck_ns).abs() < 1e-12);
        debug_assert_eq!((got_bus as u64, got_bl as u64), (bus_bits, bl));
        Ok(Self {
            sys,
            sink,
            dir,
            config,
            map,
            channels: channels as usize,
            tck_ns,
            dies_per_rank: (bus_bits / device_bits) as u32,
            dram_cycle: 0,
            waiting: HashMap::new(),
            snapshot: RefCell::new(Snapshot::default()),
        })
    }

    /// Command counts and row hits so far, read from DRAMsim3 (see the module docs).
    pub fn command_counts(&self) -> (CommandCounts, u64) {
        let mut snap = self.snapshot.borrow_mut();
        if snap.at_dram_cycle != Some(self.dram_cycle) {
            let delta = self.read_dramsim3_stats();
            let c = &mut snap.counts;
            c.act += delta.0.act;
            c.pre += delta.0.pre;
            c.read += delta.0.read;
            c.write += delta.0.write;
            c.refresh += delta.0.refresh;
            c.active_rank_cycles += delta.0.active_rank_cycles;
            c.precharged_rank_cycles += delta.0.precharged_rank_cycles;
            snap.row_hits += delta.1;
            snap.at_dram_cycle = Some(self.dram_cycle);
        }
        (snap.counts, snap.row_hits)
    }
    /// Writes, parses and resets DRAMsim3's counters: the counts since the last call.
    fn read_dramsim3_stats(&self) -> (CommandCounts, u64) {
        // SAFETY: `sys` is live. PrintStats writes files into our temporary directory;
        // ResetStats zeroes DRAMsim3's counters, which only this function reads.
        unsafe { ffi::ds3_print_stats(self.sys) };
        let path = self.dir.path().join("dramsim3.json");
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        // SAFETY: as above.
        unsafe { ffi::ds3_reset_stats(self.sys) };
        let json: serde_json::Value = serde_json::from_str(&text)
            .unwrap_or_else(|e| panic!("DRAMsim3 statistics {} unreadable: {e}", path.display()));
        let mut counts = CommandCounts::default();
        let mut hits = 0;
        let Some(channels) = json.as_object() else {
            panic!("DRAMsim3 statistics {}: not an object", path.display());
        };
        let num =
            |v: &serde_json::Value, key: &str| v.get(key).and_then(|x| x.as_u64()).unwrap_or(0);
        let per_rank = |v: &serde_json::Value, key: &str| -> u64 {
            v.get(key)
                .and_then(|x| x.as_object())
                .map(|m| m.values().filter_map(|x| x.as_u64()).sum())
                .unwrap_or(0)
        };
        for ch in channels.values() {
            counts.act += num(ch, "num_act_cmds");
            counts.pre += num(ch, "num_pre_cmds");
            counts.read += num(ch, "num_read_cmds");
            counts.write += num(ch, "num_write_cmds");
            counts.refresh += num(ch, "num_ref_cmds");
            counts.active_rank_cycles += per_rank(ch, "rank_active_cycles");
            counts.precharged_rank_cycles += per_rank(ch, "all_bank_idle_cycles");
            hits += num(ch, "num_read_row_hits") + num(ch, "num_write_row_hits");
        }
        (counts, hits)
    }
}

// SAFETY: the system owns its DRAMsim3 instance exclusively (nothing else holds `sys`),
// the callback's pointer targets the boxed sink, whose heap address does not change when
// the system moves, and DRAMsim3 keeps no thread-local state. Moving it to another thread
// is therefore sound; sharing it is not offered (it is not Sync).
unsafe impl Send for Dramsim3System {}

impl Drop for Dramsim3System {
    fn drop(&mut self) {
        // SAFETY: `sys` is live and dropped exactly once, before `sink` and `dir`.
        unsafe { ffi::ds3_drop(self.sys) };
    }
}

impl Backend for Dramsim3System {
    fn name(&self) -> String {
        format!("dramsim3({})", self.config.name)
    }

    fn channels(&self) -> usize {
        self.channels
    }

    fn channel_of(&self, addr: u64) -> usize {
        self.map.channel(addr)
    }

    fn can_add(&self, channel: usize, is_write: bool) -> bool {
        // DRAMsim3's answer depends on the channel and direction only; any address of
        // the channel asks it.
        let _ = channel;
        debug_assert!(channel < self.channels);
        // SAFETY: `sys` is live.
        unsafe { ffi::ds3_can_add(self.sys, self.channel_base(channel), is_write) }
    }

    fn add(&mut self, channel: usize, addr: u64, is_write: bool, token: u32) {
        debug_assert_eq!(self.map.channel(addr), channel);
        // SAFETY: `sys` is live; `can_add` said yes.
        let added = unsafe { ffi::ds3_add(self.sys, addr, is_write) };
        debug_assert!(added);
        self.waiting
            .entry((addr, is_write))
            .or_default()
            .push_back(token);
    }

    fn now(&self) -> u64 {
        self.dram_cycle
    }

    fn next_event(&self) -> u64 {
        self.dram_cycle
    }

    fn run_until(&mut self, to: u64, done: &mut Vec<u32>) {
        while self.dram_cycle < to {
            // SAFETY: `sys` is live; the callback writes only into `sink`, which nothing
            // else borrows now.
            unsafe { ffi::ds3_tick(self.sys) };
            self.dram_cycle += 1;
            let sink = self.sink.get_mut();
            if sink.is_empty() {
                continue;
            }
            for &(addr, is_write) in sink.iter() {
                let Some(queue) = self.waiting.get_mut(&(addr, is_write)) else {
                    panic!("DRAMsim3 returned {addr:#x} that was never sent");
                };
                done.push(
                    queue
                        .pop_front()
                        .expect("waiting queue is never left empty"),
                );
                if queue.is_empty() {
                    self.waiting.remove(&(addr, is_write));
                }
            }
            sink.clear();
        }
    }

    fn fill_stats(&self, s: &mut MemStats) {
        let (counts, row_hits) = self.command_counts();
        super::port::fill_command_stats(
            s,
            self.config,
            &counts,
            row_hits,
            self.dies_per_rank,
            self.tck_ns,
        );
    }
}

impl Dramsim3System {
    /// The lowest address of `channel` (DRAMsim3 picks the controller from the address).
    fn channel_base(&self, channel: usize) -> u64 {
        let (pos, _) = self.map.ch_field();
        ((channel as u64) << pos) << self.map.shift()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dram::lpddr::LpddrPort;
    use crate::dram::{bursts_of, AccessKind, MemRequest, MemResponse, MemoryPort};

    const GHZ: PeriodFs = 1_000_000;

    fn req(tag: u64, addr: u64, bytes: u32, kind: AccessKind) -> MemRequest {
        MemRequest {
            tag,
            addr,
            bytes,
            kind,
        }
    }

    /// Sends `requests` as fast as the port takes them and ticks until all are back.
    /// Returns the responses in completion order.
    fn run(port: &mut dyn MemoryPort, requests: &[MemRequest]) -> Vec<MemResponse> {
        let mut next = 0;
        let mut out = Vec::with_capacity(requests.len());
        while out.len() < requests.len() {
            while next < requests.len() && port.send(requests[next]).is_ok() {
                next += 1;
            }
            port.tick();
            while let Some(r) = port.pop_response() {
                out.push(r);
            }
        }
        out
    }

    fn sequential_reads(bytes: u64) -> Vec<MemRequest> {
        (0..bytes / 64)
            .map(|i| req(i, i * 64, 64, AccessKind::Read))
            .collect()
    }

    /// A system like `base` with its `key` set to `value` (leaked: tests only).
    fn variant(base: &'static SystemConfig, key: &str, value: &str) -> &'static SystemConfig {
        let ini: String = base
            .ini
            .lines()
            .map(|l| {
                if l.split_once('=').map(|(k, _)| k.trim()) == Some(key) {
                    format!("{key} = {value}\n")
                } else {
                    format!("{l}\n")
                }
            })
            .collect();
        Box::leak(Box::new(SystemConfig {
            name: base.name,
            ini: Box::leak(ini.into_boxed_str()),
            memspec: base.memspec,
        }))
    }

    /// Deterministic pseudo-random numbers (64-bit LCG, high bits).
    fn lcg(state: &mut u64) -> u64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        *state >> 16
    }

    fn sequential_read_stream_reaches_90_percent_of_peak_on_every_lpddr3_system<P: Open>() {
        for (name, _, _) in crate::dram::MEMORY_SYSTEMS {
            let mut port = P::open_(name, GHZ).unwrap();
            let bytes = 1 << 20;
            let responses = run(&mut port, &sequential_reads(bytes));
            let s = port.stats();
            assert_eq!(s.bytes_read, bytes);
            assert_eq!(s.read_bursts, bytes / port.burst_bytes() as u64);
            let last = responses.iter().map(|r| r.completed_cycle).max().unwrap();
            let util = bytes as f64 / (port.peak_bytes_per_unit_cycle() * last as f64);
            assert!((0.90..=1.0).contains(&util), "{name}: {util:.3} of peak");
            // A stream opens each row once: almost every burst is a row hit.
            assert!(
                s.row_hits as f64 >= 0.95 * s.read_commands as f64,
                "{name}: {s:?}"
            );
            assert_eq!(s.read_commands, s.read_bursts, "{name}");
            assert!(s.refresh_commands > 0, "{name}: no refresh in {last} ns");
        }
    }

    /// Latency in unit cycles (ns at 1 GHz) of isolated reads at `addrs`, one at a time
    /// with `gap` idle unit cycles after each.
    fn isolated_latencies(port: &mut dyn MemoryPort, addrs: &[u64], gap: u64) -> Vec<u64> {
        addrs
            .iter()
            .enumerate()
            .map(|(i, &a)| {
                port.send(req(i as u64, a, 64, AccessKind::Read)).unwrap();
                let r = loop {
                    port.tick();
                    if let Some(r) = port.pop_response() {
                        break r;
                    }
                };
                port.tick_many(gap);
                r.completed_cycle - r.accepted_cycle
            })
            .collect()
    }

    fn median(mut v: Vec<u64>) -> u64 {
        v.sort_unstable();
        v[v.len() / 2]
    }

    fn isolated_reads_see_the_closed_row_conflict_and_row_hit_latencies<P: Open>() {
        let cfg = system("lpddr3-1600-1x64").unwrap();
        let mut port = P::with_(cfg, GHZ).unwrap();
        let t = |k: &str| cfg.int(k).unwrap() as f64;
        let tck = cfg.tck_ns().unwrap();
        // Address map rorabgbacoch on one 64-bit channel: 64-B bursts, 128 columns
        // (bits 6..13), 8 banks (bits 13..16), rows above bit 16.
        let at = |row: u64, bank: u64, col: u64| row << 16 | bank << 13 | col << 6;
        let data_ns = (t("CL") + t("BL") / 2.0) * tck;
        let closed_ns = t("tRCD") * tck + data_ns;
        let conflict_ns = (t("tRP") + t("tRCD")) * tck + data_ns;
        // DRAMsim3 moves a new transaction to its command queue in the DRAM cycle it
        // arrives and issues the first command in the next one, and the port sees the data
        // at the start of the DRAM tick after it is complete: up to 3 DRAM cycles beyond the
        // JEDEC sum. The clock crossing adds up to one unit cycle (1 ns) at each end.
        let slack_ns = 3.0 * tck + 2.0;
        let within = |got: u64, want: f64, what: &str| {
            println!("{what}: {got} ns (JEDEC sum {want} ns)");
            assert!(
                got as f64 >= want && got as f64 <= want + slack_ns,
                "{what}: {got} ns, expected {want} .. {}",
                want + slack_ns
            );
        };
        // The first read finds every bank closed: ACT, RD.
        within(
            isolated_latencies(&mut port, &[at(5, 3, 0)], 10)[0],
            closed_ns,
            "closed bank",
        );
        // Random rows of one bank, back to back with short gaps (the row stays open, and a
        // refresh, which closes it, falls between two reads only now and then): PRE, ACT, RD.
        let mut state = 7;
        let rows: Vec<u64> = (0..41)
            .map(|i| at(1 + 2 * i + lcg(&mut state) % 2, 3, 0))
            .collect();
        within(
            median(isolated_latencies(&mut port, &rows, 10)),
            conflict_ns,
            "row conflict",
        );
        // Another column of the row just read: RD only.
        let last = *rows.last().unwrap();
        within(
            isolated_latencies(&mut port, &[last + 64], 10)[0],
            data_ns,
            "row hit",
        );
        let s = port.stats();
        println!("latency: closed {closed_ns} ns, conflict {conflict_ns} ns, hit {data_ns} ns expected; {s:?}");
        assert_eq!(s.row_hits, 1, "{s:?}");
        assert_eq!(s.row_misses, 42, "{s:?}");
    }

    fn refresh_runs_every_trefi_and_costs_about_trfc_over_trefi<P: Open>() {
        let cfg = system("lpddr3-1600-1x64").unwrap();
        let trefi = cfg.int("tREFI").unwrap();
        let trfc = cfg.int("tRFC").unwrap();
        // Idle: DRAMsim3 asks for a refresh at every DRAM cycle k * tREFI (k >= 1) and
        // issues it at once when the banks are closed.
        let mut port = P::with_(cfg, GHZ).unwrap();
        let k = 20;
        let dram_cycles = k * trefi + 100;
        // 1 GHz unit, 800 MHz DRAM: 5 unit cycles per 4 DRAM cycles.
        port.tick_many(dram_cycles * 5 / 4);
        assert_eq!(port.dram(), dram_cycles);
        assert_eq!(port.stats().refresh_commands, k);

        // Loaded: the same stream with and without refresh.
        let stream = sequential_reads(1 << 20);
        let mut with = P::with_(cfg, GHZ).unwrap();
        let t_with = run(&mut with, &stream).last().unwrap().completed_cycle;
        let mut without = P::with_(variant(cfg, "tREFI", "2000000000"), GHZ).unwrap();
        let t_without = run(&mut without, &stream).last().unwrap().completed_cycle;
        assert_eq!(without.stats().refresh_commands, 0);
        let loss = 1.0 - t_without as f64 / t_with as f64;
        // Each refresh blocks the rank for tRFC and closes the open row, which costs one
        // more PRE..ACT (tRP + tRCD) to reopen it: between tRFC / tREFI and
        // (tRFC + tRP + tRCD + a few cycles of queue drain) / tREFI.
        let low = trfc as f64 / trefi as f64;
        let reopen = (cfg.int("tRP").unwrap() + cfg.int("tRCD").unwrap() + 8) as f64;
        let high = (trfc as f64 + reopen) / trefi as f64;
        println!(
            "refresh: {t_with} vs {t_without} unit cycles, loss {loss:.4} ({low:.4} .. {high:.4})"
        );
        assert!(
            loss >= 0.8 * low && loss <= high,
            "loss {loss:.4}, expected {low:.4} .. {high:.4}"
        );
    }

    fn mixed_workload(n: u64, seed: u64) -> Vec<MemRequest> {
        let mut state = seed;
        (0..n)
            .map(|i| {
                let r = lcg(&mut state);
                let kind = if matches!(r % 3, 0) {
                    AccessKind::Write
                } else {
                    AccessKind::Read
                };
                let addr = (r >> 8) % (1 << 28);
                let bytes = 1 + (r % 256) as u32;
                req(i, addr, bytes, kind)
            })
            .collect()
    }

    fn runs_are_deterministic<P: Open>() {
        let work = mixed_workload(3000, 11);
        let go = || {
            let mut port = P::open_("lpddr3-1600-2x64", GHZ).unwrap();
            let responses = run(&mut port, &work);
            (responses, port.stats())
        };
        let (ra, sa) = go();
        let (rb, sb) = go();
        assert_eq!(ra, rb);
        assert_eq!(sa, sb);
        assert_eq!(ra.len(), work.len());
    }

    fn full_port_refuses_and_returns_the_request<P: Open>() {
        let mut port = P::open_("lpddr3-1600-1x64", GHZ).unwrap();
        let mut accepted = 0;
        let refused = loop {
            let r = req(accepted, accepted * 4096, 64, AccessKind::Read);
            match port.send(r) {
                Ok(()) => accepted += 1,
                Err(back) => {
                    assert_eq!(back, r);
                    break back;
                }
            }
        };
        // Without ticks nothing reaches DRAMsim3: the staging queue is the limit.
        assert_eq!(accepted as usize, STAGING_BURSTS);
        port.drain();
        assert_eq!(port.completed_waiting(), STAGING_BURSTS);
        let tags: Vec<u64> = std::iter::from_fn(|| port.pop_response().map(|r| r.tag)).collect();
        let mut sorted = tags.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..accepted).collect::<Vec<_>>());
        assert!(port.send(refused).is_ok());
        // Under a flood with ticks, what is outstanding stays bounded by DRAMsim3's
        // 32-entry read queue, its 8-entry command queue per bank, the staging queue and
        // the reads whose RD has issued but whose data is still on its way (RL + BL/2 =
        // 16 cycles at one RD per tCCD = 4 cycles).
        let bound = 32 + 8 * 8 + STAGING_BURSTS + 16 / 4;
        let mut peak = 0;
        for i in 0..2000u64 {
            let _ = port.send(req(1000 + i, i * 8192, 64, AccessKind::Read));
            peak = peak.max(port.outstanding());
            assert!(port.outstanding() <= bound, "{}", port.outstanding());
            port.tick();
            while port.pop_response().is_some() {}
        }
        assert!(peak > 32, "the flood never filled the queues: {peak}");
    }

    fn bytes_bursts_and_commands_add_up<P: Open>() {
        let work = mixed_workload(2000, 5);
        let mut port = P::open_("lpddr3-1600-2x32", GHZ).unwrap();
        run(&mut port, &work);
        let s = port.stats();
        let b = port.burst_bytes() as u64;
        assert_eq!(b, 32);
        let (mut rb, mut wb) = (0, 0);
        for r in &work {
            let n = bursts_of(r.addr, r.bytes, b as u32);
            match r.kind {
                AccessKind::Read => rb += n,
                AccessKind::Write => wb += n,
            }
        }
        assert_eq!((s.read_bursts, s.write_bursts), (rb, wb));
        assert_eq!((s.bytes_read, s.bytes_written), (rb * b, wb * b));
        assert_eq!(s.read_requests + s.write_requests, work.len() as u64);
        // Reads of buffered writes and merged writes never reach the DRAM, so there are
        // at most as many commands as bursts; the rest must be few.
        assert!(s.read_commands <= rb && s.write_commands <= wb);
        assert!(
            s.read_commands + s.write_commands >= (rb + wb) * 9 / 10,
            "{s:?}"
        );
        assert_eq!(
            s.row_hits + s.row_misses,
            s.read_commands + s.write_commands
        );
        // Every row miss needs an ACT; ACTs at the start of a refresh-closed row too.
        assert!(s.act_commands >= s.row_misses, "{s:?}");
        let e = s.energy_pj.unwrap();
        let spec = system("lpddr3-1600-2x32").unwrap().memspec;
        // One x32 die per 32-bit channel.
        assert!((e.read_pj - s.read_commands as f64 * spec.read_burst_pj()).abs() < 1e-3);
        assert!((e.refresh_pj - s.refresh_commands as f64 * spec.refresh_pj()).abs() < 1e-3);
        assert!(e.background_pj > 0.0);
    }

    fn clock_crossing_is_exact_at_one_ghz<P: Open>() {
        for (name, dram_per_unit) in [("lpddr3-1600-1x64", (4, 5)), ("lpddr3-1333-4x64", (2, 3))] {
            let mut a = P::open_(name, GHZ).unwrap();
            let mut b = P::open_(name, GHZ).unwrap();
            let unit = 30_000;
            a.tick_many(unit);
            for _ in 0..unit {
                b.tick();
            }
            assert_eq!(a.dram(), unit * dram_per_unit.0 / dram_per_unit.1, "{name}");
            assert_eq!(a.dram(), b.dram());
            assert_eq!(a.stats(), b.stats());
        }
    }

    fn tick_many_equals_ticks_under_load<P: Open>() {
        let work = mixed_workload(300, 3);
        let mut a = P::open_("lpddr3-1333-4x64", GHZ).unwrap();
        let mut b = P::open_("lpddr3-1333-4x64", GHZ).unwrap();
        for (i, r) in work.iter().enumerate() {
            let (ra, rb) = (a.send(*r), b.send(*r));
            assert_eq!(ra.is_ok(), rb.is_ok());
            let n = 1 + (i as u64 % 7);
            for _ in 0..n {
                a.tick();
            }
            b.tick_many(n);
        }
        a.tick_many(5000);
        for _ in 0..5000 {
            b.tick();
        }
        let ra: Vec<_> = std::iter::from_fn(|| a.pop_response()).collect();
        let rb: Vec<_> = std::iter::from_fn(|| b.pop_response()).collect();
        assert_eq!(ra, rb);
        assert_eq!(a.stats(), b.stats());
    }

    fn a_port_can_move_to_another_thread<P: Open>() {
        let work = mixed_workload(200, 9);
        let mut here = P::open_("lpddr3-1600-2x64", GHZ).unwrap();
        let there = std::thread::spawn({
            let work = work.clone();
            move || {
                let mut p = P::open_("lpddr3-1600-2x64", GHZ).unwrap();
                let r = run(&mut p, &work);
                (p, r)
            }
        });
        let mine = run(&mut here, &work);
        let (port, theirs) = there.join().unwrap();
        assert_eq!(mine, theirs);
        assert_eq!(here.stats(), port.stats());
    }

    #[test]
    fn outputs_stay_in_a_private_directory_that_is_removed() {
        let port = Dramsim3Port::open("lpddr3-1600-1x64", GHZ).unwrap();
        let dir = port.output_dir().to_path_buf();
        let _ = port.stats();
        assert!(dir.join("dramsim3.json").is_file());
        drop(port);
        assert!(!dir.exists());
    }

    fn stats_can_be_read_repeatedly_without_double_counting<P: Open>() {
        let mut port = P::open_("lpddr3-1600-1x64", GHZ).unwrap();
        run(&mut port, &sequential_reads(64 * 100));
        let a = port.stats();
        let b = port.stats();
        assert_eq!(a, b);
        run(&mut port, &sequential_reads(64 * 100));
        let c = port.stats();
        assert_eq!(c.read_commands, 200 - (c.read_bursts - c.read_commands));
        assert!(c.read_commands >= 100 + a.read_commands - 1, "{a:?} {c:?}");
    }

    #[test]
    fn every_shipped_config_spells_trefi() {
        for s in SYSTEMS {
            assert!(
                s.value("REFI").is_none(),
                "{}: DRAMsim3 ignores REFI",
                s.name
            );
            let trefi = s.int("tREFI").unwrap() as f64 * s.tck_ns().unwrap();
            assert!((trefi - 3900.0).abs() < 5.0, "{}: tREFI {trefi} ns", s.name);
        }
    }

    /// The two cycle-accurate ports, for tests that must pass on both.
    trait Open: MemoryPort + Send + Sized + 'static {
        fn open_(name: &str, unit: PeriodFs) -> Result<Self, DramError>;
        fn with_(cfg: &'static SystemConfig, unit: PeriodFs) -> Result<Self, DramError>;
        fn dram(&self) -> u64;
    }

    impl Open for Dramsim3Port {
        fn open_(name: &str, unit: PeriodFs) -> Result<Self, DramError> {
            Dramsim3Port::open(name, unit)
        }
        fn with_(cfg: &'static SystemConfig, unit: PeriodFs) -> Result<Self, DramError> {
            Dramsim3Port::with_config(cfg, unit)
        }
        fn dram(&self) -> u64 {
            self.dram_cycle()
        }
    }

    impl Open for LpddrPort {
        fn open_(name: &str, unit: PeriodFs) -> Result<Self, DramError> {
            LpddrPort::open(name, unit)
        }
        fn with_(cfg: &'static SystemConfig, unit: PeriodFs) -> Result<Self, DramError> {
            LpddrPort::with_config(cfg, unit)
        }
        fn dram(&self) -> u64 {
            self.dram_cycle()
        }
    }

    /// Each test above as two tests: on DRAMsim3 and on Arbor's model.
    macro_rules! on_both {
        ($($name:ident => $ds3:ident, $model:ident;)*) => {$(
            #[test]
            fn $ds3() {
                $name::<Dramsim3Port>();
            }
            #[test]
            fn $model() {
                $name::<LpddrPort>();
            }
        )*};
    }

    on_both! {
        sequential_read_stream_reaches_90_percent_of_peak_on_every_lpddr3_system => sequential_read_stream_reaches_90_percent_of_peak_on_every_lpddr3_system_on_dramsim3, sequential_read_stream_reaches_90_percent_of_peak_on_every_lpddr3_system_on_the_model;
        isolated_reads_see_the_closed_row_conflict_and_row_hit_latencies => isolated_reads_see_the_closed_row_conflict_and_row_hit_latencies_on_dramsim3, isolated_reads_see_the_closed_row_conflict_and_row_hit_latencies_on_the_model;
        refresh_runs_every_trefi_and_costs_about_trfc_over_trefi => refresh_runs_every_trefi_and_costs_about_trfc_over_trefi_on_dramsim3, refresh_runs_every_trefi_and_costs_about_trfc_over_trefi_on_the_model;
        runs_are_deterministic => runs_are_deterministic_on_dramsim3, runs_are_deterministic_on_the_model;
        full_port_refuses_and_returns_the_request => full_port_refuses_and_returns_the_request_on_dramsim3, full_port_refuses_and_returns_the_request_on_the_model;
        bytes_bursts_and_commands_add_up => bytes_bursts_and_commands_add_up_on_dramsim3, bytes_bursts_and_commands_add_up_on_the_model;
        clock_crossing_is_exact_at_one_ghz => clock_crossing_is_exact_at_one_ghz_on_dramsim3, clock_crossing_is_exact_at_one_ghz_on_the_model;
        tick_many_equals_ticks_under_load => tick_many_equals_ticks_under_load_on_dramsim3, tick_many_equals_ticks_under_load_on_the_model;
        a_port_can_move_to_another_thread => a_port_can_move_to_another_thread_on_dramsim3, a_port_can_move_to_another_thread_on_the_model;
        stats_can_be_read_repeatedly_without_double_counting => stats_can_be_read_repeatedly_without_double_counting_on_dramsim3, stats_can_be_read_repeatedly_without_double_counting_on_the_model;
    }
}
