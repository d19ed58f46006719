//! How much each assumption moves the reproduced figures: every open choice of the
//! models (the energy conventions, the memory controller's address mapping, MergeTree's
//! and the accelerator's unstated timing parameters, the sampling rate) set to each value
//! of a documented range, one at a time from the defaults, and for every reproduced figure
//! the default, the lowest and highest value any variant gave, and the assumption that
//! moves it most (`arbor report sensitivity`; `arbor.report.sensitivity.v1`). The figures:
//! \[P2\] Tables III (MergeTree's build time on the three memory systems, its
//! speed-ups, and the SAH of each builder's tree against a full sweep), IV (its units' area and power on the fast system, largest scene), VI (its
//! traffic), VII (its mean traffic and power per system) and VIII (system energy), and
//! \[P4\] Tables 1 (area and power per unit) and 2 (MBVH4's changes over BVH2).
//!
//! Variants that differ only in what is computed from the cycle-level runs (the energy
//! conventions, the IST division's FLOPs) reuse the runs ([`SimMemo`]), so those cost
//! almost nothing; the timing parameters and the sampling rate simulate again.

use outfile::table::Table;

use rayon::prelude::*;
use serde::Serialize;

use super::report::{scene_result_memo, table8, SceneResult, SystemScene};
use super::{SimMemo, SystemConfig, SystemError};
use crate::rtunit::{self, RayMode, RtConfig, TreeKind, Workload};

/// Schema of the JSON document.
pub const SCHEMA: &str = "arbor.report.sensitivity.v1";

/// The key of [`Assumption`] that sets the scenes' sampling rate rather than a
/// configuration key.
pub const SAMPLE_KEY: &str = "sample";

/// The key of [`Assumption`] that widens or narrows every scene's camera
/// (`trace::PinholeCamera::with_view_scale`): the viewpoint, which the thesis does not give.
pub const VIEW_KEY: &str = "view_scale";

/// One assumption and the values it is swept over.
#[derive(Clone, Debug, Serialize)]
pub struct Assumption {
    /// A `SystemConfig::set` key, or [`SAMPLE_KEY`].
    pub key: &'static str,
    /// Its value in the default model (as documented; the runs use the configuration's).
    pub default: &'static str,
    /// The other values tried.
    pub values: Vec<&'static str>,
    /// What it is and where its default comes from.
    pub what: &'static str,
}

/// The documented assumptions and ranges of the system model.
pub fn assumptions() -> Vec<Assumption> {
    let a = |key, default, values: &[&'static str], what| Assumption {
        key,
        default,
        values: values.to_vec(),
        what,
    };
    vec![
        a(
            "sram_cell",
            "lop",
            &["hp"],
            "SRAM cell type (thesis: 28 nm FDSOI with multi-threshold optimizations)",
        ),
        a(
            "fpu_energy",
            "galal",
            &["horowitz"],
            "FPU energy per operation (thesis: Galal et al., linear scaling)",
        ),
        a(
            "ram_figures",
            "scratchpad",
            &["cache-table"],
            "figures of FIFOs, stacks, heap and scratchpad (hardware.md §3.1)",
        ),
        a(
            "wide_port",
            "banked",
            &["p4-ratio"],
            "cost of a wide cache port (none in the BVH2 system)",
        ),
        a(
            "dram_energy",
            "above-idle",
            &["full"],
            "DRAM energy in the totals (thesis: above an idle memory)",
        ),
        a(
            "ist_div_flops",
            "3",
            &["11"],
            "FLOPs of the IST division ([P2] §6.4: 3; [P4] §3.2: 11)",
        ),
        a(
            "stacks_per_trv",
            "32",
            &["8"],
            "ray slots per TRV ([P4] §3: 32)",
        ),
        a(
            "l2_latency",
            "4",
            &["2", "8"],
            "node cache hit latency, cycles (Arbor's assumption)",
        ),
        a(
            "prim_latency",
            "2",
            &["1", "4"],
            "primitive cache hit latency, cycles (Arbor's assumption)",
        ),
        a(
            "mshrs",
            "16",
            &["8", "32"],
            "misses in flight per cache (Arbor's assumption)",
        ),
        a(
            "trv_stages",
            "6",
            &["4", "8"],
            "TRV pipeline depth (Arbor's reading of [P4] Fig. 3)",
        ),
        a(
            "ist_stages",
            "20",
            &["10", "30"],
            "IST pipeline depth (Arbor's assumption)",
        ),
        a(
            "cull_cycles_per_entry",
            "1",
            &["0", "2"],
            "cycles per culled stack entry (Arbor's assumption)",
        ),
        a(
            "l2_ports",
            "1",
            &["0"],
            "lines the node cache returns per cycle (0: unlimited, the earlier model)",
        ),
        a(
            "address_mapping",
            "rorabgbacoch",
            &["rorabgbachco"],
            "DRAM address mapping, most significant field first (Arbor's: channels \
             interleaved every burst; tried: every column span)",
        ),
        a(
            "mergetree.presort_slots",
            "4",
            &["2", "8"],
            "MergeTree read buffers per presorter (Arbor's assumption)",
        ),
        a(
            "mergetree.write_chunk_bytes",
            "512",
            &["128", "1024"],
            "MergeTree node and leaf write request size, bytes (Arbor's assumption)",
        ),
        a(
            "mergetree.morton_grid",
            "cube",
            &["box"],
            "Morton grid over the centroid bounds (thesis silent; docs/mergetree-vs-thesis.md)",
        ),
        a(
            "toplevel_bits",
            "12",
            &["9", "15"],
            "top Morton bits whose cells the toplevel builds take as primitives (at most \
             512, 4,096 or 32,768 cells; the thesis gives only the top trees' size, \
             'ca. 500-2,000 nodes', [P2] §6.1)",
        ),
        a(
            VIEW_KEY,
            "1",
            &["0.5", "1.5"],
            "camera's image plane scaled (tan of half the field of view; 70° becomes 39° and \
             93°): how much of the scene a frame sees (the thesis gives no viewpoints)",
        ),
        a(
            SAMPLE_KEY,
            "the scenes'",
            &["8", "64"],
            "one in N tile chunks timed (sampling error)",
        ),
    ]
}

