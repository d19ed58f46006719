//! A renderer's frame loop over an animated scene, with `trace` as its ray-tracing
//! library: the tree is built once, and every frame the mesh is skinned at its time, the
//! prepared tree is refitted in place (`Accel::refit`), primary rays are traced and the
//! image is written as a PNG. Prints per frame the skinning, update and trace times.
//!
//! ```sh
//! cargo run --release -p trace --example frame_loop -- [SCENE [FRAMES [WIDTH HEIGHT [OUT]]]]
//! ```
//!
//! Defaults: the bundled `scenes/CesiumMan.glb`, 8 frames spread over its animation,
//! 640x360, images in `frame-loop-out/`. `cargo test -p trace` runs this loop on the
//! bundled scene (few frames, small images) and checks that every refitted frame traces
//! exactly like a tree built afresh for it.

use std::path::{Path, PathBuf};
use std::time::Instant;
use trace::{Accel, KernelOptions, Mbvh4Accel, Render, RenderSettings, Shading};

type Error = Box<dyn std::error::Error>;

/// What the loop renders.
struct FrameLoop {
    /// A scene spec (`scene::open`): a glTF file, a keyframe folder, `proc:...`.
    scene: String,
    /// Frames, spread evenly over the scene's timeline (first and last included).
    frames: u32,
    /// Image size in pixels.
    width: u32,
    height: u32,
    /// Where `frame-NNN.png` go.
    out: PathBuf,
}

