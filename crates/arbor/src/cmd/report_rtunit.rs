//! `arbor report rtunit`: \[P4\] Table 2 from the accelerator model (`sim::rtunit`): the
//! BVH and MBVH4 accelerators on each scene with primary rays and diffuse paths, beside
//! the thesis's figures, and a check of pixel sampling against whole frames. The table is
//! library code (`sim::rtunit::report`); this command loads the scenes and writes:
//! - `table2.md` / `table2.csv` / `table2.json`: the table (performance, traffic, energy
//!   per frame, performance per area);
//! - `table1.md`: \[P4\] Table 1's analogue (area and power per unit) on the first scene;
//! - `sampling.md`: every whole-frame scene sampled one in `--check-sample` tile
//!   chunks, against its whole-frame figures;
//! - `report.md`: both, with the scene list.

use super::report::SHARED_SCENES;
use super::report_cbvh_trace::load_traced;
use super::thousands;
use crate::progress::{Ui, Unit};
use report::fs::write_file;
use sim::rtunit::report::{sampling_check, sampling_markdown, table2, ReportScene};
use sim::rtunit::RtConfig;
use std::path::PathBuf;

/// Arguments of `arbor report rtunit`.
#[derive(clap::Args, Debug)]
pub struct ReportRtunitArgs {
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/report-rtunit")]
    out: PathBuf,
    /// Scenes, comma separated: mesh files or procedural specs. Default: Crytek Sponza
    /// (the thesis's scene we have) and the procedural stand-ins for Hairball and Rungholt
    /// at their sizes, plus Conference and Sibenik where they exist.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    #[arg(long, value_name = "DIR", default_value = SHARED_SCENES)]
    scene_dir: PathBuf,
    /// Image width.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Diffuse bounces (thesis P4 3.2: 4).
    #[arg(long, default_value_t = 4, value_name = "N")]
    bounces: u32,
    /// Scenes of more than 1M triangles are timed one in N tile chunks (1: whole frames).
    #[arg(long, default_value_t = 16, value_name = "N")]
    large_sample: u32,
    /// Time every scene one in N tile chunks (default: whole frames below 1M triangles,
    /// `--large-sample` above).
    #[arg(long, value_name = "N")]
    sample: Option<u32>,
    /// The sampling factor of the sampling check (0: no check).
    #[arg(long, default_value_t = 16, value_name = "N")]
    check_sample: u32,
    /// Override an accelerator parameter (repeatable), as in `arbor sim rtunit`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Write the files without printing the tables (`arbor report energy` runs this one).
    #[arg(skip)]
    quiet: bool,
}

impl ReportRtunitArgs {
    /// The report into `out` over `scenes` (`None`: the default list) with scenes timed one
    /// in `sample` tile chunks, without the sampling check, quietly.
    pub fn quiet(
        out: PathBuf,
        scenes: Option<Vec<String>>,
        scene_dir: PathBuf,
        sample: u32,
    ) -> Self {
        Self {
            out,
            scenes,
            scene_dir,
            width: 1280,
            height: 720,
            bounces: 4,
            large_sample: sample,
            sample: Some(sample),
            check_sample: 0,
            set: Vec::new(),
            quiet: true,
        }
    }

    /// The same with `--set` overrides.
    pub fn with_set(mut self, set: Vec<String>) -> Self {
        self.set = set;
        self
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

/// Runs `arbor report rtunit`.
pub fn run(a: &ReportRtunitArgs, ui: &Ui) -> anyhow::Result<sim::rtunit::report::Table2> {
    let mut cfg = RtConfig::default();
    for s in &a.set {
        cfg.set_pair(s)?;
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
                    let p = a.scene_dir.join(spec);
                    if !p.exists() {
                        ui.warn(&format!("{} not found: skipped", p.display()));
                        return None;
                    }
                    p.display().to_string()
                };
                Some((path, thesis, note.to_string()))
            })
            .collect(),
    };
    anyhow::ensure!(!specs.is_empty(), "no scenes to report on");
    std::fs::create_dir_all(&a.out)?;
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
    let bar = ui.progress("accelerator runs (scene, rays, tree)", Unit::Items);
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
    if !a.quiet {
        crate::say!(ui, "{md}");
        crate::say!(ui, "{t1}");
        if !checks.is_empty() {
            crate::say!(ui, "{sampling}");
        }
        crate::say!(ui, "wrote {}", a.out.join("report.md").display());
    }
    Ok(table)
}
