//! `forest`: many trees on a huge ground plane, swaying in the wind.
//!
//! The point is very uneven triangle sizes, which stresses spatial splits and SAH
//! builders: the ground is 8 huge triangles, trunks are medium, canopies are blobs of small
//! triangles and leaves are many tiny free triangles (ground/leaf area ratio above 1e4,
//! typically 1e5).
//! Trees are scattered uniformly at random; each sways with its own phase, displacement
//! growing with the square of height so trunks stay rooted.
//!
//! Parameters: `n` (default 200 000, 100..=10 M) is rounded to whole trees of
//! `192 + leaves` triangles (48 trunk, 3 canopy blobs of 48, the leaves) plus the 8 ground
//! triangles; `leaves` per tree (default 150, 0..=10 000); `wind` (default 0.15, 0..=10) is
//! the sway amplitude at height 4.

use super::{uv_sphere, Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Vec3};
use rayon::prelude::*;

/// Trunk tessellation: sides and height segments (open tube).
const TRUNK_SIDES: u32 = 8;
const TRUNK_SEGS: u32 = 3;
/// Canopy blob tessellation (UV sphere) and blobs per tree.
const BLOB_BANDS: u32 = 4;
const BLOB_SEGS: u32 = 8;
const BLOBS: u32 = 3;
/// Triangles per tree without leaves: 48 + 3 * 48.
const TREE_BASE_TRIS: usize =
    (2 * TRUNK_SIDES * TRUNK_SEGS + BLOBS * 2 * BLOB_SEGS * (BLOB_BANDS - 1)) as usize;
/// Ground triangles (a 2 x 2 grid of squares).
const GROUND_TRIS: usize = 8;
/// Mean distance between trees.
const SPACING: f32 = 3.0;
/// Height at which the sway equals `wind`.
const SWAY_HEIGHT: f32 = 4.0;

/// A vertex at rest, with how much and in which phase it sways.
#[derive(Clone, Copy)]
struct SwayVertex {
    rest: Vec3,
    weight: f32,
    phase: f32,
}

/// The forest.
pub struct Forest {
    info: SceneInfo,
    vertices: Vec<SwayVertex>,
    triangles: Vec<[u32; 3]>,
    material_ids: Vec<u32>,
    wind: f32,
    /// Unit wind direction in the ground plane.
    wind_dir: Vec3,
}

/// One tree's geometry, appended to the scene's buffers.
struct TreeBuf {
    verts: Vec<Vec3>,
    tris: Vec<[u32; 3]>,
    mats: Vec<u32>,
}

impl TreeBuf {
    fn push_mesh(&mut self, pos: impl IntoIterator<Item = Vec3>, tris: &[[u32; 3]], mat: u32) {
        let base = self.verts.len() as u32;
        self.verts.extend(pos);
        self.tris.extend(tris.iter().map(|t| t.map(|v| v + base)));
        self.mats.extend(std::iter::repeat_n(mat, tris.len()));
    }
}

/// Material ids, in the order of `material_names`.
const GROUND: u32 = 0;
const BARK: u32 = 1;
const CANOPY: u32 = 2;
const LEAF: u32 = 3;

impl Forest {
    /// Reads the parameters and places the trees.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(200_000, 100, 10_000_000)?;
        let leaves = p.get_in("leaves", 150u32, 0, 10_000)?;
        let wind = p.get_in("wind", 0.15f32, 0.0, 10.0)?;
        p.finish()?;
        let per_tree = TREE_BASE_TRIS + leaves as usize;
        let trees = ((c.n.saturating_sub(GROUND_TRIS)) as f64 / per_tree as f64)
            .round()
            .max(1.0) as usize;
        let half = 0.5 * SPACING * (trees as f32).sqrt() + 20.0;

