//! Triangles.

use crate::Aabb;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// A triangle given by its three vertices in world space.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Triangle {
    /// The vertices, counter-clockwise for the front face.
    pub v: [Vec3; 3],
}

impl Triangle {
    /// A triangle from three vertices.
    #[inline]
    pub const fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self { v: [a, b, c] }
    }

    /// Bounding box of the three vertices.
    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(
            self.v[0].min(self.v[1]).min(self.v[2]),
            self.v[0].max(self.v[1]).max(self.v[2]),
        )
    }

    /// Centroid (mean of the vertices).
    #[inline]
    pub fn centroid(&self) -> Vec3 {
        (self.v[0] + self.v[1] + self.v[2]) * (1.0 / 3.0)
    }

    /// Unnormalized geometric normal `(b - a) x (c - a)`; zero for degenerate triangles.
    #[inline]
    pub fn normal(&self) -> Vec3 {
        (self.v[1] - self.v[0]).cross(self.v[2] - self.v[0])
    }

    /// Area (zero for degenerate, collinear or repeated-vertex triangles).
    #[inline]
    pub fn area(&self) -> f32 {
        0.5 * self.normal().length()
    }

    /// True when the area is zero (the triangle still loads and is counted, see `scene`).
    #[inline]
    pub fn is_degenerate(&self) -> bool {
        self.normal() == Vec3::ZERO
    }

    /// True when every coordinate is finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.v.iter().all(|p| p.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_and_bounds() {
        let t = Triangle::new(Vec3::ZERO, Vec3::X * 2.0, Vec3::Y * 2.0);
        assert_eq!(t.area(), 2.0);
        assert_eq!(t.aabb(), Aabb::new(Vec3::ZERO, Vec3::new(2.0, 2.0, 0.0)));
        assert!(!t.is_degenerate());
        let d = Triangle::new(Vec3::ZERO, Vec3::X, Vec3::X * 2.0);
        assert!(d.is_degenerate());
        assert_eq!(d.area(), 0.0);
    }
}
