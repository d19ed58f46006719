//! `arbor sim mergetree` runs the MergeTree
//! builder model (`sim::mergetree`, \[P1\], \[P2\] §4-6) over a scene, checks that its tree
//! equals the software HLBVH builder's node for node, and reports cycles, time, traffic per
//! phase, bus utilization, stall causes and a utilization trace (CSV and SVG, \[P2\] Fig. 6
//! style). With `--cbvh` the unit writes a compressed BVH (\[P3\] §5.3): through the
//! streaming bottom-up encoder attached to the emitter, or with a top-down pass after the
//! build; the CBVH is then also checked bit for bit against the software encoder. With
//! `--set output=mbvh4` the unit writes 128-byte MBVH4 nodes through the streaming collapse
//! behind the emitter, and with `--set output=mbvh4-collapse` through a collapse pass after
//! the build (issue 18 part 2); the MBVH4 is then checked node for node against the
//! software collapse. With `--set output=cbvh4` the collapse unit's wide nodes go through
//! the streaming CBVH encoder carried over to 4-wide nodes (32-byte compressed nodes),
//! checked bit for bit against `cbvh::compress_stream_collapse`. The JSON
//! form (`arbor.sim.mergetree.v1`) is documented in `docs/cli-json.md`.
//! `--set output=kdtree-points` (issue 18, part 3) the unit builds a point k-d tree over the
//! triangles' centroids (or `--points uniform:N`, random points in the scene's box), checked
//! node for node against `bvh::PointTree`; `--points` in the other modes builds them over the
//! same points (degenerate boxes), the baseline of the point mode. The JSON form (`arbor.sim.mergetree.v1`) is
//! documented in `docs/cli-json.md`.

use super::build::mesh_aabbs;
use super::{ms, open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::Context;
use geom::Aabb;
use serde::Serialize;
use sim::mergetree::{self, MergeTreeConfig, MergeTreeReport, OutputMode};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `arbor sim mergetree`.
#[derive(clap::Args, Debug)]
pub struct MergetreeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Architecture preset: p1 (thesis P1: M=4096, B=8), p2 (thesis P2: M=8192, B=16) or
    /// p3 (thesis P3: M=8192, B=8, leaves of any size). Default: p2, or p3 with --cbvh.
    #[arg(long)]
    preset: Option<String>,
    /// Memory system: lpddr3-1600-1x64 (slow), lpddr3-1600-2x64 (medium),
    /// lpddr3-1333-4x64 (fast), lpddr3-1600-2x32 (Arbor's model of DRAMsim3's controller); prefix
    /// `dramsim3:` for DRAMsim3 itself, `simple:` for the simple model; append
    /// `,KEY=VALUE,...` to a name for a what-if of the model (any key of its configuration,
    /// or write_drain, write_high_watermark, write_low_watermark, row_hit_cap, bank_xor).
    /// Default: lpddr3-1600-1x64, or lpddr3-1600-2x32 with --cbvh (thesis P3 5.3).
    #[arg(long)]
    dram: Option<String>,
    /// Write a compressed BVH (thesis P3): `stream` (the streaming bottom-up encoder behind
    /// the emitter) or `topdown` (64-byte nodes, then a top-down compression pass).
    #[arg(long, value_enum, value_name = "MODE")]
    cbvh: Option<CbvhMode>,
    /// CBVH coordinates with --cbvh: relative (default) or modulo.
    #[arg(long, value_enum)]
    coords: Option<CoordsArg>,
    /// Treelet depth of the streaming encoder with --cbvh stream (1 = none, the default; up
    /// to 8).
    #[arg(long, value_name = "D")]
    treelet: Option<u32>,
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
    /// Build over points instead of the triangles: `centroids` (the triangles' vertex
    /// means; the default of `--set output=kdtree-points`) or `uniform:N` (N uniform random
    /// points in the centroids' box, a fixed seed). Each point is a degenerate box.
    #[arg(long, value_name = "SPEC")]
    points: Option<String>,
    #[command(flatten)]
    energy: super::energy_args::EnergyArgs,
    /// Print JSON (schema `arbor.sim.mergetree.v1`) instead of text.
    #[arg(long)]
    json: bool,
}

