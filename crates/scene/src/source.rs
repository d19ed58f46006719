//! The [`Scene`] trait, scene metadata and [`open`], which turns a spec string into a scene.

use crate::{
    gltf_scene, keyframes, mesh::LoadedMesh, obj, ply, procedural, spec, Camera, Mesh, SceneError,
};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;

/// A progress callback: `(done, total)` in a unit of the loader's choosing (bytes for file
/// loaders, frames for sequences). Called at most a few hundred times per load.
pub type ProgressFn = Arc<dyn Fn(u64, u64) + Send + Sync>;

/// Options shared by every loader.
#[derive(Clone, Default)]
pub struct LoadOptions {
    /// Called as loading advances, so a caller can show a progress bar.
    pub progress: Option<ProgressFn>,
    /// Frame rate of keyframe sequences (one file per frame), in frames per second.
    /// Default [`DEFAULT_FPS`].
    pub fps: Option<f32>,
    /// glTF: which animation to play, by index or name. Default: the first.
    pub animation: Option<String>,
}

impl LoadOptions {
    /// Reports progress if a callback is set.
    #[inline]
    pub fn report(&self, done: u64, total: u64) {
        if let Some(p) = &self.progress {
            p(done, total)
        }
    }
}

/// Frame rate used to number the frames of a sequence when none is given.
pub const DEFAULT_FPS: f32 = 30.0;

/// The time span of a scene. Time runs from 0 to `duration_s`; frame `n` is at `n / fps`.
/// A static scene has duration 0 and one frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Timeline {
    /// Length of the animation in seconds (0 for a static scene).
    pub duration_s: f32,
    /// Frames per second used to number frames.
    pub fps: f32,
}

impl Timeline {
    /// A static scene's timeline.
    pub const STATIC: Timeline = Timeline {
        duration_s: 0.0,
        fps: DEFAULT_FPS,
    };

    /// Number of frames: those at `0, 1/fps, ...` up to and including `duration_s`.
    pub fn frame_count(&self) -> u32 {
        let positive = |x: f32| x > 0.0; // false for NaN too
        if !positive(self.duration_s) || !positive(self.fps) {
            return 1;
        }
        // The small slack makes a duration of exactly (n-1)/fps give n frames despite rounding.
        (self.duration_s * self.fps + 1e-3).floor() as u32 + 1
    }

    /// Time of frame `n` in seconds, clamped to the duration.
    pub fn time_of_frame(&self, n: u32) -> f32 {
        if self.fps > 0.0 {
            (n as f32 / self.fps).min(self.duration_s).max(0.0)
        } else {
            0.0
        }
    }

    /// `t` clamped to `[0, duration_s]` (NaN becomes 0). Scenes hold their first and last
    /// poses outside their time span.
    pub fn clamp(&self, t: f32) -> f32 {
        if t.is_nan() {
            0.0
        } else {
            t.clamp(0.0, self.duration_s.max(0.0))
        }
    }
}

/// What a scene is, independent of time.
#[derive(Clone, Debug, Serialize)]
pub struct SceneInfo {
    /// Short name (file stem or procedural name).
    pub name: String,
    /// The spec the scene was opened from.
    pub source: String,
    /// Source format: `ply`, `obj`, `gltf`, `keyframes`, `procedural`.
    pub format: String,
    /// Time span and frame numbering.
    pub timeline: Timeline,
    /// True when every frame has the same triangles in the same order (triangle index is
    /// a stable primitive id, so a BVH can be refitted). False for e.g. `fluid`.
    pub stable_topology: bool,
    /// Triangles dropped at load time for non-finite coordinates (static files only).
    pub dropped_triangles: usize,
    /// The default camera.
    pub camera: Camera,
}

/// A scene: world-space triangles as a function of time, plus a default camera.
pub trait Scene: Send + Sync {
    /// Metadata: name, timeline, topology, default camera.
    fn info(&self) -> &SceneInfo;

    /// The world-space mesh at time `t` seconds (clamped to the timeline).
    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError>;

    /// The mesh of frame `n` (see [`Timeline::time_of_frame`]).
    fn mesh_at_frame(&self, n: u32) -> Result<Mesh, SceneError> {
        self.mesh_at(self.info().timeline.time_of_frame(n))
    }
}

/// A scene that does not move: one mesh for all time.
pub struct StaticScene {
    info: SceneInfo,
    mesh: Mesh,
}

