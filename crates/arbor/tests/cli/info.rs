//! Integration tests of `arbor info` and `arbor demo`: the binary as a user runs it.

use crate::common::arbor;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Runs `arbor info --json` and parses its output, failing with stderr on error.
fn info_json(args: &[&str]) -> Value {
    crate::common::json("info", args)
}

/// Runs `arbor info` expecting failure; returns the single stderr line.
fn info_error(path: &Path) -> String {
    let out = arbor(&["info", path.to_str().unwrap()]);
    assert!(
        !out.status.success(),
        "arbor info {} succeeded",
        path.display()
    );
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {err}");
    assert!(!err.contains("panicked"), "{err}");
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(err.contains(name), "error does not name the file: {err}");
    err
}

fn shared_scenes() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

fn bounds(v: &Value) -> Vec<f64> {
    let b = &v["bounds"];
    b["min"]
        .as_array()
        .unwrap()
        .iter()
        .chain(b["max"].as_array().unwrap())
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[test]
fn bundled_scene_info_is_animated_and_stable() {
    let bundled = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/CesiumMan.glb");
    let j = info_json(&[bundled.to_str().unwrap()]);
    assert_eq!(j["schema"], "arbor.info.v1");
    assert_eq!(j["triangles"], 4672);
    assert_eq!(j["format"], "gltf");
    assert!(j["frames"].as_u64().unwrap() > 1);
    assert!(j["duration_s"].as_f64().unwrap() > 0.0);
    assert_eq!(j["stable_topology"], true);
    let b = bounds(&j);
    assert!(b[3] > b[0] && b[4] > b[1] && b[5] > b[2]);
}

#[test]
fn text_output_names_the_essentials() {
    let out = arbor(&["info", "proc:cloth?n=2000"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = String::from_utf8_lossy(&out.stdout);
    for key in ["triangles", "bounds", "frames", "load"] {
        assert!(s.contains(key), "missing {key} in:\n{s}");
    }
}

#[test]
fn every_shared_scene_loads() {
    let Some(dir) = shared_scenes() else { return };
    let expected = [
        ("bunny.ply", 69_451),
        ("sibenik.ply", 75_284),
        ("crytek-sponza.ply", 262_205),
        ("conference.ply", 331_179),
        ("dragon.ply", 871_414),
        ("dragon-res2.ply", 202_520),
        ("horse-gallop", 16_843),
        ("gltf/BrainStem.glb", 61_666),
        ("gltf/CesiumMan.glb", 4_672),
        ("gltf/Fox.glb", 576),
        ("gltf/RiggedFigure.glb", 256),
        ("gltf/RiggedSimple.glb", 188),
    ];
    for (name, tris) in expected {
        let p = dir.join(name);
        let j = info_json(&[p.to_str().unwrap()]);
        assert_eq!(j["triangles"], tris, "{name}");
        assert!(j["bounds"].is_object(), "{name}");
    }
    let horse = info_json(&[dir.join("horse-gallop").to_str().unwrap(), "--frame", "47"]);
    assert_eq!(horse["frames"], 48);
    assert_eq!(horse["format"], "keyframes");
}

#[test]
fn skinned_gltf_bounds_move_over_time() {
    let Some(dir) = shared_scenes() else { return };
    for name in [
        "BrainStem.glb",
        "CesiumMan.glb",
        "Fox.glb",
        "RiggedFigure.glb",
        "RiggedSimple.glb",
    ] {
        let p = dir.join("gltf").join(name);
        let p = p.to_str().unwrap();
        let d = info_json(&[p])["duration_s"].as_f64().unwrap();
        let times = [0.0, d * 0.25, d * 0.5, d * 0.75];
        let all: Vec<Vec<f64>> = times
            .iter()
            .map(|t| bounds(&info_json(&[p, "--time", &t.to_string()])))
            .collect();
        assert!(
            all.windows(2).any(|w| w[0] != w[1]),
            "{name}: bounds never move: {all:?}"
        );
    }
}

#[test]
fn procedural_scenes_at_two_sizes() {
    for name in ["cloth", "skinned", "explode", "fluid", "forest", "soup"] {
        let small = info_json(&[&format!("proc:{name}?n=2000&seed=3")]);
        let large = info_json(&[&format!("proc:{name}?n=40000&seed=3")]);
        let (s, l) = (
            small["triangles"].as_u64().unwrap(),
            large["triangles"].as_u64().unwrap(),
        );
        assert!(s > 0 && l > 4 * s, "{name}: {s} then {l} triangles");
        assert_eq!(small["format"], "procedural");
        // Determinism: the same spec gives the same answer.
        let again = info_json(&[&format!("proc:{name}?n=2000&seed=3")]);
        assert_eq!(bounds(&small), bounds(&again), "{name}");
    }
}

#[test]
fn bad_specs_and_arguments_fail_cleanly() {
    for spec in [
        "proc:nosuchscene",
        "proc:cloth?n=abc",
        "proc:cloth?bogus=1",
        "proc:soup?n=1000000000000",
    ] {
        let out = arbor(&["info", spec]);
        assert_eq!(out.status.code(), Some(1), "{spec}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.lines().count(), 1, "{spec}: {err}");
    }
    let out = arbor(&["info", "proc:cloth?n=1000", "--frame", "100000"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("out of range"));
    let out = arbor(&["info", "proc:cloth?n=1000", "--time", "NaN"]);
    assert_eq!(out.status.code(), Some(1));
}

/// Writes `bytes` to a file named `name` in `dir`.
fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn malformed_files_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply_head = |fmt: &str, nv: &str, nf: &str| {
        format!(
            "ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
        )
    };
    let mut truncated = ply_head("binary_little_endian", "3", "1").into_bytes();
    truncated.extend_from_slice(&[0u8; 20]);
    let mut bad_index = ply_head("binary_little_endian", "3", "1").into_bytes();
    bad_index.extend_from_slice(&[0u8; 36]);
    bad_index.push(3);
    for i in [0i32, 1, 7] {
        bad_index.extend_from_slice(&i.to_le_bytes());
    }
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty.ply", vec![]),
        ("empty.obj", vec![]),
        ("empty.glb", vec![]),
        ("garbage.ply", b"\xff\xfe\x00not a ply".to_vec()),
        ("truncated.ply", truncated),
        ("huge-count.ply", {
            let mut v = ply_head("binary_little_endian", "999999999999", "999999999999").into_bytes();
            v.extend_from_slice(&[0u8; 64]);
            v
        }),
        ("bad-index.ply", bad_index),
        ("bad-index-ascii.ply", (ply_head("ascii", "3", "1") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n").into_bytes()),
        ("bad-index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec()),
        ("zero-index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n".to_vec()),
        ("bad-number.obj", b"v 0 zero 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec()),
        ("truncated.glb", b"glTF\x02\x00\x00\x00\xff\xff\x00\x00".to_vec()),
        ("bad-json.gltf", b"{\"asset\": {\"version\": \"2.0\"".to_vec()),
        (
            "missing-bin.gltf",
            br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"nothere.bin","byteLength":36}],"bufferViews":[{"buffer":0,"byteLength":36}],"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#.to_vec(),
        ),
    ];
    for (name, bytes) in cases {
        let p = write(d, name, &bytes);
        let err = info_error(&p);
        assert!(err.starts_with("arbor: error:"), "{name}: {err}");
    }
}

#[test]
fn nan_vertices_are_dropped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "nan.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 0 0 inf\nf 1 2 3\nf 1 2 4\nf 5 2 3\n",
    );
    let out = arbor(&["info", "--json", p.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["triangles"], 1);
    assert_eq!(j["dropped_triangles"], 2);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warning") && err.contains("dropped 2"),
        "{err}"
    );
}

#[test]
fn degenerate_triangles_load_and_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "degenerate.obj",
        b"v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 1\nf 1 2 4\n",
    );
    let j = info_json(&[p.to_str().unwrap()]);
    assert_eq!(j["triangles"], 3);
    assert_eq!(j["degenerate_triangles"], 2);
}

#[test]
fn empty_but_valid_scene_has_null_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "comments.obj", b"# nothing but a comment\n");
    let j = info_json(&[p.to_str().unwrap()]);
    assert_eq!(j["triangles"], 0);
    assert!(j["bounds"].is_null());
}

