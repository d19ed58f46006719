//! Traversal contexts and the encode/decode of one node pair, shared by every encoder and
//! by the decoder (\[P3\] §3 and Algorithm 1's `Encode` and `Decode`).
//!
//! A traversal context (\[P3\] §3) is what is needed to encode or decode the children of a
//! node: per axis the node's scale `e` and its decoded lower bound `u` (and, for modulo
//! coordinates, `u / 2^e mod 2^N`, derived from them). We also keep the node's decoded
//! upper bound, so that a context is the node's decoded box plus its grid: Algorithm 1's
//! backtracking re-encodes `oldChildContexts[i].aabb`.

use crate::coords::{load_with, quantize, store};
use crate::error::CbvhError;
use crate::format::{NodePair, Slot, EMPTY_PTR};
use crate::grid::{AxisCtx, Params, MAX_ABS_COORD};
use crate::Coords;
use geom::{Aabb, Vec3};

/// A traversal context: per axis the node's grid scale and decoded bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ctx {
    /// Axes x, y, z.
    pub axes: [AxisCtx; 3],
}

impl Ctx {
    /// Checks a context that did not come from an encoder (the root context of a tree
    /// built or read elsewhere): finite bounds in order on every axis, and a scale
    /// exponent whose powers of two the decoder can form (`FINEST_MIN_SCALE_EXP..=1000`,
    /// the range `estimate` produces).
    pub fn check(&self) -> Result<(), CbvhError> {
        for (a, ax) in self.axes.iter().enumerate() {
            let ok = ax.lo.is_finite()
                && ax.hi.is_finite()
                && ax.lo <= ax.hi
                && (crate::grid::FINEST_MIN_SCALE_EXP..=1000).contains(&ax.e);
            if !ok {
                return Err(CbvhError::Corrupt(format!(
                    "context axis {a} (scale 2^{}, bounds {}..{}) is out of range",
                    ax.e, ax.lo, ax.hi
                )));
            }
        }
        Ok(())
    }

    /// `EstimateContext` (\[P3\] Algorithm 1 line 16) of a node with original box `b`.
    pub fn estimate(b: &Aabb, p: &Params) -> Self {
        if b.is_empty() {
            return Self::from_decoded(&Aabb::new(Vec3::ZERO, Vec3::ZERO), p);
        }
        Self {
            axes: [0, 1, 2].map(|i| AxisCtx::estimate(b.min[i], b.max[i], p)),
        }
    }

    /// The context of a node whose decoded box is `b` (scales by Eq. 2).
    #[inline]
    pub fn from_decoded(b: &Aabb, p: &Params) -> Self {
        Self {
            // Written out: `[0, 1, 2].map(..)` is not inlined into a traversal kernel.
            axes: [
                AxisCtx::from_decoded(b.min.x, b.max.x, p),
                AxisCtx::from_decoded(b.min.y, b.max.y, p),
                AxisCtx::from_decoded(b.min.z, b.max.z, p),
            ],
        }
    }

    /// The node's decoded box.
    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(
            Vec3::new(self.axes[0].lo, self.axes[1].lo, self.axes[2].lo),
            Vec3::new(self.axes[0].hi, self.axes[1].hi, self.axes[2].hi),
        )
    }

    /// The per-axis scale exponents.
    pub fn scales(&self) -> [i32; 3] {
        self.axes.map(|a| a.e)
    }

    /// Algorithm 1's invalidation test: true when a node encoded in context `self` (its
    /// old context) must be re-encoded because its context is now `new`.
    ///
    /// Relative coordinates depend on the scale and the lower bound (\[P3\] Fig. 3).
    /// Modulo coordinates depend on the scale only (\[P3\] §4.2), provided the node's child
    /// cells stay within the `2^N`-cell window of the new lower bound: encoding keeps them
    /// inside the node's decoded box (see [`crate::coords::quantize`]), so a node whose new
    /// box encloses its old box keeps that invariant and decodes to the same children.
    /// A same-scale change that does not enclose the old box (rare: a degenerate axis on a
    /// grid line) is also treated as invalidating, where Algorithm 1 tests the scale alone.
    /// With plane sharing every change of the decoded box invalidates: the children's
    /// shared planes are the node's decoded planes, so they move with it even where the
    /// stored fields stay valid (\[P3\] §4.5: "it often invalidates nodes far down").
    #[inline]
    pub fn invalidates(&self, new: &Ctx, p: &Params) -> bool {
        self.axes.iter().zip(&new.axes).any(|(a, b)| {
            a.e != b.e
                || match p.coords {
                    Coords::Relative => a.lo.to_bits() != b.lo.to_bits(),
                    Coords::Modulo => a.lo < b.lo || a.hi > b.hi,
                    // The children reuse the node's decoded planes: any change of the
                    // node's box moves a child's box, so the subtree must be revisited.
                    Coords::PlaneSharing => {
                        a.lo.to_bits() != b.lo.to_bits() || a.hi.to_bits() != b.hi.to_bits()
                    }
                }
        })
    }
}

