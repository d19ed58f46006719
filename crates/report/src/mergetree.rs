//! The MergeTree report (`arbor report mergetree`): the analogues of \[P2\] Tables III and VI for our scenes,
//! written as CSV, Markdown and SVG into one folder, each of our numbers beside the
//! thesis's where we share the scene (`sim::thesis`), with the difference in percent:
//! - `table3.csv`: MergeTree (preset `p2`) on the slow, medium and fast memory systems of
//!   \[P2\] §6.2 (DRAMsim3's timing by default, from Arbor's model of its controller):
//!   cycles, build time, speed-up over the slow system, bus utilization, traffic, DRAM
//!   energy, and whether the tree matched the software HLBVH builder node for node
//!   (\[P2\] Table III, time columns);
//! - `sah.csv`: SAH relative to a full sweep SAH build for `hlbvh`, `hlbvh+sah`,
//!   `hlbvh+atrbvh` and `binned-sah`, and the time of MergeTree's toplevel binned SAH unit
//!   (\[P2\] Table III, SAH columns and the "HW Binned SAH topl." row);
//! - `table6.csv`: traffic of MergeTree against the binned SAH hardware model and the GPU
//!   HLBVH model (`sim::analytic`), with the ratio columns, and MergeTree's traffic split
//!   into input, sort runs and output (\[P2\] Table VI);
//! - `fig6-SYSTEM.csv` / `.svg`: unit activity against time for one scene (Sibenik when
//!   present, as in \[P2\] Fig. 6), and `table3.svg`, `speedup.svg`, `table6.svg`;
//! - `report.md` with every table and a summary against the targets.

use crate::fs::write_file;
use crate::progress::Progress;
use crate::scenes::{scene_prims, short_name};
use crate::svg::bar_svg;
use crate::table::{thousands, Table};
use anyhow::Context;
use geom::Aabb;
use rayon::prelude::*;
use sim::analytic::{binned_sah_hw, gpu_hlbvh};
use sim::mergetree::{self, MergeTreeConfig, PhaseReport};
use sim::thesis::{self, P2Scene};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// The software builders the report compares against, by name (`sweep-sah`, `hlbvh`,
/// `hlbvh+sah`, `hlbvh+atrbvh`, `binned-sah`: the command line's registry, `arbor build
/// --builder`), each building a tree over primitive boxes.
pub type SoftwareBuild =
    std::sync::Arc<dyn Fn(&str, &[Aabb]) -> anyhow::Result<bvh::Tree> + Send + Sync>;

/// Options of the MergeTree report.
#[derive(Clone)]
pub struct MergetreeOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes (mesh files or procedural specs). Default: the shared real scenes that exist
    /// (others skipped with a warning) and the report's procedural scenes.
    pub scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// Memory systems, slowest first (speed-ups are over the first). Default: the slow,
    /// medium and fast systems of [P2] 6.2 (`sim::thesis::P2_SYSTEMS`).
    pub drams: Vec<String>,
    /// Time at which animated scenes are sampled, in seconds.
    pub time: f32,
    /// Energy conventions.
    pub energy: sim::energy::Conventions,
    /// The software builders.
    pub build: SoftwareBuild,
    /// The largest leaf of the software builders' trees (each is validated with it).
    pub max_leaf: u32,
}

impl MergetreeOptions {
    /// The default report (`arbor report mergetree` without options) with the software
    /// builders `build` making leaves of at most `max_leaf`.
    pub fn new(build: SoftwareBuild, max_leaf: u32) -> Self {
        MergetreeOptions {
            out: "arbor-out/report-mergetree".into(),
            scenes: None,
            scene_dir: crate::scenes::shared_scenes(),
            drams: thesis::P2_SYSTEMS.map(String::from).to_vec(),
            time: 1.0,
            energy: Default::default(),
            build,
            max_leaf,
        }
    }
}

/// Real scenes of the default list (files under `--scene-dir`): the four of \[P2\] Tables
/// III and VI, and Sibenik, the scene of \[P2\] Fig. 6.
const REAL: [&str; 5] = [
    "bunny.ply",
    "crytek-sponza.ply",
    "conference.ply",
    "dragon.ply",
    "sibenik.ply",
];

/// Procedural scenes of the default list: a cloth of the size of \[P2\]'s Cloth (a
/// different mesh, so without thesis values), a forest of very uneven triangles, and a
/// soup above the 2M triangles one merge pass of preset `p2` sorts (two passes).
const PROCEDURAL: [&str; 3] = [
    "proc:cloth?n=92000",
    "proc:forest?n=300000",
    "proc:soup?n=2200000",
];

/// The scene whose unit activity is plotted (\[P2\] Fig. 6 shows Sibenik).
const FIG6_SCENE: &str = "sibenik";

/// Names of the builders of the SAH table, in \[P2\] Table III's order (the columns of
/// [`P2Scene::sah_pct`]).
const SAH_BUILDERS: [&str; 4] = ["hlbvh", "hlbvh+sah", "hlbvh+atrbvh", "binned-sah"];

/// One scene of the report.
struct Scene {
    name: String,
    prims: Vec<Aabb>,
    thesis: Option<&'static P2Scene>,
}

/// One MergeTree simulation, reduced to what the report prints.
#[derive(Clone, Debug, Default)]
struct SimRow {
    cycles: u64,
    ms: f64,
    bytes_read: u64,
    bytes_written: u64,
    bus_utilization: f64,
    merge_passes: u32,
    phases: Vec<PhaseReport>,
    row_hit_rate: Option<f64>,
    energy_mj: Option<f64>,
    /// DRAM energy above an idle memory's ([P2] §6.2), mJ.
    energy_above_idle_mj: Option<f64>,
    /// Energy and area at 28 nm (`sim::mergetree::energy`).
    energy: Option<sim::mergetree::energy::MergeTreeEnergy>,
    toplevel_cycles: u64,
    /// Inner nodes written.
    nodes: u64,
    tree_matches_software: bool,
    /// `(csv, svg)` of the activity trace, for the Fig. 6 scene.
    trace: Option<(String, String)>,
    wall_s: f64,
}

