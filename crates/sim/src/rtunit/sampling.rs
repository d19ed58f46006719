//! The sampling error of a sampled run: how far its frame estimates may lie from a whole
//! frame's.
//!
//! A run with `sample` = k times one chunk of tiles in each run of k chunks, drawn at a
//! hashed position (stratified sampling, one unit per stratum; `super::plan`). Each timed
//! chunk is measured in a window (from its first timed ray's retirement to its last;
//! chunks that follow each other closely share one), and the frame figures are ratio
//! estimates over the windows: rays per cycle (MRPS), bytes per pixel (frame traffic),
//! rays per pixel (frame rays). With one unit per stratum the variance of a total has no
//! unbiased estimate; the usual stand-in is the successive-difference estimator over the
//! units in stratum order (Wolter, *Introduction to Variance Estimation*, 2nd ed., §8.2),
//! applied here to the ratio estimator's linearized residuals, with the finite population
//! correction `1 - 1/k`. It is the error of sampling alone: the warm-up of a chunk's
//! caches by functional warming, not by the full model, is a bias it does not see.

use serde::Serialize;

/// One measurement window of a sampled run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Window {
    /// Camera pixels of the timed rays it closed (issued since the last window closed).
    pub pixels: u64,
    /// Timed rays retired since the last window closed.
    pub rays: u64,
    /// Rays retired inside the window (timed or not: the throughput's numerator).
    pub window_rays: u64,
    /// Its cycles.
    pub cycles: u64,
    /// DRAM bytes fetched for timed rays since the last window closed.
    pub bytes: u64,
    /// Node visits of timed rays since the last window closed.
    pub visits: u64,
    /// Triangle tests of timed rays since the last window closed.
    pub tests: u64,
}

/// A run's energy by what drives it, in mJ: the frame energy is taken as linear in these
/// (see [`frame_energy_rel_se`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnergyDrivers {
    /// Per node visit (TRV, stacks, node caches, FIFOs).
    pub visits_mj: f64,
    /// Per triangle test (IST).
    pub tests_mj: f64,
    /// Per DRAM byte.
    pub bytes_mj: f64,
    /// Per cycle (leakage, the memory's background).
    pub time_mj: f64,
}

/// Relative standard errors of a sampled run's frame estimates (fractions of the
/// estimate; the frame energy's is [`frame_energy_rel_se`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct SamplingError {
    /// Windows measured.
    pub windows: u64,
    /// Of the throughput (MRPS).
    pub mrps: f64,
    /// Of the frame's DRAM traffic.
    pub frame_traffic: f64,
    /// Of the frame's ray count.
    pub frame_rays: f64,
}

/// The relative standard error of the ratio `sum(y) / sum(x)` estimated from units in
/// stratum order, one per stratum, of which a fraction `f` of the population was
/// sampled: the successive-difference variance of the residuals `y - r x`, times
/// `1 - f`, over `sum(y)`. `None` with fewer than two units or an empty numerator or
/// denominator.
pub fn ratio_rel_se(y: &[f64], x: &[f64], f: f64) -> Option<f64> {
    let n = y.len();
    if n < 2 || x.len() != n {
        return None;
    }
    let (sy, sx): (f64, f64) = (y.iter().sum(), x.iter().sum());
    if !(sy > 0.0 && sx > 0.0) {
        return None;
    }
    let r = sy / sx;
    let d: Vec<f64> = y.iter().zip(x).map(|(y, x)| y - r * x).collect();
    let sq: f64 = d.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum();
    let var = n as f64 / (2.0 * (n - 1) as f64) * sq * (1.0 - f).clamp(0.0, 1.0);
    Some(var.sqrt() / sy)
}

/// The errors of a run over `windows` that timed one in `sample` chunks; `None` for a
/// whole frame (`sample` = 1) or fewer than two windows.
pub fn sampling_error(windows: &[Window], sample: u32) -> Option<SamplingError> {
    if sample <= 1 || windows.len() < 2 {
        return None;
    }
    let f = 1.0 / sample as f64;
    let col = |g: fn(&Window) -> u64| windows.iter().map(|w| g(w) as f64).collect::<Vec<_>>();
    let (pixels, rays, window_rays, cycles, bytes) = (
        col(|w| w.pixels),
        col(|w| w.rays),
        col(|w| w.window_rays),
        col(|w| w.cycles),
        col(|w| w.bytes),
    );
    Some(SamplingError {
        windows: windows.len() as u64,
        mrps: ratio_rel_se(&window_rays, &cycles, f).unwrap_or(0.0),
        frame_traffic: ratio_rel_se(&bytes, &pixels, f).unwrap_or(0.0),
        frame_rays: ratio_rel_se(&rays, &pixels, f).unwrap_or(0.0),
    })
}

