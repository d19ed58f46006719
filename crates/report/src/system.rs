//! \[P2\] §6.4's system energy per frame (a BVH built by each of four builders, then a
//! frame traced by the \[P4\] BVH accelerator, on a 28 nm mobile SoC with the 25.6 GB/s
//! memory), and the animation study beyond the thesis. The model and the tables are
//! `sim::system`; [`run`] loads the scenes, runs them (two at a time on two cores) and
//! writes to [`SystemOptions::out`]:
//! - `table8.md` / `table8.csv`: the Table VIII analogue beside the thesis's;
//! - `scenes.md` / `scenes.csv`: per scene and builder, build and trace energy;
//! - `fig7-primary.svg` / `fig7-diffuse.svg`: the Fig. 7 analogue (power at 30 FPS,
//!   build and trace stacked, four builders per scene);
//! - `animation.md`: energy per frame of the animated scenes under three policies;
//! - `system.json`: the whole document (`arbor.report.system.v1`);
//! - `report.md`: all of it.

use crate::fs::write_file;
use crate::progress::Progress;
use crate::scenes::{existing, load_traced, mesh_boxes, short_name, view_camera};
use crate::svg::stacked_bar_svg;
use anyhow::Context;
use rayon::prelude::*;
use sim::energy::{Conventions, Node};
use sim::rtunit::RayMode;
use sim::system::report::{
    animation_study, scene_result, AnimationResult, AnimationScene, SceneResult, SystemReport,
    SystemScene, LARGE_TRIANGLES,
};
use sim::system::SystemConfig;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use trace::PinholeCamera;

/// The modelled SoC and frame of the system studies ([P2] §6.4), shared by the system and
/// sensitivity reports.
#[derive(Clone, Debug)]
pub struct SocOptions {
    /// Image width ([P2] 6.4: 1280).
    pub width: u32,
    /// Image height ([P2] 6.4: 720).
    pub height: u32,
    /// Process node of the on-chip figures ([P2] 6.4: `28nm`).
    pub node: String,
    /// Energy conventions.
    pub energy: Conventions,
    /// Memory system ([P2] 6.4: `lpddr3-1600-2x64`, the 25.6 GB/s system).
    pub dram: String,
}

impl Default for SocOptions {
    fn default() -> Self {
        SocOptions {
            width: 1280,
            height: 720,
            node: "28nm".into(),
            energy: Conventions::default(),
            dram: "lpddr3-1600-2x64".into(),
        }
    }
}

impl SocOptions {
    /// The system configuration of these options (a bad node or memory name is an error
    /// here, before anything runs).
    pub fn config(&self) -> anyhow::Result<SystemConfig> {
        let cfg = SystemConfig::default().with(Node::parse(&self.node)?, self.energy, &self.dram);
        sim::dram::stream::streaming(&cfg.dram, 0, 0)?;
        Ok(cfg)
    }
}

/// Options of the system report.
#[derive(Clone, Debug)]
pub struct SystemOptions {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Static scenes (mesh files or procedural specs; `["none"]`: none). Default: the
    /// shared real scenes that exist (others skipped with a warning) and two large
    /// procedural scenes.
    pub scenes: Option<Vec<String>>,
    /// Animated scenes of the policy study (`["none"]`: no study). Default: the shared
    /// horse gallop (keyframes) where it exists and a procedural cloth.
    pub animated: Option<Vec<String>>,
    /// Folder of the shared real scenes.
    pub scene_dir: PathBuf,
    /// The SoC and frame.
    pub soc: SocOptions,
    /// Diffuse bounces ([P2] 6.4: three).
    pub bounces: u32,
    /// Time one in N chunks of 16 pixel tiles of each frame (1: whole frames).
    pub sample: u32,
    /// Frames of each animated scene, spread evenly over its timeline.
    pub frames: u32,
    /// SAH ratio above which the refit tracker advises a rebuild.
    pub threshold: f64,
}

impl Default for SystemOptions {
    fn default() -> Self {
        SystemOptions {
            out: "arbor-out/report-system".into(),
            scenes: None,
            animated: None,
            scene_dir: crate::scenes::shared_scenes(),
            soc: SocOptions::default(),
            bounces: 3,
            sample: 8,
            frames: 8,
            threshold: bvh::RefitTracker::DEFAULT_THRESHOLD,
        }
    }
}

/// Real scenes of the default list (files under `scene_dir`).
const REAL: [&str; 5] = [
    "bunny.ply",
    "sibenik.ply",
    "crytek-sponza.ply",
    "conference.ply",
    "dragon.ply",
];

