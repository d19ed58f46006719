//! `arbor report system`: \[P2\] §6.4's system energy per frame with four builders, and
//! the animation study beyond the thesis. The report is library code
//! (`report::system`); this is its command line: the options, and the printed result.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::system::{SocOptions, SystemOptions};
use std::path::PathBuf;

/// Arguments of `arbor report system`.
#[derive(clap::Args, Debug)]
pub struct ReportSystemArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-system")]
    out: PathBuf,
    /// Static scenes, comma separated: mesh files or procedural specs. Default: the shared
    /// real scenes that exist (others are skipped with a message) and two large
    /// procedural scenes.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Animated scenes of the policy study, comma separated (`none`: no study). Default:
    /// the shared horse gallop (keyframes) where it exists and a procedural cloth.
    /// (`--animation` elsewhere picks a glTF animation; the old spelling here still works.)
    #[arg(long, value_name = "LIST", value_delimiter = ',', alias = "animation")]
    animated: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    #[command(flatten)]
    soc: SocArgs,
    /// Diffuse bounces ([P2] 6.4: three).
    #[arg(long, default_value_t = 3, value_name = "N")]
    bounces: u32,
    /// Time one in N chunks of 16 pixel tiles of each frame, warming the caches with the
    /// others (1: whole frames; `arbor report rtunit` checks the error of sampling).
    #[arg(long, default_value_t = 8, value_name = "N")]
    sample: u32,
    /// Frames of each animated scene, spread evenly over its timeline.
    #[arg(long, default_value_t = 8, value_name = "N")]
    frames: u32,
    /// SAH ratio above which the refit tracker advises a rebuild.
    #[arg(long, default_value_t = bvh::RefitTracker::DEFAULT_THRESHOLD)]
    threshold: f64,
    /// Print the report as JSON (`arbor.report.system.v1`) on standard output.
    #[arg(long)]
    json: bool,
}

/// The modelled SoC and frame of the system studies ([P2] §6.4), shared by `arbor report
/// system` and `arbor report sensitivity`.
#[derive(clap::Args, Debug)]
pub struct SocArgs {
    /// Image width ([P2] 6.4: 1280).
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Image height ([P2] 6.4: 720).
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Process node of the on-chip figures ([P2] 6.4: 28nm).
    #[arg(long, default_value = "28nm")]
    pub node: String,
    #[command(flatten)]
    pub energy: super::energy_args::EnergyArgs,
    /// Memory system ([P2] 6.4: the 25.6 GB/s system).
    #[arg(long, default_value = "lpddr3-1600-2x64")]
    pub dram: String,
}

impl SocArgs {
    /// The options of the library's report (a bad energy convention is an error here).
    pub fn options(&self) -> anyhow::Result<SocOptions> {
        Ok(SocOptions {
            width: self.width,
            height: self.height,
            node: self.node.clone(),
            energy: self.energy.conventions()?,
            dram: self.dram.clone(),
        })
    }
}

impl ReportSystemArgs {
    /// The options of the library's report.
    pub fn options(&self) -> anyhow::Result<SystemOptions> {
        Ok(SystemOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            animated: self.animated.clone(),
            scene_dir: self.scene_dir.clone(),
            soc: self.soc.options()?,
            bounces: self.bounces,
            sample: self.sample,
            frames: self.frames,
            threshold: self.threshold,
        })
    }
}

/// Runs `arbor report system`.
pub fn run(a: &ReportSystemArgs, ui: &Ui) -> anyhow::Result<()> {
    let rep = report::system::run(&a.options()?, ui)?;
    if a.json {
        ui.emit_json(&rep)?;
    } else {
        crate::say!(ui, "{}", rep.table8_markdown());
        if !rep.animation.is_empty() {
            crate::say!(ui, "{}", rep.animation_markdown());
        }
        crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    }
    Ok(())
}
