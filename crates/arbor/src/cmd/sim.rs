//! `arbor sim`: the hardware models, one subcommand each (`sim_*.rs`).

use super::{sim_dram, sim_mergetree, sim_rtunit};
use crate::progress::Ui;

/// Arguments of `arbor sim`.
#[derive(clap::Args, Debug)]
pub struct SimArgs {
    #[command(subcommand)]
    pub model: SimCommand,
}

/// The hardware models `arbor sim` runs.
#[derive(clap::Subcommand, Debug)]
pub enum SimCommand {
    /// Simulate the MergeTree HLBVH builder (thesis P2) over a scene.
    Mergetree(sim_mergetree::MergetreeArgs),
    /// Drive a memory system with a synthetic access pattern; report bandwidth, latency,
    /// row hits, DRAM commands and energy.
    Dram(sim_dram::DramArgs),
    /// Simulate the ray-tracing accelerator (thesis P4: TRV and IST pipelines, caches,
    /// DRAM) with a binary BVH or a 4-wide MBVH over a scene.
    Rtunit(sim_rtunit::RtunitArgs),
}

/// Runs `arbor sim ...`.
pub fn run(args: &SimArgs, ui: &Ui) -> anyhow::Result<()> {
    match &args.model {
        SimCommand::Mergetree(a) => sim_mergetree::run_mergetree(a, ui),
        SimCommand::Dram(a) => sim_dram::run_dram(a, ui),
        SimCommand::Rtunit(a) => sim_rtunit::run_rtunit(a, ui),
    }
}

/// Checks the options of `arbor sim ...` without loading a scene or simulating.
pub fn check(args: &SimArgs) -> anyhow::Result<()> {
    match &args.model {
        SimCommand::Mergetree(a) => sim_mergetree::check_mergetree(a),
        SimCommand::Dram(a) => sim_dram::check_dram(a),
        SimCommand::Rtunit(a) => sim_rtunit::check_rtunit(a),
    }
}
