//! Zero-aligned power-of-two grids of \[P3\] §4.1 (Eq. 6) and the scale exponent of Eq. 2,
//! with exact, outward-rounded arithmetic.
//!
//! A node's children are quantized on a per-axis grid of cell size `2^e` aligned to zero:
//! every grid point is `k * 2^e` with `k` an integer (\[P3\] Eq. 6/7, read as `u = k 2^e`,
//! `v = l 2^e`, see the OCR note in `seed/INDEX.md`). The scale `e` of a node is the
//! smallest exponent (not below the minimum scale, \[P3\] §4.4) at which the node's decoded
//! box spans at most `2^N` cells (Eq. 2).
//!
//! Decoded bounds are `f32`. A grid point `k 2^e` is not always an `f32` (far from the
//! origin, or for fine scales), so every decoded lower bound is rounded down and every
//! upper bound up to the next `f32`: the decoded box then still encloses the original box.
//! A rounded bound is still a multiple of `2^e` (rounding goes to a multiple of the `f32`
//! spacing, which is then coarser than `2^e`), so nested grids stay aligned. Sums are
//! formed exactly with Knuth's two-sum, so the rounding is exact, never off by an ulp.

use crate::error::CbvhError;
use serde::{Deserialize, Serialize};

/// Fewest coordinate bits per bound supported (parameter studies).
pub const MIN_BITS: u32 = 3;
/// Most coordinate bits per bound supported (the stored fields are bytes).
pub const MAX_BITS: u32 = 8;
/// \[P3\] §5: "six 6-bit relative or modulo coordinates".
pub const DEFAULT_BITS: u32 = 6;
/// \[P3\] §5.1: "In the following benchmarks, we use a value of 2^-30".
pub const DEFAULT_MIN_SCALE_EXP: i32 = -30;
/// Finest minimum scale accepted (\[P3\] Fig. 4 saturates at 2^-126).
pub const FINEST_MIN_SCALE_EXP: i32 = -126;
/// Coarsest minimum scale accepted.
pub const COARSEST_MIN_SCALE_EXP: i32 = 100;
/// Largest coordinate magnitude the encoders accept (2^120): keeps every decoded bound,
/// one grid cell beyond the input, finite.
pub const MAX_ABS_COORD: f32 = f32::from_bits(247 << 23);

/// Which coordinates the node pairs store (\[P3\] §3 Eq. 1 and §4.2 Eq. 8).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Coords {
    /// Relative coordinates `(r, s - 1)`, Eq. 1 and 3.
    Relative,
    /// Modulo coordinates `(k mod 2^N, l mod 2^N)`, Eq. 8 and 9.
    Modulo,
    /// Modulo coordinates with plane sharing (\[P3\] §4.5, after Fabianowski and Dingliana
    /// 2009): per axis and side, one child of a pair reuses its node's decoded plane
    /// instead of its own quantized coordinate, so a pair needs six stored coordinates and
    /// six one-bit flags instead of twelve coordinates (see
    /// [`crate::codec::share_planes`] and `docs/beyond-thesis.md`).
    #[serde(rename = "plane-sharing")]
    PlaneSharing,
}

impl Coords {
    /// Lower-case name as the CLI writes it.
    pub fn name(self) -> &'static str {
        match self {
            Coords::Relative => "relative",
            Coords::Modulo => "modulo",
            Coords::PlaneSharing => "plane-sharing",
        }
    }

    /// True for the encodings whose stored fields are modulo coordinates (Eq. 8, 9).
    #[inline(always)]
    pub fn is_modulo(self) -> bool {
        !matches!(self, Coords::Relative)
    }

    /// True when a pair's children reuse their node's decoded planes.
    #[inline(always)]
    pub fn shares_planes(self) -> bool {
        matches!(self, Coords::PlaneSharing)
    }
}

/// Quantization parameters shared by encoder and decoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Params {
    /// Bits per coordinate `N` (3..=8; \[P3\] uses 6).
    pub bits: u32,
    /// Minimum scale exponent (\[P3\] §4.4; default -30).
    pub min_scale_exp: i32,
    /// Coordinate encoding.
    pub coords: Coords,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            bits: DEFAULT_BITS,
            min_scale_exp: DEFAULT_MIN_SCALE_EXP,
            coords: Coords::Relative,
        }
    }
}

