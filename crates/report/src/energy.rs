//! The energy report (`arbor report energy`): the energy and area reproductions in one place:
//! - `components.md` / `components.csv`: the component models' figures (`sim::energy`:
//!   CACTI SRAMs by size and node, FPUs and integer adders by node, the LPDDR3 die's
//!   commands);
//! - `p2/`: the MergeTree report's run ([`crate::mergetree`]) (MergeTree on the three memory systems), whose
//!   `table7.md`, `table7.csv` and `table4.csv` are \[P2\] Tables VII and IV;
//! - `p4/`: the accelerator report's run ([`crate::rtunit`]) on the \[P4\] scenes (Crytek Sponza by default),
//!   whose `table1.md` and `table2.md` are \[P4\] Tables 1 and 2 with their energy and
//!   performance-per-area columns;
//! - `report.md`: the component tables and those tables together; `energy.json`
//!   (`arbor.report.energy.v1`) the components and the \[P4\] table.

use crate::fs::write_file;
use crate::mergetree::{MergetreeOptions, SoftwareBuild};
use crate::progress::Progress;
use crate::rtunit::RtunitOptions;
use anyhow::Context;
use serde::Serialize;
use sim::energy::{component_csv, component_markdown, component_rows, ComponentRow};
use std::path::PathBuf;

/// Options of the energy report.
#[derive(Clone)]
pub struct EnergyOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes of the MergeTree tables ([P2] IV and VII). Default: the MergeTree report's.
    pub scenes: Option<Vec<String>>,
    /// Scenes of the accelerator tables ([P4] 1 and 2). Default: Crytek Sponza, [P4]'s
    /// scene, under `scene_dir`.
    pub p4_scenes: Option<Vec<String>>,
    /// Time one in N tile chunks of each accelerator frame (1: whole frames).
    pub sample: u32,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// Energy conventions.
    pub energy: sim::energy::Conventions,
    /// The software builders of the MergeTree report.
    pub build: SoftwareBuild,
    /// The largest leaf of their trees.
    pub max_leaf: u32,
}

/// What [`run`] wrote: `report.md`'s text and the JSON document (`energy.json`).
pub struct EnergyReport {
    /// `report.md`.
    pub markdown: String,
    /// `energy.json` (`arbor.report.energy.v1`).
    pub json: String,
}

/// The JSON document.
#[derive(Serialize)]
struct EnergyDoc<'a> {
    schema: &'static str,
    components: &'a [ComponentRow],
    p4: &'a sim::rtunit::report::Table2,
    files: Vec<String>,
}

/// Runs the energy report: writes its files and returns the Markdown and JSON.
pub fn run(a: &EnergyOptions, ui: &dyn Progress) -> anyhow::Result<EnergyReport> {
    let conv = a.energy;
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
    crate::mergetree::run(
        &MergetreeOptions {
            out: p2.clone(),
            scenes: a.scenes.clone(),
            scene_dir: a.scene_dir.clone(),
            energy: conv,
            ..MergetreeOptions::new(a.build.clone(), a.max_leaf)
        },
        ui,
    )
    .context("the MergeTree tables ([P2] IV and VII)")?;
    let p4 = a.out.join("p4");
    let table = crate::rtunit::run(
        &RtunitOptions {
            out: p4.clone(),
            scenes: Some(p4_scenes),
            scene_dir: a.scene_dir.clone(),
            large_sample: a.sample,
            sample: Some(a.sample),
            check_sample: 0,
            energy: Some(conv),
            ..RtunitOptions::default()
        },
        ui,
    )
    .context("the accelerator tables ([P4] 1 and 2)")?
    .table;
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
    Ok(EnergyReport { markdown: md, json })
}
