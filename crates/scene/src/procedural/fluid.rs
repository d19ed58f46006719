//! `fluid`: metaballs moving on seeded paths, polygonized every frame, so the triangle
//! count and topology change over time (`stable_topology: false`): a BVH must be rebuilt,
//! never refitted.
//!
//! Polygonization is **marching tetrahedra** on the Freudenthal (Kuhn) split of each grid
//! cube into six tetrahedra around the main diagonal, which needs no 256-case table and
//! has no ambiguous cases: every cube is split the same way, so neighbouring cubes agree
//! on their shared faces and the surface is closed. Vertices are welded by the id of the
//! grid edge they lie on, so the mesh is indexed and every edge has exactly two triangles,
//! consistently wound (normals point out of the fluid). The domain is a margin wider than
//! any ball can reach, chosen so the field is below the iso level on the whole boundary.
//!
//! Parameters: `n` (default 100 000, 100..=2 M): the grid resolution is calibrated once at
//! open time by polygonizing t = 0 on a coarse grid and scaling (triangle count grows with
//! the square of the resolution), so frame 0 has about `n` triangles and later frames vary
//! with the surface area; `balls` (default 8, 1..=64).

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Vec3};
use rayon::prelude::*;

/// The iso level of the field `sum r^2 / d^2`: a lone ball's surface is its radius.
const ISO: f32 = 1.0;
/// Keeps the field finite at a ball's centre.
const EPS: f32 = 1e-9;
/// Grid points per axis of the calibration pass and the largest grid allowed.
const CALIBRATION_POINTS: u32 = 40;
const MAX_POINTS: u32 = 640;
/// Cell layers per parallel task.
const SLAB: usize = 4;

