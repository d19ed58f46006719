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
#[allow(dead_code)] // not every test file uses it
pub fn json(command: &str, args: &[&str]) -> Value {
    let mut a = vec![command, "--json", "--quiet"];
    a.extend_from_slice(args);
    let out = arbor(&a);
    assert!(
        out.status.success(),
        "arbor {a:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}