impl SimRow {
    fn mb(&self) -> f64 {
        (self.bytes_read + self.bytes_written) as f64 / 1e6
    }

    fn mib(&self) -> f64 {
        (self.bytes_read + self.bytes_written) as f64 / (1u64 << 20) as f64
    }

    /// Mean read latency (cycles) of the first phase and of the final merge.
    fn read_latency(&self) -> [f64; 2] {
        let first = self
            .phases
            .first()
            .map_or(0.0, |p| p.read_latency_mean_cycles);
        let last = self
            .phases
            .iter()
            .rfind(|p| p.name.ends_with("emit"))
            .map_or(0.0, |p| p.read_latency_mean_cycles);
        [first, last]
    }
}

/// The software builds of one scene.
#[derive(Clone, Debug, Default)]
struct SoftwareRow {
    sweep_sah: f64,
    /// SAH of each of [`SAH_BUILDERS`].
    sah: [f64; 4],
    binned_hw: binned_sah_hw::BinnedSahHwTraffic,
    gpu_bytes: u64,
}

/// A unit of work of the report.
#[derive(Clone, Copy, Debug)]
enum Job {
    /// Plain HLBVH on memory system `system`.
    Sim { scene: usize, system: usize },
    /// HLBVH+SAH (high-level output and the toplevel unit) on the first system.
    Toplevel { scene: usize },
    /// The software builders and the analytic models.
    Software { scene: usize },
    /// Plain HLBVH on the first system with the software builder's defaults instead of the
    /// preset's: Morton codes on a box grid and leaves of at most 8 (the model's defaults
    /// before the presets followed the thesis, `docs/mergetree-vs-thesis.md`).
    BoxGrid { scene: usize },
}

enum Done {
    Sim(usize, usize, SimRow),
    Toplevel(usize, SimRow),
    Software(usize, SoftwareRow),
    BoxGrid(usize, SimRow),
}

/// Everything the report prints.
struct Results {
    scenes: Vec<Scene>,
    drams: Vec<String>,
    /// `sims[scene][system]`.
    sims: Vec<Vec<SimRow>>,
    top: Vec<SimRow>,
    sw: Vec<SoftwareRow>,
    /// [`Job::BoxGrid`] per scene.
    boxgrid: Vec<SimRow>,
    /// The conventions of the energy figures.
    energy: sim::energy::Conventions,
}

