//! `arbor sim mergetree` runs the MergeTree
//! builder model (`sim::mergetree`, \[P1\], \[P2\] §4-6) over a scene, checks that its tree
//! equals the software HLBVH builder's node for node, and reports cycles, time, traffic per
//! phase, bus utilization, stall causes and a utilization trace (CSV and SVG, \[P2\] Fig. 6
//! style). The JSON form (`arbor.sim.mergetree.v1`) is documented in `docs/cli-json.md`.

use super::build::mesh_aabbs;
use super::{ms, open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::Context;
use geom::Aabb;
use serde::Serialize;
use sim::mergetree::{self, MergeTreeConfig, MergeTreeReport};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `arbor sim mergetree`.
#[derive(clap::Args, Debug)]
pub struct MergetreeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Architecture preset: p1 (thesis P1: M=4096, B=8) or p2 (thesis P2: M=8192, B=16).
    #[arg(long, default_value = "p2")]
    preset: String,
    /// Memory system: lpddr3-1600-1x64 (slow), lpddr3-1600-2x64 (medium),
    /// lpddr3-1333-4x64 (fast), lpddr3-1600-2x32; prefix `simple:` for the simple model.
    #[arg(long, default_value = "lpddr3-1600-1x64")]
    dram: String,
    /// Configuration file (flat TOML `key = value` lines or a flat JSON object), applied
    /// after the preset and before --set.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Override one parameter, e.g. --set m=4096 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Time at which to sample the scene, in seconds.
    #[arg(long, value_name = "SECONDS")]
    time: Option<f32>,
    /// Write the utilization time series as CSV.
    #[arg(long, value_name = "FILE")]
    trace: Option<PathBuf>,
    /// Write the utilization plot as SVG.
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
    /// Skip the node-for-node comparison with the software builder.
    #[arg(long)]
    no_check: bool,
    /// Print JSON (schema `arbor.sim.mergetree.v1`) instead of text.
    #[arg(long)]
    json: bool,
}

/// The JSON document `arbor sim mergetree --json` prints.
#[derive(Serialize)]
struct Output<'a> {
    schema: &'static str,
    scene: &'a str,
    preset: &'a str,
    /// Memory system name as given.
    dram_system: &'a str,
    #[serde(flatten)]
    report: &'a MergeTreeReport,
    tree_matches_software: Option<bool>,
    trace: Option<String>,
    svg: Option<String>,
    sim_wall_ms: f64,
    sim_cycles_per_s: f64,
}

/// Builds the configuration from the preset, the file and the overrides.
pub fn config_from(
    preset: &str,
    file: Option<&std::path::Path>,
    set: &[String],
) -> anyhow::Result<MergeTreeConfig> {
    let mut cfg = MergeTreeConfig::preset(preset)?;
    if let Some(f) = file {
        cfg.apply_file(f)?;
    }
    for s in set {
        cfg.set_pair(s)?;
    }
    cfg.validate()?;
    Ok(cfg)
}

/// One simulation with a progress bar; returns the report and the wall time in ms.
pub fn simulate(
    ui: &Ui,
    aabbs: &[Aabb],
    cfg: &MergeTreeConfig,
    dram: &str,
) -> anyhow::Result<(MergeTreeReport, f64)> {
    let port = sim::dram::open(dram, cfg.period_fs())?;
    let bar = ui.progress(
        &format!(
            "simulating MergeTree over {} triangles on {dram}",
            thousands(aabbs.len() as u64)
        ),
        Unit::Items,
    );
    let start = Instant::now();
    let mut hook = |done: u64, total: u64| bar.update(done, total);
    let r = mergetree::simulate_with_progress(aabbs, cfg, port, Some(&mut hook));
    bar.finish();
    let r = r.context("MergeTree simulation failed")?;
    Ok((r, ms(start.elapsed())))
}