/// One reproduced figure across the variants.
#[derive(Clone, Debug, Serialize)]
pub struct FigureRow {
    /// The figure, e.g. `VIII primary all hlbvh total`.
    pub figure: String,
    /// Its unit: `ratio` (to binned SAH) and `change` (relative) are fractions, shown in
    /// percent; otherwise `ms`, `x` (a speed-up), `MB`, `GB/s`, `mW` or `mm2`.
    pub unit: &'static str,
    /// The thesis's value, where it gives one.
    pub thesis: Option<f64>,
    /// The default model's value.
    pub default: f64,
    /// The lowest value of any variant (the default included).
    pub low: f64,
    /// The highest.
    pub high: f64,
    /// The assumption whose values spread the figure most (empty when none moves it).
    pub driver: String,
    /// That assumption's spread (highest less lowest of its values and the default).
    pub driver_spread: f64,
    /// Whether the thesis's value lies in `[low, high]`.
    pub thesis_inside: Option<bool>,
}

/// One variant's figures.
#[derive(Clone, Debug, Serialize)]
pub struct Variant {
    /// The assumption (`default` for the default model).
    pub key: String,
    /// Its value.
    pub value: String,
    /// Figure name and value, in [`SensitivityReport::rows`] order.
    pub figures: Vec<(String, f64)>,
}

/// The whole study.
#[derive(Clone, Debug, Serialize)]
pub struct SensitivityReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// Scenes (name, triangles).
    pub scenes: Vec<(String, usize)>,
    /// The assumptions swept.
    pub assumptions: Vec<Assumption>,
    /// Per figure.
    pub rows: Vec<FigureRow>,
    /// Per variant.
    pub variants: Vec<Variant>,
    /// Cycle-level runs simulated.
    pub simulated: u64,
    /// Cycle-level runs reused from an earlier variant.
    pub reused: u64,
}

/// One figure of one variant: name, value, the thesis's value, unit
/// ([`FigureRow::unit`]).
type Figure = (String, f64, Option<f64>, &'static str);

/// The Table VIII figures of one variant: every builder but the reference, per ray kind,
/// scene set and column, with the thesis's value.
fn figures(results: &[SceneResult]) -> Vec<Figure> {
    let mut v = Vec::new();
    for r in table8(results) {
        if r.builder == super::Builder::BinnedSah.name() {
            continue;
        }
        for (i, col) in ["build", "trace", "total"].into_iter().enumerate() {
            v.push((
                format!("VIII {} {} {} {col}", r.rays, r.scenes, r.builder),
                [r.build, r.trace, r.total][i],
                r.thesis.map(|t| t[i]),
                "ratio",
            ));
        }
    }
    v
}

/// The \[P4\] part of the study: one scene traced by the BVH2 and the MBVH4 accelerator at
/// \[P4\]'s settings (45 nm, 4 bounces, the IST division as 11 FLOPs), whose Table 2
/// changes (MBVH4 over BVH2: performance, energy per frame, performance per area, DRAM
/// traffic) are figures of the study beside the thesis's row for `thesis_scene`.
pub struct P4Scene<'a> {
    /// Short name.
    pub name: String,
    /// \[P4\] Table 2's scene name (`Crytek` for Crytek Sponza), for the thesis's values.
    pub thesis_scene: &'static str,
    /// Its triangles.
    pub triangles: &'a [geom::Triangle],
    /// The camera.
    pub camera: trace::PinholeCamera,
    /// One in `sample` tile chunks timed.
    pub sample: u32,
}

/// A variant of the study: assumption key, value, configuration, and the sampling rate
/// and view scale it sets instead of the scenes' own.
type Variation = (String, String, SystemConfig, Option<u32>, Option<f32>);

/// Bounces of \[P4\] §3.2's diffuse paths.
pub const P4_BOUNCES: u32 = 4;