/// Procedural scenes of the default list: large scenes beside Dragon (\[P2\]'s large
/// scenes are 0.75M to 1.6M triangles).
const PROCEDURAL: [&str; 2] = ["proc:hairball?n=1000000", "proc:city?n=1500000"];

/// Animated scenes of the default list.
const ANIMATED: [&str; 2] = ["horse-gallop", "proc:cloth?n=92000"];

/// Runs the system report: writes its files and returns the document.
pub fn run(a: &SystemOptions, ui: &dyn Progress) -> anyhow::Result<SystemReport> {
    anyhow::ensure!(a.sample >= 1, "--sample must be at least 1");
    anyhow::ensure!((1..=1000).contains(&a.frames), "--frames must be 1 to 1000");
    anyhow::ensure!(
        a.threshold.is_finite() && a.threshold > 0.0,
        "--threshold must be a positive number"
    );
    let cfg = SystemConfig {
        bounces: a.bounces,
        ..a.soc.config()?
    };
    let specs = static_scene_specs(a.scenes.as_deref(), &a.scene_dir, ui);
    let anim_specs = animation_specs(a, ui);
    anyhow::ensure!(
        !specs.is_empty() || !anim_specs.is_empty(),
        "no scenes to report on"
    );
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut loaded = Vec::new();
    for spec in &specs {
        loaded.push(load_static(spec, a.soc.width, a.soc.height, ui)?);
    }
    let mut animated = Vec::new();
    for spec in &anim_specs {
        let _s = ui.spinner(&format!("loading {spec}"));
        animated.push(load_animation(spec, a)?);
    }
    // Progress: one step per build and trace (static), per frame build and trace run
    // (animated, an upper bound: shared trees are traced once).
    let total = 12 * loaded.len() as u64 + animated.len() as u64 * a.frames as u64 * 7;
    let bar = ui.bar("system energy runs");
    let done = AtomicU64::new(0);
    let tick = || {
        let d = done.fetch_add(1, Ordering::Relaxed) + 1;
        bar.update(d.min(total), total);
    };
    let scenes: Vec<SceneResult> = loaded
        .par_iter()
        .map(|(name, tris, camera)| {
            let s = SystemScene {
                name: name.clone(),
                triangles: tris,
                camera: *camera,
                sample: a.sample,
            };
            scene_result(&s, &cfg, |_| tick()).with_context(|| format!("scene {name}"))
        })
        .collect::<anyhow::Result<_>>()?;
    let animation: Vec<AnimationResult> = animated
        .par_iter()
        .map(|s| {
            animation_study(s, &cfg, a.threshold, |_| tick())
                .with_context(|| format!("animated scene {}", s.name))
        })
        .collect::<anyhow::Result<_>>()?;
    bar.update(total, total);
    bar.finish();
    let rep = SystemReport::new(&cfg, a.soc.width, a.soc.height, scenes, animation);
    write_report(a, &rep)?;
    Ok(rep)
}

/// A static scene of the system studies: its name, triangles (an empty scene is an error)
/// and camera at `width` x `height`.
pub fn load_static(
    spec: &str,
    width: u32,
    height: u32,
    ui: &dyn Progress,
) -> anyhow::Result<(String, Vec<geom::Triangle>, PinholeCamera)> {
    let _s = ui.spinner(&format!("loading {spec}"));
    let (name, tris, camera) = load_traced(spec)?;
    anyhow::ensure!(!tris.is_empty(), "{spec}: the scene has no triangles");
    Ok((name, tris, PinholeCamera::new(&camera, width, height)?))
}

/// The static scenes of the system study: `scenes` (`none`: no scene) or the default list,
/// the shared real scenes that exist under `scene_dir` and the procedural ones.
pub fn static_scene_specs(
    scenes: Option<&[String]>,
    scene_dir: &Path,
    ui: &dyn Progress,
) -> Vec<String> {
    match scenes {
        Some(list) if list.len() == 1 && list[0] == "none" => Vec::new(),
        Some(list) => list.to_vec(),
        None => existing(scene_dir, &REAL, &|m| ui.warn(m))
            .into_iter()
            .chain(PROCEDURAL.iter().map(|s| s.to_string()))
            .collect(),
    }
}

/// The animated scenes to study.
fn animation_specs(a: &SystemOptions, ui: &dyn Progress) -> Vec<String> {
    match &a.animated {
        Some(list) if list.len() == 1 && list[0] == "none" => Vec::new(),
        Some(list) => list.clone(),
        None => ANIMATED
            .iter()
            .filter_map(|s| {
                if s.starts_with("proc:") {
                    return Some(s.to_string());
                }
                existing(&a.scene_dir, &[*s], &|m| ui.warn(m)).pop()
            })
            .collect(),
    }
}