        // Shared templates: unit trunk tube and unit blob.
        let ring = |r: u32, s: u32| r * TRUNK_SIDES + s % TRUNK_SIDES;
        let mut trunk_tris = Vec::new();
        for r in 0..TRUNK_SEGS {
            for s in 0..TRUNK_SIDES {
                let (a, b, cc, d) = (
                    ring(r, s),
                    ring(r, s + 1),
                    ring(r + 1, s),
                    ring(r + 1, s + 1),
                );
                trunk_tris.push([a, cc, d]);
                trunk_tris.push([a, d, b]);
            }
        }
        let trunk_pos: Vec<Vec3> = (0..=TRUNK_SEGS)
            .flat_map(|r| {
                (0..TRUNK_SIDES).map(move |s| {
                    let a = std::f32::consts::TAU * s as f32 / TRUNK_SIDES as f32;
                    let h = r as f32 / TRUNK_SEGS as f32;
                    // Tapers to 60% at the top.
                    Vec3::new(a.cos() * (1.0 - 0.4 * h), h, a.sin() * (1.0 - 0.4 * h))
                })
            })
            .collect();
        let (blob_pos, blob_tris) = uv_sphere(BLOB_BANDS, BLOB_SEGS);

        let built: Vec<(TreeBuf, f32)> = (0..trees)
            .into_par_iter()
            .map(|i| {
                let mut rng = Rng::stream(c.seed, i as u64);
                let at = Vec3::new(
                    rng.range(-half + 2.0, half - 2.0),
                    0.0,
                    rng.range(-half + 2.0, half - 2.0),
                );
                let scale = rng.range(0.7, 1.3);
                let (height, radius) = (2.0 * scale, 0.12 * scale);
                let mut b = TreeBuf {
                    verts: Vec::new(),
                    tris: Vec::new(),
                    mats: Vec::new(),
                };
                b.push_mesh(
                    trunk_pos
                        .iter()
                        .map(|v| at + Vec3::new(v.x * radius, v.y * height, v.z * radius)),
                    &trunk_tris,
                    BARK,
                );
                let top = at + Vec3::new(0.0, height + 0.5 * scale, 0.0);
                let mut blobs = Vec::new();
                for _ in 0..BLOBS {
                    let centre = top + 0.5 * scale * rng.in_ball();
                    let r = scale * rng.range(0.6, 0.9);
                    let squash = Vec3::new(1.0, rng.range(0.6, 0.9), 1.0);
                    b.push_mesh(
                        blob_pos.iter().map(|v| centre + r * squash * *v),
                        &blob_tris,
                        CANOPY,
                    );
                    blobs.push((centre, r));
                }
                // Tiny equilateral leaves scattered in and around the blobs.
                let size = 0.05 * scale;
                for _ in 0..leaves {
                    let (centre, r) = blobs[(rng.next_u64() % BLOBS as u64) as usize];
                    let p = centre + 1.15 * r * rng.in_ball();
                    let u = rng.unit();
                    let v = u.any_orthonormal_vector();
                    let (s3, h) = (0.866_025_4 * size, 0.5 * size);
                    b.push_mesh(
                        [p + size * u, p - h * u + s3 * v, p - h * u - s3 * v],
                        &[[0, 1, 2]],
                        LEAF,
                    );
                }
                (b, rng.range(0.0, std::f32::consts::TAU))
            })
            .collect();

        // Trunk 32 + blobs 3 x 26 vertices, three per leaf.
        let mut vertices = Vec::with_capacity(9 + trees * (110 + 3 * leaves as usize));
        let mut triangles = Vec::with_capacity(GROUND_TRIS + trees * per_tree);
        let mut material_ids = Vec::with_capacity(triangles.capacity());
        // Ground: 3 x 3 vertices, 2 x 2 squares of two triangles, facing +y.
        for j in 0..3 {
            for i in 0..3 {
                let rest = Vec3::new(-half + half * i as f32, 0.0, -half + half * j as f32);
                vertices.push(SwayVertex {
                    rest,
                    weight: 0.0,
                    phase: 0.0,
                });
            }
        }
        for j in 0..2u32 {
            for i in 0..2u32 {
                let v = j * 3 + i;
                triangles.extend([[v, v + 3, v + 4], [v, v + 4, v + 1]]);
                material_ids.extend([GROUND, GROUND]);
            }
        }
        for (b, phase) in built {
            let base = vertices.len() as u32;
            vertices.extend(b.verts.iter().map(|&rest| SwayVertex {
                rest,
                weight: (rest.y / SWAY_HEIGHT).powi(2),
                // A slight phase lag with height makes the canopy lag the trunk.
                phase: phase - 0.3 * rest.y,
            }));
            triangles.extend(b.tris.iter().map(|t| t.map(|v| v + base)));
            material_ids.extend(b.mats);
        }

