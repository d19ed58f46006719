//! Integration tests of `arbor render` and `arbor log-info`: every output file, the
//! statistics against the log's own totals, the same image from every tree format (the
//! compressed one with several encoders), and
//! every bad-argument case.

use crate::common::{arbor, error, json};
use serde_json::Value;

const SCENE: &str = "proc:skinned?n=3000&seed=2";

fn render(dir: &std::path::Path, name: &str, extra: &[&str]) -> Value {
    let p = |f: &str| dir.join(format!("{name}.{f}")).display().to_string();
    let (out, depth, heat, stats, log) = (p("png"), p("pfm"), p("heat.png"), p("json"), p("log"));
    let mut args = vec![
        SCENE,
        "--width",
        "64",
        "--height",
        "36",
        "--out",
        &out,
        "--depth",
        &depth,
        "--heatmap",
        &heat,
        "--stats",
        &stats,
        "--log",
        &log,
    ];
    args.extend_from_slice(extra);
    let j = json("render", &args);
    // --stats writes the same document that --json prints.
    let file: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(file["total"], j["total"]);
    for f in [&out, &depth, &heat, &log] {
        assert!(std::fs::metadata(f).unwrap().len() > 0, "{f}");
    }
    j
}

#[test]
fn outputs_stats_and_log_agree() {
    let dir = tempfile::tempdir().unwrap();
    for (name, extra) in [
        ("primary", vec![]),
        (
            "diffuse",
            vec!["--rays", "diffuse", "--bounces", "2", "--format", "mbvh4"],
        ),
        ("shadow", vec!["--rays", "shadow", "--builder", "lbvh"]),
        (
            "cbvh",
            vec!["--rays", "diffuse", "--bounces", "1", "--format", "cbvh"],
        ),
    ] {
        let j = render(dir.path(), name, &extra);
        assert_eq!(j["schema"], "arbor.render.v1");
        let total = &j["total"];
        assert_eq!(total["rays"], j["rays"]);
        let per: &Vec<Value> = j["per_bounce"].as_array().unwrap();
        assert_eq!(per[0]["rays"], 64 * 36);
        let sum: u64 = per.iter().map(|b| b["rays"].as_u64().unwrap()).sum();
        assert_eq!(sum, j["rays"].as_u64().unwrap());
        assert!(j["hits"].as_u64().unwrap() > 0);
        assert!(j["mrays_per_s"].as_f64().unwrap() > 0.0);
        // The log's totals, recomputed from its events, are the tracer's counters.
        let log = dir.path().join(format!("{name}.log")).display().to_string();
        let info = json("log-info", &[&log]);
        assert_eq!(info["schema"], "arbor.log-info.v1");
        for key in [
            "rays",
            "hits",
            "node_visits",
            "box_tests",
            "tri_tests",
            "leaf_visits",
            "pushes",
            "pops",
            "culled_pops",
            "max_stack_depth",
        ] {
            assert_eq!(info["total"][key], total[key], "{name}: {key}");
        }
        assert_eq!(info["per_bounce"].as_array().unwrap().len(), per.len());
        // The text form prints too.
        let out = arbor(&["log-info", &log]);
        assert!(out.status.success());
        assert!(String::from_utf8_lossy(&out.stdout).contains("distinct nodes"));
    }
}

#[test]
fn both_formats_and_every_kernel_give_the_same_depth_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let mut depths = Vec::new();
    for (name, extra) in [
        ("a", vec!["--format", "bvh2"]),
        ("b", vec!["--format", "mbvh4", "--distance-stack", "off"]),
        ("c", vec!["--format", "mbvh4", "--builder", "mbvh4-topdown"]),
        (
            "d",
            vec![
                "--format",
                "bvh2",
                "--builder",
                "hlbvh",
                "--distance-stack",
                "on",
            ],
        ),
        ("e", vec!["--format", "cbvh"]),
        (
            "f",
            vec![
                "--format",
                "cbvh",
                "--encoder",
                "topdown",
                "--coords",
                "relative",
                "--bits",
                "4",
            ],
        ),
        (
            "g",
            vec![
                "--format",
                "cbvh",
                "--builder",
                "lbvh",
                "--treelet",
                "3",
                "--min-scale-exp",
                "-40",
                "--distance-stack",
                "on",
            ],
        ),
    ] {
        let j = render(dir.path(), name, &extra);
        if extra.contains(&"cbvh") {
            // The compressed tree: 16-byte pairs at 6 bits (13 at 4), 4 bytes per id.
            assert_eq!(j["format"], "cbvh");
            let c = &j["cbvh"];
            let bits = c["bits"].as_u64().unwrap();
            assert_eq!(bits, if name == "f" { 4 } else { 6 });
            assert_eq!(
                c["encoder"],
                if name == "f" { "topdown" } else { "bottomup" }
            );
            assert_eq!(c["treelet_depth"], if name == "g" { 3 } else { 1 });
            assert_eq!(c["min_scale_exp"], if name == "g" { -40 } else { -30 });
            let pair = if bits == 6 { 16 } else { 13 };
            let nodes = j["nodes"].as_u64().unwrap();
            let ids = j["triangles"].as_u64().unwrap();
            assert_eq!(j["tree_bytes"].as_u64().unwrap(), nodes * pair + ids * 4);
        } else {
            assert!(j["cbvh"].is_null());
        }
        depths.push((
            std::fs::read(dir.path().join(format!("{name}.pfm"))).unwrap(),
            std::fs::read(dir.path().join(format!("{name}.png"))).unwrap(),
        ));
    }
    for d in &depths[1..] {
        assert!(d == &depths[0]);
    }
}

