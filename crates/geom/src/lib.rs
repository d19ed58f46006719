//! Geometry core of Arbor: vectors, axis-aligned boxes, rays, triangles, Morton codes and the
//! ray/primitive tests every other crate builds on.
//!
//! Vectors are [`glam::Vec3`] (re-exported as [`Vec3`]); everything else is plain `Copy` data.

#![warn(missing_docs)]

mod aabb;
mod intersect;
mod morton;
mod ray;
mod triangle;

pub use aabb::Aabb;
pub use glam::{BVec4A, Mat4, Quat, Vec3, Vec4};
pub use intersect::{
    intersect_triangle_watertight, intersect_triangles4_watertight, ray_aabb, Hits4, RayPrecomp,
    TriangleHit, Triangles4, SLAB_FAR_SCALE,
};
pub use morton::{morton30, morton63, MortonGrid, MortonQuantizer};
pub use ray::Ray;
pub use triangle::Triangle;

/// True when all three components are finite (neither NaN nor infinite).
#[inline]
pub fn is_finite3(v: Vec3) -> bool {
    v.x.is_finite() && v.y.is_finite() && v.z.is_finite()
}
