//! Integration tests of `arbor build`: every available builder on a procedural scene and the
//! bundled glTF scene, tree files read back with `bvh::io`, and every bad-argument case.

use crate::common::arbor;
use serde_json::Value;
use std::path::Path;

/// Every builder of `arbor build`: twelve binary, then the four 4-wide ones.
const BUILDERS: [&str; 16] = [
    "lbvh",
    "hlbvh",
    "hlbvh-large",
    "hlbvh+sah",
    "hlbvh+atrbvh",
    "hlbvh+atrbvh-cells",
    "binned-sah",
    "sweep-sah",
    "atrbvh",
    "ploc",
    "ploc+reinsert",
    "hlbvh+reinsert",
    "mbvh4-collapse",
    "mbvh4-stream",
    "mbvh4-stream-w4",
    "mbvh4-topdown",
];

/// True for the builders of 4-wide trees.
fn wide(builder: &str) -> bool {
    builder.starts_with("mbvh4-")
}
const CLOTH: &str = "proc:cloth?n=5000";
const BUNDLED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/CesiumMan.glb");

/// Runs `arbor build --json --quiet ARGS` and parses its output, failing with stderr.
fn build_json(args: &[&str]) -> Value {
    crate::common::json("build", args)
}

/// Runs `arbor build ARGS` expecting exit 1 with a one-line error; returns that line.
fn build_error(args: &[&str]) -> String {
    let mut a = vec!["build"];
    a.extend_from_slice(args);
    let out = arbor(&a);
    assert_eq!(
        out.status.code(),
        Some(1),
        "arbor {a:?} did not fail with 1"
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.lines().count(), 1, "expected one line, got: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.stdout.is_empty(), "printed a result on failure");
    err
}

fn check_doc(j: &Value, scene: &str, builder: &str) {
    assert_eq!(j["schema"], "arbor.build.v1");
    assert_eq!(j["builder"], builder);
    assert_eq!(j["valid"], true);
    let tris = j["triangles"].as_u64().unwrap();
    assert!(tris > 0, "{scene}");
    let leaves = j["leaves"].as_u64().unwrap();
    let inner = j["inner_nodes"].as_u64().unwrap();
    let children = j["mean_children"].as_f64().unwrap();
    if wide(builder) {
        // Every node below the root has 2..=4 children: between (leaves - 1) / 3 and
        // leaves - 1 nodes.
        assert_eq!(
            (
                j["tree_kind"].as_str(),
                j["width"].as_u64(),
                j["node_bytes"].as_u64()
            ),
            (Some("Mbvh4"), Some(4), Some(128))
        );
        assert!(
            3 * inner + 1 >= leaves && inner < leaves,
            "{scene} {builder}"
        );
        assert!(children > 2.0 && children <= 4.0, "{children}");
        let tree_bytes = j["tree_bytes"].as_u64().unwrap();
        assert_eq!(tree_bytes, 128 * inner + 4 * tris);
    } else {
        // A binary tree: one inner node fewer than leaves (or one root for a single leaf).
        assert_eq!(inner, (leaves - 1).max(1), "{scene} {builder}");
        assert_eq!(
            (
                j["tree_kind"].as_str(),
                j["width"].as_u64(),
                j["node_bytes"].as_u64()
            ),
            (Some("Bvh2"), Some(2), Some(64))
        );
        assert_eq!(children, 2.0);
    }
    assert_eq!(
        j["collapse_from"].as_str(),
        (builder == "mbvh4-collapse").then_some("binned-sah")
    );
    assert!(leaves <= tris);
    let max_leaf = j["max_leaf_size"].as_u64().unwrap();
    assert!((1..=8).contains(&max_leaf));
    if builder == "lbvh" {
        assert_eq!(max_leaf, 1);
        assert_eq!(leaves, tris);
    }
    assert!(j["max_depth"].as_u64().unwrap() >= 1);
    assert!(j["sah"].as_f64().unwrap() > 0.0);
    let ratio = j["sah_vs_sweep"].as_f64().unwrap();
    if builder == "sweep-sah" {
        assert_eq!(ratio, 1.0);
    } else if builder == "mbvh4-topdown" {
        // Its leaves are chosen for the 4-wide cost the ratio is computed with (binary
        // sweep SAH's leaves are not), so it may come out a little below it: 0.988 on the
        // bundled character.
        assert!(ratio >= 0.95, "{scene} {builder}: {ratio}");
    } else {
        assert!(ratio >= 0.99, "{scene} {builder}: {ratio}");
    }
    assert!(j["build_ms"].as_f64().unwrap() >= 0.0);
    assert!(j["aabb_ms"].as_f64().unwrap() >= 0.0);
    assert!(j["threads"].as_u64().unwrap() >= 1);
}

#[test]
fn every_builder_on_cloth_and_bundled_scene() {
    for scene in [CLOTH, BUNDLED] {
        for b in BUILDERS {
            let j = build_json(&[scene, "--builder", b]);
            check_doc(&j, scene, b);
        }
    }
    // Frames and threads are honoured.
    let j = build_json(&[
        BUNDLED,
        "--builder",
        "lbvh",
        "--frame",
        "3",
        "--threads",
        "1",
    ]);
    assert_eq!(j["frame"], 3);
    assert_eq!(j["threads"], 1);
    assert!(j["time_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn binned_bins_and_max_leaf_are_honoured() {
    for bins in ["8", "32"] {
        let j = build_json(&[CLOTH, "--builder", "binned-sah", "--bins", bins]);
        assert_eq!(j["bins"].to_string(), bins);
    }
    let j = build_json(&[CLOTH, "--builder", "sweep-sah", "--max-leaf", "2"]);
    assert!(j["max_leaf_size"].as_u64().unwrap() <= 2);
    assert_eq!(j["max_leaf_limit"], 2);
}

#[test]
fn out_file_reads_back_as_the_built_tree() {
    let dir = tempfile::tempdir().unwrap();
    for b in BUILDERS {
        let path = dir.path().join(format!("{b}.bvh"));
        let p = path.to_str().unwrap();
        let j = build_json(&[CLOTH, "--builder", b, "--out", p]);
        let (tree, header) = bvh::io::read_tree_file(&path).unwrap();
        assert_eq!(header.builder, b);
        assert_eq!(header.kind, tree.kind());
        assert_eq!(tree.kind().width() as u64, j["width"].as_u64().unwrap());
        assert_eq!(tree.node_count() as u64, j["inner_nodes"].as_u64().unwrap());
        assert_eq!(tree.prim_count() as u64, j["triangles"].as_u64().unwrap());
        assert_eq!(header.sah, tree.normalized_sah());
        // serde_json parses floats to within an ulp, not bit-exactly.
        let sah = tree.normalized_sah();
        assert!((sah - j["sah"].as_f64().unwrap()).abs() <= 1e-12 * sah);
        // Node for node equal to a build of the same mesh through the library.
        let scene = scene::open(CLOTH, &Default::default()).unwrap();
        let mesh = scene.mesh_at(0.0).unwrap();
        let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).unwrap();
        let binned = bvh::BinnedSahBuilder::default().build(&aabbs).unwrap();
        let expect: bvh::Tree = match b {
            "lbvh" => bvh::LbvhBuilder::default().build(&aabbs).unwrap().into(),
            "binned-sah" => binned.into(),
            "atrbvh" => bvh::AtrbvhBuilder::default().build(&aabbs).unwrap().into(),
            "hlbvh" => bvh::HlbvhBuilder::default().build(&aabbs).unwrap().into(),
            "hlbvh-large" => bvh::HlbvhBuilder {
                large_prims: Some(0.5),
                ..Default::default()
            }
            .build(&aabbs)
            .unwrap()
            .into(),
            "hlbvh+sah" => bvh::HlbvhSahBuilder::default()
                .build(&aabbs)
                .unwrap()
                .into(),
            "hlbvh+atrbvh" => bvh::HlbvhAtrbvhBuilder::default()
                .build(&aabbs)
                .unwrap()
                .into(),
            "hlbvh+atrbvh-cells" => bvh::HlbvhAtrbvhBuilder {
                cells: Some(bvh::AtrbvhConfig {
                    iterations: 1,
                    ..Default::default()
                }),
                ..Default::default()
            }
            .build(&aabbs)
            .unwrap()
            .into(),
            "sweep-sah" => bvh::SweepSahBuilder::default()
                .build(&aabbs)
                .unwrap()
                .into(),
            "ploc" => bvh::PlocBuilder::default().build(&aabbs).unwrap().into(),
            "ploc+reinsert" | "hlbvh+reinsert" => {
                let mut t = if b == "ploc+reinsert" {
                    let one = bvh::PlocBuilder {
                        max_leaf_size: 1,
                        ..Default::default()
                    };
                    one.build(&aabbs).unwrap()
                } else {
                    bvh::HlbvhBuilder::default().build(&aabbs).unwrap()
                };
                bvh::reinsert(&mut t, &aabbs, &Default::default()).unwrap();
                t.into()
            }
            "mbvh4-collapse" => bvh::collapse(&binned).unwrap().into(),
            "mbvh4-stream" | "mbvh4-stream-w4" => {
                let hl = bvh::HlbvhBuilder::default()
                    .build_highlevel(&aabbs)
                    .unwrap();
                let sc = if b == "mbvh4-stream" {
                    bvh::StreamCollapse::new()
                } else {
                    bvh::StreamCollapse::with_window(4)
                };
                bvh::stream_collapse_with(&hl, sc).unwrap().0.into()
            }
            "mbvh4-topdown" => bvh::Mbvh4TopDownBuilder::default()
                .build(&aabbs)
                .unwrap()
                .into(),
            other => panic!("no library reference for builder {other}"),
        };
        assert_eq!(tree, expect, "{b}");
        assert_eq!(tree.validate(&aabbs, 8), Ok(()));
        // The single-kind readers accept exactly their kind.
        assert_eq!(bvh::io::read_bvh2_file(&path).is_ok(), !wide(b));
        assert_eq!(bvh::io::read_mbvh4_file(&path).is_ok(), wide(b));
    }
    // Collapsing another binary builder's tree, and the 4-wide builder's bins.
    let path = dir.path().join("c.bvh");
    let j = build_json(&[
        CLOTH,
        "--builder",
        "mbvh4-collapse",
        "--collapse-from",
        "hlbvh",
        "--out",
        path.to_str().unwrap(),
    ]);
    assert_eq!(j["collapse_from"], "hlbvh");
    let scene = scene::open(CLOTH, &Default::default()).unwrap();
    let mesh = scene.mesh_at(0.0).unwrap();
    let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).unwrap();
    let hl = bvh::HlbvhBuilder::default().build(&aabbs).unwrap();
    let (back, _) = bvh::io::read_mbvh4_file(&path).unwrap();
    assert_eq!(back, bvh::collapse(&hl).unwrap());
    let j = build_json(&[CLOTH, "--builder", "mbvh4-topdown", "--bins", "8"]);
    assert_eq!(j["bins"], 8);
}

#[test]
fn bad_arguments_are_one_line_errors() {
    let e = build_error(&[CLOTH, "--builder", "nope"]);
    assert!(
        e.contains("unknown builder") && e.contains("binned-sah"),
        "{e}"
    );
    let e = build_error(&[CLOTH, "--builder", "lbvh", "--collapse-from", "lbvh"]);
    assert!(e.contains("--collapse-from applies only"), "{e}");
    for bad in ["mbvh4-topdown", "nope"] {
        let e = build_error(&[CLOTH, "--builder", "mbvh4-collapse", "--collapse-from", bad]);
        assert!(e.contains(bad) && e.contains("binned-sah"), "{e}");
    }
    let e = build_error(&[CLOTH, "--builder", "lbvh", "--threads", "0"]);
    assert!(e.contains("--threads"), "{e}");
    let e = build_error(&[CLOTH, "--builder", "lbvh", "--threads", "100000"]);
    assert!(e.contains("--threads"), "{e}");
    let e = build_error(&[CLOTH, "--builder", "sweep-sah", "--max-leaf", "0"]);
    assert!(e.contains("--max-leaf"), "{e}");
    let e = build_error(&[CLOTH, "--builder", "binned-sah", "--bins", "12"]);
    assert!(e.contains("--bins"), "{e}");
    let e = build_error(&[CLOTH, "--builder", "lbvh", "--bins", "16"]);
    assert!(e.contains("binned-sah"), "{e}");
    let e = build_error(&[
        "proc:fluid?n=2000",
        "--builder",
        "lbvh",
        "--refit-from",
        "0",
    ]);
    assert!(e.contains("stable topology"), "{e}");
    let e = build_error(&[CLOTH, "--builder", "lbvh", "--refit-from", "inf"]);
    assert!(e.contains("--refit-from"), "{e}");
    let e = build_error(&[BUNDLED, "--builder", "lbvh", "--frame", "100000"]);
    assert!(e.contains("out of range"), "{e}");
    let e = build_error(&["no/such/file.ply", "--builder", "lbvh"]);
    assert!(e.contains("file.ply"), "{e}");
}

#[test]
fn unwritable_out_never_leaves_a_partial_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no/such/dir/t.bvh");
    let e = build_error(&[
        CLOTH,
        "--builder",
        "lbvh",
        "--out",
        missing.to_str().unwrap(),
    ]);
    assert!(e.contains("t.bvh"), "{e}");
    let e = build_error(&[
        CLOTH,
        "--builder",
        "lbvh",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(e.contains("directory"), "{e}");
    // An existing file survives a failing run untouched.
    let keep = dir.path().join("keep.bvh");
    std::fs::write(&keep, b"precious").unwrap();
    build_error(&[
        CLOTH,
        "--builder",
        "lbvh",
        "--threads",
        "0",
        "--out",
        keep.to_str().unwrap(),
    ]);
    assert_eq!(std::fs::read(&keep).unwrap(), b"precious");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    #[cfg(unix)]
    {
        // A read-only folder: the write fails and leaves nothing behind.
        use std::os::unix::fs::PermissionsExt;
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let target = ro.join("t.bvh");
        let out = arbor(&[
            "build",
            CLOTH,
            "--builder",
            "lbvh",
            "--out",
            target.to_str().unwrap(),
        ]);
        // Root can write anywhere; only check when the folder really is read-only.
        if std::fs::File::create(ro.join("probe")).is_err() {
            assert_eq!(out.status.code(), Some(1));
            assert_eq!(std::fs::read_dir(&ro).unwrap().count(), 0);
        }
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
}

#[test]
fn text_output_names_the_numbers() {
    let out = arbor(&["build", "--quiet", CLOTH, "--builder", "binned-sah"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for word in [
        "triangles",
        "inner nodes",
        "SAH",
        "of sweep SAH",
        "valid",
        "build",
    ] {
        assert!(text.contains(word), "missing {word}: {text}");
    }
    assert!(Path::new(BUNDLED).exists());
}

#[test]
fn demo_reports_every_available_builder() {
    let dir = tempfile::tempdir().unwrap();
    let out = arbor(&[
        "demo",
        "--quiet",
        "--frames",
        "4",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("SAH vs sweep"), "{text}");
    let s: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("summary.json")).unwrap()).unwrap();
    let builds = s["builds"].as_array().unwrap();
    // Frames 0..=3 with 4 walked: 0, 1, 2, 3; every available builder at each (those of
    // `BUILDERS` and sbvh, which needs the triangles the demo gives it).
    assert_eq!(builds.len(), 4 * (BUILDERS.len() + 1));
    for b in builds {
        assert_eq!(b["valid"], true);
        let name = b["builder"].as_str().unwrap();
        assert!(BUILDERS.contains(&name) || name == "sbvh", "{name}");
        let r = b["sah_vs_sweep"].as_f64().unwrap();
        if b["builder"] == "sweep-sah" {
            assert_eq!(r, 1.0);
        } else if wide(name) || name == "sbvh" {
            // 4-wide trees count their nodes' costs otherwise; spatial splits can go below
            // the sweep (it only partitions).
            assert!((0.8..2.0).contains(&r), "{b}");
        } else {
            assert!(r >= 0.99, "{b}");
        }
    }
}

#[test]
fn empty_and_single_triangle_scenes_build() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.obj");
    std::fs::write(&empty, "# no triangles\n").unwrap();
    let one = dir.path().join("one.obj");
    std::fs::write(&one, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    for b in BUILDERS {
        let out = dir.path().join("t.bvh");
        let j = build_json(&[
            empty.to_str().unwrap(),
            "--builder",
            b,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(
            (j["triangles"].as_u64(), j["leaves"].as_u64()),
            (Some(0), Some(0))
        );
        assert_eq!(j["valid"], true);
        let empty: bvh::Tree = if wide(b) {
            bvh::Mbvh4::empty().into()
        } else {
            bvh::Bvh2::empty().into()
        };
        assert_eq!(bvh::io::read_tree_file(&out).unwrap().0, empty);
        let j = build_json(&[
            one.to_str().unwrap(),
            "--builder",
            b,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(
            (j["triangles"].as_u64(), j["leaves"].as_u64()),
            (Some(1), Some(1))
        );
        // One leaf under the root: C_i + C_t, a 4-wide root costing 2 C_i.
        let ratio = j["sah_vs_sweep"].as_f64().unwrap();
        let want = if wide(b) { 3.4 / 2.2 } else { 1.0 };
        assert!((ratio - want).abs() < 1e-6, "{b}: {ratio}");
        assert_eq!(
            bvh::io::read_tree_file(&out).unwrap().0.prim_indices(),
            &[0]
        );
    }
}

#[test]
fn refit_from_an_earlier_frame_gives_a_valid_tree_of_the_later_frame() {
    // The explode scene degrades under refitting; cloth barely does.
    let explode = "proc:explode?n=3000";
    let fresh = build_json(&[explode, "--builder", "binned-sah", "--time", "2"]);
    let refit = build_json(&[
        explode,
        "--builder",
        "binned-sah",
        "--time",
        "2",
        "--refit-from",
        "0",
    ]);
    assert_eq!(refit["valid"], true);
    assert_eq!(refit["refit_from_s"], 0.0);
    assert!(refit["refit_ms"].as_f64().unwrap() >= 0.0);
    assert_eq!(refit["triangles"], fresh["triangles"]);
    // Same topology as the T0 build, boxes of the later frame: worse SAH than a rebuild.
    let (r, f) = (
        refit["sah"].as_f64().unwrap(),
        fresh["sah"].as_f64().unwrap(),
    );
    assert!(r > 1.2 * f, "refit SAH {r} vs rebuild {f}");
    // Refitting to the build time itself changes nothing.
    let same = build_json(&[explode, "--builder", "binned-sah", "--refit-from", "0"]);
    let built = build_json(&[explode, "--builder", "binned-sah"]);
    assert_eq!(same["sah"], built["sah"]);
    assert_eq!(same["sah_at_build"], built["sah"]);
    assert!(fresh["refit_from_s"].is_null());
    // 4-wide trees refit the same way.
    for b in ["mbvh4-collapse", "mbvh4-topdown"] {
        let refit = build_json(&[explode, "--builder", b, "--time", "2", "--refit-from", "0"]);
        let fresh = build_json(&[explode, "--builder", b, "--time", "2"]);
        assert_eq!(
            (refit["valid"].as_bool(), refit["width"].as_u64()),
            (Some(true), Some(4))
        );
        assert!(refit["sah"].as_f64().unwrap() > 1.2 * fresh["sah"].as_f64().unwrap());
    }
}

/// The point builders (issue 18, part 3): one point per triangle, a valid tree, every
/// checked kNN query equal to brute force; the k-d tree is binary (nodes = 2 leaves - 1).
#[test]
fn point_builders_on_cloth() {
    let tris = build_json(&[CLOTH, "--builder", "lbvh"])["triangles"]
        .as_u64()
        .unwrap();
    for b in ["kdtree-points", "octree-points"] {
        let j = build_json(&[CLOTH, "--builder", b, "--max-leaf", "4", "--threads", "1"]);
        assert_eq!(j["schema"], "arbor.build.points.v1");
        assert_eq!(j["builder"], b);
        assert_eq!(j["points"].as_u64().unwrap(), tris);
        assert_eq!(j["max_leaf"], 4);
        assert_eq!(j["threads"], 1);
        assert_eq!(j["knn_checks"], 200);
        assert_eq!(j["knn_mismatches"], 0);
        let (nodes, leaves) = (j["nodes"].as_u64().unwrap(), j["leaves"].as_u64().unwrap());
        assert!(leaves * 4 >= tris, "{b}: {leaves} leaves of at most 4");
        if b == "kdtree-points" {
            assert_eq!(nodes, 2 * leaves - 1);
            assert!(j["single_child"].is_null());
        } else {
            assert!(nodes > leaves);
            assert!(j["index_splits"].is_null());
        }
    }
    for (args, want) in [
        (vec!["--out", "x.bvh"], "--out does not apply"),
        (vec!["--bins", "8"], "--bins does not apply"),
        (vec!["--max-leaf", "0"], "--max-leaf must be between"),
    ] {
        let mut a = vec![CLOTH, "--builder", "octree-points"];
        a.extend(args);
        let err = build_error(&a);
        assert!(err.contains(want), "{err}");
    }
}

/// `--builder sbvh` (spatial splits): a valid tree, lower in SAH than binned SAH on long
/// thin strands (where spatial splits pay: on the full 500K hairball 93.8% of sweep SAH
/// against 100.8%), with `--bins`; no tree file yet, and no collapse source.
#[test]
fn sbvh_splits_triangles_and_lowers_the_sah() {
    let scene = "proc:hairball?n=20000";
    let binned = build_json(&[scene, "--builder", "binned-sah"]);
    let s = build_json(&[scene, "--builder", "sbvh", "--bins", "32"]);
    assert_eq!(
        (s["valid"].as_bool(), s["tree_kind"].as_str()),
        (Some(true), Some("Bvh2"))
    );
    assert_eq!(s["triangles"], binned["triangles"]);
    let (sb, ss) = (binned["sah"].as_f64().unwrap(), s["sah"].as_f64().unwrap());
    assert!(ss < sb, "sbvh SAH {ss} not below binned SAH {sb}");
    let tmp = std::env::temp_dir().join(format!("arbor-sbvh-{}.bvh", std::process::id()));
    let e = build_error(&[scene, "--builder", "sbvh", "--out", tmp.to_str().unwrap()]);
    assert!(e.contains("cannot be written to a tree file"), "{e}");
    assert!(!tmp.exists());
    let e = build_error(&[
        scene,
        "--builder",
        "mbvh4-collapse",
        "--collapse-from",
        "sbvh",
    ]);
    assert!(e.contains("each triangle once"), "{e}");
}