/// Runs the MergeTree report: writes its files and returns `report.md`'s text.
pub fn run(a: &MergetreeOptions, ui: &dyn Progress) -> anyhow::Result<String> {
    anyhow::ensure!(
        !a.drams.is_empty(),
        "--drams needs at least one memory system"
    );
    let cfg = MergeTreeConfig::p2();
    let energy = a.energy;
    for d in &a.drams {
        sim::dram::open(d, cfg.period_fs())?;
    }
    let specs: Vec<String> = match &a.scenes {
        Some(s) => s.clone(),
        None => {
            let mut v = Vec::new();
            for f in REAL {
                let p = a.scene_dir.join(f);
                if p.is_file() {
                    v.push(p.to_string_lossy().into_owned());
                } else {
                    ui.warn(&format!("skipping {}: not found", p.display()));
                }
            }
            v.extend(PROCEDURAL.map(String::from));
            v
        }
    };
    anyhow::ensure!(!specs.is_empty(), "no scenes to run on");
    let mut scenes = Vec::new();
    for spec in &specs {
        let spinner = ui.spinner(&format!("loading {spec}"));
        let prims = scene_prims(spec, a.time)?;
        drop(spinner);
        anyhow::ensure!(!prims.is_empty(), "{spec}: no triangles");
        let name = short_name(spec);
        scenes.push(Scene {
            thesis: thesis::p2_scene(&name),
            name,
            prims,
        });
    }
    let results = simulate_all(scenes, a, &energy, ui)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut md = String::new();
    writeln!(md, "# MergeTree report (\\[P2\\] Tables III and VI)\n")?;
    writeln!(
        md,
        "MergeTree preset p2 (M = 8192, B = 16, 8 presorters, 1 GHz, 30-bit Morton codes on \
         a cube grid, identical codes combined into one leaf of any size). Memory systems: \
         {}. Every value \
         of ours is followed by [P2]'s where we share the scene (`sim::thesis`, with the line \
         of the thesis text) and the difference in percent, (ours / thesis - 1). MB = 10^6 \
         bytes. Scenes (animated ones at t = {} s): {}.\n",
        results.drams.join(", "),
        a.time,
        results
            .scenes
            .iter()
            .map(|s| format!("{} ({})", s.name, thousands(s.prims.len() as u64)))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    write_summary(&mut md, &results)?;
    write_table3(&a.out, &mut md, &results)?;
    write_sah(&a.out, &mut md, &results)?;
    write_table6(&a.out, &mut md, &results)?;
    write_table7(&a.out, &mut md, &results)?;
    write_fig6(&a.out, &mut md, &results)?;
    write_file(&a.out, "report.md", &md)?;
    Ok(md)
}

/// Runs every job in parallel with a progress bar over the runs.
fn simulate_all(
    scenes: Vec<Scene>,
    opts: &MergetreeOptions,
    energy: &sim::energy::Conventions,
    ui: &dyn Progress,
) -> anyhow::Result<Results> {
    let drams = &opts.drams[..];
    let mut jobs = Vec::new();
    for scene in 0..scenes.len() {
        jobs.extend((0..drams.len()).map(|system| Job::Sim { scene, system }));
        jobs.push(Job::Toplevel { scene });
        jobs.push(Job::Software { scene });
        jobs.push(Job::BoxGrid { scene });
    }
    // Largest first, so the last jobs to start are short ones.
    jobs.sort_by_key(|j| {
        let (s, w) = match *j {
            Job::Sim { scene, system } => (scene, if system == 0 { 4 } else { 3 }),
            Job::Toplevel { scene } => (scene, 4),
            Job::Software { scene } => (scene, 2),
            Job::BoxGrid { scene } => (scene, 4),
        };
        std::cmp::Reverse(scenes[s].prims.len() as u64 * w)
    });
    let bar = ui.bar("report mergetree: runs");
    let total = jobs.len() as u64;
    let done = AtomicU64::new(0);
    bar.update(0, total);
    let out: Vec<anyhow::Result<Done>> = jobs
        .par_iter()
        .map(|&job| {
            let r = run_job(job, &scenes, opts, energy);
            bar.update(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            r
        })
        .collect();
    bar.finish();
    let n = scenes.len();
    let mut res = Results {
        sims: vec![vec![SimRow::default(); drams.len()]; n],
        top: vec![SimRow::default(); n],
        sw: vec![SoftwareRow::default(); n],
        boxgrid: vec![SimRow::default(); n],
        drams: drams.to_vec(),
        scenes,
        energy: *energy,
    };
    for r in out {
        match r? {
            Done::Sim(s, k, row) => res.sims[s][k] = row,
            Done::Toplevel(s, row) => res.top[s] = row,
            Done::Software(s, row) => res.sw[s] = row,
            Done::BoxGrid(s, row) => res.boxgrid[s] = row,
        }
    }
    for (s, scene) in res.scenes.iter().enumerate() {
        for (k, row) in res.sims[s].iter().enumerate() {
            anyhow::ensure!(
                row.tree_matches_software,
                "{} on {}: the simulated tree differs from the software HLBVH tree",
                scene.name,
                drams[k]
            );
        }
        anyhow::ensure!(
            res.top[s].tree_matches_software,
            "{}: the simulated HLBVH+SAH tree differs from the software one",
            scene.name
        );
        anyhow::ensure!(
            res.boxgrid[s].tree_matches_software,
            "{}: the simulated box-grid tree differs from the software one",
            scene.name
        );
    }
    Ok(res)
}

fn run_job(
    job: Job,
    scenes: &[Scene],
    opts: &MergetreeOptions,
    energy: &sim::energy::Conventions,
) -> anyhow::Result<Done> {
    let drams = &opts.drams[..];
    match job {
        Job::Sim { scene, system } => {
            let s = &scenes[scene];
            let row = simulate(
                s,
                &MergeTreeConfig::p2(),
                &drams[system],
                s.name == FIG6_SCENE,
                energy,
            )?;
            Ok(Done::Sim(scene, system, row))
        }
        Job::Toplevel { scene } => {
            let cfg = MergeTreeConfig {
                highlevel_threshold: Some(bvh::toplevel::default_threshold(
                    bvh::MortonBits::Bits30,
                )),
                toplevel_sah: true,
                ..MergeTreeConfig::p2()
            };
            let row = simulate(&scenes[scene], &cfg, &drams[0], false, energy)?;
            Ok(Done::Toplevel(scene, row))
        }
        Job::Software { scene } => Ok(Done::Software(scene, software(&scenes[scene], opts)?)),
        Job::BoxGrid { scene } => {
            let row = simulate(&scenes[scene], &box_grid_config(), &drams[0], false, energy)?;
            Ok(Done::BoxGrid(scene, row))
        }
    }
}

/// Preset `p2` with Morton codes on a box grid and leaves of at most 8 ([`Job::BoxGrid`]).
fn box_grid_config() -> MergeTreeConfig {
    MergeTreeConfig {
        morton_grid: geom::MortonGrid::Box,
        max_leaf_size: 8,
        ..MergeTreeConfig::p2()
    }
}

/// One MergeTree simulation, checked node for node against the software builder.
fn simulate(
    s: &Scene,
    cfg: &MergeTreeConfig,
    dram: &str,
    trace: bool,
    energy: &sim::energy::Conventions,
) -> anyhow::Result<SimRow> {
    let port = sim::dram::open(dram, cfg.period_fs())?;
    let start = Instant::now();
    let r = mergetree::simulate(&s.prims, cfg, port)
        .with_context(|| format!("MergeTree simulation of {} on {dram}", s.name))?;
    let wall_s = start.elapsed().as_secs_f64();
    let matches = mergetree::tree_matches_software(&r, &s.prims)?;
    let m = &r.memory;
    let bursts = m.row_hits + m.row_misses;
    Ok(SimRow {
        cycles: r.cycles,
        ms: r.ms,
        bytes_read: r.bytes_read,
        bytes_written: r.bytes_written,
        bus_utilization: r.bus_utilization,
        merge_passes: r.merge_passes,
        row_hit_rate: (bursts > 0).then(|| m.row_hits as f64 / bursts as f64),
        energy_mj: m.energy_pj.map(|e| e.total_pj() * 1e-9),
        energy_above_idle_mj: m.energy_pj.map(|e| e.above_idle_pj() * 1e-9),
        energy: sim::mergetree::energy::mergetree_energy(&r, sim::energy::Node::Nm28, energy).ok(),
        toplevel_cycles: r.toplevel_cycles,
        nodes: r.nodes,
        tree_matches_software: matches,
        trace: trace.then(|| {
            let title = format!("MergeTree p2 on {dram}: {} (cf. [P2] Fig. 6)", s.name);
            (r.trace_csv(), r.trace_svg(&title))
        }),
        phases: r.phases,
        wall_s,
    })
}

/// The software builds of a scene (each tree validated) and the analytic models.
fn software(s: &Scene, opts: &MergetreeOptions) -> anyhow::Result<SoftwareRow> {
    let build = |name: &str| -> anyhow::Result<bvh::Bvh2> {
        let tree =
            (opts.build)(name, &s.prims).with_context(|| format!("{name} over {}", s.name))?;
        let bvh::Tree::Bvh2(tree) = tree else {
            anyhow::bail!("{name} makes a 4-wide tree, not a binary one")
        };
        bvh::validate(&tree, &s.prims, opts.max_leaf)
            .with_context(|| format!("{name} over {}: invalid tree", s.name))?;
        Ok(tree)
    };
    let sweep_sah = build("sweep-sah")?.sah();
    let mut row = SoftwareRow {
        sweep_sah,
        gpu_bytes: gpu_hlbvh::build_bytes(s.prims.len() as u64),
        ..Default::default()
    };
    for (i, name) in SAH_BUILDERS.iter().enumerate() {
        let tree = build(name)?;
        row.sah[i] = tree.sah();
        if *name == "binned-sah" {
            row.binned_hw = binned_sah_hw::model(&tree, &Default::default());
        }
    }
    Ok(row)
}

/// `ours / thesis - 1` in percent, signed.
fn diff(ours: f64, thesis: f64) -> String {
    format!("{:+.1}%", (ours / thesis - 1.0) * 100.0)
}

/// `ours / thesis (diff)` for Markdown, or `ours` alone without a thesis value.
fn pair(ours: f64, thesis: Option<f64>, digits: usize) -> String {
    match thesis {
        Some(t) => format!(
            "{ours:.digits$} / {t:.digits$} ({})",
            diff(ours, t),
            digits = digits
        ),
        None => format!("{ours:.digits$}", digits = digits),
    }
}

/// CSV cells `thesis,diff_pct` (empty without a thesis value).
fn csv_pair(ours: f64, thesis: Option<f64>) -> [String; 2] {
    match thesis {
        Some(t) => [t.to_string(), format!("{:.2}", (ours / t - 1.0) * 100.0)],
        None => [String::new(), String::new()],
    }
}

impl Results {
    /// The thesis's system index for our system `k`, when it is the same system of \[P2\]
    /// §6.2 at the same position (a `simple:` model of it counts).
    fn thesis_system(&self, k: usize) -> Option<usize> {
        let bare = self.drams[k]
            .strip_prefix("simple:")
            .unwrap_or(&self.drams[k]);
        (thesis::P2_SYSTEMS.get(k) == Some(&bare)).then_some(k)
    }

    fn label(&self, k: usize) -> String {
        match self.thesis_system(k) {
            Some(0) => "slow".into(),
            Some(1) => "medium".into(),
            Some(2) => "fast".into(),
            _ => self.drams[k].clone(),
        }
    }
}

fn write_summary(md: &mut String, r: &Results) -> anyhow::Result<()> {
    writeln!(md, "## Against the targets\n")?;
    // Speed-ups within 15 %.
    let mut lines = Vec::new();
    for (s, scene) in r.scenes.iter().enumerate() {
        let Some(t) = scene.thesis else { continue };
        for k in 1..r.drams.len() {
            let Some(tk) = r.thesis_system(k) else {
                continue;
            };
            let ours = r.sims[s][0].ms / r.sims[s][k].ms;
            let theirs = t.speedups()[tk - 1];
            let d = (ours / theirs - 1.0) * 100.0;
            lines.push(format!(
                "{} {}: {ours:.2} vs {theirs:.2} ({d:+.1}%, {})",
                scene.name,
                r.label(k),
                if d.abs() <= 15.0 { "met" } else { "missed" }
            ));
        }
    }
    if !lines.is_empty() {
        writeln!(
            md,
            "- Speed-ups over the slow system within 15% of Table III's: {}.",
            lines.join("; ")
        )?;
    }
    // Bus utilization against 72 / 54 / 44 %.
    let mut util = Vec::new();
    for k in 0..r.drams.len() {
        let v: Vec<f64> = r.sims.iter().map(|s| s[k].bus_utilization).collect();
        let shared: Vec<f64> = r
            .scenes
            .iter()
            .zip(&r.sims)
            .filter(|(s, _)| s.thesis.is_some())
            .map(|(_, s)| s[k].bus_utilization)
            .collect();
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
        let thesis = r
            .thesis_system(k)
            .map(|t| {
                format!(
                    " ([P2] average over 14 scenes: {:.0}%)",
                    thesis::P2_BUS_UTILIZATION[t] * 100.0
                )
            })
            .unwrap_or_default();
        util.push(format!(
            "{}: {:.0}% over all scenes, {}{thesis}",
            r.label(k),
            mean(&v) * 100.0,
            if shared.is_empty() {
                "no shared scene".to_string()
            } else {
                format!("{:.0}% over the shared ones", mean(&shared) * 100.0)
            }
        ));
    }
    writeln!(md, "- Bus utilization: {}.", util.join("; "))?;
    // Traffic within 10 %.
    let (mut traffic, mut mib, mut boxed) = (Vec::new(), Vec::new(), Vec::new());
    let verdict = |d: f64| if d.abs() <= 10.0 { "met" } else { "missed" };
    for (s, scene) in r.scenes.iter().enumerate() {
        let Some(t) = scene.thesis else { continue };
        let d = (r.sims[s][0].mb() / t.traffic_mb[0] - 1.0) * 100.0;
        traffic.push(format!("{} {d:+.1}% ({})", scene.name, verdict(d)));
        let d = (r.sims[s][0].mib() / t.traffic_mb[0] - 1.0) * 100.0;
        mib.push(format!("{} {d:+.1}% ({})", scene.name, verdict(d)));
        let d = (r.boxgrid[s].mb() / t.traffic_mb[0] - 1.0) * 100.0;
        boxed.push(format!("{} {d:+.1}%", scene.name));
    }
    if !traffic.is_empty() {
        writeln!(
            md,
            "- MergeTree traffic within 10% of Table VI: {} in 10^6 bytes; {} with Table VI \
             read as MiB (2^20 bytes, the likelier reading); with the box grid and leaves \
             of at most 8 instead (10^6 bytes): {}.",
            traffic.join(", "),
            mib.join(", "),
            boxed.join(", ")
        )?;
    }
    let all = r.sims.iter().flatten().count() + r.top.len() + r.boxgrid.len();
    writeln!(
        md,
        "- Every simulated tree ({all} runs) equals the software builder's node for node; \
         every software tree passed `bvh::validate`.\n\n\
         Why targets are missed: `docs/mergetree-vs-thesis.md`.\n"
    )?;
    Ok(())
}

fn write_table3(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "triangles",
        "system",
        "memory",
        "cycles",
        "ms",
        "thesis_ms",
        "ms_diff_pct",
        "speedup",
        "thesis_speedup",
        "speedup_diff_pct",
        "bus_utilization",
        "thesis_implied_utilization",
        "thesis_average_utilization",
        "bytes_read",
        "bytes_written",
        "merge_passes",
        "row_hit_rate",
        "dram_energy_mj",
        "dram_energy_above_idle_mj",
        "partial_sort_read_latency",
        "final_merge_read_latency",
        "tree_matches_software",
        "sim_wall_s",
    ]);
    writeln!(md, "## Table III analogue: MergeTree build time\n")?;
    writeln!(
        md,
        "Build time in ms and speed-up over the first system, ours / [P2] (difference). \
         [P2]'s bus utilization is implied by its tables (Table VI traffic over Table III \
         time and the peak bandwidth); its text gives the averages 72 / 54 / 44%. DRAM \
         energy: the total, and in brackets what the build adds over an idle memory (the \
         figure [P2] §6.2 reports: idle standby and refresh subtracted). Read \
         latency: mean unit cycles from a read request's acceptance to its last burst, in \
         the partial sorts and in the final merge.\n"
    )?;
    let mut table = Table::text(&[
        "scene",
        "triangles",
        "system",
        "ms",
        "speed-up",
        "bus utilization (ours / [P2] implied)",
        "read latency (sort / merge)",
        "row hits",
        "DRAM mJ (above idle)",
        "passes",
        "same tree",
    ])
    .right(&[1, 7, 8, 9]);
    let mut labels = Vec::new();
    let (mut ours_ms, mut thesis_ms, mut ours_su, mut thesis_su) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (s, scene) in r.scenes.iter().enumerate() {
        for (k, row) in r.sims[s].iter().enumerate() {
            let tk = r.thesis_system(k);
            let t = scene.thesis.zip(tk);
            let t_ms = t.map(|(t, k)| t.mergetree_ms[k]);
            let speedup = r.sims[s][0].ms / row.ms;
            let t_su = t.map(|(t, k)| t.mergetree_ms[0] / t.mergetree_ms[k]);
            let t_util = t.map(|(t, k)| t.implied_utilization()[k]);
            let t_avg = tk.map(|k| thesis::P2_BUS_UTILIZATION[k]);
            let opt = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:.4}"));
            let [t_ms_cell, ms_diff] = csv_pair(row.ms, t_ms);
            let [t_su_cell, su_diff] = csv_pair(speedup, t_su);
            csv.push([
                scene.name.clone(),
                scene.prims.len().to_string(),
                r.label(k).to_string(),
                r.drams[k].to_string(),
                row.cycles.to_string(),
                format!("{:.4}", row.ms),
                t_ms_cell,
                ms_diff,
                format!("{speedup:.4}"),
                t_su_cell,
                su_diff,
                row.bus_utilization.to_string(),
                opt(t_util),
                opt(t_avg),
                row.bytes_read.to_string(),
                row.bytes_written.to_string(),
                row.merge_passes.to_string(),
                opt(row.row_hit_rate),
                opt(row.energy_mj),
                opt(row.energy_above_idle_mj),
                format!("{:.1}", row.read_latency()[0]),
                format!("{:.1}", row.read_latency()[1]),
                row.tree_matches_software.to_string(),
                format!("{:.2}", row.wall_s),
            ]);
            table.push([
                scene.name.clone(),
                thousands(scene.prims.len() as u64),
                r.label(k).to_string(),
                pair(row.ms, t_ms, 3),
                if k == 0 {
                    "1".to_string()
                } else {
                    pair(speedup, t_su, 2)
                },
                match t_util {
                    Some(u) => format!("{:.0}% / {:.0}%", row.bus_utilization * 100.0, u * 100.0),
                    None => format!("{:.0}%", row.bus_utilization * 100.0),
                },
                format!(
                    "{:.0} / {:.0}",
                    row.read_latency()[0],
                    row.read_latency()[1]
                ),
                row.row_hit_rate
                    .map_or("-".into(), |h| format!("{:.0}%", h * 100.0)),
                match (row.energy_mj, row.energy_above_idle_mj) {
                    (Some(e), Some(a)) => format!("{e:.2} ({a:.2})"),
                    _ => "-".into(),
                },
                row.merge_passes.to_string(),
                if row.tree_matches_software {
                    "yes"
                } else {
                    "NO"
                }
                .to_string(),
            ]);
            if scene.thesis.is_some() {
                labels.push(format!("{} {}", scene.name, r.label(k)));
                ours_ms.push(Some(row.ms));
                thesis_ms.push(t_ms);
                if k > 0 {
                    ours_su.push(Some(speedup));
                    thesis_su.push(t_su);
                }
            }
        }
    }
    writeln!(md, "{}", table.markdown())?;
    write_file(out, "table3.csv", &csv.csv())?;
    if !labels.is_empty() {
        write_file(
            out,
            "table3.svg",
            &bar_svg(
                "MergeTree build time (ms), ours vs [P2] Table III",
                &labels,
                &[("ours".into(), ours_ms), ("[P2]".into(), thesis_ms)],
            ),
        )?;
        let su_labels: Vec<String> = r
            .scenes
            .iter()
            .filter(|s| s.thesis.is_some())
            .flat_map(|s| (1..r.drams.len()).map(move |k| (s, k)))
            .map(|(s, k)| format!("{} {}", s.name, r.label(k)))
            .collect();
        write_file(
            out,
            "speedup.svg",
            &bar_svg(
                "Speed-up over the slow system, ours vs [P2] Table III",
                &su_labels,
                &[("ours".into(), ours_su), ("[P2]".into(), thesis_su)],
            ),
        )?;
    }
    Ok(())
}

