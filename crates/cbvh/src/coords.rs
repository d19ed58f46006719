//! Relative (\[P3\] Eq. 1, 3) and modulo (\[P3\] Eq. 8, 9) child coordinates along one axis,
//! and transcriptions of the paper's hardware listings: the modulo traversal decode of
//! Fig. 4 and the hardware-oriented modulo encode of Fig. 5.
//!
//! A child box `p..q` inside a node with context `(e, u)` covers the grid cells
//! `r = floor((p - u) / 2^e)` to `s = floor((q - u) / 2^e) + 1` (Eq. 1), with
//! `0 <= r < s <= 2^N`. Relative coordinates store `(r, s - 1)`; modulo coordinates store
//! the absolute grid indices modulo `2^N`: `(k mod 2^N, l mod 2^N)` with `k = u/2^e + r`,
//! `l = u/2^e + s` (Eq. 8). Modulo coordinates do not depend on `u`, only on `e`, which is
//! why they survive a change of the parent's lower bound (\[P3\] Fig. 3).
//!
//! Decoding modulo coordinates (Eq. 9): `r = (k̂ - û) mod 2^N`. For the upper bound we
//! use the child's width `w = ((l̂ - k̂ - 1) mod 2^N) + 1` (in `1..=2^N`) and `s = r + w`.
//! This is Eq. 9's case split generalised: Eq. 9 (and Fig. 4 line 3-6) computes
//! `s = (l̂ - û) mod 2^N`, plus `2^N` only when `k̂ = l̂`, which decodes a child that ends
//! exactly on the upper bound of a parent `2^N` cells wide (`s = 2^N`, `r > 0`) as `s = 0`.
//! Such children occur (a parent's box can span exactly `2^N` cells); see the test
//! `fig4_literal_wraps_a_child_on_the_parent_upper_bound`.

use crate::grid::{floor_cells, pow2, AxisCtx, Params};
use crate::Coords;

/// Grid cells `r..s` covered by the interval `p..q` in a node's grid (Eq. 1:
/// `r = floor((p - u) / 2^e)`, `s = floor((q - u) / 2^e) + 1`), kept inside the node's
/// decoded box.
///
/// The cells are intersected with the node's decoded box (`0..top`, `top <= 2^N`). An
/// original child always lies strictly below its node's upper bound (Eq. 1's `+ 1` makes
/// every decoded upper bound exceed the original), so this only acts when a backtracking
/// step re-encodes a *decoded* child box: its upper bound lies on a grid line, Eq. 1 adds
/// a cell, and that cell can fall outside the parent's new box. The intersection still
/// encloses the original child, which lies inside both. It gives the invariant that every
/// node's child cells lie inside its own decoded box, which modulo coordinates rely on
/// (see [`crate::codec::Ctx::invalidates`]).
///
/// `decoded`: the interval is a decoded box (backtracking re-encodes those). Its upper
/// bound is then rounded up (`ceil`) instead of `floor + 1`: a decoded upper bound `v` is
/// already the smallest point of a finer grid strictly above the original `q`, so the
/// smallest point of the new, coarser (or equal) grid at or above `v` is exactly the one
/// `floor + 1` gives for `q`, and likewise for the lower bound. Re-encoding a decoded box
/// then gives the box top-down compression gives the original, instead of growing it by
/// one cell per backtracking step.
#[inline]
pub fn quantize(p: f32, q: f32, ctx: &AxisCtx, prm: &Params, decoded: bool) -> (i64, i64) {
    let n = prm.cells();
    // The node's decoded box in cells: its bounds are multiples of 2^e, their difference
    // is exact in f64.
    let top = ((ctx.hi as f64 - ctx.lo as f64) * pow2(-ctx.e)).floor() as i64;
    let top = top.clamp(1, n);
    let r = floor_cells(p, ctx.lo, ctx.e).clamp(0, top - 1);
    let s = if decoded {
        0i64.saturating_sub(floor_cells(-q, -ctx.lo, ctx.e))
    } else {
        floor_cells(q, ctx.lo, ctx.e).saturating_add(1)
    };
    (r, s.clamp(r + 1, top))
}

/// The two stored `N`-bit fields for cells `r..s`.
#[inline]
pub fn store(r: i64, s: i64, ctx: &AxisCtx, prm: &Params) -> (u8, u8) {
    let mask = prm.cells() - 1;
    match prm.coords {
        Coords::Relative => (r as u8, (s - 1) as u8),
        Coords::Modulo | Coords::PlaneSharing => {
            let m = ctx.lo_mod(prm);
            (((m + r) & mask) as u8, ((m + s) & mask) as u8)
        }
    }
}