impl Params {
    /// Checks the ranges of the parameters.
    pub fn check(&self) -> Result<(), CbvhError> {
        if !(MIN_BITS..=MAX_BITS).contains(&self.bits) {
            return Err(CbvhError::InvalidParams(format!(
                "coordinate bits must be {MIN_BITS}..={MAX_BITS}, got {}",
                self.bits
            )));
        }
        if !(FINEST_MIN_SCALE_EXP..=COARSEST_MIN_SCALE_EXP).contains(&self.min_scale_exp) {
            return Err(CbvhError::InvalidParams(format!(
                "minimum scale exponent must be {FINEST_MIN_SCALE_EXP}..={COARSEST_MIN_SCALE_EXP}, got {}",
                self.min_scale_exp
            )));
        }
        Ok(())
    }

    /// Number of grid cells a node spans at most, `2^N`.
    #[inline]
    pub fn cells(&self) -> i64 {
        1i64 << self.bits
    }
}

/// `2^e` as an `f64` (exact for `e` in -1022..=1023).
#[inline]
pub fn pow2(e: i32) -> f64 {
    debug_assert!((-1022..=1023).contains(&e));
    f64::from_bits(((1023 + e) as u64) << 52)
}

/// Knuth's two-sum: `a + b = s + err` exactly.
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let err = (a - (s - bb)) + (b - bb);
    (s, err)
}

/// The next `f32` above `x` (finite `x`). Branch-free (selects only): decoding rounds
/// every bound through it, and traversal decodes at every node visit.
#[inline]
pub fn next_up(x: f32) -> f32 {
    // -0 counts as +0, whose successor is the smallest subnormal (bits 1).
    let b = if x == 0.0 { 0 } else { x.to_bits() };
    f32::from_bits(if (b as i32) >= 0 { b + 1 } else { b - 1 })
}

/// The next `f32` below `x` (finite `x`).
#[inline]
pub fn next_down(x: f32) -> f32 {
    -next_up(-x)
}

/// The largest `f32` not above the exact value `s + err` (with `|err| <= ulp(s) / 2`).
#[inline]
fn round_down(s: f64, err: f64) -> f32 {
    let f = s as f32;
    let fd = f as f64;
    // Non-short-circuit `|` and `&`, and a select: whether `f` lies above the exact value
    // is data-dependent, and a branch on it mispredicts half the time.
    let above = (fd > s) | ((fd == s) & (err < 0.0));
    let down = next_down(f);
    if above {
        down
    } else {
        f
    }
}

/// The smallest `f32` not below the exact value `s + err`.
#[inline]
fn round_up(s: f64, err: f64) -> f32 {
    -round_down(-s, -err)
}

/// `a + b`, exact, rounded down to an `f32`.
#[inline]
pub fn add_down(a: f64, b: f64) -> f32 {
    let (s, e) = two_sum(a, b);
    round_down(s, e)
}

/// `a + b`, exact, rounded up to an `f32`.
#[inline]
pub fn add_up(a: f64, b: f64) -> f32 {
    let (s, e) = two_sum(a, b);
    round_up(s, e)
}

/// `floor((x - base) / 2^e)`, exact (saturating to the `i64` range).
#[inline]
pub fn floor_cells(x: f32, base: f32, e: i32) -> i64 {
    let (d, err) = two_sum(x as f64, -(base as f64));
    let k = pow2(-e);
    let xs = d * k;
    let ys = err * k;
    let fl = xs.floor();
    let fl = if fl == xs && ys < 0.0 { fl - 1.0 } else { fl };
    fl as i64
}

/// `ceil(log2(w))` of a positive finite `w`.
#[inline]
fn ceil_log2(w: f64) -> i32 {
    let b = w.to_bits();
    let exp = ((b >> 52) & 0x7ff) as i32;
    let mant = b & ((1u64 << 52) - 1);
    if exp == 0 {
        // Subnormal f64: not reachable from f32 inputs, but stay total.
        return -1074 + (64 - mant.leading_zeros() as i32);
    }
    exp - 1023 + i32::from(mant != 0)
}

/// Eq. 2: the smallest scale exponent `e >= min_scale_exp` with `w <= 2^(N + e)`, for a
/// decoded width `w` (a difference of two decoded bounds; 0 gives the minimum scale).
#[inline]
pub fn scale_for_width(w: f64, p: &Params) -> i32 {
    if w.is_nan() || w <= 0.0 {
        return p.min_scale_exp;
    }
    (ceil_log2(w) - p.bits as i32).max(p.min_scale_exp)
}