/// A child reference as an encoder hands it to [`encode_pair`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChildPtr {
    /// An inner child at node pair `0`.
    Inner(u32),
    /// A leaf starting at primitive-id index `0`.
    Leaf(u32),
    /// No child.
    Empty,
}

/// Checks that a box is usable by the grids (no NaN, magnitudes up to 2^120).
#[inline]
pub fn check_box(b: &Aabb, index: usize) -> Result<(), CbvhError> {
    if b.is_empty() {
        return Ok(());
    }
    let ok = (0..3).all(|i| {
        b.min[i].abs() <= MAX_ABS_COORD && b.max[i].abs() <= MAX_ABS_COORD && b.min[i] <= b.max[i]
    });
    if ok {
        Ok(())
    } else {
        Err(CbvhError::BadBox { index })
    }
}

/// `Encode` of Algorithm 1: quantizes the two original child boxes `boxes` in context
/// `ctx` and returns the pair and each child's decoded context (the empty child gets a copy
/// of `ctx`).
#[inline]
pub fn encode_pair(
    boxes: &[Aabb; 2],
    ptrs: [ChildPtr; 2],
    ctx: &Ctx,
    p: &Params,
) -> (NodePair, [Ctx; 2]) {
    encode_pair_with(boxes, ptrs, ctx, p, false)
}

/// [`encode_pair`] for boxes that are themselves decoded boxes (`decoded = true`: the
/// re-encoding of a backtracking step, see [`crate::coords::quantize`]).
#[inline]
pub fn encode_pair_with(
    boxes: &[Aabb; 2],
    ptrs: [ChildPtr; 2],
    ctx: &Ctx,
    p: &Params,
    decoded: bool,
) -> (NodePair, [Ctx; 2]) {
    let (slots, out) = encode_slots(boxes, ptrs, ctx, p, decoded);
    (NodePair { slots }, out)
}

/// `Encode` of Algorithm 1 for a node of `K` children (a node pair, `K = 2`, or a
/// compressed 4-wide node, `K = 4`, [`crate::wide`]): quantizes the original child boxes
/// `boxes` in context `ctx` (each slot as [`encode_pair`] does) and returns the slots and
/// each child's decoded context (an empty child gets a copy of `ctx`). `decoded`: the
/// boxes are decoded boxes (a backtracking step's re-encoding).
#[inline]
pub fn encode_slots<const K: usize>(
    boxes: &[Aabb; K],
    ptrs: [ChildPtr; K],
    ctx: &Ctx,
    p: &Params,
    decoded: bool,
) -> ([Slot; K], [Ctx; K]) {
    let mut slots = [Slot::default(); K];
    let mut out = [*ctx; K];
    let mut decoded_boxes = [None; K];
    for c in 0..K {
        let (leaf, ptr) = match ptrs[c] {
            ChildPtr::Empty => {
                slots[c] = Slot::EMPTY;
                continue;
            }
            ChildPtr::Inner(i) => (false, i),
            ChildPtr::Leaf(i) => (true, i),
        };
        let mut slot = Slot {
            leaf,
            ptr,
            ..Slot::default()
        };
        let mut lo = [0f32; 3];
        let mut hi = [0f32; 3];
        for (i, a) in ctx.axes.iter().enumerate() {
            let (r, s) = quantize(boxes[c].min[i], boxes[c].max[i], a, p, decoded);
            (slot.lo[i], slot.hi[i]) = store(r, s, a, p);
            (lo[i], hi[i]) = a.child_bounds(r, s);
        }
        decoded_boxes[c] = Some(Aabb::new(Vec3::from(lo), Vec3::from(hi)));
        slots[c] = slot;
    }
    if p.coords.shares_planes() {
        share_planes_of(&mut decoded_boxes, ctx);
    }
    for c in 0..K {
        if let Some(b) = decoded_boxes[c] {
            out[c] = Ctx::from_decoded(&b, p);
        }
    }
    (slots, out)
}

