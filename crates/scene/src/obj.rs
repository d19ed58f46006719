//! Wavefront OBJ loader and writer (geometry and material assignment only).
//!
//! A small dedicated parser over byte slices rather than `tobj` (from its documentation:
//! it splits the file into per-object/per-material models that we would have to re-merge,
//! takes material ids from the `.mtl` file rather than `usemtl` names, and reports errors
//! as context-free enum variants); we need one merged mesh, ids by `usemtl` name even when
//! the `.mtl` is missing, line numbers in every error, and a single pass over the bytes.
//!
//! Supported: `v x y z [w]` (w and any vertex colours ignored), `f` with `v`, `v/vt`, `v//vn`
//! and `v/vt/vn` corners, negative (relative) indices, polygons (fan-triangulated), `usemtl`,
//! `g` and `o`, `#` comments (to the end of the line), blank lines, `\` line continuations
//! and CRLF. Every other statement (`vt`, `vn`, `s`, `mtllib`, `l`, `p`, ...) is skipped.
//!
//! Materials: ids follow `usemtl` names in order of first use. Faces before the first
//! `usemtl` get a material named `default`, which is created only when such faces exist and
//! the file also uses `usemtl`. A file without any `usemtl` but with `g` / `o` statements
//! keeps its groups instead: the group names (first name of a `g` line, or the `o` name)
//! become the material names and ids, in order of first use, with `default` for faces
//! before the first group. A file with neither has no material names and every id is 0.
//!
//! Lines are bytes, not text: non-UTF-8 bytes are fine in comments, skipped statements and
//! material names (converted lossily); in a number they are an error with the line number.
//! A face index must refer to a vertex defined earlier in the file (as the format
//! specifies); an index of 0 or out of range is an error.

use crate::ply::{finish_mesh, parse_f32, parse_int, Progress};
use crate::{LoadOptions, LoadedMesh, Mesh, SceneError};
use geom::Vec3;
use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// Loads an OBJ file.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    parse(&bytes, path, opts)
}

/// Writes `mesh` as OBJ (`v` and `f` lines, plus `usemtl` where the material changes when
/// the mesh has material names).
pub fn write(mesh: &Mesh, w: &mut impl Write) -> std::io::Result<()> {
    writeln!(w, "# written by arbor")?;
    for p in &mesh.positions {
        writeln!(w, "v {} {} {}", p.x, p.y, p.z)?;
    }
    let mut current = None;
    for (i, t) in mesh.triangles.iter().enumerate() {
        if !mesh.material_names.is_empty() {
            let m = mesh.material_ids.get(i).copied().unwrap_or(0);
            if current != Some(m) {
                let name = mesh.material_names.get(m as usize).map_or("default", |s| s);
                writeln!(w, "usemtl {name}")?;
                current = Some(m);
            }
        }
        writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    Ok(())
}

/// Splits the input into logical lines: `\n` or `\r\n` ended, with `\`-continued physical
/// lines joined by a space. Yields the 1-based number of the first physical line.
struct Lines<'a> {
    data: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Lines<'a> {
    fn physical(&mut self) -> Option<&'a [u8]> {
        if self.pos >= self.data.len() {
            return None;
        }
        let rest = &self.data[self.pos..];
        let n = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += n + 1;
        self.line += 1;
        let l = &rest[..n];
        Some(l.strip_suffix(b"\r").unwrap_or(l))
    }

    fn next(&mut self) -> Option<(usize, Cow<'a, [u8]>)> {
        let first = self.physical()?;
        let no = self.line;
        let Some(head) = first.strip_suffix(b"\\") else {
            return Some((no, Cow::Borrowed(first)));
        };
        let mut joined = head.to_vec();
        while let Some(l) = self.physical() {
            joined.push(b' ');
            match l.strip_suffix(b"\\") {
                Some(h) => joined.extend_from_slice(h),
                None => {
                    joined.extend_from_slice(l);
                    break;
                }
            }
        }
        Some((no, Cow::Owned(joined)))
    }
}

#[inline]
fn is_space(b: u8) -> bool {
    b == b' ' || b == b'\t' || b == b'\x0c'
}

fn words(l: &[u8]) -> impl Iterator<Item = &[u8]> {
    l.split(|&b| is_space(b)).filter(|w| !w.is_empty())
}

fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(32)]).into_owned();
    if tok.len() > 32 {
        s + "..."
    } else {
        s
    }
}

