//! `arbor report cbvh`: the \[P3\] §5 tables for our scenes, written as CSV, Markdown and
//! SVG into one folder, each beside the thesis's value where we share the quantity:
//! - `table1.csv`: the analogue of \[P3\] Table 1 (backtracking normalized to plain
//!   bottom-up, LBVH and refit traffic normalized to top-down; min / max / avg over scenes);
//! - `table3.csv`: per-scene traffic breakdown (\[P3\] Table 3; its per-scene values are a
//!   figure the text does not carry, so only ours), with leaf sizes beside \[P3\] Table 2's;
//! - `quality.csv`: SAH of every decoded tree against the uncompressed and the top-down one
//!   (\[P3\] §5.4), and the enclosure check;
//! - `fig7.csv`: backtracking depth histogram, relative vs modulo (\[P3\] Fig. 7);
//! - `fig10.csv`: backtracking and SAH against the minimum scale, cloth vs the others
//!   (\[P3\] Fig. 10);
//! - `bits.csv`: quality and backtracking against the coordinate bits `N = 3..=8`;
//! - `table2.csv`, `table2-dram.csv`, `table2.svg`: the analogue of \[P3\] Table 2, LBVH
//!   runtime with single-precision output, top-down postprocessing and streaming
//!   compression, simulated on the MergeTree model ([`runtime`]);
//! - `trace_quality.csv`: box and triangle tests per ray, CBVH vs BVH, primary and diffuse
//!   rays, beside \[P3\] §5.4's averages; `watertight.csv`: the \[P3\] §5.5 check over
//!   every box test of those renders (see [`traced`]);
//! - `report.md` with all tables, and `table1.svg`, `table2.svg`, `fig7.svg`, `fig10.svg`,
//!   `trace_quality.svg`.

pub mod runtime;
pub mod traced;

use crate::fs::write_file as write;
use crate::progress::Progress;
use crate::scenes::{load_triangles, CLOTH};
use crate::svg::bar_svg;
use crate::table::Table;
use anyhow::Context;
use cbvh::study::{
    bits_sweep, min_scale_sweep, study_scene, BitsPoint, MinScalePoint, SceneStudy, Variant,
};
use cbvh::Params;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Options of the CBVH report.
#[derive(Clone, Debug)]
pub struct CbvhOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes: files, procedural specs, or `cloth` (the report's half-flat cloth,
    /// [`CLOTH`]). Default: the shared real scenes and `cloth`.
    pub scenes: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// Skip the minimum-scale sweep (Fig. 10).
    pub no_sweep: bool,
    /// Skip the runtime simulations (Table 2).
    pub no_runtime: bool,
    /// Memory system of the runtime simulations (Table 2); `simple:NAME` for the quick
    /// model.
    pub runtime_dram: String,
    /// Image size (width, height; 1 to 4096 each) of the ray-traced quality and
    /// watertightness measurement (\[P3\] §5.4-5.5).
    pub trace_size: (u32, u32),
    /// Skip the ray-traced measurement.
    pub no_trace: bool,
}

impl Default for CbvhOptions {
    fn default() -> Self {
        CbvhOptions {
            out: "arbor-out/report-cbvh".into(),
            scenes: None,
            scene_dir: crate::scenes::shared_scenes(),
            no_sweep: false,
            no_runtime: false,
            runtime_dram: runtime::DEFAULT_DRAM.into(),
            trace_size: (640, 360),
            no_trace: false,
        }
    }
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let bad = || anyhow::anyhow!("--trace-size must be WIDTHxHEIGHT (1..=4096 each), got '{s}'");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    anyhow::ensure!((1..=4096).contains(&w) && (1..=4096).contains(&h), bad());
    Ok((w, h))
}

