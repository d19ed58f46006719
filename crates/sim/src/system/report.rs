//! The \[P2\] §6.4 reproduction: per scene the build and trace energy of every builder
//! with primary and diffuse rays, the Table VIII analogue (energy normalized to binned
//! SAH, the mean over scenes of each scene's ratio, all scenes and scenes over 500K
//! triangles), the Fig. 7 analogue (power at 30 FPS), and, beyond the thesis, the energy
//! per frame of an animated sequence under three tree-update policies. The command line
//! (`arbor report system`) loads the scenes and writes the files; everything else is here.

use outfile::table::Table;

use geom::Triangle;
use serde::Serialize;
use trace::PinholeCamera;

use super::{
    build_energy, build_energy_memo, trace_energy, trace_energy_memo, BuildEnergy, Builder,
    SimMemo, SystemConfig, SystemError, TraceEnergy, TraceJob, SCHEMA,
};
use crate::dram;
use crate::energy::{Flops, Fpu, UnitEnergy};
use crate::rtunit::RayMode;

/// Scenes of more than this many triangles are "large" (\[P2\] §6.4: ">500K").
pub const LARGE_TRIANGLES: usize = 500_000;

/// Frames per second of Fig. 7's power figures.
pub const FPS: f64 = 30.0;

/// A scene of the study.
pub struct SystemScene<'a> {
    /// Short name.
    pub name: String,
    /// Its triangles.
    pub triangles: &'a [Triangle],
    /// The camera (its size is the image size).
    pub camera: PinholeCamera,
    /// Time one in `sample` tile chunks of each frame (1: whole frames).
    pub sample: u32,
}

/// One scene's results.
#[derive(Clone, Debug, Serialize)]
pub struct SceneResult {
    /// Scene.
    pub scene: String,
    /// Triangles.
    pub triangles: usize,
    /// Per builder, in [`Builder::ALL`] order.
    pub builds: Vec<BuildEnergy>,
    /// Per ray kind (primary, diffuse) and builder.
    pub traces: Vec<TraceEnergy>,
}

impl SceneResult {
    /// The build of `b`.
    pub fn build(&self, b: Builder) -> &BuildEnergy {
        self.builds
            .iter()
            .find(|x| x.builder == b)
            .expect("every builder ran")
    }

    /// The trace of `b`'s tree with `rays`.
    pub fn trace(&self, b: Builder, rays: RayMode) -> &TraceEnergy {
        self.traces
            .iter()
            .find(|x| x.builder == b && x.rays == rays)
            .expect("every builder and ray kind ran")
    }

    /// Build plus trace energy of a frame, mJ.
    pub fn total_mj(&self, b: Builder, rays: RayMode) -> f64 {
        self.build(b).mj + self.trace(b, rays).frame_mj
    }

    /// [`Self::total_mj`] with the DRAM counted above idle.
    pub fn total_mj_above_idle(&self, b: Builder, rays: RayMode) -> f64 {
        self.build(b).mj_above_idle() + self.trace(b, rays).frame_mj_above_idle
    }

    /// [`Self::total_mj`] with the memory's idle energy charged while streamed units
    /// compute.
    pub fn total_mj_with_dram_wait(&self, b: Builder, rays: RayMode) -> f64 {
        self.build(b).mj_with_dram_wait() + self.trace(b, rays).frame_mj
    }

    /// Whether the scene counts as large.
    pub fn large(&self) -> bool {
        self.triangles > LARGE_TRIANGLES
    }
}

/// Runs every builder over the scene and traces each tree with both ray kinds.
/// `progress` is told what runs.
pub fn scene_result(
    s: &SystemScene<'_>,
    cfg: &SystemConfig,
    progress: impl FnMut(&str),
) -> Result<SceneResult, SystemError> {
    scene_result_memo(s, cfg, &mut SimMemo::default(), progress)
}

