//! DRAM energy from command counts, with the formulas of DRAMPower v4.
//!
//! DRAMPower (tag v4.1, `src/MemoryPowerModel.cc`, `shared/reference/hardware.md` §2.1)
//! charges, per die and per supply rail, then summed over rails:
//! - ACT: `V (IDD0 - IDD3N) tRAS`;
//! - PRE: `V (IDD0 - IDD2N) (tRC - tRAS)`;
//! - RD / WR burst: `V (IDD4R - IDD3N) (BL/2) tCK`, likewise with IDD4W;
//! - REF (all-bank): `V (IDD5 - IDD3N) tRFC`;
//! - background: `V IDD3N` while any bank of the rank is open (active standby) and
//!   `V IDD2N` while all are precharged (precharged standby).
//!
//! Power-down and self-refresh are never entered by Arbor's memory configurations, and the
//! LPDDR3 memspec gives no IO or termination figures, so those terms are absent. A command
//! acts on every die of a rank at once (two x32 dies behind a 64-bit channel), so each
//! count is multiplied by the dies per rank. The DRAMsim3 backend supplies the counts and
//! the exact active/precharged cycle split per rank (DRAMsim3 counts both every cycle).
//!
//! Approximation: the LPDDR3-1333 system uses the LPDDR3-1600 memspec (the only LPDDR3
//! memspec in the reference). Its per-command energies are kept as they are (they are
//! fixed currents over fixed times in ns), and background power is integrated over the
//! actual 1.5 ns clock. A real 1333 part draws somewhat less IDD4R/W per burst but for
//! longer, so read/write energy per bit is about the same.

use super::DramEnergy;

/// One supply rail of a die: its voltage and the IDD currents DRAMPower uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rail {
    /// Supply voltage in volts.
    pub volts: f64,
    /// IDD0: one bank activated and precharged repeatedly, in mA.
    pub idd0_ma: f64,
    /// IDD2N: precharged standby, in mA.
    pub idd2n_ma: f64,
    /// IDD3N: active standby, in mA.
    pub idd3n_ma: f64,
    /// IDD4R: burst read, in mA.
    pub idd4r_ma: f64,
    /// IDD4W: burst write, in mA.
    pub idd4w_ma: f64,
    /// IDD5: all-bank refresh, in mA.
    pub idd5_ma: f64,
}

/// The figures of one DRAM die that the energy formulas need (a DRAMPower memspec).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemSpec {
    /// The memspec's name.
    pub name: &'static str,
    /// Supply rails (VDD1, VDD2, and VDDQ where the memspec gives it).
    pub rails: &'static [Rail],
    /// Clock period in nanoseconds.
    pub tck_ns: f64,
    /// Burst length in beats (data is moved in BL/2 clocks).
    pub burst_length: u32,
    /// Row active time tRAS in clocks.
    pub t_ras_cycles: u32,
    /// Row cycle time tRC in clocks.
    pub t_rc_cycles: u32,
    /// All-bank refresh cycle time tRFC in clocks.
    pub t_rfc_cycles: u32,
}

/// MICRON_4Gb_LPDDR3-1600_32bit_A of DRAMPower v4.1 (`shared/reference/hardware.md` §2.1):
/// one x32 die, VDD1 = 1.8 V, VDD2 = 1.2 V, BL8 at 800 MHz; RAS 36, RC 48, RFC 104.
pub const MICRON_4GB_LPDDR3_1600_X32: MemSpec = MemSpec {
    name: "MICRON_4Gb_LPDDR3-1600_32bit_A",
    rails: &[
        Rail {
            volts: 1.8,
            idd0_ma: 15.0,
            idd2n_ma: 2.0,
            idd3n_ma: 2.0,
            idd4r_ma: 5.0,
            idd4w_ma: 10.0,
            idd5_ma: 40.0,
        },
        Rail {
            volts: 1.2,
            idd0_ma: 80.0,
            idd2n_ma: 38.0,
            idd3n_ma: 45.0,
            idd4r_ma: 260.0,
            idd4w_ma: 284.0,
            idd5_ma: 160.0,
        },
    ],
    tck_ns: 1.25,
    burst_length: 8,
    t_ras_cycles: 36,
    t_rc_cycles: 48,
    t_rfc_cycles: 104,
};