/// \[P3\] Table 1, in the column order of [`Variant::table1`] (TD, R, R2, R3, R4, M, M2,
/// M3, M4); `None` where the paper prints "-". Source: the thesis text, \[P3\] Table 1.
pub const P3_TABLE1: [(&str, &str, [Option<f64>; 9]); 9] = {
    const fn s(v: f64) -> Option<f64> {
        Some(v)
    }
    [
        (
            "backtrack",
            "min",
            [
                None,
                s(1.00),
                s(0.06),
                s(0.01),
                s(0.00),
                s(0.10),
                s(0.02),
                s(0.00),
                s(0.00),
            ],
        ),
        (
            "backtrack",
            "max",
            [
                None,
                s(1.00),
                s(0.25),
                s(0.09),
                s(0.03),
                s(0.44),
                s(0.15),
                s(0.06),
                s(0.03),
            ],
        ),
        (
            "backtrack",
            "avg",
            [
                None,
                s(1.00),
                s(0.15),
                s(0.04),
                s(0.01),
                s(0.22),
                s(0.06),
                s(0.02),
                s(0.01),
            ],
        ),
        (
            "traffic_lbvh",
            "min",
            [
                s(1.00),
                s(0.75),
                s(0.53),
                s(0.51),
                s(0.50),
                s(0.54),
                s(0.51),
                s(0.50),
                s(0.50),
            ],
        ),
        (
            "traffic_lbvh",
            "max",
            [
                s(1.00),
                s(0.95),
                s(0.86),
                s(0.84),
                s(0.83),
                s(0.87),
                s(0.84),
                s(0.83),
                s(0.83),
            ],
        ),
        (
            "traffic_lbvh",
            "avg",
            [
                s(1.00),
                s(0.84),
                s(0.61),
                s(0.59),
                s(0.58),
                s(0.63),
                s(0.59),
                s(0.58),
                s(0.58),
            ],
        ),
        (
            "traffic_refit",
            "min",
            [
                s(1.00),
                s(0.67),
                s(0.41),
                s(0.39),
                s(0.38),
                s(0.42),
                s(0.39),
                s(0.38),
                s(0.38),
            ],
        ),
        (
            "traffic_refit",
            "max",
            [
                s(1.00),
                s(0.90),
                s(0.74),
                s(0.70),
                s(0.69),
                s(0.76),
                s(0.71),
                s(0.69),
                s(0.68),
            ],
        ),
        (
            "traffic_refit",
            "avg",
            [
                s(1.00),
                s(0.79),
                s(0.49),
                s(0.45),
                s(0.44),
                s(0.52),
                s(0.46),
                s(0.44),
                s(0.44),
            ],
        ),
    ]
};

/// Minimum-scale exponents of the Fig. 10 sweep.
const SWEEP_EXPS: [i32; 11] = [-126, -90, -60, -45, -35, -30, -25, -20, -15, -10, -5];
/// Real scenes of the default list (files under `--scene-dir`).
const REAL: [&str; 5] = [
    "bunny.ply",
    "conference.ply",
    "crytek-sponza.ply",
    "dragon.ply",
    "sibenik.ply",
];
/// Scenes the sweep skips for time (the largest).
const SWEEP_SKIP: [&str; 1] = ["dragon"];

struct SceneRun {
    name: String,
    study: SceneStudy,
    sweep: Option<Vec<MinScalePoint>>,
    bits: Option<Vec<BitsPoint>>,
}

/// Coordinate bits of the bits study.
const BITS: [u32; 6] = [3, 4, 5, 6, 7, 8];

/// The primitive boxes of a scene spec (see [`load_triangles`]).
fn load(spec: &str) -> anyhow::Result<(String, Vec<geom::Aabb>)> {
    let (name, tris, _) = load_triangles(spec)?;
    Ok((name, bvh::triangle_aabbs(&tris)))
}

