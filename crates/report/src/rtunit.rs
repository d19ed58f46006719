//! \[P4\] Table 2 from the accelerator model (`sim::rtunit`): the BVH and MBVH4
//! accelerators on each scene with primary rays and diffuse paths, beside the thesis's
//! figures, and a check of pixel sampling against whole frames. The table is
//! `sim::rtunit::report`; [`run`] loads the scenes and writes to [`RtunitOptions::out`]:
//! - `table2.md` / `table2.csv` / `table2.json`: the table (performance, traffic, energy
//!   per frame, performance per area);
//! - `table1.md`: \[P4\] Table 1's analogue (area and power per unit) on the first scene;
//! - `sampling.md`: every whole-frame scene sampled one in `check_sample` tile chunks,
//!   against its whole-frame figures;
//! - `report.md`: both, with the scene list.

use crate::fs::write_file;
use crate::progress::Progress;
use crate::scenes::{existing, load_traced};
use crate::table::thousands;
use anyhow::Context;
use sim::rtunit::report::{
    sampling_check, sampling_markdown, table2, ReportScene, SamplingCheck, Table2,
};
use sim::rtunit::RtConfig;
use std::path::PathBuf;

/// Options of the accelerator report.
#[derive(Clone, Debug)]
pub struct RtunitOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes (mesh files or procedural specs). Default: Crytek Sponza (the thesis's
    /// scene we have) and the procedural stand-ins for Hairball and Rungholt at their
    /// sizes, plus Conference and Sibenik where they exist.
    pub scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Diffuse bounces (thesis P4 3.2: 4).
    pub bounces: u32,
    /// Scenes of more than 1M triangles are timed one in N tile chunks (1: whole frames).
    pub large_sample: u32,
    /// Time every scene one in N tile chunks (default: whole frames below 1M triangles,
    /// `large_sample` above).
    pub sample: Option<u32>,
    /// The sampling factor of the sampling check (0: no check).
    pub check_sample: u32,
    /// Accelerator parameter overrides, `KEY=VALUE`, as in `arbor sim rtunit --set`.
    pub set: Vec<String>,
    /// Energy conventions replacing the configuration's (after `set`).
    pub energy: Option<sim::energy::Conventions>,
}

impl Default for RtunitOptions {
    fn default() -> Self {
        RtunitOptions {
            out: "arbor-out/report-rtunit".into(),
            scenes: None,
            scene_dir: crate::scenes::shared_scenes(),
            width: 1280,
            height: 720,
            bounces: 4,
            large_sample: 16,
            sample: None,
            check_sample: 16,
            set: Vec::new(),
            energy: None,
        }
    }
}

/// What [`run`] found: the table and the sampling checks.
pub struct RtunitReport {
    /// \[P4\] Table 2 (and Table 1's analogue).
    pub table: Table2,
    /// The sampling checks (empty without one).
    pub checks: Vec<SamplingCheck>,
}

impl RtunitReport {
    /// The sampling checks as Markdown.
    pub fn sampling_markdown(&self) -> String {
        sampling_markdown(&self.checks)
    }
}

/// The thesis's scenes our default scenes stand for: (our spec, thesis name, note).
const DEFAULT_SCENES: [(&str, Option<&str>, &str); 5] = [
    (
        "crytek-sponza.ply",
        Some("Crytek"),
        "Crytek Sponza (262K triangles), the thesis's scene; interior camera (Arbor's choice, the thesis does not give its view)",
    ),
    (
        "proc:hairball?n=2900000",
        Some("Hairball"),
        "procedural stand-in for Hairball (2.9M triangles, not in shared/scenes): thin strands filling a ball",
    ),
    (
        "proc:city?n=6700000",
        Some("Rungholt"),
        "procedural stand-in for Rungholt (6.7M triangles, not in shared/scenes): a voxel city",
    ),
    ("conference.ply", None, "Conference (331K), not in the thesis's Table 2; interior camera"),
    ("sibenik.ply", None, "Sibenik (75K), not in the thesis's Table 2; interior camera"),
];

