//! The brute-force reference: every triangle tested, the closest-hit rule of
//! [`crate::Hit::beats`] and [`crate::accel::enters_own_box`] applied. Tests compare
//! every kernel against it.

use crate::Hit;
use geom::{intersect_triangle_watertight, Ray, RayPrecomp, Triangle};

/// The closest hit of `ray` among all `triangles` (ties on `t` go to the smaller index),
/// with `leaf_entry` set to the triangle index.
pub fn brute_force(ray: &Ray, triangles: &[Triangle]) -> Option<Hit> {
    let pre = RayPrecomp::new(ray);
    let mut best: Option<Hit> = None;
    for (i, tri) in triangles.iter().enumerate() {
        if let Some(h) = intersect_triangle_watertight(&pre, tri, ray.t_min, ray.t_max) {
            if !crate::accel::enters_own_box(&pre, tri, ray.t_min, h.t) {
                continue;
            }
            let hit = Hit {
                t: h.t,
                prim: i as u32,
                leaf_entry: i as u32,
                bary: h.bary,
            };
            if hit.beats(best.as_ref()) {
                best = Some(hit);
            }
        }
    }
    best
}
