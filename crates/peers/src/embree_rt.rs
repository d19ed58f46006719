//! Embree 3 as a ray tracer, for side-by-side traversal benchmarks: a triangle-mesh scene
//! built with Embree's own scene builder and traced one ray at a time with `rtcIntersect1`
//! and `rtcOccluded1` (its single-ray API), through a hand-written FFI of the parts of
//! `rtcore_scene.h`, `rtcore_geometry.h`, `rtcore_buffer.h` and `rtcore_ray.h` (Embree
//! 3.13) that this needs.

use crate::embree::EmbreeDevice;
use crate::{check_input, PeerError};
use geom::{Ray, Vec3};
use std::ffi::c_void;
use std::time::{Duration, Instant};

type RtcScene = *mut c_void;
type RtcGeometry = *mut c_void;

const RTC_GEOMETRY_TYPE_TRIANGLE: u32 = 0;
const RTC_BUFFER_TYPE_INDEX: u32 = 0;
const RTC_BUFFER_TYPE_VERTEX: u32 = 1;
const RTC_FORMAT_UINT3: u32 = 0x5003;
const RTC_FORMAT_FLOAT3: u32 = 0x9003;
const RTC_SCENE_FLAG_DYNAMIC: u32 = 1 << 0;
const RTC_SCENE_FLAG_ROBUST: u32 = 1 << 2;
const RTC_BUILD_QUALITY_LOW: u32 = 0;
const RTC_BUILD_QUALITY_REFIT: u32 = 3;
const RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT: u32 = 0;
const RTC_INVALID_GEOMETRY_ID: u32 = u32::MAX;

/// `struct RTC_ALIGN(16) RTCRay`.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
struct RtcRay {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: u32,
    id: u32,
    flags: u32,
}

/// `struct RTC_ALIGN(16) RTCHit` with `RTC_MAX_INSTANCE_LEVEL_COUNT` = 1.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
struct RtcHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: u32,
    geom_id: u32,
    inst_id: [u32; 1],
}

/// `struct RTC_ALIGN(16) RTCRayHit`.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
struct RtcRayHit {
    ray: RtcRay,
    hit: RtcHit,
}

/// `struct RTCIntersectContext` (`RTC_MAX_INSTANCE_LEVEL_COUNT` = 1, `RTC_MIN_WIDTH` = 0).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
struct RtcIntersectContext {
    flags: u32,
    filter: *const c_void,
    inst_id: [u32; 1],
}

const _: () = assert!(std::mem::size_of::<RtcRay>() == 48);
const _: () = assert!(std::mem::size_of::<RtcHit>() == 32);
const _: () = assert!(std::mem::size_of::<RtcRayHit>() == 80);
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<RtcIntersectContext>() == 24);

extern "C" {
    fn rtcNewScene(device: *mut c_void) -> RtcScene;
    fn rtcReleaseScene(scene: RtcScene);
    fn rtcSetSceneFlags(scene: RtcScene, flags: u32);
    fn rtcSetSceneBuildQuality(scene: RtcScene, quality: u32);
    fn rtcNewGeometry(device: *mut c_void, ty: u32) -> RtcGeometry;
    fn rtcReleaseGeometry(geometry: RtcGeometry);
    fn rtcCommitGeometry(geometry: RtcGeometry);
    fn rtcSetNewGeometryBuffer(
        geometry: RtcGeometry,
        ty: u32,
        slot: u32,
        format: u32,
        byte_stride: usize,
        item_count: usize,
    ) -> *mut c_void;
    fn rtcAttachGeometry(scene: RtcScene, geometry: RtcGeometry) -> u32;
    fn rtcCommitScene(scene: RtcScene);
    fn rtcSetGeometryBuildQuality(geometry: RtcGeometry, quality: u32);
    fn rtcUpdateGeometryBuffer(geometry: RtcGeometry, ty: u32, slot: u32);
    fn rtcIntersect1(scene: RtcScene, context: *mut RtcIntersectContext, rayhit: *mut RtcRayHit);
    fn rtcOccluded1(scene: RtcScene, context: *mut RtcIntersectContext, ray: *mut RtcRay);
}

/// How Embree builds its scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EmbreeSceneConfig {
    /// Build quality: 0 = LOW, 1 = MEDIUM (Embree's default), 2 = HIGH.
    pub quality: u32,
    /// `RTC_SCENE_FLAG_ROBUST`: avoid optimizations that reduce arithmetic accuracy.
    pub robust: bool,
}

impl Default for EmbreeSceneConfig {
    fn default() -> Self {
        Self {
            quality: 1,
            robust: false,
        }
    }
}

