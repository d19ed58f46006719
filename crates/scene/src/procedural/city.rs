//! `city`: a voxel city of box buildings on a street grid; static.
//!
//! A stand-in for Rungholt (6.7 M triangles): box-heavy, made of axis-aligned unit voxel
//! faces, most triangles small and axis-aligned, over a large flat ground. The city is a
//! grid of blocks of [`BLOCK`] x [`BLOCK`] voxels separated by streets [`STREET`] voxels
//! wide; each block holds 2 x 2 lots, each lot one building whose footprint is inset at
//! random and whose columns have random heights around the building's (so roofs are
//! stepped). Only the outer faces of each building's voxels are emitted (a unit square,
//! two triangles, per visible voxel face; no bottoms), plus two ground triangles under the
//! whole city. Block `(x, z)` draws from its own [`Rng`] stream.
//!
//! Static: the timeline is [`Timeline::STATIC`] (`duration` and `fps` are checked like
//! every scene's but do not change it).
//!
//! Parameters: `n` (default 500 000, 100..=10 M) is rounded to a whole grid of blocks
//! (the mean triangles per block is estimated from the seed's own blocks, so the count is
//! within a few percent of `n` for large `n`, within about 30% for tiny ones); `height`
//! (default 12, 1..=200) is the largest building height in voxels.

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo, Timeline};
use geom::Vec3;
use rayon::prelude::*;

/// Block edge and street width, in voxels.
const BLOCK: i32 = 10;
const STREET: i32 = 3;
/// Lot edge (2 x 2 lots per block).
const LOT: i32 = BLOCK / 2;
/// Blocks sampled to estimate triangles per block.
const SAMPLE: u64 = 64;

/// The city.
pub struct City {
    info: SceneInfo,
    mesh: Mesh,
}

/// Appends the unit quad at `o` spanned by `e1`, `e2` (normal `e1 x e2`).
fn quad(pos: &mut Vec<Vec3>, tris: &mut Vec<[u32; 3]>, o: Vec3, e1: Vec3, e2: Vec3) {
    let b = pos.len() as u32;
    pos.extend([o, o + e1, o + e1 + e2, o + e2]);
    tris.push([b, b + 1, b + 2]);
    tris.push([b, b + 2, b + 3]);
}

/// The block with random stream `key`, its corner at voxel `(x0, z0)`.
fn block(seed: u64, key: u64, height: i32, x0: i32, z0: i32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut rng = Rng::stream(seed, key);
    let (mut pos, mut tris) = (Vec::new(), Vec::new());
    for lot in 0..4 {
        let (lx, lz) = (x0 + LOT * (lot % 2), z0 + LOT * (lot / 2));
        // Footprint: inset 0 or 1 voxel on each side.
        let ix0 = (rng.f32() * 2.0) as i32;
        let iz0 = (rng.f32() * 2.0) as i32;
        let ix1 = (rng.f32() * 2.0) as i32;
        let iz1 = (rng.f32() * 2.0) as i32;
        let (w, d) = (LOT - ix0 - ix1, LOT - iz0 - iz1);
        // Mostly low houses, a few towers.
        let r = rng.f32();
        let base = 1 + ((height - 1) as f32 * r * r * r) as i32;
        let mut h = vec![0i32; (w * d) as usize];
        for v in h.iter_mut() {
            *v = (base - (rng.f32() * 3.0) as i32).max(1);
        }
        let at = |x: i32, z: i32| -> i32 {
            if x < 0 || z < 0 || x >= w || z >= d {
                0
            } else {
                h[(z * w + x) as usize]
            }
        };
        let (bx, bz) = (lx + ix0, lz + iz0);
        for z in 0..d {
            for x in 0..w {
                let hc = at(x, z);
                let (fx, fz) = ((bx + x) as f32, (bz + z) as f32);
                quad(
                    &mut pos,
                    &mut tris,
                    Vec3::new(fx, hc as f32, fz),
                    Vec3::Z,
                    Vec3::X,
                );
                // Side faces where the neighbour column is lower.
                for y in at(x + 1, z)..hc {
                    let o = Vec3::new(fx + 1.0, y as f32, fz);
                    quad(&mut pos, &mut tris, o, Vec3::Y, Vec3::Z);
                }
                for y in at(x - 1, z)..hc {
                    let o = Vec3::new(fx, y as f32, fz);
                    quad(&mut pos, &mut tris, o, Vec3::Z, Vec3::Y);
                }
                for y in at(x, z + 1)..hc {
                    let o = Vec3::new(fx, y as f32, fz + 1.0);
                    quad(&mut pos, &mut tris, o, Vec3::X, Vec3::Y);
                }
                for y in at(x, z - 1)..hc {
                    let o = Vec3::new(fx, y as f32, fz);
                    quad(&mut pos, &mut tris, o, Vec3::Y, Vec3::X);
                }
            }
        }
    }
    (pos, tris)
}