/// [`scene_result`] reusing the cycle-level runs of `memo`, which belongs to this scene.
pub fn scene_result_memo(
    s: &SystemScene<'_>,
    cfg: &SystemConfig,
    memo: &mut SimMemo,
    mut progress: impl FnMut(&str),
) -> Result<SceneResult, SystemError> {
    if s.triangles.is_empty() {
        return Err(SystemError::Config(format!("{}: no triangles", s.name)));
    }
    let aabbs = bvh::triangle_aabbs(s.triangles);
    let mut builds = Vec::new();
    let mut traces = Vec::new();
    for b in Builder::ALL {
        progress(&format!("{} build {}", s.name, b.name()));
        let (e, tree) = build_energy_memo(b, &aabbs, cfg, memo)?;
        builds.push(e);
        for rays in [RayMode::Primary, RayMode::Diffuse] {
            progress(&format!("{} trace {} {}", s.name, b.name(), ray_name(rays)));
            let job = TraceJob {
                builder: b,
                triangles: s.triangles,
                camera: &s.camera,
                rays,
                sample: s.sample,
            };
            traces.push(trace_energy_memo(&job, tree.clone(), cfg, memo)?);
        }
    }
    Ok(SceneResult {
        scene: s.name.clone(),
        triangles: s.triangles.len(),
        builds,
        traces,
    })
}

/// `primary` or `diffuse`.
pub fn ray_name(r: RayMode) -> &'static str {
    match r {
        RayMode::Primary => "primary",
        RayMode::Diffuse => "diffuse",
    }
}

/// A row of the Table VIII analogue.
#[derive(Clone, Debug, Serialize)]
pub struct Table8Row {
    /// `primary` or `diffuse`.
    pub rays: &'static str,
    /// `all` or `large`.
    pub scenes: &'static str,
    /// Builder name.
    pub builder: &'static str,
    /// Scenes averaged.
    pub count: usize,
    /// Build energy relative to binned SAH (1.0 = equal), mean over the scenes.
    pub build: f64,
    /// Trace energy relative to binned SAH's tree.
    pub trace: f64,
    /// Build plus trace relative to binned SAH's.
    pub total: f64,
    /// The same three with the DRAM energy counted above an idle memory's (\[P2\] §6.2's
    /// convention for memory power).
    pub above_idle: [f64; 3],
    /// The same three with the idle memory's energy charged while streamed units compute
    /// (`BuildEnergy::dram_wait_mj`; binned SAH's FPU-bound build time, not its
    /// transfer time, then sets its DRAM's standby time).
    pub with_dram_wait: [f64; 3],
    /// The standard errors of `build`, `trace` and `total` from the traces' sampling
    /// (builds are not sampled): per scene, the error of the ratio of the builder's run to
    /// binned SAH's over the same timed chunks
    /// (`rtunit::sampling::paired_ratio_rel_se`), or where their measurement windows do
    /// not pair up, the delta method with both runs' errors
    /// (`TraceEnergy::frame_mj_rel_se`) taken as independent (an upper estimate); then
    /// over the mean of the scenes. Zeros for whole frames.
    pub sampling_se: [f64; 3],
    /// \[P2\] Table VIII's build, trace and total (fractions).
    pub thesis: Option<[f64; 3]>,
    /// Binned SAH's build energy over its build plus trace energy, mean over the scenes:
    /// how much of the reference system's energy the builder choice can save.
    pub sah_build_share: f64,
    /// The same share as \[P2\]'s row implies: a total `X` of build `B` and trace `T`
    /// ratios with share `s` is `X = s B + (1 - s) T`, so `s = (T - X) / (T - B)`
    /// (exact for a ratio of sums; Table VIII's means of per-scene ratios make it an
    /// estimate). None for binned SAH, whose ratios are all 1.
    pub thesis_build_share: Option<f64>,
    /// Our build and trace ratios weighted with the thesis's share,
    /// `s B + (1 - s) T`: the total we would report if our scenes and viewpoints had
    /// \[P2\]'s balance of build and trace energy.
    pub total_at_thesis_share: Option<f64>,
}

/// The build share `(T - X) / (T - B)` implied by build, trace and total ratios
/// `[B, T, X]`, when it is defined (`T != B`).
pub fn implied_build_share(r: [f64; 3]) -> Option<f64> {
    let [b, t, x] = r;
    ((t - b).abs() > 1e-9).then(|| (t - x) / (t - b))
}