/// Cells `r..s` from the two stored fields (Eq. 3 / Eq. 9, see the module doc).
#[inline]
pub fn load(a: u8, b: u8, ctx: &AxisCtx, prm: &Params) -> (i64, i64) {
    let m = match prm.coords {
        Coords::Relative => 0,
        Coords::Modulo | Coords::PlaneSharing => ctx.lo_mod(prm),
    };
    load_with(a, b, m, prm)
}

/// [`load`] with the node's lower-bound modulo coordinate `m` (`ctx.lo_mod(prm)`, unused
/// for relative coordinates) computed once for both children of a pair, as the traversal
/// decode of \[P3\] Fig. 4 does (its line 1, per node).
#[inline(always)]
pub fn load_with(a: u8, b: u8, m: i64, prm: &Params) -> (i64, i64) {
    let mask = prm.cells() - 1;
    match prm.coords {
        Coords::Relative => (a as i64, b as i64 + 1),
        Coords::Modulo | Coords::PlaneSharing => {
            let r = (a as i64 - m) & mask;
            let w = ((b as i64 - a as i64 - 1) & mask) + 1;
            (r, r + w)
        }
    }
}

/// Outputs of the Fig. 4 / Fig. 5 transcriptions along one axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCode {
    /// Stored lower-bound modulo coordinate (`lb_mod`).
    pub lb_mod: i64,
    /// Stored upper-bound modulo coordinate (`ub_mod`).
    pub ub_mod: i64,
    /// Scale of the child's own grid (`child_scale_out`).
    pub child_scale: i32,
    /// Decoded lower bound (`clb_out`).
    pub clb: f64,
    /// Decoded upper bound (`cub_out`).
    pub cub: f64,
}

/// \[P3\] Fig. 5, the hardware-oriented modulo encode of one axis, transcribed with the two
/// OCR slips fixed (the sign test reads the sign flag; the upper bound packs `ub_m`) and the
/// child-scale loop reading `<=` so that it gives the scale of Eq. 2 (the listing's `<`
/// keeps a one-step coarser scale when the child is exactly `2^(N-1)` cells wide).
/// Computes in exact `f64`; inputs must be such that `lb / 2^scale` fits 52 bits.
pub fn fig5_encode_axis(lb: f32, ub: f32, scale: i32, prm: &Params) -> AxisCode {
    let n = prm.bits as i32;
    // Lines 1-8: align both bounds to the grid, rounding down (towards -inf).
    let lb_m = (lb as f64 * pow2(-scale)).floor() as i64;
    let mut ub_m = (ub as f64 * pow2(-scale)).floor() as i64;
    // Line 14: the quantized upper bound lies strictly above the original.
    ub_m += 1;
    // Lines 16-18: the low bits are the modulo coordinates.
    let mask = (1i64 << n) - 1;
    let lb_mod = lb_m & mask;
    let ub_mod = ub_m & mask;
    // Lines 20-28: child scale.
    let mut gridsize = ub_m - lb_m;
    let mut child_scale = scale;
    while gridsize <= 1 << (n - 1) {
        gridsize <<= 1;
        child_scale -= 1;
    }
    child_scale = child_scale.max(prm.min_scale_exp);
    // Lines 30-39: decoded bounds (sign-magnitude round trip; exact here).
    let lb_s = lb_m < 0;
    let ub_s = ub_m < 0;
    let (lbm, ubm) = (lb_m.abs(), ub_m.abs());
    let clb = if lb_s { -1.0 } else { 1.0 } * lbm as f64 * pow2(scale);
    let cub = if ub_s { -1.0 } else { 1.0 } * ubm as f64 * pow2(scale);
    AxisCode {
        lb_mod,
        ub_mod,
        child_scale,
        clb,
        cub,
    }
}