fn write_sah(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "triangles",
        "builder",
        "sah",
        "sweep_sah",
        "sah_vs_sweep_pct",
        "thesis_pct",
        "diff_pct",
        "toplevel_unit_ms",
        "thesis_toplevel_ms",
    ]);
    writeln!(md, "## Table III analogue: tree quality\n")?;
    writeln!(
        md,
        "SAH (C_i = 1.2, C_t = 1) in % of a full sweep SAH build of the same triangles, \
         ours / [P2] (difference). `hlbvh` is MergeTree's tree and `hlbvh+sah` the tree of \
         MergeTree with its toplevel binned SAH unit (both equal to the software builders' \
         node for node); `hlbvh+atrbvh` and `binned-sah` are the software builders (Arbor's \
         defaults: ATRBVH over the top tree, treelets of 8, two iterations; 16 bins). [P2]'s \
         binned SAH column is Doyle et al.'s hardware builder. The toplevel unit's time is \
         in addition to the HLBVH build ([P2] \"HW Binned SAH topl.\"), on the {} system.\n",
        r.label(0)
    )?;
    let mut table = Table::text(&[
        "scene",
        "triangles",
        "hlbvh",
        "hlbvh+sah",
        "hlbvh+atrbvh",
        "binned-sah",
        "toplevel unit ms",
    ])
    .right(&[1]);
    for (s, scene) in r.scenes.iter().enumerate() {
        let sw = &r.sw[s];
        let mut cells = Vec::new();
        for (i, name) in SAH_BUILDERS.iter().enumerate() {
            let pct = 100.0 * bvh::sah_ratio(sw.sah[i], sw.sweep_sah);
            let t = scene.thesis.map(|t| t.sah_pct[i]);
            let top = (i == 1).then(|| {
                let ms = r.top[s].toplevel_cycles as f64 / 1e6;
                (ms, scene.thesis.map(|t| t.toplevel_sah_ms))
            });
            let [t_cell, diff_cell] = csv_pair(pct, t);
            csv.push([
                scene.name.clone(),
                scene.prims.len().to_string(),
                name.to_string(),
                format!("{:.4}", sw.sah[i]),
                format!("{:.4}", sw.sweep_sah),
                format!("{pct:.2}"),
                t_cell,
                diff_cell,
                top.map_or(String::new(), |x| format!("{:.4}", x.0)),
                top.and_then(|x| x.1)
                    .map_or(String::new(), |x| x.to_string()),
            ]);
            cells.push(pair(pct, t, 1));
        }
        let ms = r.top[s].toplevel_cycles as f64 / 1e6;
        let mut row = vec![scene.name.clone(), thousands(scene.prims.len() as u64)];
        row.extend(cells);
        row.push(pair(ms, scene.thesis.map(|t| t.toplevel_sah_ms), 3));
        table.push(row);
    }
    writeln!(md, "{}", table.markdown())?;
    write_file(out, "sah.csv", &csv.csv())
}