/// `--cbvh` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum CbvhMode {
    Stream,
    Topdown,
}

/// `--coords` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum CoordsArg {
    Relative,
    Modulo,
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
    cbvh_matches_software: Option<bool>,
    mbvh4_matches_software: Option<bool>,
    /// `output = cbvh4`: the compressed 4-wide tree equals the software encoder's.
    cbvh4_matches_software: Option<bool>,
    trace: Option<String>,
    svg: Option<String>,
    sim_wall_ms: f64,
    sim_cycles_per_s: f64,
    /// Energy and area at 28 nm ([P2] §6.4's node) under `--energy`'s conventions.
    energy: Option<sim::mergetree::energy::MergeTreeEnergy>,
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

/// The configuration of `a`: preset, file, the `--cbvh` options, then `--set`.
fn config_of(a: &MergetreeArgs) -> anyhow::Result<MergeTreeConfig> {
    let preset = a
        .preset
        .as_deref()
        .unwrap_or(if a.cbvh.is_some() { "p3" } else { "p2" });
    let mut set = Vec::new();
    match a.cbvh {
        Some(mode) => {
            let output = match mode {
                CbvhMode::Stream => OutputMode::CbvhStream,
                CbvhMode::Topdown => OutputMode::CbvhTopdown,
            };
            let coords = match a.coords.unwrap_or(CoordsArg::Relative) {
                CoordsArg::Relative => "relative",
                CoordsArg::Modulo => "modulo",
            };
            let treelet = a.treelet.unwrap_or(1);
            if mode == CbvhMode::Topdown && treelet != 1 {
                anyhow::bail!("--treelet applies to --cbvh stream only");
            }
            set.push(format!("output={}", output.name()));
            set.push(format!("cbvh_coords={coords}"));
            set.push(format!("cbvh_treelet_depth={treelet}"));
        }
        None => {
            if a.coords.is_some() || a.treelet.is_some() {
                anyhow::bail!("--coords and --treelet need --cbvh stream or --cbvh topdown");
            }
        }
    }
    set.extend(a.set.iter().cloned());
    config_from(preset, a.config.as_deref(), &set)
}

/// The configuration and memory system of `a`, checked without loading the scene.
fn config_and_dram(a: &MergetreeArgs) -> anyhow::Result<(MergeTreeConfig, &str)> {
    let cfg = config_of(a)?;
    let dram = a.dram.as_deref().unwrap_or(if a.cbvh.is_some() {
        "lpddr3-1600-2x32"
    } else {
        "lpddr3-1600-1x64"
    });
    sim::dram::open(dram, cfg.period_fs())?;
    Ok((cfg, dram))
}

/// Checks the options of `a` (preset, file, `--set` keys and values, memory system)
/// without loading the scene or simulating: what a sweep checks before it runs.
pub fn check_mergetree(a: &MergetreeArgs) -> anyhow::Result<()> {
    config_and_dram(a)?;
    a.points.as_deref().map(points_spec).transpose()?;
    Ok(())
}

