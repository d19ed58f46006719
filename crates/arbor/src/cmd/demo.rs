//! `arbor demo`: the main job on the bundled default scene. It opens the scene, walks its
//! animation frame by frame, and prints a short summary; each capability of Arbor adds its
//! step here. Results also go to an output folder (`summary.json`, `frames.csv`).
//!
//! Steps: (1) walk the animation; (2) build a BVH with every available builder at frame 0
//! and a few later frames, validated, with SAH relative to the sweep SAH build; (3) refit
//! against rebuild; (4) simulate the MergeTree hardware builder (preset p2) at frame 0 on
//! the three memory systems of \[P2\] §6.2, with a utilization plot per system; (5)
//! compressed BVHs (\[P3\]): LBVH memory traffic with top-down vs
//! streaming bottom-up compression at a few frames, and a CBVH built at frame 0 refitted in
//! a stream to those frames; (6) ray tracing: frame 0 and the middle frame rendered with
//! primary rays and with diffuse path tracing through a binary and a 4-wide tree (same
//! image, different traversal cost), with the shaded image and the heatmap of frame 0.

use super::{info::gather, ms, open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::Context;
use geom::Aabb;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// The name of the scene `arbor demo` runs on when none is given: a skinned glTF character
/// shipped in the repository (`scenes/`; see `scenes/README.md` for its licence) and
/// compiled into the binary, so that an installed `arbor` needs no source tree.
pub const DEFAULT_SCENE: &str = "CesiumMan.glb";

/// The bundled scene's bytes.
const BUNDLED_BYTES: &[u8] = include_bytes!("../../../../scenes/CesiumMan.glb");

/// The bundled scene written to a private temporary folder (removed when dropped), for the
/// loaders, which read files.
pub struct BundledScene {
    _dir: tempfile::TempDir,
    /// The file's path, to open as a scene spec.
    pub path: String,
}

/// Writes the bundled scene [`DEFAULT_SCENE`] out for the loaders.
pub fn bundled_scene() -> anyhow::Result<BundledScene> {
    let dir = tempfile::Builder::new()
        .prefix("arbor-scene-")
        .tempdir()
        .context("cannot create a temporary folder for the bundled scene")?;
    let path = dir.path().join(DEFAULT_SCENE);
    std::fs::write(&path, BUNDLED_BYTES)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(BundledScene {
        path: path.display().to_string(),
        _dir: dir,
    })
}

/// Arguments of `arbor demo`.
#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Scene to run on (default: the bundled CesiumMan.glb).
    #[arg(long, value_name = "SCENE")]
    scene: Option<String>,
    /// Folder for the demo's outputs (created if missing; only files named by the demo are
    /// written there, `index.html` and `style.css` among them).
    #[arg(long, value_name = "DIR", default_value = "arbor-out/demo")]
    out: PathBuf,
    /// Frames to walk (default: all of them, at most 600).
    #[arg(long, value_name = "N")]
    frames: Option<u32>,
}

#[derive(Serialize)]
struct FrameRow {
    frame: u32,
    time_s: f32,
    triangles: usize,
    min: [f32; 3],
    max: [f32; 3],
    sample_ms: f64,
}

#[derive(Serialize)]
struct Summary {
    schema: &'static str,
    info: super::info::InfoJson,
    frames_walked: u32,
    mean_sample_ms: f64,
    swept_bounds: Option<[[f32; 3]; 2]>,
    max_center_travel: f32,
    frames: Vec<FrameRow>,
    builds: Vec<BuildRow>,
    refits: Vec<RefitRow>,
    mergetree: Vec<MergeTreeRow>,
    cbvh: Vec<CbvhRow>,
    renders: Vec<RenderRow>,
    accelerator: Vec<AcceleratorRow>,
}

/// One run of the demo's accelerator step (`accelerator` in `summary.json`).
#[derive(Serialize)]
struct AcceleratorRow {
    tree: &'static str,
    rays: &'static str,
    width: u32,
    height: u32,
    ray_count: u64,
    cycles: u64,
    mrps: f64,
    dram_mb: f64,
    energy_mj: f64,
    area_mm2: f64,
    max_stack_depth: usize,
    hits_match_software: bool,
}

