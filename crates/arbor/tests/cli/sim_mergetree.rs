//! Integration tests of `arbor sim mergetree`: JSON fields, the node-for-node check, two
//! merge passes with a small scratchpad, trace files, and bad arguments.

// This file runs `arbor sim mergetree` itself (the `--json` flag follows the model name).

use crate::common::arbor;
use serde_json::Value;

const CLOTH: &str = "proc:cloth?n=20000";

/// Runs `arbor sim mergetree --json --quiet ARGS` and parses its output.
fn sim_json(args: &[&str]) -> Value {
    let mut a = vec!["sim", "mergetree", "--json", "--quiet"];
    a.extend_from_slice(args);
    crate::common::json_of(&a)
}

/// Runs `arbor sim mergetree ARGS` expecting failure; returns stderr.
fn sim_error(args: &[&str]) -> String {
    let mut a = vec!["sim", "mergetree"];
    a.extend_from_slice(args);
    let out = arbor(&a);
    assert!(!out.status.success(), "arbor {a:?} should fail");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    err
}

#[test]
fn json_has_the_documented_fields() {
    let j = sim_json(&[CLOTH]);
    assert_eq!(j["schema"], "arbor.sim.mergetree.v1");
    let n = j["triangles"].as_u64().unwrap();
    assert!((20000..20100).contains(&n), "{n}");
    assert_eq!(j["tree_matches_software"], true);
    assert_eq!(j["merge_passes"], 1);
    let cycles = j["cycles"].as_u64().unwrap();
    assert!(cycles > 2 * 2 * n);
    assert!((j["ms"].as_f64().unwrap() - cycles as f64 / 1e6).abs() < 1e-9);
    let util = j["bus_utilization"].as_f64().unwrap();
    assert!(util > 0.0 && util <= 1.0);
    let read = j["bytes_read"].as_u64().unwrap();
    let written = j["bytes_written"].as_u64().unwrap();
    assert!(read >= 2 * n * 32 && written >= n * 32);
    let phases = j["phases"].as_array().unwrap();
    let sum: u64 = phases
        .iter()
        .map(|p| p["bytes_read"].as_u64().unwrap() + p["bytes_written"].as_u64().unwrap())
        .sum();
    assert_eq!(sum, read + written);
    assert!(j["stalls"]["merge"]["queue_dry_cycles"].is_u64());
    assert_eq!(j["config"]["m"], 8192);
}

#[test]
fn small_scratchpad_needs_two_passes_and_still_matches() {
    let j = sim_json(&[
        CLOTH,
        "--preset",
        "p1",
        "--set",
        "m=256",
        "--set",
        "b=8",
        "--dram",
        "lpddr3-1333-4x64",
    ]);
    assert_eq!(j["merge_passes"], 2);
    assert_eq!(j["tree_matches_software"], true);
    assert_eq!(j["config"]["presorters"], 4);
}

/// Forecasting read scheduling (issue 18): the same scratchpad merges about twice the
/// runs in a pass, so the scene that needs two double-buffered passes needs one, and the
/// tree is still the software builder's.
#[test]
fn forecasting_merges_in_one_pass_what_double_buffering_needs_two_for() {
    // 24 partial-sort blocks: more than double buffering's 16 runs per pass, fewer than
    // forecasting's 32 - 2.
    let run = |schedule: &str| {
        sim_json(&[
            "proc:cloth?n=6000",
            "--preset",
            "p1",
            "--set",
            "m=256",
            "--set",
            "b=8",
            "--set",
            &format!("read_schedule={schedule}"),
            "--set",
            "forecast_spares=2",
        ])
    };
    let (double, forecast) = (run("double"), run("forecast"));
    assert_eq!(double["merge_passes"], 2);
    assert_eq!(forecast["merge_passes"], 1);
    assert_eq!(forecast["tree_matches_software"], true);
    let bytes =
        |j: &Value| j["bytes_read"].as_u64().unwrap() + j["bytes_written"].as_u64().unwrap();
    assert!(bytes(&forecast) < bytes(&double));
    assert!(sim_error(&[CLOTH, "--set", "read_schedule=psychic"]).contains("read_schedule"));
}

#[test]
fn faster_memory_is_faster() {
    let slow = sim_json(&[CLOTH, "--dram", "lpddr3-1600-1x64", "--no-check"]);
    let fast = sim_json(&[CLOTH, "--dram", "lpddr3-1333-4x64", "--no-check"]);
    assert!(slow["tree_matches_software"].is_null());
    assert!(slow["cycles"].as_u64() > fast["cycles"].as_u64());
    assert_eq!(slow["bytes_read"], fast["bytes_read"]);
}

