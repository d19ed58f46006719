//! Integration tests of `arbor report mergetree`: the files, their rows and columns, the
//! node-for-node check, the thesis columns on a shared scene, and bad arguments.

use crate::common::arbor;

/// Parses a CSV file with a header into rows of (column name -> cell).
fn csv(path: &std::path::Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), head.len(), "{}: {l}", path.display());
            head.iter()
                .cloned()
                .zip(cells.iter().map(|c| c.to_string()))
                .collect()
        })
        .collect()
}

fn num(row: &std::collections::HashMap<String, String>, key: &str) -> f64 {
    row[key]
        .parse()
        .unwrap_or_else(|_| panic!("{key} = '{}' is not a number", row[key]))
}

/// Runs the report and returns its output folder.
fn report(args: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap().to_string();
    let mut a = vec!["report", "mergetree", "--quiet", "--out", &out];
    a.extend_from_slice(args);
    let run = arbor(&a);
    assert!(
        run.status.success(),
        "arbor {a:?} failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    dir
}

#[test]
fn tiny_procedural_scenes_on_dramsim3() {
    let dir = report(&["--scenes", "proc:soup?n=3000&seed=2,proc:cloth?n=2000"]);
    let d = dir.path();
    for f in [
        "report.md",
        "table3.csv",
        "sah.csv",
        "table6.csv",
        "table7.csv",
        "table4.csv",
    ] {
        assert!(d.join(f).is_file(), "{f} missing");
    }
    // Table VII: one row per system with the thesis beside; DRAM the larger part.
    let t7 = csv(&d.join("table7.csv"));
    assert_eq!(t7.len(), 3);
    for (r, system) in t7.iter().zip(["slow", "medium", "fast"]) {
        assert_eq!(r["system"], system);
        let num = |k: &str| r[k].parse::<f64>().unwrap();
        assert!(num("logic_mw") > 0.0 && num("dram_above_idle_mw") > 0.0);
        assert!((num("total_mw") - num("logic_mw") - num("dram_above_idle_mw")).abs() < 0.05);
        assert!(num("thesis_total_mw") > 500.0);
    }
    assert_eq!(csv(&d.join("table4.csv")).len(), 5);
    // Table III: two scenes on the three systems, every tree the software builder's.
    let t3 = csv(&d.join("table3.csv"));
    assert_eq!(t3.len(), 6);
    for (i, (scene, system)) in [
        ("soup", "slow"),
        ("soup", "medium"),
        ("soup", "fast"),
        ("cloth", "slow"),
        ("cloth", "medium"),
        ("cloth", "fast"),
    ]
    .into_iter()
    .enumerate()
    {
        let r = &t3[i];
        assert_eq!((r["scene"].as_str(), r["system"].as_str()), (scene, system));
        assert_eq!(r["tree_matches_software"], "true");
        assert!(r["thesis_ms"].is_empty(), "no thesis value for {scene}");
        let util = num(r, "bus_utilization");
        assert!(util > 0.0 && util <= 1.0);
        assert!((num(r, "ms") - num(r, "cycles") / 1e6).abs() < 1e-3);
        // The same bytes on every system; faster memory is not slower.
        let first = &t3[i / 3 * 3];
        assert_eq!(r["bytes_read"], first["bytes_read"]);
        assert!(num(r, "speedup") >= 1.0);
    }
    assert_eq!(t3[0]["speedup"], "1.0000");
    assert_eq!(t3[0]["memory"], "lpddr3-1600-1x64");
    // SAH: four builders per scene, none better than a sweep by much.
    let sah = csv(&d.join("sah.csv"));
    assert_eq!(sah.len(), 8);
    let builders: Vec<&str> = sah[..4].iter().map(|r| r["builder"].as_str()).collect();
    assert_eq!(
        builders,
        ["hlbvh", "hlbvh+sah", "hlbvh+atrbvh", "binned-sah"]
    );
    for r in &sah {
        assert!(num(r, "sah_vs_sweep_pct") > 90.0, "{r:?}");
    }
    assert!(num(&sah[1], "toplevel_unit_ms") > 0.0);
    // Table VI: the GPU model is 324 B per triangle, and MergeTree moves less.
    let t6 = csv(&d.join("table6.csv"));
    assert_eq!(t6.len(), 2);
    let n = num(&t6[0], "triangles");
    assert!((num(&t6[0], "gpu_hlbvh_mb") - n * 324.0 / 1e6).abs() < 1e-3);
    assert!(num(&t6[0], "gpu_ratio") > 1.0);
    let split: f64 = ["input_mb", "runs_written_mb", "runs_read_mb", "output_mb"]
        .iter()
        .map(|k| num(&t6[0], k))
        .sum();
    assert!((split - num(&t6[0], "mergetree_mb")).abs() < 1e-2);
    // MiB beside MB, leaves of at least one triangle, and the box-grid run (leaves of at
    // most 8); no thesis value to compare with.
    for r in &t6 {
        let mib = num(r, "mergetree_mib");
        assert!((mib * (1u64 << 20) as f64 / 1e6 - num(r, "mergetree_mb")).abs() < 1e-2);
        assert!(num(r, "leaf_size") >= 1.0);
        assert!(num(r, "box_grid_mb") > 0.0);
        let box_leaf = num(r, "box_grid_leaf_size");
        assert!((1.0..=8.0).contains(&box_leaf), "{box_leaf}");
        assert!(r["mergetree_diff_pct_mib"].is_empty() && r["box_grid_diff_pct"].is_empty());
    }
    let md = std::fs::read_to_string(d.join("report.md")).unwrap();
    assert!(md.contains("Table III analogue") && md.contains("Table VI analogue"));
}

#[test]
fn a_shared_scene_gets_the_thesis_columns() {
    let bunny =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes/bunny.ply");
    if !bunny.is_file() {
        println!("skipping: {} not found", bunny.display());
        return;
    }
    // The simple model of the same systems keeps this test quick.
    let dir = report(&[
        "--scenes",
        bunny.to_str().unwrap(),
        "--drams",
        "simple:lpddr3-1600-1x64,simple:lpddr3-1600-2x64,simple:lpddr3-1333-4x64",
    ]);
    let t3 = csv(&dir.path().join("table3.csv"));
    assert_eq!(t3.len(), 3);
    assert_eq!(t3[0]["thesis_ms"], "1.11");
    assert_eq!(t3[2]["thesis_ms"], "0.49");
    let got = num(&t3[1], "speedup_diff_pct");
    let want = (num(&t3[1], "speedup") / num(&t3[1], "thesis_speedup") - 1.0) * 100.0;
    assert!((got - want).abs() < 0.01);
    let t6 = csv(&dir.path().join("table6.csv"));
    assert_eq!(t6[0]["thesis_mergetree_mb"], "10.6");
    assert_eq!(t6[0]["thesis_gpu_hlbvh_mb"], "27");
    // The preset (codes on a cube grid, no leaf-size limit), Table VI read as MiB: Bunny's
    // 10.6.
    let d = num(&t6[0], "mergetree_diff_pct_mib");
    assert!(d.abs() < 0.5, "preset p2: {d}% from Table VI");
    let sah = csv(&dir.path().join("sah.csv"));
    assert_eq!(sah[0]["thesis_pct"], "122");
    for f in ["table3.svg", "speedup.svg", "table6.svg"] {
        let svg = std::fs::read_to_string(dir.path().join(f)).unwrap();
        assert!(svg.contains("<rect") && svg.ends_with("</svg>\n"), "{f}");
    }
}

#[test]
fn bad_arguments_are_one_line_errors() {
    for (args, needle) in [
        (
            vec!["--scenes", "proc:soup?n=100", "--drams", "ddr9"],
            "ddr9",
        ),
        (vec!["--scenes", "/no/such/scene.ply"], "scene.ply"),
        (
            vec!["--scenes", "proc:soup?n=100", "--time", "NaN"],
            "finite",
        ),
    ] {
        let mut a = vec!["report", "mergetree", "--out", "/nonexistent-arbor-out"];
        a.extend_from_slice(&args);
        let out = arbor(&a);
        assert!(!out.status.success(), "{args:?} should fail");
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
        assert!(err.contains(needle), "{err}");
    }
}

/// `arbor report beyond` (issue 18): every part's rows on a small scene, each checked
/// against its software; the files; bad arguments as one-line errors.
#[test]
fn report_beyond_runs_every_part() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("b");
    let o = arbor(&[
        "report",
        "beyond",
        "--scenes",
        "proc:soup?n=3000",
        "--out",
        out.to_str().unwrap(),
        "--json",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(doc["schema"], "arbor.report.beyond.v1");
    let rows = doc["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 13);
    for part in 1..=4 {
        let n = rows.iter().filter(|r| r["part"] == part).count();
        assert!(n >= 2, "part {part}: {n} rows");
    }
    assert!(rows.iter().all(|r| r["matches"] == true), "{rows:#?}");
    for f in ["report.md", "beyond.csv", "beyond.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let e = arbor(&[
        "report",
        "beyond",
        "--scenes",
        "proc:soup?n=300",
        "--dram",
        "nope",
    ]);
    assert_eq!(e.status.code(), Some(1));
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(err.contains("--dram") && err.lines().count() == 1, "{err}");
}
