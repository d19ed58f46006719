//! The analogue of \[P4\] Table 2 from the accelerator model: per scene and ray kind, the
//! BVH and MBVH4 accelerators' performance and DRAM traffic, the relative change, and the
//! thesis's figures beside them (`crate::thesis::P4_TABLE2`), as Markdown, CSV and JSON.
//! The command line (`arbor report rtunit`) calls this; it only loads the scenes and
//! writes the files.
//!
//! Energy per frame and performance per area (\[P4\] Table 2's other columns) and the
//! area and power breakdown of \[P4\] Table 1 come from the accelerator's energy model
//! (`super::energy`).

use std::fmt::Write as _;

use geom::Triangle;
use outfile::table::{Align, Table};
use serde::Serialize;
use trace::PinholeCamera;

use super::{build_tree, run, RayMode, RtConfig, RtError, RtReport, TreeKind, Workload};
use crate::thesis::{p4_row, P4Row};

/// A scene of the report.
pub struct ReportScene<'a> {
    /// Short name.
    pub name: String,
    /// Its triangles.
    pub triangles: &'a [Triangle],
    /// The camera (its size is the image size).
    pub camera: PinholeCamera,
    /// Time one in `sample` tile chunks (1: the whole frame).
    pub sample: u32,
    /// The thesis's name of the scene this one is compared with, if any.
    pub thesis_scene: Option<&'static str>,
    /// What the scene is (e.g. a stand-in for one of the thesis's).
    pub note: String,
}

/// The figures of one run.
#[derive(Clone, Debug, Serialize)]
pub struct Figures {
    /// Million rays per second.
    pub mrps: f64,
    /// DRAM traffic of the frame in MB (10^6 bytes; estimated when sampled).
    pub frame_dram_mb: f64,
    /// Cycles simulated.
    pub cycles: u64,
    /// Rays simulated.
    pub rays: u64,
    /// One in `sample` tile chunks timed.
    pub sample: u32,
    /// Fraction of the data bus's peak used.
    pub bus_utilization: f64,
    /// Deepest stack.
    pub max_stack_depth: usize,
    /// Every hit equal to the software tracer's.
    pub hits_match_software: bool,
    /// Bytes of the tree's nodes.
    pub node_bytes: u64,
    /// Node visits per ray.
    pub visits_per_ray: f64,
    /// Triangle tests per ray.
    pub tests_per_ray: f64,
    /// Hit rates of the L1, shared node and primitive caches.
    pub hit_rates: [f64; 3],
    /// Energy of a frame in mJ.
    pub frame_mj: f64,
    /// Area of the accelerator in mm^2.
    pub area_mm2: f64,
    /// MRPS per mm^2.
    pub mrps_per_mm2: f64,
    /// Per unit of \[P4\] Table 1 (TRV, IST, stack, cache, FIFO, DRAM): area in mm^2 and
    /// mean power in mW.
    pub units: Vec<(&'static str, f64, f64)>,
    /// Wall-clock seconds of the simulation.
    pub wall_seconds: f64,
}

impl Figures {
    /// The figures of `r`.
    pub fn of(r: &RtReport) -> Self {
        let per = |x: u64| x as f64 / r.rays.max(1) as f64;
        Self {
            mrps: r.mrps,
            frame_dram_mb: r.frame_dram_mb,
            cycles: r.cycles,
            rays: r.rays,
            sample: r.sample,
            bus_utilization: r.bus_utilization,
            max_stack_depth: r.max_stack_depth,
            hits_match_software: r.hits_match_software,
            node_bytes: r.tree_nodes as u64 * r.tree.node_bytes() as u64,
            visits_per_ray: per(r.node_visits),
            tests_per_ray: per(r.triangle_tests),
            hit_rates: [0, 1, 2].map(|k| r.caches.get(k).map_or(0.0, |c| c.hit_rate)),
            frame_mj: r.energy.as_ref().map_or(0.0, |e| e.frame_mj),
            area_mm2: r.energy.as_ref().map_or(0.0, |e| e.area_mm2),
            mrps_per_mm2: r.energy.as_ref().map_or(0.0, |e| e.mrps_per_mm2),
            units: r.energy.as_ref().map_or(Vec::new(), |e| {
                e.units
                    .iter()
                    .map(|u| (u.unit, u.area_mm2, u.power_mw))
                    .collect()
            }),
            wall_seconds: r.wall_seconds,
        }
    }
}

/// One row: a scene and ray kind.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Scene.
    pub scene: String,
    /// Triangles.
    pub triangles: usize,
    /// "primary" or "diffuse".
    pub rays: &'static str,
    /// The BVH accelerator.
    pub bvh: Figures,
    /// The MBVH4 accelerator.
    pub mbvh4: Figures,
    /// MBVH4's performance over BVH's, in percent.
    pub perf_change_pct: f64,
    /// MBVH4's traffic over BVH's, in percent.
    pub traffic_change_pct: f64,
    /// MBVH4's energy per frame over BVH's, in percent.
    pub energy_change_pct: f64,
    /// MBVH4's performance per area over BVH's, in percent.
    pub ppa_change_pct: f64,
    /// The thesis's row it is compared with.
    pub thesis: Option<P4Row>,
    /// What the scene is.
    pub note: String,
}

