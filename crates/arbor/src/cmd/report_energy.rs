//! `arbor report energy`: the energy and area reproductions in one place. The report is
//! library code (`report::energy`); this is its command line.

use super::report::SHARED_SCENES;
use super::report_mergetree::software_builders;
use crate::progress::Ui;
use report::energy::EnergyOptions;
use std::path::PathBuf;

/// Arguments of `arbor report energy`.
#[derive(clap::Args, Debug)]
pub struct ReportEnergyArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-energy")]
    out: PathBuf,
    /// Scenes of the MergeTree tables ([P2] IV and VII), comma separated. Default: those of
    /// `arbor report mergetree`.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Scenes of the accelerator tables ([P4] 1 and 2), comma separated. Default: Crytek
    /// Sponza, [P4]'s scene.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    p4_scenes: Option<Vec<String>>,
    /// Time one in N tile chunks of each accelerator frame (1: whole frames).
    #[arg(long, default_value_t = 4, value_name = "N")]
    sample: u32,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    #[command(flatten)]
    energy: super::energy_args::EnergyArgs,
    /// Print `arbor.report.energy.v1` on standard output.
    #[arg(long)]
    json: bool,
}

impl ReportEnergyArgs {
    /// The options of the library's report (a bad energy convention is an error here).
    pub fn options(&self) -> anyhow::Result<EnergyOptions> {
        let (build, max_leaf) = software_builders();
        Ok(EnergyOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            p4_scenes: self.p4_scenes.clone(),
            sample: self.sample,
            scene_dir: self.scene_dir.clone(),
            energy: self.energy.conventions()?,
            build,
            max_leaf,
        })
    }
}

/// Runs `arbor report energy`.
pub fn run(a: &ReportEnergyArgs, ui: &Ui) -> anyhow::Result<()> {
    let rep = report::energy::run(&a.options()?, ui)?;
    if a.json {
        crate::say!(ui, "{}", rep.json);
    } else {
        crate::say!(ui, "{}", rep.markdown);
        crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    }
    Ok(())
}
