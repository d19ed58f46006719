//! A peak-bandwidth-plus-fixed-latency memory: the quick what-if and unit-test backend.
//!
//! Bursts are served one after another on a single data bus at the configured peak
//! bandwidth; a request completes a fixed latency after its last burst has crossed the bus.
//! There are no rows, banks, refreshes or commands, so this model is an upper bound on what
//! a real DRAM delivers (DRAMsim3 reaches about 93 % of peak on a sequential stream and a
//! third of it on random rows, `shared/reference/hardware.md` §1.1). Time is kept in exact
//! integer units (femtoseconds times bytes per second), so no rounding accumulates.

use std::collections::VecDeque;

use super::{bursts_of, AccessKind, MemRequest, MemResponse, MemStats, MemoryPort};
use crate::clock::PeriodFs;

/// Configuration of [`SimpleDram`].
#[derive(Clone, Debug, PartialEq)]
pub struct SimpleDramConfig {
    /// Period of the unit clock that drives the port (1 GHz = 1,000,000 fs).
    pub unit_period_fs: PeriodFs,
    /// Peak bandwidth in bytes per second.
    pub peak_bytes_per_s: u64,
    /// Time from the end of a request's last burst to its completion, in nanoseconds.
    pub latency_ns: u64,
    /// Bytes per burst.
    pub burst_bytes: u32,
    /// Requests that may be outstanding (accepted, not yet complete) at once.
    pub queue_capacity: usize,
}

impl SimpleDramConfig {
    /// 12.8 GB/s (one 64-bit LPDDR3-1600 channel), 64-byte bursts, 40 ns latency, a 32-entry
    /// queue, driven at 1 GHz.
    pub fn lpddr3_1600_1x64_like() -> Self {
        Self {
            unit_period_fs: 1_000_000,
            peak_bytes_per_s: 12_800_000_000,
            latency_ns: 40,
            burst_bytes: 64,
            queue_capacity: 32,
        }
    }
}

/// The simple backend. See the module documentation.
#[derive(Clone, Debug)]
pub struct SimpleDram {
    config: SimpleDramConfig,
    cycle: u64,
    /// Time at which the bus is next free, in femtoseconds x bytes/s.
    bus_free_scaled: u128,
    /// Accepted requests in completion order, with their completion cycle.
    in_flight: VecDeque<(u64, MemResponse)>,
    /// Completion cycle of the first request in flight (`u64::MAX` when none).
    next_due: u64,
    done: VecDeque<MemResponse>,
    stats: MemStats,
}

impl SimpleDram {
    /// A new, idle memory.
    ///
    /// # Panics
    /// If a period, the bandwidth, the burst size or the queue capacity is zero.
    pub fn new(config: SimpleDramConfig) -> Self {
        assert!(
            config.unit_period_fs > 0
                && config.peak_bytes_per_s > 0
                && config.burst_bytes > 0
                && config.queue_capacity > 0,
            "SimpleDram: zero in configuration {config:?}"
        );
        Self {
            config,
            cycle: 0,
            bus_free_scaled: 0,
            in_flight: VecDeque::new(),
            next_due: u64::MAX,
            done: VecDeque::new(),
            stats: MemStats::default(),
        }
    }

    /// Moves the requests due by now to the completed queue (out of line: most cycles
    /// complete nothing).
    #[inline(never)]
    fn retire(&mut self) {
        while let Some(&(c, r)) = self.in_flight.front() {
            if c > self.cycle {
                break;
            }
            self.in_flight.pop_front();
            self.done.push_back(r);
        }
        self.next_due = self.in_flight.front().map_or(u64::MAX, |f| f.0);
    }

    fn now_scaled(&self) -> u128 {
        self.cycle as u128
            * self.config.unit_period_fs as u128
            * self.config.peak_bytes_per_s as u128
    }
}

impl MemoryPort for SimpleDram {
    fn name(&self) -> String {
        format!(
            "simple({:.1} GB/s, {} ns)",
            self.config.peak_bytes_per_s as f64 / 1e9,
            self.config.latency_ns
        )
    }

    fn burst_bytes(&self) -> u32 {
        self.config.burst_bytes
    }

    fn peak_bytes_per_unit_cycle(&self) -> f64 {
        self.config.peak_bytes_per_s as f64 * self.config.unit_period_fs as f64 * 1e-15
    }

    fn refusals_lift_only_with_responses(&self) -> bool {
        // The queue is the requests in flight; one leaves only when it completes.
        true
    }