/// One render of the demo's ray-tracing step (`renders` in `summary.json`).
#[derive(Serialize)]
struct RenderRow {
    frame: u32,
    time_s: f32,
    format: &'static str,
    rays: trace::RayKind,
    width: u32,
    height: u32,
    ray_count: u64,
    hits: u64,
    node_visits_per_ray: f64,
    box_tests_per_ray: f64,
    tri_tests_per_ray: f64,
    mrays_per_s: f64,
    /// The image and depth buffer equal the binary tree's, bit for bit.
    same_image_as_bvh2: bool,
    image: Option<String>,
    heatmap: Option<String>,
}

/// The memory systems of \[P2\] §6.2 (slow, medium, fast) the demo simulates MergeTree on.
const MERGETREE_DRAMS: [&str; 3] = sim::thesis::P2_SYSTEMS;

/// One MergeTree simulation of the demo (`mergetree` in `summary.json`).
#[derive(Serialize)]
struct MergeTreeRow {
    dram: String,
    triangles: u64,
    cycles: u64,
    ms: f64,
    bytes_read: u64,
    bytes_written: u64,
    bus_utilization: f64,
    merge_passes: u32,
    tree_matches_software: bool,
    svg: String,
}

/// One frame of the demo's CBVH step (`cbvh` in `summary.json`).
#[derive(Serialize)]
struct CbvhRow {
    frame: u32,
    time_s: f32,
    triangles: usize,
    node_pairs: u64,
    /// LBVH with top-down compression, bytes (\[P3\] §5.2 model).
    lbvh_topdown_bytes: u64,
    /// LBVH with streaming bottom-up compression (modulo, treelet depth 4), bytes.
    lbvh_bottomup_bytes: u64,
    lbvh_backtrack_steps: u64,
    /// Plain bottom-up (relative, no treelets) for comparison.
    lbvh_bottomup_plain_bytes: u64,
    lbvh_plain_backtrack_steps: u64,
    /// Refit of the frame-0 CBVH to this frame: full-precision refit + top-down, bytes.
    refit_topdown_bytes: Option<u64>,
    /// Streaming CBVH refit (modulo, treelet depth 4), bytes.
    refit_bottomup_bytes: Option<u64>,
    refit_backtrack_steps: Option<u64>,
    /// Every decoded box encloses its geometry (built and refitted trees).
    encloses: bool,
}

/// One build of the demo's build step (`builds` in `summary.json`).
#[derive(Serialize)]
struct BuildRow {
    frame: u32,
    time_s: f32,
    builder: &'static str,
    triangles: usize,
    build_ms: f64,
    sah: f64,
    sah_vs_sweep: f64,
    valid: bool,
}

/// One frame of the demo's rebuild-vs-refit comparison (`refits` in `summary.json`).
#[derive(Serialize)]
struct RefitRow {
    frame: u32,
    time_s: f32,
    refit_ms: f64,
    rebuild_ms: f64,
    refit_sah: f64,
    rebuild_sah: f64,
    /// Refitted SAH over the SAH the tree had when built (what the tracker watches).
    ratio_to_build: f64,
    rebuild_advised: bool,
}

/// Builder of the rebuild-vs-refit comparison.
const REFIT_BUILDER: &str = "binned-sah";

/// Frames the build step runs on: frame 0 and up to this many more, evenly spread.
const BUILD_STEP_EXTRA_FRAMES: u32 = 3;