pub fn run_mergetree(a: &MergetreeArgs, ui: &Ui) -> anyhow::Result<()> {
    let cfg = config_from(&a.preset, a.config.as_deref(), &a.set)?;
    // Fail on a bad memory name before loading the scene.
    sim::dram::open(&a.dram, cfg.period_fs())?;
    let (scene, _) = open_scene(&a.scene, ui)?;
    let t = scene.info().timeline.clamp(a.time.unwrap_or(0.0));
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample the scene at t = {t} s"))?;
    let (aabbs, _) = mesh_aabbs(&mesh)?;
    drop(mesh);
    let (report, wall_ms) = simulate(ui, &aabbs, &cfg, &a.dram)?;
    let matches = if a.no_check {
        None
    } else {
        let _s = ui.spinner("building the software HLBVH tree to compare");
        Some(mergetree::tree_matches_software(&report, &aabbs)?)
    };
    if let Some(p) = &a.trace {
        super::report::write_atomic(p, &report.trace_csv())?;
    }
    if let Some(p) = &a.svg {
        let title = format!("MergeTree {} on {}: {}", cfg.preset, a.dram, a.scene.scene);
        super::report::write_atomic(p, &report.trace_svg(&title))?;
    }
    let cps = report.cycles as f64 / (wall_ms / 1e3).max(1e-9);
    if a.json {
        let out = Output {
            schema: "arbor.sim.mergetree.v1",
            scene: &a.scene.scene,
            preset: &a.preset,
            dram_system: &a.dram,
            report: &report,
            tree_matches_software: matches,
            trace: a.trace.as_ref().map(|p| p.display().to_string()),
            svg: a.svg.as_ref().map(|p| p.display().to_string()),
            sim_wall_ms: wall_ms,
            sim_cycles_per_s: cps,
        };
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_text(a, &report, matches, wall_ms);
    }
    if matches == Some(false) {
        anyhow::bail!("the simulated tree differs from the software HLBVH tree");
    }
    Ok(())
}

fn print_text(a: &MergetreeArgs, r: &MergeTreeReport, matches: Option<bool>, wall_ms: f64) {
    println!(
        "MergeTree {} (M={}, B={}, {} presorters, {} MHz) on {} [{}]",
        r.config.preset,
        r.config.m,
        r.config.b,
        r.config.presorters,
        r.config.clock_mhz,
        a.dram,
        r.dram
    );
    println!(
        "scene {}: {} triangles, {} partial-sort blocks, {} merge pass(es)",
        a.scene.scene,
        thousands(r.triangles),
        r.partial_sort_blocks,
        r.merge_passes
    );
    println!(
        "cycles {} = {:.3} ms; read {:.2} MB, written {:.2} MB; bus utilization {:.1}%",
        thousands(r.cycles),
        r.ms,
        r.bytes_read as f64 / 1e6,
        r.bytes_written as f64 / 1e6,
        r.bus_utilization * 100.0
    );
    for p in &r.phases {
        println!(
            "  {:<24} cycles {:>12}  read {:>9.2} MB  written {:>9.2} MB  read latency {:>6.1} cycles",
            p.name,
            thousands(p.end_cycle - p.start_cycle),
            p.bytes_read as f64 / 1e6,
            p.bytes_written as f64 / 1e6,
            p.read_latency_mean_cycles
        );
    }
    let s = &r.stalls;
    println!(
        "stalls: merge queue dry {} / output full {} / init wait {}; emitter starved {} / \
         write full {}; presorters starved {} / waiting for scratchpad {}",
        thousands(s.merge.queue_dry_cycles),
        thousands(s.merge.output_full_cycles),
        thousands(s.merge.init_wait_cycles),
        thousands(s.emitter.starved_cycles),
        thousands(s.emitter.write_full_cycles),
        thousands(s.presort_starved_cycles),
        thousands(s.presort_wait_scratchpad_cycles)
    );
    println!(
        "tree matches software hlbvh: {}; simulated {:.1} M cycles/s",
        match matches {
            Some(true) => "yes",
            Some(false) => "NO",
            None => "not checked",
        },
        r.cycles as f64 / (wall_ms * 1e3).max(1e-9)
    );
}
