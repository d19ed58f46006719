//! `hairball`: a ball filled with many thin curved strands; static.
//!
//! A stand-in for the Hairball scene (2.9 M triangles): triangle-heavy and very
//! incoherent, with long thin triangles criss-crossing the whole volume, so nearly every
//! node's box overlaps its siblings. Each strand is a smooth random walk of [`SEGS`] steps
//! inside the unit ball (its direction turns a little at each step and reflects off the
//! sphere), swept as an open tube with 3 sides: `6 * SEGS` = 96 triangles per strand.
//! Strand `i` draws from its own [`Rng`] stream, so the mesh is independent of the thread
//! count, and the first strands of a larger ball are those of a smaller one.
//!
//! Static: the timeline is [`Timeline::STATIC`] (`duration` and `fps` are checked like
//! every scene's but do not change it).
//!
//! Parameters: `n` (default 500 000, 96..=10 M) is rounded to whole strands of 96
//! triangles; `thickness` (default 0.004, 1e-5..=0.05) is the tube's radius (the ball's
//! radius is 1); `curl` (default 0.35, 0..=2) is how far a strand's direction turns per
//! step.

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo, Timeline};
use geom::Vec3;
use rayon::prelude::*;

/// Segments per strand.
const SEGS: usize = 16;
/// Tube sides.
const SIDES: usize = 3;
/// Triangles and vertices per strand.
const STRAND_TRIS: usize = 2 * SIDES * SEGS;
const STRAND_VERTS: usize = SIDES * (SEGS + 1);
/// Length of one step of a strand (the ball's radius is 1).
const STEP: f32 = 0.09;

/// The hairball.
pub struct Hairball {
    info: SceneInfo,
    mesh: Mesh,
}

impl Hairball {
    /// Reads the parameters and generates the mesh.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(500_000, STRAND_TRIS, 10_000_000)?;
        let thickness = p.get_in("thickness", 0.004f32, 1e-5, 0.05)?;
        let curl = p.get_in("curl", 0.35f32, 0.0, 2.0)?;
        p.finish()?;
        let strands = ((c.n + STRAND_TRIS / 2) / STRAND_TRIS).max(1);
        let mut positions = vec![Vec3::ZERO; strands * STRAND_VERTS];
        positions
            .par_chunks_mut(STRAND_VERTS)
            .enumerate()
            .for_each(|(i, out)| strand(c.seed, i as u64, thickness, curl, out));
        let triangles: Vec<[u32; 3]> = (0..strands)
            .into_par_iter()
            .flat_map_iter(|s| {
                let base = (s * STRAND_VERTS) as u32;
                (0..SEGS).flat_map(move |g| {
                    (0..SIDES).flat_map(move |k| {
                        let ring = |g: usize, k: usize| base + (g * SIDES + k % SIDES) as u32;
                        let (a, b) = (ring(g, k), ring(g, k + 1));
                        let (c, d) = (ring(g + 1, k), ring(g + 1, k + 1));
                        [[a, b, d], [a, d, c]]
                    })
                })
            })
            .collect();
        let mesh = Mesh::new(positions, triangles);
        let mut timeline = Timeline::STATIC;
        timeline.fps = c.timeline.fps;
        Ok(Hairball {
            info: p.info(timeline, true, mesh.bounds()),
            mesh,
        })
    }
}

/// Any unit vector perpendicular to the unit vector `t`.
fn perpendicular(t: Vec3) -> Vec3 {
    let a = if t.x.abs() < 0.6 { Vec3::X } else { Vec3::Y };
    (a - t * a.dot(t)).normalize()
}

