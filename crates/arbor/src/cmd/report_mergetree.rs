//! `arbor report mergetree`: the analogues of \[P2\] Tables III and VI. The report is
//! library code (`report::mergetree`); this is its command line, which also hands the
//! report the software builders of `arbor build`.

use super::build::{builder, BuildConfig};
use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::mergetree::{MergetreeOptions, SoftwareBuild};
use sim::thesis;
use std::path::PathBuf;

/// Arguments of `arbor report mergetree`.
#[derive(clap::Args, Debug)]
pub struct ReportMergetreeArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-mergetree")]
    out: PathBuf,
    /// Scenes to use, comma separated: mesh files or procedural specs. Default: the
    /// shared real scenes that exist (others are skipped with a message) and the report's
    /// procedural scenes.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Memory systems, slowest first (speed-ups are over the first), comma separated.
    /// Default: the slow, medium and fast systems of [P2] 6.2 on Arbor's model of DRAMsim3's
    /// controller (`dramsim3:NAME` runs DRAMsim3 itself); `simple:NAME`
    /// selects the quick bandwidth-plus-latency model.
    #[arg(
        long,
        value_name = "LIST",
        value_delimiter = ',',
        default_values_t = thesis::P2_SYSTEMS.map(String::from)
    )]
    drams: Vec<String>,
    /// Time at which animated scenes are sampled, in seconds (static meshes have one
    /// frame; the procedural cloth is exactly flat at 0).
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0)]
    time: f32,
    #[command(flatten)]
    energy: super::energy_args::EnergyArgs,
}

/// The software builders of `arbor build`, with their default configuration, for the
/// reports; and the largest leaf they make.
pub fn software_builders() -> (SoftwareBuild, u32) {
    let cfg = BuildConfig::default();
    let max_leaf = cfg.max_leaf;
    let build: SoftwareBuild = std::sync::Arc::new(move |name, prims| builder(name)?(prims, &cfg));
    (build, max_leaf)
}

impl ReportMergetreeArgs {
    /// The options of the library's report (a bad energy convention is an error here).
    pub fn options(&self) -> anyhow::Result<MergetreeOptions> {
        let (build, max_leaf) = software_builders();
        Ok(MergetreeOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            scene_dir: self.scene_dir.clone(),
            drams: self.drams.clone(),
            time: self.time,
            energy: self.energy.conventions()?,
            ..MergetreeOptions::new(build, max_leaf)
        })
    }
}

/// Runs `arbor report mergetree`.
pub fn run(a: &ReportMergetreeArgs, ui: &Ui) -> anyhow::Result<()> {
    let md = report::mergetree::run(&a.options()?, ui)?;
    crate::say!(ui, "{md}");
    crate::say!(ui, "wrote {}", a.out.display());
    Ok(())
}
