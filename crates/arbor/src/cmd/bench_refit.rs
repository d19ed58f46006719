//! `arbor bench refit`: what it costs per frame to bring a tracer up to date with an
//! animated mesh (same triangles, moved vertices), Arbor next to Embree 3 in one process
//! and one run, as ratios (issue 33, "Benchmarks").
//!
//! Every tracer builds its tree once, over the first frame: Arbor a binned SAH tree
//! (\[P4\] §3.2) prepared as each kernel (`bvh2`, `mbvh4`, `mbvh8` collapsed from it);
//! Embree 3 a `RTC_SCENE_FLAG_DYNAMIC` scene at build quality LOW whose geometry has
//! `RTC_BUILD_QUALITY_REFIT` (see `peers::EmbreeRefitScene`). Then, per frame, with the
//! frame's vertex positions already in memory (skinning is the renderer's work, not the
//! tracer's), Arbor resolves the indexed triangles into its triangle list and calls
//! `Accel::refit` (the packed triangles rewritten and every box recomputed bottom-up, in
//! place); Embree copies the positions into its vertex buffer and runs
//! `rtcUpdateGeometryBuffer`, `rtcCommitGeometry` and `rtcCommitScene`. A rebuild of the
//! 8-wide kernel per frame (binned SAH build, collapse, preparation) is measured beside
//! them for scale. `--runs` rounds each play the frames once per tracer in turn, so that
//! load from other processes falls on all alike, and each tracer's best round counts.
//! Everything runs on one thread (Arbor's refit is serial; the Embree device has one
//! worker).
//!
//! After the last frame, every tracer traces the primary rays of a 64x36 view of that
//! frame and its hits are compared with brute force over the frame's triangles
//! (`agreement`): Arbor's kernels must agree exactly (a refitted tree traces like a fresh
//! one), Embree up to its own rounding.

use super::bench::{markdown_report, text_report, RunInfo};
pub use super::bench_build::Format;
use super::bench_build::Rendered;
use super::{open_scene, thousands, SceneArgs};
use crate::progress::Ui;
use anyhow::Context;
use geom::{Ray, Triangle};
use report::table::Table;
use serde::Serialize;
use std::time::Instant;
use trace::{Accel, KernelOptions, RayStats, TraversalStack, Traverse};

/// Largest `--runs`.
pub const MAX_ROUNDS: usize = 100;
/// Largest `--frames`.
pub const MAX_FRAMES: u32 = 10_000;
/// True when this binary was built with Embree (`--features embree`).
pub const EMBREE: bool = cfg!(feature = "embree");
/// The Embree row's name.
const EMBREE_ROW: &str = "embree 3 refit commit (RTC_BUILD_QUALITY_REFIT)";
/// Size of the view whose primary rays check each tracer's hits after the last frame.
const CHECK_VIEW: (u32, u32) = (64, 36);

/// Arguments of `arbor bench refit`.
#[derive(clap::Args, Debug)]
pub struct BenchRefitArgs {
    /// Animated scenes (default: the bundled CesiumMan.glb).
    pub scenes: Vec<String>,
    /// Frames of each animation to update to, evenly spaced over it (fewer when the
    /// animation has fewer frames at its frame rate).
    #[arg(long, default_value_t = 30, value_name = "N")]
    pub frames: u32,
    /// Runs per measurement, interleaved over the tracers; the fastest counts (as `bench
    /// build --runs` and `bench trace --runs`).
    #[arg(long = "runs", default_value_t = 5, value_name = "N")]
    pub rounds: usize,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,
    /// Same as `--format json`.
    #[arg(long)]
    pub json: bool,
    /// Also write every format to DIR (bench-refit.txt, .md, .csv, .json), atomically.
    #[arg(long, value_name = "DIR")]
    pub out: Option<std::path::PathBuf>,
}

/// One tracer's per-frame update on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct RefitRow {
    /// Scene name.
    pub scene: String,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Frames per round.
    pub frames: usize,
    /// The tracer and its update.
    pub tracer: String,
    /// Milliseconds per frame in the fastest round.
    pub best_ms_per_frame: f64,
    /// Milliseconds per frame in the median round.
    pub median_ms_per_frame: f64,
    /// Embree's best time per frame over this one (above 1: faster than Embree); null
    /// without Embree.
    pub vs_embree: Option<f64>,
    /// Fraction of the check rays whose hit (triangle and distance) equals brute force's.
    pub agreement: f64,
    /// Milliseconds of the initial build (tree and preparation, or Embree's commit).
    pub build_ms: f64,
}