/// The stream key of block `(x, z)` (independent of the grid's size).
fn key(x: u32, z: u32) -> u64 {
    ((x as u64) << 32) | z as u64
}

impl City {
    /// Reads the parameters and generates the mesh.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(500_000, 100, 10_000_000)?;
        let height = p.get_in("height", 12i32, 1, 200)?;
        p.finish()?;
        // Mean triangles per block, from blocks of this seed on the grid's diagonal.
        let sample: usize = (0..SAMPLE as u32)
            .into_par_iter()
            .map(|i| block(c.seed, key(i, i), height, 0, 0).1.len())
            .sum();
        let per_block = (sample as f64 / SAMPLE as f64).max(1.0);
        let blocks = ((c.n.saturating_sub(2)) as f64 / per_block).max(1.0);
        let nx = blocks.sqrt().ceil().max(1.0) as u32;
        let nz = (blocks / nx as f64).round().max(1.0) as u32;
        let pitch = BLOCK + STREET;
        let parts: Vec<(Vec<Vec3>, Vec<[u32; 3]>)> = (0..nx * nz)
            .into_par_iter()
            .map(|i| {
                let (x, z) = (i % nx, i / nx);
                block(
                    c.seed,
                    key(x, z),
                    height,
                    x as i32 * pitch,
                    z as i32 * pitch,
                )
            })
            .collect();
        let nv: usize = parts.iter().map(|p| p.0.len()).sum::<usize>() + 4;
        let nt: usize = parts.iter().map(|p| p.1.len()).sum::<usize>() + 2;
        let (mut positions, mut triangles) = (Vec::with_capacity(nv), Vec::with_capacity(nt));
        // Ground: the city plus a street's margin all round.
        let m = STREET as f32;
        let (ex, ez) = (
            (nx as i32 * pitch) as f32 + m,
            (nz as i32 * pitch) as f32 + m,
        );
        quad(
            &mut positions,
            &mut triangles,
            Vec3::new(-m, 0.0, -m),
            Vec3::new(0.0, 0.0, ez + m),
            Vec3::new(ex + m, 0.0, 0.0),
        );
        for (pos, tris) in parts {
            let b = positions.len() as u32;
            positions.extend(pos);
            triangles.extend(tris.into_iter().map(|t| t.map(|v| v + b)));
        }
        let mesh = Mesh::new(positions, triangles);
        let mut timeline = Timeline::STATIC;
        timeline.fps = c.timeline.fps;
        Ok(City {
            info: p.info(timeline, true, mesh.bounds()),
            mesh,
        })
    }
}

impl Scene for City {
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
        check_static_scene("city?n=3000&seed=4");
    }

    #[test]
    fn count_is_close_to_n() {
        for (n, tol) in [(3_000usize, 0.35), (20_000, 0.15)] {
            let m = open_proc(&format!("city?n={n}")).mesh_at(0.0).unwrap();
            let got = m.triangle_count() as f64;
            assert!((got / n as f64 - 1.0).abs() < tol, "{n}: {got}");
        }
    }

    #[test]
    fn axis_aligned_voxel_faces_on_the_ground() {
        let m = open_proc("city?n=5000&seed=3").mesh_at(0.0).unwrap();
        assert!(min_double_area(&m) >= 1.0 - 1e-6);
        assert!(m.positions.iter().all(|p| p.y >= 0.0 && p.y <= 12.0));
        // Every vertex but the ground's is on the integer voxel grid.
        assert!(m.positions[4..].iter().all(|p| *p == p.round()));
        // Every triangle is axis-aligned (normal along one axis), outward or up.
        for t in m.triangles_iter() {
            let nrm = (t.v[1] - t.v[0]).cross(t.v[2] - t.v[0]);
            assert_eq!(nrm.abs().cmpgt(Vec3::splat(1e-6)).bitmask().count_ones(), 1);
            assert!(nrm.y >= 0.0);
        }
    }

    #[test]
    fn seed_changes_city() {
        let a = open_proc("city?n=3000").mesh_at(0.0).unwrap();
        let b = open_proc("city?n=3000&seed=2").mesh_at(0.0).unwrap();
        assert_ne!(a, b);
    }

    #[test]
    fn rejects_bad_parameters() {
        for (q, key) in [
            ("height=0", "height"),
            ("height=1000", "height"),
            ("height=x", "height"),
            ("n=20000000", "parameter n="),
        ] {
            let e = open_err(&format!("city?{q}"));
            assert!(e.contains(key) && !e.contains('\n'), "{e}");
        }
    }
}