/// One axis of a traversal context: the node's scale and its decoded bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCtx {
    /// Scale exponent of the node's grid (its children are quantized at `2^e`).
    pub e: i32,
    /// Decoded lower bound `u` of the node (a multiple of `2^e`).
    pub lo: f32,
    /// Decoded upper bound `v` of the node.
    pub hi: f32,
}

impl AxisCtx {
    /// The context of a node whose decoded bounds are `lo..hi` (scale from Eq. 2).
    #[inline]
    pub fn from_decoded(lo: f32, hi: f32, p: &Params) -> Self {
        let w = hi as f64 - lo as f64;
        Self {
            e: scale_for_width(w, p),
            lo,
            hi,
        }
    }

    /// `EstimateContext` of \[P3\] Algorithm 1 for one axis of an original box `p..q`: the
    /// finest scale whose zero-aligned grid box around `p..q` spans at most `2^N` cells,
    /// with that grid box as the bounds. (The true context, from the parent, is never
    /// finer: the parent's grid is coarser and its decoded box encloses this one.)
    pub fn estimate(p: f32, q: f32, prm: &Params) -> Self {
        let w0 = q as f64 - p as f64;
        let mut e = if w0 > 0.0 {
            (ceil_log2(w0) - prm.bits as i32 - 1).max(prm.min_scale_exp)
        } else {
            prm.min_scale_exp
        };
        loop {
            let (lo, hi) = aligned(p, q, e);
            let w = hi as f64 - lo as f64;
            if w <= pow2(e + prm.bits as i32) || e >= 1000 {
                return Self { e, lo, hi };
            }
            e += 1;
        }
    }

    /// Decoded bounds of a child that spans cells `r..s` of this node's grid.
    #[inline]
    pub fn child_bounds(&self, r: i64, s: i64) -> (f32, f32) {
        let c = pow2(self.e);
        (
            add_down(self.lo as f64, r as f64 * c),
            add_up(self.lo as f64, s as f64 * c),
        )
    }

    /// `k mod 2^N` of the node's lower bound `lo = k 2^e` (its modulo coordinate in its
    /// own grid).
    #[inline]
    pub fn lo_mod(&self, p: &Params) -> i64 {
        // k is an integer held exactly in f64 (an f32 scaled by a power of two). Below 2^62
        // its two's-complement low bits are k mod 2^N; above, k has at most 24 significant
        // bits, all above bit 38, so k mod 2^N is 0 (N <= 8).
        let k = self.lo as f64 * pow2(-self.e);
        let mask = (1i64 << p.bits) - 1;
        if k.abs() < pow2(62) {
            (k as i64) & mask
        } else {
            0
        }
    }
}

