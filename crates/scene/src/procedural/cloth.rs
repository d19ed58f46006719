//! `cloth`: a finely tessellated flag that starts exactly flat and waves.
//!
//! At t = 0 the sheet lies in the plane z = 0 (every z is exactly 0.0), the degenerate
//! axis that quantized BVH encoders must handle (\[P3\] §4.4: a node whose box has zero
//! extent on one axis). Over time travelling waves whose amplitude ramps up from 0 move it
//! along z, growing from the pole edge (x = 0, held still) to the free edge, like a flag.
//!
//! Parameters: `n` (default 100 000, 2..=20 M) is rounded to a grid of `nx * ny` cells
//! with a 2:1 aspect, two triangles per cell, so the count is `2 * nx * ny`;
//! `amplitude` (default 0.2, 0..=10) is the largest z displacement in sheet widths/2.

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Vec3};
use rayon::prelude::*;

/// Sheet size: 2 x 1 in the xy plane.
const WIDTH: f32 = 2.0;
const HEIGHT: f32 = 1.0;

/// The waving sheet.
pub struct Cloth {
    info: SceneInfo,
    nx: u32,
    ny: u32,
    amplitude: f32,
    /// Two travelling waves: (wave vector x, wave vector y, angular speed, phase).
    waves: [[f32; 4]; 2],
    triangles: Vec<[u32; 3]>,
}

impl Cloth {
    /// Reads the parameters and builds the grid topology.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(100_000, 2, 20_000_000)?;
        let amplitude = p.get_in("amplitude", 0.2f32, 0.0, 10.0)?;
        p.finish()?;
        let cells = (c.n / 2).max(1) as f64;
        let ny = (cells / 2.0).sqrt().round().max(1.0) as u32;
        let nx = (cells / ny as f64).round().max(1.0) as u32;
        let mut rng = Rng::stream(c.seed, 0);
        let tau = std::f32::consts::TAU;
        // A main wave running along the flag and a slanted, slower one for irregularity.
        let k1 = rng.range(1.5, 2.5) * tau / WIDTH;
        let angle = rng.range(-0.8, 0.8);
        let k2 = rng.range(2.5, 4.0) * tau / WIDTH;
        let waves = [
            [k1, 0.0, rng.range(4.0, 7.0), rng.range(0.0, tau)],
            [
                k2 * angle.cos(),
                k2 * angle.sin(),
                rng.range(2.0, 4.0),
                rng.range(0.0, tau),
            ],
        ];
        let row = nx + 1;
        let mut triangles = Vec::with_capacity(2 * nx as usize * ny as usize);
        for j in 0..ny {
            for i in 0..nx {
                let v = j * row + i;
                triangles.push([v, v + 1, v + row + 1]);
                triangles.push([v, v + row + 1, v + row]);
            }
        }
        // z stays within the two waves' summed amplitude (1 + 0.5) times `amplitude`.
        let zmax = 1.5 * amplitude;
        let bounds = Aabb::new(Vec3::new(0.0, 0.0, -zmax), Vec3::new(WIDTH, HEIGHT, zmax));
        Ok(Cloth {
            info: p.info(c.timeline, true, bounds),
            nx,
            ny,
            amplitude,
            waves,
            triangles,
        })
    }

    /// Amplitude envelope: 0 at t = 0, smoothly reaching 1 at half the duration.
    fn ramp(&self, t: f32) -> f32 {
        let x = (t / (0.5 * self.info.timeline.duration_s)).clamp(0.0, 1.0);
        x * x * (3.0 - 2.0 * x)
    }
}

impl Scene for Cloth {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let amp = self.amplitude * self.ramp(t);
        let (nx, ny) = (self.nx, self.ny);
        let row = nx as usize + 1;
        let w = self.waves;
        let positions: Vec<Vec3> = (0..row * (ny as usize + 1))
            .into_par_iter()
            .map(|v| {
                let x = WIDTH * (v % row) as f32 / nx as f32;
                let y = HEIGHT * (v / row) as f32 / ny as f32;
                // Exactly 0 when flat, so the t = 0 sheet is exactly planar.
                let z = if amp == 0.0 {
                    0.0
                } else {
                    let s1 = (w[0][0] * x + w[0][1] * y - w[0][2] * t + w[0][3]).sin();
                    let s2 = (w[1][0] * x + w[1][1] * y - w[1][2] * t + w[1][3]).sin();
                    amp * (x / WIDTH) * (s1 + 0.5 * s2)
                };
                Vec3::new(x, y, z)
            })
            .collect();
        Ok(Mesh::new(positions, self.triangles.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_scene, open_err, open_proc};

    #[test]
    fn count_follows_n() {
        for n in [1_000usize, 60_000] {
            let m = open_proc(&format!("cloth?n={n}")).mesh_at(0.0).unwrap();
            let c = m.triangle_count() as f64;
            assert!((c / n as f64 - 1.0).abs() < 0.05, "n={n}: {c}");
        }
        assert_eq!(
            open_proc("cloth?n=2")
                .mesh_at(0.0)
                .unwrap()
                .triangle_count(),
            2
        );
    }

    #[test]
    fn common_checks() {
        check_scene("cloth?n=5000&seed=3");
    }

    #[test]
    fn exactly_planar_at_start_then_waves() {
        let s = open_proc("cloth?n=20000");
        let m = s.mesh_at(0.0).unwrap();
        assert!(m.positions.iter().all(|p| p.z == 0.0));
        let b = m.bounds();
        assert_eq!((b.min.z, b.max.z), (0.0, 0.0));
        let m = s.mesh_at(s.info().timeline.duration_s * 0.5).unwrap();
        let b = m.bounds();
        assert!(b.max.z - b.min.z > 0.1, "{b:?}");
        // The pole edge (x = 0) is held.
        assert!(m
            .positions
            .iter()
            .filter(|p| p.x == 0.0)
            .all(|p| p.z == 0.0));
        // The camera's box holds every frame.
        let cam = s.info().camera;
        assert!(cam.eye.z > b.max.z);
    }

    #[test]
    fn rejects_bad_amplitude() {
        assert!(open_err("cloth?amplitude=-1").contains("amplitude"));
        assert!(open_err("cloth?amplitude=inf").contains("amplitude"));
    }
}