    fn send(&mut self, request: MemRequest) -> Result<(), MemRequest> {
        assert!(request.bytes > 0, "memory request of zero bytes");
        if self.in_flight.len() >= self.config.queue_capacity {
            return Err(request);
        }
        let bursts = bursts_of(request.addr, request.bytes, self.config.burst_bytes);
        let bytes = bursts * self.config.burst_bytes as u64;
        // One burst occupies burst_bytes / bw seconds = burst_bytes * 1e15 scaled units.
        let start = self.bus_free_scaled.max(self.now_scaled());
        self.bus_free_scaled = start + bytes as u128 * 1_000_000_000_000_000u128;
        let done_scaled = self.bus_free_scaled
            + self.config.latency_ns as u128 * 1_000_000 * self.config.peak_bytes_per_s as u128;
        let per_cycle = self.config.unit_period_fs as u128 * self.config.peak_bytes_per_s as u128;
        let completed_cycle = done_scaled.div_ceil(per_cycle) as u64;
        match request.kind {
            AccessKind::Read => {
                self.stats.read_requests += 1;
                self.stats.read_bursts += bursts;
                self.stats.bytes_read += bytes;
            }
            AccessKind::Write => {
                self.stats.write_requests += 1;
                self.stats.write_bursts += bursts;
                self.stats.bytes_written += bytes;
            }
        }
        let response = MemResponse {
            tag: request.tag,
            kind: request.kind,
            accepted_cycle: self.cycle,
            completed_cycle,
        };
        // The bus is serial and the latency fixed, so completions are in request order.
        debug_assert!(self.in_flight.back().is_none_or(|b| b.0 <= completed_cycle));
        self.in_flight.push_back((completed_cycle, response));
        self.next_due = self.next_due.min(completed_cycle);
        Ok(())
    }

    #[inline]
    fn tick(&mut self) {
        self.cycle += 1;
        if self.cycle >= self.next_due {
            self.retire();
        }
    }

    fn pop_response(&mut self) -> Option<MemResponse> {
        self.done.pop_front()
    }

    fn cycle(&self) -> u64 {
        self.cycle
    }

    fn outstanding(&self) -> usize {
        self.in_flight.len() + self.done.len()
    }

    fn completed_waiting(&self) -> usize {
        self.done.len()
    }

    #[inline]
    fn tick_and_count(&mut self) -> usize {
        self.tick();
        self.done.len()
    }

    fn stats(&self) -> MemStats {
        MemStats {
            unit_cycles: self.cycle,
            ..self.stats.clone()
        }
    }

    fn tick_many(&mut self, cycles: u64) {
        // Jump straight to the next completion when it is further than one cycle away.
        let target = self.cycle + cycles;
        while self.cycle < target {
            match self.in_flight.front() {
                Some(&(c, _)) if c <= target => {
                    self.cycle = c.max(self.cycle + 1) - 1;
                    self.tick();
                }
                _ => self.cycle = target,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(tag: u64, addr: u64, bytes: u32) -> MemRequest {
        MemRequest {
            tag,
            addr,
            bytes,
            kind: AccessKind::Read,
        }
    }

    #[test]
    fn sequential_stream_reaches_peak_bandwidth() {
        let mut m = SimpleDram::new(SimpleDramConfig::lpddr3_1600_1x64_like());
        let mut next = 0u64;
        let total = 10_000u64;
        let mut got = 0;
        while got < total {
            while next < total && m.send(read(next, next * 64, 64)).is_ok() {
                next += 1;
            }
            m.tick();
            while m.pop_response().is_some() {
                got += 1;
            }
        }
        let s = m.stats();
        assert_eq!(s.bytes_read, total * 64);
        let util = s.bus_utilization(m.peak_bytes_per_unit_cycle());
        assert!(util > 0.99 && util <= 1.0, "utilization {util}");
    }

    #[test]
    fn isolated_read_sees_transfer_plus_latency() {
        let mut m = SimpleDram::new(SimpleDramConfig::lpddr3_1600_1x64_like());
        m.send(read(7, 0, 64)).unwrap();
        // 64 B at 12.8 GB/s = 5 ns, plus 40 ns.
        let mut cycles = 0;
        loop {
            m.tick();
            cycles += 1;
            if let Some(r) = m.pop_response() {
                assert_eq!(r.tag, 7);
                assert_eq!(r.completed_cycle, 45);
                break;
            }
        }
        assert_eq!(cycles, 45);
    }

    #[test]
    fn full_queue_refuses_and_returns_the_request() {
        let cfg = SimpleDramConfig {
            queue_capacity: 2,
            ..SimpleDramConfig::lpddr3_1600_1x64_like()
        };
        let mut m = SimpleDram::new(cfg);
        assert!(m.send(read(0, 0, 64)).is_ok());
        assert!(m.send(read(1, 64, 64)).is_ok());
        assert_eq!(m.send(read(2, 128, 64)), Err(read(2, 128, 64)));
        assert_eq!(m.drain(), 50);
        assert_eq!(m.pop_response().map(|r| r.tag), Some(0));
        assert_eq!(m.pop_response().map(|r| r.tag), Some(1));
    }

    #[test]
    fn tick_many_equals_ticks() {
        let mut a = SimpleDram::new(SimpleDramConfig::lpddr3_1600_1x64_like());
        let mut b = a.clone();
        for i in 0..20 {
            a.send(read(i, i * 4096, 200)).unwrap();
            b.send(read(i, i * 4096, 200)).unwrap();
        }
        for _ in 0..500 {
            a.tick();
        }
        b.tick_many(123);
        b.tick_many(377);
        assert_eq!(a.cycle(), b.cycle());
        let ra: Vec<_> = std::iter::from_fn(|| a.pop_response()).collect();
        let rb: Vec<_> = std::iter::from_fn(|| b.pop_response()).collect();
        assert_eq!(ra, rb);
        assert_eq!(ra.len(), 20);
    }
}