/// The document `arbor bench refit --json` prints (`arbor.bench.refit.v1`).
#[derive(Clone, Debug, Serialize)]
pub struct BenchRefitJson {
    /// `"arbor.bench.refit.v1"`.
    pub schema: &'static str,
    /// When, where and how it ran (flattened into the document).
    #[serde(flatten)]
    pub run: RunInfo,
    /// Rounds per measurement.
    pub rounds: usize,
    /// Whether the Embree row could run.
    pub embree: bool,
    /// Notes (a missing peer).
    pub notes: Vec<String>,
    /// Measurements.
    pub rows: Vec<RefitRow>,
}

fn check_args(a: &BenchRefitArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=MAX_ROUNDS).contains(&a.rounds),
        "--runs must be between 1 and {MAX_ROUNDS}, got {}",
        a.rounds
    );
    anyhow::ensure!(
        (2..=MAX_FRAMES).contains(&a.frames),
        "--frames must be between 2 and {MAX_FRAMES}, got {}",
        a.frames
    );
    Ok(())
}

/// A contender's per-frame update: the frame's mesh in, the tracer up to date.
type Update<'a> = Box<dyn FnMut(&scene::Mesh) -> anyhow::Result<()> + 'a>;
/// A contender's closest hit over its current state: (triangle, distance).
type ClosestHit<'a> = Box<dyn Fn(&Ray) -> Option<(u32, f32)> + 'a>;

/// One contender: a name, its initial build time, a per-frame update, and a closest-hit
/// query over its current state.
struct Contender<'a> {
    name: String,
    build_ms: f64,
    update: Update<'a>,
    hit: ClosestHit<'a>,
}

/// `mesh`'s triangles written into `out` (reused across frames).
fn resolve_into(mesh: &scene::Mesh, out: &mut Vec<Triangle>) {
    out.clear();
    out.extend(mesh.triangles.iter().map(|t| {
        let p = |k: usize| mesh.positions[t[k] as usize];
        Triangle::new(p(0), p(1), p(2))
    }));
}

/// An Arbor kernel over the binned SAH tree of `tris`.
fn arbor_accel(format: &str, tris: &[Triangle]) -> anyhow::Result<Accel> {
    let tree = bvh::BinnedSahBuilder::default().build(&bvh::triangle_aabbs(tris))?;
    let o = KernelOptions::default();
    Ok(match format {
        "bvh2" => Accel::Bvh2(trace::Bvh2Accel::new(tree, tris, o)?),
        "mbvh4" => Accel::Mbvh4(trace::Mbvh4Accel::new(bvh::collapse(&tree)?, tris, o)?),
        _ => Accel::Mbvh8(trace::Mbvh8Accel::from_bvh2(&tree, tris, o)?),
    })
}

fn closest(a: &Accel, r: &Ray) -> Option<(u32, f32)> {
    let (mut st, mut s) = (TraversalStack::new(), RayStats::default());
    a.closest_hit(r, &mut st, &mut s).map(|h| (h.prim, h.t))
}

