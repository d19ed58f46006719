//! Procedural animated scenes, deterministic from a seed and a size.
//!
//! Each scene stands for one animation class of the thesis, so builders and refitting can
//! be tested on every kind of motion without external data:
//!
//! | name      | motion                                         | topology |
//! |-----------|------------------------------------------------|----------|
//! | `cloth`   | flat sheet (exactly planar at t=0) that waves  | stable   |
//! | `skinned` | tentacles bent by bone chains (linear blend)   | stable   |
//! | `explode` | closed noisy sphere whose triangles fly apart  | stable   |
//! | `fluid`   | metaballs polygonized every frame              | changes  |
//! | `forest`  | instanced trees on a huge ground, wind sway    | stable   |
//! | `soup`    | uniformly random small triangles, slow jitter  | stable   |
//! | `hairball`| thin random strands filling a ball (static)    | stable   |
//! | `city`    | voxel box buildings on a street grid (static)  | stable   |
//!
//! Spec: `proc:NAME?n=...&seed=...&duration=...&fps=...` plus per-scene parameters (see each
//! module). `n` is an approximate triangle count: each scene rounds it to its structure
//! (grid cells, rings, trees, ...), as its module documents. Unknown parameters are errors.
//!
//! Everything is a pure function of (seed, parameters, t): random numbers come from
//! `Rng` streams keyed by element index, never from shared state, and parallel work
//! writes each element independently, so the meshes are bit-identical on any thread count.

mod city;
mod cloth;
mod explode;
mod fluid;
mod forest;
mod hairball;
mod skinned;
mod soup;

use crate::{
    source::DEFAULT_FPS, spec::ProcSpec, Camera, LoadOptions, Scene, SceneError, SceneInfo,
    Timeline,
};
use geom::{Aabb, Vec3};
use std::str::FromStr;

/// Names of the procedural scenes, for error messages and listings.
pub const NAMES: [&str; 8] = [
    "cloth", "skinned", "explode", "fluid", "forest", "soup", "hairball", "city",
];

/// Opens the procedural scene named by `ps` (`spec` is the full spec, for messages).
pub fn open(spec: &str, ps: &ProcSpec, opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    let p = Params { spec, ps, opts };
    let scene: Box<dyn Scene> = match ps.name.as_str() {
        "cloth" => Box::new(cloth::Cloth::new(&p)?),
        "skinned" => Box::new(skinned::Skinned::new(&p)?),
        "explode" => Box::new(explode::Explode::new(&p)?),
        "fluid" => Box::new(fluid::Fluid::new(&p)?),
        "forest" => Box::new(forest::Forest::new(&p)?),
        "soup" => Box::new(soup::Soup::new(&p)?),
        "hairball" => Box::new(hairball::Hairball::new(&p)?),
        "city" => Box::new(city::City::new(&p)?),
        other => {
            return Err(SceneError::spec(
                spec,
                format!(
                    "unknown procedural scene '{other}' (known: {})",
                    NAMES.join(", ")
                ),
            ))
        }
    };
    Ok(scene)
}

/// Parameter access for one scene's constructor: errors become [`SceneError::Spec`].
pub(crate) struct Params<'a> {
    spec: &'a str,
    ps: &'a ProcSpec,
    opts: &'a LoadOptions,
}

/// The parameters every scene takes.
pub(crate) struct Common {
    /// Approximate triangle count asked for.
    pub n: usize,
    /// Seed of every random choice.
    pub seed: u64,
    /// Time span.
    pub timeline: Timeline,
}

