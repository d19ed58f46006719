//! Helpers shared by the CLI integration tests: run the `arbor` binary as a user would.

use serde_json::Value;
use std::process::{Command, Output};

/// Runs `arbor ARGS` and returns its exit status and output.
pub fn arbor(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_arbor"))
        .args(args)
        .output()
        .expect("run arbor")
}

/// Runs `arbor COMMAND --json --quiet ARGS` and parses its output, failing with stderr.
pub fn json(command: &str, args: &[&str]) -> Value {
    let mut a = vec![command, "--json", "--quiet"];
    a.extend_from_slice(args);
    json_of(&a)
}

/// Runs `arbor ARGS` (which ask for JSON) and parses its output, failing with stderr.
pub fn json_of(a: &[&str]) -> Value {
    let out = arbor(a);
    assert!(
        out.status.success(),
        "arbor {a:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

/// Runs `arbor ARGS` expecting exit status 1 with a one-line error on stderr and nothing on
/// stdout; returns that line.
pub fn error(args: &[&str]) -> String {
    let out = arbor(args);
    assert_eq!(
        out.status.code(),
        Some(1),
        "arbor {args:?} did not fail with 1"
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.lines().count(), 1, "expected one line, got: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.stdout.is_empty(), "printed a result on failure");
    err
}
