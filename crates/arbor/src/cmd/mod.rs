//! Subcommands, one file each.

pub mod bench;
pub mod bench_build;
pub mod bench_compare;
pub mod bench_record;
pub mod bench_refit;
pub mod bench_trace;
pub mod build;
pub mod cbvh;
pub mod demo;
pub mod energy_args;
pub mod info;
pub mod log_info;
pub mod render;
pub mod report;
pub mod report_beyond;
pub mod report_cbvh;
pub mod report_energy;
pub mod report_html;
pub mod report_mergetree;
pub mod report_rtunit;
pub mod report_sensitivity;
pub mod report_system;
pub mod sim;
pub mod sim_dram;
pub mod sim_mergetree;
pub mod sim_rtunit;

use crate::progress::{Ui, Unit};
use anyhow::Context;
use scene::{LoadOptions, Scene};
use std::time::{Duration, Instant};

/// Options every command that opens a scene takes.
#[derive(clap::Args, Clone, Debug)]
pub struct SceneArgs {
    /// A mesh file (.ply .obj .gltf .glb), a directory or quoted glob of frame meshes, or a
    /// procedural spec such as 'proc:cloth?n=100000&seed=1'.
    pub scene: String,
    /// Frame rate used to number frames of keyframe sequences and animations.
    #[arg(long, value_name = "FPS")]
    pub fps: Option<f32>,
    /// glTF: the animation to play, by index or name (default: the first).
    #[arg(long, value_name = "NAME|INDEX")]
    pub animation: Option<String>,
}

/// Checks that a time option (`flag`, e.g. `--time`) is a finite number of seconds.
pub fn check_seconds(flag: &str, t: Option<f32>) -> anyhow::Result<()> {
    if let Some(t) = t {
        anyhow::ensure!(
            t.is_finite(),
            "{flag} must be a finite number of seconds, got {t}"
        );
    }
    Ok(())
}

/// The scene time the `--time T` / `--frame N` options of every command select: `T`, or
/// frame `N`'s time, or 0; a non-finite `T`, a `T` outside the timeline (0 to the
/// animation's length; 0 for a static scene) or a frame past the last is a one-line error.
/// The one place these options are interpreted.
pub fn resolve_time(
    info: &scene::SceneInfo,
    time: Option<f32>,
    frame: Option<u32>,
) -> anyhow::Result<f32> {
    check_seconds("--time", time)?;
    let frames = info.timeline.frame_count();
    if let Some(f) = frame {
        anyhow::ensure!(
            f < frames,
            "--frame {f} is out of range: the scene has {frames} frame(s)"
        );
    }
    if let Some(t) = time {
        let end = info.timeline.duration_s.max(0.0);
        // A little slack for times written with a few decimals.
        let slack = 1e-4 * end.max(1.0);
        if end > 0.0 {
            anyhow::ensure!(
                (-slack..=end + slack).contains(&t),
                "--time {t} is out of range: the scene's animation runs from 0 to {end} s"
            );
        } else {
            anyhow::ensure!(
                t.abs() <= slack,
                "--time {t} is out of range: the scene is static (time 0 only)"
            );
        }
    }
    Ok(match (time, frame) {
        (Some(t), _) => info.timeline.clamp(t),
        (None, Some(f)) => info.timeline.time_of_frame(f),
        (None, None) => 0.0,
    })
}

/// Opens the scene named by `args`, with a progress bar when it takes a while, and
/// returns it with the time the open took.
pub fn open_scene(args: &SceneArgs, ui: &Ui) -> anyhow::Result<(Box<dyn Scene>, Duration)> {
    if let Some(fps) = args.fps {
        anyhow::ensure!(
            fps.is_finite() && fps > 0.0,
            "--fps must be a positive number, got {fps}"
        );
    }
    let bar = ui.progress(&format!("loading {}", args.scene), Unit::Bytes);
    let opts = LoadOptions {
        progress: Some(bar.callback()),
        fps: args.fps,
        animation: args.animation.clone(),
    };
    let start = Instant::now();
    let scene = scene::open(&args.scene, &opts);
    bar.finish();
    let scene = scene.with_context(|| "cannot open scene".to_string())?;
    let elapsed = start.elapsed();
    let dropped = scene.info().dropped_triangles;
    if dropped > 0 {
        ui.warn(&format!(
            "{}: dropped {dropped} triangle(s) with NaN or infinite coordinates",
            args.scene
        ));
    }
    Ok((scene, elapsed))
}

/// Milliseconds of a duration, as a float.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

pub use ::report::table::thousands;