#[test]
fn trace_csv_svg_and_config_file() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("util.csv");
    let svg = dir.path().join("util.svg");
    let cfg = dir.path().join("mt.toml");
    std::fs::write(&cfg, "preset = \"p1\"\ntrace_window_cycles = 5000\n").unwrap();
    let j = sim_json(&[
        CLOTH,
        "--config",
        cfg.to_str().unwrap(),
        "--trace",
        csv.to_str().unwrap(),
        "--svg",
        svg.to_str().unwrap(),
    ]);
    assert_eq!(j["config"]["m"], 4096);
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows = text.lines().count() as u64 - 1;
    assert_eq!(rows, j["cycles"].as_u64().unwrap().div_ceil(5000));
    assert!(text.starts_with("cycle_start,cycles,phase,bus_utilization"));
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<polyline"));
}

#[test]
fn bad_arguments_are_one_line_errors() {
    assert!(sim_error(&[CLOTH, "--preset", "p9"]).contains("p9"));
    assert!(sim_error(&[CLOTH, "--set", "bogus=1"]).contains("bogus"));
    assert!(sim_error(&[CLOTH, "--set", "m=x"]).contains("'m'"));
    assert!(sim_error(&[CLOTH, "--set", "m=1000"]).contains("multiple of 2B"));
    assert!(sim_error(&[CLOTH, "--dram", "ddr9"]).contains("ddr9"));
    assert!(sim_error(&["/nonexistent.ply"]).contains("nonexistent"));
    assert!(sim_error(&[CLOTH, "--time", "nan"]).contains("--time must be a finite"));
}

#[test]
fn cbvh_output_modes() {
    const SOUP: &str = "proc:soup?n=6000";
    // --cbvh defaults to preset p3 on lpddr3-1600-2x32 (DRAMsim3), thesis P3 5.3.
    let j = sim_json(&[SOUP, "--cbvh", "stream"]);
    assert_eq!(j["preset"], "p3");
    assert_eq!(j["dram_system"], "lpddr3-1600-2x32");
    assert_eq!(
        (j["config"]["m"].as_u64(), j["config"]["b"].as_u64()),
        (Some(8192), Some(8))
    );
    assert_eq!(j["config"]["output"], "cbvh-stream");
    assert_eq!(j["tree_matches_software"], true);
    assert_eq!(j["cbvh_matches_software"], true);
    let c = &j["cbvh"];
    assert_eq!(c["mode"], "cbvh-stream");
    assert_eq!(c["params"]["coords"], "relative");
    assert_eq!(c["treelet_depth"], 1);
    assert_eq!(c["pair_bytes"], 16);
    assert_eq!(c["node_pairs"], j["nodes"]);
    let steps = c["backtrack_steps"].as_u64().unwrap();
    assert!(steps > 0);
    assert_eq!(c["stream"]["backtrack_reads"].as_u64(), Some(steps));
    assert_eq!(c["build_cycles"], j["cycles"]);
    assert_eq!(c["compress_cycles"], 0);
    assert!(c["topdown"].is_null());
    let m4 = sim_json(&[
        SOUP,
        "--cbvh",
        "stream",
        "--coords",
        "modulo",
        "--treelet",
        "4",
        "--dram",
        "simple:lpddr3-1600-2x32",
    ]);
    assert_eq!(m4["cbvh_matches_software"], true);
    assert_eq!(m4["cbvh"]["params"]["coords"], "modulo");
    assert!(m4["cbvh"]["backtrack_steps"].as_u64().unwrap() < steps / 10);
    let td = sim_json(&[
        SOUP,
        "--cbvh",
        "topdown",
        "--dram",
        "simple:lpddr3-1600-2x32",
    ]);
    assert_eq!(td["cbvh_matches_software"], true);
    let c = &td["cbvh"];
    let (build, pass) = (
        c["build_cycles"].as_u64().unwrap(),
        c["compress_cycles"].as_u64().unwrap(),
    );
    assert!(pass > 0);
    assert_eq!(build + pass, td["cycles"].as_u64().unwrap());
    assert_eq!(
        td["phases"].as_array().unwrap().last().unwrap()["name"],
        "topdown_compress"
    );
    assert_eq!(c["topdown"]["node_reads"], td["nodes"]);
    // The plain build of the same preset takes the TD run's build cycles.
    let plain = sim_json(&[SOUP, "--preset", "p3", "--dram", "simple:lpddr3-1600-2x32"]);
    assert_eq!(plain["cycles"].as_u64(), Some(build));
    assert!(plain["cbvh"].is_null() && plain["cbvh_matches_software"].is_null());
}

