//! Exact clock-domain crossing.
//!
//! A unit clocked at 1 GHz drives a DRAM clocked at 800 MHz (LPDDR3-1600) or 666.7 MHz
//! (LPDDR3-1333). Rounding the ratio would drift by whole DRAM cycles over a long run, so
//! periods are kept as integer femtoseconds and the crossing carries the remainder from
//! one unit cycle to the next: after `n` unit cycles the slow domain has advanced exactly
//! `floor(n * unit_period / other_period)` cycles.

/// One femtosecond per unit: a clock period in femtoseconds (1 GHz = 1,000,000 fs).
pub type PeriodFs = u64;

/// Converts a period in nanoseconds (as DRAM configuration files give `tCK`) to
/// femtoseconds, rounding to the nearest femtosecond.
pub fn period_fs_from_ns(ns: f64) -> PeriodFs {
    (ns * 1e6).round() as PeriodFs
}

/// Converts a frequency in hertz to a period in femtoseconds, rounded to the nearest
/// femtosecond.
pub fn period_fs_from_hz(hz: f64) -> PeriodFs {
    (1e15 / hz).round() as PeriodFs
}

/// The number of `other`-domain cycles that elapse in each cycle of the driving domain.
#[derive(Clone, Debug)]
pub struct ClockCrossing {
    driver_period_fs: PeriodFs,
    other_period_fs: PeriodFs,
    /// Femtoseconds of driver time not yet converted into whole `other` cycles.
    carry_fs: PeriodFs,
}

impl ClockCrossing {
    /// A crossing from a driving clock to another clock, both given as periods.
    ///
    /// # Panics
    /// If either period is zero.
    pub fn new(driver_period_fs: PeriodFs, other_period_fs: PeriodFs) -> Self {
        assert!(
            driver_period_fs > 0 && other_period_fs > 0,
            "clock periods must be non-zero"
        );
        Self {
            driver_period_fs,
            other_period_fs,
            carry_fs: 0,
        }
    }

    /// Advances the driving clock by one cycle and returns how many cycles of the other
    /// clock complete during it.
    pub fn step(&mut self) -> u64 {
        self.carry_fs += self.driver_period_fs;
        let n = self.carry_fs / self.other_period_fs;
        self.carry_fs -= n * self.other_period_fs;
        n
    }

    /// Advances the driving clock by `cycles` cycles at once and returns how many cycles of
    /// the other clock complete (the same total as `cycles` calls of [`Self::step`]).
    pub fn step_many(&mut self, cycles: u64) -> u64 {
        let total = self.carry_fs as u128 + cycles as u128 * self.driver_period_fs as u128;
        let n = total / self.other_period_fs as u128;
        self.carry_fs = (total - n * self.other_period_fs as u128) as PeriodFs;
        n as u64
    }

    /// Period of the driving clock in femtoseconds.
    pub fn driver_period_fs(&self) -> PeriodFs {
        self.driver_period_fs
    }

    /// Period of the other clock in femtoseconds.
    pub fn other_period_fs(&self) -> PeriodFs {
        self.other_period_fs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_ghz_to_800_mhz_is_exactly_four_fifths() {
        let mut c = ClockCrossing::new(period_fs_from_hz(1e9), period_fs_from_ns(1.25));
        let total: u64 = (0..1_000_000).map(|_| c.step()).sum();
        assert_eq!(total, 800_000);
    }

    #[test]
    fn lpddr3_1333_does_not_drift() {
        // tCK = 1.5 ns: 2 DRAM cycles every 3 ns.
        let mut c = ClockCrossing::new(period_fs_from_hz(1e9), period_fs_from_ns(1.5));
        let steps: Vec<u64> = (0..6).map(|_| c.step()).collect();
        assert_eq!(steps, vec![0, 1, 1, 0, 1, 1]);
        let total: u64 = (0..2_999_994).map(|_| c.step()).sum();
        assert_eq!(total + 4, 2_000_000);
    }

    #[test]
    fn step_many_equals_repeated_steps() {
        for (a, b) in [
            (1_000_000, 1_250_000),
            (1_000_000, 1_500_000),
            (1_250_000, 1_000_000),
            (7, 3),
        ] {
            let mut one = ClockCrossing::new(a, b);
            let mut many = ClockCrossing::new(a, b);
            for chunk in [1u64, 2, 3, 17, 1000, 5] {
                let s: u64 = (0..chunk).map(|_| one.step()).sum();
                assert_eq!(many.step_many(chunk), s);
            }
        }
    }
}