/// The rows of one scene.
fn bench_scene(
    spec: &str,
    a: &BenchRefitArgs,
    ui: &Ui,
    note: &dyn Fn(&str),
) -> anyhow::Result<Vec<RefitRow>> {
    let sargs = SceneArgs {
        scene: spec.to_string(),
        fps: None,
        animation: None,
    };
    let (scene, _) = open_scene(&sargs, ui)?;
    let info = scene.info().clone();
    let tl = info.timeline;
    let available = tl.frame_count();
    anyhow::ensure!(
        available >= 2,
        "{spec}: not animated (one frame): nothing to refit"
    );
    let n = a.frames.min(available);
    note(&format!("{}: sampling {n} frames", info.name));
    let meshes: Vec<scene::Mesh> = (0..n)
        .map(|k| {
            let f = (k as u64 * (available - 1) as u64 / (n - 1).max(1) as u64) as u32;
            scene
                .mesh_at_frame(f)
                .with_context(|| format!("{spec}: cannot sample frame {f}"))
        })
        .collect::<anyhow::Result<_>>()?;
    let first = &meshes[0];
    anyhow::ensure!(
        meshes.iter().all(|m| m.triangles == first.triangles),
        "{spec}: the triangles change between frames; refitting needs the same topology"
    );
    let mut tris0 = Vec::new();
    resolve_into(first, &mut tris0);

    let mut contenders: Vec<Contender> = Vec::new();
    for format in ["bvh2", "mbvh4", "mbvh8"] {
        note(&format!("{}: preparing arbor {format}", info.name));
        let start = Instant::now();
        let accel = std::cell::RefCell::new(arbor_accel(format, &tris0)?);
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        let accel = std::rc::Rc::new(accel);
        let (upd, q) = (accel.clone(), accel);
        let mut buf = Vec::new();
        contenders.push(Contender {
            name: format!("arbor {format} binned-sah, Accel::refit"),
            build_ms,
            update: Box::new(move |m: &scene::Mesh| {
                resolve_into(m, &mut buf);
                upd.borrow_mut().refit(&buf)?;
                Ok(())
            }),
            hit: Box::new(move |r: &Ray| closest(&q.borrow(), r)),
        });
    }
    {
        let start = Instant::now();
        let accel = std::rc::Rc::new(std::cell::RefCell::new(arbor_accel("mbvh8", &tris0)?));
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        let (upd, q) = (accel.clone(), accel);
        let mut buf = Vec::new();
        contenders.push(Contender {
            name: "arbor mbvh8 binned-sah, rebuilt per frame".into(),
            build_ms,
            update: Box::new(move |m: &scene::Mesh| {
                resolve_into(m, &mut buf);
                *upd.borrow_mut() = arbor_accel("mbvh8", &buf)?;
                Ok(())
            }),
            hit: Box::new(move |r: &Ray| closest(&q.borrow(), r)),
        });
    }
    #[cfg(feature = "embree")]
    {
        note(&format!("{}: building the Embree scene", info.name));
        let device = std::sync::Arc::new(peers::EmbreeDevice::new(1)?);
        let s = peers::EmbreeRefitScene::new(device, &first.positions, &first.triangles)?;
        let build_ms = s.build_time.as_secs_f64() * 1e3;
        let s = std::rc::Rc::new(std::cell::RefCell::new(s));
        let (upd, q) = (s.clone(), s);
        contenders.push(Contender {
            name: EMBREE_ROW.into(),
            build_ms,
            update: Box::new(move |m: &scene::Mesh| {
                upd.borrow_mut().update(&m.positions)?;
                Ok(())
            }),
            hit: Box::new(move |r: &Ray| q.borrow().intersect1(r)),
        });
    }

    // Rounds: every contender plays frames 1, 2, ..., n-1, 0 in turn (back to the frame
    // it was built over, so that every round starts from the same state).
    let order: Vec<usize> = (1..meshes.len()).chain([0]).collect();
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); contenders.len()];
    for round in 0..a.rounds {
        note(&format!(
            "{}: round {} of {}",
            info.name,
            round + 1,
            a.rounds
        ));
        for (c, t) in contenders.iter_mut().zip(&mut times) {
            let start = Instant::now();
            for &k in &order {
                (c.update)(&meshes[k])?;
            }
            t.push(start.elapsed().as_secs_f64() * 1e3 / order.len() as f64);
        }
    }
    // The check, on the last frame (moved furthest from the built one's neighbourhood in
    // time, a stronger test than frame 0, where every tree is as built).
    let last = &meshes[meshes.len() - 1];
    for c in &mut contenders {
        (c.update)(last)?;
    }
    let mut tris_last = Vec::new();
    resolve_into(last, &mut tris_last);
    let camera = scene::camera::view_camera(&info.name, info.camera);
    let cam = trace::PinholeCamera::new(&camera, CHECK_VIEW.0, CHECK_VIEW.1)?;
    let rays: Vec<Ray> = (0..CHECK_VIEW.1)
        .flat_map(|y| (0..CHECK_VIEW.0).map(move |x| (x, y)))
        .map(|(x, y)| cam.pixel_ray(x, y))
        .collect();
    let truth: Vec<Option<(u32, f32)>> = rays
        .iter()
        .map(|r| trace::brute_force(r, &tris_last).map(|h| (h.prim, h.t)))
        .collect();

    let stat = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        (s[0], s[s.len() / 2])
    };
    let embree_best = contenders
        .iter()
        .zip(&times)
        .find(|(c, _)| c.name == EMBREE_ROW)
        .map(|(_, t)| stat(t).0);
    let rows = contenders
        .iter()
        .zip(&times)
        .map(|(c, t)| {
            let (best, median) = stat(t);
            let same = rays
                .iter()
                .zip(&truth)
                .filter(|(r, want)| {
                    let got = (c.hit)(r);
                    match (got, want) {
                        (None, None) => true,
                        (Some((p, t)), Some((wp, wt))) => {
                            p == *wp && (t == *wt || (t - wt).abs() <= 1e-4 * wt.abs().max(1.0))
                        }
                        _ => false,
                    }
                })
                .count();
            RefitRow {
                scene: info.name.clone(),
                triangles: first.triangles.len(),
                frames: order.len(),
                tracer: c.name.clone(),
                best_ms_per_frame: best,
                median_ms_per_frame: median,
                vs_embree: embree_best.map(|e| e / best),
                agreement: same as f64 / rays.len() as f64,
                build_ms: c.build_ms,
            }
        })
        .collect();
    Ok(rows)
}

