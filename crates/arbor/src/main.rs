//! The `arbor` command: scene inspection, BVH builds, rendering, hardware simulation,
//! benchmarks and reports. The parser and subcommands live in the library (`src/lib.rs`),
//! which the Python package shares; `--json` output is the stable interface for scripts
//! (see `docs/cli-json.md`).

/// Counts live and peak bytes for `arbor bench build`'s memory column.
#[global_allocator]
static ALLOC: arbor::alloc::Counting = arbor::alloc::Counting;

use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = match arbor::Cli::try_parse_from(std::env::args_os()) {
        Ok(cli) => cli,
        // `--help` and `--version`: their text on stdout, status 0.
        Err(e) if !e.use_stderr() => e.exit(),
        // A bad command line is an error like any other: one line, status 1.
        Err(e) => {
            eprintln!(
                "arbor: error: {} (see 'arbor --help')",
                arbor::arg_error_line(&e)
            );
            return ExitCode::FAILURE;
        }
    };
    let ui = arbor::progress::Ui {
        quiet: false,
        json: None,
        silent: false,
    };
    match cli.run(&ui) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("arbor: error: {}", arbor::one_line(&e));
            ExitCode::FAILURE
        }
    }
}