#[test]
fn cbvh_bad_arguments_are_one_line_errors() {
    assert!(sim_error(&[CLOTH, "--treelet", "2"]).contains("--cbvh"));
    assert!(sim_error(&[CLOTH, "--cbvh", "topdown", "--treelet", "2"]).contains("stream"));
    assert!(sim_error(&[CLOTH, "--cbvh", "stream", "--treelet", "9"]).contains("treelet"));
    assert!(
        sim_error(&[CLOTH, "--cbvh", "stream", "--set", "highlevel_threshold=18"])
            .contains("highlevel_threshold")
    );
    assert!(sim_error(&[CLOTH, "--cbvh", "stream", "--set", "cbvh_bits=2"]).contains("bits"));
}

#[test]
fn mbvh4_output_modes() {
    const SOUP: &str = "proc:soup?n=6000";
    let dram = ["--dram", "simple:lpddr3-1600-1x64"];
    let run = |output: &str| {
        let set = format!("output={output}");
        let mut a = vec![SOUP, "--set", set.as_str()];
        a.extend_from_slice(&dram);
        sim_json(&a)
    };
    let plain = run("bvh");
    assert!(plain["mbvh4"].is_null() && plain["mbvh4_matches_software"].is_null());
    let s = run("mbvh4");
    assert_eq!(s["config"]["output"], "mbvh4");
    assert_eq!(s["tree_matches_software"], true);
    assert_eq!(s["mbvh4_matches_software"], true);
    let m = &s["mbvh4"];
    assert_eq!(m["mode"], "mbvh4");
    assert_eq!(m["node_bytes"], 128);
    assert_eq!(m["binary_nodes"], plain["nodes"]);
    assert_eq!(m["stream"]["nodes_written"], m["wide_nodes"]);
    assert!(
        m["stream"]["max_open"].as_u64().unwrap() <= s["max_stack_depth"].as_u64().unwrap() + 1
    );
    assert!(m["pass"].is_null() && s["cbvh"].is_null());
    // Same reads; 128-byte wide nodes written instead of 64-byte binary nodes.
    let (wide, binary) = (
        m["wide_nodes"].as_u64().unwrap(),
        plain["nodes"].as_u64().unwrap(),
    );
    let u = |j: &Value, k: &str| j[k].as_u64().unwrap();
    assert_eq!(u(&s, "bytes_read"), u(&plain, "bytes_read"));
    assert_eq!(
        u(&s, "bytes_written") + 64 * binary,
        u(&plain, "bytes_written") + 128 * wide
    );
    let p = run("mbvh4-collapse");
    assert_eq!(p["mbvh4_matches_software"], true);
    let mp = &p["mbvh4"];
    assert_eq!(mp["build_cycles"], plain["cycles"]);
    assert_eq!(
        u(mp, "build_cycles") + u(mp, "collapse_cycles"),
        u(&p, "cycles")
    );
    assert_eq!(mp["pass"]["node_reads"], plain["nodes"]);
    assert_eq!(u(&p, "bytes_read"), u(&plain, "bytes_read") + 64 * binary);
    assert!(u(&s, "cycles") < u(&p, "cycles"));
    // The collapse unit's row in the energy object: only with `output = mbvh4`, before
    // the DRAM, its storage the peak open subtrees' slots.
    let names = |j: &Value| -> Vec<String> {
        j["energy"]["units"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x["unit"].as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(names(&s)[4..], ["MBVH4 collapse unit", "DRAM"]);
    for j in [&plain, &p] {
        assert!(!names(j).contains(&"MBVH4 collapse unit".to_string()));
        assert!(j["energy"]["collapse_unit"].is_null());
    }
    let cu = &s["energy"]["collapse_unit"];
    assert_eq!(u(cu, "storage_bytes"), 128 * u(&m["stream"], "max_open"));
    assert_eq!(u(cu, "fifo_bytes"), 16 * 64);
    assert!(cu["window"].is_null());
    // One tree only.
    assert!(sim_error(&[
        CLOTH,
        "--set",
        "output=mbvh4",
        "--set",
        "highlevel_threshold=18"
    ])
    .contains("highlevel_threshold"));
    assert!(sim_error(&[CLOTH, "--set", "output=mbvh8"]).contains("mbvh4"));
}

/// `output = cbvh4`: the collapse's wide nodes through the wide CBVH encoder, 32 bytes
/// each, equal to the software encoder; modulo coordinates with treelets backtrack less
/// and write fewer bytes than relative ones.
#[test]
fn cbvh4_output_mode() {
    const SOUP: &str = "proc:soup?n=6000";
    let run = |extra: &[&str]| {
        let mut a = vec![SOUP, "--dram", "simple:lpddr3-1600-1x64"];
        a.extend_from_slice(extra);
        sim_json(&a)
    };
    let u = |j: &Value, k: &str| j[k].as_u64().unwrap();
    let m = run(&["--set", "output=mbvh4"]);
    let r = run(&["--set", "output=cbvh4"]);
    assert_eq!(r["config"]["output"], "cbvh4");
    assert_eq!(r["tree_matches_software"], true);
    assert_eq!(r["cbvh4_matches_software"], true);
    assert!(r["mbvh4"].is_null() && r["cbvh"].is_null() && m["cbvh4"].is_null());
    let w = &r["cbvh4"];
    assert_eq!(w["node_bytes"], 32);
    assert_eq!(w["wide_nodes"], m["mbvh4"]["wide_nodes"]);
    assert_eq!(w["stream"]["pairs_written"], w["wide_nodes"]);
    assert_eq!(w["collapse"]["nodes_written"], w["wide_nodes"]);
    assert_eq!(u(w, "backtrack_steps"), u(&w["stream"], "backtrack_reads"));
    assert_eq!(
        u(&r, "bytes_read"),
        u(&m, "bytes_read") + 64 * u(w, "backtrack_steps")
    );
    let m4 = run(&[
        "--set",
        "output=cbvh4",
        "--set",
        "cbvh_coords=modulo",
        "--set",
        "cbvh_treelet_depth=4",
    ]);
    assert_eq!(m4["cbvh4_matches_software"], true);
    assert!(u(&m4["cbvh4"], "backtrack_steps") < u(w, "backtrack_steps"));
    assert!(u(&m4, "bytes_written") < u(&m, "bytes_written"));
    assert!(sim_error(&[
        CLOTH,
        "--set",
        "output=cbvh4",
        "--set",
        "highlevel_threshold=18"
    ])
    .contains("highlevel_threshold"));
}

/// The point mode (issue 18, part 3): the unit's k-d tree over the triangles' centroids
/// equals `bvh::PointTree`, and `--points uniform:N` builds over N points.
#[test]
fn kdtree_points_mode() {
    let grid = [
        "--set",
        "output=kdtree-points",
        "--set",
        "morton_bits=63",
        "--set",
        "morton_grid=box",
        "--set",
        "max_leaf_size=8",
    ];
    let mut a = vec![CLOTH];
    a.extend(grid);
    let j = sim_json(&a);
    assert_eq!(j["tree_matches_software"], true);
    let p = &j["points"];
    let n = j["triangles"].as_u64().unwrap();
    assert_eq!(p["points"].as_u64().unwrap(), n);
    assert_eq!(p["emitted"].as_u64().unwrap(), n - 1);
    assert_eq!(
        p["written"].as_u64().unwrap() + p["collapsed"].as_u64().unwrap(),
        n - 1
    );
    assert_eq!(
        p["tree_nodes"].as_u64().unwrap(),
        2 * p["written"].as_u64().unwrap() + 1
    );
    assert_eq!(p["kind"], "kdtree");
    assert_eq!(
        p["node_bytes"].as_u64().unwrap(),
        64 * p["written"].as_u64().unwrap()
    );
    a.extend(["--points", "uniform:3000"]);
    let u = sim_json(&a);
    assert_eq!(u["triangles"], 3000);
    assert_eq!(u["tree_matches_software"], true);
    // 16-byte elements by default in the point modes; 32 on request: one block of 3000
    // points, so the sort reads the input once.
    assert_eq!(u["config"]["point_element"], 16);
    assert_eq!(u["bytes_read"], 3000 * 16);
    let mut b32 = a.clone();
    b32.extend(["--set", "point_element=32"]);
    let u32 = sim_json(&b32);
    assert_eq!(u32["bytes_read"], 3000 * 32);
    assert_eq!(u32["bytes_written"], u["bytes_written"]);
    assert!(sim_error(&[CLOTH, "--set", "point_element=8"]).contains("16 or 32"));
    // Plane-only k-d nodes: the same tree, 16 bytes per written node.
    let mut pl = a.clone();
    pl.extend(["--set", "point_node=plane"]);
    let up = sim_json(&pl);
    assert_eq!(up["tree_matches_software"], true);
    assert_eq!(up["config"]["point_node"], "plane");
    assert_eq!(up["points"]["written"], u["points"]["written"]);
    assert_eq!(
        up["points"]["node_bytes"].as_u64().unwrap(),
        16 * u["points"]["written"].as_u64().unwrap()
    );
    // The octree of the same points.
    a[2] = "output=octree-points";
    let o = sim_json(&a);
    assert_eq!(o["tree_matches_software"], true);
    assert_eq!(o["points"]["kind"], "octree");
    assert_eq!(o["points"]["points"], 3000);
    // The presets' grid is refused; so is a bad point set.
    let err = sim_error(&[CLOTH, "--set", "output=kdtree-points"]);
    assert!(err.contains("morton_bits = 63"), "{err}");
    let err = sim_error(&[CLOTH, "--points", "uniform:x"]);
    assert!(err.contains("--points expects"), "{err}");
}
