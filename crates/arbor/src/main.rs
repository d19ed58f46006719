//! The `arbor` command: scene inspection, and (as the project grows) BVH builds, rendering,
//! hardware simulation, benchmarks and reports. Every subcommand is a thin layer over the
//! library crates; `--json` output is the stable interface for scripts (see
//! `docs/cli-json.md`).

mod alloc;
mod cmd;
mod progress;

/// Counts live and peak bytes for `arbor bench build`'s memory column.
#[global_allocator]
static ALLOC: alloc::Counting = alloc::Counting;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Arbor: BVH construction, compression and traversal for animated ray tracing, and
/// cycle-level models of the hardware that does it.
#[derive(Parser)]
#[command(name = "arbor", version, about, long_about = None)]
struct Cli {
    /// Hide progress bars and warnings.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print a scene's triangle count, bounds, frames and load time.
    Info(cmd::info::InfoArgs),
    /// Run the main job on the bundled default scene (or another) and summarize it.
    Demo(cmd::demo::DemoArgs),
    /// Build a BVH over a scene with a named builder, validate it, report SAH and timings.
    Build(cmd::build::BuildArgs),
    /// Run a cycle-level hardware model (`arbor sim mergetree`, `arbor sim dram`).
    Sim(cmd::sim::SimArgs),
    /// Compress a scene's LBVH into a CBVH (or refit one) and report backtracking, traffic
    /// and quality ([P3]).
    Cbvh(cmd::cbvh::CbvhArgs),
    /// Trace an image through a BVH (primary, diffuse or shadow rays); write the image,
    /// depth buffer, heatmap, statistics and traversal log.
    Render(Box<cmd::render::RenderArgs>),
    /// Check a traversal log and print its totals.
    LogInfo(cmd::log_info::LogInfoArgs),
    /// Regenerate a table or figure of the thesis (CSV, Markdown, SVG).
    Report(cmd::report::ReportArgs),
    /// Benchmark Arbor against peer libraries in one run (`arbor bench build`).
    Bench(cmd::bench::BenchArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let ui = progress::Ui { quiet: cli.quiet };
    let result = match cli.command {
        Command::Info(a) => cmd::info::run(&a, &ui),
        Command::Demo(a) => cmd::demo::run(&a, &ui),
        Command::Build(a) => cmd::build::run(&a, &ui),
        Command::Sim(a) => cmd::sim::run(&a, &ui),
        Command::Cbvh(a) => cmd::cbvh::run(&a, &ui),
        Command::Report(a) => cmd::report::run(&a, &ui),
        Command::Render(a) => cmd::render::run(&a, &ui),
        Command::LogInfo(a) => cmd::log_info::run(&a, &ui),
        Command::Bench(a) => cmd::bench::run(&a, &ui),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and its causes, outermost first, skipping a cause whose
            // text the line already holds (library errors often include their source).
            let mut line = String::new();
            for cause in e.chain().map(|c| c.to_string()) {
                if line.contains(&cause) {
                    continue;
                }
                if !line.is_empty() {
                    line.push_str(": ");
                }
                line.push_str(&cause);
            }
            eprintln!("arbor: error: {}", line.replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}
