//! Morton (Z-order) codes of points quantized to a bounding box.
//!
//! LBVH and HLBVH builders (\[P2\] §3, §5.4) sort primitives by the Morton code of their
//! AABB centroid. A 30-bit code interleaves 10 bits per axis (1024^3 cells); a 63-bit code
//! interleaves 21 bits per axis. In every code, bit `3i + 2` is bit `i` of x, `3i + 1` of y
//! and `3i` of z, so x is the most significant axis (the convention of Karras 2012).

use crate::Aabb;
use glam::Vec3;

/// Spreads the low 10 bits of `v` so that bit `i` moves to bit `3i`.
#[inline]
fn spread10(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

/// Spreads the low 21 bits of `v` so that bit `i` moves to bit `3i`.
#[inline]
fn spread21(v: u32) -> u64 {
    let mut x = (v as u64) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Interleaves three 10-bit cell coordinates into a 30-bit Morton code.
#[inline]
pub fn morton30(q: [u32; 3]) -> u32 {
    (spread10(q[0]) << 2) | (spread10(q[1]) << 1) | spread10(q[2])
}

/// Interleaves three 21-bit cell coordinates into a 63-bit Morton code.
#[inline]
pub fn morton63(q: [u32; 3]) -> u64 {
    (spread21(q[0]) << 2) | (spread21(q[1]) << 1) | spread21(q[2])
}

/// The grid that Morton codes quantize centroids on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MortonGrid {
    /// `2^bits` cells on each axis of the box: cells are stretched to the box's shape, so a
    /// long, flat scene keeps its full resolution on every axis (the default; Karras 2012).
    #[default]
    Box,
    /// Cubic cells: the box's longest axis is split into `2^bits` cells and the others get
    /// cells of the same size (fewer of them), as when a unit quantizes on the scene's
    /// bounding cube. Coarser on the short axes, so more primitives share a code.
    Cube,
}

impl MortonGrid {
    /// The grid's name as `--set morton_grid=` takes it.
    pub fn name(self) -> &'static str {
        match self {
            MortonGrid::Box => "box",
            MortonGrid::Cube => "cube",
        }
    }
}

/// Maps points in a bounding box to integer grid cells and Morton codes.
///
/// Each axis of the box is split into `2^bits` equal cells; points outside the box (and
/// NaN) are clamped to the nearest cell, so codes are always defined. An axis of zero
/// extent (a flat scene, such as the cloth sheet of \[P3\] §4.4) maps every point to cell 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MortonQuantizer {
    origin: Vec3,
    /// Cells per unit length on each axis, for a 1-cell grid; multiplied by `2^bits`.
    inv_extent: Vec3,
}

impl MortonQuantizer {
    /// A quantizer over `bounds` (an empty or non-finite box degrades to a single cell).
    pub fn new(bounds: &Aabb) -> Self {
        if bounds.is_empty() || !bounds.is_finite() {
            return Self {
                origin: Vec3::ZERO,
                inv_extent: Vec3::ZERO,
            };
        }
        let e = bounds.max - bounds.min;
        let inv = |x: f32| if x > 0.0 { 1.0 / x } else { 0.0 };
        Self {
            origin: bounds.min,
            inv_extent: Vec3::new(inv(e.x), inv(e.y), inv(e.z)),
        }
    }

    /// A quantizer over `bounds` on `grid`: [`Self::new`] for [`MortonGrid::Box`]; for
    /// [`MortonGrid::Cube`], cells whose size on every axis is the longest extent over
    /// `2^bits`, from the same origin.
    pub fn with_grid(bounds: &Aabb, grid: MortonGrid) -> Self {
        let q = Self::new(bounds);
        match grid {
            MortonGrid::Box => q,
            MortonGrid::Cube => {
                let inv = q.inv_extent;
                // The longest axis has the smallest non-zero inverse extent; an all-flat
                // box (every inverse zero) stays a single cell.
                let longest = [inv.x, inv.y, inv.z]
                    .into_iter()
                    .filter(|&v| v > 0.0)
                    .fold(f32::INFINITY, f32::min);
                let c = if longest.is_finite() { longest } else { 0.0 };
                Self {
                    origin: q.origin,
                    inv_extent: Vec3::splat(c),
                }
            }
        }
    }

    /// The cell of `p` on a grid of `2^bits` cells per axis (`bits <= 21`).
    #[inline]
    pub fn cell(&self, p: Vec3, bits: u32) -> [u32; 3] {
        debug_assert!(bits <= 21);
        let cells = (1u32 << bits) as f32;
        let max_cell = (1u32 << bits) - 1;
        let r = (p - self.origin) * self.inv_extent * cells;
        // `as u32` saturates: negative and NaN give 0, huge values give u32::MAX.
        let q = |x: f32| (x as u32).min(max_cell);
        [q(r.x), q(r.y), q(r.z)]
    }

    /// 30-bit Morton code of `p`.
    #[inline]
    pub fn code30(&self, p: Vec3) -> u32 {
        morton30(self.cell(p, 10))
    }

    /// 63-bit Morton code of `p`.
    #[inline]
    pub fn code63(&self, p: Vec3) -> u64 {
        morton63(self.cell(p, 21))
    }

    /// 30-bit Morton code of the centroid of `b`.
    #[inline]
    pub fn code30_aabb(&self, b: &Aabb) -> u32 {
        self.code30(b.center())
    }