/// Runs the CBVH report: writes its files and returns `report.md`'s text.
pub fn run(a: &CbvhOptions, ui: &dyn Progress) -> anyhow::Result<String> {
    let specs: Vec<String> = match &a.scenes {
        Some(s) => s.clone(),
        None => {
            let mut v: Vec<String> = REAL
                .iter()
                .map(|f| a.scene_dir.join(f))
                .filter(|p| p.exists())
                .map(|p| p.to_string_lossy().into_owned())
                .collect();
            v.push(CLOTH.to_string());
            v
        }
    };
    anyhow::ensure!(!specs.is_empty(), "no scenes to run on");
    let trace_size = a.trace_size;
    anyhow::ensure!(
        (1..=4096).contains(&trace_size.0) && (1..=4096).contains(&trace_size.1),
        "--trace-size must be WIDTHxHEIGHT (1..=4096 each), got '{}x{}'",
        trace_size.0,
        trace_size.1
    );
    let variants = Variant::table1();
    let params = Params::default();
    let sweeps = if a.no_sweep { 0 } else { specs.len() };
    let total = (specs.len() * variants.len() + sweeps) as u64;
    let bar = ui.bar("report cbvh");
    let mut done = 0u64;
    let mut runs = Vec::new();
    let mut scenes = Vec::new();
    for spec in &specs {
        let (name, prims) = load(spec)?;
        let study = study_scene(&prims, &params, &variants, |_| {
            done += 1;
            bar.update(done, total);
        })
        .with_context(|| format!("study of {name}"))?;
        for v in &study.variants {
            anyhow::ensure!(
                v.enclosure_violations == 0,
                "{name} {}: {} decoded boxes do not enclose their geometry",
                v.label,
                v.enclosure_violations
            );
        }
        let sweep = if a.no_sweep || SWEEP_SKIP.contains(&name.as_str()) {
            None
        } else {
            Some(min_scale_sweep(&prims, &params, &SWEEP_EXPS)?)
        };
        let bits = if a.no_sweep || SWEEP_SKIP.contains(&name.as_str()) {
            None
        } else {
            Some(bits_sweep(&prims, &params, &BITS)?)
        };
        if !a.no_sweep {
            done += 1;
            bar.update(done, total);
        }
        if !a.no_runtime {
            scenes.push((name.clone(), prims));
        }
        runs.push(SceneRun {
            name,
            study,
            sweep,
            bits,
        });
    }
    bar.finish();
    let runtime_rows = if a.no_runtime {
        None
    } else {
        let rows = runtime::simulate_all(&scenes, &a.runtime_dram, ui)?;
        // The model builds the study's LBVH: its backtracking must be the study's.
        for (run, row) in runs.iter().zip(&rows) {
            let study_r = run.study.variants[1].build.backtrack_steps;
            anyhow::ensure!(
                row.main[1].backtrack_steps == study_r,
                "{}: the simulated R run backtracked {} times, the study {study_r}",
                run.name,
                row.main[1].backtrack_steps
            );
        }
        Some(rows)
    };
    let traced = if a.no_trace {
        None
    } else {
        Some(traced::measure(&specs, trace_size, ui)?)
    };
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let t1 = table1(&runs, &variants);
    let mut md = String::new();
    writeln!(md, "# CBVH report (\\[P3\\] §5)\n")?;
    writeln!(
        md,
        "Scenes: {}. LBVH: streaming emitter, 30-bit Morton codes, one leaf per run of equal codes \
         ([P3] §5.2). 6-bit coordinates, minimum scale 2^-30. Traffic model of [P3] §5.2 \
         (see `cbvh::traffic`). Refit: the top-down CBVH refitted to the same geometry, as in [P3].\n",
        runs.iter().map(|r| r.name.as_str()).collect::<Vec<_>>().join(", ")
    )?;
    write_table1(&a.out, &mut md, &t1, &variants)?;
    write_table3(&a.out, &mut md, &runs)?;
    if let Some(rows) = &runtime_rows {
        let names: Vec<String> = runs.iter().map(|r| r.name.clone()).collect();
        let leaf: Vec<f64> = runs.iter().map(|r| r.study.avg_leaf_size).collect();
        runtime::write_table2(&a.out, &mut md, &names, &leaf, rows, &a.runtime_dram)?;
    }
    write_quality(&a.out, &mut md, &runs)?;
    if let Some(rows) = &traced {
        traced::write_tables(&a.out, &mut md, rows, trace_size)?;
    }
    write_fig7(&a.out, &mut md, &runs)?;
    if !a.no_sweep {
        write_fig10(&a.out, &mut md, &runs)?;
        write_bits(&a.out, &mut md, &runs)?;
    }
    write(&a.out, "report.md", &md)?;
    Ok(md)
}