/// MergeTree's traffic split as \[P2\] §4.2 counts it: input read, sort runs written and
/// read back, BVH output (nodes, leaf table, high-level records), in bytes.
fn traffic_split(row: &SimRow) -> [u64; 4] {
    let mut t = [0u64; 4];
    for p in &row.phases {
        if p.name == "partial_sort" {
            t[0] += p.bytes_read;
            t[1] += p.bytes_written;
        } else if p.name == "sort_and_emit" {
            // One block: the sorted input streams straight into the emitter.
            t[0] += p.bytes_read;
            t[3] += p.bytes_written;
        } else if p.name.ends_with("_and_emit") {
            t[2] += p.bytes_read;
            t[3] += p.bytes_written;
        } else {
            // Intermediate passes read and write sort runs; the toplevel writes nodes.
            t[2] += p.bytes_read;
            if p.name.starts_with("merge_pass") {
                t[1] += p.bytes_written;
            } else {
                t[3] += p.bytes_written;
            }
        }
    }
    t
}

/// \[P2\] Tables IV and VII: MergeTree's power per memory system averaged over the scenes
/// (traffic, logic, DRAM above idle, total) and the unit breakdown of the largest scene on
/// the last system, beside the thesis's, from `sim::mergetree::energy` at 28 nm.
fn write_table7(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let start = md.len();
    write_table7_into(out, md, r)?;
    write_file(out, "table7.md", &md[start..])
}

