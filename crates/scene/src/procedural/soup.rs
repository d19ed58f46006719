//! `soup`: uniformly random small triangles in the cube `[-1, 1]^3`, slowly jittering.
//!
//! The worst case for spatial coherence and the scale test: `n` (default 1 M, 1..=50 M)
//! is exact. Nothing is stored: each frame is regenerated in parallel chunks of
//! [`CHUNK`] triangles, chunk `c` drawing from its own [`Rng`] stream, so the result is
//! independent of the thread count and peak memory is one mesh (about 52 bytes per
//! triangle: three unshared vertices, indices and a material id).
//!
//! Parameters: `size` (default `2 / cbrt(n)`, the mean centroid spacing; 1e-6..=2) is the
//! edge of the cube each triangle's vertices are drawn in; `jitter` (default 0.25,
//! 0..=100) is the radius of each triangle's elliptical orbit in units of `size`.

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Vec3};
use rayon::prelude::*;

/// Triangles per random stream (and per parallel task).
const CHUNK: usize = 1 << 15;

/// Orbit frequency of the jitter, in revolutions per second.
const JITTER_HZ: f32 = 0.5;

/// The random soup.
pub struct Soup {
    info: SceneInfo,
    n: usize,
    seed: u64,
    size: f32,
    jitter: f32,
}

impl Soup {
    /// Reads the parameters; generates nothing yet.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(1_000_000, 1, 50_000_000)?;
        let auto = 2.0 / (c.n as f32).cbrt();
        let size = p.get_in("size", auto, 1e-6, 2.0)?;
        let jitter = p.get_in("jitter", 0.25f32, 0.0, 100.0)?;
        p.finish()?;
        // Centroids in [-1, 1]^3, vertices within size/2 of them, orbits within
        // 3 * jitter * size per axis (|a sin + b (cos - 1)| <= 1 + 2).
        let r = 0.5 * size + 3.0 * jitter * size;
        let bounds = Aabb::new(Vec3::splat(-1.0 - r), Vec3::splat(1.0 + r));
        Ok(Soup {
            info: p.info(c.timeline, true, bounds),
            n: c.n,
            seed: c.seed,
            size,
            jitter,
        })
    }
}

impl Scene for Soup {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let w = std::f32::consts::TAU * JITTER_HZ * t;
        // Orbit a * sin(wt) + b * (cos(wt) - 1): zero at t = 0, no trig per triangle.
        let (sw, cw) = (w.sin(), w.cos() - 1.0);
        let (half, orbit) = (0.5 * self.size, self.jitter * self.size);
        let mut positions = vec![Vec3::ZERO; 3 * self.n];
        positions
            .par_chunks_mut(3 * CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                let mut rng = Rng::stream(self.seed, chunk as u64);
                for tri in out.chunks_exact_mut(3) {
                    let c = rng.in_cube();
                    let (a, b) = (rng.in_cube(), rng.in_cube());
                    let c = c + orbit * (a * sw + b * cw);
                    for v in tri.iter_mut() {
                        *v = c + half * rng.in_cube();
                    }
                }
            });
        let triangles: Vec<[u32; 3]> = (0..self.n as u32)
            .into_par_iter()
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        Ok(Mesh::new(positions, triangles))
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_scene, open_err, open_proc};

    #[test]
    fn count_is_exact() {
        for n in [1usize, 1_000, 100_000] {
            let m = open_proc(&format!("soup?n={n}")).mesh_at(0.3).unwrap();
            assert_eq!(m.triangle_count(), n);
            assert_eq!(m.positions.len(), 3 * n);
        }
    }

    #[test]
    fn common_checks() {
        check_scene("soup?n=10000&seed=9");
    }

    #[test]
    fn two_million_fill_the_cube_with_small_triangles() {
        let s = open_proc("soup?n=2000000");
        let m = s.mesh_at(1.0).unwrap();
        assert_eq!(m.triangle_count(), 2_000_000);
        m.check().unwrap();
        assert!(m.positions.iter().all(|p| p.is_finite()));
        let b = m.bounds();
        assert!(b.min.cmplt(geom::Vec3::splat(-0.99)).all(), "{b:?}");
        assert!(b.max.cmpgt(geom::Vec3::splat(0.99)).all(), "{b:?}");
        // Triangles are small: edge of the vertex cube is 2 / cbrt(n) = 0.016.
        let big = m
            .triangles_iter()
            .filter(|t| t.aabb().extent().max_element() > 0.05)
            .count();
        assert!(big < 20, "{big}");
        // Uniform: each octant holds about an eighth.
        let pos_x = m.triangles_iter().filter(|t| t.centroid().x > 0.0).count();
        assert!((pos_x as f64 / 2e6 - 0.5).abs() < 0.01, "{pos_x}");
    }

    /// The scale target: too slow for the suite, run by hand with
    /// `/usr/bin/time -v <test binary> --ignored --exact procedural::soup::tests::twenty_million`.
    #[test]
    #[ignore]
    fn twenty_million() {
        let t0 = std::time::Instant::now();
        let m = open_proc("soup?n=20000000").mesh_at(1.0).unwrap();
        assert_eq!(m.triangle_count(), 20_000_000);
        println!("soup n=20M: {:?}", t0.elapsed());
    }

    #[test]
    fn chunks_are_independent_streams() {
        // The first triangles of a larger soup are those of a smaller one (same seed and
        // size), so generation does not depend on n's chunking or the thread count.
        let a = open_proc("soup?n=70000&size=0.01").mesh_at(0.5).unwrap();
        let b = open_proc("soup?n=40000&size=0.01").mesh_at(0.5).unwrap();
        assert_eq!(&a.positions[..b.positions.len()], &b.positions[..]);
        let c = open_proc("soup?n=40000&size=0.01&seed=2")
            .mesh_at(0.5)
            .unwrap();
        assert_ne!(b.positions, c.positions);
    }

    #[test]
    fn rejects_bad_size() {
        assert!(open_err("soup?size=0").contains("size"));
        assert!(open_err("soup?size=3").contains("size"));
        assert!(open_err("soup?n=60000000").contains("parameter n="));
    }
}