/// Our Table 1: (metric, stat) -> value per variant.
type Table1 = Vec<(&'static str, &'static str, Vec<Option<f64>>)>;

fn table1(runs: &[SceneRun], variants: &[Variant]) -> Table1 {
    let per_scene = |f: &dyn Fn(&SceneStudy, usize) -> Option<f64>| -> Vec<Vec<f64>> {
        (0..variants.len())
            .map(|i| runs.iter().filter_map(|r| f(&r.study, i)).collect())
            .collect()
    };
    let bt = per_scene(&|s, i| {
        let base = s.variants[1].build.backtrack_steps;
        (i > 0 && base > 0).then(|| s.variants[i].build.backtrack_steps as f64 / base as f64)
    });
    let tl = per_scene(&|s, i| {
        Some(
            s.variants[i].build_traffic.total_bytes() as f64
                / s.variants[0].build_traffic.total_bytes() as f64,
        )
    });
    let tr = per_scene(&|s, i| {
        Some(
            s.variants[i].refit_traffic.total_bytes() as f64
                / s.variants[0].refit_traffic.total_bytes() as f64,
        )
    });
    let stat = |v: &Vec<Vec<f64>>, k: &str| -> Vec<Option<f64>> {
        v.iter()
            .map(|xs| {
                if xs.is_empty() {
                    return None;
                }
                Some(match k {
                    "min" => xs.iter().cloned().fold(f64::INFINITY, f64::min),
                    "max" => xs.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
                    _ => xs.iter().sum::<f64>() / xs.len() as f64,
                })
            })
            .collect()
    };
    let mut out = Vec::new();
    for (m, v) in [
        ("backtrack", &bt),
        ("traffic_lbvh", &tl),
        ("traffic_refit", &tr),
    ] {
        for k in ["min", "max", "avg"] {
            out.push((m, k, stat(v, k)));
        }
    }
    out
}

fn fmt(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.2}"))
}

fn write_table1(
    out: &Path,
    md: &mut String,
    t: &Table1,
    variants: &[Variant],
) -> anyhow::Result<()> {
    let labels: Vec<String> = variants.iter().map(Variant::label).collect();
    let mut csv = Table::text(&["metric", "stat", "variant", "ours", "thesis"]);
    writeln!(
        md,
        "## Table 1 analogue: backtracking and traffic (ours / [P3])\n"
    )?;
    let headers: Vec<&str> = ["metric", "stat"]
        .into_iter()
        .chain(labels.iter().map(String::as_str))
        .collect();
    let mut table = Table::text(&headers);
    for (row, (m, k, ours)) in t.iter().enumerate() {
        let thesis = P3_TABLE1[row].2;
        let mut cells = vec![m.to_string(), k.to_string()];
        for (i, l) in labels.iter().enumerate() {
            csv.push([
                m.to_string(),
                k.to_string(),
                l.clone(),
                opt(ours[i]),
                opt(thesis[i]),
            ]);
            cells.push(format!("{} / {}", fmt(ours[i]), fmt(thesis[i])));
        }
        table.push(cells);
    }
    writeln!(md, "{}", table.markdown())?;
    write(out, "table1.csv", &csv.csv())?;
    // SVG: average traffic (LBVH and refit), ours vs thesis, per variant.
    let mut series = Vec::new();
    for (row, name) in [(5usize, "LBVH"), (8, "refit")] {
        series.push((format!("{name} ours"), t[row].2.clone()));
        series.push((format!("{name} [P3]"), P3_TABLE1[row].2.to_vec()));
    }
    write(
        out,
        "table1.svg",
        &bar_svg("Average traffic normalized to top-down", &labels, &series),
    )?;
    Ok(())
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x:.4}"))
}