/// An Embree scene of one triangle mesh, ready to trace.
pub struct EmbreeScene {
    _device: std::sync::Arc<EmbreeDevice>,
    scene: RtcScene,
    /// Wall time of `rtcCommitScene` (Embree's build).
    pub build_time: Duration,
}

// Committed Embree scenes may be traced from any number of threads at once.
unsafe impl Send for EmbreeScene {}
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds a scene over the indexed triangles `(positions, triangles)`.
    pub fn new(
        device: std::sync::Arc<EmbreeDevice>,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        config: EmbreeSceneConfig,
    ) -> Result<Self, PeerError> {
        if triangles
            .iter()
            .any(|t| t.iter().any(|&v| v as usize >= positions.len()))
        {
            return Err(PeerError::Peer {
                peer: "embree",
                message: "a triangle index is out of range".into(),
            });
        }
        let boxes: Vec<geom::Aabb> = triangles
            .iter()
            .map(|t| geom::Aabb::from_points(t.iter().map(|&v| positions[v as usize])))
            .collect();
        check_input(&boxes)?;
        let raw = device.raw();
        // SAFETY: `raw` is a live device; every handle made here is checked for null and
        // released on every path; buffer pointers returned by Embree are written within the
        // sizes we asked for (Embree pads vertex buffers itself).
        unsafe {
            let scene = rtcNewScene(raw);
            if scene.is_null() {
                return Err(PeerError::Peer {
                    peer: "embree",
                    message: "rtcNewScene failed".into(),
                });
            }
            let out = Self {
                _device: device.clone(),
                scene,
                build_time: Duration::ZERO,
            };
            if config.robust {
                rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
            }
            rtcSetSceneBuildQuality(scene, config.quality.min(2));
            let g = rtcNewGeometry(raw, RTC_GEOMETRY_TYPE_TRIANGLE);
            if g.is_null() {
                return Err(PeerError::Peer {
                    peer: "embree",
                    message: "rtcNewGeometry failed".into(),
                });
            }
            let vb = rtcSetNewGeometryBuffer(
                g,
                RTC_BUFFER_TYPE_VERTEX,
                0,
                RTC_FORMAT_FLOAT3,
                12,
                positions.len(),
            ) as *mut f32;
            let ib = rtcSetNewGeometryBuffer(
                g,
                RTC_BUFFER_TYPE_INDEX,
                0,
                RTC_FORMAT_UINT3,
                12,
                triangles.len(),
            ) as *mut u32;
            if (vb.is_null() && !positions.is_empty()) || (ib.is_null() && !triangles.is_empty()) {
                rtcReleaseGeometry(g);
                return Err(PeerError::Peer {
                    peer: "embree",
                    message: "cannot allocate geometry buffers".into(),
                });
            }
            for (i, p) in positions.iter().enumerate() {
                vb.add(i * 3).write(p.x);
                vb.add(i * 3 + 1).write(p.y);
                vb.add(i * 3 + 2).write(p.z);
            }
            for (i, t) in triangles.iter().enumerate() {
                for (k, &v) in t.iter().enumerate() {
                    ib.add(i * 3 + k).write(v);
                }
            }
            rtcCommitGeometry(g);
            rtcAttachGeometry(scene, g);
            rtcReleaseGeometry(g);
            let start = Instant::now();
            rtcCommitScene(scene);
            let mut out = out;
            out.build_time = start.elapsed();
            Ok(out)
        }
    }

    fn context() -> RtcIntersectContext {
        // What rtcInitIntersectContext (a header-inline function) sets.
        RtcIntersectContext {
            flags: RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT,
            filter: std::ptr::null(),
            inst_id: [RTC_INVALID_GEOMETRY_ID],
        }
    }

    fn rtc_ray(ray: &Ray) -> RtcRay {
        RtcRay {
            org: ray.origin.to_array(),
            tnear: ray.t_min,
            dir: ray.dir.to_array(),
            time: 0.0,
            tfar: ray.t_max,
            mask: u32::MAX,
            id: 0,
            flags: 0,
        }
    }

    /// The closest hit of `ray` with `rtcIntersect1`: `(triangle index, t)`.
    #[inline]
    pub fn intersect1(&self, ray: &Ray) -> Option<(u32, f32)> {
        let mut rh = RtcRayHit {
            ray: Self::rtc_ray(ray),
            hit: RtcHit {
                geom_id: RTC_INVALID_GEOMETRY_ID,
                inst_id: [RTC_INVALID_GEOMETRY_ID],
                ..Default::default()
            },
        };
        let mut ctx = Self::context();
        // SAFETY: the scene is committed; the structs match the header's layout.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        (rh.hit.geom_id != RTC_INVALID_GEOMETRY_ID).then_some((rh.hit.prim_id, rh.ray.tfar))
    }

    /// Whether anything lies along `ray`, with `rtcOccluded1`.
    #[inline]
    pub fn occluded1(&self, ray: &Ray) -> bool {
        let mut r = Self::rtc_ray(ray);
        let mut ctx = Self::context();
        // SAFETY: as in `intersect1`.
        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut r) };
        // Embree sets tfar to -inf when the ray is occluded.
        r.tfar == f32::NEG_INFINITY
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: the scene is owned by this value and released once.
        unsafe { rtcReleaseScene(self.scene) }
    }
}

