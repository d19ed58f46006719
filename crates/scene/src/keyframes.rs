//! Keyframe sequences: one OBJ or PLY file per frame, all with the same triangles, played at
//! a fixed frame rate with positions linearly interpolated between neighbouring frames.
//!
//! This is how animated scan data (e.g. the horse gallop) reaches the refitting BVH
//! builders: topology is fixed, so triangle `i` is the same primitive in every frame.
//! Sequences can be long, so only frame 0 is read at open time (for the topology and the
//! camera); other frames are read when first sampled and kept in a small LRU cache.
//! A non-finite coordinate in any frame is an error (the crate's NaN policy for animated
//! sources), as is a frame whose triangles differ from frame 0's; both are detected when a
//! frame is first read, since frames are not read at open time.

use crate::source::{load_mesh_file, DEFAULT_FPS};
use crate::{Camera, LoadOptions, Mesh, Scene, SceneError, SceneInfo, Timeline};
use geom::Vec3;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Frames kept in memory besides frame 0 (two neighbours for interpolation, plus slack for
/// a caller stepping forwards while another samples nearby).
const CACHE_FRAMES: usize = 4;

/// Opens the `.obj` / `.ply` files of a directory, in natural name order ([`natural_cmp`]), as a keyframe sequence.
pub fn open_dir(spec: &str, dir: &Path, opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    let entries = std::fs::read_dir(dir).map_err(|e| SceneError::io(dir, e))?;
    let mut files = Vec::new();
    for e in entries {
        let p = e.map_err(|e| SceneError::io(dir, e))?.path();
        let ext = p
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        if matches!(ext.as_deref(), Some("obj" | "ply")) && p.is_file() {
            files.push(p);
        }
    }
    if files.is_empty() {
        return Err(SceneError::spec(
            spec,
            "directory has no .obj or .ply files",
        ));
    }
    sort_natural(&mut files);
    let name = dir
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec.to_string());
    Ok(Box::new(KeyframeScene::open(spec, &name, files, opts)?))
}

/// Opens the files matching a glob pattern, in natural name order ([`natural_cmp`]), as a keyframe sequence.
pub fn open_glob(spec: &str, opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    let paths =
        glob::glob(spec).map_err(|e| SceneError::spec(spec, format!("bad glob pattern: {e}")))?;
    let mut files = Vec::new();
    for p in paths {
        let p = p.map_err(|e| SceneError::spec(spec, e.to_string()))?;
        if p.is_file() {
            files.push(p);
        }
    }
    if files.is_empty() {
        return Err(SceneError::spec(spec, "no files match the pattern"));
    }
    sort_natural(&mut files);
    let name = Path::new(spec)
        .parent()
        .and_then(|p| p.file_name())
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "keyframes".to_string());
    Ok(Box::new(KeyframeScene::open(spec, &name, files, opts)?))
}

/// Sorts frame files in natural order of their paths ([`natural_cmp`]), so `f2` plays
/// before `f10`.
fn sort_natural(files: &mut [PathBuf]) {
    files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
}

/// Natural ("numeric") order of names: runs of ASCII digits compare as numbers, everything
/// else character by character, so `f1 < f2 < f10`. Numbers equal in value but written
/// differently (`f01` and `f1`) fall back to the plain string order, as do otherwise equal
/// names, so the order is total and deterministic.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (ab, bb) = (a.as_bytes(), b.as_bytes());
    let (mut i, mut j) = (0, 0);
    while i < ab.len() && j < bb.len() {
        if ab[i].is_ascii_digit() && bb[j].is_ascii_digit() {
            let si = i;
            while i < ab.len() && ab[i].is_ascii_digit() {
                i += 1;
            }
            let sj = j;
            while j < bb.len() && bb[j].is_ascii_digit() {
                j += 1;
            }
            // Compare digit runs by value without parsing (any length): strip leading
            // zeros, then longer is larger, then lexicographic.
            let x = a[si..i].trim_start_matches('0');
            let y = b[sj..j].trim_start_matches('0');
            let o = x.len().cmp(&y.len()).then_with(|| x.cmp(y));
            if o != Ordering::Equal {
                return o;
            }
        } else {
            // Compare whole characters, not bytes, so non-ASCII names order sensibly.
            let ca = a[i..].chars().next().unwrap();
            let cb = b[j..].chars().next().unwrap();
            if ca != cb {
                return ca.cmp(&cb);
            }
            i += ca.len_utf8();
            j += cb.len_utf8();
        }
    }
    (ab.len() - i).cmp(&(bb.len() - j)).then_with(|| a.cmp(b))
}