        let mut rng = Rng::stream(c.seed, u64::MAX);
        let a = rng.range(0.0, std::f32::consts::TAU);
        let wind_dir = Vec3::new(a.cos(), 0.0, a.sin());
        // The sway moves a vertex by at most wind * weight * sqrt(1 + 0.3^2) sideways.
        let bounds = vertices.iter().fold(Aabb::EMPTY, |bb, v| {
            let r = Vec3::new(1.0, 0.0, 1.0) * (1.05 * wind * v.weight);
            bb.grow(v.rest - r).grow(v.rest + r)
        });
        Ok(Forest {
            info: p.info(c.timeline, true, bounds),
            vertices,
            triangles,
            material_ids,
            wind,
            wind_dir,
        })
    }
}

impl Scene for Forest {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let across = self.wind_dir.cross(Vec3::Y);
        let (w_main, w_gust) = (2.1f32, 3.7f32);
        let positions: Vec<Vec3> = self
            .vertices
            .par_iter()
            .map(|v| {
                if v.weight == 0.0 {
                    return v.rest;
                }
                // Sway about the rest pose: zero offset at t = 0 plus a small cross wobble.
                let main = (w_main * t + v.phase).sin() - v.phase.sin();
                let gust = 0.3 * ((w_gust * t + 1.7 * v.phase).sin() - (1.7 * v.phase).sin());
                v.rest + self.wind * v.weight * 0.5 * (self.wind_dir * main + across * gust)
            })
            .collect();
        Ok(Mesh {
            positions,
            triangles: self.triangles.clone(),
            material_ids: self.material_ids.clone(),
            material_names: ["ground", "bark", "canopy", "leaf"]
                .map(String::from)
                .to_vec(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_scene, open_err, open_proc};

    #[test]
    fn count_follows_n() {
        for n in [5_000usize, 100_000] {
            let c = open_proc(&format!("forest?n={n}"))
                .mesh_at(0.0)
                .unwrap()
                .triangle_count();
            assert!((c as f64 / n as f64 - 1.0).abs() < 0.05, "n={n}: {c}");
        }
        // One tree at least.
        let c = open_proc("forest?n=100&leaves=10000")
            .mesh_at(0.0)
            .unwrap()
            .triangle_count();
        assert_eq!(c, 8 + 192 + 10_000);
    }

    #[test]
    fn common_checks() {
        check_scene("forest?n=8000&seed=11");
    }

    #[test]
    fn triangle_sizes_are_very_uneven() {
        let s = open_proc("forest?n=20000");
        for t in [0.0, 1.3] {
            let m = s.mesh_at(t).unwrap();
            let areas: Vec<f32> = m.triangles_iter().map(|t| t.area()).collect();
            let max = areas.iter().cloned().fold(0.0f32, f32::max);
            let min = areas.iter().cloned().fold(f32::INFINITY, f32::min);
            assert!(min > 0.0);
            assert!(max / min > 1e4, "{max} / {min}");
            // Bounds hold in the camera's box: the ground is the widest thing.
            assert_eq!(m.material_names.len(), 4);
        }
    }

    #[test]
    fn ground_and_roots_stay_still() {
        let s = open_proc("forest?n=5000&wind=2");
        let (a, b) = (s.mesh_at(0.0).unwrap(), s.mesh_at(1.0).unwrap());
        for (p, q) in a.positions.iter().zip(&b.positions) {
            if p.y == 0.0 {
                assert_eq!(p, q);
            }
        }
        assert_ne!(a.positions, b.positions);
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(open_err("forest?leaves=100000").contains("leaves"));
        assert!(open_err("forest?wind=-1").contains("wind"));
    }
}
