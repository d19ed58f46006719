//! Integration tests of `arbor bench compare` on hand-written records (fixtures/record-*.json):
//! which entries are flagged, the CPU warning, `--fail-on-regression`, and bad input.
//! No timing is measured here.

use crate::common::{arbor, error, json_of};

fn fixture(name: &str) -> String {
    format!("{}/tests/cli/fixtures/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn compare(args: &[&str]) -> std::process::Output {
    let mut a = vec!["bench", "compare"];
    a.extend_from_slice(args);
    arbor(&a)
}

/// The verdict column of the text table for `subject`.
fn verdict_of<'a>(text: &'a str, subject: &str) -> &'a str {
    let line = text
        .lines()
        .find(|l| l.starts_with("scene.ply") && l.split_whitespace().nth(1) == Some(subject))
        .unwrap_or_else(|| panic!("no row for {subject}: {text}"));
    line.split("%  ")
        .nth(1)
        .unwrap_or_else(|| panic!("{line}"))
        .trim()
}

#[test]
fn flags_regressions_beyond_noise_only() {
    let (old, new) = (fixture("record-old.json"), fixture("record-new.json"));
    let out = compare(&[&old, &new]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    // 1.20 with spreads of 2% and 1%: beyond the 5% floor.
    assert_eq!(verdict_of(&text, "binned-sah"), "REGRESSION", "{text}");
    // 1.04: within the floor.
    assert_eq!(verdict_of(&text, "hlbvh"), "within noise", "{text}");
    // 1.10, but the old run varied by 15% between its own runs.
    assert_eq!(verdict_of(&text, "sweep-sah"), "within noise", "{text}");
    assert_eq!(verdict_of(&text, "lbvh"), "faster", "{text}");
    assert!(
        text.contains("4 shared entries: 1 regressions, 1 faster, 2 within noise"),
        "{text}"
    );
    assert!(
        text.contains("only in old: scene.ply / atrbvh / 1 threads"),
        "{text}"
    );
    assert!(
        text.contains("only in new: scene.ply / lbvh / 2 threads"),
        "{text}"
    );
    assert!(!text.contains("warning"), "{text}");
    // A higher floor absorbs the regression.
    let out = compare(&[&old, &new, "--noise", "25", "--fail-on-regression"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(verdict_of(&text, "binned-sah"), "within noise", "{text}");
    // JSON: the same verdicts, exact ratios and noise.
    let j = json_of(&["bench", "compare", &old, &new, "--json"]);
    assert_eq!(j["schema"], "arbor.bench.compare.v1");
    assert_eq!(j["regressions"], 1);
    assert_eq!(j["cpu_mismatch"], false);
    let e = j["entries"].as_array().unwrap();
    let verdicts: Vec<&str> = e.iter().map(|e| e["verdict"].as_str().unwrap()).collect();
    assert_eq!(verdicts, ["regression", "same", "same", "faster"]);
    assert!((e[0]["ratio"].as_f64().unwrap() - 1.2).abs() < 1e-12);
    assert!((e[0]["noise"].as_f64().unwrap() - 0.05).abs() < 1e-12);
    assert!((e[2]["noise"].as_f64().unwrap() - 0.15).abs() < 1e-12);
}

#[test]
fn fail_on_regression_sets_the_status() {
    let (old, new) = (fixture("record-old.json"), fixture("record-new.json"));
    let out = compare(&[&old, &new, "--fail-on-regression"]);
    assert_eq!(out.status.code(), Some(1));
    // The table still comes out, and one error line says why.
    assert!(String::from_utf8_lossy(&out.stdout).contains("REGRESSION"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("1 entry regressed"), "{err}");
    // Comparing a record with itself: nothing moves.
    let out = compare(&[&old, &old, "--fail-on-regression"]);
    assert!(out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("0 regressions, 0 faster, 5 within noise")
    );
}

#[test]
fn different_cpus_are_warned_about() {
    let out = compare(&[
        &fixture("record-old.json"),
        &fixture("record-other-cpu.json"),
    ]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("warning: CPU models differ ('Test CPU 3000' vs 'Other CPU 9000')")
            && text.contains("not comparable"),
        "{text}"
    );
    let j = json_of(&[
        "bench",
        "compare",
        &fixture("record-old.json"),
        &fixture("record-other-cpu.json"),
        "--json",
    ]);
    assert_eq!(j["cpu_mismatch"], true);
}

#[test]
fn bad_input_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, body: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, body).unwrap();
        p.to_str().unwrap().to_string()
    };
    let old = fixture("record-old.json");
    let empty = write("empty.json", "  \n");
    let garbage = write("garbage.json", "{ not json");
    let other = write(
        "other.json",
        r#"{"schema": "arbor.bench.build.v1", "rows": []}"#,
    );
    let no_schema = write("noschema.json", r#"{"entries": []}"#);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&old).unwrap()).unwrap();
    v["entries"] = serde_json::json!([]);
    let no_entries = write("none.json", &v.to_string());
    let missing_field = write(
        "missing.json",
        r#"{"schema": "arbor.bench.record.v1", "entries": [{"scene": "s"}]}"#,
    );
    let negative = write(
        "negative.json",
        &std::fs::read_to_string(&old)
            .unwrap()
            .replace("\"best_ms\": 100.0", "\"best_ms\": -1.0"),
    );
    let disjoint = write(
        "disjoint.json",
        &std::fs::read_to_string(&old)
            .unwrap()
            .replace("scene.ply", "other.ply"),
    );
    for (file, want) in [
        (
            "no/such/record.json".to_string(),
            "cannot read no/such/record.json",
        ),
        (empty, "empty file"),
        (garbage, "not valid JSON"),
        (
            other,
            "schema 'arbor.bench.build.v1' is not a benchmark record",
        ),
        (no_schema, "no \"schema\" field"),
        (no_entries, "no entries"),
        (missing_field, "not a valid arbor.bench.record.v1 record"),
        (negative, "times must be positive"),
        (disjoint, "share no (scene, subject, threads) entry"),
    ] {
        let e = error(&["bench", "compare", &old, &file]);
        assert!(e.contains(want), "{file}: {e}");
    }
    let e = error(&["bench", "compare", &old, &old, "--noise", "-1"]);
    assert!(e.contains("--noise"), "{e}");
    let e = error(&["bench", "compare", &old]);
    assert!(e.contains("NEW"), "{e}");
}

#[test]
fn bench_build_writes_a_record_that_compares() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = arbor(&[
        "bench",
        "build",
        "--quiet",
        "proc:soup?n=2000",
        "--runs",
        "2",
        "--threads",
        "1",
        "--builders",
        "lbvh,binned-sah",
        "--record",
        d,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // One folder, named after the CPU, holding build.json.
    let sub: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sub.len(), 1, "{sub:?}");
    let rec = sub[0].join("build.json");
    let j: serde_json::Value = serde_json::from_slice(&std::fs::read(&rec).unwrap()).unwrap();
    assert_eq!(j["schema"], "arbor.bench.record.v1");
    assert_eq!(j["bench"], "build");
    for k in ["cpu_model", "date_utc", "command"] {
        assert!(!j[k].as_str().unwrap().is_empty(), "{k}");
    }
    assert!(j["cpus"].as_u64().unwrap() >= 1);
    let entries = j["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 2);
    for e in entries {
        assert_eq!(e["scene"], "proc:soup?n=2000");
        assert_eq!(e["runs"], 2);
        assert!(e["best_ms"].as_f64().unwrap() <= e["median_ms"].as_f64().unwrap());
        assert!(e["spread"].as_f64().unwrap() >= 0.0);
    }
    let r = rec.to_str().unwrap();
    let out = compare(&[r, r]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("2 shared entries: 0 regressions"));
}