/// [`share_planes`] for any number of children: per axis and side, the first child whose
/// decoded bound is the outermost takes the node's decoded plane. For two children it is
/// [`share_planes`] (tested); a compressed 4-wide node ([`crate::wide`]) shares the same
/// way, one child per axis and side.
#[inline]
pub fn share_planes_of(boxes: &mut [Option<Aabb>], ctx: &Ctx) {
    for i in 0..3 {
        let (lo, hi) = (ctx.axes[i].lo, ctx.axes[i].hi);
        let mut low: Option<usize> = None;
        let mut high: Option<usize> = None;
        for (c, b) in boxes.iter().enumerate() {
            let Some(b) = b else { continue };
            if low.is_none_or(|k| b.min[i] < boxes[k].expect("set").min[i]) {
                low = Some(c);
            }
            if high.is_none_or(|k| b.max[i] > boxes[k].expect("set").max[i]) {
                high = Some(c);
            }
        }
        if let Some(k) = low {
            boxes[k].as_mut().expect("set").min[i] = lo;
        }
        if let Some(k) = high {
            boxes[k].as_mut().expect("set").max[i] = hi;
        }
    }
}

/// Plane sharing (\[P3\] §4.5; Fabianowski and Dingliana 2009): per axis and side, the
/// child whose decoded bound is the outermost (child 0 on a tie) takes the node's decoded
/// plane from `ctx` in place of its own. Every plane of a node's original box is a plane of
/// one child's original box, and outward rounding keeps that child outermost, so a format
/// needs to store only the other child's coordinate and one bit naming the sharing child:
/// six coordinates and six flag bits per pair instead of twelve coordinates. The node's
/// decoded box encloses its original box, so a shared plane still encloses the child.
///
/// The shared value is the node's plane quantized on its parent's (coarser) grid, which is
/// itself shared from further up when the node is its parent's outermost child: a child's
/// box depends on the decoded boxes of a chain of ancestors, not only on its node's scale.
#[inline(always)]
pub fn share_planes(boxes: &mut [Option<Aabb>; 2], ctx: &Ctx) {
    for i in 0..3 {
        let (lo, hi) = (ctx.axes[i].lo, ctx.axes[i].hi);
        match boxes {
            [Some(a), Some(b)] => {
                if a.min[i] <= b.min[i] {
                    a.min[i] = lo;
                } else {
                    b.min[i] = lo;
                }
                if a.max[i] >= b.max[i] {
                    a.max[i] = hi;
                } else {
                    b.max[i] = hi;
                }
            }
            [Some(a), None] | [None, Some(a)] => {
                a.min[i] = lo;
                a.max[i] = hi;
            }
            [None, None] => {}
        }
    }
}

/// `Decode` of Algorithm 1 for both children of `pair`: their decoded contexts (`None`
/// for an absent child).
#[inline]
pub fn decode_pair(pair: &NodePair, ctx: &Ctx, p: &Params) -> [Option<Ctx>; 2] {
    decode_boxes(pair, ctx, p).map(|b| b.map(|b| Ctx::from_decoded(&b, p)))
}

/// The decoded boxes of both children of `pair` in context `ctx` (`None` for the absent
/// child), without their contexts: what a traversal kernel tests per node visit (\[P3\]
/// Fig. 4 lines 1-9). [`Ctx::from_decoded`] of a box gives the child's context, so
/// `decode_boxes(..)[c].map(|b| Ctx::from_decoded(&b, p))` equals [`decode_pair`].
#[inline]
pub fn decode_boxes(pair: &NodePair, ctx: &Ctx, p: &Params) -> [Option<Aabb>; 2] {
    let m = lo_mods(ctx, p);
    let mut boxes = [
        slot_box(&pair.slots[0], ctx, &m, p),
        slot_box(&pair.slots[1], ctx, &m, p),
    ];
    if p.coords.shares_planes() {
        share_planes(&mut boxes, ctx);
    }
    boxes
}

