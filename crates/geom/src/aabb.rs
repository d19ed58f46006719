//! Axis-aligned bounding boxes.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// An axis-aligned bounding box. The empty box has `min = +inf`, `max = -inf`, so that
/// growing it by any point or box gives that point or box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    /// The empty box (identity of [`Aabb::union`]).
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// A box from its corners (not reordered).
    #[inline]
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    /// The box of a single point.
    #[inline]
    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }

    /// The smallest box that holds all `points` (empty for no points).
    pub fn from_points<I: IntoIterator<Item = Vec3>>(points: I) -> Self {
        points.into_iter().fold(Self::EMPTY, |b, p| b.grow(p))
    }

    /// True when the box contains no point (some `min > max`).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// This box grown to contain `p`.
    #[inline]
    pub fn grow(self, p: Vec3) -> Self {
        Self {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The smallest box containing both boxes.
    #[inline]
    pub fn union(self, o: Aabb) -> Self {
        Self {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// The overlap of both boxes (may be empty).
    #[inline]
    pub fn intersection(self, o: Aabb) -> Self {
        Self {
            min: self.min.max(o.min),
            max: self.max.min(o.max),
        }
    }

    /// Edge lengths (zero for an empty box).
    #[inline]
    pub fn extent(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    /// Centre point (the centroid of the box).
    #[inline]
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area `2(xy + yz + zx)`; zero for an empty box.
    #[inline]
    pub fn surface_area(&self) -> f32 {
        let e = self.extent();
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Half the surface area, the quantity SAH ratios actually need.
    #[inline]
    pub fn half_area(&self) -> f32 {
        let e = self.extent();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Index (0 = x, 1 = y, 2 = z) of the longest axis.
    #[inline]
    pub fn largest_axis(&self) -> usize {
        let e = self.extent();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }

    /// True when `p` lies inside or on the boundary.
    #[inline]
    pub fn contains_point(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// True when `o` lies entirely inside this box (an empty `o` is inside anything).
    #[inline]
    pub fn contains(&self, o: &Aabb) -> bool {
        o.is_empty() || (o.min.cmpge(self.min).all() && o.max.cmple(self.max).all())
    }

    /// True when both corners are finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.min.is_finite() && self.max.is_finite()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn empty_box_is_identity_of_union() {
        let b = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.0, 3.0, 4.0));
        assert_eq!(Aabb::EMPTY.union(b), b);
        assert!(Aabb::EMPTY.is_empty());
        assert_eq!(Aabb::EMPTY.surface_area(), 0.0);
    }

    #[test]
    fn surface_area_of_unit_cube_is_six() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(b.surface_area(), 6.0);
        assert_eq!(b.half_area(), 3.0);
        assert_eq!(
            Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 0.0)).surface_area(),
            4.0
        );
    }

    #[test]
    fn largest_axis_picks_longest_edge() {
        assert_eq!(
            Aabb::new(Vec3::ZERO, Vec3::new(1.0, 5.0, 2.0)).largest_axis(),
            1
        );
        assert_eq!(
            Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 2.0)).largest_axis(),
            2
        );
    }

    fn v3() -> impl Strategy<Value = Vec3> {
        (-1e3f32..1e3, -1e3f32..1e3, -1e3f32..1e3).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #[test]
        fn union_contains_both(a in v3(), b in v3(), c in v3(), d in v3()) {
            let x = Aabb::from_points([a, b]);
            let y = Aabb::from_points([c, d]);
            let u = x.union(y);
            prop_assert!(u.contains(&x) && u.contains(&y));
            prop_assert!(u.surface_area() >= x.surface_area().max(y.surface_area()));
            for p in [a, b, c, d] { prop_assert!(u.contains_point(p)); }
        }
    }
}