/// Timings and counts of one frame.
#[derive(Debug)]
struct FrameReport {
    frame: u32,
    time_s: f32,
    triangles: usize,
    /// Evaluating the mesh at the frame's time (skinning, for a glTF character).
    skin_ms: f64,
    /// Building the tree (frame 0) or refitting the prepared tree in place.
    update_ms: f64,
    /// Tracing and shading the primary rays.
    trace_ms: f64,
    mrays_per_s: f64,
    hits: u64,
    png: PathBuf,
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// The prepared 4-wide tree of `tris`: a binned SAH build collapsed to `Mbvh4`.
fn build(tris: &[geom::Triangle]) -> Result<Accel, Error> {
    let tree = bvh::BinnedSahBuilder::default().build(&bvh::triangle_aabbs(tris))?;
    let wide = bvh::collapse(&tree)?;
    Ok(Accel::Mbvh4(Mbvh4Accel::new(
        wide,
        tris,
        KernelOptions::default(),
    )?))
}

/// Runs the loop; `each` sees every frame's report, refitted tree, triangles and materials,
/// settings and image (the test compares them with a fresh build).
fn run(
    cfg: &FrameLoop,
    mut each: impl FnMut(&FrameReport, &Accel, Shading<'_>, &RenderSettings, &Render),
) -> Result<Vec<FrameReport>, Error> {
    let scene = scene::open(&cfg.scene, &scene::LoadOptions::default())?;
    let info = scene.info();
    if !info.stable_topology {
        return Err(format!(
            "{}: its topology changes over time; a refit needs a stable one",
            cfg.scene
        )
        .into());
    }
    std::fs::create_dir_all(&cfg.out)?;
    let last = info.timeline.frame_count().saturating_sub(1);
    let mut settings = RenderSettings::new(info.camera);
    (settings.width, settings.height) = (cfg.width, cfg.height);
    let mut accel: Option<Accel> = None;
    let mut reports = Vec::new();
    for f in 0..cfg.frames {
        // Frame f of `frames` spread over the timeline's frames.
        let n = (f as u64 * last as u64 / (cfg.frames.max(2) - 1) as u64) as u32;
        let time_s = info.timeline.time_of_frame(n);
        let start = Instant::now();
        let mesh = scene.mesh_at(time_s)?;
        let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
        let skin_ms = ms(start);

        let start = Instant::now();
        match accel.as_mut() {
            None => accel = Some(build(&tris)?),
            // A CBVH is not refitted in place (`refit` says false): built anew instead.
            Some(a) => {
                if !a.refit(&tris)? {
                    *a = build(&tris)?;
                }
            }
        }
        let update_ms = ms(start);
        let a = accel.as_ref().ok_or("no tree")?;

        let shading = Shading {
            triangles: &tris,
            material_ids: &mesh.material_ids,
        };
        let start = Instant::now();
        let image = trace::render(a, shading, &settings, None, None)?;
        let trace_ms = ms(start);
        let png = cfg.out.join(format!("frame-{f:03}.png"));
        trace::image::write_color_png(&png, &image)?;

        let report = FrameReport {
            frame: f,
            time_s,
            triangles: tris.len(),
            skin_ms,
            update_ms,
            trace_ms,
            mrays_per_s: image.stats.mrays_per_s,
            hits: image.stats.total.hits,
            png,
        };
        each(&report, a, shading, &settings, &image);
        reports.push(report);
    }
    Ok(reports)
}

fn bundled_scene() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/CesiumMan.glb")
        .display()
        .to_string()
}

fn main() -> Result<(), Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize| args.get(i).map(String::as_str);
    let number = |i: usize, default: u32| -> Result<u32, Error> {
        Ok(arg(i).map(str::parse).transpose()?.unwrap_or(default))
    };
    let cfg = FrameLoop {
        scene: arg(0).map_or_else(bundled_scene, str::to_string),
        frames: number(1, 8)?,
        width: number(2, 640)?,
        height: number(3, 360)?,
        out: PathBuf::from(arg(4).unwrap_or("frame-loop-out")),
    };
    println!("frame  time_s  triangles  skin_ms  update_ms  trace_ms  Mrays/s  hits");
    let reports = run(&cfg, |r, _, _, _, _| {
        println!(
            "{:>5}  {:>6.3}  {:>9}  {:>7.2}  {:>9.3}  {:>8.2}  {:>7.2}  {}",
            r.frame,
            r.time_s,
            r.triangles,
            r.skin_ms,
            r.update_ms,
            r.trace_ms,
            r.mrays_per_s,
            r.hits
        )
    })?;
    if let Some(r) = reports.last() {
        println!(
            "images in {}",
            r.png.parent().unwrap_or(Path::new(".")).display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use trace::Traverse;

    /// The loop on the bundled character: every frame's image has hits and is written,
    /// the character moves, and the refitted tree renders the same colors, depth buffer
    /// and hit primitives, bit for bit, as a tree built afresh for the frame (another
    /// topology and another format: the closest hit does not depend on the tree).
    #[test]
    fn frame_loop_refits_like_fresh_builds() {
        let out = tempfile::tempdir().unwrap();
        let cfg = FrameLoop {
            scene: bundled_scene(),
            frames: 3,
            width: 48,
            height: 32,
            out: out.path().to_path_buf(),
        };
        let mut depths: Vec<Vec<u32>> = Vec::new();
        let reports = run(&cfg, |r, accel, shading, settings, image| {
            let tris = shading.triangles;
            let fresh_tree = bvh::SweepSahBuilder::default()
                .build(&bvh::triangle_aabbs(tris))
                .unwrap();
            let fresh = trace::Bvh2Accel::new(fresh_tree, tris, KernelOptions::default()).unwrap();
            let want = trace::render(&fresh, shading, settings, None, None).unwrap();
            let bits = |i: &Render| i.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(image), bits(&want), "frame {}: depth", r.frame);
            assert_eq!(image.prim, want.prim, "frame {}: hit primitives", r.frame);
            assert_eq!(image.color, want.color, "frame {}: colors", r.frame);
            // Refitted and fresh trees are different trees of the same triangles.
            assert_eq!(accel.source_triangles(), tris.len());
            depths.push(bits(image));
        })
        .unwrap();
        assert_eq!(reports.len(), 3);
        for r in &reports {
            assert!(r.hits > 0, "frame {}: nothing hit", r.frame);
            assert!(
                r.hits < (48 * 32) as u64,
                "frame {}: no background",
                r.frame
            );
            let bytes = std::fs::metadata(&r.png).unwrap().len();
            assert!(bytes > 100, "frame {}: {bytes} bytes of PNG", r.frame);
        }
        assert!(reports[2].time_s > reports[0].time_s);
        assert_ne!(depths[0], depths[2], "the character does not move");
    }
}