/// The Table VIII analogue: for each ray kind and scene set (all, large; a set without
/// scenes is left out), each builder's mean over the scenes of its energy over binned
/// SAH's on the same scene.
pub fn table8(results: &[SceneResult]) -> Vec<Table8Row> {
    let mut rows = Vec::new();
    for rays in [RayMode::Primary, RayMode::Diffuse] {
        for (set, large_only) in [("all", false), ("large", true)] {
            let scenes: Vec<&SceneResult> = results
                .iter()
                .filter(|r| !large_only || r.large())
                .collect();
            if scenes.is_empty() {
                continue;
            }
            let mean = |f: &dyn Fn(&SceneResult) -> f64| {
                scenes.iter().map(|s| f(s)).sum::<f64>() / scenes.len() as f64
            };
            let sah = Builder::BinnedSah;
            let sah_build_share = mean(&|s| s.build(sah).mj / s.total_mj(sah, rays));
            for b in Builder::ALL {
                let build = mean(&|s| s.build(b).mj / s.build(sah).mj);
                let trace = mean(&|s| s.trace(b, rays).frame_mj / s.trace(sah, rays).frame_mj);
                let thesis = crate::thesis::p2_table8(ray_name(rays), set, b.name());
                let thesis_build_share = thesis.and_then(implied_build_share);
                // Per scene: the variances of the trace and total ratios.
                let var = |s: &SceneResult| -> [f64; 2] {
                    if b == sah {
                        return [0.0; 2]; // the same run over itself
                    }
                    let (tb, tr) = (s.trace(b, rays), s.trace(sah, rays));
                    let trace = tb.frame_mj / tr.frame_mj;
                    let total = s.total_mj(b, rays) / s.total_mj(sah, rays);
                    let paired = |fixed_b: f64, fixed_r: f64| {
                        crate::rtunit::sampling::paired_ratio_rel_se(
                            &tb.window_mj,
                            &tr.window_mj,
                            fixed_b * tb.window_mj.iter().map(|w| w.1).sum::<f64>() / tb.frame_mj,
                            fixed_r * tr.window_mj.iter().map(|w| w.1).sum::<f64>() / tr.frame_mj,
                            tb.sample,
                        )
                    };
                    if let (Some(t), Some(x)) =
                        (paired(0.0, 0.0), paired(s.build(b).mj, s.build(sah).mj))
                    {
                        return [(trace * t).powi(2), (total * x).powi(2)];
                    }
                    let rel_b = tb.frame_mj_rel_se * tb.frame_mj;
                    let rel_r = tr.frame_mj_rel_se * tr.frame_mj;
                    [
                        trace.powi(2) * (tb.frame_mj_rel_se.powi(2) + tr.frame_mj_rel_se.powi(2)),
                        total.powi(2)
                            * ((rel_b / s.total_mj(b, rays)).powi(2)
                                + (rel_r / s.total_mj(sah, rays)).powi(2)),
                    ]
                };
                let n = scenes.len() as f64;
                let se = |k: usize| scenes.iter().map(|s| var(s)[k]).sum::<f64>().sqrt() / n;
                rows.push(Table8Row {
                    rays: ray_name(rays),
                    scenes: set,
                    builder: b.name(),
                    count: scenes.len(),
                    build,
                    trace,
                    total: mean(&|s| s.total_mj(b, rays) / s.total_mj(sah, rays)),
                    above_idle: [
                        mean(&|s| s.build(b).mj_above_idle() / s.build(sah).mj_above_idle()),
                        mean(&|s| {
                            s.trace(b, rays).frame_mj_above_idle
                                / s.trace(sah, rays).frame_mj_above_idle
                        }),
                        mean(&|s| {
                            s.total_mj_above_idle(b, rays) / s.total_mj_above_idle(sah, rays)
                        }),
                    ],
                    with_dram_wait: [
                        mean(&|s| {
                            s.build(b).mj_with_dram_wait() / s.build(sah).mj_with_dram_wait()
                        }),
                        trace,
                        mean(&|s| {
                            s.total_mj_with_dram_wait(b, rays)
                                / s.total_mj_with_dram_wait(sah, rays)
                        }),
                    ],
                    sampling_se: [0.0, se(0), se(1)],
                    thesis,
                    sah_build_share,
                    thesis_build_share,
                    total_at_thesis_share: thesis_build_share
                        .map(|s| s * build + (1.0 - s) * trace),
                });
            }
        }
    }
    rows
}