/// \[P4\] Table 2's changes for one variant: per ray kind, MBVH4 over BVH2 minus one.
fn p4_figures(
    p4: &P4Scene<'_>,
    camera: &trace::PinholeCamera,
    trees: &[rtunit::BuiltTree; 2],
    cfg: &RtConfig,
    sample: u32,
    memo: &mut SimMemo,
) -> Result<Vec<Figure>, SystemError> {
    let mut v = Vec::new();
    let mut table1: Vec<[rtunit::report::Figures; 2]> = Vec::new();
    for rays in [RayMode::Primary, RayMode::Diffuse] {
        let mut runs = Vec::new();
        for tree in trees {
            let tag = ("p4", tree.kind, rays, sample, camera);
            let r = memo.rt_run(&tag, cfg, || {
                let work = Workload {
                    triangles: p4.triangles,
                    camera,
                    rays,
                    bounces: P4_BOUNCES,
                    seed: 1,
                    sample,
                    progress: None,
                };
                Ok(rtunit::run(tree, &work, cfg)?)
            })?;
            if !r.hits_match_software {
                return Err(SystemError::Config(format!(
                    "{}: accelerator hits differ from the software tracer's",
                    p4.name
                )));
            }
            runs.push(r);
        }
        let e = |r: &rtunit::RtReport| {
            r.energy
                .as_ref()
                .map_or((0.0, 0.0), |e| (e.frame_mj, e.mrps_per_mm2))
        };
        let (b, m) = (&runs[0], &runs[1]);
        let ray = super::report::ray_name(rays);
        let thesis = crate::thesis::p4_row(p4.thesis_scene, ray).map(|t| t.change_pct);
        let change = |x: f64, y: f64| if x > 0.0 { y / x - 1.0 } else { 0.0 };
        for (i, (what, value)) in [
            ("perf", change(b.mrps, m.mrps)),
            ("energy", change(e(b).0, e(m).0)),
            ("perf/area", change(e(b).1, e(m).1)),
            ("traffic", change(b.frame_dram_mb, m.frame_dram_mb)),
        ]
        .into_iter()
        .enumerate()
        {
            v.push((
                format!("P4 Table 2 {} {ray} MBVH4 {what} change", p4.name),
                value,
                thesis.map(|t| t[i] / 100.0),
                "change",
            ));
        }
        table1.push([
            rtunit::report::Figures::of(b),
            rtunit::report::Figures::of(m),
        ]);
    }
    // [P4] Table 1: per tree, the area of each unit and its power with each ray kind
    // (the thesis's figures are Fairy's; ours the study's scene).
    for (t, tree) in ["BVH2", "MBVH4"].into_iter().enumerate() {
        for (k, what) in ["area", "primary", "diffuse"].into_iter().enumerate() {
            let f = &table1[k.saturating_sub(1)][t];
            let ours: Vec<(&str, f64)> = f
                .units
                .iter()
                .map(|u| (u.0, if k == 0 { u.1 } else { u.2 }))
                .collect();
            let thesis = crate::thesis::P4_TABLE1[t][k];
            let sum: f64 = ours.iter().map(|u| u.1).sum();
            let unit = if k == 0 { "mm2" } else { "mW" };
            for (i, (name, x)) in ours.into_iter().chain([("sum", sum)]).enumerate() {
                v.push((
                    format!("P4 Table 1 {} {tree} {name} {what}", p4.name),
                    x,
                    thesis.get(i.min(6)).copied(),
                    unit,
                ));
            }
        }
    }
    Ok(v)
}

/// The names of \[P2\]'s three memory systems in its tables.
const P2_SYSTEM_NAMES: [&str; 3] = ["slow", "medium", "fast"];