/// Parses OBJ file contents; `path` only names the file in errors.
pub fn parse(bytes: &[u8], path: &Path, opts: &LoadOptions) -> Result<LoadedMesh, SceneError> {
    let mut progress = Progress::new(opts, bytes.len() as u64);
    let mut lines = Lines {
        data: bytes,
        pos: 0,
        line: 0,
    };
    // A line is at least two bytes, so these bounds keep the first allocation honest.
    let mut positions: Vec<Vec3> = Vec::with_capacity((bytes.len() / 64).min(1 << 20));
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity((bytes.len() / 64).min(1 << 20));
    let mut material_ids: Vec<u32> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    let mut by_name: HashMap<String, u32> = HashMap::new();
    let mut current: Option<u32> = None;
    let mut any_usemtl = false;
    // Groups (`g` / `o`), kept as materials when the file has no `usemtl`.
    let mut group_ids: Vec<u32> = Vec::new();
    let mut group_names: Vec<String> = Vec::new();
    let mut group_by_name: HashMap<String, u32> = HashMap::new();
    let mut current_group: Option<u32> = None;
    let mut any_group = false;
    let mut polygons = 0usize;
    let mut poly: Vec<u32> = Vec::with_capacity(16);
    let mut count = 0usize;

    while let Some((no, line)) = lines.next() {
        count += 1;
        if count & 4095 == 0 {
            progress.at(lines.pos);
        }
        let line: &[u8] = &line;
        let line = match line.iter().position(|&b| b == b'#') {
            Some(i) => &line[..i],
            None => line,
        };
        let err = |m: String| SceneError::malformed(path, format!("line {no}: {m}"));
        let mut w = words(line);
        let Some(kw) = w.next() else { continue };
        match kw {
            b"v" => {
                let mut xyz = [0f32; 3];
                for c in &mut xyz {
                    let t = w
                        .next()
                        .ok_or_else(|| err("'v' needs three coordinates".into()))?;
                    *c =
                        parse_f32(t).ok_or_else(|| err(format!("bad coordinate '{}'", show(t))))?;
                }
                if positions.len() >= u32::MAX as usize {
                    return Err(err("more than 2^32-1 vertices".into()));
                }
                positions.push(Vec3::from(xyz));
            }
            b"f" => {
                poly.clear();
                let n = positions.len() as i64;
                for t in w {
                    let v = t.split(|&b| b == b'/').next().unwrap_or(t);
                    let k = parse_int(v)
                        .ok_or_else(|| err(format!("bad face vertex '{}'", show(t))))?;
                    let idx = if k > 0 { k - 1 } else { n + k };
                    if k == 0 || idx < 0 || idx >= n {
                        return Err(err(format!(
                            "face vertex index {k} out of range ({n} vertices defined so far)"
                        )));
                    }
                    poly.push(idx as u32);
                }
                if poly.len() < 3 {
                    return Err(err(format!(
                        "face has {} vertices (need at least 3)",
                        poly.len()
                    )));
                }
                if poly.len() > 3 {
                    polygons += 1;
                }
                let m = match current {
                    Some(m) => m,
                    None => {
                        let m = intern(&mut names, &mut by_name, "default");
                        current = Some(m);
                        m
                    }
                };
                let g = match current_group {
                    Some(g) => g,
                    None => {
                        let g = intern(&mut group_names, &mut group_by_name, "default");
                        current_group = Some(g);
                        g
                    }
                };
                for i in 1..poly.len() - 1 {
                    triangles.push([poly[0], poly[i], poly[i + 1]]);
                    material_ids.push(m);
                    group_ids.push(g);
                }
            }
            b"usemtl" => {
                // The name is the rest of the line, spaces included.
                let rest = line
                    .trim_ascii_start()
                    .strip_prefix(b"usemtl")
                    .unwrap_or(b"");
                let name = String::from_utf8_lossy(rest.trim_ascii()).into_owned();
                if name.is_empty() {
                    return Err(err("'usemtl' without a material name".into()));
                }
                any_usemtl = true;
                current = Some(intern(&mut names, &mut by_name, &name));
            }
            b"g" | b"o" => {
                // `g a b` puts faces in several groups; the first name identifies it. A
                // bare `g` returns to the default group.
                let name = w
                    .next()
                    .map(|n| String::from_utf8_lossy(n).into_owned())
                    .unwrap_or_else(|| "default".to_string());
                any_group = true;
                current_group = Some(intern(&mut group_names, &mut group_by_name, &name));
            }
            _ => {}
        }
    }
    if !any_usemtl {
        if any_group {
            material_ids = group_ids;
            names = group_names;
        } else {
            // Only the implicit "default" material: report no materials at all.
            names.clear();
        }
    }
    progress.done();
    Ok(finish_mesh(
        positions,
        triangles,
        material_ids,
        names,
        polygons,
    ))
}