/// The six tetrahedra of a cube (corner `c` is at `(c & 1, c >> 1 & 1, c >> 2 & 1)`): one
/// per axis order, each a monotone path from corner 0 to corner 7.
const TETS: [[u8; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];

/// One metaball: centre `base + amp * sin(omega t + phase)` per axis, radius squared.
#[derive(Clone, Copy)]
struct Ball {
    base: Vec3,
    amp: Vec3,
    omega: Vec3,
    phase: Vec3,
    r2: f32,
}

/// The metaball fluid.
pub struct Fluid {
    info: SceneInfo,
    balls: Vec<Ball>,
    /// The domain is `[-half, half]^3`.
    half: f32,
    /// Grid points per axis.
    points: u32,
}

impl Fluid {
    /// Reads the parameters, draws the balls and calibrates the grid.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(100_000, 100, 2_000_000)?;
        let k = p.get_in("balls", 8u32, 1, 64)?;
        p.finish()?;
        // More balls, smaller balls: keeps the total volume about constant.
        let scale = (8.0 / k as f32).cbrt().min(1.5);
        let balls: Vec<Ball> = (0..k)
            .map(|i| {
                let mut rng = Rng::stream(c.seed, i as u64);
                let r = scale * rng.range(0.25, 0.45);
                Ball {
                    base: 0.5 * rng.in_cube(),
                    amp: Vec3::new(
                        rng.range(0.2, 0.5),
                        rng.range(0.2, 0.5),
                        rng.range(0.2, 0.5),
                    ),
                    omega: Vec3::new(
                        rng.range(1.0, 3.0),
                        rng.range(1.0, 3.0),
                        rng.range(1.0, 3.0),
                    ),
                    phase: Vec3::new(
                        rng.range(0.0, 6.3),
                        rng.range(0.0, 6.3),
                        rng.range(0.0, 6.3),
                    ),
                    r2: r * r,
                }
            })
            .collect();
        // Centres stay in [-1, 1]^3. A boundary point is at least `margin` from every
        // centre, so its field is at most k * r_max^2 / margin^2 < ISO.
        let r_max = balls.iter().map(|b| b.r2).fold(0.0f32, f32::max).sqrt();
        let half = 1.0 + 1.1 * r_max * (k as f32).sqrt() / ISO.sqrt();
        let mut s = Fluid {
            info: p.info(
                c.timeline,
                false,
                Aabb::new(Vec3::splat(-half), Vec3::splat(half)),
            ),
            balls,
            half,
            points: CALIBRATION_POINTS,
        };
        let t0 = s.polygonize(0.0).triangle_count().max(1) as f64;
        let cells = (CALIBRATION_POINTS - 1) as f64 * (c.n as f64 / t0).sqrt();
        s.points = (cells.round() as u32 + 1).clamp(8, MAX_POINTS);
        Ok(s)
    }

    /// Ball centres and squared radii at `t`.
    fn balls_at(&self, t: f32) -> Vec<(Vec3, f32)> {
        let sin3 = |v: Vec3| Vec3::new(v.x.sin(), v.y.sin(), v.z.sin());
        self.balls
            .iter()
            .map(|b| (b.base + b.amp * sin3(b.omega * t + b.phase), b.r2))
            .collect()
    }

    /// Polygonizes the field at `t` on the scene's grid.
    fn polygonize(&self, t: f32) -> Mesh {
        let balls = self.balls_at(t);
        let np = self.points as usize;
        let cells = np - 1;
        let h = 2.0 * self.half / cells as f32;
        let half = self.half;
        // The same expressions here and in the welding pass give bit-identical values.
        let point = move |i: usize, j: usize, k: usize| {
            Vec3::new(
                -half + h * i as f32,
                -half + h * j as f32,
                -half + h * k as f32,
            )
        };
        let field = |p: Vec3| {
            balls
                .iter()
                .map(|&(c, r2)| r2 / (p.distance_squared(c) + EPS))
                .sum::<f32>()
        };
        let fill = |k: usize, layer: &mut [f32]| {
            for j in 0..np {
                for i in 0..np {
                    layer[j * np + i] = field(point(i, j, k));
                }
            }
        };
        let corner_offset = |c: u8| {
            (c & 1) as u64
                + ((c >> 1) & 1) as u64 * np as u64
                + ((c >> 2) & 1) as u64 * (np * np) as u64
        };

        // Pass 1, parallel over slabs of cell layers: triangles as triples of edge ids.
        let slabs: Vec<Vec<[u64; 3]>> = (0..cells.div_ceil(SLAB))
            .into_par_iter()
            .map(|slab| {
                let (z0, z1) = (slab * SLAB, ((slab + 1) * SLAB).min(cells));
                let mut lo = vec![0.0f32; np * np];
                let mut hi = vec![0.0f32; np * np];
                fill(z0, &mut lo);
                let mut out = Vec::new();
                for k in z0..z1 {
                    fill(k + 1, &mut hi);
                    for j in 0..cells {
                        for i in 0..cells {
                            let mut v = [0.0f32; 8];
                            let mut inside = 0u8;
                            for (c, val) in v.iter_mut().enumerate() {
                                let layer = if c & 4 == 0 { &lo } else { &hi };
                                *val = layer[(j + (c >> 1 & 1)) * np + i + (c & 1)];
                                inside |= u8::from(*val > ISO) << c;
                            }
                            if inside == 0 || inside == 255 {
                                continue;
                            }
                            let base = ((k * np + j) * np + i) as u64;
                            let edge = |a: u8, b: u8| {
                                // Tetrahedron edges join corners whose bits nest.
                                let lo = if a & b == a { a } else { b };
                                (base + corner_offset(lo)) * 8 + (a ^ b) as u64
                            };
                            for tet in &TETS {
                                march_tet(tet, inside, &edge, &mut out);
                            }
                        }
                    }
                    std::mem::swap(&mut lo, &mut hi);
                }
                out
            })
            .collect();
        let tris: Vec<[u64; 3]> = slabs.concat();

        // Pass 2: weld. Each distinct edge id is one vertex, placed where the field
        // crosses the iso level along that grid edge.
        let mut keys: Vec<u64> = tris.iter().flatten().copied().collect();
        keys.par_sort_unstable();
        keys.dedup();
        let positions: Vec<Vec3> = keys
            .par_iter()
            .map(|&e| {
                let (p, d) = ((e >> 3) as usize, (e & 7) as usize);
                let (i, j, k) = (p % np, (p / np) % np, p / (np * np));
                let a = point(i, j, k);
                let b = point(i + (d & 1), j + (d >> 1 & 1), k + (d >> 2 & 1));
                let (fa, fb) = (field(a), field(b));
                let s = (ISO - fa) / (fb - fa);
                let s = if s.is_finite() {
                    s.clamp(0.0, 1.0)
                } else {
                    0.5
                };
                a + s * (b - a)
            })
            .collect();
        let triangles: Vec<[u32; 3]> = tris
            .par_iter()
            .map(|t| t.map(|e| keys.binary_search(&e).unwrap_or_else(|i| i) as u32))
            .collect();
        Mesh::new(positions, triangles)
    }
}

/// Sign of the volume of the tetrahedron on cube corners `a, b, c, d`.
fn orientation(a: u8, b: u8, c: u8, d: u8) -> i32 {
    let p = |c: u8| [(c & 1) as i32, (c >> 1 & 1) as i32, (c >> 2 & 1) as i32];
    let (pa, pb, pc, pd) = (p(a), p(b), p(c), p(d));
    let u = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
    let v = [pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]];
    let w = [pd[0] - pa[0], pd[1] - pa[1], pd[2] - pa[2]];
    (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
        + u[2] * (v[0] * w[1] - v[1] * w[0]))
        .signum()
}