#[test]
fn text_output_and_default_image_path() {
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_arbor"))
        .current_dir(dir.path())
        .args([
            "render", SCENE, "--width", "32", "--height", "20", "--quiet",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Mrays/s") && text.contains("total"), "{text}");
    assert!(
        dir.path().join("arbor-out/render/skinned.png").exists(),
        "{text}"
    );
}

#[test]
fn bad_arguments_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir
        .path()
        .join("no/such/folder/x.png")
        .display()
        .to_string();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec![SCENE, "--format", "bvh8"], "unknown format"),
        (vec![SCENE, "--rays", "glossy"], "unknown ray kind"),
        (vec![SCENE, "--builder", "nope"], "unknown builder"),
        (vec![SCENE, "--builder", "mbvh4-topdown"], "--format mbvh4"),
        (vec![SCENE, "--width", "0"], "--width"),
        (vec![SCENE, "--height", "100000"], "--width and --height"),
        (vec![SCENE, "--bounces", "1000"], "--bounces"),
        (vec![SCENE, "--eye", "1,2"], "--eye"),
        (vec![SCENE, "--target", "1,nan,2"], "--target"),
        (vec![SCENE, "--fov", "0"], "--fov"),
        (vec![SCENE, "--distance-stack", "maybe"], "on or off"),
        (vec![SCENE, "--heatmap-scale", "10"], "--heatmap-scale"),
        (vec![SCENE, "--depth", "d.exr"], ".pfm or .npy"),
        (vec![SCENE, "--out", &missing], "does not exist"),
        (vec![SCENE, "--threads", "0"], "--threads"),
        (vec![SCENE, "--frame", "100000"], "out of range"),
        (vec![SCENE, "--coords", "relative"], "--format cbvh only"),
        (
            vec![SCENE, "--format", "mbvh4", "--bits", "5"],
            "--format cbvh only",
        ),
        (
            vec![
                SCENE,
                "--format",
                "cbvh",
                "--encoder",
                "topdown",
                "--treelet",
                "2",
            ],
            "bottom-up encoder only",
        ),
        (
            vec![SCENE, "--format", "cbvh", "--bits", "9"],
            "coordinate bits",
        ),
        (
            vec![SCENE, "--format", "cbvh", "--treelet", "0"],
            "--treelet",
        ),
        (
            vec![SCENE, "--format", "cbvh", "--builder", "mbvh4-topdown"],
            "--format mbvh4",
        ),
        (
            vec![SCENE, "--eye", "0,0,0", "--target", "0,0,0"],
            "same point",
        ),
        (vec!["no-such-file.ply"], "no-such-file.ply"),
    ];
    for (args, want) in cases {
        let mut a = vec!["render"];
        a.extend_from_slice(&args);
        let e = error(&a);
        assert!(e.contains(want), "{args:?}: {e}");
    }
    // log-info on a missing file and on a file that is not a log.
    let e = error(&["log-info", "no-such.log"]);
    assert!(e.contains("no-such.log"), "{e}");
    let junk = dir.path().join("junk.log");
    std::fs::write(
        &junk,
        b"ARBTRLOG but not really a log at all, just some bytes that go on for long enough",
    )
    .unwrap();
    let e = error(&["log-info", &junk.display().to_string()]);
    assert!(e.contains("not a valid traversal log"), "{e}");
}