pub fn run_mergetree(a: &MergetreeArgs, ui: &Ui) -> anyhow::Result<()> {
    // Fail on a bad option or memory name before loading the scene.
    let (cfg, dram) = config_and_dram(a)?;
    let uniform = a.points.as_deref().map(points_spec).transpose()?;
    let conv = a.energy.conventions()?;
    let (scene, _) = open_scene(&a.scene, ui)?;
    let t = super::resolve_time(scene.info(), a.time, None)?;
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample the scene at t = {t} s"))?;
    let aabbs = match (&uniform, cfg.output.is_points()) {
        (None, false) => mesh_aabbs(&mesh)?.0,
        (u, _) => mergetree::point_boxes(&scene_points(&mesh, u.flatten()))?,
    };
    drop(mesh);
    let (report, wall_ms) = simulate(ui, &aabbs, &cfg, dram)?;
    let (matches, cbvh_matches, mbvh4_matches, cbvh4_matches) = if a.no_check {
        (None, None, None, None)
    } else {
        let _s = ui.spinner("building the software HLBVH tree to compare");
        (
            Some(mergetree::tree_matches_software(&report, &aabbs)?),
            mergetree::cbvh_matches_software(&report, &aabbs)?,
            mergetree::mbvh4_matches_software(&report, &aabbs)?,
            mergetree::cbvh4_matches_software(&report, &aabbs)?,
        )
    };
    if let Some(p) = &a.trace {
        report::fs::write_atomic(p, report.trace_csv())?;
    }
    if let Some(p) = &a.svg {
        let title = format!("MergeTree {} on {}: {}", cfg.preset, dram, a.scene.scene);
        report::fs::write_atomic(p, report.trace_svg(&title))?;
    }
    let cps = report.cycles as f64 / (wall_ms / 1e3).max(1e-9);
    let energy =
        sim::mergetree::energy::mergetree_energy(&report, sim::energy::Node::Nm28, &conv).ok();
    if a.json {
        let out = Output {
            schema: "arbor.sim.mergetree.v1",
            scene: &a.scene.scene,
            preset: &cfg.preset,
            dram_system: dram,
            report: &report,
            tree_matches_software: matches,
            cbvh_matches_software: cbvh_matches,
            mbvh4_matches_software: mbvh4_matches,
            cbvh4_matches_software: cbvh4_matches,
            trace: a.trace.as_ref().map(|p| p.display().to_string()),
            svg: a.svg.as_ref().map(|p| p.display().to_string()),
            sim_wall_ms: wall_ms,
            sim_cycles_per_s: cps,
            energy,
        };
        ui.emit_json(&out)?;
    } else {
        print_text(
            a,
            dram,
            &report,
            [matches, cbvh_matches, mbvh4_matches, cbvh4_matches],
            wall_ms,
        );
        if let Some(e) = &energy {
            println!(
                "power at 28 nm: logic {:.1} mW, DRAM {:.1} mW ({:.1} mW above idle); on-chip area {:.2} mm^2",
                e.logic_mw, e.dram_mw, e.dram_above_idle_mw, e.area_mm2
            );
            for u in e.on_chip() {
                println!(
                    "  {:<19} {:>6.3} mm^2 {:>8.2} mW",
                    u.unit, u.area_mm2, u.power_mw
                );
            }
            if let Some(c) = &e.collapse_unit {
                println!(
                    "  (collapse unit: storage {} B {:.4} mm^2, FIFO {} B {:.4} mm^2, datapath {:.4} mm^2)",
                    c.size.storage_bytes, c.storage_mm2, c.size.fifo_bytes, c.fifo_mm2, c.datapath_mm2
                );
            }
        }
    }
    if matches == Some(false) {
        anyhow::bail!("the simulated tree differs from the software HLBVH tree");
    }
    if cbvh_matches == Some(false) {
        anyhow::bail!("the simulated CBVH differs from the software encoder's");
    }
    if mbvh4_matches == Some(false) {
        anyhow::bail!("the simulated MBVH4 differs from the software collapse's");
    }
    if cbvh4_matches == Some(false) {
        anyhow::bail!("the simulated compressed 4-wide tree differs from the software encoder's");
    }
    Ok(())
}

/// `--points SPEC`: `None` for the centroids, `Some(n)` for `uniform:n`.
fn points_spec(spec: &str) -> anyhow::Result<Option<usize>> {
    if spec == "centroids" {
        return Ok(None);
    }
    let n = spec
        .strip_prefix("uniform:")
        .and_then(|n| n.parse::<usize>().ok())
        .filter(|&n| n > 0 && n < u32::MAX as usize / 2);
    match n {
        Some(n) => Ok(Some(n)),
        None => anyhow::bail!(
            "--points expects centroids or uniform:N (N from 1 to {}), got '{spec}'",
            u32::MAX / 2 - 1
        ),
    }
}

