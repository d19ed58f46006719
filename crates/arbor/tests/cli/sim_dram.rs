//! Integration tests of `arbor sim dram`: the binary as a user runs it.

// Not every shared helper is used here.

use crate::common::arbor;
use serde_json::Value;

/// Runs `arbor sim dram --json --quiet ARGS` and parses its output.
fn dram_json(args: &[&str]) -> Value {
    let mut a = vec!["sim", "dram", "--json", "--quiet"];
    a.extend_from_slice(args);
    crate::common::json_of(&a)
}

#[test]
fn sequential_reads_run_near_peak_and_random_reads_do_not() {
    let seq = dram_json(&["--system", "lpddr3-1600-1x64", "--bytes", "262144"]);
    assert_eq!(seq["schema"], "arbor.sim.dram.v1");
    assert_eq!(seq["backend"], "lpddr(lpddr3-1600-1x64)");
    let reference = dram_json(&["--system", "dramsim3:lpddr3-1600-1x64", "--bytes", "262144"]);
    assert_eq!(reference["backend"], "dramsim3(lpddr3-1600-1x64)");
    assert_eq!(reference["stats"], seq["stats"]);
    assert_eq!(seq["stats"]["bytes_read"], 262144);
    assert_eq!(seq["requests"], 4096);
    let util = seq["utilization"].as_f64().unwrap();
    assert!(util > 0.9 && util <= 1.0, "{util}");
    assert!((seq["peak_gb_s"].as_f64().unwrap() - 12.8).abs() < 1e-9);
    assert!(seq["stats"]["energy_pj"]["read_pj"].as_f64().unwrap() > 0.0);
    let random = dram_json(&["--pattern", "random", "--bytes", "262144"]);
    let r = random["utilization"].as_f64().unwrap();
    assert!(r < 0.6 * util, "random {r} vs sequential {util}");
    assert!(random["stats"]["row_misses"].as_u64().unwrap() > 3000);
}

#[test]
fn simple_backend_and_text_output() {
    let v = dram_json(&["--system", "simple:bw=25.6e9,lat=40", "--pattern", "copy"]);
    assert_eq!(v["pattern"], "copy");
    assert!(v["stats"]["energy_pj"].is_null());
    let out = arbor(&["sim", "dram", "--bytes", "4096"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("bandwidth") && text.contains("pJ/bit"),
        "{text}"
    );
}

#[test]
fn bad_input_gives_one_line_and_exit_code_1() {
    for args in [
        vec!["sim", "dram", "--system", "ddr9"],
        vec!["sim", "dram", "--bytes", "0"],
        vec!["sim", "dram", "--request-bytes", "0"],
        vec!["sim", "dram", "--unit-mhz", "0"],
        vec!["sim", "dram", "--system", "simple:bw=oops"],
    ] {
        let out = arbor(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with("arbor: error:") && !err.contains("panicked"),
            "{err}"
        );
    }
}
