//! Beyond the thesis (issue 18, `docs/beyond-thesis.md`): the four open problems of
//! MergeTree and CBVH that the thesis names, each run as a mode of the MergeTree model
//! beside the thesis's own baseline on the same scene, memory and preset (\[P2\]'s `p2`):
//!
//! 1. forecasting read scheduling against double buffering (\[P1\] §5, \[P2\] §7);
//! 2. MBVH4 out of the stream (greedy and windowed collapse behind the emitter, and
//!    compressed 4-wide nodes behind it) against building BVH2 and collapsing it after;
//! 3. point k-d trees (box and plane-only nodes) and octrees from the Morton order
//!    against a BVH over the same points (the triangles' centroids);
//! 4. streaming CBVH update with plane sharing against the \[P3\] node pairs.
//!
//! Every run is checked against the software it models (`matches`). [`run`] writes to
//! [`BeyondOptions::out`]: `report.md` (a table per part), `beyond.csv` and `beyond.json`
//! (every row).

use crate::fs::write_file;
use crate::progress::Progress;
use crate::table::Table;
use anyhow::Context;
use serde::Serialize;
use sim::mergetree::{self, MergeTreeConfig, MergeTreeReport};
use std::path::PathBuf;

/// Options of the report.
#[derive(Clone, Debug)]
pub struct BeyondOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Scenes (mesh files or procedural specs).
    pub scenes: Vec<String>,
    /// Memory system of every run (`sim::dram::open`'s names).
    pub dram: String,
}

impl Default for BeyondOptions {
    fn default() -> Self {
        BeyondOptions {
            out: "arbor-out/report-beyond".into(),
            scenes: Vec::new(),
            dram: "lpddr3-1600-1x64".into(),
        }
    }
}

/// One run of the model.
#[derive(Clone, Debug, Serialize)]
pub struct BeyondRow {
    /// Scene name.
    pub scene: String,
    /// Part of issue 18 (1 to 4).
    pub part: u32,
    /// What ran (the baseline first in each part).
    pub variant: &'static str,
    /// The `--set` settings of the run (beyond the `p2` preset).
    pub settings: String,
    /// Whether this is the part's baseline.
    pub baseline: bool,
    /// Multi-merge passes.
    pub merge_passes: u32,
    /// Unit cycles of the whole run.
    pub cycles: u64,
    /// Milliseconds of the whole run.
    pub ms: f64,
    /// DRAM bytes read and written, in MB.
    pub mb_read: f64,
    /// DRAM bytes written, in MB.
    pub mb_written: f64,
    /// Traffic (read + written) over the baseline's.
    pub traffic_vs_baseline: f64,
    /// Cycles over the baseline's.
    pub cycles_vs_baseline: f64,
    /// SAH of the wide tree (parts 2; 4-wide nodes at 2 C_i), of the decoded tree for
    /// compressed nodes; none elsewhere.
    pub sah: Option<f64>,
    /// Bytes of the output nodes (node pairs, wide nodes, point-tree nodes).
    pub node_bytes: Option<u64>,
    /// Backtracking steps of a streaming compressor.
    pub backtrack_steps: Option<u64>,
    /// The unit's result equals the software it models.
    pub matches: bool,
}

/// `--set` settings of a run.
type Settings = &'static [(&'static str, &'static str)];