/// Runs `arbor demo`.
pub fn run(args: &DemoArgs, ui: &Ui) -> anyhow::Result<()> {
    // The bundled scene is recorded by its name, not by where it was unpacked.
    let mut bundled = None;
    let (path, spec) = match &args.scene {
        Some(s) => (s.clone(), s.clone()),
        None => {
            let b: &BundledScene = bundled.insert(bundled_scene()?);
            (b.path.clone(), format!("{DEFAULT_SCENE} (bundled)"))
        }
    };
    let sargs = SceneArgs {
        scene: path,
        fps: None,
        animation: None,
    };
    crate::say!(ui, "Arbor demo");
    let (scene, open) = open_scene(&sargs, ui)?;
    let info = gather(ui, &spec, scene.as_ref(), open, None, Some(0))?;
    crate::say!(
        ui,
        "  scene      {} ({}): {} triangles, {} frames over {:.2} s, topology {}",
        info.name,
        info.format,
        thousands(info.triangles as u64),
        info.frames,
        info.duration_s,
        if info.stable_topology {
            "stable"
        } else {
            "changing"
        }
    );
    crate::say!(ui, "  opened in  {:.1} ms", info.open_ms);

    // Step 1: walk the animation.
    let timeline = scene.info().timeline;
    let n = args
        .frames
        .unwrap_or(timeline.frame_count().min(600))
        .max(1);
    let bar = ui.progress("sampling frames", Unit::Items);
    let mut rows = Vec::with_capacity(n as usize);
    let mut swept = Aabb::EMPTY;
    let start = Instant::now();
    for f in 0..n {
        let t = timeline.time_of_frame(f);
        let s = Instant::now();
        let mesh = scene.mesh_at(t).with_context(|| format!("frame {f}"))?;
        let b = mesh.bounds();
        swept = swept.union(b);
        rows.push(FrameRow {
            frame: f,
            time_s: t,
            triangles: mesh.triangle_count(),
            min: b.min.to_array(),
            max: b.max.to_array(),
            sample_ms: ms(s.elapsed()),
        });
        bar.update(f as u64 + 1, n as u64);
    }
    bar.finish();
    let walk_ms = ms(start.elapsed());
    let c0 = (glam_vec(rows[0].min) + glam_vec(rows[0].max)) * 0.5;
    let travel = rows
        .iter()
        .map(|r| ((glam_vec(r.min) + glam_vec(r.max)) * 0.5 - c0).length())
        .fold(0.0f32, f32::max);
    crate::say!(ui,
        "  animation  {n} frames sampled in {walk_ms:.1} ms ({:.2} ms/frame); bounds centre travels up to {travel:.3}",
        walk_ms / n as f64
    );

    // Step 2: every available builder at a few frames.
    let builds = build_step(ui, scene.as_ref(), n)?;
    // Step 3: refit one tree over the animation against rebuilding every frame.
    let refits = if scene.info().stable_topology {
        refit_step(ui, scene.as_ref(), n)?
    } else {
        crate::say!(
            ui,
            "  refit      skipped: the scene's topology changes over time"
        );
        Vec::new()
    };

    // Step 4: the MergeTree hardware model on the three memory systems.
    let mergetree = mergetree_step(ui, scene.as_ref(), &args.out)?;
    // Step 5: compressed BVHs, top-down vs streaming bottom-up.
    let cbvh = cbvh_step(ui, scene.as_ref(), n)?;
    // Step 6: ray tracing through both tree formats.
    let renders = render_step(ui, scene.as_ref(), n, &args.out)?;
    // Step 7: the ray-tracing accelerator model with each tree.
    let accelerator = accelerator_step(ui, scene.as_ref())?;

    let summary = Summary {
        schema: "arbor.demo.v1",
        info,
        frames_walked: n,
        mean_sample_ms: walk_ms / n as f64,
        swept_bounds: (!swept.is_empty()).then(|| [swept.min.to_array(), swept.max.to_array()]),
        max_center_travel: travel,
        frames: rows,
        builds,
        refits,
        mergetree,
        cbvh,
        renders,
        accelerator,
    };
    write_outputs(&args.out, &summary)?;
    let mut command = String::from("arbor demo");
    if let Some(s) = &args.scene {
        command += &format!(" --scene '{s}'");
    }
    if let Some(f) = args.frames {
        command += &format!(" --frames {f}");
    }
    command += &format!(" --out '{}'", args.out.display());
    report::html::write_folder_page(
        &args.out,
        &format!("arbor demo: {}", summary.info.name),
        "The demo's results: every builder at a few frames, refit against rebuild, the \
         MergeTree model on three memory systems, CBVH traffic, renders through binary and \
         4-wide trees with the heatmap, and the accelerator model. `arbor report html` \
         builds the site of every report.",
        &command,
        &super::report_html::provenance(),
    )?;
    crate::say!(
        ui,
        "  outputs    {} (open index.html there)",
        args.out.display()
    );
    if let Some(bad) = summary.mergetree.iter().find(|m| !m.tree_matches_software) {
        anyhow::bail!(
            "the MergeTree model's tree differs from the software HLBVH tree on {}",
            bad.dram
        );
    }
    if let Some(bad) = summary.renders.iter().find(|r| !r.same_image_as_bvh2) {
        anyhow::bail!(
            "the {} tree rendered a different image than the binary tree at frame {}",
            bad.format,
            bad.frame
        );
    }
    if let Some(bad) = summary.accelerator.iter().find(|r| !r.hits_match_software) {
        anyhow::bail!(
            "the accelerator model with the {} tree found hits that differ from the software tracer's ({} rays)",
            bad.tree,
            bad.rays
        );
    }
    if let Some(bad) = summary.builds.iter().find(|b| !b.valid) {
        anyhow::bail!(
            "builder {} produced an invalid tree at frame {} (see {})",
            bad.builder,
            bad.frame,
            args.out.join("summary.json").display()
        );
    }
    Ok(())
}

