//! Integration tests of `arbor report system` and `arbor report energy`: the documented
//! JSON document and files on small scenes, and one-line errors for bad options.

use crate::common::{arbor, error, json_of};
use serde_json::Value;

const HAIRBALL: &str = "proc:hairball?n=3000&seed=2";
const CLOTH: &str = "proc:cloth?n=20000";

#[test]
fn report_system_json_and_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let j = json_of(&[
        "report",
        "system",
        "--quiet",
        "--json",
        "--scenes",
        HAIRBALL,
        "--animated",
        CLOTH,
        "--frames",
        "3",
        "--width",
        "32",
        "--height",
        "24",
        "--sample",
        "1",
        "--out",
        out,
    ]);
    assert_eq!(j["schema"], "arbor.report.system.v1");
    let rows = j["table8"].as_array().unwrap();
    // One small scene: primary and diffuse over all scenes (no large set), four builders.
    assert_eq!(rows.len(), 8);
    let builders = ["binned-sah", "hlbvh", "hlbvh+sah", "hlbvh+atrbvh"];
    for r in rows {
        assert!(r["rays"] == "primary" || r["rays"] == "diffuse");
        assert_eq!(r["scenes"], "all");
        assert!(builders.contains(&r["builder"].as_str().unwrap()));
        for k in ["build", "trace", "total"] {
            let v = r[k].as_f64().unwrap();
            assert!(v > 0.0, "{k}: {r}");
            if r["builder"] == "binned-sah" {
                assert_eq!(v, 1.0);
            }
        }
    }
    let scene = &j["scenes"][0];
    assert_eq!(scene["builds"].as_array().unwrap().len(), 4);
    assert_eq!(scene["traces"].as_array().unwrap().len(), 8);
    let anim = &j["animation"][0];
    assert_eq!(anim["scene"], "cloth");
    assert_eq!(anim["times"].as_array().unwrap().len(), 3);
    for rays in anim["rays"].as_array().unwrap() {
        let p = rays["policies"].as_array().unwrap();
        assert_eq!(p.len(), 3);
        assert_eq!(p[0]["policy"], "rebuild");
        assert!(p[0]["frames"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["rebuilt"] == true));
    }
    for f in [
        "table8.md",
        "table8.csv",
        "scenes.md",
        "scenes.csv",
        "fig7-primary.svg",
        "fig7-diffuse.svg",
        "animation.md",
        "system.json",
        "report.md",
    ] {
        let p = dir.path().join(f);
        assert!(p.is_file(), "{f} missing");
    }
    let svg = std::fs::read_to_string(dir.path().join("fig7-diffuse.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("hlbvh+atrbvh trace"));
    let csv = std::fs::read_to_string(dir.path().join("table8.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 8);
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("system.json")).unwrap())
            .unwrap();
    assert_eq!(doc["table8"], j["table8"]);
}

#[test]
fn report_system_bad_options_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let base = ["report", "system", "--quiet", "--out", out];
    let run = |extra: &[&str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        error(&a)
    };
    assert!(run(&["--sample", "0"]).contains("--sample"));
    assert!(run(&["--dram", "ddr9", "--scenes", HAIRBALL]).contains("ddr9"));
    assert!(run(&["--node", "7nm"]).contains("unknown process node"));
    assert!(run(&["--threshold=-1"]).contains("--threshold"));
    let e = run(&["--scenes", "none", "--animated", HAIRBALL]);
    assert!(e.contains("static scene"), "{e}");
    let e = run(&["--scenes", "/nonexistent.ply", "--animated", "none"]);
    assert!(e.contains("nonexistent"), "{e}");
    // Nothing but the error: no files were written for the failed runs' results.
    assert!(!dir.path().join("report.md").exists());
}

#[test]
fn report_energy_components_and_reproductions() {
    let dir = tempfile::tempdir().unwrap();
    let out = arbor(&[
        "report",
        "energy",
        "--quiet",
        "--scenes",
        "proc:cloth?n=20000",
        "--p4-scenes",
        HAIRBALL,
        "--out",
        dir.path().to_str().unwrap(),
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["schema"], "arbor.report.energy.v1");
    let comps = j["components"].as_array().unwrap();
    assert!(comps
        .iter()
        .any(|c| c["kind"] == "sram" && c["node"] == "28nm"));
    assert!(comps.iter().any(|c| c["kind"] == "dram"));
    assert_eq!(j["p4"]["rows"].as_array().unwrap().len(), 2);
    for f in j["files"].as_array().unwrap() {
        let p = dir.path().join(f.as_str().unwrap());
        assert!(p.is_file(), "{} missing", p.display());
    }
    let t7 = std::fs::read_to_string(dir.path().join("p2/table7.md")).unwrap();
    assert!(
        t7.contains("Table VII") || t7.contains("Tables IV and VII"),
        "{t7}"
    );
    let e = error(&[
        "report",
        "energy",
        "--quiet",
        "--cell",
        "xx",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(e.contains("unknown SRAM cell type"), "{e}");
}

#[test]
fn report_sensitivity_json_and_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let j = json_of(&[
        "report",
        "sensitivity",
        "--quiet",
        "--json",
        "--scenes",
        HAIRBALL,
        "--p4-scene",
        "none",
        "--only",
        "dram_energy,trv_stages",
        "--width",
        "32",
        "--height",
        "24",
        "--sample",
        "1",
        "--out",
        out,
    ]);
    assert_eq!(j["schema"], "arbor.report.sensitivity.v1");
    let rows = j["rows"].as_array().unwrap();
    // One small scene: Table VIII's primary and diffuse, all scenes, three builders, three
    // columns; Table III's SAH of four builders; [P2] MergeTree's three times, two
    // speed-ups and the traffic of the scene (Tables III and VI), four means per system
    // (VII), four units and total (IV).
    assert_eq!(rows.len(), 18 + 4 + 6 + 12 + 10);
    for r in rows {
        for k in [
            "figure", "unit", "thesis", "default", "low", "high", "driver",
        ] {
            assert!(r.get(k).is_some(), "{k} missing in {r}");
        }
        let (lo, d, hi) = (
            r["low"].as_f64().unwrap(),
            r["default"].as_f64().unwrap(),
            r["high"].as_f64().unwrap(),
        );
        assert!(lo <= d && d <= hi, "{r}");
    }
    // The default, full DRAM energy, TRV depths 4 and 8.
    assert_eq!(j["variants"].as_array().unwrap().len(), 4);
    for f in ["sensitivity.md", "sensitivity.csv", "sensitivity.json"] {
        assert!(dir.path().join(f).is_file(), "{f}");
    }
    let e = error(&[
        "report",
        "sensitivity",
        "--quiet",
        "--only",
        "warp_drive",
        "--out",
        out,
    ]);
    assert!(e.contains("unknown assumption 'warp_drive'"), "{e}");
    let e = error(&[
        "report",
        "sensitivity",
        "--quiet",
        "--energy",
        "fpu_energy=abacus",
        "--out",
        out,
    ]);
    assert!(e.contains("abacus"), "{e}");
}