/// An Embree scene of one triangle mesh whose vertices move (same triangles, new
/// positions each frame), updated by refitting: the scene is `RTC_SCENE_FLAG_DYNAMIC` at
/// build quality LOW, which makes Embree build a two-level structure whose geometry BVH
/// uses the geometry's own quality, here `RTC_BUILD_QUALITY_REFIT` ("uses a BVH refitting
/// approach when changing only the vertex buffer", `rtcSetGeometryBuildQuality(3)`).
/// [`EmbreeRefitScene::update`] writes the new positions into Embree's vertex buffer and
/// commits: `rtcUpdateGeometryBuffer`, `rtcCommitGeometry`, `rtcCommitScene`.
pub struct EmbreeRefitScene {
    _device: std::sync::Arc<EmbreeDevice>,
    scene: RtcScene,
    geometry: RtcGeometry,
    vertices: *mut f32,
    vertex_count: usize,
    /// Wall time of the first `rtcCommitScene` (the build).
    pub build_time: Duration,
}

// As `EmbreeScene`; `update` takes `&mut self`, so no trace runs during an update.
unsafe impl Send for EmbreeRefitScene {}
unsafe impl Sync for EmbreeRefitScene {}

impl EmbreeRefitScene {
    /// Builds the scene over the indexed triangles `(positions, triangles)`.
    pub fn new(
        device: std::sync::Arc<EmbreeDevice>,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
    ) -> Result<Self, PeerError> {
        let peer_err = |m: &str| PeerError::Peer {
            peer: "embree",
            message: m.into(),
        };
        if triangles
            .iter()
            .any(|t| t.iter().any(|&v| v as usize >= positions.len()))
        {
            return Err(peer_err("a triangle index is out of range"));
        }
        let boxes: Vec<geom::Aabb> = triangles
            .iter()
            .map(|t| geom::Aabb::from_points(t.iter().map(|&v| positions[v as usize])))
            .collect();
        check_input(&boxes)?;
        let raw = device.raw();
        // SAFETY: as in `EmbreeScene::new`; the geometry is kept (released in `drop`), so
        // its vertex buffer stays valid for `update`.
        unsafe {
            let scene = rtcNewScene(raw);
            if scene.is_null() {
                return Err(peer_err("rtcNewScene failed"));
            }
            let g = rtcNewGeometry(raw, RTC_GEOMETRY_TYPE_TRIANGLE);
            if g.is_null() {
                rtcReleaseScene(scene);
                return Err(peer_err("rtcNewGeometry failed"));
            }
            let mut out = Self {
                _device: device.clone(),
                scene,
                geometry: g,
                vertices: std::ptr::null_mut(),
                vertex_count: positions.len(),
                build_time: Duration::ZERO,
            };
            rtcSetSceneFlags(scene, RTC_SCENE_FLAG_DYNAMIC);
            rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_LOW);
            rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_REFIT);
            let vb = rtcSetNewGeometryBuffer(
                g,
                RTC_BUFFER_TYPE_VERTEX,
                0,
                RTC_FORMAT_FLOAT3,
                12,
                positions.len(),
            ) as *mut f32;
            let ib = rtcSetNewGeometryBuffer(
                g,
                RTC_BUFFER_TYPE_INDEX,
                0,
                RTC_FORMAT_UINT3,
                12,
                triangles.len(),
            ) as *mut u32;
            if (vb.is_null() && !positions.is_empty()) || (ib.is_null() && !triangles.is_empty()) {
                return Err(peer_err("cannot allocate geometry buffers"));
            }
            out.vertices = vb;
            out.write_positions(positions);
            for (i, t) in triangles.iter().enumerate() {
                for (k, &v) in t.iter().enumerate() {
                    ib.add(i * 3 + k).write(v);
                }
            }
            rtcCommitGeometry(g);
            rtcAttachGeometry(scene, g);
            let start = Instant::now();
            rtcCommitScene(scene);
            out.build_time = start.elapsed();
            Ok(out)
        }
    }

    fn write_positions(&mut self, positions: &[Vec3]) {
        for (i, p) in positions.iter().enumerate() {
            // SAFETY: the vertex buffer holds `vertex_count` floats x3 and the caller
            // passes exactly that many positions.
            unsafe {
                self.vertices.add(i * 3).write(p.x);
                self.vertices.add(i * 3 + 1).write(p.y);
                self.vertices.add(i * 3 + 2).write(p.z);
            }
        }
    }

    /// Moves the vertices to `positions` (as many as at construction) and refits: the
    /// per-frame update of an animated mesh.
    pub fn update(&mut self, positions: &[Vec3]) -> Result<(), PeerError> {
        if positions.len() != self.vertex_count {
            return Err(PeerError::Peer {
                peer: "embree",
                message: format!(
                    "the scene has {} vertices, {} given",
                    self.vertex_count,
                    positions.len()
                ),
            });
        }
        self.write_positions(positions);
        // SAFETY: the geometry and scene are live and owned by this value.
        unsafe {
            rtcUpdateGeometryBuffer(self.geometry, RTC_BUFFER_TYPE_VERTEX, 0);
            rtcCommitGeometry(self.geometry);
            rtcCommitScene(self.scene);
        }
        Ok(())
    }

    /// The closest hit of `ray` with `rtcIntersect1`: `(triangle index, t)`.
    pub fn intersect1(&self, ray: &Ray) -> Option<(u32, f32)> {
        let mut rh = RtcRayHit {
            ray: EmbreeScene::rtc_ray(ray),
            hit: RtcHit {
                geom_id: RTC_INVALID_GEOMETRY_ID,
                inst_id: [RTC_INVALID_GEOMETRY_ID],
                ..Default::default()
            },
        };
        let mut ctx = EmbreeScene::context();
        // SAFETY: the scene is committed; the structs match the header's layout.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        (rh.hit.geom_id != RTC_INVALID_GEOMETRY_ID).then_some((rh.hit.prim_id, rh.ray.tfar))
    }
}

