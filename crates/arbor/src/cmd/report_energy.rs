//! `arbor report energy`: the energy and area reproductions in one place:
//! - `components.md` / `components.csv`: the component models' figures (`sim::energy`:
//!   CACTI SRAMs by size and node, FPUs and integer adders by node, the LPDDR3 die's
//!   commands);
//! - `p2/`: `arbor report mergetree`'s run (MergeTree on the three memory systems), whose
//!   `table7.md`, `table7.csv` and `table4.csv` are \[P2\] Tables VII and IV;
//! - `p4/`: `arbor report rtunit`'s run on the \[P4\] scenes (Crytek Sponza by default),
//!   whose `table1.md` and `table2.md` are \[P4\] Tables 1 and 2 with their energy and
//!   performance-per-area columns;
//! - `report.md`: the component tables and those tables together; `energy.json`
//!   (`arbor.report.energy.v1`) the components and the \[P4\] table, also printed by
//!   `--json`.

use super::report::SHARED_SCENES;
use super::report_mergetree::{self, ReportMergetreeArgs};
use super::report_rtunit::{self, ReportRtunitArgs};
use crate::progress::Ui;
use anyhow::Context;
use report::fs::write_file;
use serde::Serialize;
use sim::energy::{component_csv, component_markdown, component_rows, ComponentRow};
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

/// The JSON document.
#[derive(Serialize)]
struct EnergyDoc<'a> {
    schema: &'static str,
    components: &'a [ComponentRow],
    p4: &'a sim::rtunit::report::Table2,
    files: Vec<String>,
}

/// Runs `arbor report energy`.
pub fn run(a: &ReportEnergyArgs, ui: &Ui) -> anyhow::Result<()> {
    let conv = a.energy.conventions()?;
    anyhow::ensure!(a.sample >= 1, "--sample must be at least 1");
    let p4_scenes = match &a.p4_scenes {
        Some(s) => s.clone(),
        None => {
            let p = a.scene_dir.join("crytek-sponza.ply");
            anyhow::ensure!(
                p.exists(),
                "{} not found: give the accelerator's scenes with --p4-scenes",
                p.display()
            );
            vec![p.display().to_string()]
        }
    };
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let rows = component_rows(&conv);
    let comp = component_markdown(&rows);
    write_file(&a.out, "components.md", &comp)?;
    write_file(&a.out, "components.csv", &component_csv(&rows))?;
    let p2 = a.out.join("p2");
    report_mergetree::run(
        &ReportMergetreeArgs::quiet(p2.clone(), a.scenes.clone(), a.scene_dir.clone())
            .with_energy(a.energy.clone()),
        ui,
    )
    .context("the MergeTree tables ([P2] IV and VII)")?;
    let p4 = a.out.join("p4");
    let table = report_rtunit::run(
        &ReportRtunitArgs::quiet(p4.clone(), Some(p4_scenes), a.scene_dir.clone(), a.sample)
            .with_set(a.energy.as_set()),
        ui,
    )
    .context("the accelerator tables ([P4] 1 and 2)")?;
    let read = |p: PathBuf| {
        std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))
    };
    let mut md = String::from("# Energy and area from Arbor's component models\n\n");
    md += &format!(
        "## Components ({}; `docs/energy-model.md` gives every source)\n\n",
        conv.describe()
    );
    md += &comp;
    md += "\n## [P2] Tables VII and IV: MergeTree (files in `p2/`)\n\n";
    md += &read(p2.join("table7.md"))?;
    md += "\n## [P4] Table 1: the accelerators' area and power (files in `p4/`)\n\n";
    md += &table.table1_markdown();
    md += "\n## [P4] Table 2: performance, traffic, energy per frame, performance per area\n\n";
    md += &table.markdown();
    write_file(&a.out, "report.md", &md)?;
    let doc = EnergyDoc {
        schema: "arbor.report.energy.v1",
        components: &rows,
        p4: &table,
        files: [
            "components.md",
            "components.csv",
            "p2/table7.md",
            "p2/table7.csv",
            "p2/table4.csv",
            "p4/table1.md",
            "p4/table2.md",
            "p4/table2.csv",
            "report.md",
        ]
        .map(String::from)
        .to_vec(),
    };
    let json = serde_json::to_string_pretty(&doc)?;
    write_file(&a.out, "energy.json", &json)?;
    if a.json {
        crate::say!(ui, "{json}");
    } else {
        crate::say!(ui, "{md}");
        crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    }
    Ok(())
}
