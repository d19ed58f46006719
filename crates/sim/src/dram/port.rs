//! The memory port shared by the cycle-accurate backends: request splitting, staging per
//! channel and direction, the clock crossing and completion bookkeeping.
//!
//! A backend ([`Backend`]) is a set of channel controllers clocked together at the DRAM
//! clock. [`BurstPort`] turns it into a [`MemoryPort`]:
//! - a request is split into bursts (`burst_bytes`, aligned); each burst goes to the
//!   staging queue of its channel and direction (reads and writes apart), so a burst that
//!   its controller cannot take yet blocks only later bursts of the same channel and
//!   direction, never the other channels or the other direction (no head-of-line
//!   blocking);
//! - a request is accepted only when, for every staging queue it goes to, its bursts fit
//!   in the room left ([`STAGING_BURSTS`] per queue). A request larger than a whole queue
//!   is accepted when the queues it goes to are empty, so it cannot be refused forever;
//! - before every DRAM clock tick, each channel takes staged bursts while its controller
//!   accepts them (the backend's `can_add`), the oldest first when both directions could
//!   go;
//! - a request completes at the unit cycle in which its last burst came back.
//!
//! Backends that can tell when nothing will happen ([`Backend::next_event`]) let the port
//! skip DRAM cycles; the results are those of ticking every cycle.

use std::collections::VecDeque;

use super::dramsim3::{system, SystemConfig, SYSTEMS};
use super::energy::{self, CommandCounts};
use super::{bursts_of, AccessKind, DramError, MemRequest, MemResponse, MemStats, MemoryPort};
use crate::clock::{period_fs_from_ns, ClockCrossing, PeriodFs};

/// Bursts each staging queue (one per channel and direction) may hold before
/// [`MemoryPort::send`] refuses requests that go to it. Small next to a controller's
/// 32-entry transaction queue, so the controller, not the port, decides how much is in
/// flight.
pub const STAGING_BURSTS: usize = 16;

/// A set of DRAM channel controllers, clocked together.
pub trait Backend {
    /// Short name for reports.
    fn name(&self) -> String;
    /// Number of channels.
    fn channels(&self) -> usize;
    /// Channel of a (burst-aligned) byte address.
    fn channel_of(&self, addr: u64) -> usize;
    /// Whether `channel`'s controller would take a transaction of this direction now.
    fn can_add(&self, channel: usize, is_write: bool) -> bool;
    /// Gives a burst to `channel`'s controller (only after `can_add` said yes). `token` is
    /// returned when the burst completes.
    fn add(&mut self, channel: usize, addr: u64, is_write: bool, token: u32);
    /// DRAM cycles ticked so far.
    fn now(&self) -> u64;
    /// The earliest DRAM cycle (at least [`Self::now`]) whose tick may change anything,
    /// given no further `add`; `now()` when the backend cannot tell.
    fn next_event(&self) -> u64;
    /// Ticks DRAM cycles until `now() == to`, pushing the tokens of completed bursts in the
    /// order they complete.
    fn run_until(&mut self, to: u64, done: &mut Vec<u32>);
    /// Fills the command, row and energy fields of `stats`.
    fn fill_stats(&self, stats: &mut MemStats);
}

/// One accepted request whose bursts are not all back.
#[derive(Clone, Copy, Debug)]
struct Slot {
    response: MemResponse,
    bursts_left: u64,
}

/// A staged burst: address, request slot and arrival order.
#[derive(Clone, Copy, Debug)]
struct Staged {
    addr: u64,
    slot: u32,
    seq: u64,
}

/// A [`MemoryPort`] over a [`Backend`]. See the module documentation.
pub struct BurstPort<B: Backend> {
    pub(crate) backend: B,
    crossing: ClockCrossing,
    burst_bytes: u32,
    peak_bytes_per_unit_cycle: f64,
    cycle: u64,
    /// Staging queues, index `2 * channel + is_write`.
    staged: Vec<VecDeque<Staged>>,
    staged_total: usize,
    staging_cap: usize,
    seq: u64,
    slots: Vec<Option<Slot>>,
    free_slots: Vec<u32>,
    in_flight: usize,
    done: VecDeque<MemResponse>,
    completed: Vec<u32>,
    /// Bursts per staging queue of the request being offered (scratch).
    need: Vec<usize>,
    stats: MemStats,
}