/// The decoded boxes of the `K` children `slots` of a node in context `ctx` (`None` for an
/// absent child): [`decode_boxes`] for any node width (a compressed 4-wide node,
/// [`crate::wide`]).
#[inline]
pub fn decode_slot_boxes<const K: usize>(
    slots: &[Slot; K],
    ctx: &Ctx,
    p: &Params,
) -> [Option<Aabb>; K] {
    let m = lo_mods(ctx, p);
    let mut boxes = slots.map(|s| slot_box(&s, ctx, &m, p));
    if p.coords.shares_planes() {
        share_planes_of(&mut boxes, ctx);
    }
    boxes
}

/// `Decode` of Algorithm 1 for the `K` children `slots` of a node: their decoded contexts
/// ([`decode_pair`] for any node width).
#[inline]
pub fn decode_slots<const K: usize>(slots: &[Slot; K], ctx: &Ctx, p: &Params) -> [Option<Ctx>; K] {
    decode_slot_boxes(slots, ctx, p).map(|b| b.map(|b| Ctx::from_decoded(&b, p)))
}

/// Per axis the node's lower-bound modulo coordinate (0 for relative coordinates).
#[inline(always)]
fn lo_mods(ctx: &Ctx, p: &Params) -> [i64; 3] {
    match p.coords {
        Coords::Relative => [0; 3],
        Coords::Modulo | Coords::PlaneSharing => [
            ctx.axes[0].lo_mod(p),
            ctx.axes[1].lo_mod(p),
            ctx.axes[2].lo_mod(p),
        ],
    }
}

/// The decoded box of one slot (Eq. 3 or Eq. 9, rounded outward to `f32`).
#[inline(always)]
fn slot_box(slot: &Slot, ctx: &Ctx, m: &[i64; 3], p: &Params) -> Option<Aabb> {
    if slot.is_empty() {
        return None;
    }
    let mut lo = [0f32; 3];
    let mut hi = [0f32; 3];
    for i in 0..3 {
        let (r, s) = load_with(slot.lo[i], slot.hi[i], m[i], p);
        (lo[i], hi[i]) = ctx.axes[i].child_bounds(r, s);
    }
    Some(Aabb::new(Vec3::from(lo), Vec3::from(hi)))
}