fn write_table3(out: &Path, md: &mut String, runs: &[SceneRun]) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "triangles",
        "node_pairs",
        "avg_leaf_size",
        "thesis_leaf_size",
        "variant",
        "backtrack_steps",
        "lbvh_update_bytes",
        "lbvh_compression_bytes",
        "lbvh_backtrack_bytes",
        "lbvh_total_bytes",
        "refit_backtrack_steps",
        "refit_update_bytes",
        "refit_compression_bytes",
        "refit_backtrack_bytes",
        "refit_total_bytes",
    ]);
    writeln!(
        md,
        "## Table 3 analogue: traffic per scene (bytes per triangle)\n"
    )?;
    writeln!(
        md,
        "Leaf size beside [P3] Table 2's where we share the scene. Columns: LBVH / refit traffic per triangle \
         for top-down (B), relative (R), relative with depth-2 treelets (R2), modulo (M), modulo with depth-2 treelets (M2).\n"
    )?;
    let mut table = Table::text(&[
        "scene",
        "triangles",
        "leaf size (ours / [P3])",
        "B",
        "R",
        "R2",
        "M",
        "M2",
        "backtracks R / M",
    ]);
    for r in runs {
        let s = &r.study;
        let thesis = runtime::p3_row(&r.name).map(|x| x.leaf_size);
        for v in &s.variants {
            csv.push([
                r.name.clone(),
                s.prims.to_string(),
                s.node_pairs.to_string(),
                format!("{:.3}", s.avg_leaf_size),
                opt(thesis),
                v.label.to_string(),
                v.build.backtrack_steps.to_string(),
                v.build_traffic.update_bytes.to_string(),
                v.build_traffic.compression_bytes.to_string(),
                v.build_traffic.backtrack_bytes.to_string(),
                v.build_traffic.total_bytes().to_string(),
                v.refit.backtrack_steps.to_string(),
                v.refit_traffic.update_bytes.to_string(),
                v.refit_traffic.compression_bytes.to_string(),
                v.refit_traffic.backtrack_bytes.to_string(),
                v.refit_traffic.total_bytes().to_string(),
            ]);
        }
        let per = |l: &str| {
            let v = s.variants.iter().find(|v| v.label == l).expect("variant");
            format!(
                "{:.0} / {:.0}",
                v.build_traffic.total_bytes() as f64 / s.prims as f64,
                v.refit_traffic.total_bytes() as f64 / s.prims as f64
            )
        };
        table.push([
            r.name.clone(),
            s.prims.to_string(),
            format!("{:.2} / {}", s.avg_leaf_size, fmt(thesis)),
            per("TD"),
            per("R"),
            per("R2"),
            per("M"),
            per("M2"),
            format!(
                "{} / {}",
                s.variants[1].build.backtrack_steps, s.variants[5].build.backtrack_steps
            ),
        ]);
    }
    md.push_str(&table.markdown());
    writeln!(md)?;
    write(out, "table3.csv", &csv.csv())
}

fn write_quality(out: &Path, md: &mut String, runs: &[SceneRun]) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "variant",
        "sah_uncompressed",
        "sah_vs_uncompressed",
        "sah_vs_topdown",
        "enclosure_violations",
        "not_enclosing_topdown",
    ]);
    writeln!(md, "## Tree quality (\\[P3\\] §5.4)\n")?;
    writeln!(
        md,
        "SAH of the decoded CBVH over the uncompressed LBVH, and the largest SAH of a bottom-up variant over \
         top-down (the context-estimation looseness; [P3] reports < 0.1%). Every decoded box encloses its geometry.\n"
    )?;
    let mut table = Table::text(&[
        "scene",
        "SAH CBVH / BVH",
        "max SAH bottom-up / top-down",
        "enclosure violations",
    ]);
    for r in runs {
        let s = &r.study;
        let mut worst: f64 = 1.0;
        let mut viol = 0;
        for v in &s.variants {
            csv.push([
                r.name.clone(),
                v.label.to_string(),
                format!("{:.6}", s.sah_uncompressed),
                format!("{:.6}", v.sah_vs_uncompressed),
                format!("{:.6}", v.sah_vs_topdown),
                v.enclosure_violations.to_string(),
                v.not_enclosing_topdown.to_string(),
            ]);
            worst = worst.max(v.sah_vs_topdown);
            viol += v.enclosure_violations;
        }
        table.push([
            r.name.clone(),
            format!("{:.4}", s.variants[0].sah_vs_uncompressed),
            format!("{worst:.6}"),
            viol.to_string(),
        ]);
    }
    md.push_str(&table.markdown());
    writeln!(md)?;
    write(out, "quality.csv", &csv.csv())
}