/// Builds with every available builder at frame 0 and a few of the `n` walked frames,
/// prints a table, and returns its rows. A tree that fails validation is recorded as
/// invalid (the caller reports it after writing the outputs).
fn build_step(ui: &Ui, scene: &dyn scene::Scene, n: u32) -> anyhow::Result<Vec<BuildRow>> {
    use super::build::{
        available_builders, builder, mesh_aabbs, timed_build, triangles_for, validate_built,
        BuildConfig,
    };
    let timeline = scene.info().timeline;
    let mut frames: Vec<u32> = (0..=BUILD_STEP_EXTRA_FRAMES)
        .map(|k| (n - 1) * k / BUILD_STEP_EXTRA_FRAMES)
        .collect();
    frames.dedup();
    let cfg = BuildConfig::default();
    let mut rows = Vec::new();
    crate::say!(
        ui,
        "  builds     frame  builder         build ms  SAH vs sweep  valid"
    );
    for &f in &frames {
        let t = timeline.time_of_frame(f);
        let mesh = scene.mesh_at(t).with_context(|| format!("frame {f}"))?;
        let (aabbs, _) = mesh_aabbs(&mesh)?;
        let mut built = Vec::new();
        for name in available_builders() {
            let cfg = BuildConfig {
                triangles: triangles_for(name, &mesh),
                ..cfg.clone()
            };
            let (tree, build_ms) = timed_build(ui, name, builder(name)?, &cfg, &aabbs)?;
            let valid = validate_built(&tree, name, &aabbs, cfg.max_leaf).is_ok();
            built.push((name, tree.normalized_sah(), build_ms, valid));
        }
        // The sweep SAH build is one of the builders: it normalizes the others.
        let sweep = built
            .iter()
            .find(|b| b.0 == "sweep-sah")
            .map(|b| b.1)
            .context("the sweep-sah builder is missing")?;
        for (name, sah, build_ms, valid) in built {
            let ratio = bvh::sah_ratio(sah, sweep);
            crate::say!(
                ui,
                "             {f:>5}  {name:<14} {build_ms:>9.2}  {ratio:>12.3}  {}",
                if valid { "yes" } else { "NO" }
            );
            rows.push(BuildRow {
                frame: f,
                time_s: t,
                builder: name,
                triangles: aabbs.len(),
                build_ms,
                sah,
                sah_vs_sweep: ratio,
                valid,
            });
        }
    }
    Ok(rows)
}

