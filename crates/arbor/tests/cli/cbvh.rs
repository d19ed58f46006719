//! Integration tests of `arbor cbvh` and `arbor report cbvh`.

use crate::common::{arbor, json};

#[test]
fn cbvh_json_has_the_documented_fields_and_encloses() {
    for (enc, coords, treelet) in [
        ("topdown", "relative", "1"),
        ("bottomup", "relative", "1"),
        ("bottomup", "modulo", "3"),
        // Without treelets plane sharing backtracks more than it saves
        // (docs/beyond-thesis.md); with them it saves traffic.
        ("bottomup", "plane-sharing", "4"),
    ] {
        let v = json(
            "cbvh",
            &[
                "proc:soup?n=3000",
                "--encoder",
                enc,
                "--coords",
                coords,
                "--treelet",
                treelet,
            ],
        );
        assert_eq!(v["schema"], "arbor.cbvh.v1");
        assert_eq!(v["coords"], coords);
        for k in [
            "nodes",
            "backtrack_steps",
            "backtrack_unchanged",
            "traffic_bytes",
            "decoded_encloses_original",
            "sah_vs_uncompressed",
        ] {
            assert!(!v[k].is_null(), "{k} missing for {enc}");
        }
        assert_eq!(v["decoded_encloses_original"], true);
        assert!(v["backtrack_unchanged"].as_u64() <= v["backtrack_steps"].as_u64());
        assert!(v["sah_vs_uncompressed"].as_f64().unwrap() >= 1.0);
        let ratio = v["traffic_vs_topdown"].as_f64().unwrap();
        if enc == "topdown" {
            assert_eq!(v["backtrack_steps"], 0);
            assert_eq!(ratio, 1.0);
        } else {
            assert!(ratio < 1.0, "{ratio}");
        }
    }
}

#[test]
fn cbvh_refit_from_an_earlier_time() {
    let v = json(
        "cbvh",
        &[
            "proc:cloth?n=2000&duration=1&fps=10",
            "--time",
            "0.5",
            "--refit-from",
            "0",
            "--coords",
            "modulo",
        ],
    );
    assert_eq!(v["refit_from_s"], 0.0);
    assert_eq!(v["decoded_encloses_original"], true);
    assert!(v["traffic_vs_topdown"].as_f64().unwrap() < 1.0);
}

#[test]
fn cbvh_bad_arguments_fail_with_one_line() {
    for args in [
        vec!["cbvh", "proc:soup?n=100", "--treelet", "0"],
        vec!["cbvh", "proc:soup?n=100", "--bits", "9"],
        vec![
            "cbvh",
            "proc:soup?n=100",
            "--encoder",
            "topdown",
            "--treelet",
            "2",
        ],
        vec!["cbvh", "/no/such/scene.ply"],
        // Time options are checked as in every other command (issue 15).
        vec!["cbvh", "proc:soup?n=100", "--time", "nan"],
        vec!["cbvh", "proc:soup?n=100", "--frame", "100000"],
        vec![
            "cbvh",
            "proc:cloth?n=200",
            "--time",
            "1",
            "--refit-from",
            "inf",
        ],
    ] {
        let out = arbor(&args);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.starts_with("arbor: error:"), "{err}");
    }
}

#[test]
fn report_cbvh_writes_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r");
    let o = arbor(&[
        "--quiet",
        "report",
        "cbvh",
        "--scenes",
        "cloth,proc:soup?n=3000",
        "--runtime-dram",
        "simple:lpddr3-1600-2x32",
        "--out",
        out.to_str().unwrap(),
        "--trace-size",
        "64x36",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "trace_quality.csv",
        "trace_quality.svg",
        "watertight.csv",
        "report.md",
        "table1.csv",
        "table1.svg",
        "table3.csv",
        "quality.csv",
        "fig7.csv",
        "fig7.svg",
        "fig10.csv",
        "fig10.svg",
        "table2.csv",
        "table2-dram.csv",
        "table2.svg",
    ] {
        let p = out.join(f);
        assert!(
            p.exists() && std::fs::metadata(&p).unwrap().len() > 0,
            "{f}"
        );
    }
    let t1 = std::fs::read_to_string(out.join("table1.csv")).unwrap();
    // 9 metric rows x 9 variants, plus the header.
    assert_eq!(t1.lines().count(), 82);
    assert!(t1.contains("traffic_lbvh,avg,M4,"));
    // Tree quality by ray tracing: two scenes, primary and diffuse rays, the same rays
    // through both trees; the CBVH costs at least as many box tests (looser boxes) and the
    // bottom-up CBVH exactly what the top-down one costs.
    let q = std::fs::read_to_string(out.join("trace_quality.csv")).unwrap();
    let head: Vec<&str> = q.lines().next().unwrap().split(',').collect();
    let col = |name: &str| head.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = q.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4, "{q}");
    for r in &rows {
        let f = |name: &str| r[col(name)].parse::<f64>().unwrap();
        assert!(f("ray_count") > 2000.0, "{q}");
        assert!(
            f("cbvh_box_tests_per_ray") >= f("bvh_box_tests_per_ray"),
            "{q}"
        );
        assert_eq!(r[col("bottomup_same_counts")], "true", "{q}");
        assert_eq!(f("thesis_box_increase"), 0.08);
    }
    // The watertightness check saw every box test of those renders, without a violation.
    let w = std::fs::read_to_string(out.join("watertight.csv")).unwrap();
    assert_eq!(w.lines().count(), 5, "{w}");
    for l in w.lines().skip(1) {
        let v: Vec<&str> = l.split(',').collect();
        assert!(v[3].parse::<u64>().unwrap() > 1000, "{w}");
        assert_eq!((v[5], v[6]), ("0", "0"), "{w}");
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("Watertightness") && md.contains("+8.0%"),
        "{md}"
    );
    // Table 2: four alternatives per scene, the cloth beside [P3]'s.
    let t2 = std::fs::read_to_string(out.join("table2.csv")).unwrap();
    assert_eq!(t2.lines().count(), 1 + 2 * 4);
    let cloth_r = t2
        .lines()
        .find(|l| l.starts_with("cloth,") && l.contains(",R,"))
        .unwrap();
    assert!(cloth_r.contains(",2.4,"), "{cloth_r}");
    assert!(md.contains("Table 2 analogue"));
    // --no-runtime skips it.
    let out2 = dir.path().join("r2");
    let o = arbor(&[
        "--quiet",
        "report",
        "cbvh",
        "--scenes",
        "proc:soup?n=2000",
        "--no-sweep",
        "--no-trace",
        "--no-runtime",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out2.join("table2.csv").exists());
}
