//! `skinned`: a ring of tentacles (tapered closed tubes), each bent by a chain of bones
//! with linear blend skinning, the deformation class of skinned characters.
//!
//! Each vertex is weighted to the two bones nearest its height along the tube, blending
//! linearly between bone centres, so the skin bends smoothly at the joints. Bones rotate
//! sinusoidally about two axes with a phase lag along the chain, which makes waves run
//! down each tentacle.
//!
//! Parameters: `n` (default 100 000, 100..=10 M) is split over the tentacles; each tube
//! has `S` sides and `R = ~4S` rings plus two cap fans, `2 * S * R` triangles, with
//! `S >= 3`, `R >= 2` (so tiny `n` rounds up); `tentacles` (default 8, 1..=256); `bones`
//! per tentacle (default 8, 2..=64); `bend` (default 0.35, 0..=3) is the largest rotation of
//! one bone in radians.

use super::{Params, Rng};
use crate::{Mesh, Scene, SceneError, SceneInfo};
use geom::{Aabb, Quat, Vec3};
use glam::Affine3A;
use rayon::prelude::*;

/// Tentacle length and base radius (the tip is 20% of the base).
const LENGTH: f32 = 2.0;
const RADIUS: f32 = 0.12;
/// Radius of the ring the tentacle bases sit on.
const HUB_RADIUS: f32 = 0.4;

/// A vertex in its tentacle's rest frame with its two bone influences.
#[derive(Clone, Copy)]
struct SkinVertex {
    rest: Vec3,
    /// First bone; the second is `bone + 1` (clamped to the chain).
    bone: u32,
    /// Weight of the second bone (the first has `1 - w`).
    w: f32,
}

/// Per-tentacle animation: placement, bend axes, angular speed and phase.
#[derive(Clone, Copy)]
struct Tentacle {
    placement: Affine3A,
    axes: [Vec3; 2],
    omega: [f32; 2],
    phase: [f32; 2],
}

/// The tentacles.
pub struct Skinned {
    info: SceneInfo,
    bones: u32,
    bend: f32,
    tentacles: Vec<Tentacle>,
    /// Skin of one tentacle (all share it; vertex `v` of tentacle `k` is
    /// `k * skin.len() + v`).
    skin: Vec<SkinVertex>,
    triangles: Vec<[u32; 3]>,
}

impl Skinned {
    /// Reads the parameters and builds the rest tubes and skin weights.
    pub(crate) fn new(p: &Params) -> Result<Self, SceneError> {
        let c = p.common(100_000, 100, 10_000_000)?;
        let count = p.get_in("tentacles", 8u32, 1, 256)?;
        let bones = p.get_in("bones", 8u32, 2, 64)?;
        let bend = p.get_in("bend", 0.35f32, 0.0, 3.0)?;
        p.finish()?;
        let per = c.n as f64 / count as f64;
        let sides = (per / 8.0).sqrt().round().max(3.0) as u32;
        let rings = (per / (2.0 * sides as f64)).round().max(2.0) as u32;

        // Rest tube along +y: `rings` rings from the base (y = 0) to the tip, a centre
        // vertex closing each end.
        let seg = LENGTH / bones as f32;
        let skin_at = |rest: Vec3| {
            // Blend between the centres of the two bones around this height.
            let u = (rest.y / seg - 0.5).clamp(0.0, (bones - 1) as f32);
            let bone = (u.floor() as u32).min(bones - 2);
            SkinVertex {
                rest,
                bone,
                w: u - bone as f32,
            }
        };
        let mut skin = Vec::with_capacity((sides * rings + 2) as usize);
        for r in 0..rings {
            let y = LENGTH * r as f32 / (rings - 1) as f32;
            let radius = RADIUS * (1.0 - 0.8 * y / LENGTH);
            for s in 0..sides {
                let a = std::f32::consts::TAU * s as f32 / sides as f32;
                skin.push(skin_at(Vec3::new(radius * a.cos(), y, radius * a.sin())));
            }
        }
        let (base, tip) = (sides * rings, sides * rings + 1);
        skin.push(skin_at(Vec3::ZERO));
        skin.push(skin_at(Vec3::new(0.0, LENGTH, 0.0)));
        let ring = |r: u32, s: u32| r * sides + s % sides;
        let mut tube = Vec::with_capacity((2 * sides * rings) as usize);
        for s in 0..sides {
            tube.push([base, ring(0, s), ring(0, s + 1)]);
            tube.push([tip, ring(rings - 1, s + 1), ring(rings - 1, s)]);
        }
        for r in 0..rings - 1 {
            for s in 0..sides {
                let (a, b, cc, d) = (
                    ring(r, s),
                    ring(r, s + 1),
                    ring(r + 1, s),
                    ring(r + 1, s + 1),
                );
                tube.push([a, cc, d]);
                tube.push([a, d, b]);
            }
        }
        let nv = skin.len() as u32;
        let triangles: Vec<[u32; 3]> = (0..count)
            .flat_map(|k| tube.iter().map(move |t| t.map(|v| v + k * nv)))
            .collect();

        let tentacles = (0..count)
            .map(|k| {
                let mut rng = Rng::stream(c.seed, k as u64);
                let a = std::f32::consts::TAU * (k as f32 + rng.range(-0.2, 0.2)) / count as f32;
                let out = Vec3::new(a.cos(), 0.0, a.sin());
                let dir = (out * rng.range(0.3, 0.8) + Vec3::Y).normalize();
                let g = rng.range(0.0, std::f32::consts::TAU);
                Tentacle {
                    placement: Affine3A::from_rotation_translation(
                        Quat::from_rotation_arc(Vec3::Y, dir),
                        out * HUB_RADIUS,
                    ),
                    axes: [
                        Vec3::new(g.cos(), 0.0, g.sin()),
                        Vec3::new(-g.sin(), 0.0, g.cos()),
                    ],
                    omega: [rng.range(2.0, 4.0), rng.range(1.0, 2.5)],
                    phase: [rng.range(0.0, 6.3), rng.range(0.0, 6.3)],
                }
            })
            .collect();
        let mut s = Skinned {
            info: p.info(c.timeline, true, Aabb::EMPTY),
            bones,
            bend,
            tentacles,
            skin,
            triangles,
        };
        let d = c.timeline.duration_s;
        let b = super::bounds_at(&s, &[0.0, 0.25 * d, 0.5 * d, 0.75 * d, d])?;
        s.info = p.info(c.timeline, true, b);
        Ok(s)
    }