/// [`write_table7`]'s tables, appended to `md`.
fn write_table7_into(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "system",
        "memory",
        "scenes",
        "traffic_gbs",
        "thesis_traffic_gbs",
        "logic_mw",
        "thesis_logic_mw",
        "dram_mw",
        "dram_above_idle_mw",
        "thesis_dram_mw",
        "total_mw",
        "thesis_total_mw",
        "dram_share",
    ]);
    writeln!(md, "## Tables IV and VII analogues: MergeTree power\n")?;
    writeln!(
        md,
        "Means over the scenes at 28 nm ({}; `sim::mergetree::energy`: the \
         unit's memory blocks and operations, not synthesized logic; comparators, muxes and \
         control are not counted). DRAM power is above an idle memory, as [P2] §6.2 reports it; \
         total = logic + DRAM above idle. Ours / [P2] Table VII.\n",
        r.energy.describe()
    )?;
    let mut table = Table::text(&[
        "system",
        "traffic GB/s",
        "logic mW",
        "DRAM mW",
        "total mW",
        "DRAM share",
    ])
    .right(&[5]);
    for k in 0..r.drams.len() {
        let rows: Vec<&SimRow> = r.sims.iter().filter_map(|s| s.get(k)).collect();
        let es: Vec<&sim::mergetree::energy::MergeTreeEnergy> =
            rows.iter().filter_map(|row| row.energy.as_ref()).collect();
        if es.is_empty() {
            continue;
        }
        let n = es.len() as f64;
        let mean = |f: &dyn Fn(&sim::mergetree::energy::MergeTreeEnergy) -> f64| {
            es.iter().map(|e| f(e)).sum::<f64>() / n
        };
        let traffic = rows
            .iter()
            .map(|row| (row.bytes_read + row.bytes_written) as f64 / (row.ms * 1e-3) / 1e9)
            .sum::<f64>()
            / rows.len() as f64;
        let (logic, dram, above) = (
            mean(&|e| e.logic_mw),
            mean(&|e| e.dram_mw),
            mean(&|e| e.dram_above_idle_mw),
        );
        let total = logic + above;
        let t = r
            .thesis_system(k)
            .map(|k| [0, 1, 2, 3].map(|i| thesis::P2_TABLE_VII[i][k]));
        let pair = |ours: f64, i: usize| match t {
            Some(t) => format!("{ours:.1} / {}", t[i]),
            None => format!("{ours:.1}"),
        };
        table.push([
            r.label(k).to_string(),
            pair(traffic, 0),
            pair(logic, 1),
            pair(above, 2),
            pair(total, 3),
            format!("{:.0}%", 100.0 * above / total),
        ]);
        let th = |i: usize| t.map_or(String::new(), |t| t[i].to_string());
        csv.push([
            r.label(k).to_string(),
            r.drams[k].to_string(),
            es.len().to_string(),
            format!("{traffic:.3}"),
            th(0),
            format!("{logic:.2}"),
            th(1),
            format!("{dram:.2}"),
            format!("{above:.2}"),
            th(2),
            format!("{total:.2}"),
            th(3),
            format!("{:.4}", above / total),
        ]);
    }
    md.push_str(&table.markdown());
    write_file(out, "table7.csv", &csv.csv())?;
    // Table IV: the largest scene on the last system.
    let last = r.drams.len().saturating_sub(1);
    let big = (0..r.scenes.len()).max_by_key(|&s| r.scenes[s].prims.len());
    if let Some(e) = big
        .and_then(|s| r.sims[s].get(last))
        .and_then(|row| row.energy.as_ref())
    {
        let s = big.expect("some scene");
        writeln!(
            md,
            "\nTable IV analogue: {} on {} (the thesis: Lion on the fast system); area mm^2 and power mW, ours / [P2].\n",
            r.scenes[s].name,
            r.label(last)
        )?;
        let mut table = Table::text(&["unit", "area", "power"]);
        let mut t4 = Table::text(&[
            "unit",
            "area_mm2",
            "thesis_area_mm2",
            "power_mw",
            "thesis_power_mw",
        ]);
        // The unit's name in the Markdown and in the CSV (the total row: "total", "Total").
        let units = e.units[..4].iter().map(|u| {
            (
                u.unit.to_string(),
                u.unit.to_string(),
                u.area_mm2,
                u.power_mw,
            )
        });
        let total = [("total".into(), "Total".into(), e.area_mm2, e.logic_mw)];
        for ((unit, csv_unit, area, power), t) in units.chain(total).zip(thesis::P2_TABLE_IV) {
            table.push([
                unit,
                format!("{area:.3} / {}", t.1),
                format!("{power:.1} / {}", t.2),
            ]);
            t4.push([
                csv_unit,
                format!("{area:.4}"),
                t.1.to_string(),
                format!("{power:.3}"),
                t.2.to_string(),
            ]);
        }
        writeln!(md, "{}", table.markdown())?;
        write_file(out, "table4.csv", &t4.csv())?;
    }
    Ok(())
}