fn write_fig7(out: &Path, md: &mut String, runs: &[SceneRun]) -> anyhow::Result<()> {
    let mut csv = Table::text(&["scene", "variant", "depth", "iterations"]);
    for r in runs {
        for v in &r.study.variants[1..] {
            for (d, n) in v.build.backtrack_depth_hist.iter().enumerate() {
                csv.push([
                    r.name.to_string(),
                    v.label.to_string(),
                    (d + 1).to_string(),
                    n.to_string(),
                ]);
            }
        }
    }
    write(out, "fig7.csv", &csv.csv())?;
    // Figure for the first scene (the paper shows Elephant, which we do not have).
    let Some(r) = runs.first() else { return Ok(()) };
    let rel = &r.study.variants[1].build.backtrack_depth_hist;
    let modu = &r.study.variants[5].build.backtrack_depth_hist;
    let depth = rel.len().max(modu.len()).min(16);
    let labels: Vec<String> = (1..=depth).map(|d| d.to_string()).collect();
    let get = |h: &Vec<u64>| {
        (0..depth)
            .map(|d| Some(*h.get(d).unwrap_or(&0) as f64))
            .collect::<Vec<_>>()
    };
    write(
        out,
        "fig7.svg",
        &bar_svg(
            &format!(
                "Backtracking iterations by depth, {} (cf. [P3] Fig. 7)",
                r.name
            ),
            &labels,
            &[("relative".into(), get(rel)), ("modulo".into(), get(modu))],
        ),
    )?;
    writeln!(
        md,
        "## Backtracking depth histogram ({}, cf. \\[P3\\] Fig. 7)\n",
        r.name
    )?;
    let headers: Vec<&str> = std::iter::once("depth")
        .chain(labels.iter().map(String::as_str))
        .collect();
    let mut table = Table::text(&headers);
    for (n, h) in [("relative", rel), ("modulo", modu)] {
        let cells = (0..depth).map(|d| h.get(d).unwrap_or(&0).to_string());
        table.push(std::iter::once(n.to_string()).chain(cells));
    }
    writeln!(md, "{}", table.markdown())?;
    Ok(())
}