    /// Skinning matrices of every bone of every tentacle at `t`: posed bone frame times the
    /// inverse bind frame, then the tentacle's placement.
    fn skinning_matrices(&self, t: f32) -> Vec<Affine3A> {
        let seg = LENGTH / self.bones as f32;
        let mut out = Vec::with_capacity(self.tentacles.len() * self.bones as usize);
        for tc in &self.tentacles {
            let mut posed = Affine3A::IDENTITY;
            for j in 0..self.bones {
                // Phase lag along the chain: a wave travelling to the tip.
                let lag = 0.6 * j as f32;
                let r0 = self.bend * (tc.omega[0] * t + tc.phase[0] - lag).sin();
                let r1 = self.bend * 0.6 * (tc.omega[1] * t + tc.phase[1] - lag).sin();
                let rot =
                    Quat::from_axis_angle(tc.axes[0], r0) * Quat::from_axis_angle(tc.axes[1], r1);
                let step = if j == 0 {
                    Vec3::ZERO
                } else {
                    Vec3::new(0.0, seg, 0.0)
                };
                posed *= Affine3A::from_rotation_translation(rot, step);
                let bind_inv = Affine3A::from_translation(Vec3::new(0.0, -seg * j as f32, 0.0));
                out.push(tc.placement * posed * bind_inv);
            }
        }
        out
    }
}

impl Scene for Skinned {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let mats = self.skinning_matrices(t);
        let nv = self.skin.len();
        let nb = self.bones as usize;
        let positions: Vec<Vec3> = (0..nv * self.tentacles.len())
            .into_par_iter()
            .map(|i| {
                let v = self.skin[i % nv];
                let m = &mats[(i / nv) * nb + v.bone as usize..];
                (1.0 - v.w) * m[0].transform_point3(v.rest) + v.w * m[1].transform_point3(v.rest)
            })
            .collect();
        Ok(Mesh::new(positions, self.triangles.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check_closed, check_scene, open_err, open_proc, signed_volume};

    #[test]
    fn count_follows_n() {
        for n in [5_000usize, 80_000] {
            let c = open_proc(&format!("skinned?n={n}"))
                .mesh_at(0.0)
                .unwrap()
                .triangle_count();
            assert!((c as f64 / n as f64 - 1.0).abs() < 0.1, "n={n}: {c}");
        }
        let c = open_proc("skinned?n=100&tentacles=1")
            .mesh_at(0.0)
            .unwrap()
            .triangle_count();
        assert!((80..=120).contains(&c), "{c}");
    }

    #[test]
    fn common_checks() {
        check_scene("skinned?n=4000&seed=7");
    }

    #[test]
    fn tubes_stay_closed_and_bend() {
        let s = open_proc("skinned?n=4000&tentacles=3&bones=5");
        for t in [0.0, 0.7, 2.0] {
            let m = s.mesh_at(t).unwrap();
            check_closed(&m).unwrap();
            // Skinning keeps the volume roughly (bends only): three positive tubes.
            let v = signed_volume(&m);
            assert!(v > 0.0 && v < 3.0 * 0.12f64.powi(2) * 3.2 * 2.0, "{v}");
        }
        // With no bend the tentacles are straight: every tip lies at distance LENGTH from
        // its base.
        let s = open_proc("skinned?n=4000&tentacles=3&bend=0");
        let a = s.mesh_at(0.0).unwrap();
        assert_eq!(a, s.mesh_at(1.0).unwrap());
        let nv = a.positions.len() / 3;
        let (base, tip) = (a.positions[nv - 2], a.positions[nv - 1]);
        assert!(((tip - base).length() - 2.0).abs() < 1e-4);
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(open_err("skinned?bones=1").contains("bones"));
        assert!(open_err("skinned?tentacles=0").contains("tentacles"));
        assert!(open_err("skinned?bend=nan").contains("bend"));
    }
}
