//! Integration tests of `arbor bench trace`: the JSON document on a small soup (every
//! tracer on both ray sets and thread counts, Arbor's kernels agreeing exactly), the other
//! output formats and `--out`, and bad arguments.

use crate::common::arbor;
use serde_json::Value;

const SOUP: &str = "proc:soup?n=3000";
/// Arbor's kernels in the benchmark, and the peers always present (obvhs; Embree only in
/// a build with `--features embree`).
const ARBOR_TRACERS: usize = peers::trace_bench::ARBOR_KERNELS.len();

fn bench(args: &[&str]) -> std::process::Output {
    let mut a = vec![
        "bench",
        "trace",
        "--quiet",
        "--width",
        "48",
        "--height",
        "32",
        "--bounces",
        "2",
    ];
    a.extend_from_slice(args);
    arbor(&a)
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn json_has_every_tracer_on_both_ray_sets() {
    let out = bench(&[SOUP, "--runs", "2", "--threads", "1,2", "--json"]);
    ok(&out);
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["schema"], "arbor.bench.trace.v1");
    assert_eq!(j["rounds"], 2);
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64()),
        (Some(48), Some(32))
    );
    assert_eq!(j["embree"], cfg!(feature = "embree"));
    assert!(j["command"].as_str().unwrap().contains("bench trace"));
    let peers = if cfg!(feature = "embree") { 3 } else { 1 };
    let rows = j["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2 * 2 * (ARBOR_TRACERS + peers), "{rows:#?}");
    for set in ["primary", "diffuse"] {
        for th in [1, 2] {
            let n = rows
                .iter()
                .filter(|r| r["rays"] == set && r["threads"] == th)
                .count();
            assert_eq!(n, ARBOR_TRACERS + peers, "{set} {th}");
        }
    }
    for r in rows {
        let tracer = r["tracer"].as_str().unwrap();
        assert!(r["mrays_per_s"].as_f64().unwrap() > 0.0, "{tracer}");
        assert!(r["mrays_per_cpu_s"].as_f64().unwrap() > 0.0, "{tracer}");
        let count = r["ray_count"].as_u64().unwrap();
        if r["rays"] == "primary" {
            assert_eq!(count, 48 * 32);
        } else {
            assert!(count > 0, "no diffuse rays");
        }
        let agreement = r["agreement"].as_f64().unwrap();
        if tracer.starts_with("arbor") {
            // Arbor's kernels return the brute-force hit bit for bit, whatever the tree.
            assert_eq!(agreement, 1.0, "{tracer}");
            // A tiny scene's tree fits any cache: only the forced row interleaves.
            let lanes = if tracer.ends_with("interleave 8") {
                8
            } else {
                1
            };
            assert_eq!(r["interleave"], lanes, "{tracer}");
        } else {
            assert!(agreement > 0.99, "{tracer}: {agreement}");
            assert!(r["interleave"].is_null(), "{tracer}");
        }
        assert_eq!(r["vs_embree"].is_null(), !cfg!(feature = "embree"));
    }
    let goals = j["goals"].as_array().unwrap();
    if cfg!(feature = "embree") {
        // Per (scene, threads): one goal for the primary and one for the diffuse rays.
        assert_eq!(goals.len(), 4);
        for g in goals {
            let (w, c) = (
                g["vs_embree"].as_f64().unwrap(),
                g["vs_embree_cpu"].as_f64().unwrap(),
            );
            let target = g["target"].as_f64().unwrap();
            let sponza_primary = g["scene"] == "crytek-sponza" && g["rays"] == "primary";
            assert_eq!(target, if sponza_primary { 1.3 } else { 1.0 });
            assert_eq!(g["met"], w >= target && c >= target);
            assert!(g["best_kernel"].as_str().unwrap().starts_with("arbor"));
        }
    } else {
        assert!(goals.is_empty());
        assert!(j["notes"].to_string().contains("without Embree"));
    }
}

#[test]
fn text_markdown_csv_and_out_folder() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("bench");
    let args = [
        SOUP,
        "--rounds",
        "1",
        "--threads",
        "1",
        "--out",
        out_dir.to_str().unwrap(),
    ];
    let out = bench(&args);
    ok(&out);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with("command: "), "{text}");
    assert!(text.contains("arbor mbvh8 collapse(binned-sah)"), "{text}");
    assert!(text.contains("obvhs cwbvh"), "{text}");
    for name in [
        "bench-trace.txt",
        "bench-trace.md",
        "bench-trace.csv",
        "bench-trace.json",
    ] {
        let body = std::fs::read_to_string(out_dir.join(name)).unwrap();
        assert!(!body.is_empty(), "{name}");
    }
    // The folder's text file is what was printed; its JSON is the same document.
    assert_eq!(
        std::fs::read_to_string(out_dir.join("bench-trace.txt")).unwrap(),
        text
    );
    let j: Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("bench-trace.json")).unwrap())
            .unwrap();
    assert_eq!(j["schema"], "arbor.bench.trace.v1");
    let rows = j["rows"].as_array().unwrap().len();
    let csv = std::fs::read_to_string(out_dir.join("bench-trace.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(lines[0].starts_with("scene,rays,ray_count,tracer,threads,mrays_per_s"));
    assert_eq!(lines.len(), rows + 1);
    assert!(
        lines[1].starts_with("soup,primary,1536,arbor bvh2 binned-sah,1,"),
        "{csv}"
    );
    let md = std::fs::read_to_string(out_dir.join("bench-trace.md")).unwrap();
    assert!(
        md.contains("| scene | rays | tracer | threads | Mrays/s |"),
        "{md}"
    );
    assert_eq!(
        md.lines().filter(|l| l.starts_with("| soup |")).count(),
        rows
    );
}

#[test]
fn bad_arguments_are_one_line_errors() {
    let f = tempfile::NamedTempFile::new().unwrap();
    for (args, want) in [
        (vec![SOUP, "--runs", "0"], "--runs"),
        (vec![SOUP, "--threads", "0"], "--threads"),
        (vec![SOUP, "--width", "0"], "--width"),
        (vec![SOUP, "--bounces", "99"], "--bounces"),
        (vec!["no/such/scene.ply"], "scene.ply"),
        (vec![SOUP, "--out", f.path().to_str().unwrap()], "is a file"),
    ] {
        let mut a = vec!["bench", "trace", "--quiet"];
        a.extend_from_slice(&args);
        let out = arbor(&a);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(out.stdout.is_empty());
    }
}

#[test]
fn no_bounces_means_no_diffuse_rows_and_says_so() {
    let out = arbor(&[
        "bench",
        "trace",
        "--quiet",
        "--width",
        "24",
        "--height",
        "16",
        "--bounces",
        "0",
        "--runs",
        "1",
        "--threads",
        "1",
        "--json",
        SOUP,
    ]);
    ok(&out);
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = j["rows"].as_array().unwrap();
    assert!(!rows.is_empty());
    assert!(rows.iter().all(|r| r["rays"] == "primary"), "{rows:#?}");
    assert!(rows
        .iter()
        .all(|r| r["mrays_per_s"].as_f64().unwrap() > 0.0));
    let notes = j["notes"].as_array().unwrap();
    assert!(
        notes
            .iter()
            .any(|n| n.as_str().unwrap().contains("no diffuse rays")),
        "{notes:#?}"
    );
    assert!(j["goals"]
        .as_array()
        .unwrap()
        .iter()
        .all(|g| g["rays"] == "primary"));
    // Which instruction set the 8-wide kernel chose is part of the record.
    let isa = format!("runs with {}", trace::Mbvh8Accel::detected_isa());
    assert!(
        notes.iter().any(|n| n.as_str().unwrap().contains(&isa)),
        "{notes:#?}"
    );
}