/// \[P3\] Fig. 4, the modulo traversal decode of one axis, transcribed. `parent_lb_mod` is
/// the node's own lower-bound modulo coordinate in its parent's grid, `parent_clb` its
/// decoded lower bound. With `wrap_fix = false` the upper bound follows the listing
/// (line 5-6); with `true` it uses the width rule of the module doc. The child scale uses
/// `<=` as in [`fig5_encode_axis`].
#[allow(clippy::too_many_arguments)]
pub fn fig4_decode_axis(
    lb_mod: i64,
    ub_mod: i64,
    parent_lb_mod: i64,
    parent_scale: i32,
    scale: i32,
    parent_clb: f64,
    prm: &Params,
    wrap_fix: bool,
) -> AxisCode {
    let n = prm.bits as i32;
    let mask = (1i64 << n) - 1;
    // Line 1: the parent's lower bound in the local grid.
    let plm = (parent_lb_mod << (parent_scale - scale)) & mask;
    let rel_lb = (lb_mod - plm) & mask;
    let rel_ub = if wrap_fix {
        rel_lb + ((ub_mod - lb_mod - 1) & mask) + 1
    } else {
        let mut u = (ub_mod - plm) & mask;
        if lb_mod == ub_mod {
            u += 1 << n;
        }
        u
    };
    let clb = parent_clb + rel_lb as f64 * pow2(scale);
    let cub = parent_clb + rel_ub as f64 * pow2(scale);
    let mut gridsize = rel_ub - rel_lb;
    let mut child_scale = scale;
    while gridsize > 0 && gridsize <= 1 << (n - 1) {
        gridsize <<= 1;
        child_scale -= 1;
    }
    child_scale = child_scale.max(prm.min_scale_exp);
    AxisCode {
        lb_mod,
        ub_mod,
        child_scale,
        clb,
        cub,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::scale_for_width;

    fn prm(bits: u32, coords: Coords) -> Params {
        Params {
            bits,
            min_scale_exp: -30,
            coords,
        }
    }

    /// Every node position and width and every child inside it, for small N: the
    /// library's encode/decode round-trips in both encodings, and Fig. 5 then Fig. 4 (with
    /// the wrap fix) agree with it on the stored fields, the decoded bounds and the child
    /// scale.
    #[test]
    fn fig4_and_fig5_agree_with_the_library_exhaustively() {
        for bits in 3..=5u32 {
            let n = 1i64 << bits;
            for coords in [Coords::Relative, Coords::Modulo] {
                let p = prm(bits, coords);
                for parent_scale in [0i32, 2] {
                    // The node: decoded bounds k0..k0+w on its parent's grid (scale
                    // parent_scale); its own scale from Eq. 2.
                    for k0 in -2 * n..2 * n {
                        for w in 1..=n {
                            let c = pow2(parent_scale);
                            let lo = (k0 as f64 * c) as f32;
                            let hi = ((k0 + w) as f64 * c) as f32;
                            let ctx = AxisCtx::from_decoded(lo, hi, &p);
                            assert_eq!(ctx.e, scale_for_width((w as f64) * c, &p));
                            let cells = ((hi as f64 - lo as f64) * pow2(-ctx.e)) as i64;
                            assert!(cells <= n);
                            let parent_lb_mod = k0 & (n - 1);
                            for r in 0..cells {
                                for s in r + 1..=cells {
                                    check_child(&p, &ctx, r, s, parent_scale, parent_lb_mod);
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    fn check_child(p: &Params, ctx: &AxisCtx, r: i64, s: i64, pscale: i32, plm: i64) {
        let c = pow2(ctx.e);
        // An original interval strictly inside cells r..s.
        let lb = (ctx.lo as f64 + (r as f64 + 0.25) * c) as f32;
        let ub = (ctx.lo as f64 + (s as f64 - 0.5) * c) as f32;
        assert_eq!(quantize(lb, ub, ctx, p, false), (r, s));
        let (a, b) = store(r, s, ctx, p);
        assert_eq!(load(a, b, ctx, p), (r, s));
        let (clo, chi) = ctx.child_bounds(r, s);
        assert!(clo <= lb && chi > ub);
        if p.coords == Coords::Modulo {
            let f5 = fig5_encode_axis(lb, ub, ctx.e, p);
            assert_eq!((f5.lb_mod, f5.ub_mod), (a as i64, b as i64));
            assert_eq!((f5.clb, f5.cub), (clo as f64, chi as f64));
            assert_eq!(
                f5.child_scale,
                AxisCtx::from_decoded(clo, chi, p).e,
                "{ctx:?} {r} {s}"
            );
            let f4 = fig4_decode_axis(
                a as i64,
                b as i64,
                plm,
                pscale,
                ctx.e,
                ctx.lo as f64,
                p,
                true,
            );
            assert_eq!(
                (f4.clb, f4.cub, f4.child_scale),
                (f5.clb, f5.cub, f5.child_scale)
            );
        }
    }

    /// The listing's upper-bound rule (Eq. 9) fails exactly for a child that ends on the
    /// upper bound of a parent `2^N` cells wide and does not start at its lower bound.
    #[test]
    fn fig4_literal_wraps_a_child_on_the_parent_upper_bound() {
        let p = prm(3, Coords::Modulo);
        let n = 8i64;
        // Node at cells 0..8 of scale 0, children r..s.
        let mut failures = 0;
        for r in 0..n {
            for s in r + 1..=n {
                let (a, b) = (r & 7, s & 7);
                let lit = fig4_decode_axis(a, b, 0, 0, 0, 0.0, &p, false);
                let ok = lit.clb == r as f64 && lit.cub == s as f64;
                assert_eq!(ok, !(s == n && r > 0), "r {r} s {s}");
                failures += usize::from(!ok);
            }
        }
        assert_eq!(failures, 7);
    }
}