/// Fig. 7's bars: per builder, per scene, (build, trace) power in mW.
pub type Fig7Series = Vec<(&'static str, Vec<[f64; 2]>)>;

/// The whole report.
#[derive(Clone, Debug, Serialize)]
pub struct SystemReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The modelled system.
    pub config: SystemConfig,
    /// Image size.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Per scene.
    pub scenes: Vec<SceneResult>,
    /// The Table VIII analogue.
    pub table8: Vec<Table8Row>,
    /// The animation study, per animated scene.
    pub animation: Vec<AnimationResult>,
}

impl SystemReport {
    /// The report over `scenes` and `animation` results.
    pub fn new(
        cfg: &SystemConfig,
        width: u32,
        height: u32,
        scenes: Vec<SceneResult>,
        animation: Vec<AnimationResult>,
    ) -> Self {
        Self {
            schema: SCHEMA,
            config: cfg.clone(),
            width,
            height,
            table8: table8(&scenes),
            scenes,
            animation,
        }
    }

    /// Table VIII as Markdown, ours beside the thesis's.
    pub fn table8_markdown(&self) -> String {
        let mut t = Table::text(&[
            "rays",
            "scenes",
            "n",
            "builder",
            "build",
            "thesis",
            "trace",
            "thesis",
            "total",
            "thesis",
            "total diff (pp)",
            "above idle: build, trace, total",
            "DRAM wait: build, total",
        ]);
        // A sampled figure carries its standard error from sampling.
        let pm = |x: f64, se: f64| {
            if se >= 0.0005 {
                format!("{} ± {:.0}", pct(x), 100.0 * se)
            } else {
                pct(x)
            }
        };
        for r in &self.table8 {
            let th = |k: usize| r.thesis.map_or("-".into(), |t| pct(t[k]));
            t.push([
                r.rays.to_string(),
                r.scenes.to_string(),
                r.count.to_string(),
                r.builder.to_string(),
                pct(r.build),
                th(0),
                pm(r.trace, r.sampling_se[1]),
                th(1),
                pm(r.total, r.sampling_se[2]),
                th(2),
                r.thesis
                    .map_or("-".into(), |t| format!("{:+.0}", 100.0 * (r.total - t[2]))),
                format!(
                    "{}, {}, {}",
                    pct(r.above_idle[0]),
                    pct(r.above_idle[1]),
                    pct(r.above_idle[2])
                ),
                format!("{}, {}", pct(r.with_dram_wait[0]), pct(r.with_dram_wait[2])),
            ]);
        }
        t.markdown()
    }

    /// The balance of build and trace energy behind each Table VIII total, ours beside
    /// the thesis's implied one, and our ratios re-weighted with the thesis's balance, as
    /// Markdown.
    pub fn balance_markdown(&self) -> String {
        let mut t = Table::text(&[
            "rays",
            "scenes",
            "builder",
            "binned SAH build share",
            "thesis (implied)",
            "total",
            "at thesis share",
            "thesis total",
        ]);
        let opt = |x: Option<f64>| x.map_or("-".into(), pct);
        for r in self
            .table8
            .iter()
            .filter(|r| r.builder != Builder::BinnedSah.name())
        {
            t.push([
                r.rays.to_string(),
                r.scenes.to_string(),
                r.builder.to_string(),
                pct(r.sah_build_share),
                opt(r.thesis_build_share),
                pct(r.total),
                opt(r.total_at_thesis_share),
                opt(r.thesis.map(|t| t[2])),
            ]);
        }
        t.markdown()
    }

