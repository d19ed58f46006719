//! Instancing in a renderer's frame loop: a crowd of the bundled walking character.
//! A few bottom levels hold the character skinned at different phases of its walk (each
//! refitted in place every frame, `InstanceAccel::refit_bottom`); many instances place
//! them on a grid, each turning on the spot (`InstanceAccel::set_transforms` refits the
//! top level); primary rays are traced through both levels and shaded by their
//! world-space normal. For comparison, each frame also builds one flat tree over all the
//! instanced triangles moved into world space (what a renderer without instancing does)
//! and traces the same rays through it. Prints per frame the update and trace times of
//! both.
//!
//! ```sh
//! cargo run --release -p trace --example crowd -- [INSTANCES [POSES [FRAMES [WIDTH HEIGHT [OUT]]]]]
//! ```
//!
//! Defaults: 64 instances of 4 poses of `scenes/CesiumMan.glb`, 8 frames, 640x360, images
//! in `crowd-out/`. `cargo test -p trace` runs a small crowd and checks that the instanced
//! hits are the flat tree's (same instance and triangle, same distance up to rounding).

use geom::{Mat4, Quat, Ray, Triangle, Vec3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;
use trace::instance::{
    BottomLevel, Instance, InstanceAccel, InstanceHit, InstanceStack, Transform,
};
use trace::{Accel, Bvh2Accel, KernelOptions, PinholeCamera, RayStats, TraversalStack, Traverse};

type Error = Box<dyn std::error::Error>;

/// What the loop renders.
struct Crowd {
    scene: String,
    /// Instances, on a square grid.
    instances: u32,
    /// Bottom levels: the character at this many phases of its animation.
    poses: u32,
    frames: u32,
    width: u32,
    height: u32,
    out: PathBuf,
}

/// Timings of one frame.
#[derive(Debug)]
struct FrameReport {
    frame: u32,
    /// Skinning every pose.
    skin_ms: f64,
    /// Refitting the bottom levels and the top level (frame 0: building them).
    update_ms: f64,
    /// Tracing the primary rays through the instances.
    trace_ms: f64,
    /// Moving every instanced triangle into world space and building one flat tree.
    flat_build_ms: f64,
    /// Tracing the same rays through the flat tree.
    flat_trace_ms: f64,
    /// Triangles in the world (instances x triangles per pose).
    world_triangles: usize,
    hits: usize,
    /// Pixels whose instanced hit is not the flat tree's (another instance or triangle,
    /// or a distance off by more than 1e-4 relative).
    differ: usize,
    png: PathBuf,
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

fn prepare(tris: &[Triangle]) -> Result<Accel, Error> {
    let tree = bvh::BinnedSahBuilder::default().build(&bvh::triangle_aabbs(tris))?;
    Ok(Accel::Bvh2(Bvh2Accel::new(
        tree,
        tris,
        KernelOptions::default(),
    )?))
}

/// Instance `i`'s transform at frame `f`: its grid cell (spacing `step`, on the ground
/// plane y = 0), turned about the vertical axis.
fn place(i: u32, side: u32, step: f32, f: u32) -> Result<Transform, Error> {
    let (gx, gz) = ((i % side) as f32, (i / side) as f32);
    let at = Vec3::new(gx * step, 0.0, gz * step);
    let turn = Quat::from_rotation_y(i as f32 * 0.7 + f as f32 * 0.25);
    Ok(Transform::from_mat4(Mat4::from_rotation_translation(
        turn, at,
    ))?)
}

/// One primary ray per pixel, closest hits through `trace`, in parallel by rows.
fn trace_image<H: Send>(
    cam: &PinholeCamera,
    closest: impl Fn(&Ray, &mut InstanceStack, &mut TraversalStack) -> Option<H> + Sync,
) -> Vec<Option<H>> {
    (0..cam.height())
        .into_par_iter()
        .flat_map_iter(|y| {
            let (mut s2, mut s1) = (InstanceStack::new(), TraversalStack::new());
            (0..cam.width())
                .map(|x| closest(&cam.pixel_ray(x, y), &mut s2, &mut s1))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Runs the loop; `each` sees every frame's report, the instanced hits and, per pixel,
/// the flat tree's hit as (instance, triangle, t).
fn run(
    cfg: &Crowd,
    mut each: impl FnMut(&FrameReport, &[Option<InstanceHit>], &[Option<(u32, u32, f32)>]),
) -> Result<Vec<FrameReport>, Error> {
    let scene = scene::open(&cfg.scene, &scene::LoadOptions::default())?;
    let timeline = scene.info().timeline;
    if !scene.info().stable_topology {
        return Err(format!("{}: its topology changes over time", cfg.scene).into());
    }
    std::fs::create_dir_all(&cfg.out)?;
    let (poses, count) = (cfg.poses.max(1), cfg.instances.max(1));
    let side = (count as f32).sqrt().ceil() as u32;
    let pose_time = |f: u32, b: u32| {
        let period = timeline.duration_s.max(1e-3);
        (timeline.time_of_frame(f) + period * b as f32 / poses as f32) % period
    };
    // Grid spacing: 1.5 times the character's footprint in its first pose.
    let step = {
        let mesh = scene.mesh_at(pose_time(0, 0))?;
        let b = mesh.bounds();
        b.extent().x.max(b.extent().z) * 1.5
    };
    let mut crowd: Option<InstanceAccel> = None;
    let mut cam: Option<PinholeCamera> = None;
    let mut reports = Vec::new();
    for f in 0..cfg.frames {
        let start = Instant::now();
        let posed = (0..poses)
            .map(|b| {
                let mesh = scene.mesh_at(pose_time(f, b))?;
                Ok(mesh.triangles_iter().collect::<Vec<_>>())
            })
            .collect::<Result<Vec<Vec<Triangle>>, Error>>()?;
        let skin_ms = ms(start);

        let start = Instant::now();
        let transforms = (0..count)
            .map(|i| place(i, side, step, f))
            .collect::<Result<Vec<_>, _>>()?;
        match crowd.as_mut() {
            None => {
                let bottoms = posed
                    .iter()
                    .map(|tris| Ok(BottomLevel::new(prepare(tris)?, tris)?))
                    .collect::<Result<Vec<_>, Error>>()?;
                let instances = transforms
                    .iter()
                    .enumerate()
                    .map(|(i, &transform)| Instance {
                        bottom: i as u32 % poses,
                        transform,
                    })
                    .collect();
                crowd = Some(InstanceAccel::new(bottoms, instances)?);
            }
            Some(c) => {
                for (b, tris) in posed.iter().enumerate() {
                    c.refit_bottom(b, tris)?;
                }
                c.set_transforms(&transforms)?;
            }
        }
        let update_ms = ms(start);
        let c = crowd.as_ref().ok_or("no crowd")?;
        if cam.is_none() {
            let framing = scene::Camera::framing(&c.top().bounds());
            cam = Some(PinholeCamera::new(&framing, cfg.width, cfg.height)?);
        }
        let cam = cam.as_ref().ok_or("no camera")?;

        let start = Instant::now();
        let hits = trace_image(cam, |r, s, _| c.closest_hit(r, s, &mut RayStats::default()));
        let trace_ms = ms(start);

        // The renderer without instancing: every instanced triangle in world space.
        let start = Instant::now();
        let (mut world, mut owner) = (Vec::new(), Vec::new());
        for (i, inst) in c.instances().iter().enumerate() {
            for (p, tri) in posed[inst.bottom as usize].iter().enumerate() {
                world.push(inst.transform.triangle_to_world(tri));
                owner.push((i as u32, p as u32));
            }
        }
        let flat = prepare(&world)?;
        let flat_build_ms = ms(start);
        let start = Instant::now();
        let flat_hits = trace_image(cam, |r, _, s| {
            flat.closest_hit(r, s, &mut RayStats::default())
                .map(|h| (owner[h.prim as usize].0, owner[h.prim as usize].1, h.t))
        });
        let flat_trace_ms = ms(start);

        // Shade by the world-space normal facing the camera, tinted per pose.
        let rgb: Vec<u8> = hits
            .iter()
            .enumerate()
            .flat_map(|(px, h)| {
                let Some(h) = h else { return [60, 60, 64] };
                let inst = c.instances()[h.instance as usize];
                let tri = inst
                    .transform
                    .triangle_to_world(&posed[inst.bottom as usize][h.prim as usize]);
                let ray = cam.pixel_ray(px as u32 % cfg.width, px as u32 / cfg.width);
                let lit = 0.25
                    + 0.75
                        * tri
                            .normal()
                            .normalize_or_zero()
                            .dot(ray.dir.normalize())
                            .abs();
                let tint = [
                    1.0,
                    0.85 + 0.15 * (inst.bottom % 2) as f32,
                    0.7 + 0.3 * (inst.bottom % 3) as f32 / 2.0,
                ];
                tint.map(|k| (255.0 * (lit * k).clamp(0.0, 1.0)) as u8)
            })
            .collect();
        let png = cfg.out.join(format!("crowd-{f:03}.png"));
        trace::image::write_png(&png, cfg.width, cfg.height, &rgb)?;

        let report = FrameReport {
            frame: f,
            skin_ms,
            update_ms,
            trace_ms,
            flat_build_ms,
            flat_trace_ms,
            world_triangles: world.len(),
            hits: hits.iter().flatten().count(),
            differ: differing(&hits, &flat_hits),
            png,
        };
        each(&report, &hits, &flat_hits);
        reports.push(report);
    }
    Ok(reports)
}

/// Pixels where the instanced and the flat hits disagree (see [`FrameReport::differ`]).
fn differing(hits: &[Option<InstanceHit>], flat: &[Option<(u32, u32, f32)>]) -> usize {
    hits.iter()
        .zip(flat)
        .filter(|(h, w)| match (h, w) {
            (None, None) => false,
            (Some(h), Some(w)) => {
                (h.instance, h.prim) != (w.0, w.1) || (h.t - w.2).abs() > 1e-4 * w.2.max(1.0)
            }
            _ => true,
        })
        .count()
}

fn bundled_scene() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/CesiumMan.glb")
        .display()
        .to_string()
}

fn main() -> Result<(), Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let number = |i: usize, default: u32| -> Result<u32, Error> {
        Ok(args
            .get(i)
            .map(|a| a.parse())
            .transpose()?
            .unwrap_or(default))
    };
    let cfg = Crowd {
        scene: bundled_scene(),
        instances: number(0, 64)?,
        poses: number(1, 4)?,
        frames: number(2, 8)?,
        width: number(3, 640)?,
        height: number(4, 360)?,
        out: PathBuf::from(args.get(5).map_or("crowd-out", String::as_str)),
    };
    println!(
        "frame  world_tris  skin_ms  update_ms  trace_ms  | flat: build_ms  trace_ms  hits  differ"
    );
    let reports = run(&cfg, |r, _, _| {
        println!(
            "{:>5}  {:>10}  {:>7.2}  {:>9.3}  {:>8.2}  |      {:>8.2}  {:>8.2}  {}  {}",
            r.frame,
            r.world_triangles,
            r.skin_ms,
            r.update_ms,
            r.trace_ms,
            r.flat_build_ms,
            r.flat_trace_ms,
            r.hits,
            r.differ
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

    /// A small crowd: every frame has hits, its image is written, and the instanced hits
    /// are the flat tree's: the same instance and triangle at the same distance up to the
    /// rounding of the ray transform, for all but a few pixels grazing an edge.
    #[test]
    fn crowd_traces_like_a_flat_tree() {
        let out = tempfile::tempdir().unwrap();
        let cfg = Crowd {
            scene: bundled_scene(),
            instances: 9,
            poses: 2,
            frames: 3,
            width: 48,
            height: 32,
            out: out.path().to_path_buf(),
        };
        let reports = run(&cfg, |r, hits, flat| {
            assert_eq!(r.differ, differing(hits, flat));
            assert!(
                r.differ * 100 <= hits.len(),
                "frame {}: {} pixels differ",
                r.frame,
                r.differ
            );
        })
        .unwrap();
        for r in &reports {
            assert!(r.hits > 0, "frame {}: nothing hit", r.frame);
            assert!(std::fs::metadata(&r.png).unwrap().len() > 100);
        }
    }
}