impl Params<'_> {
    /// `key` in `[lo, hi]`, or `default` when absent.
    pub fn get_in<T: FromStr + PartialOrd + std::fmt::Display + Copy>(
        &self,
        key: &str,
        default: T,
        lo: T,
        hi: T,
    ) -> Result<T, SceneError> {
        self.ps
            .get_in(key, default, lo, hi)
            .map_err(|m| self.err(m))
    }

    /// A spec error for this scene.
    pub fn err(&self, msg: impl Into<String>) -> SceneError {
        SceneError::spec(self.spec, msg)
    }

    /// Reads `n` (in `[min_n, max_n]`; the upper bound keeps memory and time sane),
    /// `seed`, `duration` and `fps`.
    pub fn common(
        &self,
        default_n: usize,
        min_n: usize,
        max_n: usize,
    ) -> Result<Common, SceneError> {
        let n = self.get_in("n", default_n, min_n, max_n)?;
        let seed = self.get_in("seed", 1u64, 0, u64::MAX)?;
        let duration_s = self.get_in("duration", 2.0f32, 0.01, 3600.0)?;
        // The caller's frame rate is the default, when it is usable.
        let default_fps = self
            .opts
            .fps
            .filter(|f| (1.0..=1000.0).contains(f))
            .unwrap_or(DEFAULT_FPS);
        let fps = self.get_in("fps", default_fps, 1.0, 1000.0)?;
        Ok(Common {
            n,
            seed,
            timeline: Timeline { duration_s, fps },
        })
    }

    /// Rejects parameters no getter read (typos).
    pub fn finish(&self) -> Result<(), SceneError> {
        self.ps.finish().map_err(|m| self.err(m))
    }

    /// Scene metadata; the camera frames `bounds` (the bounds over the whole animation).
    pub fn info(&self, timeline: Timeline, stable_topology: bool, bounds: Aabb) -> SceneInfo {
        SceneInfo {
            name: self.ps.name.clone(),
            source: self.spec.to_string(),
            format: "procedural".to_string(),
            timeline,
            stable_topology,
            dropped_triangles: 0,
            camera: Camera::framing(&bounds),
        }
    }
}

/// The splitmix64 finalizer: a bijective 64-bit mix with good avalanche.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A small seeded generator (splitmix64). Streams keyed by an element index give each
/// element its own numbers, independent of the order elements are generated in.
#[derive(Clone, Debug)]
pub(crate) struct Rng(u64);

impl Rng {
    /// Stream `stream` of seed `seed`.
    pub fn stream(seed: u64, stream: u64) -> Self {
        Rng(mix64(
            seed ^ mix64(stream.wrapping_add(0x632B_E59B_D9B4_E019)),
        ))
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.0)
    }

    /// Uniform in `[0, 1)` (24 random bits, exact in f32).
    #[inline]
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Uniform in `[lo, hi)`.
    #[inline]
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    /// Uniform in the cube `[-1, 1)^3`.
    #[inline]
    pub fn in_cube(&mut self) -> Vec3 {
        Vec3::new(
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
        )
    }

    /// Uniform in the unit ball (rejection sampling, bounded: the fallback after 64 misses,
    /// probability ~1e-21, is the centre).
    pub fn in_ball(&mut self) -> Vec3 {
        for _ in 0..64 {
            let p = self.in_cube();
            if p.length_squared() <= 1.0 {
                return p;
            }
        }
        Vec3::ZERO
    }

    /// A uniformly random unit vector.
    pub fn unit(&mut self) -> Vec3 {
        for _ in 0..64 {
            let p = self.in_cube();
            let l2 = p.length_squared();
            if l2 > 1e-4 && l2 <= 1.0 {
                return p / l2.sqrt();
            }
        }
        Vec3::Y
    }
}

/// A closed unit UV sphere with outward winding: `bands` latitude bands (>= 2) and `segs`
/// longitude segments (>= 3); `2 * segs * (bands - 1)` triangles.
pub(crate) fn uv_sphere(bands: u32, segs: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (bands, segs) = (bands.max(2), segs.max(3));
    let mut pos = Vec::with_capacity(((bands - 1) * segs + 2) as usize);
    pos.push(Vec3::Y);
    for b in 1..bands {
        let theta = std::f32::consts::PI * b as f32 / bands as f32;
        for s in 0..segs {
            let phi = std::f32::consts::TAU * s as f32 / segs as f32;
            pos.push(Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            ));
        }
    }
    let south = pos.len() as u32;
    pos.push(-Vec3::Y);
    let ring = |b: u32, s: u32| 1 + (b - 1) * segs + s % segs;
    let mut tris = Vec::with_capacity((2 * segs * (bands - 1)) as usize);
    for s in 0..segs {
        tris.push([0, ring(1, s + 1), ring(1, s)]);
    }
    for b in 1..bands - 1 {
        for s in 0..segs {
            let (a, bb, c, d) = (
                ring(b, s),
                ring(b, s + 1),
                ring(b + 1, s),
                ring(b + 1, s + 1),
            );
            tris.push([a, bb, d]);
            tris.push([a, d, c]);
        }
    }
    for s in 0..segs {
        tris.push([south, ring(bands - 1, s), ring(bands - 1, s + 1)]);
    }
    (pos, tris)
}