/// JEDEC_8Gb_LPDDR4-3200_16bit of DRAMSys (`shared/reference/hardware.md` §1.2 timing,
/// §2.2 currents): one x16 channel, VDD1 = 1.8 V, VDD2 = 1.1 V, VDDQ = 1.1 V (read current
/// only), BL16 at 1.6 GHz; RAS 68, RCpb 97, RFCab 448.
pub const JEDEC_8GB_LPDDR4_3200_X16: MemSpec = MemSpec {
    name: "JEDEC_8Gb_LPDDR4-3200_16bit",
    rails: &[
        Rail {
            volts: 1.8,
            idd0_ma: 3.5,
            idd2n_ma: 2.0,
            idd3n_ma: 2.25,
            idd4r_ma: 2.25,
            idd4w_ma: 2.25,
            idd5_ma: 10.0,
        },
        Rail {
            volts: 1.1,
            idd0_ma: 45.0,
            idd2n_ma: 27.0,
            idd3n_ma: 30.0,
            idd4r_ma: 275.0,
            idd4w_ma: 210.0,
            idd5_ma: 90.0,
        },
        Rail {
            volts: 1.1,
            idd0_ma: 0.0,
            idd2n_ma: 0.0,
            idd3n_ma: 0.0,
            idd4r_ma: 150.0,
            idd4w_ma: 0.0,
            idd5_ma: 0.0,
        },
    ],
    tck_ns: 0.625,
    burst_length: 16,
    t_ras_cycles: 68,
    t_rc_cycles: 97,
    t_rfc_cycles: 448,
};

impl MemSpec {
    /// Sum over rails of `V * f(rail)` in milliwatts.
    fn power_mw(&self, f: impl Fn(&Rail) -> f64) -> f64 {
        self.rails.iter().map(|r| r.volts * f(r)).sum()
    }

    fn ns(&self, cycles: f64) -> f64 {
        cycles * self.tck_ns
    }

    /// Energy of one ACT on one die, in picojoules (mW x ns = pJ).
    pub fn act_pj(&self) -> f64 {
        self.power_mw(|r| r.idd0_ma - r.idd3n_ma) * self.ns(self.t_ras_cycles as f64)
    }

    /// Energy of one PRE on one die, in picojoules.
    pub fn pre_pj(&self) -> f64 {
        self.power_mw(|r| r.idd0_ma - r.idd2n_ma)
            * self.ns((self.t_rc_cycles - self.t_ras_cycles) as f64)
    }

    /// Energy of one read burst on one die, in picojoules.
    pub fn read_burst_pj(&self) -> f64 {
        self.power_mw(|r| r.idd4r_ma - r.idd3n_ma) * self.ns(self.burst_length as f64 / 2.0)
    }

    /// Energy of one write burst on one die, in picojoules.
    pub fn write_burst_pj(&self) -> f64 {
        self.power_mw(|r| r.idd4w_ma - r.idd3n_ma) * self.ns(self.burst_length as f64 / 2.0)
    }

    /// Energy of one all-bank refresh on one die, in picojoules.
    pub fn refresh_pj(&self) -> f64 {
        self.power_mw(|r| r.idd5_ma - r.idd3n_ma) * self.ns(self.t_rfc_cycles as f64)
    }

    /// Active-standby power of one die (a bank open), in milliwatts.
    pub fn active_standby_mw(&self) -> f64 {
        self.power_mw(|r| r.idd3n_ma)
    }

    /// Precharged-standby power of one die (all banks closed), in milliwatts.
    pub fn precharged_standby_mw(&self) -> f64 {
        self.power_mw(|r| r.idd2n_ma)
    }
}

/// Command counts and background time of one run, summed over channels and ranks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandCounts {
    /// ACT commands.
    pub act: u64,
    /// PRE commands (single-bank and all-bank).
    pub pre: u64,
    /// RD commands (one burst each).
    pub read: u64,
    /// WR commands (one burst each).
    pub write: u64,
    /// All-bank REF commands.
    pub refresh: u64,
    /// Rank-cycles (DRAM clocks x ranks) with at least one bank open.
    pub active_rank_cycles: u64,
    /// Rank-cycles with every bank precharged.
    pub precharged_rank_cycles: u64,
}