/// Strand `i`'s tube vertices: `SEGS + 1` rings of `SIDES`.
fn strand(seed: u64, i: u64, radius: f32, curl: f32, out: &mut [Vec3]) {
    let mut rng = Rng::stream(seed, i);
    // The centre line: a smooth random walk that stays in the ball.
    let mut pts = [Vec3::ZERO; SEGS + 1];
    pts[0] = 0.95 * rng.in_ball();
    let mut dir = rng.unit();
    for g in 1..=SEGS {
        dir = (dir + curl * rng.unit()).normalize_or(dir);
        let p = pts[g - 1];
        if (p + STEP * dir).length() > 1.0 {
            // Reflect off the sphere's tangent plane: the strand turns inwards.
            let nrm = p.normalize_or(Vec3::Y);
            let along = dir.dot(nrm);
            if along > 0.0 {
                dir = (dir - 2.0 * along * nrm).normalize_or(-nrm);
            }
        }
        pts[g] = p + STEP * dir;
    }
    // Sweep a triangle along it with a parallel-transported frame.
    let mut u = perpendicular((pts[1] - pts[0]).normalize());
    for g in 0..=SEGS {
        let t = (pts[(g + 1).min(SEGS)] - pts[g.saturating_sub(1)]).normalize();
        let w = u - t * u.dot(t);
        u = if w.length_squared() > 1e-6 {
            w.normalize()
        } else {
            perpendicular(t)
        };
        let v = t.cross(u);
        for k in 0..SIDES {
            let a = std::f32::consts::TAU * k as f32 / SIDES as f32;
            out[g * SIDES + k] = pts[g] + radius * (a.cos() * u + a.sin() * v);
        }
    }
}

impl Scene for Hairball {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, _t: f32) -> Result<Mesh, SceneError> {
        Ok(self.mesh.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_static_scene, min_double_area, open_err, open_proc};
    use super::*;

    #[test]
    fn common_checks() {
        check_static_scene("hairball?n=3000&seed=4");
    }

    #[test]
    fn count_is_close_to_n_and_in_the_ball() {
        for n in [96usize, 1_000, 5_000] {
            let m = open_proc(&format!("hairball?n={n}")).mesh_at(0.0).unwrap();
            let got = m.triangle_count();
            assert_eq!(got % STRAND_TRIS, 0);
            assert!(got.abs_diff(n) <= STRAND_TRIS / 2, "{n}: {got}");
            let r = m.positions.iter().map(|p| p.length()).fold(0.0, f32::max);
            assert!(r < 1.0 + STEP + 0.01, "{r}");
        }
    }

    #[test]
    fn no_degenerate_triangles_and_incoherent() {
        let m = open_proc("hairball?n=5000&seed=3").mesh_at(0.0).unwrap();
        let a = min_double_area(&m);
        assert!(a > 1e-6, "{a}");
        // Strands criss-cross the ball: it is filled, not a shell.
        let b = m.bounds();
        assert!(b.min.cmplt(Vec3::splat(-0.8)).all(), "{b:?}");
        assert!(b.max.cmpgt(Vec3::splat(0.8)).all(), "{b:?}");
        let inner = m.positions.iter().filter(|p| p.length() < 0.5).count();
        assert!(inner > m.positions.len() / 20, "{inner}");
    }

    #[test]
    fn strands_are_independent_streams() {
        let a = open_proc("hairball?n=3000").mesh_at(0.0).unwrap();
        let b = open_proc("hairball?n=1500").mesh_at(0.0).unwrap();
        assert_eq!(&a.positions[..b.positions.len()], &b.positions[..]);
        let c = open_proc("hairball?n=1500&seed=2").mesh_at(0.0).unwrap();
        assert_ne!(b.positions, c.positions);
    }

    #[test]
    fn rejects_bad_parameters() {
        for (q, key) in [
            ("thickness=0", "thickness"),
            ("thickness=1", "thickness"),
            ("curl=-1", "curl"),
            ("curl=x", "curl"),
            ("n=20000000", "parameter n="),
        ] {
            let e = open_err(&format!("hairball?{q}"));
            assert!(e.contains(key) && !e.contains('\n'), "{e}");
        }
    }
}
