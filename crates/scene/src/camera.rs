//! The default camera of a scene.

use geom::{Aabb, Vec3};
use serde::{Deserialize, Serialize};

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Up direction (need not be orthogonal to the view direction).
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub vfov_deg: f32,
}

impl Camera {
    /// A camera that frames `bounds`: it looks at the centre from the front-right-above
    /// diagonal (+z towards the viewer, y up), far enough that the bounding sphere fits the
    /// vertical field of view.
    pub fn framing(bounds: &Aabb) -> Self {
        let vfov_deg = 45.0f32;
        if bounds.is_empty() || !bounds.is_finite() {
            return Camera {
                eye: Vec3::new(0.0, 0.0, 5.0),
                target: Vec3::ZERO,
                up: Vec3::Y,
                vfov_deg,
            };
        }
        let center = bounds.center();
        let radius = (bounds.extent().length() * 0.5).max(1e-3);
        let dist = radius / (0.5 * vfov_deg.to_radians()).sin();
        let dir = Vec3::new(0.35, 0.3, 1.0).normalize();
        Camera {
            eye: center + dir * dist,
            target: center,
            up: Vec3::Y,
            vfov_deg,
        }
    }
}

/// Cameras inside the architectural scenes of `shared/scenes` (their default cameras frame
/// them from outside, where a ray sees a few walls): (scene, eye, target, vertical field
/// of view in degrees). Chosen for Arbor's reports and benchmarks; the thesis does not
/// give its viewpoints.
pub const INTERIOR_VIEWS: [(&str, [f32; 3], [f32; 3], f32); 3] = [
    (
        "crytek-sponza",
        [-120.0, 20.0, -5.0],
        [60.0, 40.0, 5.0],
        70.0,
    ),
    (
        "conference",
        [1500.0, 350.0, -900.0],
        [0.0, 150.0, 500.0],
        70.0,
    ),
    ("sibenik", [-17.0, -10.0, 0.0], [10.0, -5.0, 0.0], 70.0),
];

/// The camera reports and benchmarks use for the scene named `name`: its interior view
/// where [`INTERIOR_VIEWS`] has one, else `camera` (the scene's own).
pub fn view_camera(name: &str, mut camera: Camera) -> Camera {
    if let Some((_, eye, target, fov)) = INTERIOR_VIEWS.iter().find(|c| c.0 == name) {
        camera.eye = Vec3::from(*eye);
        camera.target = Vec3::from(*target);
        camera.vfov_deg = *fov;
    }
    camera
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interior_views_replace_the_camera_of_their_scenes_only() {
        let own = Camera::framing(&Aabb::new(Vec3::ZERO, Vec3::ONE));
        let inside = view_camera("crytek-sponza", own);
        assert_eq!(inside.eye, Vec3::new(-120.0, 20.0, -5.0));
        assert_eq!((inside.vfov_deg, inside.up), (70.0, own.up));
        assert_eq!(view_camera("bunny", own), own);
    }

    #[test]
    fn framing_sees_the_whole_box() {
        let b = Aabb::new(Vec3::splat(-2.0), Vec3::new(4.0, 1.0, 3.0));
        let c = Camera::framing(&b);
        let half = (0.5 * c.vfov_deg.to_radians()).tan();
        let fwd = (c.target - c.eye).normalize();
        for i in 0..8 {
            let p = Vec3::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            let d = p - c.eye;
            let along = d.dot(fwd);
            assert!(along > 0.0);
            let off = (d - fwd * along).length();
            assert!(off / along <= half * 1.01, "corner {p} outside view");
        }
    }
}
