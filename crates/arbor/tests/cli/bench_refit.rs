//! Integration tests of `arbor bench refit`: the JSON document on the bundled animated
//! character (every Arbor kernel's refit agreeing exactly with brute force after the last
//! frame, the Embree row only in a build with Embree, a note otherwise), the other
//! formats and `--out`, and bad arguments.

use crate::common::arbor;
use serde_json::Value;

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn json_has_every_update_and_exact_arbor_hits() {
    let out = arbor(&[
        "bench", "refit", "--quiet", "--frames", "4", "--runs", "2", "--json",
    ]);
    ok(&out);
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["schema"], "arbor.bench.refit.v1");
    assert_eq!(j["rounds"], 2);
    assert!(!j["cpu_model"].as_str().unwrap().is_empty());
    assert_eq!(j["embree"], cfg!(feature = "embree"));
    let notes = j["notes"].as_array().unwrap();
    assert_eq!(
        notes
            .iter()
            .any(|n| n.as_str().unwrap().contains("without Embree")),
        !cfg!(feature = "embree")
    );
    let rows = j["rows"].as_array().unwrap();
    let embree = cfg!(feature = "embree") as usize;
    assert_eq!(rows.len(), 4 + embree, "{rows:#?}");
    for r in rows {
        let tracer = r["tracer"].as_str().unwrap();
        assert_eq!(r["frames"], 4, "{tracer}");
        assert!(r["triangles"].as_u64().unwrap() > 1000);
        let best = r["best_ms_per_frame"].as_f64().unwrap();
        assert!(best > 0.0 && best <= r["median_ms_per_frame"].as_f64().unwrap());
        let agreement = r["agreement"].as_f64().unwrap();
        if tracer.starts_with("arbor") {
            // A refitted kernel traces exactly like brute force over the moved triangles.
            assert_eq!(agreement, 1.0, "{tracer}");
        } else {
            assert!(agreement > 0.99, "{tracer}: {agreement}");
        }
        assert_eq!(r["vs_embree"].is_null(), embree == 0, "{tracer}");
    }
}

#[test]
fn formats_and_out_folder() {
    let dir = tempfile::tempdir().unwrap();
    let out = arbor(&[
        "bench",
        "refit",
        "--quiet",
        "--frames",
        "2",
        "--runs",
        "1",
        "--format",
        "markdown",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    ok(&out);
    let md = String::from_utf8(out.stdout).unwrap();
    assert!(md.contains("| scene | triangles | tracer |"), "{md}");
    assert!(md.contains("Accel::refit"));
    for f in [
        "bench-refit.txt",
        "bench-refit.md",
        "bench-refit.csv",
        "bench-refit.json",
    ] {
        assert!(dir.path().join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(dir.path().join("bench-refit.csv")).unwrap();
    assert!(csv.starts_with("scene,triangles,frames,tracer,"));
}

#[test]
fn bad_arguments_are_one_line_errors() {
    // A static mesh: one triangle.
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("one.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
         end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    )
    .unwrap();
    for (args, want) in [
        (&["--frames", "1"][..], "--frames"),
        (&["--runs", "0"][..], "--runs"),
        (&[ply.to_str().unwrap()][..], "not animated"),
    ] {
        let mut a = vec!["bench", "refit", "--quiet"];
        a.extend_from_slice(args);
        let out = arbor(&a);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}