/// Relative difference between our change and the thesis's is within this fraction of the
/// thesis's change (the criterion for agreement).
pub const AGREEMENT: f64 = 0.25;

impl Row {
    /// Whether our perf, traffic, energy and perf/area changes lie within [`AGREEMENT`] of
    /// the thesis's.
    pub fn agrees(&self) -> Option<[bool; 4]> {
        let t = self.thesis?;
        let close = |ours: f64, theirs: f64| (ours - theirs).abs() <= AGREEMENT * theirs.abs();
        Some([
            close(self.perf_change_pct, t.change_pct[0]),
            close(self.traffic_change_pct, t.change_pct[3]),
            close(self.energy_change_pct, t.change_pct[1]),
            close(self.ppa_change_pct, t.change_pct[2]),
        ])
    }
}

/// The table.
#[derive(Clone, Debug, Serialize)]
pub struct Table2 {
    /// Schema name.
    pub schema: &'static str,
    /// Image size.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Diffuse bounces.
    pub bounces: u32,
    /// The accelerator's configuration.
    pub config: RtConfig,
    /// Rows in scene order, primary then diffuse.
    pub rows: Vec<Row>,
}

/// Runs both trees and both ray kinds over every scene. `progress` is told what runs.
pub fn table2(
    scenes: &[ReportScene<'_>],
    cfg: &RtConfig,
    bounces: u32,
    mut progress: impl FnMut(&str),
) -> Result<Table2, RtError> {
    let mut rows = Vec::new();
    let (mut width, mut height) = (0, 0);
    for s in scenes {
        width = s.camera.width();
        height = s.camera.height();
        let trees = [
            build_tree(TreeKind::Bvh2, s.triangles)?,
            build_tree(TreeKind::Mbvh4, s.triangles)?,
        ];
        for (rays, name) in [(RayMode::Primary, "primary"), (RayMode::Diffuse, "diffuse")] {
            let work = Workload {
                triangles: s.triangles,
                camera: &s.camera,
                rays,
                bounces,
                seed: 1,
                sample: s.sample,
                progress: None,
            };
            let mut figs = Vec::new();
            for t in &trees {
                progress(&format!("{} {name} {}", s.name, t.kind.name()));
                figs.push(Figures::of(&run(t, &work, cfg)?));
            }
            let mbvh4 = figs.pop().expect("two runs");
            let bvh = figs.pop().expect("two runs");
            rows.push(Row {
                scene: s.name.clone(),
                triangles: s.triangles.len(),
                rays: name,
                perf_change_pct: 100.0 * (mbvh4.mrps / bvh.mrps - 1.0),
                traffic_change_pct: 100.0 * (mbvh4.frame_dram_mb / bvh.frame_dram_mb - 1.0),
                energy_change_pct: 100.0 * (mbvh4.frame_mj / bvh.frame_mj - 1.0),
                ppa_change_pct: 100.0 * (mbvh4.mrps_per_mm2 / bvh.mrps_per_mm2 - 1.0),
                bvh,
                mbvh4,
                thesis: s.thesis_scene.and_then(|t| p4_row(t, name)).copied(),
                note: s.note.clone(),
            });
        }
    }
    Ok(Table2 {
        schema: "arbor.report.rtunit.v1",
        width,
        height,
        bounces,
        config: cfg.clone(),
        rows,
    })
}

fn pct(x: f64) -> String {
    format!("{x:+.0}%")
}

impl Table2 {
    /// The table as Markdown, with a legend and a summary.
    pub fn markdown(&self) -> String {
        let mut t = Table::new(&[
            "scene",
            "rays",
            "BVH MRPS",
            "MBVH4 MRPS",
            "perf",
            "thesis perf",
            "BVH MB",
            "MBVH4 MB",
            "traffic",
            "thesis traffic",
            "BVH mJ",
            "MBVH4 mJ",
            "energy",
            "thesis energy",
            "BVH MRPS/mm2",
            "MBVH4 MRPS/mm2",
            "perf/area",
            "thesis perf/area",
            "within 25% (perf, traffic, energy, perf/area)",
            "thesis MRPS",
            "thesis MB",
            "thesis mJ",
            "node MB (BVH, MBVH4)",
            "timed",
        ])
        .with_align(1, Align::Left)
        .with_align(18, Align::Left);
        for r in &self.rows {
            let (tp, tt, te, ta, tm, tb, tj) = match r.thesis {
                Some(t) => (
                    pct(t.change_pct[0]),
                    pct(t.change_pct[3]),
                    pct(t.change_pct[1]),
                    pct(t.change_pct[2]),
                    format!("{} / {}", t.bvh[0], t.mbvh4[0]),
                    format!("{} / {}", t.bvh[3], t.mbvh4[3]),
                    format!("{} / {}", t.bvh[1], t.mbvh4[1]),
                ),
                None => Default::default(),
            };
            let yes = |b: bool| if b { "yes" } else { "no" };
            let agree = match r.agrees() {
                Some(a) => a.map(yes).join(", "),
                None => "".into(),
            };
            let timed = if r.bvh.sample == 1 {
                "full frame".to_string()
            } else {
                format!("1/{} of the tiles", r.bvh.sample)
            };
            let f1 = |x: f64| format!("{x:.1}");
            t.push([
                r.scene.clone(),
                r.rays.to_string(),
                f1(r.bvh.mrps),
                f1(r.mbvh4.mrps),
                pct(r.perf_change_pct),
                tp,
                f1(r.bvh.frame_dram_mb),
                f1(r.mbvh4.frame_dram_mb),
                pct(r.traffic_change_pct),
                tt,
                f1(r.bvh.frame_mj),
                f1(r.mbvh4.frame_mj),
                pct(r.energy_change_pct),
                te,
                f1(r.bvh.mrps_per_mm2),
                f1(r.mbvh4.mrps_per_mm2),
                pct(r.ppa_change_pct),
                ta,
                agree,
                tm,
                tb,
                tj,
                format!(
                    "{:.1}, {:.1}",
                    r.bvh.node_bytes as f64 / 1e6,
                    r.mbvh4.node_bytes as f64 / 1e6
                ),
                timed,
            ]);
        }
        let mut m = t.markdown();
        let _ = writeln!(m);
        let _ = writeln!(
            m,
            "{}x{} pixels, diffuse paths of up to {} bounces after the primary hit, one sample per pixel; \
             {} MHz, {} TRV units of {} stacks, {} KB L1 per TRV, {} KB node and {} KB primitive caches, {}. \
             MB = 10^6 bytes per frame (sampled runs: the misses of the timed tiles' rays per timed pixel, times the frame's pixels). \
             Energy per frame and area at {} ({}; `sim::rtunit::energy`: FPUs and memory blocks counted as [P4] §3.2 does; \
             sampled runs: the run's energy per simulated ray times the frame's rays).",
            self.width,
            self.height,
            self.bounces,
            self.config.clock_mhz,
            self.config.trv_units,
            self.config.stacks_per_trv,
            self.config.l1_bytes >> 10,
            self.config.l2_bytes >> 10,
            self.config.prim_bytes >> 10,
            self.config.dram,
            self.config.energy_node.name(),
            self.config.energy.describe(),
        );
        let _ = writeln!(m);
        for r in &self.rows {
            if !r.note.is_empty() && r.rays == "primary" {
                let _ = writeln!(m, "- {}: {}", r.scene, r.note);
            }
        }
        let _ = writeln!(m);
        for r in &self.rows {
            let ok = r.mbvh4.frame_dram_mb < r.bvh.frame_dram_mb && r.mbvh4.mrps > r.bvh.mrps;
            let hits = r.bvh.hits_match_software && r.mbvh4.hits_match_software;
            let _ = writeln!(
                m,
                "- {} {}: MBVH4 {} less traffic and faster than BVH; deepest stack {} (BVH) and {} (MBVH4) of {}; hits equal the software tracer's: {}.",
                r.scene,
                r.rays,
                if ok { "has" } else { "does not have" },
                r.bvh.max_stack_depth,
                r.mbvh4.max_stack_depth,
                self.config.stack_entries,
                if hits { "yes" } else { "NO" }
            );
        }
        m
    }

    /// \[P4\] Table 1's analogue for the first scene with both ray kinds: area and power
    /// per unit of both accelerators, primary and diffuse, beside the thesis's (Fairy).
    pub fn table1_markdown(&self) -> String {
        let mut m = String::new();
        let Some(p) = self.rows.iter().find(|r| r.rays == "primary") else {
            return m;
        };
        let Some(d) = self
            .rows
            .iter()
            .find(|r| r.rays == "diffuse" && r.scene == p.scene)
        else {
            return m;
        };
        let _ = writeln!(
            m,
            "Area and power per unit on {} (ours; the thesis's figure in parentheses is Fairy's, [P4] Table 1): area in mm^2, mean power in mW with primary (P) and diffuse (D) rays.\n",
            p.scene
        );
        let headers: Vec<&str> = ["tree", "figure"]
            .into_iter()
            .chain(super::energy::UNITS.iter().copied())
            .chain(["sum"])
            .collect();
        let mut table = Table::new(&headers).with_align(1, Align::Left);
        for (t, (fp, fd)) in [(&p.bvh, &d.bvh), (&p.mbvh4, &d.mbvh4)]
            .into_iter()
            .enumerate()
        {
            let tree = if t == 0 { "BVH" } else { "MBVH4" };
            for (k, what) in ["area", "P. power", "D. power"].into_iter().enumerate() {
                let ours: Vec<f64> = match k {
                    0 => fp.units.iter().map(|u| u.1).collect(),
                    1 => fp.units.iter().map(|u| u.2).collect(),
                    _ => fd.units.iter().map(|u| u.2).collect(),
                };
                let thesis = crate::thesis::P4_TABLE1[t][k];
                let fmt = |x: f64| {
                    if k == 0 {
                        format!("{x:.2}")
                    } else {
                        format!("{x:.0}")
                    }
                };
                let sum: f64 = ours.iter().sum();
                table.push(
                    [tree.to_string(), what.to_string()]
                        .into_iter()
                        .chain(
                            ours.iter()
                                .zip(thesis.iter())
                                .map(|(o, th)| format!("{} ({th})", fmt(*o))),
                        )
                        .chain([format!("{} ({})", fmt(sum), thesis[6])]),
                );
            }
        }
        m += &table.markdown();
        m
    }

    /// The table as CSV, one line per row and tree.
    pub fn csv(&self) -> String {
        let mut c = Table::text(&[
            "scene",
            "triangles",
            "rays",
            "tree",
            "mrps",
            "frame_dram_mb",
            "frame_mj",
            "area_mm2",
            "mrps_per_mm2",
            "cycles",
            "rays_simulated",
            "sample",
            "bus_utilization",
            "max_stack_depth",
            "hits_match_software",
            "node_bytes",
            "visits_per_ray",
            "tests_per_ray",
            "l1_hit_rate",
            "node_hit_rate",
            "prim_hit_rate",
            "thesis_mrps",
            "thesis_mb",
            "thesis_mj",
            "thesis_mrps_per_mm2",
        ]);
        for r in &self.rows {
            for (tree, f, t) in [
                ("bvh2", &r.bvh, r.thesis.map(|t| t.bvh)),
                ("mbvh4", &r.mbvh4, r.thesis.map(|t| t.mbvh4)),
            ] {
                let (tm, tb, tj, ta) = t.map_or(Default::default(), |t| {
                    (
                        t[0].to_string(),
                        t[3].to_string(),
                        t[1].to_string(),
                        t[2].to_string(),
                    )
                });
                c.push([
                    r.scene.clone(),
                    r.triangles.to_string(),
                    r.rays.to_string(),
                    tree.to_string(),
                    format!("{:.3}", f.mrps),
                    format!("{:.4}", f.frame_dram_mb),
                    format!("{:.4}", f.frame_mj),
                    format!("{:.4}", f.area_mm2),
                    format!("{:.4}", f.mrps_per_mm2),
                    f.cycles.to_string(),
                    f.rays.to_string(),
                    f.sample.to_string(),
                    format!("{:.4}", f.bus_utilization),
                    f.max_stack_depth.to_string(),
                    f.hits_match_software.to_string(),
                    f.node_bytes.to_string(),
                    format!("{:.3}", f.visits_per_ray),
                    format!("{:.3}", f.tests_per_ray),
                    format!("{:.4}", f.hit_rates[0]),
                    format!("{:.4}", f.hit_rates[1]),
                    format!("{:.4}", f.hit_rates[2]),
                    tm,
                    tb,
                    tj,
                    ta,
                ]);
            }
        }
        c.csv()
    }
}

/// A sampled run's figures beside the whole frame's, for one scene, tree and ray kind.
#[derive(Clone, Debug, Serialize)]
pub struct SamplingCheck {
    /// Scene.
    pub scene: String,
    /// Tree.
    pub tree: TreeKind,
    /// Ray kind.
    pub rays: &'static str,
    /// Sampling factor.
    pub sample: u32,
    /// The whole frame.
    pub full: Figures,
    /// The sample.
    pub sampled: Figures,
}

impl SamplingCheck {
    /// Relative errors of the sample's MRPS and traffic against the whole frame's.
    pub fn errors(&self) -> [f64; 2] {
        [
            self.sampled.mrps / self.full.mrps - 1.0,
            self.sampled.frame_dram_mb / self.full.frame_dram_mb - 1.0,
        ]
    }
}

/// Runs `scene` sampled one in `sample` for both trees and both ray kinds and sets each
/// beside the full-frame figures of `table` (rows of the same scene, run with sample 1).
pub fn sampling_check(
    table: &Table2,
    scene: &ReportScene<'_>,
    sample: u32,
    cfg: &RtConfig,
    mut progress: impl FnMut(&str),
) -> Result<Vec<SamplingCheck>, RtError> {
    let mut out = Vec::new();
    let trees = [
        build_tree(TreeKind::Bvh2, scene.triangles)?,
        build_tree(TreeKind::Mbvh4, scene.triangles)?,
    ];
    for row in table
        .rows
        .iter()
        .filter(|r| r.scene == scene.name && r.bvh.sample == 1)
    {
        let rays = if row.rays == "primary" {
            RayMode::Primary
        } else {
            RayMode::Diffuse
        };
        let work = Workload {
            triangles: scene.triangles,
            camera: &scene.camera,
            rays,
            bounces: table.bounces,
            seed: 1,
            sample,
            progress: None,
        };
        for (t, full) in trees.iter().zip([&row.bvh, &row.mbvh4]) {
            progress(&format!(
                "{} {} {} sampled 1/{sample}",
                scene.name,
                row.rays,
                t.kind.name()
            ));
            out.push(SamplingCheck {
                scene: scene.name.clone(),
                tree: t.kind,
                rays: row.rays,
                sample,
                full: full.clone(),
                sampled: Figures::of(&run(t, &work, cfg)?),
            });
        }
    }
    Ok(out)
}

/// The sampling checks as a Markdown table.
pub fn sampling_markdown(checks: &[SamplingCheck]) -> String {
    let mut t = Table::new(&[
        "scene",
        "rays",
        "tree",
        "full MRPS",
        "sampled MRPS",
        "error",
        "full MB",
        "sampled MB",
        "error",
        "wall s (full, sampled)",
    ])
    .with_align(1, Align::Left)
    .with_align(2, Align::Left);
    for c in checks {
        let [em, et] = c.errors();
        t.push([
            c.scene.clone(),
            c.rays.to_string(),
            c.tree.name().to_string(),
            format!("{:.1}", c.full.mrps),
            format!("{:.1}", c.sampled.mrps),
            format!("{:+.1}%", 100.0 * em),
            format!("{:.2}", c.full.frame_dram_mb),
            format!("{:.2}", c.sampled.frame_dram_mb),
            format!("{:+.1}%", 100.0 * et),
            format!("{:.1}, {:.1}", c.full.wall_seconds, c.sampled.wall_seconds),
        ]);
    }
    t.markdown()
}
