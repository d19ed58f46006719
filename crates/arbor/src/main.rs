//! The `arbor` command: scene inspection, BVH builds, rendering, hardware simulation,
//! benchmarks and reports. The parser and subcommands live in the library (`src/lib.rs`),
//! which the Python package shares; `--json` output is the stable interface for scripts
//! (see `docs/cli-json.md`).

/// Counts live and peak bytes for `arbor bench build`'s memory column.
#[global_allocator]
static ALLOC: arbor::alloc::Counting = arbor::alloc::Counting;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = arbor::Cli::parse();
    let ui = arbor::progress::Ui {
        quiet: false,
        json: None,
    };
    match cli.run(&ui) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("arbor: error: {}", arbor::one_line(&e));
            ExitCode::FAILURE
        }
    }
}
