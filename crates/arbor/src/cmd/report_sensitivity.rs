//! `arbor report sensitivity`: every open assumption of the models swept over its
//! documented range. The study is library code (`report::sensitivity`); this is its
//! command line.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::sensitivity::{chosen, SensitivityOptions};
use std::path::PathBuf;

/// Arguments of `arbor report sensitivity`.
#[derive(clap::Args, Debug)]
pub struct ReportSensitivityArgs {
    /// Output folder (created if missing).
    #[arg(
        long,
        value_name = "DIR",
        default_value = "arbor-out/report-sensitivity"
    )]
    out: PathBuf,
    /// Scenes, comma separated: mesh files or procedural specs. Default: those of `arbor
    /// report system` (the shared real scenes that exist, two large procedural scenes).
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Scene of the [P4] Table 2 part (BVH2 against MBVH4 at [P4]'s settings), or `none`.
    /// Default: Crytek Sponza under --scene-dir, [P4]'s scene, when it exists.
    #[arg(long, value_name = "SCENE")]
    p4_scene: Option<String>,
    /// Only these assumptions, comma separated keys (default: all; `--list` shows them).
    #[arg(long, value_name = "KEYS", value_delimiter = ',')]
    only: Option<Vec<String>>,
    /// Print the assumptions and their ranges, and run nothing.
    #[arg(long)]
    list: bool,
    /// A small study in about a minute: a 50K-triangle procedural scene at 320x180.
    #[arg(long)]
    quick: bool,
    #[command(flatten)]
    soc: super::report_system::SocArgs,
    /// Time one in N chunks of 16 pixel tiles of each frame (the `sample` assumption
    /// varies it).
    #[arg(long, default_value_t = 16, value_name = "N")]
    sample: u32,
    /// Print the document (`arbor.report.sensitivity.v1`) on standard output.
    #[arg(long)]
    json: bool,
}

impl ReportSensitivityArgs {
    /// The options of the library's report.
    pub fn options(&self) -> anyhow::Result<SensitivityOptions> {
        Ok(SensitivityOptions {
            out: self.out.clone(),
            scenes: self.scenes.clone(),
            scene_dir: self.scene_dir.clone(),
            p4_scene: self.p4_scene.clone(),
            only: self.only.clone(),
            quick: self.quick,
            soc: self.soc.options()?,
            sample: self.sample,
        })
    }
}

/// Runs `arbor report sensitivity`.
pub fn run(a: &ReportSensitivityArgs, ui: &Ui) -> anyhow::Result<()> {
    if a.list {
        for x in &chosen(a.only.as_deref())? {
            crate::say!(
                ui,
                "{:<28} default {:<12} tried {:<12} {}",
                x.key,
                x.default,
                x.values.join(", "),
                x.what
            );
        }
        return Ok(());
    }
    let rep = report::sensitivity::run(&a.options()?, ui)?;
    if a.json {
        ui.emit_json(&rep)?;
    } else {
        crate::say!(ui, "{}", rep.markdown());
        crate::say!(ui, "wrote {}", a.out.join("sensitivity.md").display());
    }
    Ok(())
}