impl StaticScene {
    /// Wraps a mesh; the camera frames its bounds.
    pub fn new(name: &str, source: &str, format: &str, loaded: LoadedMesh) -> Self {
        let camera = Camera::framing(&loaded.mesh.bounds());
        StaticScene {
            info: SceneInfo {
                name: name.to_string(),
                source: source.to_string(),
                format: format.to_string(),
                timeline: Timeline::STATIC,
                stable_topology: true,
                dropped_triangles: loaded.dropped_triangles,
                camera,
            },
            mesh: loaded.mesh,
        }
    }

    /// The mesh.
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }
}

impl Scene for StaticScene {
    fn info(&self) -> &SceneInfo {
        &self.info
    }
    fn mesh_at(&self, _t: f32) -> Result<Mesh, SceneError> {
        Ok(self.mesh.clone())
    }
}

/// Loads a single mesh file (OBJ or PLY) by extension.
/// A zero-byte file is an error (it is almost always a failed export or copy), while a
/// file with only comments is a valid empty mesh.
pub fn load_mesh_file(path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let len = std::fs::metadata(path)
        .map_err(|e| SceneError::io(path, e))?
        .len();
    if len == 0 {
        return Err(SceneError::malformed(path, "empty file (0 bytes)"));
    }
    match extension(path).as_str() {
        "ply" => ply::load(path, opts),
        "obj" => obj::load(path, opts),
        other => Err(SceneError::unsupported(
            path,
            format!("not a mesh file extension: '{other}' (expected .ply or .obj)"),
        )),
    }
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

fn is_glob(s: &str) -> bool {
    s.contains(['*', '?', '['])
}

/// Opens a scene from a spec:
/// - `proc:NAME?key=value&...`: a procedural scene (see [`procedural`]);
/// - a directory: a keyframe sequence of the `.obj` / `.ply` files in it, in name order;
/// - a glob such as `frames/*.obj`: a keyframe sequence of the matching files;
/// - a `.ply`, `.obj`, `.gltf` or `.glb` file.
pub fn open(spec_str: &str, opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    if let Some(rest) = spec_str.strip_prefix("proc:") {
        let ps = spec::ProcSpec::parse(rest).map_err(|m| SceneError::spec(spec_str, m))?;
        return procedural::open(spec_str, &ps, opts);
    }
    if spec_str.is_empty() {
        return Err(SceneError::spec(spec_str, "empty scene spec"));
    }
    let path = Path::new(spec_str);
    if path.is_dir() {
        return keyframes::open_dir(spec_str, path, opts);
    }
    if !path.exists() && is_glob(spec_str) {
        return keyframes::open_glob(spec_str, opts);
    }
    let meta = std::fs::metadata(path).map_err(|e| SceneError::io(path, e))?;
    if !meta.is_file() {
        return Err(SceneError::unsupported(path, "not a regular file"));
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec_str.to_string());
    match extension(path).as_str() {
        "gltf" | "glb" => gltf_scene::open(spec_str, path, opts),
        "ply" | "obj" => {
            let loaded = load_mesh_file(path, opts)?;
            let fmt = extension(path);
            Ok(Box::new(StaticScene::new(&name, spec_str, &fmt, loaded)))
        }
        other => Err(SceneError::unsupported(
            path,
            format!("unknown scene file extension '{other}' (expected .ply, .obj, .gltf or .glb)"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timeline_frames() {
        assert_eq!(Timeline::STATIC.frame_count(), 1);
        let t = Timeline {
            duration_s: 47.0 / 24.0,
            fps: 24.0,
        };
        assert_eq!(t.frame_count(), 48);
        assert_eq!(t.time_of_frame(47), t.duration_s);
        assert_eq!(t.time_of_frame(100), t.duration_s);
        assert_eq!(t.clamp(f32::NAN), 0.0);
        assert_eq!(t.clamp(-1.0), 0.0);
    }

    #[test]
    fn missing_file_names_the_path() {
        let e = match open("/definitely/not/here.ply", &LoadOptions::default()) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("opened a missing file"),
        };
        assert!(e.contains("/definitely/not/here.ply"), "{e}");
    }

    #[test]
    fn unknown_extension_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("scene.xyz");
        std::fs::write(&p, b"hello").unwrap();
        let e = open(p.to_str().unwrap(), &LoadOptions::default())
            .err()
            .unwrap();
        assert!(
            e.to_string().contains("unknown scene file extension"),
            "{e}"
        );
    }
}