/// The relative standard error of a sampled run's frame energy from its windows' energies
/// `window_mj` (pixels, mJ; [`window_energy`]): the ratio estimator of energy per pixel.
/// `None` as for [`sampling_error`].
pub fn frame_energy_rel_se(window_mj: &[(u64, f64)], sample: u32) -> Option<f64> {
    if sample <= 1 || window_mj.len() < 2 {
        return None;
    }
    let e: Vec<f64> = window_mj.iter().map(|w| w.1).collect();
    let pixels: Vec<f64> = window_mj.iter().map(|w| w.0 as f64).collect();
    Some(ratio_rel_se(&e, &pixels, 1.0 / sample as f64).unwrap_or(0.0))
}

/// Each window's pixels and share of the run's energy `d` in mJ, taking the energy as
/// linear in what each window measured: `d`'s parts spread over the windows in proportion
/// to their node visits, triangle tests, DRAM bytes and time (the window's cycles times
/// its share of timed rays).
pub fn window_energy(windows: &[Window], d: &EnergyDrivers) -> Vec<(u64, f64)> {
    let time = |w: &Window| w.cycles as f64 * w.rays as f64 / w.window_rays.max(1) as f64;
    let total = |g: &dyn Fn(&Window) -> f64| windows.iter().map(g).sum::<f64>().max(1e-300);
    let (v, t, b, c) = (
        total(&|w| w.visits as f64),
        total(&|w| w.tests as f64),
        total(&|w| w.bytes as f64),
        total(&time),
    );
    windows
        .iter()
        .map(|w| {
            let e = d.visits_mj * w.visits as f64 / v
                + d.tests_mj * w.tests as f64 / t
                + d.bytes_mj * w.bytes as f64 / b
                + d.time_mj * time(w) / c;
            (w.pixels, e)
        })
        .collect()
}