/// Zero-aligned grid box around `p..q` at scale `e`: `floor(p / 2^e) 2^e` and
/// `(floor(q / 2^e) + 1) 2^e` (Eq. 1), rounded outward to `f32`.
#[inline]
fn aligned(p: f32, q: f32, e: i32) -> (f32, f32) {
    let c = pow2(e);
    // p * 2^-e is exact in f64 and so is its floor (no i64 range limit here).
    let kp = (p as f64 * pow2(-e)).floor();
    let kq = (q as f64 * pow2(-e)).floor();
    // k * 2^e is exact in f64 (it has no more significant bits than p or q), so only the
    // conversion to f32 rounds; Eq. 1's extra cell is added exactly by the two-sum (`kq + 1`
    // itself can round away in f64 far from the origin).
    let hi = add_up(kq * c, c);
    (add_down(kp * c, 0.0), hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn rounding_is_outward_and_tight() {
        assert_eq!(add_down(1.0, 2f64.powi(-40)), 1.0);
        assert_eq!(add_up(1.0, 2f64.powi(-40)), next_up(1.0));
        assert_eq!(add_down(1.0, -(2f64.powi(-40))), next_down(1.0));
        assert_eq!(add_up(1.0, -(2f64.powi(-40))), 1.0);
        // Beyond f64 precision: two-sum keeps the tiny part.
        assert_eq!(add_up(1e30f32 as f64, 1e-30), next_up(1e30));
        assert_eq!(add_down(-1e30f32 as f64, -1e-30), next_down(-1e30));
        assert_eq!(add_down(3.0, 0.0), 3.0);
    }

    #[test]
    fn next_up_and_down_step_one_ulp() {
        for x in [
            0.0f32,
            -0.0,
            1.0,
            -1.0,
            f32::from_bits(1),
            -f32::from_bits(1),
            1e30,
            -1e-30,
            f32::MAX * 0.5,
        ] {
            let up = next_up(x);
            assert!(up > x && f32::from_bits(up.to_bits()) == up, "{x}");
            // Nothing lies strictly between x and its successor.
            let mid = (x as f64 + up as f64) / 2.0;
            assert!(mid as f32 == x || mid as f32 == up, "{x}");
            assert!(
                next_down(x) < x && next_up(next_down(x)) == x || x == 0.0,
                "{x}"
            );
        }
        assert_eq!(next_up(0.0).to_bits(), 1);
        assert_eq!(next_up(-0.0).to_bits(), 1);
        assert_eq!(next_down(0.0).to_bits(), 0x8000_0001);
    }

    #[test]
    fn floor_cells_is_exact() {
        assert_eq!(floor_cells(1.0, 0.0, 0), 1);
        assert_eq!(floor_cells(-0.5, 0.0, 0), -1);
        assert_eq!(floor_cells(1e30, next_down(1e30), -200), i64::MAX);
        assert_eq!(floor_cells(0.75, 0.25, -1), 1);
        assert_eq!(floor_cells(0.25, 0.75, -1), -1);
        // (1 - tiny) / 1 floors to 0 even when the f64 difference rounds to 1.
        assert_eq!(floor_cells(1.0, 1e-30, 0), 0);
    }

    #[test]
    fn scale_follows_eq2() {
        let p = Params::default();
        assert_eq!(scale_for_width(64.0, &p), 0); // 64 = 2^6 cells of 1
        assert_eq!(scale_for_width(65.0, &p), 1);
        assert_eq!(scale_for_width(1.0, &p), -6);
        assert_eq!(scale_for_width(0.0, &p), -30);
        assert_eq!(scale_for_width(1e-20, &p), -30);
    }

    #[test]
    fn estimate_fits_and_is_finest() {
        let prm = Params::default();
        for &(p, q) in &[
            (0.0f32, 1.0f32),
            (-3.5, 7.25),
            (1e30, 1e30),
            (0.1, 0.1),
            (-1.0, -1.0),
        ] {
            let c = AxisCtx::estimate(p, q, &prm);
            assert!(c.lo <= p && c.hi > q, "{p} {q} {c:?}");
            assert!(c.hi as f64 - c.lo as f64 <= pow2(c.e + 6));
            if c.e > prm.min_scale_exp {
                let (lo, hi) = aligned(p, q, c.e - 1);
                assert!(hi as f64 - lo as f64 > pow2(c.e - 1 + 6));
            }
        }
    }

    proptest! {
        /// The integer modulo equals Eq. 8's `k - 2^N floor(k / 2^N)` (exact in f64).
        #[test]
        fn lo_mod_is_the_floor_modulo(x in prop_oneof![-1e3f32..1e3, -1e30f32..1e30, Just(0.0f32)], e in -126i32..100, bits in 3u32..=8) {
            let p = Params { bits, ..Params::default() };
            let c = pow2(e);
            // A multiple of 2^e near x, as a decoded lower bound is.
            let lo = ((x as f64 / c).floor() * c) as f32;
            let lo = if (lo as f64 / c).fract() == 0.0 { lo } else { 0.0 };
            let a = AxisCtx { e, lo, hi: lo };
            let k = lo as f64 * pow2(-e);
            let m = pow2(bits as i32);
            prop_assert_eq!(a.lo_mod(&p), (k - m * (k / m).floor()) as i64);
        }

        #[test]
        fn add_rounding_brackets_exact_sum(a in -1e6f32..1e6, k in -40i32..40, r in 0i64..64) {
            let b = r as f64 * pow2(k);
            let lo = add_down(a as f64, b);
            let hi = add_up(a as f64, b);
            // Compare exactly through two-sum residuals.
            let (s, e) = two_sum(a as f64, b);
            prop_assert!((lo as f64) < s || ((lo as f64) == s && e >= 0.0));
            prop_assert!((hi as f64) > s || ((hi as f64) == s && e <= 0.0));
            // Tight: the neighbours outside are on the other side of the exact sum.
            let up = next_up(lo) as f64;
            prop_assert!(up > s || (up == s && e < 0.0));
            let dn = next_down(hi) as f64;
            prop_assert!(dn < s || (dn == s && e > 0.0));
        }
    }
}