    /// Table VIII as CSV.
    pub fn table8_csv(&self) -> String {
        let mut c = Table::text(&[
            "rays",
            "scenes",
            "count",
            "builder",
            "build",
            "trace",
            "total",
            "thesis_build",
            "thesis_trace",
            "thesis_total",
            "build_above_idle",
            "trace_above_idle",
            "total_above_idle",
            "sah_build_share",
            "thesis_build_share",
            "total_at_thesis_share",
            "build_with_dram_wait",
            "total_with_dram_wait",
            "trace_sampling_se",
            "total_sampling_se",
        ]);
        for r in &self.table8 {
            let t = |k: usize| r.thesis.map_or(String::new(), |t| format!("{:.2}", t[k]));
            let o = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.4}"));
            let f = |x: f64| format!("{x:.4}");
            c.push([
                r.rays.to_string(),
                r.scenes.to_string(),
                r.count.to_string(),
                r.builder.to_string(),
                f(r.build),
                f(r.trace),
                f(r.total),
                t(0),
                t(1),
                t(2),
                f(r.above_idle[0]),
                f(r.above_idle[1]),
                f(r.above_idle[2]),
                f(r.sah_build_share),
                o(r.thesis_build_share),
                o(r.total_at_thesis_share),
                f(r.with_dram_wait[0]),
                f(r.with_dram_wait[2]),
                f(r.sampling_se[1]),
                f(r.sampling_se[2]),
            ]);
        }
        c.csv()
    }

    /// Per scene and builder: build figures and both traces, as CSV.
    pub fn scenes_csv(&self) -> String {
        let mut c = Table::text(&[
            "scene",
            "triangles",
            "builder",
            "sah",
            "build_ms",
            "build_dram_mb",
            "build_mj",
            "build_dram_mj",
            "build_dram_wait_mj",
            "primary_mj",
            "diffuse_mj",
            "primary_mrps",
            "diffuse_mrps",
            "primary_dram_mb",
            "diffuse_dram_mb",
            "sample",
        ]);
        for s in &self.scenes {
            for b in Builder::ALL {
                let e = s.build(b);
                let (p, d) = (s.trace(b, RayMode::Primary), s.trace(b, RayMode::Diffuse));
                c.push([
                    s.scene.clone(),
                    s.triangles.to_string(),
                    b.name().to_string(),
                    format!("{:.3}", e.sah),
                    format!("{:.4}", e.ms),
                    format!("{:.3}", e.dram_bytes as f64 / 1e6),
                    format!("{:.4}", e.mj),
                    format!("{:.4}", e.dram_mj),
                    format!("{:.4}", e.dram_wait_mj),
                    format!("{:.4}", p.frame_mj),
                    format!("{:.4}", d.frame_mj),
                    format!("{:.2}", p.mrps),
                    format!("{:.2}", d.mrps),
                    format!("{:.2}", p.frame_dram_mb),
                    format!("{:.2}", d.frame_dram_mb),
                    p.sample.to_string(),
                ]);
            }
        }
        c.csv()
    }

    /// Fig. 7's data for `rays`: per scene (label) and builder, (build, trace) power in mW
    /// at [`FPS`].
    pub fn fig7(&self, rays: RayMode) -> (Vec<String>, Fig7Series) {
        let labels = self.scenes.iter().map(|s| s.scene.clone()).collect();
        let series = Builder::ALL
            .iter()
            .map(|&b| {
                (
                    b.name(),
                    self.scenes
                        .iter()
                        .map(|s| [s.build(b).mj * FPS, s.trace(b, rays).frame_mj * FPS])
                        .collect(),
                )
            })
            .collect();
        (labels, series)
    }

    /// Per scene and builder, the build and trace energy in mJ and power at 30 FPS, as
    /// Markdown.
    pub fn scenes_markdown(&self) -> String {
        let mut t = Table::text(&[
            "scene",
            "triangles",
            "builder",
            "SAH",
            "build ms",
            "build MB",
            "build mJ",
            "primary mJ",
            "diffuse mJ",
            "primary mW @30",
            "diffuse mW @30",
        ]);
        for s in &self.scenes {
            for b in Builder::ALL {
                let e = s.build(b);
                let (p, d) = (
                    s.total_mj(b, RayMode::Primary),
                    s.total_mj(b, RayMode::Diffuse),
                );
                t.push([
                    s.scene.clone(),
                    s.triangles.to_string(),
                    b.name().to_string(),
                    format!("{:.1}", e.sah),
                    format!("{:.2}", e.ms),
                    format!("{:.1}", e.dram_bytes as f64 / 1e6),
                    format!("{:.2}", e.mj),
                    format!("{:.2}", s.trace(b, RayMode::Primary).frame_mj),
                    format!("{:.2}", s.trace(b, RayMode::Diffuse).frame_mj),
                    format!("{:.0}", p * FPS),
                    format!("{:.0}", d * FPS),
                ]);
            }
        }
        t.markdown()
    }

    /// The animation study as Markdown.
    pub fn animation_markdown(&self) -> String {
        let mut t = Table::text(&[
            "scene",
            "rays",
            "policy",
            "frames",
            "rebuilds",
            "build mJ/frame",
            "refit mJ/frame",
            "trace mJ/frame",
            "total mJ/frame",
            "vs rebuild",
            "worst SAH ratio",
        ]);
        for a in &self.animation {
            for rays in &a.rays {
                let base = rays
                    .policies
                    .iter()
                    .find(|p| p.policy == Policy::Rebuild)
                    .map_or(f64::NAN, |p| p.mean_mj());
                for p in &rays.policies {
                    let n = p.frames.len().max(1) as f64;
                    let sum =
                        |f: &dyn Fn(&FrameEnergy) -> f64| p.frames.iter().map(f).sum::<f64>() / n;
                    t.push([
                        a.scene.to_string(),
                        rays.rays.to_string(),
                        p.policy.name().to_string(),
                        p.frames.len().to_string(),
                        p.frames.iter().filter(|f| f.rebuilt).count().to_string(),
                        format!("{:.3}", sum(&|f| f.build_mj)),
                        format!("{:.3}", sum(&|f| f.refit_mj)),
                        format!("{:.3}", sum(&|f| f.trace_mj)),
                        format!("{:.3}", p.mean_mj()),
                        pct(p.mean_mj() / base),
                        format!(
                            "{:.2}",
                            p.frames.iter().map(|f| f.sah_ratio).fold(1.0, f64::max)
                        ),
                    ]);
                }
            }
        }
        t.markdown()
    }
}

