//! Integration tests of `arbor sim rtunit` and `arbor report rtunit`: the documented JSON
//! fields, the software check, FIFO sizing, sampling, and one-line errors for bad options.

use crate::common::{arbor, error, json_of};
use serde_json::Value;

const CITY: &str = "proc:city?n=3000&seed=2";

fn rt_json(args: &[&str]) -> Value {
    let mut a = vec![
        "sim", "rtunit", "--json", "--quiet", CITY, "--width", "48", "--height", "32",
    ];
    a.extend_from_slice(args);
    json_of(&a)
}

#[test]
fn json_has_the_documented_fields() {
    for tree in ["bvh2", "mbvh4"] {
        for rays in ["primary", "diffuse"] {
            let j = rt_json(&["--tree", tree, "--rays", rays, "--bounces", "2"]);
            assert_eq!(j["schema"], "arbor.sim.rtunit.v1");
            assert_eq!(j["tree"], tree);
            assert_eq!(j["ray_kind"], rays);
            for k in [
                "cycles",
                "rays",
                "mrps",
                "dram_bytes_read",
                "dram_bytes_written",
                "bus_utilization",
                "max_stack_depth",
                "frame_dram_mb",
            ] {
                assert!(j[k].is_number(), "{k}: {}", j[k]);
            }
            assert_eq!(j["hits_match_software"], true);
            let split = &j["traffic_split"];
            let parts: u64 = [
                "node_first_bytes",
                "node_refetch_bytes",
                "triangle_first_bytes",
                "triangle_refetch_bytes",
            ]
            .iter()
            .map(|k| split[k].as_u64().unwrap())
            .sum();
            assert_eq!(parts, j["counted_dram_bytes"].as_u64().unwrap());
            assert!(j["rays"].as_u64().unwrap() >= 48 * 32);
            assert!(j["dram_bytes_read"].as_u64().unwrap() > 0);
            let caches = j["caches"].as_array().unwrap();
            assert_eq!(caches.len(), 3);
            assert!(caches
                .iter()
                .all(|c| c["hit_rate"].is_number() && c["stats"]["accesses"].is_number()));
            let units = j["units"].as_array().unwrap();
            assert_eq!(units.len(), 4 + 3, "scheduler, 4 TRV, IST, node cache");
            assert!(units
                .iter()
                .all(|u| u["busy"].is_number() && u["stalls"].is_array()));
            let fifos = j["fifos"].as_array().unwrap();
            assert_eq!(fifos.len(), 6);
            assert!(fifos
                .iter()
                .all(|f| f["capacity"] == 32 && f["high_water"].is_number()));
        }
    }
}