fn write_table6(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "triangles",
        "mergetree_mb",
        "thesis_mergetree_mb",
        "mergetree_diff_pct",
        "binned_sah_hw_mb",
        "thesis_binned_sah_hw_mb",
        "binned_sah_hw_diff_pct",
        "binned_ratio",
        "thesis_binned_ratio",
        "gpu_hlbvh_mb",
        "thesis_gpu_hlbvh_mb",
        "gpu_hlbvh_diff_pct",
        "gpu_ratio",
        "thesis_gpu_ratio",
        "input_mb",
        "runs_written_mb",
        "runs_read_mb",
        "output_mb",
        "bytes_per_triangle",
        "mergetree_mib",
        "mergetree_diff_pct_mib",
        "leaf_size",
        "box_grid_mb",
        "box_grid_diff_pct",
        "box_grid_leaf_size",
    ]);
    writeln!(md, "## Table VI analogue: memory traffic (MB)\n")?;
    writeln!(
        md,
        "MergeTree: the simulated run's bytes on the {} system (whole bursts; the same on \
         every system). Binned SAH hardware: `sim::analytic::binned_sah_hw` ([P2] §6.1) over \
         the 16-bin `binned-sah` tree. GPU HLBVH: `sim::analytic::gpu_hlbvh`, the 324 B per \
         triangle of [P2] §4.2, against [P2]'s profiler measurement on a GTX 1080. Ratios \
         are over MergeTree's traffic, ours / [P2]. The split: input read, sort runs written \
         and read, BVH output. MiB: the same traffic in 2^20 bytes beside Table VI read as \
         MiB, the likelier unit (`docs/mergetree-vs-thesis.md`), with triangles per leaf in \
         brackets. Box grid: the same simulation with Morton codes on box-shaped cells and \
         leaves of at most 8 (not the thesis's unit), in 10^6 bytes.\n",
        r.label(0)
    )?;
    let mut table = Table::text(&[
        "scene",
        "triangles",
        "MergeTree",
        "binned SAH HW",
        "ratio",
        "GPU HLBVH",
        "ratio",
        "input / runs w / runs r / output",
        "B per triangle",
        "MergeTree (MiB)",
        "box grid",
    ])
    .right(&[1, 8]);
    let mut labels = Vec::new();
    let mut series: Vec<(String, Vec<Option<f64>>)> = [
        "MergeTree ours",
        "MergeTree [P2]",
        "binned SAH HW ours",
        "binned SAH HW [P2]",
        "GPU HLBVH ours",
        "GPU HLBVH [P2]",
    ]
    .iter()
    .map(|n| (n.to_string(), Vec::new()))
    .collect();
    for (s, scene) in r.scenes.iter().enumerate() {
        let n = scene.prims.len();
        let mt = r.sims[s][0].mb();
        let bh = r.sw[s].binned_hw.total_bytes() as f64 / 1e6;
        let gpu = r.sw[s].gpu_bytes as f64 / 1e6;
        let t = scene.thesis.map(|t| t.traffic_mb);
        let split = traffic_split(&r.sims[s][0]).map(|b| b as f64 / 1e6);
        let ratio = |i: usize| t.map(|t| t[i] / t[0]);
        let mib = r.sims[s][0].mib();
        // One binary tree of L leaves has L - 1 inner nodes.
        let leaf = n as f64 / (r.sims[s][0].nodes + 1) as f64;
        let boxed = &r.boxgrid[s];
        let box_mb = boxed.mb();
        let box_leaf = n as f64 / (boxed.nodes + 1) as f64;
        let mut row = vec![scene.name.clone(), n.to_string(), format!("{mt:.3}")];
        row.extend(csv_pair(mt, t.map(|t| t[0])));
        row.push(format!("{bh:.3}"));
        row.extend(csv_pair(bh, t.map(|t| t[1])));
        row.push(format!("{:.3}", bh / mt));
        row.push(ratio(1).map_or(String::new(), |x| format!("{x:.3}")));
        row.push(format!("{gpu:.3}"));
        row.extend(csv_pair(gpu, t.map(|t| t[2])));
        row.push(format!("{:.3}", gpu / mt));
        row.push(ratio(2).map_or(String::new(), |x| format!("{x:.3}")));
        row.extend(split.map(|x| format!("{x:.3}")));
        row.push(format!("{:.1}", mt * 1e6 / n as f64));
        row.push(format!("{mib:.3}"));
        row.push(t.map_or(String::new(), |t| {
            format!("{:.2}", (mib / t[0] - 1.0) * 100.0)
        }));
        row.push(format!("{leaf:.2}"));
        row.push(format!("{box_mb:.3}"));
        row.push(t.map_or(String::new(), |t| {
            format!("{:.2}", (box_mb / t[0] - 1.0) * 100.0)
        }));
        row.push(format!("{box_leaf:.2}"));
        csv.push(row);
        let rat = |x: f64, i: usize| match ratio(i) {
            Some(tr) => format!("{:.1}x / {tr:.1}x", x / mt),
            None => format!("{:.1}x", x / mt),
        };
        table.push([
            scene.name.clone(),
            thousands(n as u64),
            pair(mt, t.map(|t| t[0]), 1),
            pair(bh, t.map(|t| t[1]), 1),
            rat(bh, 1),
            pair(gpu, t.map(|t| t[2]), 1),
            rat(gpu, 2),
            format!(
                "{:.1} / {:.1} / {:.1} / {:.1}",
                split[0], split[1], split[2], split[3]
            ),
            format!("{:.0}", mt * 1e6 / n as f64),
            format!("{} ({leaf:.2})", pair(mib, t.map(|t| t[0]), 1)),
            format!("{} ({box_leaf:.2})", pair(box_mb, t.map(|t| t[0]), 1)),
        ]);
        if let Some(t) = t {
            labels.push(scene.name.clone());
            for (i, v) in [mt, t[0], bh, t[1], gpu, t[2]].into_iter().enumerate() {
                series[i].1.push(Some(v));
            }
        }
    }
    writeln!(md, "{}", table.markdown())?;
    write_file(out, "table6.csv", &csv.csv())?;
    if !labels.is_empty() {
        write_file(
            out,
            "table6.svg",
            &bar_svg(
                "Memory traffic (MB), ours vs [P2] Table VI",
                &labels,
                &series,
            ),
        )?;
    }
    Ok(())
}