fn pct(x: f64) -> String {
    format!("{:.0}%", 100.0 * x)
}

/// How a tree follows an animation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Policy {
    /// MergeTree rebuilds every frame.
    Rebuild,
    /// Built once, refitted every later frame.
    Refit,
    /// Refitted, and rebuilt in a frame whose refitted SAH the tracker
    /// (`bvh::RefitTracker`) finds above its threshold.
    RefitAdvised,
}

impl Policy {
    /// All three.
    pub const ALL: [Policy; 3] = [Policy::Rebuild, Policy::Refit, Policy::RefitAdvised];

    /// Name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Policy::Rebuild => "rebuild",
            Policy::Refit => "refit",
            Policy::RefitAdvised => "refit+advised-rebuild",
        }
    }
}

/// One frame under a policy.
#[derive(Clone, Debug, Serialize)]
pub struct FrameEnergy {
    /// Frame index.
    pub frame: usize,
    /// The tree was built this frame.
    pub rebuilt: bool,
    /// MergeTree energy this frame, mJ.
    pub build_mj: f64,
    /// Refit unit energy this frame, mJ.
    pub refit_mj: f64,
    /// Tracing energy, mJ.
    pub trace_mj: f64,
    /// SAH of the frame's tree over the SAH of a fresh build of that frame.
    pub sah_ratio: f64,
}

/// A policy over the sequence.
#[derive(Clone, Debug, Serialize)]
pub struct PolicyResult {
    /// The policy.
    pub policy: Policy,
    /// Per frame.
    pub frames: Vec<FrameEnergy>,
}

impl PolicyResult {
    /// Mean energy per frame, mJ.
    pub fn mean_mj(&self) -> f64 {
        self.frames
            .iter()
            .map(|f| f.build_mj + f.refit_mj + f.trace_mj)
            .sum::<f64>()
            / self.frames.len().max(1) as f64
    }
}