/// `frames` frames of `spec` spread evenly over its timeline.
fn load_animation(spec: &str, a: &SystemOptions) -> anyhow::Result<AnimationScene> {
    let scene = scene::open(spec, &scene::LoadOptions::default())
        .with_context(|| format!("cannot open {spec}"))?;
    let info = scene.info();
    anyhow::ensure!(
        info.stable_topology,
        "{spec}: its triangles change between frames, so a tree cannot be refitted"
    );
    let duration = info.timeline.duration_s;
    anyhow::ensure!(
        duration > 0.0,
        "{spec}: a static scene (the animation study needs an animated one)"
    );
    let n = a.frames;
    let times: Vec<f32> = (0..n)
        .map(|k| {
            if n == 1 {
                0.0
            } else {
                duration * k as f32 / (n - 1) as f32
            }
        })
        .collect();
    let mut frames = Vec::new();
    for &t in &times {
        let mesh = scene
            .mesh_at(t)
            .with_context(|| format!("cannot sample {spec} at {t} s"))?;
        mesh_boxes(&mesh)?;
        frames.push(mesh.triangles_iter().collect::<Vec<_>>());
    }
    let name = short_name(spec);
    let camera = view_camera(&name, info.camera);
    Ok(AnimationScene {
        name,
        frames,
        times,
        camera: PinholeCamera::new(&camera, a.soc.width, a.soc.height)?,
        sample: a.sample,
    })
}

/// Writes every file of the report.
fn write_report(a: &SystemOptions, rep: &SystemReport) -> anyhow::Result<()> {
    let out = &a.out;
    let t8 = rep.table8_markdown();
    write_file(out, "table8.md", &t8)?;
    write_file(out, "table8.csv", &rep.table8_csv())?;
    let sc = rep.scenes_markdown();
    write_file(out, "scenes.md", &sc)?;
    write_file(out, "scenes.csv", &rep.scenes_csv())?;
    for (rays, file) in [
        (RayMode::Primary, "fig7-primary.svg"),
        (RayMode::Diffuse, "fig7-diffuse.svg"),
    ] {
        if rep.scenes.is_empty() {
            break;
        }
        let (labels, series) = rep.fig7(rays);
        let series: Vec<(String, Vec<Option<Vec<f64>>>)> = series
            .into_iter()
            .map(|(b, v)| {
                (
                    b.to_string(),
                    v.into_iter().map(|x| Some(x.to_vec())).collect(),
                )
            })
            .collect();
        let title = format!(
            "System power at 30 FPS (mW), {} rays: build + trace (cf. [P2] Fig. 7)",
            sim::system::report::ray_name(rays)
        );
        write_file(
            out,
            file,
            &stacked_bar_svg(&title, &labels, &series, &["build", "trace"]),
        )?;
    }
    let anim = rep.animation_markdown();
    if !rep.animation.is_empty() {
        write_file(out, "animation.md", &anim)?;
    }
    write_file(out, "system.json", &serde_json::to_string_pretty(rep)?)?;
    let mut md = String::from("# System energy per frame ([P2] §6.4) from Arbor's models\n\n");
    md += &format!(
        "{}x{}, {} diffuse bounces, {} ({}) on {}, one in {} tile chunks timed per frame; scenes over {} triangles are large.\n\n",
        rep.width,
        rep.height,
        rep.config.bounces,
        rep.config.node.name(),
        rep.config.energy.describe(),
        rep.config.dram,
        a.sample,
        LARGE_TRIANGLES
    );
    md += "## Table VIII: energy relative to binned SAH (mean of per-scene ratios)\n\n";
    if a.sample > 1 {
        md += "A ± gives the figure's standard error from sampling, in points: the traces' \
               errors from the spread of the timed chunks (`sim::rtunit::sampling`), \
               combined over the scenes with the builder's and binned SAH's errors taken as \
               independent (an upper estimate, as both trace the same pixels). It does not \
               include the bias of warming the caches functionally between chunks.\n\n";
    }
    md += &t8;
    md += "\n## Build and trace balance\n\nBinned SAH's build energy over its system energy, the same share as [P2]'s Table VIII row implies ((trace - total) / (trace - build)), and our build and trace ratios weighted with the thesis's share.\n\n";
    md += &rep.balance_markdown();
    md += "\n## Per scene\n\n";
    md += &sc;
    md += "\n![primary](fig7-primary.svg)\n\n![diffuse](fig7-diffuse.svg)\n";
    if !rep.animation.is_empty() {
        md += &format!(
            "\n## Animation: rebuild, refit, refit with advised rebuilds (threshold {})\n\n",
            a.threshold
        );
        md += &anim;
    }
    write_file(out, "report.md", &md)?;
    Ok(())
}