/// The variants of each part: (part, name, settings, over the centroids).
const VARIANTS: &[(u32, &str, Settings, bool)] = &[
    (
        1,
        "double buffering (thesis)",
        &[("read_schedule", "double")],
        false,
    ),
    (1, "forecasting", &[("read_schedule", "forecast")], false),
    (2, "BVH2, then collapse (thesis)", MBVH4_COLLAPSE, false),
    (2, "stream collapse, greedy", MBVH4_GREEDY, false),
    (2, "stream collapse, window 4", MBVH4_WINDOW, false),
    (2, "compressed 4-wide (modulo, treelets 4)", CBVH4, false),
    (
        3,
        "BVH of the points",
        &[("output", "bvh"), POINT_BITS, POINT_GRID, POINT_LEAF],
        true,
    ),
    (
        3,
        "k-d tree",
        &[
            ("output", "kdtree-points"),
            POINT_BITS,
            POINT_GRID,
            POINT_LEAF,
        ],
        true,
    ),
    (3, "k-d tree, plane-only nodes", KD_PLANE, true),
    (
        3,
        "octree",
        &[
            ("output", "octree-points"),
            POINT_BITS,
            POINT_GRID,
            POINT_LEAF,
        ],
        true,
    ),
    (
        4,
        "[P3] node pairs (thesis)",
        &[("output", "cbvh-stream"), ("cbvh_coords", "relative")],
        false,
    ),
    (
        4,
        "plane sharing",
        &[("output", "cbvh-stream"), ("cbvh_coords", "plane-sharing")],
        false,
    ),
    (4, "plane sharing, treelets 4", PLANE_TREELETS, false),
];

const ONE_TREE: [(&str, &str); 2] = [("highlevel_threshold", "none"), ("toplevel_sah", "false")];
const MBVH4_COLLAPSE: &[(&str, &str)] = &[ONE_TREE[0], ONE_TREE[1], ("output", "mbvh4-collapse")];
const MBVH4_GREEDY: &[(&str, &str)] = &[ONE_TREE[0], ONE_TREE[1], ("output", "mbvh4")];
const MBVH4_WINDOW: &[(&str, &str)] = &[
    ONE_TREE[0],
    ONE_TREE[1],
    ("output", "mbvh4"),
    ("mbvh4_window", "4"),
];
const CBVH4: &[(&str, &str)] = &[
    ONE_TREE[0],
    ONE_TREE[1],
    ("output", "cbvh4"),
    ("cbvh_coords", "modulo"),
    ("cbvh_treelet_depth", "4"),
];
const POINT_BITS: (&str, &str) = ("morton_bits", "63");
const POINT_GRID: (&str, &str) = ("morton_grid", "box");
const POINT_LEAF: (&str, &str) = ("max_leaf_size", "8");
const KD_PLANE: &[(&str, &str)] = &[
    ("output", "kdtree-points"),
    ("point_node", "plane"),
    POINT_BITS,
    POINT_GRID,
    POINT_LEAF,
];
const PLANE_TREELETS: &[(&str, &str)] = &[
    ("output", "cbvh-stream"),
    ("cbvh_coords", "plane-sharing"),
    ("cbvh_treelet_depth", "4"),
];

/// One simulation of `prims` with `settings` over the `p2` preset.
fn simulate(
    prims: &[geom::Aabb],
    settings: &[(&str, &str)],
    dram: &str,
) -> anyhow::Result<(MergeTreeReport, bool)> {
    let mut cfg = MergeTreeConfig::p2();
    for (k, v) in settings {
        cfg.set(k, v).with_context(|| format!("--set {k}={v}"))?;
    }
    let port = sim::dram::open(dram, cfg.period_fs())?;
    let r = mergetree::simulate(prims, &cfg, port)?;
    let matches = mergetree::tree_matches_software(&r, prims)?
        && mergetree::mbvh4_matches_software(&r, prims)?.unwrap_or(true)
        && mergetree::cbvh4_matches_software(&r, prims)?.unwrap_or(true)
        && mergetree::cbvh_matches_software(&r, prims)?.unwrap_or(true);
    Ok((r, matches))
}

