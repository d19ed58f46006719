//! Integration tests of `arbor bench build`: the JSON document on a small soup with Arbor
//! and peer builders, the other output formats, and bad arguments.

use crate::common::arbor;
use serde_json::Value;

const SOUP: &str = "proc:soup?n=3000";
const BUILDERS: &str = "hlbvh,binned-sah,mbvh4-topdown,obvhs-ploc-fastest,bvh-crate";

fn bench(args: &[&str]) -> std::process::Output {
    let mut a = vec!["bench", "build", "--quiet"];
    a.extend_from_slice(args);
    arbor(&a)
}

/// `hlbvh` builds into its previous run's buffers unless `--fresh`: the same tree either
/// way, the document says which, and the reused buffers count in the peak.
#[test]
fn fresh_and_reused_buffers_give_the_same_rows() {
    let mut sah = Vec::new();
    for fresh in [false, true] {
        let mut args = vec![SOUP, "--runs", "3", "--threads", "2", "--builders", "hlbvh"];
        args.extend(fresh.then_some("--fresh"));
        args.push("--json");
        let out = bench(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let j: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(j["fresh"], fresh);
        let r = &j["rows"][0];
        assert!(r["peak_bytes"].as_u64().unwrap() >= r["output_bytes"].as_u64().unwrap());
        sah.push(r["sah"].as_f64().unwrap());
    }
    assert_eq!(sah[0], sah[1]);
}

#[test]
fn json_has_every_row_with_ratios_and_memory() {
    // With Embree built in, its Morton builder joins so that the ratio columns fill.
    let builders = if cfg!(feature = "embree") {
        format!("{BUILDERS},embree-low")
    } else {
        BUILDERS.to_string()
    };
    let out = bench(&[
        SOUP,
        "--runs",
        "2",
        "--threads",
        "1,2",
        "--builders",
        &builders,
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["schema"], "arbor.bench.build.v1");
    assert_eq!(j["runs"], 2);
    assert_eq!(j["embree"], cfg!(feature = "embree"));
    assert!(j["command"].as_str().unwrap().contains("bench build"));
    if !cfg!(feature = "embree") {
        let notes = j["notes"].to_string();
        assert!(notes.contains("Embree rows omitted"), "{notes}");
    }
    let rows = j["rows"].as_array().unwrap();
    assert_eq!(rows.len(), builders.split(',').count() * 2);
    for r in rows {
        let id = r["id"].as_str().unwrap();
        assert_eq!(r["triangles"], 3000);
        assert!(r["best_ms"].as_f64().unwrap() <= r["median_ms"].as_f64().unwrap());
        assert!(r["mtris_per_s"].as_f64().unwrap() > 0.0);
        // Every tree is compared with the sweep SAH reference (built untimed here).
        let q = r["sah_vs_sweep"].as_f64().unwrap();
        assert!((0.8..2.0).contains(&q), "{id}: {q}");
        assert_eq!(r["width"], if id == "mbvh4-topdown" { 4 } else { 2 });
        assert_eq!(r["input_bytes"], 3000 * 24);
        let (peak, output) = (
            r["peak_bytes"].as_u64().unwrap(),
            r["output_bytes"].as_u64().unwrap(),
        );
        assert!(output > 3000 * 4, "{id}");
        if r["library"] == "arbor" {
            // The tree is allocated during the build and still alive at its end.
            assert!(
                peak >= output,
                "{id}: peak {peak} below the output {output}"
            );
            assert!(r["memory_ratio"].as_f64().unwrap() >= 1.0);
        } else {
            // A peer's own tree is allocated during its build call.
            assert!(peak > 0, "{id}");
        }
        let vs_low = &r["vs_embree_low"];
        assert_eq!(vs_low.is_null(), !cfg!(feature = "embree"));
        if id == "embree-low" {
            assert_eq!(vs_low.as_f64(), Some(1.0));
        }
    }
    // Deterministic builders: the same SAH on 1 and 2 threads.
    for id in ["hlbvh", "binned-sah", "mbvh4-topdown"] {
        let s: Vec<f64> = rows
            .iter()
            .filter(|r| r["id"] == id)
            .map(|r| r["sah"].as_f64().unwrap())
            .collect();
        assert_eq!(s.len(), 2);
        assert_eq!(s[0], s[1], "{id}");
    }
    // The memory goal is evaluated per thread count over the Arbor rows.
    let goals = j["goals"].as_array().unwrap();
    let mem: Vec<&Value> = goals
        .iter()
        .filter(|g| g["goal"].as_str().unwrap().starts_with("peak memory"))
        .collect();
    assert_eq!(mem.len(), 2);
    let worst = rows
        .iter()
        .filter(|r| r["library"] == "arbor" && r["threads"] == 1)
        .map(|r| r["memory_ratio"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert_eq!(mem[0]["value"].as_f64().unwrap(), worst);
    assert_eq!(mem[0]["met"], worst <= 2.0);
}

#[test]
fn text_markdown_and_csv_outputs() {
    let args = [
        SOUP,
        "--runs",
        "1",
        "--threads",
        "1",
        "--builders",
        "lbvh,obvhs-ploc-fast",
    ];
    let out = bench(&args);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for word in [
        "load average",
        "arbor lbvh",
        "obvhs PLOC fast",
        "memory ratio",
        "goals",
    ] {
        assert!(text.contains(word), "missing {word}: {text}");
    }
    let mut a = args.to_vec();
    a.extend(["--format", "markdown"]);
    let md = String::from_utf8(bench(&a).stdout).unwrap();
    assert!(md.contains("| scene | triangles | builder |"), "{md}");
    assert_eq!(
        md.lines().filter(|l| l.starts_with("| proc:soup")).count(),
        2,
        "{md}"
    );
    let mut a = args.to_vec();
    a.extend(["--format", "csv"]);
    let csv = String::from_utf8(bench(&a).stdout).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3, "{csv}");
    let cols = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == cols), "{csv}");
    assert!(
        lines[1].starts_with("proc:soup?n=3000,3000,arbor lbvh,arbor,2,1,"),
        "{csv}"
    );
    // --out: every format, and the SAH-against-time plot with one point per builder.
    let dir = tempfile::tempdir().unwrap();
    let mut a = args.to_vec();
    a.extend(["--out", dir.path().to_str().unwrap()]);
    assert!(bench(&a).status.success());
    for ext in ["txt", "md", "csv", "json"] {
        assert!(
            dir.path().join(format!("bench-build.{ext}")).is_file(),
            "{ext}"
        );
    }
    let svg =
        std::fs::read_to_string(dir.path().join("bench-build-sah-proc-soup-n-3000.svg")).unwrap();
    assert_eq!(svg.matches("<circle").count(), 2, "{svg}");
    assert!(svg.contains(">arbor lbvh</text>") && svg.contains(">obvhs PLOC fast</text>"));
}

#[test]
fn bad_arguments_are_one_line_errors() {
    for (args, want) in [
        (vec![SOUP, "--runs", "0"], "--runs"),
        (vec![SOUP, "--threads", "0"], "--threads"),
        (vec![SOUP, "--builders", "nope"], "unknown builder"),
        (vec!["no/such/scene.ply", "--builders", "lbvh"], "scene.ply"),
    ] {
        let out = bench(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(out.stdout.is_empty());
    }
    // --out naming a file, not a folder.
    let f = tempfile::NamedTempFile::new().unwrap();
    let out = bench(&[
        SOUP,
        "--runs",
        "1",
        "--builders",
        "lbvh",
        "--out",
        f.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.lines().count() == 1 && err.contains("cannot create"),
        "{err}"
    );
    if !cfg!(feature = "embree") {
        let out = bench(&[SOUP, "--builders", "embree-low"]);
        assert_eq!(out.status.code(), Some(1));
        assert!(String::from_utf8_lossy(&out.stderr).contains("--features embree"));
    }
}