/// The shipped configuration called `name`, or an error listing the known ones.
pub fn shipped_system(name: &str) -> Result<&'static SystemConfig, DramError> {
    system(name).ok_or_else(|| DramError::UnknownSystem {
        name: name.to_string(),
        known: SYSTEMS
            .iter()
            .map(|s| s.name)
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// Writes a cycle-accurate backend's command counts, row hits and the energy they imply into
/// `s` (the same for every backend that counts commands).
pub fn fill_command_stats(
    s: &mut MemStats,
    config: &SystemConfig,
    counts: &CommandCounts,
    row_hits: u64,
    dies_per_rank: u32,
    tck_ns: f64,
) {
    s.row_hits = row_hits;
    s.row_misses = (counts.read + counts.write).saturating_sub(row_hits);
    s.act_commands = counts.act;
    s.read_commands = counts.read;
    s.write_commands = counts.write;
    s.refresh_commands = counts.refresh;
    s.energy_pj = Some(energy::energy(
        config.memspec,
        counts,
        dies_per_rank,
        tck_ns,
    ));
}

impl<B: Backend> BurstPort<B> {
    /// A port over `backend`, which runs `config` with DRAM clock period `tck_ns`, driven by
    /// a unit clock of period `unit_period_fs`: bursts of `bus_width / 8 * BL` bytes and
    /// two transfers per DRAM clock on each channel.
    pub fn for_system(
        backend: B,
        config: &SystemConfig,
        tck_ns: f64,
        unit_period_fs: PeriodFs,
    ) -> Result<Self, DramError> {
        if unit_period_fs == 0 {
            return Err(DramError::Config("unit clock period of zero".into()));
        }
        let channels = config.int("channels")?;
        let bus_bits = config.int("bus_width")?;
        let bl = config.int("BL")?;
        let peak_bytes_per_ns = channels as f64 * bus_bits as f64 / 8.0 * 2.0 / tck_ns;
        Ok(Self::new(
            backend,
            ClockCrossing::new(unit_period_fs, period_fs_from_ns(tck_ns)),
            (bus_bits / 8 * bl) as u32,
            peak_bytes_per_ns * unit_period_fs as f64 * 1e-6,
        ))
    }

    /// A port over `backend`, whose bursts are `burst_bytes` long, crossing from the unit
    /// clock to the DRAM clock with `crossing`.
    pub fn new(
        backend: B,
        crossing: ClockCrossing,
        burst_bytes: u32,
        peak_bytes_per_unit_cycle: f64,
    ) -> Self {
        let queues = 2 * backend.channels();
        Self {
            backend,
            crossing,
            burst_bytes,
            peak_bytes_per_unit_cycle,
            cycle: 0,
            staged: vec![VecDeque::new(); queues],
            staged_total: 0,
            staging_cap: STAGING_BURSTS,
            seq: 0,
            slots: Vec::new(),
            free_slots: Vec::new(),
            in_flight: 0,
            done: VecDeque::new(),
            completed: Vec::new(),
            need: vec![0; queues],
            stats: MemStats::default(),
        }
    }

    /// DRAM clock cycles simulated so far.
    pub fn dram_cycle(&self) -> u64 {
        self.backend.now()
    }

    /// The backend.
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// Before a DRAM tick: each channel takes what it accepts, oldest first.
    fn feed(&mut self) {
        for ch in 0..self.staged.len() / 2 {
            loop {
                let r = self.staged[2 * ch].front().map(|s| s.seq);
                let w = self.staged[2 * ch + 1].front().map(|s| s.seq);
                let r_ok = r.is_some() && self.backend.can_add(ch, false);
                let w_ok = w.is_some() && self.backend.can_add(ch, true);
                let is_write = match (r_ok, w_ok) {
                    (false, false) => break,
                    (true, false) => false,
                    (false, true) => true,
                    (true, true) => w < r,
                };
                let q = 2 * ch + is_write as usize;
                let s = self.staged[q].pop_front().expect("checked");
                self.staged_total -= 1;
                self.backend.add(ch, s.addr, is_write, s.slot);
            }
        }
    }

    /// Runs `k` DRAM cycles, feeding staged bursts before each.
    fn run_dram(&mut self, k: u64) {
        let end = self.backend.now() + k;
        while self.backend.now() < end {
            if self.staged_total > 0 {
                self.feed();
            }
            let now = self.backend.now();
            let ev = self.backend.next_event();
            let to = if ev > now { ev.min(end) } else { now + 1 };
            self.backend.run_until(to, &mut self.completed);
        }
    }

    /// Hands completed bursts to their requests.
    fn retire(&mut self) {
        for &slot in &self.completed {
            let entry = self.slots[slot as usize].as_mut().expect("live slot");
            match entry.response.kind {
                AccessKind::Read => self.stats.read_bursts += 1,
                AccessKind::Write => self.stats.write_bursts += 1,
            }
            entry.bursts_left -= 1;
            if entry.bursts_left == 0 {
                let mut response = entry.response;
                response.completed_cycle = self.cycle;
                self.slots[slot as usize] = None;
                self.free_slots.push(slot);
                self.in_flight -= 1;
                self.done.push_back(response);
            }
        }
        self.completed.clear();
    }
}

impl<B: Backend> MemoryPort for BurstPort<B> {
    fn name(&self) -> String {
        self.backend.name()
    }

    fn burst_bytes(&self) -> u32 {
        self.burst_bytes
    }

    fn peak_bytes_per_unit_cycle(&self) -> f64 {
        self.peak_bytes_per_unit_cycle
    }

    fn send(&mut self, request: MemRequest) -> Result<(), MemRequest> {
        assert!(request.bytes > 0, "memory request of zero bytes");
        let b = self.burst_bytes as u64;
        let bursts = bursts_of(request.addr, request.bytes, self.burst_bytes);
        let is_write = request.kind == AccessKind::Write;
        let first = request.addr / b * b;
        // Room in every staging queue the bursts go to.
        self.need.iter_mut().for_each(|n| *n = 0);
        let channels = self.staged.len() / 2;
        if channels == 1 {
            self.need[is_write as usize] = bursts as usize;
        } else {
            // Channels repeat with a period of at most `channels` bursts in any address
            // map that puts channel bits above the burst offset; count them all anyway.
            for i in 0..bursts {
                let ch = self.backend.channel_of(first + i * b);
                self.need[2 * ch + is_write as usize] += 1;
            }
        }
        for (q, &n) in self.need.iter().enumerate() {
            let len = self.staged[q].len();
            if n > 0 && len > 0 && len + n > self.staging_cap {
                return Err(request);
            }
        }
        let slot = self.free_slots.pop().unwrap_or_else(|| {
            self.slots.push(None);
            (self.slots.len() - 1) as u32
        });
        self.slots[slot as usize] = Some(Slot {
            response: MemResponse {
                tag: request.tag,
                kind: request.kind,
                accepted_cycle: self.cycle,
                completed_cycle: 0,
            },
            bursts_left: bursts,
        });
        for i in 0..bursts {
            let addr = first + i * b;
            let ch = if channels == 1 {
                0
            } else {
                self.backend.channel_of(addr)
            };
            self.staged[2 * ch + is_write as usize].push_back(Staged {
                addr,
                slot,
                seq: self.seq,
            });
            self.seq += 1;
        }
        self.staged_total += bursts as usize;
        self.in_flight += 1;
        match request.kind {
            AccessKind::Read => {
                self.stats.read_requests += 1;
                self.stats.bytes_read += bursts * b;
            }
            AccessKind::Write => {
                self.stats.write_requests += 1;
                self.stats.bytes_written += bursts * b;
            }
        }
        Ok(())
    }

    #[inline]
    fn tick(&mut self) {
        self.cycle += 1;
        let k = self.crossing.step();
        if k > 0 {
            // Fast path: nothing staged and nothing due in this unit cycle.
            let now = self.backend.now();
            if self.staged_total == 0 && self.backend.next_event() >= now + k {
                self.backend.run_until(now + k, &mut self.completed);
            } else {
                self.run_dram(k);
            }
        }
        if !self.completed.is_empty() {
            self.retire();
        }
    }

    fn tick_many(&mut self, cycles: u64) {
        if self.in_flight == 0 {
            // Nothing can complete: run the DRAM clock (refresh goes on) without per-unit
            // bookkeeping. Equal to `cycles` ticks.
            let k = self.crossing.step_many(cycles);
            let to = self.backend.now() + k;
            self.backend.run_until(to, &mut self.completed);
            self.cycle += cycles;
            debug_assert!(self.completed.is_empty());
        } else {
            for _ in 0..cycles {
                self.tick();
            }
        }
    }

    fn pop_response(&mut self) -> Option<MemResponse> {
        self.done.pop_front()
    }

    fn cycle(&self) -> u64 {
        self.cycle
    }

    fn outstanding(&self) -> usize {
        self.in_flight + self.done.len()
    }

    fn completed_waiting(&self) -> usize {
        self.done.len()
    }

    fn stats(&self) -> MemStats {
        let mut s = MemStats {
            unit_cycles: self.cycle,
            dram_cycles: self.backend.now(),
            ..self.stats.clone()
        };
        self.backend.fill_stats(&mut s);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dram::dramsim3::Dramsim3Port;
    use crate::dram::lpddr::LpddrPort;

    fn req(tag: u64, addr: u64, bytes: u32, kind: AccessKind) -> MemRequest {
        MemRequest {
            tag,
            addr,
            bytes,
            kind,
        }
    }

    /// Staging per channel and direction, checked without ticks (nothing leaves staging).
    fn staging_has_no_head_of_line_blocking(port: &mut dyn MemoryPort) {
        let w = AccessKind::Write;
        let r = AccessKind::Read;
        // Channel bit 6 (two channels, 64-B bursts): even bursts on channel 0.
        for i in 0..STAGING_BURSTS as u64 {
            assert!(port.send(req(i, i * 128, 64, w)).is_ok());
        }
        // Channel 0's write queue is full: a write to it is refused ...
        assert!(port.send(req(100, 1 << 20, 64, w)).is_err());
        // ... but reads to it and writes to channel 1 go on.
        assert!(port.send(req(101, 1 << 20, 64, r)).is_ok());
        assert!(port.send(req(102, (1 << 20) + 64, 64, w)).is_ok());
        // A request whose bursts would overshoot a queue is refused as a whole: 14 more
        // reads on channel 0 (15 staged), then a 3-burst read (channels 0, 1, 0) does not
        // fit, though 2 bursts would.
        for i in 0..14u64 {
            assert!(port.send(req(200 + i, (2 << 20) + i * 128, 64, r)).is_ok());
        }
        assert!(port.send(req(300, 3 << 20, 192, r)).is_err());
        // A request larger than a whole queue (80 bursts, 40 on each channel) is refused
        // while a queue it goes to holds anything ...
        assert!(port.send(req(301, 4 << 20, 64 * 80, w)).is_err());
        port.drain();
        let n = std::iter::from_fn(|| port.pop_response()).count();
        assert_eq!(n, STAGING_BURSTS + 2 + 14);
        // ... and accepted once they are empty.
        assert!(port.send(req(302, 4 << 20, 64 * 80, w)).is_ok());
        port.drain();
        assert_eq!(port.pop_response().map(|x| x.tag), Some(302));
    }

    #[test]
    fn staging_is_per_channel_and_direction_on_both_backends() {
        staging_has_no_head_of_line_blocking(
            &mut Dramsim3Port::open("lpddr3-1600-2x64", 1_000_000).unwrap(),
        );
        staging_has_no_head_of_line_blocking(
            &mut LpddrPort::open("lpddr3-1600-2x64", 1_000_000).unwrap(),
        );
    }
}
