//! `explode`: a closed noisy sphere whose triangles fly apart, each on its own straight
//! path and spinning about its own axis.
//!
//! This is the case where refitting a BVH built at t = 0 degrades most: neighbouring
//! triangles end up far apart while the tree still groups them. Triangles keep their ids;
//! vertices are unshared (three per triangle) so they can separate.
//!
//! Parameters: `n` (default 100 000, 8..=5 M) is rounded to a UV sphere with `b` latitude
//! bands and `2b` longitude segments, `4 b (b - 1)` triangles; `speed` (default 1.0,
//! 0..=100) is the mean outward speed in sphere radii per second.

use super::{uv_sphere, Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Quat, Vec3};
use rayon::prelude::*;

/// One flying triangle: rest centroid, vertex offsets from it, velocity and spin.
#[derive(Clone, Copy)]
struct Shard {
    centroid: Vec3,
    offsets: [Vec3; 3],
    velocity: Vec3,
    /// Unit spin axis.
    axis: Vec3,
    /// Spin in radians per second.
    omega: f32,
}

/// The exploding sphere.
pub struct Explode {
    info: SceneInfo,
    shards: Vec<Shard>,
    triangles: Vec<[u32; 3]>,
}

impl Explode {
    /// Reads the parameters, builds the sphere and draws each triangle's motion.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(100_000, 8, 5_000_000)?;
        let speed = p.get_in("speed", 1.0f32, 0.0, 100.0)?;
        p.finish()?;
        let bands = ((c.n as f64 / 4.0).sqrt() + 0.5).round().max(2.0) as u32;
        let (mut pos, tris) = uv_sphere(bands, 2 * bands);
        // Smooth radial noise: a few seeded plane waves over the direction, applied to the
        // shared vertices so the surface stays closed before it breaks.
        let mut rng = Rng::stream(c.seed, u64::MAX);
        let waves: Vec<(Vec3, f32, f32)> = (1..=4)
            .map(|m| {
                (
                    rng.unit() * (2.0 * m as f32),
                    rng.range(0.0, std::f32::consts::TAU),
                    0.12 / m as f32,
                )
            })
            .collect();
        pos.par_iter_mut().for_each(|p| {
            let r = 1.0
                + waves
                    .iter()
                    .map(|&(k, ph, a)| a * (k.dot(*p) + ph).sin())
                    .sum::<f32>();
            *p *= r;
        });
        let shards: Vec<Shard> = tris
            .par_iter()
            .enumerate()
            .map(|(i, t)| {
                let v = t.map(|k| pos[k as usize]);
                let centroid = (v[0] + v[1] + v[2]) / 3.0;
                let mut rng = Rng::stream(c.seed, i as u64);
                let out = centroid.normalize_or(Vec3::Y);
                let velocity = speed * (out * rng.range(0.5, 1.5) + 0.3 * rng.in_ball());
                Shard {
                    centroid,
                    offsets: v.map(|p| p - centroid),
                    velocity,
                    axis: rng.unit(),
                    omega: rng.range(-6.0, 6.0),
                }
            })
            .collect();
        let triangles = (0..shards.len() as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let mut s = Explode {
            info: p.info(c.timeline, true, Aabb::EMPTY),
            shards,
            triangles,
        };
        // Shards move in straight lines, so the first and last frames bound the motion up to
        // the spin, which stays within a shard's size.
        let d = s.info.timeline.duration_s;
        let b = super::bounds_at(&s, &[0.0, d])?;
        s.info = p.info(c.timeline, true, b);
        Ok(s)
    }
}

impl Scene for Explode {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let mut positions = vec![Vec3::ZERO; 3 * self.shards.len()];
        positions
            .par_chunks_mut(3)
            .zip(self.shards.par_iter())
            .for_each(|(out, s)| {
                let c = s.centroid + s.velocity * t;
                let q = Quat::from_axis_angle(s.axis, s.omega * t);
                for (o, off) in out.iter_mut().zip(s.offsets) {
                    *o = c + q * off;
                }
            });
        Ok(Mesh::new(positions, self.triangles.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_scene, open_err, open_proc, signed_volume};

    #[test]
    fn count_follows_n() {
        for n in [2_000usize, 50_000] {
            let c = open_proc(&format!("explode?n={n}"))
                .mesh_at(0.0)
                .unwrap()
                .triangle_count();
            assert!((c as f64 / n as f64 - 1.0).abs() < 0.1, "n={n}: {c}");
        }
    }

    #[test]
    fn common_checks() {
        check_scene("explode?n=3000&seed=5");
    }

    #[test]
    fn starts_closed_and_spreads() {
        let s = open_proc("explode?n=5000");
        let m0 = s.mesh_at(0.0).unwrap();
        // A closed outward sphere of radius about 1 at t = 0.
        let v = signed_volume(&m0);
        assert!(v > 2.5 && v < 6.0, "{v}");
        let b0 = m0.bounds();
        let b1 = s.mesh_at(s.info().timeline.duration_s).unwrap().bounds();
        assert!(
            b1.extent().min_element() > 2.0 * b0.extent().max_element(),
            "{b0:?} {b1:?}"
        );
        // Triangles stay rigid: areas are kept as they fly.
        let a0: f32 = m0.triangles_iter().map(|t| t.area()).sum();
        let a1: f32 = s
            .mesh_at(1.0)
            .unwrap()
            .triangles_iter()
            .map(|t| t.area())
            .sum();
        assert!((a0 / a1 - 1.0).abs() < 1e-3);
        // speed=0 still spins but does not spread.
        let s = open_proc("explode?n=5000&speed=0");
        let b = s.mesh_at(2.0).unwrap().bounds();
        assert!(b.extent().max_element() < 1.2 * b0.extent().max_element());
    }

    #[test]
    fn rejects_bad_speed() {
        assert!(open_err("explode?speed=-1").contains("speed"));
    }
}