#[test]
fn fifo_sizing_prints_the_sized_fifos() {
    let out = arbor(&[
        "sim",
        "rtunit",
        "--quiet",
        CITY,
        "--width",
        "32",
        "--height",
        "16",
        "--size-fifos",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("sized from 32"), "{text}");
    let j = rt_json(&["--size-fifos"]);
    for f in j["fifos"].as_array().unwrap() {
        let c = f["capacity"].as_u64().unwrap();
        assert!(c.is_power_of_two() && c <= 32, "{f}");
    }
}

#[test]
fn any_builder_can_make_the_tree() {
    for (tree, builder) in [
        ("bvh2", "hlbvh"),
        ("cbvh", "lbvh"),
        ("mbvh4", "mbvh4-collapse"),
    ] {
        let j = rt_json(&["--tree", tree, "--builder", builder]);
        assert_eq!(j["hits_match_software"], true, "{tree} {builder}");
    }
    let e = error(&[
        "sim",
        "rtunit",
        "--quiet",
        CITY,
        "--tree",
        "bvh2",
        "--builder",
        "mbvh4-topdown",
    ]);
    assert!(e.contains("needs a binary tree"), "{e}");
    let e = error(&["sim", "rtunit", "--quiet", CITY, "--builder", "nope"]);
    assert!(e.contains("unknown builder 'nope'"), "{e}");
}

/// MergeTree's MBVH4 (the streaming collapses) against the offline collapse of the same
/// HLBVH tree (`--collapse-from`), as in `docs/beyond-thesis.md`.
#[test]
fn streaming_and_offline_collapses_of_the_hlbvh_tree() {
    let mut nodes = Vec::new();
    for b in [
        &["--builder", "mbvh4-stream"][..],
        &["--builder", "mbvh4-stream-w4"],
        &["--builder", "mbvh4-collapse", "--collapse-from", "hlbvh"],
        &["--builder", "mbvh4-collapse"],
    ] {
        let mut a = vec!["--tree", "mbvh4"];
        a.extend_from_slice(b);
        let j = rt_json(&a);
        assert_eq!(j["hits_match_software"], true, "{b:?}");
        nodes.push(j["tree_nodes"].as_u64().unwrap());
    }
    // The collapses of HLBVH differ from the binned SAH tree's, and from one another.
    assert_ne!(nodes[2], nodes[3]);
    assert_ne!(nodes[0], nodes[2]);
    let e = error(&[
        "sim",
        "rtunit",
        "--quiet",
        CITY,
        "--tree",
        "mbvh4",
        "--collapse-from",
        "hlbvh",
    ]);
    assert!(e.contains("--builder mbvh4-collapse"), "{e}");
    let e = error(&[
        "sim",
        "rtunit",
        "--quiet",
        CITY,
        "--tree",
        "mbvh4",
        "--builder",
        "mbvh4-collapse",
        "--collapse-from",
        "nope",
    ]);
    assert!(e.contains("nope"), "{e}");
}

#[test]
fn set_overrides_reach_the_model() {
    let j = rt_json(&["--set", "l2_bytes=65536", "--set", "trv_units=2"]);
    assert_eq!(j["config"]["l2_bytes"], 65536);
    assert_eq!(j["units"].as_array().unwrap().len(), 2 + 3);
}

#[test]
fn bad_options_are_one_line_errors() {
    let base = [
        "sim", "rtunit", "--quiet", CITY, "--width", "8", "--height", "8",
    ];
    let with = |extra: &[&str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        error(&a)
    };
    assert!(with(&["--tree", "kd"]).contains("unknown tree"));
    assert!(with(&["--rays", "shadow"]).contains("unknown --rays"));
    assert!(with(&["--set", "l1_bytes=0"]).contains("l1_bytes"));
    assert!(with(&["--set", "stacks_per_trv=0"]).contains("stacks_per_trv"));
    assert!(with(&["--set", "nonsense=1"]).contains("known:"));
    assert!(with(&["--set", "l2_bytes=3000"]).contains("l2_bytes"));
    assert!(with(&["--sample", "0"]).contains("sample"));
    assert!(with(&["--bounces", "100000", "--rays", "diffuse"]).contains("bounces"));
    let e = error(&["sim", "rtunit", "--quiet", CITY, "--width", "0"]);
    assert!(e.contains("0x720") || e.contains("width"), "{e}");
    let e = error(&[
        "sim", "rtunit", "--quiet", CITY, "--width", "65536", "--height", "65536",
    ]);
    assert!(e.contains("pixels"), "{e}");
    assert!(with(&["--set", "dram=nowhere"]).contains("unknown memory system"));
    assert!(with(&["--time", "NaN"]).contains("finite"));
    let e = error(&["sim", "rtunit", "--quiet", "no-such-file.ply"]);
    assert!(e.contains("no-such-file"), "{e}");
}

#[test]
fn report_writes_the_table_beside_the_thesis() {
    let dir = tempfile::tempdir().unwrap();
    let out = arbor(&[
        "report",
        "rtunit",
        "--quiet",
        "--scenes",
        CITY,
        "--width",
        "64",
        "--height",
        "32",
        "--bounces",
        "1",
        "--check-sample",
        "2",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(dir.path().join("table2.md")).unwrap();
    assert!(
        md.contains("| city | primary |") && md.contains("| city | diffuse |"),
        "{md}"
    );
    let j: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("table2.json")).unwrap())
            .unwrap();
    assert_eq!(j["schema"], "arbor.report.rtunit.v1");
    assert_eq!(j["rows"].as_array().unwrap().len(), 2);
    for r in j["rows"].as_array().unwrap() {
        assert_eq!(r["bvh"]["hits_match_software"], true);
        assert_eq!(r["mbvh4"]["hits_match_software"], true);
    }
    let csv = std::fs::read_to_string(dir.path().join("table2.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4);
    let sampling = std::fs::read_to_string(dir.path().join("sampling.md")).unwrap();
    assert_eq!(sampling.lines().count(), 2 + 4, "{sampling}");
}