/// Runs every part on every scene; writes the files and returns the rows.
pub fn run(o: &BeyondOptions, p: &dyn Progress) -> anyhow::Result<Vec<BeyondRow>> {
    anyhow::ensure!(!o.scenes.is_empty(), "no scenes given");
    let bar = p.bar("beyond the thesis: MergeTree runs");
    let total = (o.scenes.len() * VARIANTS.len()) as u64;
    let mut rows: Vec<BeyondRow> = Vec::new();
    for spec in &o.scenes {
        let (name, prims, points) = {
            let _s = p.spinner(&format!("loading {spec}"));
            let scene = scene::open(spec, &Default::default())
                .with_context(|| format!("cannot open {spec}"))?;
            let mesh = scene.mesh_at(0.0)?;
            let prims = crate::scenes::mesh_boxes(&mesh)?;
            let centroids = mesh.centroids();
            let points = mergetree::point_boxes(&centroids)?;
            (crate::scenes::short_name(spec), prims, points)
        };
        let mut base: Option<(f64, u64)> = None;
        for (part, variant, settings, over_points) in VARIANTS {
            let input = if *over_points { &points } else { &prims };
            let (r, matches) =
                simulate(input, settings, &o.dram).with_context(|| format!("{name}: {variant}"))?;
            let traffic = (r.bytes_read + r.bytes_written) as f64;
            let baseline = rows
                .last()
                .is_none_or(|l| l.part != *part || l.scene != name);
            if baseline {
                base = Some((traffic, r.cycles));
            }
            let (bt, bc) = base.unwrap_or((traffic, r.cycles));
            let (sah, node_bytes, backtrack) = match (&r.mbvh4, &r.cbvh4, &r.cbvh, &r.points) {
                (Some(m), _, _, _) => (Some(m.sah), Some(m.wide_nodes * m.node_bytes), None),
                (_, Some(c), _, _) => (
                    Some(c.sah_decoded),
                    Some(c.wide_nodes * c.node_bytes),
                    Some(c.backtrack_steps),
                ),
                (_, _, Some(c), _) => (
                    None,
                    Some(c.node_pairs * c.pair_bytes),
                    Some(c.backtrack_steps),
                ),
                (_, _, _, Some(pt)) => (None, Some(pt.node_bytes), None),
                _ => (None, None, None),
            };
            rows.push(BeyondRow {
                scene: name.clone(),
                part: *part,
                variant,
                settings: settings
                    .iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(" "),
                baseline,
                merge_passes: r.merge_passes,
                cycles: r.cycles,
                ms: r.ms,
                mb_read: r.bytes_read as f64 / 1e6,
                mb_written: r.bytes_written as f64 / 1e6,
                traffic_vs_baseline: traffic / bt,
                cycles_vs_baseline: r.cycles as f64 / bc as f64,
                sah,
                node_bytes,
                backtrack_steps: backtrack,
                matches,
            });
            bar.update(rows.len() as u64, total);
        }
    }
    bar.finish();
    write_report(o, &rows)?;
    Ok(rows)
}

const PART_TITLES: [&str; 4] = [
    "Part 1: forecasting read scheduling ([P1] §5, [P2] §7) against double buffering",
    "Part 2: MBVH4 out of the stream against building BVH2 and collapsing it",
    "Part 3: point k-d trees and octrees over the triangles' centroids",
    "Part 4: streaming CBVH update with plane sharing against the [P3] node pairs",
];

/// The table of every row (all parts), or of one part.
fn table(rows: &[&BeyondRow]) -> Table {
    let opt = |v: Option<f64>, d: usize| v.map(|x| format!("{x:.d$}")).unwrap_or_default();
    let mut t = Table::new(&[
        "scene",
        "part",
        "variant",
        "merge passes",
        "ms",
        "MB read",
        "MB written",
        "traffic / baseline",
        "cycles / baseline",
        "SAH",
        "node bytes",
        "backtracks",
        "matches software",
    ]);
    for r in rows {
        t.push([
            r.scene.clone(),
            r.part.to_string(),
            r.variant.to_string(),
            r.merge_passes.to_string(),
            format!("{:.3}", r.ms),
            format!("{:.2}", r.mb_read),
            format!("{:.2}", r.mb_written),
            format!("{:.3}", r.traffic_vs_baseline),
            format!("{:.3}", r.cycles_vs_baseline),
            opt(r.sah, 2),
            r.node_bytes.map(|b| b.to_string()).unwrap_or_default(),
            r.backtrack_steps.map(|b| b.to_string()).unwrap_or_default(),
            r.matches.to_string(),
        ]);
    }
    t
}