/// MergeTree (the system's configuration) on the three memory systems of \[P2\] Tables
/// III and VII, for one scene and variant.
#[derive(Clone, Debug)]
struct MergeTreeFigures {
    scene: String,
    triangles: usize,
    /// Per system: build time in ms.
    ms: [f64; 3],
    /// Per system: traffic over the build time, GB/s.
    gbs: [f64; 3],
    /// Per system: on-chip power, mW.
    logic_mw: [f64; 3],
    /// Per system: DRAM power under the variant's DRAM convention, mW.
    dram_mw: [f64; 3],
    /// Traffic on the slow system, MB.
    mb: f64,
    /// On the fast system: the on-chip units (name, mm^2, mW), then the total.
    units_fast: Vec<(&'static str, f64, f64)>,
}

/// `system` with the what-if options of `dram` (the configuration's memory).
fn with_options_of(system: &str, dram: &str) -> String {
    match dram.split_once(',') {
        Some((_, options)) => format!("{system},{options}"),
        None => system.to_string(),
    }
}

/// [`MergeTreeFigures`] of `s` under `cfg`; the run on the configuration's own memory is
/// the system study's, from `memo`.
fn mergetree_figures(
    s: &SystemScene<'_>,
    cfg: &SystemConfig,
    memo: &mut SimMemo,
) -> Result<MergeTreeFigures, SystemError> {
    let aabbs = bvh::triangle_aabbs(s.triangles);
    let mut f = MergeTreeFigures {
        scene: s.name.clone(),
        triangles: s.triangles.len(),
        ms: [0.0; 3],
        gbs: [0.0; 3],
        logic_mw: [0.0; 3],
        dram_mw: [0.0; 3],
        mb: 0.0,
        units_fast: Vec::new(),
    };
    for (k, system) in crate::thesis::P2_SYSTEMS.iter().enumerate() {
        let mut c = cfg.clone();
        c.dram = with_options_of(system, &cfg.dram);
        let r = super::mergetree_run(&aabbs, &cfg.mergetree, &c, memo)?;
        let e = crate::mergetree::energy::mergetree_energy(&r, cfg.node, &cfg.energy)?;
        let bytes = (r.bytes_read + r.bytes_written) as f64;
        f.ms[k] = r.ms;
        f.gbs[k] = if r.ms > 0.0 {
            bytes / (r.ms * 1e-3) / 1e9
        } else {
            0.0
        };
        f.logic_mw[k] = e.logic_mw;
        f.dram_mw[k] = match cfg.energy.dram {
            crate::energy::DramConvention::AboveIdle => e.dram_above_idle_mw,
            crate::energy::DramConvention::Full => e.dram_mw,
        };
        if k == 0 {
            f.mb = bytes / 1e6;
        }
        if k == 2 {
            // The on-chip units, in Table IV's order (the DRAM is the last).
            f.units_fast = e.units[..e.units.len().saturating_sub(1)]
                .iter()
                .map(|u| (u.unit, u.area_mm2, u.power_mw))
                .chain([("total", e.area_mm2, e.logic_mw)])
                .collect();
        }
    }
    Ok(f)
}

/// \[P2\] Table III's SAH columns: each builder's tree (the system study's: MergeTree's
/// for the three MergeTree builds, the binned SAH builder's) as a fraction of the SAH of a
/// full sweep SAH build of the same triangles (`sweeps`, per scene in `results`' order;
/// \[P2\] §6.2: "SAH costs are normalized to a full SAH sweep"), beside Table III's
/// percentages where it has the scene.
fn sah_rows(results: &[SceneResult], sweeps: &[f64]) -> Vec<Figure> {
    use crate::thesis::p2_scene;
    // Table III's columns, in `P2Scene::sah_pct` order.
    const COLUMNS: [super::Builder; 4] = [
        super::Builder::Hlbvh,
        super::Builder::HlbvhSah,
        super::Builder::HlbvhAtrbvh,
        super::Builder::BinnedSah,
    ];
    let mut v = Vec::new();
    for (r, &sweep) in results.iter().zip(sweeps) {
        let th = p2_scene(&r.scene);
        for (i, b) in COLUMNS.into_iter().enumerate() {
            v.push((
                format!("III {} SAH {} vs sweep", r.scene, b.name()),
                bvh::sah_ratio(r.build(b).sah, sweep),
                th.map(|t| t.sah_pct[i] / 100.0),
                "ratio",
            ));
        }
    }
    v
}

/// \[P2\] Tables III, VI, VII and IV from the scenes' [`MergeTreeFigures`], with the
/// thesis's values where it has the scene (Tables III and VI) or the average (VII), and
/// Table IV (Lion on the fast system) beside the largest scene.
fn mergetree_rows(mts: &[MergeTreeFigures]) -> Vec<Figure> {
    use crate::thesis::{p2_scene, P2_TABLE_IV, P2_TABLE_VII};
    let mut v = Vec::new();
    for m in mts {
        let th = p2_scene(&m.scene);
        for (k, sys) in P2_SYSTEM_NAMES.iter().enumerate() {
            v.push((
                format!("III {} MergeTree ms {sys}", m.scene),
                m.ms[k],
                th.map(|t| t.mergetree_ms[k]),
                "ms",
            ));
        }
        for (k, sys) in P2_SYSTEM_NAMES.iter().enumerate().skip(1) {
            v.push((
                format!("III {} speed-up {sys} over slow", m.scene),
                if m.ms[k] > 0.0 {
                    m.ms[0] / m.ms[k]
                } else {
                    0.0
                },
                th.map(|t| t.speedups()[k - 1]),
                "x",
            ));
        }
        v.push((
            format!("VI {} MergeTree traffic", m.scene),
            m.mb,
            th.map(|t| t.traffic_mb[0]),
            "MB",
        ));
    }
    if !mts.is_empty() {
        let n = mts.len() as f64;
        let mean = |f: &dyn Fn(&MergeTreeFigures) -> f64| mts.iter().map(f).sum::<f64>() / n;
        for (k, sys) in P2_SYSTEM_NAMES.iter().enumerate() {
            let logic = mean(&|m| m.logic_mw[k]);
            let dram = mean(&|m| m.dram_mw[k]);
            for (i, (what, x, unit)) in [
                ("traffic", mean(&|m| m.gbs[k]), "GB/s"),
                ("logic", logic, "mW"),
                ("DRAM", dram, "mW"),
                ("total", logic + dram, "mW"),
            ]
            .into_iter()
            .enumerate()
            {
                v.push((
                    format!("VII {sys} mean {what}"),
                    x,
                    Some(P2_TABLE_VII[i][k]),
                    unit,
                ));
            }
        }
    }
    if let Some(big) = mts.iter().max_by_key(|m| m.triangles) {
        for (u, t) in big.units_fast.iter().zip(P2_TABLE_IV) {
            v.push((
                format!("IV {} fast {} area", big.scene, u.0),
                u.1,
                Some(t.1),
                "mm2",
            ));
            v.push((
                format!("IV {} fast {} power", big.scene, u.0),
                u.2,
                Some(t.2),
                "mW",
            ));
        }
    }
    v
}

/// Runs the default model and every value of every assumption over `scenes` (Table VIII's
/// figures) and `p4` (\[P4\] Table 2's changes; its accelerator takes the same keys at
/// \[P4\]'s node and IST division). `progress`
/// is told what runs. An assumption with a key the configuration does not know is an
/// error before anything runs.
pub fn run(
    scenes: &[SystemScene<'_>],
    p4: Option<&P4Scene<'_>>,
    base: &SystemConfig,
    assumptions: &[Assumption],
    progress: impl Fn(&str) + Sync,
) -> Result<SensitivityReport, SystemError> {
    if scenes.is_empty() && p4.is_none() {
        return Err(SystemError::Config(
            "no scenes for the sensitivity study".into(),
        ));
    }
    // (key, value, config, sample override); the [P4] accelerator's configuration per
    // variant beside it.
    let p4_base = RtConfig {
        energy: base.energy,
        dram: "lpddr3-1600-2x32".into(),
        ..RtConfig::default()
    };
    // (key, value, config, sample override, view scale override)
    let mut variants: Vec<Variation> =
        vec![("default".into(), String::new(), base.clone(), None, None)];
    let mut p4_cfgs = vec![p4_base.clone()];
    for a in assumptions {
        for &v in &a.values {
            let mut rt = p4_base.clone();
            if a.key == SAMPLE_KEY {
                let k: u32 = v
                    .parse()
                    .ok()
                    .filter(|k| *k >= 1)
                    .ok_or_else(|| SystemError::Config(format!("bad sample '{v}'")))?;
                variants.push((a.key.into(), v.into(), base.clone(), Some(k), None));
            } else if a.key == VIEW_KEY {
                let k: f32 = v
                    .parse()
                    .ok()
                    .filter(|k: &f32| k.is_finite() && *k > 0.0)
                    .ok_or_else(|| SystemError::Config(format!("bad view scale '{v}'")))?;
                variants.push((a.key.into(), v.into(), base.clone(), None, Some(k)));
            } else {
                let mut c = base.clone();
                c.set(a.key, v)?;
                variants.push((a.key.into(), v.into(), c, None, None));
                // MergeTree's parameters and the toplevel builds' cells do not touch
                // the [P4] accelerator.
                if !a.key.starts_with(super::MERGETREE_PREFIX) && a.key != "toplevel_bits" {
                    rt.set(a.key, v)
                        .map_err(|e| SystemError::Config(e.to_string()))?;
                }
            }
            p4_cfgs.push(rt);
        }
    }
    // Scenes in parallel, each with its own memo over all the variants.
    type PerScene = (Vec<(SceneResult, MergeTreeFigures)>, u64, u64, f64);
    let per_scene: Vec<PerScene> = scenes
        .par_iter()
        .map(|s| {
            progress(&format!("{}: sweep SAH reference", s.name));
            let sweep = bvh::SweepSahBuilder::default()
                .build(&bvh::triangle_aabbs(s.triangles))?
                .sah();
            let mut memo = SimMemo::default();
            let mut out = Vec::with_capacity(variants.len());
            for (key, value, cfg, sample, view) in &variants {
                let camera = match view {
                    Some(k) => s
                        .camera
                        .with_view_scale(*k)
                        .map_err(|e| SystemError::Config(e.to_string()))?,
                    None => s.camera,
                };
                let scene = SystemScene {
                    name: s.name.clone(),
                    triangles: s.triangles,
                    camera,
                    sample: sample.unwrap_or(s.sample),
                };
                let label = if key == "default" {
                    "default".to_string()
                } else {
                    format!("{key}={value}")
                };
                let r = scene_result_memo(&scene, cfg, &mut memo, |what| {
                    progress(&format!("{label}: {what}"))
                })?;
                progress(&format!("{label}: {} MergeTree on [P2]'s systems", s.name));
                let m = mergetree_figures(&scene, cfg, &mut memo)?;
                out.push((r, m));
            }
            Ok((out, memo.simulated, memo.reused, sweep))
        })
        .collect::<Result<_, SystemError>>()?;
    let (mut simulated, mut reused) = (0, 0);
    let mut results: Vec<Vec<SceneResult>> = vec![Vec::new(); variants.len()];
    let mut mts: Vec<Vec<MergeTreeFigures>> = vec![Vec::new(); variants.len()];
    let mut sweeps = Vec::with_capacity(per_scene.len());
    for (out, sim, re, sweep) in per_scene {
        sweeps.push(sweep);
        simulated += sim;
        reused += re;
        for (i, (r, m)) in out.into_iter().enumerate() {
            results[i].push(r);
            mts[i].push(m);
        }
    }
    let mut per_variant: Vec<Vec<Figure>> = results
        .iter()
        .zip(&mts)
        .map(|(r, m)| {
            let mut f = figures(r);
            f.extend(sah_rows(r, &sweeps));
            f.extend(mergetree_rows(m));
            f
        })
        .collect();
    if let Some(p4) = p4 {
        let trees = [
            rtunit::build_tree(TreeKind::Bvh2, p4.triangles)?,
            rtunit::build_tree(TreeKind::Mbvh4, p4.triangles)?,
        ];
        let mut memo = SimMemo::default();
        for (i, ((key, value, _, sample, view), rt)) in variants.iter().zip(&p4_cfgs).enumerate() {
            progress(&format!("{key}={value}: [P4] {}", p4.name));
            let camera = match view {
                Some(k) => p4
                    .camera
                    .with_view_scale(*k)
                    .map_err(|e| SystemError::Config(e.to_string()))?,
                None => p4.camera,
            };
            let f = p4_figures(
                p4,
                &camera,
                &trees,
                rt,
                sample.unwrap_or(p4.sample),
                &mut memo,
            )?;
            per_variant[i].extend(f);
        }
        simulated += memo.simulated;
        reused += memo.reused;
    }
    let mut rows = Vec::new();
    for (f, (name, default, thesis, unit)) in per_variant[0].iter().enumerate() {
        let values: Vec<f64> = per_variant.iter().map(|v| v[f].1).collect();
        let low = values.iter().copied().fold(f64::INFINITY, f64::min);
        let high = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut driver = String::new();
        let mut driver_spread = 0.0;
        for a in assumptions {
            let of: Vec<f64> = variants
                .iter()
                .zip(&values)
                .filter(|((k, ..), _)| k == a.key)
                .map(|(_, &x)| x)
                .chain([*default])
                .collect();
            let spread = of.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                - of.iter().copied().fold(f64::INFINITY, f64::min);
            if spread > driver_spread {
                driver_spread = spread;
                driver = a.key.to_string();
            }
        }
        rows.push(FigureRow {
            figure: name.clone(),
            unit,
            thesis: *thesis,
            default: *default,
            low,
            high,
            driver,
            driver_spread,
            thesis_inside: thesis.map(|t| t >= low - 1e-12 && t <= high + 1e-12),
        });
    }
    let variants = variants
        .into_iter()
        .zip(&per_variant)
        .map(|((key, value, ..), figs)| Variant {
            key,
            value,
            figures: figs.iter().map(|(n, v, ..)| (n.clone(), *v)).collect(),
        })
        .collect();
    Ok(SensitivityReport {
        schema: SCHEMA,
        scenes: scenes
            .iter()
            .map(|s| (s.name.clone(), s.triangles.len()))
            .collect(),
        assumptions: assumptions.to_vec(),
        rows,
        variants,
        simulated,
        reused,
    })
}

impl SensitivityReport {
    /// The figures as Markdown: value, range, driver, thesis; fractions (ratios to
    /// binned SAH, relative changes) in percent, the rest in their units.
    pub fn markdown(&self) -> String {
        let mut t = Table::text(&[
            "figure",
            "unit",
            "thesis",
            "default",
            "low",
            "high",
            "driver (spread)",
            "thesis in range",
        ])
        .right(&[2, 3, 4, 5]);
        for r in &self.rows {
            let fraction = matches!(r.unit, "ratio" | "change");
            let fmt = |x: f64| {
                if fraction {
                    format!("{:.0}%", x * 100.0)
                } else {
                    significant(x)
                }
            };
            t.push([
                r.figure.to_string(),
                if fraction { "%" } else { r.unit }.to_string(),
                r.thesis.map_or("-".into(), fmt),
                fmt(r.default),
                fmt(r.low),
                fmt(r.high),
                if r.driver.is_empty() {
                    "-".to_string()
                } else if fraction {
                    format!("{} ({:.1} pp)", r.driver, r.driver_spread * 100.0)
                } else {
                    format!("{} ({})", r.driver, significant(r.driver_spread))
                },
                match r.thesis_inside {
                    Some(true) => "yes",
                    Some(false) => "no",
                    None => "-",
                }
                .to_string(),
            ]);
        }
        t.markdown()
    }

    /// The assumptions as Markdown.
    pub fn assumptions_markdown(&self) -> String {
        let mut t = Table::text(&["key", "default", "tried", "what"]);
        for a in &self.assumptions {
            t.push([
                format!("`{}`", a.key),
                a.default.to_string(),
                a.values.join(", "),
                a.what.to_string(),
            ]);
        }
        t.markdown()
    }

    /// One CSV row per figure.
    pub fn csv(&self) -> String {
        let mut c = Table::text(&[
            "figure",
            "unit",
            "thesis",
            "default",
            "low",
            "high",
            "driver",
            "driver_spread",
        ]);
        for r in &self.rows {
            c.push([
                r.figure.to_string(),
                r.unit.to_string(),
                r.thesis.map_or(String::new(), |t| t.to_string()),
                r.default.to_string(),
                r.low.to_string(),
                r.high.to_string(),
                r.driver.to_string(),
                r.driver_spread.to_string(),
            ]);
        }
        c.csv()
    }
}

/// `x` with three significant digits (at least none after the point).
fn significant(x: f64) -> String {
    let digits = if x == 0.0 || !x.is_finite() {
        0
    } else {
        (2 - x.abs().log10().floor() as i32).clamp(0, 6) as usize
    };
    format!("{x:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::energy::FpuSource;
    use scene::LoadOptions;

    fn scene(spec: &str) -> (Vec<geom::Triangle>, trace::PinholeCamera) {
        let s = scene::open(spec, &LoadOptions::default()).unwrap();
        let tris: Vec<geom::Triangle> = s.mesh_at(0.0).unwrap().triangles_iter().collect();
        let cam = trace::PinholeCamera::new(&s.info().camera, 16, 12).unwrap();
        (tris, cam)
    }

    /// Two assumptions over a tiny scene: the conventions reuse every cycle-level run,
    /// the figures of each variant equal a run of that configuration alone, and the rows
    /// hold the lowest and highest of the variants, with the driver the assumption that
    /// moves the figure most.
    #[test]
    fn variants_equal_single_runs_and_rows_span_them() {
        let (tris, cam) = scene("proc:hairball?n=2000&seed=3");
        let scenes = [SystemScene {
            name: "hairball".into(),
            triangles: &tris,
            camera: cam,
            sample: 1,
        }];
        let base = SystemConfig::default();
        let all = assumptions();
        let pick: Vec<Assumption> = all
            .into_iter()
            .filter(|a| a.key == "fpu_energy" || a.key == "l2_latency")
            .collect();
        let rep = run(&scenes, None, &base, &pick, |_| {}).unwrap();
        assert_eq!(rep.variants.len(), 1 + 1 + 2);
        // The default: 3 MergeTree runs and 8 traces for Table VIII, then MergeTree on
        // [P2]'s three systems, of which the medium one is Table VIII's. The FPU variant
        // reuses all 14; the latency variants reuse the 6 MergeTree runs and trace again.
        assert_eq!(rep.simulated, 11 + 2 + 2 * 8);
        assert_eq!(rep.reused, 1 + 14 + 2 * 6);
        // The Horowitz variant equals a run of that configuration on its own.
        let mut horowitz = base.clone();
        horowitz.set("fpu_energy", "horowitz").unwrap();
        assert_eq!(horowitz.energy.fpu, FpuSource::Horowitz);
        let alone = super::super::report::scene_result(&scenes[0], &horowitz, |_| {}).unwrap();
        let want = figures(&[alone]);
        let got = &rep.variants[1];
        assert_eq!(got.key, "fpu_energy");
        for ((n, v), (wn, wv, ..)) in got.figures.iter().zip(&want) {
            assert_eq!(n, wn);
            assert!(
                (v - wv).abs() <= 1e-12 * wv.abs().max(1.0),
                "{n}: {v} vs {wv}"
            );
        }
        // Rows span the variants. Table VIII's: 2 ray kinds, 3 builders, 3 columns; Table
        // III's SAH of 4 builders; [P2] MergeTree's: per scene 3 times, 2 speed-ups and
        // the traffic (III, VI), 4 means per system (VII), Table IV's 4 units and total,
        // area and power.
        assert_eq!(rep.rows.len(), 2 * 3 * 3 + 4 + 6 + 3 * 4 + 5 * 2);
        // The SAH rows are each builder's tree against a sweep SAH tree of the scene.
        let sweep = bvh::SweepSahBuilder::default()
            .build(&bvh::triangle_aabbs(&tris))
            .unwrap()
            .sah();
        for b in super::super::Builder::ALL {
            let r = rep
                .rows
                .iter()
                .find(|r| r.figure == format!("III hairball SAH {} vs sweep", b.name()))
                .unwrap();
            let (e, _) = super::super::build_energy(b, &bvh::triangle_aabbs(&tris), &base).unwrap();
            assert_eq!(r.default, e.sah / sweep, "{r:?}");
            // No tree beats the sweep by much, and the MergeTree trees are worse than it.
            assert!(r.default > 0.95 && r.default < 2.0, "{r:?}");
            // The FPU energy and a cache latency do not change a tree.
            assert_eq!((r.low, r.high), (r.default, r.default), "{r:?}");
        }
        for (f, r) in rep.rows.iter().enumerate() {
            let vals: Vec<f64> = rep.variants.iter().map(|v| v.figures[f].1).collect();
            assert_eq!(r.default, vals[0]);
            assert_eq!(r.low, vals.iter().copied().fold(f64::INFINITY, f64::min));
            assert_eq!(
                r.high,
                vals.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            );
            // The thesis has every figure but those of a scene it does not have.
            assert_eq!(
                r.thesis.is_some(),
                !r.figure.starts_with("III") && !r.figure.starts_with("VI "),
                "{r:?}"
            );
            if r.high > r.low {
                assert!(
                    r.driver == "fpu_energy" || r.driver == "l2_latency",
                    "{r:?}"
                );
                assert!(r.driver_spread > 0.0 && r.driver_spread <= r.high - r.low + 1e-12);
            }
        }
        // The FPU source moves the binned SAH reference, so it moves the build ratios.
        let build = rep
            .rows
            .iter()
            .find(|r| r.figure == "VIII primary all hlbvh build")
            .unwrap();
        assert_eq!(build.driver, "fpu_energy", "{build:?}");
        assert!(rep.markdown().lines().count() == rep.rows.len() + 2);
        assert_eq!(rep.csv().lines().count(), rep.rows.len() + 1);
    }

    /// The [P4] part alone: four accelerator runs for the default, reused by an energy
    /// convention (which moves the energy change but not the speed or traffic), simulated
    /// again for a timing parameter; eight figures with Table 2's Crytek values.
    #[test]
    fn the_p4_part_reuses_runs_and_carries_the_thesis_changes() {
        let (tris, cam) = scene("proc:hairball?n=2000&seed=5");
        let p4 = P4Scene {
            name: "hairball".into(),
            thesis_scene: "Crytek",
            triangles: &tris,
            camera: cam,
            sample: 1,
        };
        let pick: Vec<Assumption> = assumptions()
            .into_iter()
            .filter(|a| a.key == "fpu_energy" || a.key == "stacks_per_trv")
            .collect();
        let rep = run(&[], Some(&p4), &SystemConfig::default(), &pick, |_| {}).unwrap();
        assert_eq!((rep.simulated, rep.reused), (4 + 4, 4));
        // Table 2's 8 changes, then Table 1's: 2 trees, area and two powers, 6 units and
        // their sum.
        assert_eq!(rep.rows.len(), 8 + 2 * 3 * 7);
        let t1 = |f: &str| rep.rows.iter().find(|r| r.figure.ends_with(f)).unwrap();
        let sum = t1("MBVH4 sum area");
        assert_eq!(
            (sum.unit, sum.thesis),
            ("mm2", Some(crate::thesis::P4_TABLE1[1][0][6]))
        );
        let parts: f64 = ["TRV", "IST", "stack", "cache", "FIFO", "DRAM"]
            .iter()
            .map(|u| t1(&format!("MBVH4 {u} area")).default)
            .sum();
        assert!(
            (parts - sum.default).abs() < 1e-9 && sum.default > 0.5,
            "{parts}"
        );
        // The FPU source moves the IST's power, not its area.
        let (area, power) = (t1("BVH2 IST area"), t1("BVH2 IST primary"));
        assert!(area.high == area.low && power.high > power.low, "{power:?}");
        let row = |f: &str| rep.rows.iter().find(|r| r.figure.ends_with(f)).unwrap();
        assert_eq!(row("primary MBVH4 perf change").thesis, Some(0.87));
        assert_eq!(row("diffuse MBVH4 traffic change").thesis, Some(-0.30));
        // The FPU source moves no speed or traffic figure.
        let fpu = &rep.variants[1];
        assert_eq!(fpu.key, "fpu_energy");
        for (f, (name, v)) in fpu.figures.iter().enumerate() {
            if name.contains("perf change") || name.contains("traffic") {
                assert_eq!(*v, rep.variants[0].figures[f].1, "{name}");
            }
        }
    }

    /// MergeTree's parameters and the address mapping: a buffer size that leaves the
    /// tree alone simulates MergeTree again but reuses every trace (the memo keys traces
    /// by the tree), the Morton grid changes the MergeTree trees and so traces them again,
    /// and the address mapping re-runs everything that touches the memory.
    #[test]
    fn mergetree_and_memory_assumptions_rerun_what_they_change() {
        let (tris, cam) = scene("proc:hairball?n=3000&seed=4");
        let scenes = [SystemScene {
            name: "hairball".into(),
            triangles: &tris,
            camera: cam,
            sample: 1,
        }];
        let only = |keys: &[&str]| -> Vec<Assumption> {
            assumptions()
                .into_iter()
                .filter(|a| keys.contains(&a.key))
                .map(|mut a| {
                    a.values.truncate(1);
                    a
                })
                .collect()
        };
        let base = SystemConfig::default();
        let default_runs = (11 + 2, 1);
        // presort_slots=2: 5 MergeTree runs again (3 of Table VIII, 2 more systems).
        let rep = run(
            &scenes,
            None,
            &base,
            &only(&["mergetree.presort_slots"]),
            |_| {},
        )
        .unwrap();
        assert_eq!(
            (rep.simulated, rep.reused),
            (default_runs.0 + 5, default_runs.1 + 8 + 1)
        );
        let row = |rep: &SensitivityReport, f: &str| {
            rep.rows.iter().find(|r| r.figure == f).cloned().unwrap()
        };
        let ms = row(&rep, "III hairball MergeTree ms slow");
        assert_eq!(ms.driver, "mergetree.presort_slots");
        assert!(ms.high > ms.low, "{ms:?}");
        // The traces are the same trees: the trace energy moves with nothing.
        let trace = row(&rep, "VIII primary all hlbvh trace");
        assert_eq!(trace.low, trace.high);
        // The box grid: new MergeTree trees, traced again (3 builders, 2 ray kinds).
        let rep = run(
            &scenes,
            None,
            &base,
            &only(&["mergetree.morton_grid"]),
            |_| {},
        )
        .unwrap();
        assert_eq!(rep.simulated, default_runs.0 + 5 + 6);
        // The grid moves the MergeTree trees' SAH, not binned SAH's.
        let hlbvh = row(&rep, "III hairball SAH hlbvh vs sweep");
        let binned = row(&rep, "III hairball SAH binned-sah vs sweep");
        assert!(hlbvh.high > hlbvh.low, "{hlbvh:?}");
        assert_eq!(hlbvh.driver, "mergetree.morton_grid");
        assert_eq!(binned.low, binned.high);
        // The toplevel cells: the two toplevel builds' MergeTree runs (Table VIII's
        // system only) and their traces again; plain HLBVH's tree and runs stay.
        let rep = run(&scenes, None, &base, &only(&["toplevel_bits"]), |_| {}).unwrap();
        assert_eq!(rep.variants[1].value, "9");
        assert_eq!(rep.simulated, default_runs.0 + 2 + 4);
        let plain = row(&rep, "III hairball SAH hlbvh vs sweep");
        assert_eq!(plain.low, plain.high);
        let sah = row(&rep, "III hairball SAH hlbvh+sah vs sweep");
        assert!(sah.high > sah.low, "{sah:?}");
        assert_eq!(sah.driver, "toplevel_bits");
        let mut bad = base.clone();
        assert!(bad.set("toplevel_bits", "30").is_err());
        assert!(bad.set("toplevel_bits", "0").is_err());
        assert!(bad.set("toplevel_bits", "15").is_ok());
        // The address mapping: every MergeTree run and every trace again.
        let rep = run(&scenes, None, &base, &only(&["address_mapping"]), |_| {}).unwrap();
        assert_eq!(rep.simulated, 2 * default_runs.0);
        let traffic = row(&rep, "VI hairball MergeTree traffic");
        let fast = row(&rep, "III hairball MergeTree ms fast");
        // The mapping moves time, not the bytes MergeTree moves.
        assert!(
            traffic.high == traffic.low && fast.high > fast.low,
            "{fast:?}"
        );
        assert!(rep.variants[1].value == "rorabgbachco");
        // A wider view: every trace again (the memo keys traces by their camera), no
        // MergeTree run; the builds do not move, the traces do.
        let rep = run(&scenes, None, &base, &only(&[VIEW_KEY]), |_| {}).unwrap();
        assert_eq!(rep.simulated, default_runs.0 + 8);
        let build = row(&rep, "VIII primary all hlbvh build");
        let trace = row(&rep, "VIII primary all hlbvh trace");
        assert!(
            build.low == build.high && trace.low < trace.high,
            "{trace:?}"
        );
        assert_eq!(trace.driver, VIEW_KEY);
    }

    #[test]
    fn unknown_keys_and_bad_values_fail_before_running() {
        let (tris, cam) = scene("proc:hairball?n=500&seed=3");
        let scenes = [SystemScene {
            name: "h".into(),
            triangles: &tris,
            camera: cam,
            sample: 1,
        }];
        for (key, value) in [
            ("warp_drive", "1"),
            ("sram_cell", "xx"),
            (SAMPLE_KEY, "0"),
            ("mergetree.warp", "1"),
            ("mergetree.presort_slots", "-1"),
            ("mergetree.write_chunk_bytes", "4096"),
            ("address_mapping", "chchrabgbaco"),
            (VIEW_KEY, "0"),
            (VIEW_KEY, "wide"),
        ] {
            let a = Assumption {
                key,
                default: "",
                values: vec![value],
                what: "",
            };
            let ran = std::sync::atomic::AtomicBool::new(false);
            let e = run(&scenes, None, &SystemConfig::default(), &[a], |_| {
                ran.store(true, std::sync::atomic::Ordering::Relaxed)
            })
            .unwrap_err()
            .to_string();
            assert!(!ran.into_inner() && !e.contains('\n'), "{key}: {e}");
        }
        assert!(run(&[], None, &SystemConfig::default(), &assumptions(), |_| {}).is_err());
    }
}