/// The points of the point mode: the centroid (vertex mean) of every triangle of `mesh`,
/// or `uniform` points drawn uniformly in the centroids' box (xorshift, a fixed seed: the
/// sets of `cargo run -p bvh --example point_knn`).
pub fn scene_points(mesh: &scene::Mesh, uniform: Option<usize>) -> Vec<geom::Vec3> {
    let centroids = mesh.centroids();
    let Some(n) = uniform else {
        return centroids;
    };
    let b = centroids.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p));
    let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| b.min + (b.max - b.min) * geom::Vec3::new(next(), next(), next()))
        .collect()
}

fn print_text(
    a: &MergetreeArgs,
    dram: &str,
    r: &MergeTreeReport,
    [matches, cbvh_matches, mbvh4_matches, cbvh4_matches]: [Option<bool>; 4],
    wall_ms: f64,
) {
    println!(
        "MergeTree {} (M={}, B={}, {} presorters, {} MHz) on {} [{}]",
        r.config.preset,
        r.config.m,
        r.config.b,
        r.config.presorters,
        r.config.clock_mhz,
        dram,
        r.dram
    );
    if r.config.read_schedule == mergetree::ReadSchedule::Forecast {
        println!(
            "read schedule forecast: fan-in {} = M/B - {} spares, one pass up to {} elements",
            r.config.fan_in(),
            r.config.forecast_spares,
            thousands(r.config.single_pass_limit())
        );
    }
    if r.config.output.is_points() {
        println!(
            "sort element {} B: {} per run, {} per buffer, one pass up to {} points",
            r.config.elem_bytes(),
            thousands(r.config.m_elems()),
            r.config.b_elems(),
            thousands(r.config.single_pass_limit())
        );
    }
    println!(
        "scene {}: {} {}, {} partial-sort blocks, {} merge pass(es)",
        a.scene.scene,
        thousands(r.triangles),
        if a.points.is_some() || r.points.is_some() {
            "points"
        } else {
            "triangles"
        },
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
    if let Some(e) = r.memory.energy_pj {
        println!(
            "DRAM energy {:.3} mJ, {:.3} mJ above an idle memory ([P2] 6.2: idle standby and \
             refresh subtracted)",
            e.total_pj() * 1e-9,
            e.above_idle_pj() * 1e-9
        );
    }
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
    let yes_no = |m: Option<bool>| match m {
        Some(true) => "yes",
        Some(false) => "NO",
        None => "not checked",
    };
    if let Some(c) = &r.cbvh {
        println!(
            "CBVH ({}, {} coordinates, {} bits, treelet depth {}): {} node pairs of {} B, \
             {} backtracking steps; build {:.3} ms{}",
            c.mode.name(),
            c.params.coords.name(),
            c.params.bits,
            c.treelet_depth,
            thousands(c.node_pairs),
            c.pair_bytes,
            thousands(c.backtrack_steps),
            c.build_ms,
            if c.compress_cycles > 0 {
                format!(
                    " + top-down pass {:.3} ms",
                    c.compress_cycles as f64 / (r.config.clock_mhz as f64 * 1e3)
                )
            } else {
                String::new()
            }
        );
        if let Some(st) = &c.stream {
            println!(
                "  encoder: {} backtracking reads (mean latency {:.1} cycles, {} after a write-buffer \
                 flush); waiting for reads {} cycles, starved {}; emitter waiting for the encoder {} cycles",
                thousands(st.backtrack_reads),
                st.mean_backtrack_read_latency(),
                thousands(st.backtrack_flushes),
                thousands(st.read_wait_cycles),
                thousands(st.starved_cycles),
                thousands(s.emitter.encoder_full_cycles)
            );
        }
        println!(
            "CBVH matches the software encoder: {}",
            yes_no(cbvh_matches)
        );
    }
    if let Some(m) = &r.mbvh4 {
        let st = m.tree.stats();
        println!(
            "MBVH4 ({}): {} wide nodes of {} B ({:.2} children each, depth {}) from {} binary \
             nodes; SAH {:.3} (4-wide nodes at 2 C_i); build {:.3} ms{}",
            m.mode.name(),
            thousands(m.wide_nodes),
            m.node_bytes,
            m.mean_children,
            st.max_depth,
            thousands(m.binary_nodes),
            m.sah,
            m.build_ms,
            if m.collapse_cycles > 0 {
                format!(
                    " + collapse pass {:.3} ms",
                    m.collapse_cycles as f64 / (r.config.clock_mhz as f64 * 1e3)
                )
            } else {
                String::new()
            }
        );
        if let Some(c) = &m.stream {
            println!(
                "  collapse unit ({}): busy {} cycles, starved {}, write buffer full {}; at \
                 most {} open subtrees (emitter stack depth {}), {} unresolved nodes; emitter \
                 waiting for the unit {} cycles",
                match r.config.mbvh4_window {
                    None => "greedy rule".to_string(),
                    Some(w) => format!("window of {w} levels"),
                },
                thousands(c.busy_cycles),
                thousands(c.starved_cycles),
                thousands(c.write_full_cycles),
                c.max_open,
                r.max_stack_depth,
                c.max_treelet_nodes,
                thousands(s.emitter.encoder_full_cycles)
            );
        }
        println!(
            "MBVH4 matches the software collapse: {}",
            yes_no(mbvh4_matches)
        );
    }
    if let Some(w) = &r.cbvh4 {
        println!(
            "compressed 4-wide ({}, {} bits, treelets {}, {}): {} wide nodes of {} B ({:.2} \
             children each) from {} binary nodes; {} backtracking steps; SAH {:.3} exact, {:.3} \
             decoded; build {:.3} ms",
            w.params.coords.name(),
            w.params.bits,
            w.treelet_depth,
            match w.mbvh4_window {
                None => "greedy collapse".to_string(),
                Some(l) => format!("collapse window {l}"),
            },
            thousands(w.wide_nodes),
            w.node_bytes,
            w.mean_children,
            thousands(w.binary_nodes),
            thousands(w.backtrack_steps),
            w.sah,
            w.sah_decoded,
            w.build_ms
        );
        if let (Some(c), Some(e)) = (&w.collapse, &w.stream) {
            println!(
                "  collapse unit: busy {} cycles, waiting for the encoder {}; wide encoder: \
                 busy {}, starved {}, backtracking read wait {}, write buffer full {}; at most \
                 {} subtrees held",
                thousands(c.busy_cycles),
                thousands(c.encoder_full_cycles),
                thousands(e.busy_cycles),
                thousands(e.starved_cycles),
                thousands(e.read_wait_cycles),
                thousands(e.write_full_cycles),
                w.max_held
            );
        }
        println!(
            "compressed 4-wide tree matches the software encoder: {}",
            yes_no(cbvh4_matches)
        );
    }
    if let Some(p) = &r.points {
        println!(
            "point {}: {} points, leaves of at most {}: {} nodes emitted, {} written \
             ({:.2} MB), {} wrote nothing; {} tree nodes, depth {}",
            if p.kind == "octree" {
                "octree"
            } else {
                "k-d tree"
            },
            thousands(p.points),
            p.max_leaf,
            thousands(p.emitted),
            thousands(p.written),
            p.node_bytes as f64 / 1e6,
            thousands(p.collapsed),
            thousands(p.tree_nodes),
            p.depth
        );
    }
    println!(
        "tree matches software {}: {}; simulated {:.1} M cycles/s",
        match r.points.as_ref().map(|p| p.kind) {
            Some("octree") => "bvh::Octree",
            Some(_) => "bvh::PointTree",
            None => "hlbvh",
        },
        yes_no(matches),
        r.cycles as f64 / (wall_ms * 1e3).max(1e-9)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_spec_parses_and_rejects() {
        assert_eq!(points_spec("centroids").unwrap(), None);
        assert_eq!(points_spec("uniform:1000000").unwrap(), Some(1_000_000));
        for bad in [
            "uniform:0",
            "uniform:",
            "uniform:-3",
            "cloud",
            "uniform:9999999999",
        ] {
            assert!(points_spec(bad).is_err(), "{bad}");
        }
    }
}
