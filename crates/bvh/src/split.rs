//! The SAH split engine of the top-down builders (binned SAH, full sweep SAH and the
//! 4-wide top-down builder).
//!
//! Each builder generates its candidate planes its own way (bins over the centroid range,
//! primitives sorted by centroid, a zoom into one bin), but every search ends in the same
//! evaluation: a run of items in plane order (bins, or single primitives), each a box and a
//! count, where the plane before item `i` puts items `..i` left and `i..` right. [`sweep`]
//! evaluates every such boundary in two passes, right to left (storing each right side's
//! area and count) and left to right (handing each boundary to the builder's cost and tie
//! rule). What differs between builders — the box type and the precision of its area, the
//! cost formula, the tie rule, which boundaries count — stays with the builder, as the
//! [`SweepBox`] it sweeps and the closure it passes, so each keeps its trees bit for bit.

use crate::{centroid, index_lane, lane_index, ordered_bits};
use geom::{Aabb, Vec3, Vec4};

/// A box that [`sweep`] accumulates, with the area measure its builder prices sides by.
pub(crate) trait SweepBox: Copy {
    /// The area measure (half the surface area, in the builder's precision).
    type Area: Copy + Default;
    /// The empty box, identity of [`SweepBox::union`].
    const EMPTY: Self;
    /// The union of two boxes.
    fn union(self, o: Self) -> Self;
    /// The area measure of a non-empty box.
    fn area(&self) -> Self::Area;
}

/// [`SweepBox`] for a box type with an inherent `EMPTY`, `union` and `f32` `half_area`.
macro_rules! sweep_box_f32 {
    ($t:ident) => {
        impl SweepBox for $t {
            type Area = f32;
            const EMPTY: Self = $t::EMPTY;
            #[inline(always)]
            fn union(self, o: Self) -> Self {
                $t::union(self, o)
            }
            #[inline(always)]
            fn area(&self) -> f32 {
                self.half_area()
            }
        }
    };
}

sweep_box_f32!(Aabb);
sweep_box_f32!(Box4);

/// Where [`sweep`] keeps the right side of each boundary between its two passes.
pub(crate) trait RightSides<A> {
    /// Stores the right side of the boundary before item `i`.
    fn set(&mut self, i: usize, area: A, count: u32);
    /// The right side (area, count) of the boundary before item `i`.
    fn get(&self, i: usize) -> (A, u32);
}

/// Right sides of items of any count: areas and counts in two arrays indexed by boundary.
pub(crate) struct Counted<'a, A>(pub &'a mut [A], pub &'a mut [u32]);

impl<A: Copy> RightSides<A> for Counted<'_, A> {
    #[inline(always)]
    fn set(&mut self, i: usize, area: A, count: u32) {
        self.0[i] = area;
        self.1[i] = count;
    }
    #[inline(always)]
    fn get(&self, i: usize) -> (A, u32) {
        (self.0[i], self.1[i])
    }
}

/// Right sides of `m` items of one primitive each: areas by boundary; the count before item
/// `i` is `m - i`, so none is stored.
pub(crate) struct Unit<'a, A>(pub &'a mut [A], pub usize);

impl<A: Copy> RightSides<A> for Unit<'_, A> {
    #[inline(always)]
    fn set(&mut self, i: usize, area: A, _count: u32) {
        self.0[i] = area;
    }
    #[inline(always)]
    fn get(&self, i: usize) -> (A, u32) {
        (self.0[i], (self.1 - i) as u32)
    }
}

/// Evaluates every boundary of the `m` items `item(0..m)` (each a box and a count, in plane
/// order): [`right_pass`], then [`left_pass`]. Returns the union of items `1..m`.
#[inline(always)]
pub(crate) fn sweep<B: SweepBox, R: RightSides<B::Area>>(
    m: usize,
    item: impl Fn(usize) -> (B, u32),
    right: &mut R,
    eval: impl FnMut(usize, &B, u32, B::Area, u32),
) -> B {
    let acc = right_pass(m, &item, right);
    left_pass(m, &item, &*right, eval);
    acc
}

/// Right to left over items `m - 1` down to 1: stores in `right` the right side of the
/// boundary before each; returns the union of items `1..m`. A builder that needs the
/// node's box before pricing the first boundary (the full sweep) runs the two passes
/// itself.
#[inline(always)]
pub(crate) fn right_pass<B: SweepBox, R: RightSides<B::Area>>(
    m: usize,
    item: impl Fn(usize) -> (B, u32),
    right: &mut R,
) -> B {
    let (mut acc, mut count) = (B::EMPTY, 0u32);
    for i in (1..m).rev() {
        let (b, c) = item(i);
        acc = acc.union(b);
        count += c;
        right.set(i, acc.area(), count);
    }
    acc
}

/// Left to right after [`right_pass`]: calls `eval(i, left box, left count, right area,
/// right count)` for the boundary before item `i`, for `i` in `1..m`.
#[inline(always)]
pub(crate) fn left_pass<B: SweepBox, R: RightSides<B::Area>>(
    m: usize,
    item: impl Fn(usize) -> (B, u32),
    right: &R,
    mut eval: impl FnMut(usize, &B, u32, B::Area, u32),
) {
    let (mut left, mut lcount) = (B::EMPTY, 0u32);
    for i in 1..m {
        let (b, c) = item(i - 1);
        left = left.union(b);
        lcount += c;
        let (ra, rc) = right.get(i);
        eval(i, &left, lcount, ra, rc);
    }
}

/// A box in 4-wide SIMD registers; lane `w` is not part of the box (see [`PrimRef`]).
#[derive(Clone, Copy)]
pub(crate) struct Box4 {
    /// Minimum corner (lane `w`: see [`PrimRef`]).
    pub(crate) min: Vec4,
    /// Maximum corner.
    pub(crate) max: Vec4,
}

