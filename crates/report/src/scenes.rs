//! The scenes of the reports: where the shared real scenes are, short names, and loading a
//! scene spec as triangles (with its camera) or primitive boxes. Every report area uses
//! these; none of them uses another area.

use anyhow::Context;
use std::path::{Path, PathBuf};

pub use scene::camera::{view_camera, INTERIOR_VIEWS};

/// The report's cloth (`arbor report cbvh`, and any report given the spec `cloth`): the
/// procedural sheet exactly flat at z = 0 (t = 0) together with the same sheet waving at
/// t = 1 s, 92K triangles in all: like \[P3\] Fig. 9, much geometry with a degenerate axis
/// among geometry without. (A sheet flat everywhere never backtracks: all its nodes share
/// the minimum scale on that axis.)
pub const CLOTH: &str = "cloth";
/// The procedural sheet the cloth scene is made of.
pub const CLOTH_SHEET: &str = "proc:cloth?n=46000";
/// Time of the waving copy of the sheet.
pub const CLOTH_WAVING_S: f32 = 1.0;

/// The folder of the shared real scenes (every report's `--scene-dir` default), found at
/// run time: the environment variable `ARBOR_SCENE_DIR` if it is set; else the nearest
/// `shared/scenes` folder in or above the current folder (`../shared/scenes` from the
/// repository's root), else in or above the folder of the running executable; else
/// `../shared/scenes`.
pub fn shared_scenes() -> PathBuf {
    if let Some(d) = std::env::var_os("ARBOR_SCENE_DIR").filter(|d| !d.is_empty()) {
        return d.into();
    }
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf));
    for start in [std::env::current_dir().ok(), exe_dir]
        .into_iter()
        .flatten()
    {
        if let Some(d) = start
            .ancestors()
            .map(|a| a.join("shared").join("scenes"))
            .find(|d| d.is_dir())
        {
            return d;
        }
    }
    Path::new("..").join("shared").join("scenes")
}

/// Short name of a scene spec (file stem, or procedural name).
pub fn short_name(spec: &str) -> String {
    if let Some(rest) = spec.strip_prefix("proc:") {
        return rest.split('?').next().unwrap_or(rest).to_string();
    }
    Path::new(spec)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec.to_string())
}

/// The primitive boxes of `mesh`; bad indices are an error, not a panic.
pub fn mesh_boxes(mesh: &scene::Mesh) -> anyhow::Result<Vec<geom::Aabb>> {
    bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)
        .context("cannot compute triangle bounds")
}

/// The primitive boxes of scene `spec` at time `t`, clamped to its timeline (the report
/// scenes are sampled once).
pub fn scene_prims(spec: &str, t: f32) -> anyhow::Result<Vec<geom::Aabb>> {
    anyhow::ensure!(t.is_finite(), "the sampling time must be finite, got {t}");
    let scene = scene::open(spec, &scene::LoadOptions::default())
        .with_context(|| format!("cannot open {spec}"))?;
    let t = scene.info().timeline.clamp(t);
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample {spec}"))?;
    mesh_boxes(&mesh)
}

/// The triangles of a scene spec at t = 0 (or of the report's [`CLOTH`]: both sheets), by
/// name, with the scene's camera.
pub fn load_triangles(spec: &str) -> anyhow::Result<(String, Vec<geom::Triangle>, scene::Camera)> {
    let (source, times) = if spec == CLOTH {
        (CLOTH_SHEET, vec![0.0, CLOTH_WAVING_S])
    } else {
        (spec, vec![0.0])
    };
    let scene = scene::open(source, &scene::LoadOptions::default())
        .with_context(|| format!("cannot open {source}"))?;
    let mut tris = Vec::new();
    for t in times {
        let mesh = scene
            .mesh_at(t)
            .with_context(|| format!("cannot sample {source}"))?;
        // Checks the indices (a bad mesh is an error, not a panic).
        mesh_boxes(&mesh)?;
        tris.extend(mesh.triangles_iter());
    }
    Ok((short_name(spec), tris, scene.info().camera))
}

/// Triangles and camera of a report scene spec: the scene's camera, or the interior one
/// ([`view_camera`]).
pub fn load_traced(spec: &str) -> anyhow::Result<(String, Vec<geom::Triangle>, scene::Camera)> {
    let (name, tris, camera) = load_triangles(spec)?;
    let camera = view_camera(&name, camera);
    Ok((name, tris, camera))
}

/// The existing files among `files` under `dir`, as paths; a missing one is reported to
/// `warn` ("... not found: skipped") and left out.
pub fn existing(dir: &Path, files: &[&str], warn: &dyn Fn(&str)) -> Vec<String> {
    files
        .iter()
        .filter_map(|f| {
            let p = dir.join(f);
            if p.exists() {
                Some(p.display().to_string())
            } else {
                warn(&format!("{} not found: skipped", p.display()));
                None
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_loading() {
        assert_eq!(short_name("/a/b/bunny.ply"), "bunny");
        assert_eq!(short_name("proc:cloth?n=5"), "cloth");
        let (name, tris, _) = load_triangles("proc:cloth?n=200").unwrap();
        assert_eq!(name, "cloth");
        assert!(!tris.is_empty());
        assert!(scene_prims("proc:cloth?n=200", f32::NAN).is_err());
        assert_eq!(
            scene_prims("proc:cloth?n=200", 0.0).unwrap().len(),
            tris.len()
        );
        let e = load_triangles("no-such.ply").unwrap_err();
        assert!(format!("{e:#}").contains("no-such.ply"), "{e:#}");
        let warned = std::cell::RefCell::new(Vec::new());
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.ply"), "").unwrap();
        let found = existing(dir.path(), &["a.ply", "b.ply"], &|m| {
            warned.borrow_mut().push(m.to_string())
        });
        assert_eq!(found.len(), 1);
        assert!(warned.borrow()[0].ends_with("b.ply not found: skipped"));
    }
}