/// The pointer of a slot as a [`ChildPtr`].
#[inline]
pub fn slot_ptr(s: &Slot) -> ChildPtr {
    if s.leaf {
        if s.ptr == EMPTY_PTR {
            ChildPtr::Empty
        } else {
            ChildPtr::Leaf(s.ptr)
        }
    } else {
        ChildPtr::Inner(s.ptr)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A finite box of mixed magnitudes: tiny, huge, degenerate, far from the origin.
    pub(crate) fn any_box() -> impl Strategy<Value = Aabb> {
        let f = prop_oneof![
            -10.0f32..10.0,
            -1e-6f32..1e-6,
            (-1e30f32..1e30),
            Just(0.0f32),
            Just(MAX_ABS_COORD),
            Just(-MAX_ABS_COORD),
            proptest::num::f32::SUBNORMAL,
        ];
        (
            proptest::array::uniform3(f),
            proptest::array::uniform3(0u8..4),
            proptest::array::uniform3(-1e3f32..1e3),
        )
            .prop_map(|(a, kind, w)| {
                let mut lo = Vec3::from(a);
                let mut hi = lo;
                for i in 0..3 {
                    match kind[i] {
                        0 => {} // degenerate
                        1 => hi[i] = (lo[i] + w[i].abs()).min(MAX_ABS_COORD),
                        2 => {
                            hi[i] =
                                (lo[i] + w[i].abs() * 1e-9 * (1.0 + lo[i].abs())).min(MAX_ABS_COORD)
                        }
                        _ => hi[i] = grid_next(lo[i]),
                    }
                    if hi[i] < lo[i] {
                        std::mem::swap(&mut lo[i], &mut hi[i]);
                    }
                }
                Aabb::new(lo, hi)
            })
    }

    fn grid_next(x: f32) -> f32 {
        if x >= MAX_ABS_COORD {
            x
        } else {
            crate::grid::next_up(x)
        }
    }

    proptest! {
        /// The plane sharing of any width is the pair's for two children (so the engine's
        /// generic encode and decode are the pair functions).
        #[test]
        fn share_planes_of_two_is_the_pairs(a in any_box(), b in any_box(), n in any_box(), some in 0u8..4) {
            let p = Params { coords: Coords::PlaneSharing, ..Params::default() };
            let ctx = Ctx::from_decoded(&n, &p);
            let mut x = [(some & 1 != 0).then_some(a), (some & 2 != 0).then_some(b)];
            let mut y = x;
            share_planes(&mut x, &ctx);
            share_planes_of(&mut y, &ctx);
            prop_assert_eq!(x, y);
            let kids = [a, b];
            let ptrs = [ChildPtr::Inner(3), ChildPtr::Leaf(1)];
            let (pair, out) = encode_pair(&kids, ptrs, &ctx, &p);
            prop_assert_eq!(decode_slots(&pair.slots, &ctx, &p), decode_pair(&pair, &ctx, &p));
            prop_assert_eq!(decode_slot_boxes(&pair.slots, &ctx, &p), decode_boxes(&pair, &ctx, &p));
            prop_assert_eq!(decode_pair(&pair, &ctx, &p), out.map(Some));
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        /// Encoding two boxes in the context estimated for their union and decoding them
        /// gives boxes that enclose them, in both encodings and for every N; decoding
        /// gives the same contexts the encoder reported.
        #[test]
        fn decoded_children_enclose_originals(a in any_box(), b in any_box(), bits in 3u32..=8, coords in prop_oneof![Just(Coords::Relative), Just(Coords::Modulo), Just(Coords::PlaneSharing)], min_e in prop_oneof![Just(-30i32), Just(-126), Just(-10), Just(0)]) {
            let p = Params { bits, min_scale_exp: min_e, coords };
            let boxes = [a, b];
            let ctx = Ctx::estimate(&a.union(b), &p);
            prop_assert!(ctx.aabb().contains(&a.union(b)));
            let (pair, kids) = encode_pair(&boxes, [ChildPtr::Inner(1), ChildPtr::Leaf(2)], &ctx, &p);
            for c in 0..2 {
                prop_assert!(kids[c].aabb().contains(&boxes[c]), "{:?} {:?}", kids[c], boxes[c]);
                prop_assert_eq!(decode_pair(&pair, &ctx, &p)[c], Some(kids[c]));
                // The child fits its own grid: grandchildren can be encoded under it.
                for ax in kids[c].axes {
                    prop_assert!(ax.hi as f64 - ax.lo as f64 <= crate::grid::pow2(ax.e + bits as i32));
                }
                // Re-encoding the decoded box (backtracking) encloses it and stays inside
                // the node (Eq. 1's extra cell is clipped at the node's upper bound).
                // With plane sharing, child 0 of two equal boxes takes the node's planes,
                // so the check reads child 1.
                let (_, again) = encode_pair_with(&[kids[c].aabb(), kids[c].aabb()], [ChildPtr::Leaf(0); 2], &ctx, &p, true);
                prop_assert_eq!(again[usize::from(p.coords.shares_planes())], kids[c]);
                // Under the coarser context of a doubled parent box, re-encoding the
                // decoded box gives what encoding the original gives.
                let mut wide = ctx;
                for a in &mut wide.axes {
                    let w = a.hi as f64 - a.lo as f64;
                    *a = crate::grid::AxisCtx::from_decoded(a.lo, crate::grid::add_up(a.hi as f64, w), &p);
                }
                let (_, direct) = encode_pair(&boxes, [ChildPtr::Leaf(0); 2], &wide, &p);
                let (_, via) = encode_pair_with(&[kids[0].aabb(), kids[1].aabb()], [ChildPtr::Leaf(0); 2], &wide, &p, true);
                prop_assert_eq!(direct[c].aabb(), via[c].aabb());
            }
        }

        /// Modulo coordinates survive a change of the node's lower bound at the same
        /// scale (\[P3\] §4.2); relative ones are then invalidated.
        #[test]
        fn modulo_is_robust_to_parent_shift(lo in -1000i32..1000, shift in 1i32..4, bits in 3u32..=8) {
            let p = Params { bits, min_scale_exp: -30, coords: Coords::Modulo };
            let n = 1i32 << bits;
            // A node spanning cells lo..lo+n-shift at scale 0, then the box grown down by
            // `shift` cells (same scale, encloses the old one): \[P3\] Fig. 3.
            let b = |l: i32, h: i32| Aabb::new(Vec3::splat(l as f32), Vec3::splat(h as f32));
            let old = Ctx::from_decoded(&b(lo, lo + n - shift), &p);
            let new = Ctx::from_decoded(&b(lo - shift, lo + n - shift), &p);
            prop_assert_eq!(old.scales(), new.scales());
            let child = Aabb::new(Vec3::splat(lo as f32 + 0.5), Vec3::splat((lo + n - shift) as f32 - 0.5));
            let (pair, kids) = encode_pair(&[child, child], [ChildPtr::Leaf(0); 2], &old, &p);
            prop_assert!(!old.invalidates(&new, &p));
            let rel = Params { coords: Coords::Relative, ..p };
            prop_assert!(old.invalidates(&new, &rel));
            // A same-scale box that does not enclose the old one invalidates.
            let moved = Ctx::from_decoded(&b(lo + 1, lo + n - shift + 1), &p);
            prop_assert!(old.invalidates(&moved, &p));
            prop_assert_eq!(decode_pair(&pair, &new, &p)[0], Some(kids[0]));
        }
    }

    /// Plane sharing: the outermost child on each side takes the node's decoded plane, the
    /// other keeps its modulo-decoded bound; a same-scale growth of the node's box, which
    /// modulo coordinates survive, invalidates (the shared planes move).
    #[test]
    fn plane_sharing_reuses_the_nodes_planes() {
        let m = Params {
            bits: 6,
            min_scale_exp: -30,
            coords: Coords::Modulo,
        };
        let ps = Params {
            coords: Coords::PlaneSharing,
            ..m
        };
        let b = |l: [f32; 3], h: [f32; 3]| Aabb::new(Vec3::from(l), Vec3::from(h));
        // Children meeting the node's planes: child 0 the low x and both y sides, child 1
        // the high x; both the z sides (a tie: child 0 shares).
        let kids = [
            b([0.3, 0.2, 0.1], [5.2, 9.7, 3.3]),
            b([2.1, 4.4, 0.1], [9.6, 6.0, 3.3]),
        ];
        let node = kids[0].union(kids[1]);
        // A context coarser than the node's own (as its parent's grid gives it).
        let ctx = Ctx::from_decoded(&b([0.0, 0.0, 0.0], [10.0, 10.0, 4.0]), &ps);
        assert!(ctx.aabb().contains(&node));
        let ptrs = [ChildPtr::Leaf(0), ChildPtr::Leaf(1)];
        let (pm, km) = encode_pair(&kids, ptrs, &ctx, &m);
        let (pp, kp) = encode_pair(&kids, ptrs, &ctx, &ps);
        // The stored fields are the modulo ones; only the decode differs.
        assert_eq!(pm, pp);
        let (a, c) = (km[0].aabb(), km[1].aabb());
        let (sa, sc) = (kp[0].aabb(), kp[1].aabb());
        let n = ctx.aabb();
        assert_eq!(sa.min, n.min); // x, y and z (tie) low planes
        assert_eq!([sa.max.x, sa.max.y, sa.max.z], [a.max.x, n.max.y, n.max.z]);
        assert_eq!([sc.min.x, sc.min.y, sc.min.z], [c.min.x, c.min.y, c.min.z]);
        assert_eq!([sc.max.x, sc.max.y, sc.max.z], [n.max.x, c.max.y, c.max.z]);
        for c in 0..2 {
            assert!(kp[c].aabb().contains(&kids[c]));
            assert_eq!(decode_pair(&pp, &ctx, &ps)[c], Some(kp[c]));
            assert_eq!(decode_boxes(&pp, &ctx, &ps)[c], Some(kp[c].aabb()));
        }
        // One child only: it is the node.
        let (p1, k1) = encode_pair(
            &[kids[0], Aabb::EMPTY],
            [ChildPtr::Leaf(0), ChildPtr::Empty],
            &ctx,
            &ps,
        );
        assert_eq!(k1[0].aabb(), n);
        assert_eq!(decode_pair(&p1, &ctx, &ps), [Some(k1[0]), None]);
        // Growth at the same scale: invisible to modulo, visible to plane sharing.
        let grown = Ctx::from_decoded(&b([-1.0, 0.0, 0.0], [10.0, 10.0, 4.0]), &ps);
        assert_eq!(grown.scales(), ctx.scales());
        assert!(!ctx.invalidates(&grown, &m));
        assert!(ctx.invalidates(&grown, &ps));
        assert!(!ctx.invalidates(&ctx, &ps));
    }
}