/// Builds a tree at frame 0 and refits it to evenly spread frames, next to a fresh build
/// of each frame; a [`bvh::RefitTracker`] says when the refitted tree has degraded enough
/// that a rebuild is advised.
fn refit_step(ui: &Ui, scene: &dyn scene::Scene, n: u32) -> anyhow::Result<Vec<RefitRow>> {
    use super::build::{builder, mesh_aabbs, timed_build, BuildConfig};
    use std::time::Instant;
    let timeline = scene.info().timeline;
    let cfg = BuildConfig::default();
    let build = builder(REFIT_BUILDER)?;
    let frames: Vec<u32> = {
        let mut f: Vec<u32> = (0..=8).map(|k| (n - 1) * k / 8).collect();
        f.dedup();
        f
    };
    let mesh0 = scene.mesh_at(timeline.time_of_frame(0))?;
    let (aabbs0, _) = mesh_aabbs(&mesh0)?;
    drop(mesh0);
    let (mut tree, _) = timed_build(ui, REFIT_BUILDER, build, &cfg, &aabbs0)?;
    let mut tracker = bvh::RefitTracker::with_default_threshold(tree.normalized_sah());
    crate::say!(
        ui,
        "  refit      frame  refit ms  rebuild ms  refit SAH / rebuild SAH  vs build  rebuild?"
    );
    let mut rows = Vec::new();
    for &f in &frames {
        let t = timeline.time_of_frame(f);
        let mesh = scene.mesh_at(t).with_context(|| format!("frame {f}"))?;
        let (aabbs, _) = mesh_aabbs(&mesh)?;
        drop(mesh);
        let s = Instant::now();
        tree.refit(&aabbs)
            .with_context(|| format!("refit to frame {f}"))?;
        let refit_ms = super::ms(s.elapsed());
        tree.validate(&aabbs, cfg.max_leaf)
            .with_context(|| format!("refitted tree invalid at frame {f}"))?;
        let (fresh, rebuild_ms) = timed_build(ui, REFIT_BUILDER, build, &cfg, &aabbs)?;
        let rec = tracker.record(tree.normalized_sah());
        let row = RefitRow {
            frame: f,
            time_s: t,
            refit_ms,
            rebuild_ms,
            refit_sah: rec.sah,
            rebuild_sah: fresh.normalized_sah(),
            ratio_to_build: rec.ratio,
            rebuild_advised: rec.rebuild_advised,
        };
        crate::say!(
            ui,
            "             {f:>5}  {:>8.2}  {:>10.2}  {:>23.3}  {:>8.3}  {}",
            row.refit_ms,
            row.rebuild_ms,
            bvh::sah_ratio(row.refit_sah, row.rebuild_sah),
            row.ratio_to_build,
            if row.rebuild_advised { "yes" } else { "no" }
        );
        rows.push(row);
    }
    Ok(rows)
}

/// Simulates MergeTree (preset p2) over frame 0 on each memory system of \[P2\] §6.2,
/// checks its tree against the software builder, writes a utilization plot per system
/// into `out`, prints a table and returns its rows.
fn mergetree_step(
    ui: &Ui,
    scene: &dyn scene::Scene,
    out: &std::path::Path,
) -> anyhow::Result<Vec<MergeTreeRow>> {
    use super::build::mesh_aabbs;
    let mesh = scene
        .mesh_at(scene.info().timeline.time_of_frame(0))
        .context("cannot sample frame 0")?;
    let (aabbs, _) = mesh_aabbs(&mesh)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // A window of 250 cycles gives a readable plot of a small scene's few 10k cycles.
    let cfg = sim::mergetree::MergeTreeConfig {
        trace_window_cycles: 250,
        ..sim::mergetree::MergeTreeConfig::p2()
    };
    crate::say!(ui, "  mergetree  memory             cycles        ms   read MB  written MB  bus util  same tree");
    let mut rows = Vec::new();
    for dram in MERGETREE_DRAMS {
        let (r, _) = super::sim_mergetree::simulate(ui, &aabbs, &cfg, dram)?;
        let same = sim::mergetree::tree_matches_software(&r, &aabbs)?;
        let svg = out.join(format!("mergetree-{dram}.svg"));
        let title = format!("MergeTree p2, {dram}: frame 0, {} triangles", r.triangles);
        report::fs::write_atomic(&svg, r.trace_svg(&title))?;
        crate::say!(
            ui,
            "             {dram:<17} {:>10} {:>9.4} {:>9.3} {:>11.3} {:>8.1}%  {}",
            thousands(r.cycles),
            r.ms,
            r.bytes_read as f64 / 1e6,
            r.bytes_written as f64 / 1e6,
            r.bus_utilization * 100.0,
            if same { "yes" } else { "NO" }
        );
        rows.push(MergeTreeRow {
            dram: dram.to_string(),
            triangles: r.triangles,
            cycles: r.cycles,
            ms: r.ms,
            bytes_read: r.bytes_read,
            bytes_written: r.bytes_written,
            bus_utilization: r.bus_utilization,
            merge_passes: r.merge_passes,
            tree_matches_software: same,
            svg: svg.display().to_string(),
        });
    }
    Ok(rows)
}