/// Emits the 0, 1 or 2 triangles of one tetrahedron, wound so that normals point from
/// inside (field above the iso level) to outside.
///
/// For a positively oriented tetrahedron `(a, b, c, d)`, the triangle on edges
/// `(ab, ac, ad)` faces away from `a`, and the quad `(ac, ad, bd, bc)` faces away from
/// `a` and `b`; a negative orientation flips both.
fn march_tet(tet: &[u8; 4], inside: u8, edge: &impl Fn(u8, u8) -> u64, out: &mut Vec<[u64; 3]>) {
    // Split the corners (in tetrahedron order) into inside and outside, without allocating:
    // this runs for every tetrahedron the surface crosses.
    let (mut ins, mut outs) = ([0u8; 4], [0u8; 4]);
    let (mut ni, mut no) = (0, 0);
    for &c in tet {
        if inside >> c & 1 == 1 {
            ins[ni] = c;
            ni += 1;
        } else {
            outs[no] = c;
            no += 1;
        }
    }
    match ni {
        1 | 3 => {
            let (a, rest) = if ni == 1 {
                (ins[0], &outs)
            } else {
                (outs[0], &ins)
            };
            let (b, c, d) = (rest[0], rest[1], rest[2]);
            let mut tri = [edge(a, b), edge(a, c), edge(a, d)];
            // Faces away from `a`: outward when `a` is the one inside.
            if (orientation(a, b, c, d) > 0) != (ni == 1) {
                tri.swap(1, 2);
            }
            out.push(tri);
        }
        2 => {
            let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
            let q = [edge(a, c), edge(a, d), edge(b, d), edge(b, c)];
            if orientation(a, b, c, d) > 0 {
                out.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
            } else {
                out.extend([[q[0], q[2], q[1]], [q[0], q[3], q[2]]]);
            }
        }
        _ => {}
    }
}

impl Scene for Fluid {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        Ok(self.polygonize(self.info.timeline.clamp(t)))
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_closed, check_scene, open_err, open_proc, signed_volume};
    use super::*;

    #[test]
    fn count_follows_n() {
        for n in [5_000usize, 60_000] {
            let c = open_proc(&format!("fluid?n={n}"))
                .mesh_at(0.0)
                .unwrap()
                .triangle_count();
            assert!((c as f64 / n as f64 - 1.0).abs() < 0.25, "n={n}: {c}");
        }
    }

    #[test]
    fn common_checks() {
        check_scene("fluid?n=3000&seed=4");
    }

    #[test]
    fn closed_outward_and_changing() {
        let s = open_proc("fluid?n=20000&balls=5");
        assert!(!s.info().stable_topology);
        let d = s.info().timeline.duration_s;
        let mut counts = Vec::new();
        for t in [0.0, 0.4 * d, d] {
            let m = s.mesh_at(t).unwrap();
            check_closed(&m).unwrap();
            let v = signed_volume(&m);
            // Five balls of radius <= 0.45 * cbrt(8/5): volume between 0 and their sum.
            assert!(
                v > 0.0 && v < 5.0 * 4.19 * (0.45f64 * 1.17).powi(3) * 1.5,
                "{v}"
            );
            counts.push(m.triangle_count());
        }
        assert!(counts.windows(2).any(|w| w[0] != w[1]), "{counts:?}");
    }

    #[test]
    fn lone_ball_is_a_sphere() {
        let f = open_proc_fluid("fluid?n=20000&balls=1");
        let m = f.mesh_at(0.0).unwrap();
        let (c, r2) = f.balls_at(0.0)[0];
        let r = r2.sqrt();
        for p in &m.positions {
            // Interpolating 1/d^2 linearly along a cell edge is accurate to a few percent.
            assert!((p.distance(c) / r - 1.0).abs() < 0.05, "{p} {c} {r}");
        }
        let v = signed_volume(&m) as f32;
        let exact = 4.0 / 3.0 * std::f32::consts::PI * r * r * r;
        assert!((v / exact - 1.0).abs() < 0.05, "{v} {exact}");
    }

    /// The scene itself (not boxed), to reach its balls.
    fn open_proc_fluid(s: &str) -> Fluid {
        let ps = crate::spec::ProcSpec::parse(s).unwrap();
        let opts = crate::LoadOptions::default();
        let p = super::super::Params {
            spec: s,
            ps: &ps,
            opts: &opts,
        };
        Fluid::new(&p).unwrap()
    }

    #[test]
    fn tetrahedra_are_consistent() {
        // All six tetrahedra fill the cube: volumes sum to 6 * (1/6).
        assert!(TETS
            .iter()
            .all(|t| orientation(t[0], t[1], t[2], t[3]) != 0));
        // Every tetrahedron edge joins nested corners (so edge ids are well defined).
        for t in &TETS {
            for a in 0..4 {
                for b in a + 1..4 {
                    assert_eq!(t[a] & t[b], t[a]);
                }
            }
        }
    }

    #[test]
    fn rejects_bad_balls() {
        assert!(open_err("fluid?balls=0").contains("balls"));
        assert!(open_err("fluid?balls=65").contains("balls"));
    }
}
