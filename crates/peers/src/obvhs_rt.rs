//! obvhs (0.4) as a ray tracer, for side-by-side traversal benchmarks: its CWBVH (the
//! compressed 8-wide BVH of Ylitie et al. 2017, built from a PLOC tree) traced with its
//! SIMD traversal and its own triangle test (`obvhs::triangle::Triangle::intersect`).

use crate::obvhs_peer::ObvhsPreset;
use crate::{check_input, PeerError};
use geom::{Ray, Triangle};
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray as ORay, RayHit};
use obvhs::triangle::Triangle as OTri;
use obvhs_glam::Vec3A;
use std::time::Duration;

/// An obvhs CWBVH over triangles, with the triangles in leaf order.
pub struct ObvhsTracer {
    bvh: CwBvh,
    /// Triangles in obvhs's primitive order (`bvh.primitive_indices` maps them back).
    tris: Vec<OTri>,
    /// obvhs's own measure of its core build time.
    pub build_time: Duration,
}

fn v(p: geom::Vec3) -> Vec3A {
    Vec3A::new(p.x, p.y, p.z)
}

impl ObvhsTracer {
    /// Builds a CWBVH over `triangles` with an obvhs preset (in the current rayon pool).
    pub fn new(triangles: &[Triangle], preset: ObvhsPreset) -> Result<Self, PeerError> {
        let boxes: Vec<geom::Aabb> = triangles.iter().map(Triangle::aabb).collect();
        check_input(&boxes)?;
        let tris: Vec<OTri> = triangles
            .iter()
            .map(|t| OTri {
                v0: v(t.v[0]),
                v1: v(t.v[1]),
                v2: v(t.v[2]),
            })
            .collect();
        let mut build_time = Duration::ZERO;
        let bvh = build_cwbvh_from_tris(&tris, preset.params(), &mut build_time);
        Ok(Self {
            bvh,
            tris,
            build_time,
        })
    }

    /// The closest hit of `ray`: `(triangle index, t)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<(u32, f32)> {
        let r = ORay::new(v(ray.origin), v(ray.dir), ray.t_min, ray.t_max);
        let mut hit = RayHit::none();
        let bvh = &self.bvh;
        let tris = &self.tris;
        if bvh.ray_traverse(r, &mut hit, |r, id| {
            tris[bvh.primitive_indices[id] as usize].intersect(r)
        }) {
            Some((bvh.primitive_indices[hit.primitive_id as usize], hit.t))
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    #[test]
    fn obvhs_hits_what_it_should() {
        let tris = vec![
            Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y),
            Triangle::new(
                Vec3::new(0.0, 0.0, -1.0),
                Vec3::new(1.0, 0.0, -1.0),
                Vec3::new(0.0, 1.0, -1.0),
            ),
        ];
        let t = ObvhsTracer::new(&tris, ObvhsPreset::FastBuild).unwrap();
        // (obvhs's triangle test rejects barycentrics of -0.0, which a direction with
        // negative zero components gives here, so the direction is written out.)
        let down = Vec3::new(0.0, 0.0, -1.0);
        let (p, d) = t
            .intersect(&Ray::new(Vec3::new(0.2, 0.2, 1.0), down))
            .unwrap();
        assert_eq!(p, 0);
        assert!((d - 1.0).abs() < 1e-6);
        assert!(t
            .intersect(&Ray::new(Vec3::new(0.2, 0.2, 1.0), Vec3::Z))
            .is_none());
    }
}