/// \[P3\] on the demo scene: at a few frames, LBVH traffic with top-down compression
/// against streaming bottom-up compression, and the frame-0 CBVH refitted in a stream.
fn cbvh_step(ui: &Ui, scene: &dyn scene::Scene, n: u32) -> anyhow::Result<Vec<CbvhRow>> {
    use super::build::mesh_aabbs;
    use cbvh::bottomup::{compress_hlbvh, StreamConfig};
    use cbvh::traffic::{self, Counts};
    let timeline = scene.info().timeline;
    let mut frames: Vec<u32> = (0..=BUILD_STEP_EXTRA_FRAMES)
        .map(|k| (n - 1) * k / BUILD_STEP_EXTRA_FRAMES)
        .collect();
    frames.dedup();
    let proposed = StreamConfig {
        params: cbvh::Params {
            coords: cbvh::Coords::Modulo,
            ..Default::default()
        },
        treelet_depth: 4,
        ..StreamConfig::default()
    };
    let plain = StreamConfig::default();
    let stable = scene.info().stable_topology;
    let mut base: Option<cbvh::Cbvh> = None;
    let mut rows = Vec::new();
    crate::say!(ui, "  cbvh       frame  LBVH MB: top-down  bottom-up (plain)  backtracks (plain)  refit MB: top-down  bottom-up");
    for &f in &frames {
        let t = timeline.time_of_frame(f);
        let mesh = scene.mesh_at(t).with_context(|| format!("frame {f}"))?;
        let (prims, _) = mesh_aabbs(&mesh)?;
        drop(mesh);
        let (hl, _) = cbvh::study::build_lbvh(&prims)?;
        let (tree, st) = compress_hlbvh(&hl, &proposed)?;
        let (_, st_plain) = compress_hlbvh(&hl, &plain)?;
        let mut encloses = cbvh::enclosure_violations(&tree.decode_to_bvh2()?, &prims)? == 0;
        let counts = |steps| Counts {
            prims: prims.len() as u64,
            node_pairs: tree.pairs.len() as u64,
            backtrack_steps: steps,
        };
        let (mut rtd, mut rbu, mut rsteps) = (None, None, None);
        if stable {
            if let Some(b) = &base {
                if b.prim_ids.len() == prims.len() {
                    let (refit, rst) = cbvh::refit_streaming(b, &prims, &proposed)?;
                    encloses &= cbvh::enclosure_violations(&refit.decode_to_bvh2()?, &prims)? == 0;
                    let c = Counts {
                        node_pairs: b.pairs.len() as u64,
                        ..counts(rst.backtrack_steps)
                    };
                    rtd = Some(traffic::refit_topdown(&c).total_bytes());
                    rbu = Some(traffic::refit_bottomup(&c).total_bytes());
                    rsteps = Some(rst.backtrack_steps);
                }
            }
        }
        let row = CbvhRow {
            frame: f,
            time_s: t,
            triangles: prims.len(),
            node_pairs: tree.pairs.len() as u64,
            lbvh_topdown_bytes: traffic::lbvh_topdown(&counts(0)).total_bytes(),
            lbvh_bottomup_bytes: traffic::lbvh_bottomup(&counts(st.backtrack_steps)).total_bytes(),
            lbvh_backtrack_steps: st.backtrack_steps,
            lbvh_bottomup_plain_bytes: traffic::lbvh_bottomup(&counts(st_plain.backtrack_steps))
                .total_bytes(),
            lbvh_plain_backtrack_steps: st_plain.backtrack_steps,
            refit_topdown_bytes: rtd,
            refit_bottomup_bytes: rbu,
            refit_backtrack_steps: rsteps,
            encloses,
        };
        let mb = |b: u64| b as f64 / 1e6;
        let opt = |b: Option<u64>| b.map_or("-".to_string(), |b| format!("{:.3}", mb(b)));
        crate::say!(
            ui,
            "             {f:>5}  {:>17.3}  {:>8.3} ({:.3})  {:>8} ({})  {:>18}  {:>9}",
            mb(row.lbvh_topdown_bytes),
            mb(row.lbvh_bottomup_bytes),
            mb(row.lbvh_bottomup_plain_bytes),
            row.lbvh_backtrack_steps,
            row.lbvh_plain_backtrack_steps,
            opt(rtd),
            opt(rbu)
        );
        anyhow::ensure!(
            encloses,
            "frame {f}: a decoded CBVH box does not enclose its geometry"
        );
        if base.is_none() {
            base = Some(tree);
        }
        rows.push(row);
    }
    Ok(rows)
}

/// Image size of the demo's renders (a quarter of [P4]'s 1280x720, to stay quick).
const DEMO_RENDER_SIZE: (u32, u32) = (640, 360);