/// A keyframe sequence (see the module docs). `Send + Sync`: the cache sits behind a mutex.
pub struct KeyframeScene {
    info: SceneInfo,
    files: Vec<PathBuf>,
    /// Frame 0's mesh: the topology and materials of every frame.
    first: Mesh,
    /// Frame 0's positions, shared so sampling frame 0 copies them only once.
    first_positions: Arc<Vec<Vec3>>,
    /// Recently used frames' positions, most recent last.
    cache: Mutex<Vec<(usize, Arc<Vec<Vec3>>)>>,
    opts: LoadOptions,
}

impl KeyframeScene {
    /// Opens a sequence of frame files (already in frame order); reads only frame 0.
    pub fn open(
        spec: &str,
        name: &str,
        files: Vec<PathBuf>,
        opts: &LoadOptions,
    ) -> Result<Self, SceneError> {
        let fps = opts.fps.unwrap_or(DEFAULT_FPS);
        if !(fps.is_finite() && fps > 0.0) {
            return Err(SceneError::spec(
                spec,
                format!("frame rate must be positive, got {fps}"),
            ));
        }
        if files.is_empty() {
            return Err(SceneError::spec(spec, "no frames"));
        }
        // Per-file byte progress would restart for every frame; report frames instead.
        let frame_opts = LoadOptions {
            progress: None,
            ..opts.clone()
        };
        let first = load_frame(&files[0], &frame_opts)?;
        opts.report(1, files.len() as u64);
        let info = SceneInfo {
            name: name.to_string(),
            source: spec.to_string(),
            format: "keyframes".to_string(),
            timeline: Timeline {
                duration_s: (files.len() - 1) as f32 / fps,
                fps,
            },
            stable_topology: true,
            dropped_triangles: 0,
            camera: Camera::framing(&first.bounds()),
        };
        Ok(KeyframeScene {
            info,
            files,
            first_positions: Arc::new(first.positions.clone()),
            first,
            cache: Mutex::new(Vec::new()),
            opts: frame_opts,
        })
    }

    /// The frame files, in frame order.
    pub fn frame_files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Positions of frame `i`, from the cache or read and checked against frame 0.
    fn positions(&self, i: usize) -> Result<Arc<Vec<Vec3>>, SceneError> {
        if i == 0 {
            return Ok(self.first_positions.clone());
        }
        {
            let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(k) = c.iter().position(|(f, _)| *f == i) {
                let e = c.remove(k);
                let p = e.1.clone();
                c.push(e);
                return Ok(p);
            }
        }
        // Read outside the lock so other threads can use cached frames meanwhile.
        let path = &self.files[i];
        let m = load_frame(path, &self.opts)?;
        if m.positions.len() != self.first.positions.len() || m.triangles != self.first.triangles {
            return Err(SceneError::malformed(
                path,
                format!(
                    "topology differs from the first frame {} ({} vertices / {} triangles here, {} / {} there)",
                    self.files[0].display(),
                    m.positions.len(),
                    m.triangle_count(),
                    self.first.positions.len(),
                    self.first.triangle_count()
                ),
            ));
        }
        let p = Arc::new(m.positions);
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if !c.iter().any(|(f, _)| *f == i) {
            if c.len() >= CACHE_FRAMES {
                c.remove(0);
            }
            c.push((i, p.clone()));
        }
        Ok(p)
    }
}

/// Reads one frame; any non-finite coordinate is an error (animated NaN policy).
fn load_frame(path: &Path, opts: &LoadOptions) -> Result<Mesh, SceneError> {
    let l = load_mesh_file(path, opts)?;
    if let Some(i) = l.mesh.positions.iter().position(|&p| !geom::is_finite3(p)) {
        return Err(SceneError::malformed(
            path,
            format!("vertex {i} has a non-finite coordinate (not allowed in an animated sequence)"),
        ));
    }
    Ok(l.mesh)
}