#[test]
fn demo_runs_and_writes_its_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = arbor(&[
        "demo",
        "--quiet",
        "--frames",
        "5",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(s.contains("CesiumMan") && s.contains("4,672"), "{s}");
    // The demo's own page: its renders, plots and tables, with the command that made it.
    let page = std::fs::read_to_string(out_dir.join("index.html")).unwrap();
    for want in [
        "src=\"render-primary.png\"",
        "src=\"heatmap-primary.png\"",
        "src=\"mergetree-lpddr3-1600-1x64.svg\"",
        "href=\"summary.json\"",
        "Command: <code>arbor demo --frames 5 --out",
        "<h3>Renders: primary and diffuse rays",
    ] {
        assert!(page.contains(want), "{want} not in the demo's page");
    }
    assert!(out_dir.join("style.css").is_file());
    let summary: Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["schema"], "arbor.demo.v1");
    assert_eq!(summary["frames"].as_array().unwrap().len(), 5);
    // The rebuild-vs-refit step: refitting frame 0's tree to frame 0 changes nothing.
    let refits = summary["refits"].as_array().unwrap();
    assert!(refits.len() >= 2, "{refits:?}");
    assert_eq!(refits[0]["frame"], 0);
    assert_eq!(refits[0]["refit_sah"], refits[0]["rebuild_sah"]);
    assert_eq!(refits[0]["ratio_to_build"], 1.0);
    let csv = std::fs::read_to_string(out_dir.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 6);
    // The MergeTree step: three memory systems, the software tree, slower on slower memory.
    let mt = summary["mergetree"].as_array().unwrap();
    assert_eq!(mt.len(), 3);
    for row in mt {
        assert_eq!(row["tree_matches_software"], true);
        assert_eq!(row["triangles"], 4672);
        assert!(std::path::Path::new(row["svg"].as_str().unwrap()).exists());
    }
    assert!(mt[0]["cycles"].as_u64() > mt[2]["cycles"].as_u64());
    // The bundled scene is recorded by name, not by a path compiled into the binary or
    // a temporary file.
    assert_eq!(summary["info"]["scene"], "CesiumMan.glb (bundled)");
    let text = std::fs::read_to_string(out_dir.join("summary.json")).unwrap();
    assert!(!text.contains(env!("CARGO_MANIFEST_DIR")), "{text}");
    assert!(!text.contains("arbor-scene-"), "{text}");
    // The diffuse picture shows the scene: neither mostly white nor mostly black.
    let (w, h, rgb) = read_png(&out_dir.join("render-diffuse.png"));
    let n = (w * h) as usize;
    let lum: Vec<u32> = rgb
        .chunks(3)
        .map(|p| (2126 * p[0] as u32 + 7152 * p[1] as u32 + 722 * p[2] as u32) / 10000)
        .collect();
    let bright = lum.iter().filter(|&&l| l >= 250).count();
    let dark = lum.iter().filter(|&&l| l < 5).count();
    assert!(bright * 2 < n, "{bright} of {n} pixels white");
    assert!(dark * 2 < n, "{dark} of {n} pixels black");
    // And the figure (about 5% of the picture) is lit: lighter than any of the backdrop.
    let lit = lum.iter().filter(|&&l| l >= 150).count();
    assert!(lit * 40 > n, "only {lit} of {n} pixels lit");
}

/// A PNG's width, height and 8-bit RGB pixels.
fn read_png(p: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::fs::File::open(p).unwrap());
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}