/// Samples per pixel of the demo's diffuse picture (`render-diffuse.png`).
const DEMO_DIFFUSE_SPP: u32 = 16;

/// Image size of the demo's accelerator step.
const DEMO_ACCELERATOR_SIZE: (u32, u32) = (320, 180);

/// The \[P4\] accelerator model (`sim::rtunit`) at frame 0 with each tree, primary and
/// diffuse rays: cycles, MRPS, traffic, energy, and the check against the software tracer.
fn accelerator_step(ui: &Ui, scene: &dyn scene::Scene) -> anyhow::Result<Vec<AcceleratorRow>> {
    use sim::rtunit::{self, RayMode, RtConfig, TreeKind, Workload};
    let mesh = scene.mesh_at(0.0).context("frame 0")?;
    super::build::mesh_aabbs(&mesh)?;
    let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
    let (w, h) = DEMO_ACCELERATOR_SIZE;
    let camera = trace::PinholeCamera::new(&scene.info().camera, w, h)?;
    crate::say!(
        ui,
        "  accel      tree   rays      Mrays/s   cycles     DRAM MB   mJ/frame  stack  same hits"
    );
    let mut rows = Vec::new();
    for kind in [TreeKind::Bvh2, TreeKind::Mbvh4, TreeKind::Cbvh] {
        let tree = {
            let _s = ui.spinner(&format!("building the {} tree", kind.name()));
            rtunit::build_tree(kind, &tris)?
        };
        for (rays, name) in [(RayMode::Primary, "primary"), (RayMode::Diffuse, "diffuse")] {
            let work = Workload {
                triangles: &tris,
                camera: &camera,
                rays,
                bounces: 4,
                seed: 1,
                sample: 1,
                progress: None,
            };
            let r = {
                let _s = ui.spinner(&format!("simulating the {} accelerator", kind.name()));
                rtunit::run(&tree, &work, &RtConfig::default())?
            };
            let e = r.energy.as_ref();
            let row = AcceleratorRow {
                tree: kind.name(),
                rays: name,
                width: w,
                height: h,
                ray_count: r.rays,
                cycles: r.cycles,
                mrps: r.mrps,
                dram_mb: r.frame_dram_mb,
                energy_mj: e.map_or(0.0, |e| e.frame_mj),
                area_mm2: e.map_or(0.0, |e| e.area_mm2),
                max_stack_depth: r.max_stack_depth,
                hits_match_software: r.hits_match_software,
            };
            crate::say!(
                ui,
                "  accel      {:<6} {:<9} {:>7.1} {:>10} {:>9.3} {:>9.3} {:>6}  {}",
                row.tree,
                row.rays,
                row.mrps,
                row.cycles,
                row.dram_mb,
                row.energy_mj,
                row.max_stack_depth,
                if row.hits_match_software { "yes" } else { "NO" }
            );
            rows.push(row);
        }
    }
    Ok(rows)
}