/// The JSON document of a run (`arbor.report.beyond.v1`; `docs/cli-json.md`).
pub fn document(o: &BeyondOptions, rows: &[BeyondRow]) -> serde_json::Value {
    serde_json::json!({ "schema": "arbor.report.beyond.v1", "dram": o.dram, "rows": rows })
}

fn write_report(o: &BeyondOptions, rows: &[BeyondRow]) -> anyhow::Result<()> {
    std::fs::create_dir_all(&o.out)
        .with_context(|| format!("cannot create {}", o.out.display()))?;
    let all: Vec<&BeyondRow> = rows.iter().collect();
    let mut md = String::from(
        "# Beyond the thesis (issue 18)\n\nThe MergeTree model (`p2` preset) in each mode \
         beside the thesis's baseline (the first row of each part; ratios against it); \
         `matches software`: the unit's output equals the software it models. Method, \
         numbers on the shared scenes and limits: `docs/beyond-thesis.md`.\n",
    );
    md.push_str(&format!("\nMemory: `{}`.\n", o.dram));
    for (i, title) in PART_TITLES.iter().enumerate() {
        let part: Vec<&BeyondRow> = all
            .iter()
            .copied()
            .filter(|r| r.part == i as u32 + 1)
            .collect();
        md.push_str(&format!("\n## {title}\n\n"));
        md.push_str(&table(&part).markdown());
    }
    write_file(&o.out, "report.md", &md)?;
    write_file(&o.out, "beyond.csv", &table(&all).csv())?;
    let doc = document(o, rows);
    write_file(&o.out, "beyond.json", &serde_json::to_string_pretty(&doc)?)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small scene through every part: every run matches its software, each part's
    /// first row is its baseline, and the modes beat their baselines where the method
    /// says they must (fewer bytes for the streamed MBVH4 and the point trees' nodes;
    /// never more passes with forecasting).
    #[test]
    fn every_part_runs_checked_against_its_baseline() {
        let dir = tempfile::tempdir().unwrap();
        let o = BeyondOptions {
            out: dir.path().to_path_buf(),
            scenes: vec!["proc:soup?n=6000".into()],
            ..Default::default()
        };
        let rows = run(&o, &crate::progress::Silent).unwrap();
        assert_eq!(rows.len(), VARIANTS.len());
        for r in &rows {
            assert!(r.matches, "{r:?}");
            if r.baseline {
                assert_eq!((r.traffic_vs_baseline, r.cycles_vs_baseline), (1.0, 1.0));
            }
        }
        let by = |v: &str| rows.iter().find(|r| r.variant == v).unwrap();
        assert!(by("forecasting").merge_passes <= by("double buffering (thesis)").merge_passes);
        assert!(by("stream collapse, greedy").traffic_vs_baseline < 1.0);
        assert!(
            by("stream collapse, window 4").sah.unwrap()
                <= by("stream collapse, greedy").sah.unwrap() + 1e-9
        );
        assert!(by("k-d tree, plane-only nodes").node_bytes < by("k-d tree").node_bytes);
        assert_eq!(rows.iter().filter(|r| r.baseline).count(), 4);
        for f in ["report.md", "beyond.csv", "beyond.json"] {
            assert!(dir.path().join(f).is_file(), "{f}");
        }
        let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
        assert!(
            md.contains("Part 4") && md.contains("plane sharing, treelets 4"),
            "{md}"
        );
        let e = run(&BeyondOptions::default(), &crate::progress::Silent).unwrap_err();
        assert!(e.to_string().contains("no scenes"), "{e}");
    }
}