fn write_fig6(out: &Path, md: &mut String, r: &Results) -> anyhow::Result<()> {
    let Some(s) = r.scenes.iter().position(|s| s.name == FIG6_SCENE) else {
        return Ok(());
    };
    writeln!(md, "## Unit activity ({FIG6_SCENE}, cf. \\[P2\\] Fig. 6)\n")?;
    for (k, row) in r.sims[s].iter().enumerate() {
        let Some((csv, svg)) = &row.trace else {
            continue;
        };
        let label = r.label(k);
        write_file(out, &format!("fig6-{label}.csv"), csv)?;
        write_file(out, &format!("fig6-{label}.svg"), svg)?;
        writeln!(
            md,
            "- `fig6-{label}.svg` ({}): {:.3} ms",
            r.drams[k], row.ms
        )?;
    }
    writeln!(md)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_and_pairs() {
        assert_eq!(diff(1.1, 1.0), "+10.0%");
        assert_eq!(diff(0.9, 1.0), "-10.0%");
        assert_eq!(pair(2.0, Some(4.0), 1), "2.0 / 4.0 (-50.0%)");
        assert_eq!(pair(2.0, None, 2), "2.00");
        assert_eq!(csv_pair(3.0, Some(2.0)), ["2", "50.00"]);
        assert_eq!(csv_pair(3.0, None), ["", ""]);
    }

    #[test]
    fn traffic_split_sorts_phases() {
        let p = |name: &str, r, w| PhaseReport {
            name: name.into(),
            start_cycle: 0,
            end_cycle: 1,
            bytes_read: r,
            bytes_written: w,
            reads: 0,
            read_latency_mean_cycles: 0.0,
        };
        let row = SimRow {
            phases: vec![
                p("partial_sort", 10, 10),
                p("merge_pass_1", 10, 10),
                p("merge_pass_2_and_emit", 10, 7),
                p("toplevel_sah", 0, 1),
            ],
            ..Default::default()
        };
        assert_eq!(traffic_split(&row), [10, 20, 20, 8]);
        let one_block = SimRow {
            phases: vec![p("sort_and_emit", 10, 7)],
            ..Default::default()
        };
        assert_eq!(traffic_split(&one_block), [10, 0, 0, 7]);
    }
}