/// The policies for one ray kind.
#[derive(Clone, Debug, Serialize)]
pub struct AnimationRays {
    /// `primary` or `diffuse`.
    pub rays: &'static str,
    /// Per policy.
    pub policies: Vec<PolicyResult>,
}

/// The study of one animated scene.
#[derive(Clone, Debug, Serialize)]
pub struct AnimationResult {
    /// Scene.
    pub scene: String,
    /// Triangles per frame.
    pub triangles: usize,
    /// The scene times of the frames, seconds.
    pub times: Vec<f32>,
    /// Rebuild threshold of the tracker.
    pub threshold: f64,
    /// Per ray kind.
    pub rays: Vec<AnimationRays>,
}

/// An animated scene: the same triangles (same order) at each frame's time.
pub struct AnimationScene {
    /// Short name.
    pub name: String,
    /// Per frame, the triangles.
    pub frames: Vec<Vec<Triangle>>,
    /// The scene time of each frame.
    pub times: Vec<f32>,
    /// The camera.
    pub camera: PinholeCamera,
    /// Time one in `sample` tile chunks.
    pub sample: u32,
}

/// FLOPs of refitting `tree` from its primitives' boxes: the union of a leaf's
/// primitive boxes (6 min/max per primitive after the first) and of each inner node's two
/// child boxes (6).
pub fn refit_flops(tree: &bvh::Bvh2) -> Flops {
    let prims = tree.prim_indices.len() as f64;
    let leaves = tree
        .nodes
        .iter()
        .flat_map(|n| n.children)
        .filter(|c| c.is_leaf())
        .count() as f64;
    Flops {
        adds: 6.0 * (prims - leaves).max(0.0) + 6.0 * tree.nodes.len() as f64,
        muls: 0.0,
    }
}

/// Bytes the refit unit reads per primitive: its box (32 B, the input MergeTree reads
/// too, \[P2\] §4.2) and its leaf-table entry (4 B).
pub const REFIT_PRIM_BYTES: u64 = 36;

/// Bytes of a node's topology (two 4-byte child references), which the refit unit keeps
/// in an array of its own so it writes whole nodes without reading them.
pub const REFIT_TOPOLOGY_BYTES: u64 = 8;

/// Datapath width of the refit unit: one box union (6 min/max) per cycle.
pub const REFIT_FPUS: f64 = 6.0;

/// The refit unit's energy for `tree` (Arbor's model, from the same components as the
/// builders': its FLOPs on the node's FPUs, its traffic as streams: every primitive's box
/// and leaf-table entry and every node's topology read, every 64-byte node written).
pub fn refit_energy(tree: &bvh::Bvh2, cfg: &SystemConfig) -> Result<Vec<UnitEnergy>, SystemError> {
    let read = tree.prim_indices.len() as u64 * REFIT_PRIM_BYTES
        + tree.nodes.len() as u64 * REFIT_TOPOLOGY_BYTES;
    let write = tree.nodes.len() as u64 * 64;
    let flops = refit_flops(tree);
    let (mem, dram_s) = dram::stream::streaming(&cfg.dram, read, write)?;
    let seconds = dram_s.max(flops.total() / (REFIT_FPUS * cfg.unit_clock_mhz as f64 * 1e6));
    Ok(vec![
        UnitEnergy::new(
            "refit FPUs",
            0.0,
            flops.energy_pj(&Fpu::at(cfg.node, cfg.energy.fpu)) * 1e-9,
            0.0,
            seconds,
        ),
        UnitEnergy::dram(&mem, seconds, cfg.energy.dram),
    ])
}

/// A policy's tree in one frame.
#[derive(Clone)]
struct PolicyFrame {
    tree: bvh::Bvh2,
    rebuilt: bool,
    build_mj: f64,
    refit_mj: f64,
    sah: f64,
}