impl Scene for KeyframeScene {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let tl = self.info.timeline;
        let f = tl.clamp(t) * tl.fps;
        let last = self.files.len() - 1;
        let i0 = (f.floor() as usize).min(last);
        let i1 = (i0 + 1).min(last);
        let w = (f - i0 as f32).clamp(0.0, 1.0);
        let a = self.positions(i0)?;
        let positions = if i1 == i0 || w <= 0.0 {
            a.as_ref().clone()
        } else {
            let b = self.positions(i1)?;
            a.iter()
                .zip(b.iter())
                .map(|(&p, &q)| p.lerp(q, w))
                .collect()
        };
        Ok(Mesh {
            positions,
            ..self.first.clone()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(dx: f32) -> Mesh {
        Mesh {
            positions: vec![Vec3::new(dx, 0.0, 0.0), Vec3::X, Vec3::Y, Vec3::ONE],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            material_ids: vec![0, 0],
            material_names: vec![],
        }
    }

    fn write_frames(dir: &Path, n: usize) {
        for i in 0..n {
            let mut b = Vec::new();
            if i % 2 == 0 {
                crate::obj::write(&frame(i as f32), &mut b).unwrap();
                std::fs::write(dir.join(format!("f{i:03}.obj")), b).unwrap();
            } else {
                crate::ply::write_binary_le(&frame(i as f32), &mut b).unwrap();
                std::fs::write(dir.join(format!("f{i:03}.ply")), b).unwrap();
            }
        }
        std::fs::write(dir.join("notes.txt"), "ignored").unwrap();
    }

    fn opts(fps: f32) -> LoadOptions {
        LoadOptions {
            fps: Some(fps),
            ..Default::default()
        }
    }

    #[test]
    fn natural_order() {
        use std::cmp::Ordering::*;
        assert_eq!(natural_cmp("f1", "f2"), Less);
        assert_eq!(natural_cmp("f2", "f10"), Less);
        assert_eq!(natural_cmp("f10", "f2"), Greater);
        // Leading zeros: same value, tie broken by the string order (deterministic).
        assert_eq!(natural_cmp("f007", "f7"), Less);
        assert_eq!(natural_cmp("f007", "f8"), Less);
        assert_eq!(natural_cmp("f010", "f9"), Greater);
        // No digits: plain text order.
        assert_eq!(natural_cmp("abc", "abd"), Less);
        assert_eq!(natural_cmp("ab", "abc"), Less);
        assert_eq!(natural_cmp("same", "same"), Equal);
        // Mixed runs and digits against letters.
        assert_eq!(natural_cmp("a2b10", "a2b9"), Greater);
        assert_eq!(natural_cmp("a10b1", "a9b2"), Greater);
        assert_eq!(natural_cmp("frame9.obj", "frame10.obj"), Less);
        assert_eq!(natural_cmp("1x", "x"), Less);
        // Longer than any integer type.
        assert_eq!(
            natural_cmp("f99999999999999999999999", "f100000000000000000000000"),
            Less
        );
        let mut v = vec!["f10", "f2", "f1", "f01", "g", "f"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, ["f", "f01", "f1", "f2", "f10", "g"]);
    }

    #[test]
    fn dir_frames_play_in_natural_order() {
        let d = tempfile::tempdir().unwrap();
        // Frame k has x = k; named f1, f2, f10 (string order would be f1, f10, f2).
        for (name, x) in [("f1", 0.0), ("f2", 1.0), ("f10", 2.0)] {
            let mut b = Vec::new();
            crate::obj::write(&frame(x), &mut b).unwrap();
            std::fs::write(d.path().join(format!("{name}.obj")), b).unwrap();
        }
        let s = open_dir("seq", d.path(), &opts(1.0)).unwrap();
        assert_eq!(s.info().timeline.frame_count(), 3);
        for k in 0..3 {
            let m = s.mesh_at(k as f32).unwrap();
            assert_eq!(m.positions[0].x, k as f32, "frame {k}");
        }
    }

    #[test]
    fn dir_sequence_interpolates() {
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 5);
        let s = open_dir("seq", d.path(), &opts(2.0)).unwrap();
        assert_eq!(s.info().timeline.duration_s, 2.0);
        assert_eq!(s.info().timeline.frame_count(), 5);
        assert_eq!(s.info().format, "keyframes");
        for (t, x) in [
            (0.0, 0.0),
            (0.25, 0.5),
            (1.0, 2.0),
            (1.75, 3.5),
            (2.0, 4.0),
            (9.0, 4.0),
            (-1.0, 0.0),
        ] {
            let m = s.mesh_at(t).unwrap();
            assert!(
                (m.positions[0].x - x).abs() < 1e-6,
                "t={t}: {}",
                m.positions[0].x
            );
            assert_eq!(m.positions[1], Vec3::X);
            assert_eq!(m.triangles, frame(0.0).triangles);
        }
        assert_eq!(s.mesh_at_frame(3).unwrap().positions[0].x, 3.0);
    }

    #[test]
    fn glob_sequence_and_errors() {
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 3);
        let pat = format!("{}/*.obj", d.path().display());
        let s = open_glob(&pat, &LoadOptions::default()).unwrap();
        assert_eq!(s.info().timeline.duration_s, 1.0 / DEFAULT_FPS);
        assert_eq!(s.mesh_at(1.0).unwrap().positions[0].x, 2.0);
        let e = open_glob(
            &format!("{}/*.nothing", d.path().display()),
            &LoadOptions::default(),
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("no files match"), "{e}");
        assert!(open_glob("[", &LoadOptions::default()).is_err());
        let empty = tempfile::tempdir().unwrap();
        let e = open_dir("empty", empty.path(), &LoadOptions::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains("no .obj or .ply"), "{e}");
        assert!(open_dir("seq", d.path(), &opts(0.0)).is_err());
        assert!(open_dir("seq", d.path(), &opts(f32::NAN)).is_err());
    }