fn write_fig10(out: &Path, md: &mut String, runs: &[SceneRun]) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "min_scale_exp",
        "backtrack_per_prim",
        "backtrack_per_prim_m4",
        "sah",
        "sah_vs_min",
    ]);
    let mut cloth: Option<Vec<(f64, f64, f64)>> = None;
    let mut others: Vec<Vec<(f64, f64, f64)>> = Vec::new();
    for r in runs {
        let Some(sw) = &r.sweep else { continue };
        let min_sah = sw.iter().map(|p| p.sah).fold(f64::INFINITY, f64::min);
        let mut pts = Vec::new();
        for p in sw {
            let rel = if min_sah > 0.0 { p.sah / min_sah } else { 1.0 };
            csv.push([
                r.name.to_string(),
                p.min_scale_exp.to_string(),
                format!("{:.6}", p.backtrack_per_prim),
                format!("{:.6}", p.backtrack_per_prim_m4),
                format!("{:.6}", p.sah),
                format!("{rel:.6}"),
            ]);
            pts.push((p.backtrack_per_prim, p.backtrack_per_prim_m4, rel));
        }
        if r.name == "cloth" {
            cloth = Some(pts);
        } else {
            others.push(pts);
        }
    }
    write(out, "fig10.csv", &csv.csv())?;
    let labels: Vec<String> = SWEEP_EXPS.iter().map(|e| e.to_string()).collect();
    let avg = |k: usize| -> Vec<Option<f64>> {
        (0..SWEEP_EXPS.len())
            .map(|i| {
                (!others.is_empty()).then(|| {
                    others
                        .iter()
                        .map(|o| [o[i].0, o[i].1, o[i].2][k])
                        .sum::<f64>()
                        / others.len() as f64
                })
            })
            .collect()
    };
    let cl = |k: usize| -> Vec<Option<f64>> {
        (0..SWEEP_EXPS.len())
            .map(|i| cloth.as_ref().map(|c| [c[i].0, c[i].1, c[i].2][k]))
            .collect()
    };
    writeln!(md, "## Minimum scale (cf. \\[P3\\] Fig. 10)\n")?;
    writeln!(
        md,
        "Backtracking steps per triangle (plain relative bottom-up) and SAH normalized to its minimum, \
         against the minimum scale exponent; cloth vs the average of the other scenes. [P3]: cloth backtracks \
         heavily below 2^-30; quality is unaffected up to 2^-15 and suffers near 2^-10.\n"
    )?;
    let headers: Vec<&str> = std::iter::once("min scale")
        .chain(labels.iter().map(String::as_str))
        .collect();
    let mut table = Table::text(&headers);
    for (n, v) in [
        ("cloth backtracks/tri", cl(0)),
        ("cloth backtracks/tri (M4)", cl(1)),
        ("cloth SAH / min", cl(2)),
        ("others backtracks/tri", avg(0)),
        ("others backtracks/tri (M4)", avg(1)),
        ("others SAH / min", avg(2)),
    ] {
        let cells = v
            .iter()
            .map(|x| x.map_or("-".into(), |x| format!("{x:.3}")));
        table.push(std::iter::once(n.to_string()).chain(cells));
    }
    writeln!(md, "{}", table.markdown())?;
    write(
        out,
        "fig10.svg",
        &bar_svg(
            "Backtracking steps per triangle vs minimum scale exponent (cf. [P3] Fig. 10)",
            &labels,
            &[("cloth".into(), cl(0)), ("others (avg)".into(), avg(0))],
        ),
    )?;
    Ok(())
}

fn write_bits(out: &Path, md: &mut String, runs: &[SceneRun]) -> anyhow::Result<()> {
    let mut csv = Table::text(&[
        "scene",
        "bits",
        "pair_bytes",
        "sah_vs_uncompressed",
        "backtrack_per_prim",
        "backtrack_per_prim_m4",
    ]);
    writeln!(md, "## Coordinate bits\n")?;
    writeln!(
        md,
        "SAH of the decoded (top-down) CBVH over the uncompressed LBVH, and backtracking steps per triangle \
         (plain relative / modulo with depth-4 treelets), against the bits per coordinate. [P3] uses 6 bits.\n"
    )?;
    let headers: Vec<String> = std::iter::once("scene".to_string())
        .chain(BITS.map(|b| format!("N = {b} ({} B)", cbvh::format::pair_bytes(b))))
        .collect();
    let mut table = Table::text(&headers);
    for r in runs {
        let Some(pts) = &r.bits else { continue };
        let mut cells = vec![r.name.to_string()];
        for p in pts {
            csv.push([
                r.name.to_string(),
                p.bits.to_string(),
                p.pair_bytes.to_string(),
                format!("{:.6}", p.sah_vs_uncompressed),
                format!("{:.6}", p.backtrack_per_prim),
                format!("{:.6}", p.backtrack_per_prim_m4),
            ]);
            cells.push(format!(
                "{:.3}, {:.2} / {:.3}",
                p.sah_vs_uncompressed, p.backtrack_per_prim, p.backtrack_per_prim_m4
            ));
        }
        table.push(cells);
    }
    writeln!(md, "{}", table.markdown())?;
    write(out, "bits.csv", &csv.csv())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_table_has_nine_columns() {
        assert_eq!(P3_TABLE1.len(), 9);
        assert_eq!(Variant::table1().len(), 9);
        assert_eq!(parse_size("640x360").unwrap(), (640, 360));
        for bad in ["640", "0x10", "10x", "axb", "5000x10"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }
}