/// Runs the three policies over `scene`'s frames with MergeTree (plain HLBVH) as the
/// builder, for primary and diffuse rays. A frame's tree under each policy is traced once
/// even when policies share it.
pub fn animation_study(
    scene: &AnimationScene,
    cfg: &SystemConfig,
    threshold: f64,
    mut progress: impl FnMut(&str),
) -> Result<AnimationResult, SystemError> {
    let n = scene.frames.first().map_or(0, |f| f.len());
    if scene.frames.is_empty() || n == 0 {
        return Err(SystemError::Config(format!("{}: no frames", scene.name)));
    }
    if scene.frames.iter().any(|f| f.len() != n) {
        return Err(SystemError::Config(format!(
            "{}: the frames have different triangle counts (refitting needs one topology)",
            scene.name
        )));
    }
    // Per policy and frame.
    let mut trees: Vec<Vec<PolicyFrame>> = vec![Vec::new(); 3];
    for (k, tris) in scene.frames.iter().enumerate() {
        progress(&format!("{} frame {k}: build", scene.name));
        let aabbs = bvh::triangle_aabbs(tris);
        let (fresh_e, fresh) = build_energy(Builder::Hlbvh, &aabbs, cfg)?;
        let rebuilt = |refit_mj| PolicyFrame {
            tree: fresh.clone(),
            rebuilt: true,
            build_mj: fresh_e.mj,
            refit_mj,
            sah: fresh.sah(),
        };
        for (p, policy) in Policy::ALL.iter().enumerate() {
            let prev = trees[p].last().map(|t| t.tree.clone());
            let entry = match (policy, prev) {
                (Policy::Rebuild, _) | (_, None) => rebuilt(0.0),
                (_, Some(mut t)) => {
                    bvh::refit_bvh2(&mut t, &aabbs)
                        .map_err(|e| SystemError::Config(e.to_string()))?;
                    let refit_mj: f64 = refit_energy(&t, cfg)?.iter().map(|u| u.total_mj).sum();
                    // The tracker compares with the SAH of the policy's last build.
                    let base = trees[p]
                        .iter()
                        .rev()
                        .find(|e| e.rebuilt)
                        .map_or(fresh.sah(), |e| e.sah);
                    let advised = *policy == Policy::RefitAdvised
                        && bvh::RefitTracker::new(base, threshold)
                            .map_err(|e| SystemError::Config(e.to_string()))?
                            .record_bvh2(&t)
                            .rebuild_advised;
                    if advised {
                        rebuilt(refit_mj)
                    } else {
                        PolicyFrame {
                            sah: t.sah(),
                            tree: t,
                            rebuilt: false,
                            build_mj: 0.0,
                            refit_mj,
                        }
                    }
                }
            };
            trees[p].push(entry);
        }
    }
    let mut out = Vec::new();
    for rays in [RayMode::Primary, RayMode::Diffuse] {
        let mut policies: Vec<PolicyResult> = Policy::ALL
            .iter()
            .map(|&policy| PolicyResult {
                policy,
                frames: Vec::new(),
            })
            .collect();
        for (k, tris) in scene.frames.iter().enumerate() {
            let mut traced: Vec<(usize, f64)> = Vec::new();
            let fresh_sah = trees[0][k].sah;
            for (p, policy) in Policy::ALL.iter().enumerate() {
                let t = &trees[p][k];
                let same = traced.iter().find(|&&(q, _)| trees[q][k].tree == t.tree);
                let mj = match same {
                    Some(&(_, mj)) => mj,
                    None => {
                        progress(&format!(
                            "{} frame {k}: trace {} {}",
                            scene.name,
                            policy.name(),
                            ray_name(rays)
                        ));
                        trace_energy(
                            Builder::Hlbvh,
                            t.tree.clone(),
                            tris,
                            &scene.camera,
                            rays,
                            scene.sample,
                            cfg,
                        )?
                        .frame_mj
                    }
                };
                traced.push((p, mj));
                policies[p].frames.push(FrameEnergy {
                    frame: k,
                    rebuilt: t.rebuilt,
                    build_mj: t.build_mj,
                    refit_mj: t.refit_mj,
                    trace_mj: mj,
                    sah_ratio: t.sah / fresh_sah,
                });
            }
        }
        out.push(AnimationRays {
            rays: ray_name(rays),
            policies,
        });
    }
    Ok(AnimationResult {
        scene: scene.name.clone(),
        triangles: n,
        times: scene.times.clone(),
        threshold,
        rays: out,
    })
}
