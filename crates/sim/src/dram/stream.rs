//! A lower bound on a memory system's energy and time for traffic that arrives as long,
//! consecutive bursts: the model \[P2\] §6.4 uses for the binned SAH builder of Doyle et
//! al. ("a lower-bound energy model by assuming fully utilized FPUs and long, consecutive
//! burst accesses to DRAM"), and Arbor uses for the other units whose traffic is counted
//! rather than simulated (the ATRBVH toplevel unit, the refit unit).
//!
//! For `read` and `write` bytes on a system of `channels` channels of `bus_width` bits,
//! bursts of `BL` beats and rows of `columns * bus_width / 8` bytes (per rank, all its
//! dies together):
//! - every burst carries `bus_width / 8 * BL` bytes (partial bursts round up);
//! - every row is opened once and closed once: `ceil(bytes / row)` ACT and PRE commands
//!   for the reads and again for the writes (streams never share a row);
//! - the data bus is busy every cycle: `bursts * BL / 2` DRAM clocks spread evenly over
//!   the channels, with one bank open on each channel's rank the whole time (active
//!   standby);
//! - refreshes: one per `tREFI` clocks of that time on every channel, rounded down (a
//!   stream shorter than `tREFI` is charged none, which keeps the bound a bound).
//!
//! Energies are the memspec's per-command figures and standby currents through
//! [`energy::energy`], the same formulas the cycle models' counts go through. The result
//! is a [`MemStats`] like a simulated run's, so callers treat both alike.

use super::energy::{self, CommandCounts};
use super::{dramsim3, DramError, MemStats};

/// The bound for `read` and `write` bytes on the shipped system `name` (a bare
/// `dram::open` name such as `lpddr3-1600-2x64`): its counts and energy, and the seconds
/// the transfer takes at full bus utilization.
pub fn streaming(name: &str, read: u64, write: u64) -> Result<(MemStats, f64), DramError> {
    // The bound assumes ideal bursts, so what-if options (address mapping, write drain)
    // do not change it.
    let name = super::base_system(name);
    let cfg = dramsim3::system(name).ok_or_else(|| {
        DramError::Config(format!(
            "streaming bound: unknown memory system '{name}' (known: {})",
            dramsim3::SYSTEMS
                .iter()
                .map(|s| s.name)
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    let channels = cfg.int("channels")?;
    let bus_width = cfg.int("bus_width")?;
    let bl = cfg.int("BL")?;
    let columns = cfg.int("columns")?;
    let device_width = cfg.int("device_width")?;
    let t_refi = cfg.int("tREFI")?;
    let tck_ns = cfg.tck_ns()?;
    if channels == 0 || bus_width < 8 || bl == 0 || columns == 0 || device_width == 0 {
        return Err(DramError::Config(format!("{name}: bad organisation")));
    }
    let burst = bus_width / 8 * bl;
    let row = columns * bus_width / 8;
    let (rb, wb) = (read.div_ceil(burst), write.div_ceil(burst));
    let acts = read.div_ceil(row) + write.div_ceil(row);
    // Data clocks per channel: BL beats at two per clock, bursts spread over channels.
    let clocks = ((rb + wb) * bl / 2).div_ceil(channels);
    let counts = CommandCounts {
        act: acts,
        pre: acts,
        read: rb,
        write: wb,
        refresh: clocks.checked_div(t_refi).map_or(0, |r| r * channels),
        active_rank_cycles: clocks * channels,
        precharged_rank_cycles: 0,
    };
    let dies = (bus_width / device_width) as u32;
    let e = energy::energy(cfg.memspec, &counts, dies, tck_ns);
    let seconds = clocks as f64 * tck_ns * 1e-9;
    let stats = MemStats {
        bytes_read: rb * burst,
        bytes_written: wb * burst,
        read_bursts: rb,
        write_bursts: wb,
        row_hits: (rb + wb).saturating_sub(acts),
        row_misses: acts.min(rb + wb),
        act_commands: acts,
        read_commands: rb,
        write_commands: wb,
        refresh_commands: counts.refresh,
        dram_cycles: clocks,
        energy_pj: Some(e),
        ..Default::default()
    };
    Ok((stats, seconds))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_counted_stream_on_the_medium_system() {
        // lpddr3-1600-2x64: 2 channels of 64 bits, BL 8 (64-B bursts), 1024 columns
        // (8 KB rows), tCK 1.25 ns, tREFI 3120. 1 MiB read, 64 KiB + 1 B written:
        // 16384 + 1025 bursts, 128 + 9 rows, (17409 * 4) / 2 = 34818 clocks per channel,
        // 11 refreshes per channel.
        let (s, secs) = streaming("lpddr3-1600-2x64", 1 << 20, (64 << 10) + 1).unwrap();
        assert_eq!((s.read_bursts, s.write_bursts), (16384, 1025));
        assert_eq!(s.act_commands, 137);
        assert_eq!(s.dram_cycles, 34818);
        assert_eq!(s.refresh_commands, 22);
        assert!((secs - 34818.0 * 1.25e-9).abs() < 1e-15);
        // The effective bandwidth is the peak, 25.6 GB/s.
        let bw = (s.bytes_read + s.bytes_written) as f64 / secs;
        assert!((bw / 25.6e9 - 1.0).abs() < 1e-3, "{bw}");
        // Energy by hand from the memspec figures (per die, two dies per rank):
        // reads 16384 * 1320 pJ, writes 1025 * 1510, ACT/PRE 137 * (2940 + 1110),
        // REF 22 * 26800, active standby 57.6 mW over 2 * 34818 clocks.
        let spec = &energy::MICRON_4GB_LPDDR3_1600_X32;
        let e = s.energy_pj.unwrap();
        let want = 2.0
            * (16384.0 * spec.read_burst_pj()
                + 1025.0 * spec.write_burst_pj()
                + 137.0 * (spec.act_pj() + spec.pre_pj())
                + 22.0 * spec.refresh_pj()
                + 2.0 * 34818.0 * 1.25 * spec.active_standby_mw());
        assert!((e.total_pj() / want - 1.0).abs() < 1e-12);
        assert!((e.read_pj / (2.0 * 16384.0 * 1320.0) - 1.0).abs() < 0.005);
    }

    #[test]
    fn more_traffic_costs_more_and_nothing_costs_nothing() {
        let (z, t) = streaming("lpddr3-1600-2x64", 0, 0).unwrap();
        assert_eq!(t, 0.0);
        assert_eq!(z.energy_pj.unwrap().total_pj(), 0.0);
        let mut last = 0.0;
        for mb in [1u64, 2, 8, 64] {
            let (s, _) = streaming("lpddr3-1600-2x64", mb << 20, 0).unwrap();
            let e = s.energy_pj.unwrap().total_pj();
            assert!(e > last);
            last = e;
        }
        // A faster system moves the same bytes in less time.
        let slow = streaming("lpddr3-1600-1x64", 8 << 20, 0).unwrap().1;
        let fast = streaming("lpddr3-1333-4x64", 8 << 20, 0).unwrap().1;
        assert!(fast < slow);
    }

    #[test]
    fn unknown_system_is_a_one_line_error() {
        let e = streaming("ddr9", 1, 1).unwrap_err().to_string();
        assert!(
            e.contains("unknown memory system 'ddr9'") && !e.contains('\n'),
            "{e}"
        );
    }
}