/// Runs the accelerator report: writes its files and returns the table and checks.
pub fn run(a: &RtunitOptions, ui: &dyn Progress) -> anyhow::Result<RtunitReport> {
    let mut cfg = RtConfig::default();
    for s in &a.set {
        cfg.set_pair(s)?;
    }
    if let Some(e) = a.energy {
        cfg.energy = e;
    }
    anyhow::ensure!(a.large_sample >= 1, "--large-sample must be at least 1");
    anyhow::ensure!(a.sample != Some(0), "--sample must be at least 1");
    let specs: Vec<(String, Option<&'static str>, String)> = match &a.scenes {
        // A listed file that is one of the default scenes (same file name) keeps its
        // thesis row; procedural specs never do (their sizes are the caller's).
        Some(list) => list
            .iter()
            .map(|s| {
                let thesis = DEFAULT_SCENES
                    .iter()
                    .find(|d| {
                        !d.0.starts_with("proc:")
                            && !s.starts_with("proc:")
                            && std::path::Path::new(s).file_name()
                                == Some(std::ffi::OsStr::new(d.0))
                    })
                    .and_then(|d| d.1);
                (s.clone(), thesis, String::new())
            })
            .collect(),
        None => DEFAULT_SCENES
            .iter()
            .filter_map(|&(spec, thesis, note)| {
                let path = if spec.starts_with("proc:") {
                    spec.to_string()
                } else {
                    existing(&a.scene_dir, &[spec], &|m| ui.warn(m)).pop()?
                };
                Some((path, thesis, note.to_string()))
            })
            .collect(),
    };
    anyhow::ensure!(!specs.is_empty(), "no scenes to report on");
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut loaded = Vec::new();
    for (spec, thesis, note) in &specs {
        let _s = ui.spinner(&format!("loading {spec}"));
        let (name, tris, camera) = load_traced(spec)?;
        loaded.push((name, tris, camera, *thesis, note.clone()));
    }
    let mut scenes = Vec::new();
    for (name, tris, camera, thesis, note) in &loaded {
        let sample = match a.sample {
            Some(n) => n,
            None if tris.len() > 1_000_000 => a.large_sample,
            None => 1,
        };
        scenes.push(ReportScene {
            name: name.clone(),
            triangles: tris,
            camera: trace::PinholeCamera::new(camera, a.width, a.height)?,
            sample,
            thesis_scene: *thesis,
            note: note.clone(),
        });
    }
    let whole = scenes.iter().filter(|s| s.sample == 1).count() as u64;
    let check = a.check_sample > 1 && whole > 0;
    let total = 4 * scenes.len() as u64 + if check { 4 * whole } else { 0 };
    let bar = ui.bar("accelerator runs (scene, rays, tree)");
    let done = std::cell::Cell::new(0u64);
    let tick = |_what: &str| {
        bar.update(done.get(), total);
        done.set(done.get() + 1);
    };
    let table = table2(&scenes, &cfg, a.bounces, tick)?;
    let mut checks = Vec::new();
    if check {
        for s in scenes.iter().filter(|s| s.sample == 1) {
            checks.extend(sampling_check(&table, s, a.check_sample, &cfg, tick)?);
        }
    }
    bar.update(total, total);
    bar.finish();
    let md = table.markdown();
    write_file(&a.out, "table2.md", &md)?;
    let t1 = table.table1_markdown();
    write_file(&a.out, "table1.md", &t1)?;
    write_file(&a.out, "table2.csv", &table.csv())?;
    write_file(
        &a.out,
        "table2.json",
        &serde_json::to_string_pretty(&table)?,
    )?;
    let sampling = sampling_markdown(&checks);
    if !checks.is_empty() {
        write_file(&a.out, "sampling.md", &sampling)?;
    }
    let mut report = String::from("# [P4] Table 2 from Arbor's accelerator model\n\n");
    report += &md;
    report += "\n## [P4] Table 1: area and power\n\n";
    report += &t1;
    if !checks.is_empty() {
        report += &format!(
            "\n## Pixel sampling\n\nEach run below times one in {} chunks of 16 tiles and warms the caches with the others; errors are against the whole frame.\n\n{sampling}",
            a.check_sample
        );
    }
    report += "\nScenes:\n";
    for s in &scenes {
        report += &format!(
            "- {} ({} triangles)\n",
            s.name,
            thousands(s.triangles.len() as u64)
        );
    }
    write_file(&a.out, "report.md", &report)?;
    Ok(RtunitReport { table, checks })
}