    /// 63-bit Morton code of the centroid of `b`.
    #[inline]
    pub fn code63_aabb(&self, b: &Aabb) -> u64 {
        self.code63(b.center())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn cube_grid_has_equal_cells_on_every_axis() {
        let b = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(8.0, 2.0, 1.0));
        let boxed = MortonQuantizer::with_grid(&b, MortonGrid::Box);
        assert_eq!(boxed, MortonQuantizer::new(&b));
        let cube = MortonQuantizer::with_grid(&b, MortonGrid::Cube);
        // 4 bits: 16 cells of 0.5 on x, and the same 0.5 cells on y and z.
        assert_eq!(cube.cell(Vec3::new(7.9, 1.9, 0.9), 4), [15, 3, 1]);
        assert_eq!(boxed.cell(Vec3::new(7.9, 1.9, 0.9), 4), [15, 15, 14]);
        assert_eq!(cube.cell(Vec3::new(0.6, 0.6, 0.6), 4), [1, 1, 1]);
        // A flat axis stays at cell 0; a point box is one cell.
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(4.0, 0.0, 2.0));
        let q = MortonQuantizer::with_grid(&flat, MortonGrid::Cube);
        assert_eq!(q.cell(Vec3::new(4.0, 0.0, 2.0), 2), [3, 0, 2]);
        let point = Aabb::new(Vec3::ONE, Vec3::ONE);
        let q = MortonQuantizer::with_grid(&point, MortonGrid::Cube);
        assert_eq!(q.cell(Vec3::new(5.0, -3.0, 1.0), 10), [0, 0, 0]);
    }

    proptest! {
        /// On a cube grid every cell coordinate is within range and no finer than on the
        /// box grid (cells are at least as large on every axis).
        #[test]
        fn cube_cells_are_never_finer_than_box_cells(
            ext in prop::array::uniform3(0.0f32..100.0),
            t in prop::array::uniform3(0.0f32..=1.0),
        ) {
            let b = Aabb::new(Vec3::ZERO, Vec3::from(ext));
            let p = Vec3::new(t[0] * ext[0], t[1] * ext[1], t[2] * ext[2]);
            let cube = MortonQuantizer::with_grid(&b, MortonGrid::Cube).cell(p, 10);
            let boxed = MortonQuantizer::new(&b).cell(p, 10);
            for a in 0..3 {
                prop_assert!(cube[a] <= boxed[a] && cube[a] < 1024);
            }
        }
    }

    /// Reference interleaving, one bit at a time.
    fn slow(q: [u32; 3], bits: u32) -> u64 {
        let mut c = 0u64;
        for i in 0..bits {
            for (a, &v) in q.iter().enumerate() {
                c |= (((v >> i) & 1) as u64) << (3 * i + 2 - a as u32);
            }
        }
        c
    }

    proptest! {
        #[test]
        fn morton30_matches_bitwise_reference(x in 0u32..1024, y in 0u32..1024, z in 0u32..1024) {
            prop_assert_eq!(morton30([x, y, z]) as u64, slow([x, y, z], 10));
        }

        #[test]
        fn morton63_matches_bitwise_reference(x in 0u32..(1 << 21), y in 0u32..(1 << 21), z in 0u32..(1 << 21)) {
            prop_assert_eq!(morton63([x, y, z]), slow([x, y, z], 21));
        }

        #[test]
        fn codes_preserve_order_along_an_axis(a in 0.0f32..1.0, b in 0.0f32..1.0) {
            let q = MortonQuantizer::new(&Aabb::new(Vec3::ZERO, Vec3::ONE));
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            prop_assert!(q.code30(Vec3::new(lo, 0.0, 0.0)) <= q.code30(Vec3::new(hi, 0.0, 0.0)));
            prop_assert!(q.code63(Vec3::new(0.0, 0.0, lo)) <= q.code63(Vec3::new(0.0, 0.0, hi)));
        }
    }

    #[test]
    fn corners_and_bit_positions() {
        let q = MortonQuantizer::new(&Aabb::new(Vec3::ZERO, Vec3::splat(2.0)));
        assert_eq!(q.code30(Vec3::ZERO), 0);
        assert_eq!(q.code30(Vec3::splat(2.0)), (1 << 30) - 1);
        assert_eq!(q.code63(Vec3::splat(2.0)), (1 << 63) - 1);
        // The top bit of the code is the top bit of x.
        assert_eq!(q.code30(Vec3::new(1.0, 0.0, 0.0)), 1 << 29);
        assert_eq!(q.code30(Vec3::new(0.0, 1.0, 0.0)), 1 << 28);
        assert_eq!(q.code30(Vec3::new(0.0, 0.0, 1.0)), 1 << 27);
    }

    #[test]
    fn outside_nan_and_flat_boxes_are_clamped() {
        let q = MortonQuantizer::new(&Aabb::new(Vec3::ZERO, Vec3::ONE));
        assert_eq!(q.code30(Vec3::splat(-5.0)), 0);
        assert_eq!(q.code30(Vec3::splat(5.0)), (1 << 30) - 1);
        assert_eq!(q.code30(Vec3::splat(f32::NAN)), 0);
        // A flat sheet in z: z maps to cell 0, x and y still order points.
        let flat = MortonQuantizer::new(&Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)));
        assert_eq!(flat.cell(Vec3::new(0.5, 0.25, 0.0), 10), [512, 256, 0]);
        let empty = MortonQuantizer::new(&Aabb::EMPTY);
        assert_eq!(empty.code63(Vec3::ONE), 0);
    }
}
