//! `arbor info`: what a scene holds at one time. The JSON form is documented in
//! `docs/cli-json.md` and is versioned by its `schema` field.

use super::{ms, open_scene, thousands, SceneArgs};
use crate::progress::Ui;
use anyhow::Context;
use scene::{Mesh, Scene};
use serde::Serialize;
use std::time::{Duration, Instant};

/// Arguments of `arbor info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Time in seconds at which to sample the scene (clamped to its timeline).
    #[arg(long, value_name = "SECONDS", conflicts_with = "frame")]
    time: Option<f32>,
    /// Frame number at which to sample the scene.
    #[arg(long, value_name = "N")]
    frame: Option<u32>,
    /// Print JSON (schema `arbor.info.v1`) instead of text.
    #[arg(long)]
    json: bool,
}

/// A box as two corners, or null for an empty scene.
#[derive(Serialize)]
pub struct BoundsJson {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

/// The JSON document `arbor info --json` prints (`arbor.info.v1`).
#[derive(Serialize)]
pub struct InfoJson {
    pub schema: &'static str,
    pub scene: String,
    pub name: String,
    pub format: String,
    pub time_s: f32,
    pub frame: Option<u32>,
    pub triangles: usize,
    pub vertices: usize,
    pub degenerate_triangles: usize,
    pub dropped_triangles: usize,
    pub materials: usize,
    pub bounds: Option<BoundsJson>,
    pub frames: u32,
    pub duration_s: f32,
    pub fps: f32,
    pub stable_topology: bool,
    pub camera: scene::Camera,
    pub open_ms: f64,
    pub sample_ms: f64,
}

/// Bounds of a mesh for JSON (None when empty).
pub fn bounds_json(mesh: &Mesh) -> Option<BoundsJson> {
    let b = mesh.bounds();
    (!b.is_empty()).then(|| BoundsJson {
        min: b.min.to_array(),
        max: b.max.to_array(),
    })
}

/// Samples `scene` and gathers what `info` reports.
pub fn gather(
    ui: &Ui,
    spec: &str,
    scene: &dyn Scene,
    open: Duration,
    time: Option<f32>,
    frame: Option<u32>,
) -> anyhow::Result<InfoJson> {
    let info = scene.info();
    let t = super::resolve_time(info, time, frame)?;
    let start = Instant::now();
    let spinner = ui.spinner(&format!("sampling {spec} at t = {t} s"));
    let mesh = scene
        .mesh_at(t)
        .with_context(|| format!("cannot sample the scene at t = {t} s"))?;
    let sample = start.elapsed();
    drop(spinner);
    Ok(InfoJson {
        schema: "arbor.info.v1",
        scene: spec.to_string(),
        name: info.name.clone(),
        format: info.format.clone(),
        time_s: t,
        frame,
        triangles: mesh.triangle_count(),
        vertices: mesh.positions.len(),
        degenerate_triangles: mesh.degenerate_count(),
        dropped_triangles: info.dropped_triangles,
        materials: mesh.material_names.len(),
        bounds: bounds_json(&mesh),
        frames: info.timeline.frame_count(),
        duration_s: info.timeline.duration_s,
        fps: info.timeline.fps,
        stable_topology: info.stable_topology,
        camera: info.camera,
        open_ms: ms(open),
        sample_ms: ms(sample),
    })
}

/// Runs `arbor info`.
pub fn run(args: &InfoArgs, ui: &Ui) -> anyhow::Result<()> {
    let (scene, open) = open_scene(&args.scene, ui)?;
    let j = gather(
        ui,
        &args.scene.scene,
        scene.as_ref(),
        open,
        args.time,
        args.frame,
    )?;
    if args.json {
        ui.emit_json(&j)?;
        return Ok(());
    }
    let bounds = match &j.bounds {
        Some(b) => format!(
            "[{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]",
            b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]
        ),
        None => "empty".to_string(),
    };
    println!("scene       {} ({}, {})", j.scene, j.name, j.format);
    println!(
        "triangles   {} ({} degenerate, {} dropped)",
        thousands(j.triangles as u64),
        thousands(j.degenerate_triangles as u64),
        thousands(j.dropped_triangles as u64)
    );
    println!("vertices    {}", thousands(j.vertices as u64));
    println!("materials   {}", j.materials);
    let at = match j.frame {
        Some(f) => format!("t = {:.3} s, frame {f}", j.time_s),
        None => format!("t = {:.3} s", j.time_s),
    };
    println!("bounds      {bounds} ({at})");
    println!(
        "frames      {} over {:.3} s at {} fps; topology {}",
        j.frames,
        j.duration_s,
        j.fps,
        if j.stable_topology {
            "stable"
        } else {
            "changes"
        }
    );
    println!(
        "load        {:.1} ms open + {:.1} ms sample",
        j.open_ms, j.sample_ms
    );
    Ok(())
}