impl Box4 {
    /// The empty box.
    pub(crate) const EMPTY: Box4 = Box4 {
        min: Vec4::splat(f32::INFINITY),
        max: Vec4::splat(f32::NEG_INFINITY),
    };

    /// The union of two boxes.
    #[inline(always)]
    pub(crate) fn union(self, o: Box4) -> Box4 {
        Box4 {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Half the surface area; only meaningful for a non-empty box.
    #[inline(always)]
    pub(crate) fn half_area(&self) -> f32 {
        let e = self.max - self.min;
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// The box as an [`Aabb`].
    #[inline(always)]
    pub(crate) fn aabb(&self) -> Aabb {
        Aabb::new(self.min.truncate(), self.max.truncate())
    }
}

/// A primitive reference: its box, with the input index stored in `min.w` by
/// [`index_lane`] (32 bytes in all; `max.w` is 0). That lane is never subnormal, so the
/// SIMD box arithmetic, which computes it along with x, y and z, takes no subnormal
/// assists (issue 17: the raw index bits made this builder 2x slower on Intel). The builders partition arrays of these in place, so every pass over
/// a node reads memory sequentially (an index array into the input boxes made every pass a
/// random gather, which dominated the build), and box unions are single SIMD min/max.
pub(crate) type PrimRef = Box4;

impl Box4 {
    /// The primitive reference of input primitive `index`, whose box is `b`.
    #[inline]
    pub(crate) fn new(b: &Aabb, index: u32) -> PrimRef {
        Box4 {
            min: b.min.extend(index_lane(index)),
            max: b.max.extend(0.0),
        }
    }

    /// The input index of a [`PrimRef`].
    #[inline(always)]
    pub(crate) fn index(&self) -> u32 {
        lane_index(self.min.w)
    }

    /// Centroid of a [`PrimRef`] as a SIMD vector (lane w meaningless; the same arithmetic
    /// as [`centroid`] in x, y and z).
    #[inline(always)]
    pub(crate) fn centroid4(&self) -> Vec4 {
        self.min * 0.5 + self.max * 0.5
    }

    /// Centroid of a [`PrimRef`] (same arithmetic as [`centroid`]).
    #[inline(always)]
    pub(crate) fn centroid(&self) -> Vec3 {
        centroid(&self.aabb())
    }

    /// Total-order sort key along `axis`: centroid, then input index.
    #[inline]
    pub(crate) fn key(&self, axis: usize) -> u64 {
        ((ordered_bits(self.centroid()[axis]) as u64) << 32) | self.index() as u64
    }
}

/// The half area of the box `min`..`max` (lane w ignored) in `f64`, so huge finite boxes
/// do not overflow (the 4-wide builder's precision).
#[inline(always)]
pub(crate) fn area4(min: Vec4, max: Vec4) -> f64 {
    let x = max.x as f64 - min.x as f64;
    let y = max.y as f64 - min.y as f64;
    let z = max.z as f64 - min.z as f64;
    x * y + y * z + z * x
}

/// A [`Box4`] priced by [`area4`] in `f64` in a sweep (the 4-wide builder's sides).
#[derive(Clone, Copy)]
pub(crate) struct Wide(pub Box4);

impl SweepBox for Wide {
    type Area = f64;
    const EMPTY: Self = Wide(Box4::EMPTY);
    #[inline(always)]
    fn union(self, o: Self) -> Self {
        Wide(self.0.union(o.0))
    }
    #[inline(always)]
    fn area(&self) -> f64 {
        area4(self.0.min, self.0.max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    /// Every boundary is handed over once, in order, with both sides' boxes and counts
    /// equal to those of a direct union; both stores give the same sides for unit items.
    #[test]
    fn sweep_hands_every_boundary_with_both_sides() {
        let boxes: Vec<Aabb> = (0..7)
            .map(|i| {
                let a = Vec3::new(i as f32, (i * i % 5) as f32, 0.0);
                Aabb::new(a, a + Vec3::splat(1.0 + i as f32 * 0.5))
            })
            .collect();
        let counts = [1u32, 3, 0, 2, 5, 1, 4];
        let union = |r: std::ops::Range<usize>| r.fold(Aabb::EMPTY, |b, k| b.union(boxes[k]));
        let (mut areas, mut cnt) = ([0f32; 7], [0u32; 7]);
        let mut seen = Vec::new();
        let all = sweep(
            7,
            |i| (boxes[i], counts[i]),
            &mut Counted(&mut areas, &mut cnt),
            |i, l, lc, ra, rc| {
                assert_eq!(*l, union(0..i));
                assert_eq!(lc, counts[..i].iter().sum::<u32>());
                assert_eq!(ra, union(i..7).half_area());
                assert_eq!(rc, counts[i..].iter().sum::<u32>());
                seen.push(i);
            },
        );
        assert_eq!(seen, [1, 2, 3, 4, 5, 6]);
        assert_eq!(all, union(1..7));
        let mut unit = [0f32; 7];
        let mut got = Vec::new();
        sweep(
            7,
            |i| (boxes[i], 1),
            &mut Unit(&mut unit, 7),
            |i, _, lc, ra, rc| got.push((i, lc, ra, rc)),
        );
        let want: Vec<_> = (1..7)
            .map(|i| (i, i as u32, union(i..7).half_area(), 7 - i as u32))
            .collect();
        assert_eq!(got, want);
        let none = sweep(
            1,
            |i| (boxes[i], 1),
            &mut Unit(&mut unit, 1),
            |_, _, _, _, _| panic!("no boundary in one item"),
        );
        assert_eq!(none, Aabb::EMPTY);
    }
}