impl Drop for EmbreeRefitScene {
    fn drop(&mut self) {
        // SAFETY: both handles are owned by this value and released once.
        unsafe {
            rtcReleaseGeometry(self.geometry);
            rtcReleaseScene(self.scene);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embree_finds_the_same_hits_as_brute_force_mostly() {
        let device = std::sync::Arc::new(EmbreeDevice::new(1).unwrap());
        // A 20x20 grid of quads at z = 0 and one triangle in front.
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        for j in 0..=20 {
            for i in 0..=20 {
                pos.push(Vec3::new(i as f32, j as f32, 0.0));
            }
        }
        for j in 0..20u32 {
            for i in 0..20u32 {
                let a = j * 21 + i;
                tris.push([a, a + 1, a + 22]);
                tris.push([a, a + 22, a + 21]);
            }
        }
        let s = EmbreeScene::new(device, &pos, &tris, EmbreeSceneConfig::default()).unwrap();
        let r = Ray::new(Vec3::new(5.3, 7.6, 3.0), Vec3::new(0.0, 0.0, -1.0));
        let (prim, t) = s.intersect1(&r).unwrap();
        assert!((t - 3.0).abs() < 1e-5);
        let tri = geom::Triangle::new(
            pos[tris[prim as usize][0] as usize],
            pos[tris[prim as usize][1] as usize],
            pos[tris[prim as usize][2] as usize],
        );
        assert!(tri.intersect(&r).is_some());
        assert!(s.occluded1(&r));
        let miss = Ray::new(Vec3::new(5.3, 7.6, 3.0), Vec3::new(0.0, 0.0, 1.0));
        assert!(s.intersect1(&miss).is_none());
        assert!(!s.occluded1(&miss));
    }

    #[test]
    fn a_refitted_scene_finds_the_moved_triangle() {
        let device = std::sync::Arc::new(EmbreeDevice::new(1).unwrap());
        let tri = [[0u32, 1, 2]];
        let at = |z: f32| {
            vec![
                Vec3::new(-1.0, -1.0, z),
                Vec3::new(1.0, -1.0, z),
                Vec3::new(0.0, 1.0, z),
            ]
        };
        let mut s = EmbreeRefitScene::new(device, &at(0.0), &tri).unwrap();
        let r = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(s.intersect1(&r), Some((0, 5.0)));
        s.update(&at(2.0)).unwrap();
        assert_eq!(s.intersect1(&r), Some((0, 3.0)));
        // Moved out of the ray's way: the refitted boxes moved too.
        let mut far = at(0.0);
        for p in &mut far {
            p.x += 10.0;
        }
        s.update(&far).unwrap();
        assert_eq!(s.intersect1(&r), None);
        assert!(s.update(&far[..2]).is_err());
    }
}