/// Bounds of `scene`'s meshes at `times` (for the default camera of scenes whose extent is
/// not known analytically).
pub(crate) fn bounds_at(scene: &dyn Scene, times: &[f32]) -> Result<Aabb, SceneError> {
    let mut b = Aabb::EMPTY;
    for &t in times {
        b = b.union(scene.mesh_at(t)?.bounds());
    }
    Ok(b)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::Mesh;
    use std::collections::HashMap;

    /// Opens `proc:<s>`, panicking with the error.
    pub fn open_proc(s: &str) -> Box<dyn Scene> {
        match crate::open(&format!("proc:{s}"), &LoadOptions::default()) {
            Ok(sc) => sc,
            Err(e) => panic!("{e}"),
        }
    }

    /// The error of opening `proc:<s>`.
    pub fn open_err(s: &str) -> String {
        match crate::open(&format!("proc:{s}"), &LoadOptions::default()) {
            Ok(_) => panic!("proc:{s} opened"),
            Err(e) => e.to_string(),
        }
    }

    /// Signed volume of a closed mesh (positive for outward winding).
    pub fn signed_volume(m: &Mesh) -> f64 {
        m.triangles_iter()
            .map(|t| {
                t.v[0]
                    .as_dvec3()
                    .dot(t.v[1].as_dvec3().cross(t.v[2].as_dvec3()))
                    / 6.0
            })
            .sum()
    }

    /// Counts of each directed edge; a closed, consistently wound mesh has every directed
    /// edge once and its reverse once.
    pub fn check_closed(m: &Mesh) -> Result<(), String> {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &c) in &edges {
            if c != 1 {
                return Err(format!("directed edge {a}->{b} used {c} times"));
            }
            if !edges.contains_key(&(b, a)) {
                return Err(format!("edge {a}->{b} has no twin (open boundary)"));
            }
        }
        Ok(())
    }

    /// Shared checks for every scene: valid, finite at several times, deterministic, moving.
    pub fn check_scene(s: &str) {
        check_scene_with(s, true)
    }

    /// [`check_scene`] for a static scene: the same mesh at every time, duration 0.
    pub fn check_static_scene(s: &str) {
        check_scene_with(s, false);
        let a = open_proc(s);
        assert_eq!(a.info().timeline.duration_s, 0.0, "{s}");
        assert_eq!(a.info().timeline.frame_count(), 1, "{s}");
        assert_eq!(a.mesh_at(0.0).unwrap(), a.mesh_at(7.0).unwrap(), "{s}");
        // The reported bounds frame the mesh.
        let m = a.mesh_at(0.0).unwrap();
        assert!(m.bounds().min.is_finite() && m.bounds().max.is_finite());
    }

    /// Twice the smallest triangle area of `m` (0 for a degenerate triangle).
    pub fn min_double_area(m: &Mesh) -> f32 {
        m.triangles_iter()
            .map(|t| (t.v[1] - t.v[0]).cross(t.v[2] - t.v[0]).length())
            .fold(f32::INFINITY, f32::min)
    }

    fn check_scene_with(s: &str, moving: bool) {
        let a = open_proc(s);
        let b = open_proc(s);
        let info = a.info();
        assert_eq!(info.format, "procedural");
        assert!(info.camera.eye.is_finite());
        let d = info.timeline.duration_s;
        for t in [0.0, 0.3 * d, 0.5 * d, d, -1.0, d + 5.0, f32::NAN] {
            let m = a.mesh_at(t).unwrap();
            m.check().unwrap();
            assert!(m.triangle_count() > 0, "{s}: empty at t={t}");
            assert!(
                m.positions.iter().all(|p| p.is_finite()),
                "{s}: non-finite position at t={t}"
            );
            assert_eq!(m, b.mesh_at(t).unwrap(), "{s}: not deterministic at t={t}");
        }
        if moving {
            assert_ne!(
                a.mesh_at(0.0).unwrap(),
                a.mesh_at(0.5 * d).unwrap(),
                "{s}: no motion"
            );
        }
        assert_eq!(a.mesh_at(d).unwrap(), a.mesh_at_frame(u32::MAX).unwrap());
        // The default camera sees every vertex of the first, middle and last frames.
        let cam = info.camera;
        let fwd = (cam.target - cam.eye).normalize();
        let cos_half = (0.5 * cam.vfov_deg.to_radians()).cos();
        for t in [0.0, 0.5 * d, d] {
            let m = a.mesh_at(t).unwrap();
            for p in &m.positions {
                let c = (*p - cam.eye).normalize().dot(fwd);
                assert!(c >= cos_half - 1e-4, "{s}: {p} outside the camera at t={t}");
            }
        }
    }

    #[test]
    fn rng_is_uniformish_and_keyed() {
        let mut r = Rng::stream(1, 0);
        let xs: Vec<f32> = (0..10_000).map(|_| r.f32()).collect();
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "{mean}");
        assert_ne!(Rng::stream(1, 0).next_u64(), Rng::stream(1, 1).next_u64());
        assert_ne!(Rng::stream(1, 0).next_u64(), Rng::stream(2, 0).next_u64());
        let u = Rng::stream(3, 3).unit();
        assert!((u.length() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn uv_sphere_is_closed_and_outward() {
        let (positions, triangles) = uv_sphere(6, 12);
        assert_eq!(triangles.len(), 2 * 12 * 5);
        let m = Mesh {
            material_ids: vec![0; triangles.len()],
            positions,
            triangles,
            material_names: vec![],
        };
        check_closed(&m).unwrap();
        let v = signed_volume(&m);
        assert!(v > 3.0 && v < 4.19, "{v}");
    }

    #[test]
    fn independent_of_thread_count() {
        let run = |threads: usize, s: &str| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| open_proc(s).mesh_at(0.77).unwrap())
        };
        for s in [
            "cloth?n=3000",
            "skinned?n=3000",
            "explode?n=3000",
            "fluid?n=3000",
            "forest?n=3000",
            "soup?n=100000",
            "hairball?n=3000",
            "city?n=3000",
        ] {
            assert_eq!(run(1, s), run(3, s), "{s}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Any scene, size, seed and time gives a valid, finite, non-empty mesh.
        #[test]
        fn any_seed_and_time_is_valid(
            which in 0usize..NAMES.len(),
            n in 100usize..3000,
            seed in proptest::prelude::any::<u64>(),
            t in -1.0f32..4.0,
        ) {
            let s = open_proc(&format!("{}?n={n}&seed={seed}", NAMES[which]));
            let m = s.mesh_at(t).unwrap();
            proptest::prop_assert!(m.check().is_ok());
            proptest::prop_assert!(m.triangle_count() > 0);
            proptest::prop_assert!(m.positions.iter().all(|p| p.is_finite()));
            proptest::prop_assert!(s.info().camera.eye.is_finite());
        }
    }

    #[test]
    fn unknown_scene_lists_names() {
        let e = open_err("teapot?n=5");
        assert!(
            e.contains("teapot") && e.contains("cloth") && e.contains("soup"),
            "{e}"
        );
    }

    #[test]
    fn common_parameters_are_checked() {
        for name in NAMES {
            let e = open_err(&format!("{name}?n=1000&bogus=1"));
            assert!(e.contains("bogus"), "{e}");
            let e = open_err(&format!("{name}?n=100000000000"));
            assert!(e.contains("parameter n="), "{e}");
            let e = open_err(&format!("{name}?n=0"));
            assert!(e.contains("parameter n="), "{e}");
            let e = open_err(&format!("{name}?n=1000&duration=-1"));
            assert!(e.contains("duration"), "{e}");
            let e = open_err(&format!("{name}?n=1000&fps=nan"));
            assert!(e.contains("fps"), "{e}");
            let e = open_err(&format!("{name}?n=1000&seed=x"));
            assert!(e.contains("seed"), "{e}");
        }
    }

    #[test]
    fn fps_and_duration_reach_the_timeline() {
        let s = open_proc("cloth?n=200&duration=3&fps=10");
        assert_eq!(
            s.info().timeline,
            Timeline {
                duration_s: 3.0,
                fps: 10.0
            }
        );
        assert_eq!(s.info().timeline.frame_count(), 31);
        assert_eq!(s.info().name, "cloth");
        assert_eq!(s.info().source, "proc:cloth?n=200&duration=3&fps=10");
        let opts = LoadOptions {
            fps: Some(12.0),
            ..Default::default()
        };
        let s = crate::open("proc:cloth?n=200", &opts).unwrap();
        assert_eq!(s.info().timeline.fps, 12.0);
    }
}