/// The relative standard error of the ratio `X = (a_fixed + sum a) / (b_fixed + sum b)` of
/// two runs traced over the same sample (`sample`), from their windows' energies `a` and
/// `b` (pixels, mJ) when the windows pair up (the same pixels in each), with exact parts
/// `a_fixed` and `b_fixed` (a build's energy, in the windows' units) that sampling does not
/// move. Linearized, `X`'s error is that of `sum a - X sum b` over `b_fixed + sum b`; that
/// difference is estimated per pixel from the windows' `a_j - X b_j` (the ratio estimator
/// over pixels), so the errors of the two runs cancel where both are heavy on the same
/// chunks. `None` when the windows do not pair up.
pub fn paired_ratio_rel_se(
    a: &[(u64, f64)],
    b: &[(u64, f64)],
    a_fixed: f64,
    b_fixed: f64,
    sample: u32,
) -> Option<f64> {
    let n = a.len();
    if n != b.len() || n < 2 || a.iter().zip(b).any(|(x, y)| x.0 != y.0) {
        return None;
    }
    let total_a = a_fixed + a.iter().map(|w| w.1).sum::<f64>();
    let total_b = b_fixed + b.iter().map(|w| w.1).sum::<f64>();
    if !(total_a > 0.0 && total_b > 0.0) {
        return None;
    }
    let x = total_a / total_b;
    let z: Vec<f64> = a.iter().zip(b).map(|(a, b)| a.1 - x * b.1).collect();
    let pixels: Vec<f64> = a.iter().map(|w| w.0 as f64).collect();
    let per_pixel = z.iter().sum::<f64>() / pixels.iter().sum::<f64>().max(1.0);
    let d: Vec<f64> = z
        .iter()
        .zip(&pixels)
        .map(|(z, p)| z - per_pixel * p)
        .collect();
    let sq: f64 = d.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum();
    let f = 1.0 / sample.max(1) as f64;
    let var = n as f64 / (2.0 * (n - 1) as f64) * sq * (1.0 - f);
    Some(var.sqrt() / total_a)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The estimator by hand: y = 2, 4, 3 over x = 1, 1, 1 with half the population
    /// sampled. r = 3, residuals -1, 1, 0, differences 2 and -1, so the variance is
    /// 3 / (2 * 2) * (4 + 1) * 0.5 = 1.875 and the relative error sqrt(1.875) / 9.
    #[test]
    fn ratio_rel_se_by_hand() {
        let se = ratio_rel_se(&[2.0, 4.0, 3.0], &[1.0, 1.0, 1.0], 0.5).unwrap();
        assert!((se - 1.875f64.sqrt() / 9.0).abs() < 1e-15, "{se}");
        // A ratio that every unit shares has no error; a census neither.
        assert_eq!(
            ratio_rel_se(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0], 0.5),
            Some(0.0)
        );
        assert_eq!(
            ratio_rel_se(&[2.0, 4.0, 3.0], &[1.0, 1.0, 1.0], 1.0),
            Some(0.0)
        );
        assert_eq!(ratio_rel_se(&[2.0], &[1.0], 0.5), None);
        assert_eq!(ratio_rel_se(&[0.0, 0.0], &[1.0, 1.0], 0.5), None);
    }

    /// Units drawn independently: the estimate's spread over many samples matches the
    /// standard error it reports (within 15%), for a ratio with noise in both parts.
    #[test]
    fn ratio_rel_se_matches_the_spread_of_independent_draws() {
        let mut state = 7u64;
        let mut uniform = || {
            state = trace::sampling::mix64(state);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (n, trials) = (40, 4000);
        let (mut estimates, mut ses) = (Vec::new(), Vec::new());
        for _ in 0..trials {
            let x: Vec<f64> = (0..n).map(|_| 50.0 + 20.0 * uniform()).collect();
            let y: Vec<f64> = x.iter().map(|x| x * (2.0 + uniform())).collect();
            estimates.push(y.iter().sum::<f64>() / x.iter().sum::<f64>());
            ses.push(ratio_rel_se(&y, &x, 0.0).unwrap());
        }
        let mean = estimates.iter().sum::<f64>() / trials as f64;
        let sd = (estimates.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (trials - 1) as f64)
            .sqrt();
        let rms_se = (ses.iter().map(|s| s * s).sum::<f64>() / trials as f64).sqrt();
        let ratio = rms_se / (sd / mean);
        assert!((0.85..1.15).contains(&ratio), "reported/actual {ratio}");
    }

    #[test]
    fn energy_error_follows_its_drivers() {
        let w = |pixels, visits, bytes| Window {
            pixels,
            rays: pixels,
            window_rays: pixels,
            cycles: 10 * pixels,
            bytes,
            visits,
            tests: 0,
        };
        // Visits per pixel 1, 3, 2 (the first example of `ratio_rel_se_by_hand` scaled);
        // bytes and time per pixel constant.
        let ws = [w(10, 10, 100), w(10, 30, 100), w(10, 20, 100)];
        let only = |d: EnergyDrivers| frame_energy_rel_se(&window_energy(&ws, &d), 2).unwrap();
        let by_hand = ratio_rel_se(&[1.0, 3.0, 2.0], &[1.0, 1.0, 1.0], 0.5).unwrap();
        let visits = only(EnergyDrivers {
            visits_mj: 5.0,
            ..Default::default()
        });
        assert!((visits - by_hand).abs() < 1e-12, "{visits} vs {by_hand}");
        let flat = only(EnergyDrivers {
            bytes_mj: 1.0,
            time_mj: 1.0,
            ..Default::default()
        });
        assert!(flat.abs() < 1e-12, "{flat}");
        // Half the energy in visits: half the relative error.
        let half = only(EnergyDrivers {
            visits_mj: 1.0,
            bytes_mj: 1.0,
            ..Default::default()
        });
        assert!((half - by_hand / 2.0).abs() < 1e-12, "{half}");
        assert_eq!(
            frame_energy_rel_se(&window_energy(&ws, &EnergyDrivers::default()), 1),
            None
        );
        // Two runs heavy on the same windows: their ratio has no error; one proportional
        // to pixels against one that is not has the latter's error.
        let a = [(10, 1.0), (10, 3.0), (10, 2.0)];
        let twice = [(10, 2.0), (10, 6.0), (10, 4.0)];
        assert_eq!(paired_ratio_rel_se(&twice, &a, 0.0, 0.0, 2), Some(0.0));
        let flat = [(10, 5.0), (10, 5.0), (10, 5.0)];
        let se = paired_ratio_rel_se(&a, &flat, 0.0, 0.0, 2).unwrap();
        assert!((se - by_hand).abs() < 1e-12, "{se}");
        // Exact parts do not add error of their own: a build spread over windows of
        // unequal size leaves a ratio of proportional traces without error.
        let uneven = [(10, 1.0), (30, 3.0), (20, 2.0)];
        let uneven2 = [(10, 2.0), (30, 6.0), (20, 4.0)];
        let both = paired_ratio_rel_se(&uneven2, &uneven, 5.0, 2.5, 2).unwrap();
        assert!(both.abs() < 1e-12, "{both}");
        // Unpaired windows: no estimate.
        assert_eq!(paired_ratio_rel_se(&a, &a[..2], 0.0, 0.0, 2), None);
        assert_eq!(
            paired_ratio_rel_se(&a, &[(9, 1.0), (11, 3.0), (10, 2.0)], 0.0, 0.0, 2),
            None
        );
        assert_eq!(sampling_error(&ws, 1), None);
        assert_eq!(sampling_error(&ws, 2).unwrap().windows, 3);
    }
}
