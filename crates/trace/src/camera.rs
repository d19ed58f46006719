//! The pinhole camera: one ray per pixel through the pixel's centre.

use crate::TraceError;
use geom::{Ray, Vec3};

/// A pinhole camera for an image of `width x height` pixels, row 0 at the top.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PinholeCamera {
    eye: Vec3,
    /// Direction through the image centre.
    forward: Vec3,
    /// Image-plane step per pixel to the right and downwards.
    right: Vec3,
    down: Vec3,
    width: u32,
    height: u32,
}

/// Largest image side accepted (a 64K x 64K image is already 4 G pixels).
pub const MAX_IMAGE_SIDE: u32 = 65_536;

impl PinholeCamera {
    /// The camera `cam` (eye, target, up, vertical field of view) for an image of
    /// `width x height` pixels. Fails on a zero or huge image, a non-finite camera, an eye
    /// at the target, or a field of view outside (0, 180) degrees. An `up` parallel to the
    /// view direction is replaced by another axis.
    pub fn new(cam: &scene::Camera, width: u32, height: u32) -> Result<Self, TraceError> {
        if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(TraceError::Config(format!(
                "image size {width}x{height} is out of range (1..={MAX_IMAGE_SIDE} per side)"
            )));
        }
        let finite = [cam.eye, cam.target, cam.up]
            .iter()
            .all(|v| geom::is_finite3(*v))
            && cam.vfov_deg.is_finite();
        if !finite {
            return Err(TraceError::Config(format!(
                "camera has non-finite values: {cam:?}"
            )));
        }
        if !(cam.vfov_deg > 0.0 && cam.vfov_deg < 180.0) {
            return Err(TraceError::Config(format!(
                "vertical field of view {} is outside (0, 180) degrees",
                cam.vfov_deg
            )));
        }
        let forward = (cam.target - cam.eye).normalize_or_zero();
        if forward == Vec3::ZERO {
            return Err(TraceError::Config(
                "camera eye and target are the same point".into(),
            ));
        }
        let mut up = cam.up.normalize_or_zero();
        if up.cross(forward).length_squared() < 1e-8 {
            // Up along the view direction: any perpendicular axis will do.
            up = if forward.y.abs() < 0.9 {
                Vec3::Y
            } else {
                Vec3::Z
            };
        }
        let right_dir = forward.cross(up).normalize();
        let up_dir = right_dir.cross(forward);
        let half_h = (0.5 * cam.vfov_deg.to_radians()).tan();
        let pixel = 2.0 * half_h / height as f32;
        Ok(Self {
            eye: cam.eye,
            forward,
            right: right_dir * pixel,
            down: -up_dir * pixel,
            width,
            height,
        })
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The eye position.
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// The ray through image position `(x, y)` in pixels (`(0, 0)` is the top-left
    /// corner, `(x + 0.5, y + 0.5)` the centre of pixel `(x, y)`), with a unit direction.
    pub fn ray_at(&self, x: f32, y: f32) -> Ray {
        let dx = x - 0.5 * self.width as f32;
        let dy = y - 0.5 * self.height as f32;
        let dir = (self.forward + self.right * dx + self.down * dy).normalize();
        Ray::new(self.eye, dir)
    }

    /// The same camera with its image plane's extent times `k` (`k` > 1 widens the field
    /// of view: `tan(fov / 2)` scales by `k`), the eye, direction and image size kept.
    /// Fails unless `k` is positive, finite and leaves the field of view below 180
    /// degrees (any finite `k` does).
    pub fn with_view_scale(&self, k: f32) -> Result<Self, TraceError> {
        if !(k.is_finite() && k > 0.0) {
            return Err(TraceError::Config(format!(
                "view scale must be a positive number, got {k}"
            )));
        }
        Ok(Self {
            right: self.right * k,
            down: self.down * k,
            ..*self
        })
    }

    /// The ray through the centre of pixel `(px, py)`.
    pub fn pixel_ray(&self, px: u32, py: u32) -> Ray {
        self.ray_at(px as f32 + 0.5, py as f32 + 0.5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_view_scale_widens_the_field_of_view_about_the_centre() {
        let cam = scene::Camera {
            eye: Vec3::ZERO,
            target: Vec3::new(0.0, 0.0, -1.0),
            up: Vec3::Y,
            vfov_deg: 90.0,
        };
        let c = PinholeCamera::new(&cam, 64, 32).unwrap();
        let w = c.with_view_scale(2.0).unwrap();
        // The centre ray is the same; the top edge's slope doubles (tan 45° = 1 -> 2).
        assert_eq!(c.ray_at(32.0, 16.0).dir, w.ray_at(32.0, 16.0).dir);
        let top = w.ray_at(32.0, 0.0).dir;
        assert!((top.y / -top.z - 2.0).abs() < 1e-5, "{top:?}");
        assert_eq!(c.with_view_scale(1.0).unwrap(), c);
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(c.with_view_scale(bad).is_err());
        }
    }

    fn cam() -> scene::Camera {
        scene::Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 90.0,
        }
    }

    #[test]
    fn centre_ray_looks_at_the_target_and_corners_span_the_fov() {
        let c = PinholeCamera::new(&cam(), 200, 100).unwrap();
        let r = c.ray_at(100.0, 50.0);
        assert!((r.dir - -Vec3::Z).length() < 1e-6);
        // Top edge is 45 degrees up (vfov 90), left edge atan(2) to the left (aspect 2).
        let top = c.ray_at(100.0, 0.0).dir;
        assert!(
            (top.y - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5,
            "{top}"
        );
        let left = c.ray_at(0.0, 50.0).dir;
        assert!(
            left.x < 0.0 && (left.x / left.z - 2.0).abs() < 1e-5,
            "{left}"
        );
        // Rows go down, columns go right.
        assert!(c.pixel_ray(0, 99).dir.y < 0.0 && c.pixel_ray(199, 0).dir.x > 0.0);
    }

    #[test]
    fn bad_cameras_are_errors() {
        assert!(PinholeCamera::new(&cam(), 0, 10).is_err());
        assert!(PinholeCamera::new(&cam(), 10, MAX_IMAGE_SIDE + 1).is_err());
        let mut c = cam();
        c.target = c.eye;
        assert!(PinholeCamera::new(&c, 10, 10).is_err());
        let mut c = cam();
        c.vfov_deg = 180.0;
        assert!(PinholeCamera::new(&c, 10, 10).is_err());
        let mut c = cam();
        c.eye.x = f32::NAN;
        assert!(PinholeCamera::new(&c, 10, 10).is_err());
        // Up along the view direction still gives a camera.
        let mut c = cam();
        c.up = Vec3::Z;
        let p = PinholeCamera::new(&c, 10, 10).unwrap();
        assert!(p.pixel_ray(5, 5).dir.is_finite());
    }
}