/// Runs `arbor bench refit`.
pub fn run(a: &BenchRefitArgs, ui: &Ui) -> anyhow::Result<()> {
    check_args(a)?;
    let format = if a.json { Format::Json } else { a.format };
    if let Some(dir) = &a.out {
        anyhow::ensure!(!dir.is_file(), "--out {}: is a file", dir.display());
    }
    let run_info = RunInfo::start();
    let mut notes = Vec::new();
    if !EMBREE {
        notes.push(
            "built without Embree (cargo feature `embree`): no Embree row and no ratios".into(),
        );
    }
    let bundled = match a.scenes.is_empty() {
        true => Some(super::demo::bundled_scene()?),
        false => None,
    };
    let scenes: Vec<String> = match &bundled {
        Some(b) => vec![b.path.clone()],
        None => a.scenes.clone(),
    };
    let mut rows = Vec::new();
    for spec in &scenes {
        let spinner = std::cell::RefCell::new(None);
        let note = |m: &str| {
            spinner.replace(None);
            spinner.replace(Some(ui.spinner(m)));
        };
        rows.extend(bench_scene(spec, a, ui, &note)?);
        spinner.replace(None);
    }
    let doc = BenchRefitJson {
        schema: "arbor.bench.refit.v1",
        run: run_info.finish(),
        rounds: a.rounds,
        embree: EMBREE,
        notes,
        rows,
    };
    let json = serde_json::to_string_pretty(&doc)? + "\n";
    Rendered {
        text: text(&doc),
        markdown: markdown(&doc),
        csv: csv(&doc),
        json,
    }
    .emit(a.out.as_deref(), "bench-refit", format, false)?;
    Ok(())
}

fn preamble(d: &BenchRefitJson) -> Vec<String> {
    let mut v = d.run.lines().to_vec();
    v.push(format!(
        "per-frame update of an animated mesh from its vertex positions, one thread; best of \
         {} rounds; ratio: Embree's REFIT commit time over the row's (above 1: faster); \
         agreement: primary hits of a {}x{} view equal to brute force's after the last frame",
        d.rounds, CHECK_VIEW.0, CHECK_VIEW.1
    ));
    v.extend(d.notes.iter().cloned());
    v
}

const HEADERS: [&str; 8] = [
    "scene",
    "triangles",
    "tracer",
    "ms/frame",
    "median ms/frame",
    "vs Embree",
    "agreement",
    "build ms",
];

fn cells(r: &RefitRow) -> [String; 8] {
    [
        r.scene.clone(),
        thousands(r.triangles as u64),
        r.tracer.clone(),
        format!("{:.3}", r.best_ms_per_frame),
        format!("{:.3}", r.median_ms_per_frame),
        r.vs_embree.map_or("-".into(), |v| format!("{v:.2}x")),
        format!("{:.4}", r.agreement),
        format!("{:.1}", r.build_ms),
    ]
}

/// The measurements as a table.
fn table(d: &BenchRefitJson) -> Table {
    let mut t = Table::text(&HEADERS).right(&[1, 3, 4, 5, 6, 7]);
    for r in &d.rows {
        t.push(cells(r));
    }
    t
}

fn text(d: &BenchRefitJson) -> String {
    text_report(&preamble(d), &table(d), None)
}

fn markdown(d: &BenchRefitJson) -> String {
    markdown_report(&preamble(d), &table(d), None)
}

fn csv(d: &BenchRefitJson) -> String {
    let mut t = Table::text(&[
        "scene",
        "triangles",
        "frames",
        "tracer",
        "best_ms_per_frame",
        "median_ms_per_frame",
        "vs_embree",
        "agreement",
        "build_ms",
    ]);
    for r in &d.rows {
        t.push([
            r.scene.clone(),
            r.triangles.to_string(),
            r.frames.to_string(),
            r.tracer.clone(),
            r.best_ms_per_frame.to_string(),
            r.median_ms_per_frame.to_string(),
            r.vs_embree.map_or(String::new(), |v| v.to_string()),
            r.agreement.to_string(),
            r.build_ms.to_string(),
        ]);
    }
    t.csv()
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    #[test]
    fn resolving_follows_the_indices() {
        let mesh = scene::Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            triangles: vec![[0, 1, 2], [3, 2, 1]],
            ..Default::default()
        };
        let mut out = vec![Triangle::new(Vec3::ONE, Vec3::ONE, Vec3::ONE)];
        resolve_into(&mesh, &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!(out[1].v, [Vec3::Z, Vec3::Y, Vec3::X]);
    }
}