fn intern(names: &mut Vec<String>, by_name: &mut HashMap<String, u32>, name: &str) -> u32 {
    if let Some(&m) = by_name.get(name) {
        return m;
    }
    let m = names.len() as u32;
    names.push(name.to_string());
    by_name.insert(name.to_string(), m);
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p() -> &'static Path {
        Path::new("test.obj")
    }

    fn parse_ok(b: &[u8]) -> LoadedMesh {
        let m = parse(b, p(), &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        m.mesh.check().unwrap();
        m
    }

    fn parse_err(b: &[u8]) -> String {
        match parse(b, p(), &LoadOptions::default()) {
            Ok(m) => panic!("parsed: {} triangles", m.mesh.triangle_count()),
            Err(e) => {
                let s = e.to_string();
                assert!(s.contains("test.obj") && !s.contains('\n'), "{s}");
                s
            }
        }
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn face_forms_and_relative_indices() {
        for f in [
            "f 1 2 3",
            "f 1/1 2/2 3/3",
            "f 1//4 2//4 3//4",
            "f 1/2/3 2/2/3 3/1/1",
            "f -4 -3 -2",
        ] {
            let m = parse_ok(format!("{SQUARE}{f}\n").as_bytes());
            assert_eq!(m.mesh.triangles, vec![[0, 1, 2]], "{f}");
            assert!(m.mesh.material_names.is_empty());
        }
    }

    #[test]
    fn polygons_comments_continuations_crlf() {
        let src: &[u8] = b"# comment \xff\r\nmtllib x.mtl\r\n\r\nv 0 0 0 1.0\r\nv 1 0 0\r\nv 1 1 0 # trailing\r\n\
                   v 0 1 0\r\nvt 0 0\r\nvn 0 0 1\r\ns off\r\ng grp\r\no obj\r\nl 1 2\r\np 1\r\n\
                   f 1 2 \\\r\n 3 4\r\n";
        let m = parse_ok(src);
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.polygons_triangulated, 1);
        assert_eq!(m.mesh.positions[2], Vec3::new(1.0, 1.0, 0.0));
    }

    #[test]
    fn groups_become_materials_without_usemtl() {
        let m = parse_ok(
            format!("{SQUARE}f 1 2 3\ng wall brick\nf 1 2 3\no lamp\nf 1 3 4\ng wall\nf 2 3 4\n")
                .as_bytes(),
        );
        assert_eq!(m.mesh.material_names, ["default", "wall", "lamp"]);
        assert_eq!(m.mesh.material_ids, [0, 1, 2, 1]);
        // With usemtl present, materials win and groups are not used.
        let m = parse_ok(format!("{SQUARE}g a\nusemtl x\nf 1 2 3\ng b\nf 1 3 4\n").as_bytes());
        assert_eq!(m.mesh.material_names, ["x"]);
        assert_eq!(m.mesh.material_ids, [0, 0]);
    }

    #[test]
    fn materials_by_usemtl() {
        let src = format!(
            "{SQUARE}f 1 2 3\nusemtl stone\nf 1 2 3\nusemtl wood floor\nf 1 3 4\nusemtl stone\nf 2 3 4\n"
        );
        let m = parse_ok(src.as_bytes());
        assert_eq!(
            m.mesh.material_names,
            vec!["default", "stone", "wood floor"]
        );
        assert_eq!(m.mesh.material_ids, vec![0, 1, 2, 1]);
        // No face before the first usemtl: no "default".
        let m = parse_ok(format!("{SQUARE}usemtl a\nf 1 2 3 4\n").as_bytes());
        assert_eq!(m.mesh.material_names, vec!["a"]);
        assert_eq!(m.mesh.material_ids, vec![0, 0]);
    }

    #[test]
    fn malformed_lines() {
        let e = parse_err(format!("{SQUARE}f 1 2 5\n").as_bytes());
        assert!(e.contains("line 5") && e.contains("out of range"), "{e}");
        assert!(parse_err(format!("{SQUARE}f 0 1 2\n").as_bytes()).contains("index 0"));
        assert!(parse_err(format!("{SQUARE}f -5 1 2\n").as_bytes()).contains("index -5"));
        assert!(parse_err(format!("{SQUARE}f 1 2\n").as_bytes()).contains("2 vertices"));
        assert!(parse_err(format!("{SQUARE}f 1 2 x\n").as_bytes()).contains("bad face vertex 'x'"));
        assert!(
            parse_err(format!("{SQUARE}f 1 2 99999999999999999999\n").as_bytes())
                .contains("bad face")
        );
        assert!(parse_err(b"v 1 2\n").contains("three coordinates"));
        assert!(parse_err(b"v 1 2 \xff\n").contains("line 1: bad coordinate"));
        assert!(parse_err(b"f 1 2 3\nv 0 0 0\n").contains("out of range"));
        assert!(parse_err(b"usemtl   \n").contains("material name"));
    }

    #[test]
    fn empty_and_degenerate() {
        let m = parse_ok(b"");
        assert_eq!(m.mesh.triangle_count(), 0);
        let m = parse_ok(b"v 0 0 0\nf 1 1 1\n");
        assert_eq!(m.mesh.triangle_count(), 1);
        assert_eq!(m.mesh.degenerate_count(), 1);
        // A continuation at end of file.
        let m = parse_ok(b"v 0 0 0\\");
        assert_eq!(m.mesh.positions.len(), 1);
    }

    #[test]
    fn nan_drops_triangles() {
        let m = parse_ok(format!("{SQUARE}v nan 0 0\nf 1 2 3\nf 1 2 5\nf 1 2 -1\n").as_bytes());
        assert_eq!(m.dropped_triangles, 2);
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2]]);
        assert_eq!(m.mesh.material_ids, vec![0]);
    }

    #[test]
    fn horse_frame() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/scenes/horse-gallop/0001.obj");
        if !path.exists() {
            eprintln!("skipping: {} not found", path.display());
            return;
        }
        let m = load(&path, &LoadOptions::default()).unwrap();
        m.mesh.check().unwrap();
        assert_eq!(m.mesh.triangle_count(), 16_843);
        assert_eq!(m.dropped_triangles, 0);
    }

    #[test]
    fn fuzz_seeds_parse() {
        // The fuzzers' seed files are valid and must stay so.
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/seeds/obj");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let path = e.unwrap().path();
            let l = parse_ok(&std::fs::read(&path).unwrap());
            assert!(l.mesh.triangle_count() > 0, "{}", path.display());
            n += 1;
        }
        assert!(n >= 2);
    }

    proptest! {
        #[test]
        fn prop_roundtrip(
            pos in proptest::collection::vec(proptest::array::uniform3(-1e6f32..1e6), 1..30),
            tris in proptest::collection::vec((proptest::array::uniform3(any::<u32>()), 0u32..3), 0..40),
        ) {
            let n = pos.len() as u32;
            let names: Vec<String> = ["a", "b c", "d"].iter().map(|s| s.to_string()).collect();
            let mut m = Mesh {
                positions: pos.into_iter().map(Vec3::from).collect(),
                triangles: tris.iter().map(|(t, _)| t.map(|i| i % n)).collect(),
                material_ids: tris.iter().map(|&(_, m)| m).collect(),
                material_names: names,
            };
            let mut b = Vec::new();
            write(&m, &mut b).unwrap();
            let l = parse_ok(&b);
            // Names come back in order of first use; compare by name.
            prop_assert_eq!(&l.mesh.positions, &m.positions);
            prop_assert_eq!(&l.mesh.triangles, &m.triangles);
            let got: Vec<&str> = l.mesh.material_ids.iter().map(|&i| l.mesh.material_names[i as usize].as_str()).collect();
            let want: Vec<&str> = m.material_ids.iter().map(|&i| m.material_names[i as usize].as_str()).collect();
            prop_assert_eq!(got, want);
            m.material_names.clear();
            m.material_ids.iter_mut().for_each(|i| *i = 0);
            let mut b = Vec::new();
            write(&m, &mut b).unwrap();
            prop_assert_eq!(parse_ok(&b).mesh, m);
        }

        #[test]
        fn prop_garbage_never_panics(src in proptest::collection::vec(prop_oneof![
            Just(b"v ".to_vec()), Just(b"f ".to_vec()), Just(b"usemtl m".to_vec()), Just(b"1".to_vec()),
            Just(b"-1".to_vec()), Just(b"/".to_vec()), Just(b" ".to_vec()), Just(b"\n".to_vec()),
            Just(b"\\".to_vec()), Just(b"#".to_vec()), Just(b"\r".to_vec()), Just(b"nan".to_vec()),
            Just(b"0.5".to_vec()), any::<u8>().prop_map(|b| vec![b])], 0..200)) {
            let bytes: Vec<u8> = src.concat();
            if let Ok(l) = parse(&bytes, p(), &LoadOptions::default()) {
                prop_assert!(l.mesh.check().is_ok());
            }
        }
    }
}