/// Energy of `counts` on ranks of `dies_per_rank` dies of `spec`, whose clock period is
/// `tck_ns` (background time is counted in that clock; per-command energies are the
/// memspec's, see the module documentation).
pub fn energy(
    spec: &MemSpec,
    counts: &CommandCounts,
    dies_per_rank: u32,
    tck_ns: f64,
) -> DramEnergy {
    let dies = dies_per_rank as f64;
    let background_pj = (counts.active_rank_cycles as f64 * spec.active_standby_mw()
        + counts.precharged_rank_cycles as f64 * spec.precharged_standby_mw())
        * tck_ns
        * dies;
    let refresh_pj = counts.refresh as f64 * spec.refresh_pj() * dies;
    // An idle memory over the same rank-cycles: every bank precharged, same refreshes.
    let rank_cycles = (counts.active_rank_cycles + counts.precharged_rank_cycles) as f64;
    let idle_pj = rank_cycles * spec.precharged_standby_mw() * tck_ns * dies + refresh_pj;
    DramEnergy {
        act_pre_pj: (counts.act as f64 * spec.act_pj() + counts.pre as f64 * spec.pre_pj()) * dies,
        read_pj: counts.read as f64 * spec.read_burst_pj() * dies,
        write_pj: counts.write as f64 * spec.write_burst_pj() * dies,
        refresh_pj,
        background_pj,
        idle_pj,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative difference, for figures the reference prints to three digits.
    fn close(got: f64, want: f64, rel: f64) -> bool {
        ((got - want) / want).abs() <= rel
    }

    #[test]
    fn lpddr3_per_die_figures_match_the_reference() {
        // shared/reference/hardware.md 2.1 "derived per die", printed to 3 digits, so a
        // 0.5 % band covers their rounding and nothing more.
        let s = MICRON_4GB_LPDDR3_1600_X32;
        for (got, want, what) in [
            (s.act_pj(), 2940.0, "ACT"),
            (s.pre_pj(), 1110.0, "PRE"),
            (s.read_burst_pj(), 1320.0, "RD"),
            (s.write_burst_pj(), 1510.0, "WR"),
            (s.refresh_pj(), 26800.0, "REF"),
            (s.active_standby_mw(), 57.6, "active standby"),
            (s.precharged_standby_mw(), 49.2, "precharged standby"),
        ] {
            assert!(close(got, want, 0.005), "{what}: {got} vs {want}");
        }
        // 5.1 pJ/bit for a 32-B read burst.
        assert!(close(s.read_burst_pj() / 256.0, 5.1, 0.01));
    }

    #[test]
    fn lpddr4_per_channel_figures_match_the_reference() {
        // shared/reference/hardware.md 2.2, printed to 2-3 digits.
        let s = JEDEC_8GB_LPDDR4_3200_X16;
        assert!(close(s.act_pj(), 800.0, 0.01), "{}", s.act_pj());
        assert!(close(s.pre_pj(), 410.0, 0.01), "{}", s.pre_pj());
        // Core 1.35 nJ + VDDQ 0.83 nJ.
        assert!(
            close(s.read_burst_pj(), 2180.0, 0.01),
            "{}",
            s.read_burst_pj()
        );
        assert!(
            close(s.write_burst_pj(), 990.0, 0.01),
            "{}",
            s.write_burst_pj()
        );
        assert!(close(s.refresh_pj(), 22400.0, 0.01), "{}", s.refresh_pj());
        assert!(close(s.active_standby_mw(), 37.0, 0.01));
    }

    #[test]
    fn sixty_four_byte_line_on_two_dies() {
        // Reference 2.1: a row-hit 64-B read on a 64-bit channel costs 2.6 nJ, a row miss
        // including ACT+PRE 10.7 nJ.
        let s = MICRON_4GB_LPDDR3_1600_X32;
        let hit = energy(
            &s,
            &CommandCounts {
                read: 1,
                ..Default::default()
            },
            2,
            1.25,
        );
        assert!(close(hit.total_pj(), 2640.0, 0.01), "{}", hit.total_pj());
        let miss = energy(
            &s,
            &CommandCounts {
                act: 1,
                pre: 1,
                read: 1,
                ..Default::default()
            },
            2,
            1.25,
        );
        assert!(close(miss.total_pj(), 10740.0, 0.01), "{}", miss.total_pj());
    }

    #[test]
    fn background_uses_the_split_of_cycles() {
        let s = MICRON_4GB_LPDDR3_1600_X32;
        // 800 active + 800 precharged clocks of one die: 1 us at 57.6 and 1 us at 49.2 mW.
        let e = energy(
            &s,
            &CommandCounts {
                active_rank_cycles: 800,
                precharged_rank_cycles: 800,
                ..Default::default()
            },
            1,
            1.25,
        );
        assert!(
            close(e.background_pj, 57_600.0 + 49_200.0, 1e-9),
            "{}",
            e.background_pj
        );
        assert_eq!(e.act_pre_pj + e.read_pj + e.write_pj + e.refresh_pj, 0.0);
    }

    #[test]
    fn idle_term_is_precharged_standby_and_refresh() {
        let s = MICRON_4GB_LPDDR3_1600_X32;
        // 800 + 800 clocks of one die with 2 refreshes: idle = 2 us at 49.2 mW + 2 REF.
        let counts = CommandCounts {
            active_rank_cycles: 800,
            precharged_rank_cycles: 800,
            refresh: 2,
            act: 3,
            pre: 3,
            read: 10,
            ..Default::default()
        };
        let e = energy(&s, &counts, 1, 1.25);
        let idle = 2.0 * 49_200.0 + 2.0 * s.refresh_pj();
        assert!(close(e.idle_pj, idle, 1e-3), "{} vs {idle}", e.idle_pj);
        // Above idle: the commands and the active-standby surplus, nothing else.
        let want = 3.0 * (s.act_pj() + s.pre_pj())
            + 10.0 * s.read_burst_pj()
            + 800.0 * 1.25 * (s.active_standby_mw() - s.precharged_standby_mw());
        assert!(
            close(e.above_idle_pj(), want, 1e-9),
            "{}",
            e.above_idle_pj()
        );
        // An idle run (all precharged, refresh only) adds nothing over idle.
        let idle_run = energy(
            &s,
            &CommandCounts {
                precharged_rank_cycles: 1600,
                refresh: 2,
                ..Default::default()
            },
            2,
            1.25,
        );
        assert!(idle_run.above_idle_pj().abs() < 1e-6);
        assert!(idle_run.total_pj() > 0.0);
    }
}