    #[test]
    fn single_frame_is_static() {
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 1);
        let s = open_dir("seq", d.path(), &LoadOptions::default()).unwrap();
        assert_eq!(s.info().timeline.duration_s, 0.0);
        assert_eq!(s.mesh_at(5.0).unwrap(), frame(0.0));
    }

    #[test]
    fn mismatched_topology_names_the_file() {
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 3);
        let mut bad = frame(2.0);
        bad.triangles[1] = [1, 2, 3];
        let mut b = Vec::new();
        crate::obj::write(&bad, &mut b).unwrap();
        std::fs::write(d.path().join("f002.obj"), b).unwrap();
        let s = open_dir("seq", d.path(), &opts(1.0)).unwrap();
        assert!(s.mesh_at(0.5).is_ok());
        let e = s.mesh_at(1.5).unwrap_err().to_string();
        assert!(e.contains("f002.obj") && e.contains("topology"), "{e}");
    }

    #[test]
    fn nan_in_a_frame_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 2);
        std::fs::remove_file(d.path().join("f001.ply")).unwrap();
        let mut m = frame(1.0);
        m.positions[3].y = f32::NAN;
        let mut b = Vec::new();
        crate::obj::write(&m, &mut b).unwrap();
        std::fs::write(d.path().join("f001.obj"), b).unwrap();
        let s = open_dir("seq", d.path(), &opts(1.0)).unwrap();
        let e = s.mesh_at(1.0).unwrap_err().to_string();
        assert!(e.contains("f001.obj") && e.contains("non-finite"), "{e}");
    }

    #[test]
    fn scene_is_send_sync_and_threads_share_the_cache() {
        fn assert_send_sync<T: Send + Sync>() {}
        assert_send_sync::<KeyframeScene>();
        let d = tempfile::tempdir().unwrap();
        write_frames(d.path(), 8);
        let s = open_dir("seq", d.path(), &opts(1.0)).unwrap();
        std::thread::scope(|sc| {
            for k in 0..4 {
                let s = &s;
                sc.spawn(move || {
                    for i in 0..20 {
                        let t = ((i * 7 + k) % 15) as f32 * 0.5;
                        assert!((s.mesh_at(t).unwrap().positions[0].x - t).abs() < 1e-5);
                    }
                });
            }
        });
    }

    #[test]
    fn horse_gallop() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes/horse-gallop");
        if !dir.exists() {
            eprintln!("skipping: {} not found", dir.display());
            return;
        }
        let s = open_dir("horse", &dir, &opts(24.0)).unwrap();
        assert_eq!(s.info().timeline.frame_count(), 48);
        for t in [0.0, 0.51, s.info().timeline.duration_s] {
            let m = s.mesh_at(t).unwrap();
            assert_eq!(m.triangle_count(), 16_843);
            m.check().unwrap();
            assert!(m.bounds().is_finite());
        }
    }
}
