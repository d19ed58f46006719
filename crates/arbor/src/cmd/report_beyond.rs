//! `arbor report beyond`: the thesis's open problems (issue 18) against their baselines on
//! the MergeTree model. The report is library code (`report::beyond`); this is its command
//! line.

use super::report::SHARED_SCENES;
use crate::progress::Ui;
use report::beyond::BeyondOptions;
use std::path::PathBuf;

/// The shared scenes of the report when `--scenes` is not given (those that exist).
const SCENES: [&str; 4] = [
    "bunny.ply",
    "crytek-sponza.ply",
    "conference.ply",
    "dragon.ply",
];

/// Arguments of `arbor report beyond`.
#[derive(clap::Args, Debug)]
pub struct ReportBeyondArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-beyond")]
    out: PathBuf,
    /// Scenes, comma separated: mesh files or procedural specs. Default: Bunny, Crytek
    /// Sponza, Conference and Dragon under --scene-dir (those that exist).
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Memory system of every run (as `arbor sim mergetree --dram`).
    #[arg(long, value_name = "DRAM", default_value = "lpddr3-1600-1x64")]
    dram: String,
    /// A small run: a 20K-triangle procedural soup, in seconds.
    #[arg(long)]
    quick: bool,
    /// Print the document (`arbor.report.beyond.v1`, as `beyond.json`) on standard output.
    #[arg(long)]
    json: bool,
}

/// Runs `arbor report beyond`.
pub fn run(a: &ReportBeyondArgs, ui: &Ui) -> anyhow::Result<()> {
    let scenes = match (&a.scenes, a.quick) {
        (Some(s), _) => s.clone(),
        (None, true) => vec!["proc:soup?n=20000".to_string()],
        (None, false) => {
            let found = report::scenes::existing(&a.scene_dir, &SCENES, &|m| ui.warn(m));
            anyhow::ensure!(
                !found.is_empty(),
                "none of {} found in {} (give --scenes or --scene-dir)",
                SCENES.join(", "),
                a.scene_dir.display()
            );
            found
        }
    };
    let o = BeyondOptions {
        out: a.out.clone(),
        scenes,
        dram: a.dram.clone(),
    };
    // An unknown memory system fails here, before any scene is loaded.
    let period = sim::mergetree::MergeTreeConfig::p2().period_fs();
    sim::dram::open(&o.dram, period).map_err(|e| anyhow::anyhow!("--dram: {e}"))?;
    let rows = report::beyond::run(&o, ui)?;
    if a.json {
        ui.emit_json(&report::beyond::document(&o, &rows))?;
    } else {
        let md = std::fs::read_to_string(a.out.join("report.md"))?;
        crate::say!(ui, "{md}");
        crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    }
    Ok(())
}
