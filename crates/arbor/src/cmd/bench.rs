//! `arbor bench`: benchmarks that run Arbor side by side with peer libraries in one process
//! and report ratios, one subcommand each (`bench_*.rs`).

use super::bench_build;
use crate::progress::Ui;

/// Arguments of `arbor bench`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub bench: BenchCommand,
}

/// The benchmarks `arbor bench` runs.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Build speed, SAH and peak memory of Arbor's builders next to Embree 3, obvhs and
    /// the bvh crate on the same meshes, on 1 and 2 threads.
    Build(bench_build::BenchBuildArgs),
}

/// Runs `arbor bench ...`.
pub fn run(args: &BenchArgs, ui: &Ui) -> anyhow::Result<()> {
    match &args.bench {
        BenchCommand::Build(a) => bench_build::run(a, ui),
    }
}