/// Renders frame 0 and the middle of the `n` walked frames with primary and diffuse rays
/// (4 bounces, [P4] §3.2) through a binned SAH `Bvh2` and its `Mbvh4` collapse, checks
/// that both trees give the same image, prints the traversal cost, and writes frame 0's
/// shaded images and heatmap into `out`.
fn render_step(
    ui: &Ui,
    scene: &dyn scene::Scene,
    n: u32,
    out: &std::path::Path,
) -> anyhow::Result<Vec<RenderRow>> {
    use super::render::{build_accel, Format};
    use trace::{KernelOptions, RayKind, RenderSettings};
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let timeline = scene.info().timeline;
    let mut frames = vec![0];
    if n > 2 {
        frames.push(n / 2);
    }
    crate::say!(
        ui,
        "  render     frame  rays     format  Mrays/s  nodes/ray  boxes/ray  tris/ray  same image"
    );
    let mut rows = Vec::new();
    for &f in &frames {
        let t = timeline.time_of_frame(f);
        let mesh = scene.mesh_at(t).with_context(|| format!("frame {f}"))?;
        let (aabbs, _) = super::build::mesh_aabbs(&mesh)?;
        let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
        let shading = trace::Shading {
            triangles: &tris,
            material_ids: &mesh.material_ids,
        };
        let accels = [Format::Bvh2, Format::Mbvh4]
            .into_iter()
            .map(|fmt| {
                let width = if fmt == Format::Bvh2 { 2 } else { 4 };
                build_accel(
                    ui,
                    "binned-sah",
                    fmt,
                    &aabbs,
                    &tris,
                    KernelOptions::thesis(width),
                )
                .map(|a| a.0)
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        for kind in [RayKind::Primary, RayKind::Diffuse] {
            let mut settings = RenderSettings::new(scene.info().camera);
            (settings.width, settings.height) = DEMO_RENDER_SIZE;
            settings.rays = kind;
            let mut reference: Option<trace::Render> = None;
            for accel in &accels {
                let img = trace::render(accel, shading, &settings, None, None)
                    .context("rendering failed")?;
                let same = reference.as_ref().is_none_or(|r| {
                    r.depth
                        .iter()
                        .map(|d| d.to_bits())
                        .eq(img.depth.iter().map(|d| d.to_bits()))
                        && r.color == img.color
                });
                let (mut image, mut heatmap) = (None, None);
                if f == 0 && accel.format_name() == "bvh2" {
                    let name = match kind {
                        RayKind::Diffuse => "render-diffuse",
                        _ => "render-primary",
                    };
                    let p = out.join(format!("{name}.png"));
                    if kind == RayKind::Diffuse {
                        // The picture: more samples per pixel, smoothed across pixels
                        // of similar depth, exposed from its own luminance (the
                        // counters printed are the first sample's).
                        let mut picture = img.clone();
                        super::render::add_samples(
                            accel,
                            shading,
                            &settings,
                            &mut picture,
                            DEMO_DIFFUSE_SPP,
                        )?;
                        super::render::denoise(&mut picture);
                        super::render::expose(&mut picture);
                        trace::image::write_color_png(&p, &picture)?;
                    } else {
                        trace::image::write_color_png(&p, &img)?;
                    }
                    image = Some(p.display().to_string());
                    if kind == RayKind::Primary {
                        let h = out.join("heatmap-primary.png");
                        trace::image::write_heatmap(&h, &img, trace::image::HeatScale::of(&img))?;
                        heatmap = Some(h.display().to_string());
                    }
                }
                let st = &img.stats.total;
                crate::say!(
                    ui,
                    "             {f:>5}  {:<8} {:<6} {:>8.2} {:>10.2} {:>10.2} {:>9.2}  {}",
                    format!("{kind:?}").to_lowercase(),
                    accel.format_name(),
                    img.stats.mrays_per_s,
                    st.per_ray(st.node_visits),
                    st.per_ray(st.box_tests),
                    st.per_ray(st.tri_tests),
                    if same { "yes" } else { "NO" }
                );
                rows.push(RenderRow {
                    frame: f,
                    time_s: t,
                    format: accel.format_name(),
                    rays: kind,
                    width: settings.width,
                    height: settings.height,
                    ray_count: st.rays,
                    hits: st.hits,
                    node_visits_per_ray: st.per_ray(st.node_visits),
                    box_tests_per_ray: st.per_ray(st.box_tests),
                    tri_tests_per_ray: st.per_ray(st.tri_tests),
                    mrays_per_s: img.stats.mrays_per_s,
                    same_image_as_bvh2: same,
                    image,
                    heatmap,
                });
                if reference.is_none() {
                    reference = Some(img);
                }
            }
        }
    }
    Ok(rows)
}

fn glam_vec(a: [f32; 3]) -> geom::Vec3 {
    geom::Vec3::from_array(a)
}

fn write_outputs(dir: &PathBuf, s: &Summary) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let json = dir.join("summary.json");
    report::fs::write_atomic(&json, serde_json::to_string_pretty(s)?)?;
    let mut csv = report::table::Table::new(&[
        "frame",
        "time_s",
        "triangles",
        "min_x",
        "min_y",
        "min_z",
        "max_x",
        "max_y",
        "max_z",
        "sample_ms",
    ]);
    for r in &s.frames {
        csv.push([
            r.frame.to_string(),
            r.time_s.to_string(),
            r.triangles.to_string(),
            r.min[0].to_string(),
            r.min[1].to_string(),
            r.min[2].to_string(),
            r.max[0].to_string(),
            r.max[1].to_string(),
            r.max[2].to_string(),
            format!("{:.4}", r.sample_ms),
        ]);
    }
    report::fs::write_atomic(&dir.join("frames.csv"), csv.csv())?;
    Ok(())
}
