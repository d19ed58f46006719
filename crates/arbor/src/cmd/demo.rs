//! `arbor demo`: the main job on the bundled default scene. It opens the scene, walks its
//! animation frame by frame, and prints a short summary; each capability of Arbor adds its
//! step here. Results also go to an output folder (`summary.json`, `frames.csv`).

use super::{info::gather, ms, open_scene, thousands, SceneArgs};
use crate::progress::{Ui, Unit};
use anyhow::Context;
use geom::Aabb;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

/// The scene `arbor demo` runs on when none is given: a skinned glTF character shipped in
/// the repository (see `scenes/README.md` for its licence).
pub const DEFAULT_SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/CesiumMan.glb");

/// Arguments of `arbor demo`.
#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Scene to run on (default: the bundled CesiumMan.glb).
    #[arg(long, value_name = "SCENE")]
    scene: Option<String>,
    /// Folder for the demo's outputs (created if missing; only files named by the demo are
    /// written there).
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
}

/// Runs `arbor demo`.
pub fn run(args: &DemoArgs, ui: &Ui) -> anyhow::Result<()> {
    let spec = args
        .scene
        .clone()
        .unwrap_or_else(|| DEFAULT_SCENE.to_string());
    let sargs = SceneArgs {
        scene: spec.clone(),
        fps: None,
        animation: None,
    };
    println!("Arbor demo");
    let (scene, open) = open_scene(&sargs, ui)?;
    let info = gather(ui, &spec, scene.as_ref(), open, None, Some(0))?;
    println!(
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
    println!("  opened in  {:.1} ms", info.open_ms);

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
    println!(
        "  animation  {n} frames sampled in {walk_ms:.1} ms ({:.2} ms/frame); bounds centre travels up to {travel:.3}",
        walk_ms / n as f64
    );

    let summary = Summary {
        schema: "arbor.demo.v1",
        info,
        frames_walked: n,
        mean_sample_ms: walk_ms / n as f64,
        swept_bounds: (!swept.is_empty()).then(|| [swept.min.to_array(), swept.max.to_array()]),
        max_center_travel: travel,
        frames: rows,
    };
    write_outputs(&args.out, &summary)?;
    println!("  outputs    {}", args.out.display());
    Ok(())
}

fn glam_vec(a: [f32; 3]) -> geom::Vec3 {
    geom::Vec3::from_array(a)
}

fn write_outputs(dir: &PathBuf, s: &Summary) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let json = dir.join("summary.json");
    std::fs::write(&json, serde_json::to_string_pretty(s)?)
        .with_context(|| format!("cannot write {}", json.display()))?;
    let csv = dir.join("frames.csv");
    let mut w = std::io::BufWriter::new(
        std::fs::File::create(&csv).with_context(|| format!("cannot write {}", csv.display()))?,
    );
    writeln!(
        w,
        "frame,time_s,triangles,min_x,min_y,min_z,max_x,max_y,max_z,sample_ms"
    )?;
    for r in &s.frames {
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{},{:.4}",
            r.frame,
            r.time_s,
            r.triangles,
            r.min[0],
            r.min[1],
            r.min[2],
            r.max[0],
            r.max[1],
            r.max[2],
            r.sample_ms
        )?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", csv.display()))?;
    Ok(())
}
