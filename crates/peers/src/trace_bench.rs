//! Side-by-side traversal throughput: the same rays traced by Arbor's kernels and by the
//! peer tracers (Embree 3's `rtcIntersect1`, obvhs's CWBVH traversal), on 1 or more
//! threads, in one run (issue 4, "Speed, against Embree"). `arbor bench trace` is a thin
//! layer over [`RaySets::record`] and [`measure`].
//!
//! Ray sets come from an Arbor render of the scene: the primary rays (coherent), and the
//! diffuse bounce rays of a path-traced render (incoherent), recorded as traced. Each
//! tracer answers closest-hit queries for the same rays; its hits are compared with
//! Arbor's (same primitive, or the same distance to 1e-4 relative, since ties on shared
//! edges may go either way in a peer), and the agreement is reported beside the speed.

use geom::Ray;
use rayon::prelude::*;
use std::time::Instant;
use trace::{Query, RayKind, RenderSettings, Shading, Traverse};

/// The rays of a benchmark.
#[derive(Clone, Debug)]
pub struct RaySets {
    /// Primary (camera) rays, one per pixel.
    pub primary: Vec<Ray>,
    /// Diffuse bounce rays of a path-traced render (bounces 1 and up).
    pub diffuse: Vec<Ray>,
}

impl RaySets {
    /// Records the rays of a primary render and of a diffuse render with `bounces`
    /// bounces of `settings` (size, camera, seed), traced with `accel`.
    pub fn record<T: Traverse>(
        accel: &T,
        shading: Shading<'_>,
        settings: &RenderSettings,
        bounces: u32,
    ) -> Result<Self, trace::TraceError> {
        let collect = |kind: RayKind| -> Result<Vec<(Ray, u8, Query)>, trace::TraceError> {
            let mut s = settings.clone();
            s.rays = kind;
            s.bounces = bounces;
            let mut all = Vec::new();
            trace::render::render_observed(
                accel,
                shading,
                &s,
                trace::render::RayRecorder::default,
                |r| {
                    all.extend(r.rays);
                    Ok(())
                },
                None,
            )?;
            Ok(all)
        };
        let primary = collect(RayKind::Primary)?
            .into_iter()
            .map(|r| r.0)
            .collect();
        let diffuse = collect(RayKind::Diffuse)?
            .into_iter()
            .filter(|r| r.1 > 0)
            .map(|r| r.0)
            .collect();
        Ok(Self { primary, diffuse })
    }
}

pub use trace::thread_cpu_seconds;

/// One measurement.
#[derive(Clone, Copy, Debug)]
pub struct Measured {
    /// CPU time of the worker threads in the repetition with the best wall time.
    pub cpu_seconds: f64,
    /// Best wall time over the repetitions, in seconds.
    pub seconds: f64,
    /// Millions of rays per second at the best time.
    pub mrays_per_s: f64,
    /// Rays that hit.
    pub hits: u64,
}

/// Traces `rays` with `closest` (which returns `(primitive, t)` of the closest hit, using
/// per-thread scratch state made by `init`, e.g. a traversal stack) on a private pool of
/// `threads` threads, `repeats` times, and reports the best time. The results of the last
/// repetition are stored in `out` (one entry per ray) when given.
pub fn measure<S, I, F>(
    rays: &[Ray],
    threads: usize,
    repeats: usize,
    init: I,
    closest: F,
    out: Option<&mut Vec<Option<(u32, f32)>>>,
) -> Result<Measured, crate::PeerError>
where
    I: Fn() -> S + Sync,
    F: Fn(&mut S, &[Ray], &mut [Option<(u32, f32)>]) + Sync,
{
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| crate::PeerError::ThreadPool(e.to_string()))?;
    let mut best = f64::INFINITY;
    let mut best_cpu = f64::INFINITY;
    let mut results: Vec<Option<(u32, f32)>> = vec![None; rays.len()];
    for _ in 0..repeats.max(1) {
        let cpu_ns = std::sync::atomic::AtomicU64::new(0);
        let start = Instant::now();
        pool.install(|| {
            results
                .par_chunks_mut(1024)
                .zip(rays.par_chunks(1024))
                .for_each(|(res, rs)| {
                    let c0 = thread_cpu_seconds();
                    let mut state = init();
                    closest(&mut state, rs, res);
                    let ns = ((thread_cpu_seconds() - c0) * 1e9) as u64;
                    cpu_ns.fetch_add(ns, std::sync::atomic::Ordering::Relaxed);
                })
        });
        best = best.min(start.elapsed().as_secs_f64());
        best_cpu = best_cpu.min(cpu_ns.into_inner() as f64 * 1e-9);
    }
    let hits = results.iter().filter(|h| h.is_some()).count() as u64;
    if let Some(o) = out {
        *o = results;
    }
    Ok(Measured {
        cpu_seconds: best_cpu,
        seconds: best,
        mrays_per_s: if best > 0.0 {
            rays.len() as f64 / best / 1e6
        } else {
            0.0
        },
        hits,
    })
}

/// The fraction of rays on which two tracers agree: both miss, or both hit the same
/// primitive or at the same distance (to 1e-4 relative).
pub fn agreement(a: &[Option<(u32, f32)>], b: &[Option<(u32, f32)>]) -> f64 {
    if a.is_empty() {
        return 1.0;
    }
    let same = a
        .iter()
        .zip(b)
        .filter(|(x, y)| match (x, y) {
            (None, None) => true,
            (Some((p, t)), Some((q, u))) => p == q || (t - u).abs() <= 1e-4 * t.abs().max(u.abs()),
            _ => false,
        })
        .count();
    same as f64 / a.len() as f64
}

/// A scene and view to benchmark.
pub struct BenchScene<'a> {
    /// Name for the table.
    pub name: String,
    /// Vertex positions.
    pub positions: &'a [geom::Vec3],
    /// Vertex indices of each triangle.
    pub indices: &'a [[u32; 3]],
    /// The camera.
    pub camera: scene::Camera,
    /// Image width (rays per row).
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Diffuse bounces of the incoherent ray set.
    pub bounces: u32,
}

/// One row of the traversal benchmark.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TraceRow {
    /// Scene name.
    pub scene: String,
    /// Tracer name.
    pub tracer: String,
    /// `primary` or `diffuse`.
    pub rays: &'static str,
    /// Rays in the set.
    pub ray_count: usize,
    /// Worker threads.
    pub threads: usize,
    /// Millions of rays per second (best of the repetitions).
    pub mrays_per_s: f64,
    /// Throughput relative to Embree's on the same rays and threads (null without Embree).
    pub vs_embree: Option<f64>,
    /// Millions of rays per second of worker-thread CPU time (best of the repetitions):
    /// steadier than wall time on a machine shared with other work.
    pub mrays_per_cpu_s: f64,
    /// `mrays_per_cpu_s` relative to Embree's.
    pub vs_embree_cpu: Option<f64>,
    /// Fraction of rays whose hit agrees with Arbor's reference kernel.
    pub agreement: f64,
    /// Tree build time of this tracer, in ms (its own builder).
    pub build_ms: f64,
    /// Rays one thread traces at once, interleaved (`trace::Interleave`): 1 for Arbor's
    /// kernels but the 8-wide one over a tree larger than the last-level cache (or forced);
    /// null for the peers, which take one ray per call.
    pub interleave: Option<usize>,
    /// Wall time of every round, in round order, ms (for benchmark records' spread).
    pub round_ms: Vec<f64>,
}

/// Arbor tracer configurations of the benchmark: (name, builder, format, distance stack).
pub const ARBOR_KERNELS: [(&str, &str, bool, bool); 8] = [
    ("arbor bvh2 binned-sah", "binned-sah", false, false),
    ("arbor bvh2 binned-sah +dist", "binned-sah", false, true),
    ("arbor mbvh4 collapse(binned-sah)", "binned-sah", true, true),
    ("arbor mbvh4 topdown", "mbvh4-topdown", true, true),
    (
        "arbor mbvh8 collapse(binned-sah)",
        "binned-sah-8",
        true,
        true,
    ),
    // The same kernel with batches always interleaving eight rays per thread (the row
    // above interleaves only over trees larger than the last-level cache; issue 33).
    (
        "arbor mbvh8 collapse(binned-sah) interleave 8",
        "binned-sah-8-x8",
        true,
        true,
    ),
    // The same binary tree collapsed with leaves costed in blocks of four triangles
    // (`bvh::collapse_wide_blocks`): faster on fine meshes, slower on Conference, so not
    // the kernel's default collapse (issue 33).
    (
        "arbor mbvh8 collapse-blocks(binned-sah)",
        "binned-sah-8-blocks",
        true,
        true,
    ),
    // Spatial splits (`bvh::SbvhBuilder`, default configuration) under the same 8-wide
    // collapse and kernel: what tree quality alone buys (issue 33).
    ("arbor mbvh8 collapse(sbvh)", "sbvh-8", true, true),
];

/// Runs the whole comparison on `scene`: builds every tracer, records the two ray sets
/// with the first Arbor kernel, and measures every tracer on both sets for each thread
/// count. `note` is called with a line of progress.
pub fn run(
    scene: &BenchScene<'_>,
    threads: &[usize],
    repeats: usize,
    note: &dyn Fn(&str),
) -> Result<Vec<TraceRow>, Box<dyn std::error::Error>> {
    use trace::{Accel, Bvh2Accel, KernelOptions, Mbvh4Accel};
    let tris: Vec<geom::Triangle> = scene
        .indices
        .iter()
        .map(|t| {
            geom::Triangle::new(
                scene.positions[t[0] as usize],
                scene.positions[t[1] as usize],
                scene.positions[t[2] as usize],
            )
        })
        .collect();
    let aabbs = bvh::triangle_aabbs(&tris);
    // Arbor's trees, built once each (binned SAH as in [P4] §3.2, Wald's top-down MBVH4).
    note("building Arbor trees");
    let t0 = Instant::now();
    let binned = bvh::BinnedSahBuilder::default().build(&aabbs)?;
    let binned_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t0 = Instant::now();
    let collapsed = bvh::collapse(&binned)?;
    let collapse_ms = binned_ms + t0.elapsed().as_secs_f64() * 1e3;
    let t0 = Instant::now();
    let topdown = bvh::Mbvh4TopDownBuilder::default().build(&aabbs)?;
    let topdown_ms = t0.elapsed().as_secs_f64() * 1e3;
    let mut kernels: Vec<(String, Accel, f64)> = Vec::new();
    for (name, builder, wide, dist) in ARBOR_KERNELS {
        let o = KernelOptions {
            distance_stack: dist,
        };
        let (a, ms) = match (builder, wide) {
            ("binned-sah", false) => (
                Accel::Bvh2(Bvh2Accel::new(binned.clone(), &tris, o)?),
                binned_ms,
            ),
            ("binned-sah", true) => (
                Accel::Mbvh4(Mbvh4Accel::new(collapsed.clone(), &tris, o)?),
                collapse_ms,
            ),
            ("sbvh-8", _) => {
                let t0 = Instant::now();
                let t = bvh::SbvhBuilder::default().build(&tris)?;
                let a = trace::Mbvh8Accel::from_bvh2(&t, &tris, o)?;
                (Accel::Mbvh8(a), t0.elapsed().as_secs_f64() * 1e3)
            }
            ("binned-sah-8", _) | ("binned-sah-8-x8", _) => {
                let t0 = Instant::now();
                let mut a = trace::Mbvh8Accel::from_bvh2(&binned, &tris, o)?;
                if builder == "binned-sah-8-x8" {
                    a = a.with_interleave(trace::Interleave::Rays(8));
                }
                (
                    Accel::Mbvh8(a),
                    binned_ms + t0.elapsed().as_secs_f64() * 1e3,
                )
            }
            ("binned-sah-8-blocks", _) => {
                let t0 = Instant::now();
                let w = bvh::collapse_wide_blocks::<{ trace::WIDTH8 }>(
                    &binned,
                    &bvh::SahParams::THESIS,
                    4,
                )?;
                let a = trace::Mbvh8Accel::new(w, &tris, o)?;
                (
                    Accel::Mbvh8(a),
                    binned_ms + t0.elapsed().as_secs_f64() * 1e3,
                )
            }
            _ => (
                Accel::Mbvh4(Mbvh4Accel::new(topdown.clone(), &tris, o)?),
                topdown_ms,
            ),
        };
        kernels.push((name.to_string(), a, ms));
    }
    drop((binned, collapsed, topdown));
    let mut settings = RenderSettings::new(scene.camera);
    settings.width = scene.width;
    settings.height = scene.height;
    note("recording ray sets");
    let shading = Shading {
        triangles: &tris,
        material_ids: &[],
    };
    let sets = RaySets::record(&kernels[0].1, shading, &settings, scene.bounces)?;

    #[cfg(feature = "embree")]
    let embree = {
        note("building the Embree scene");
        let device = std::sync::Arc::new(crate::EmbreeDevice::new(
            threads.iter().copied().max().unwrap_or(1),
        )?);
        let robust = crate::EmbreeScene::new(
            device.clone(),
            scene.positions,
            scene.indices,
            crate::EmbreeSceneConfig {
                robust: true,
                ..Default::default()
            },
        )?;
        let plain = crate::EmbreeScene::new(
            device,
            scene.positions,
            scene.indices,
            crate::EmbreeSceneConfig::default(),
        )?;
        (plain, robust)
    };
    note("building the obvhs CWBVH");
    let obvhs = crate::ObvhsTracer::new(&tris, crate::ObvhsPreset::MediumBuild)?;

    // Every tracer behind one signature, so that they can be measured in rounds: each
    // round times every tracer once, and each tracer's best round counts. Interleaving
    // spreads any change in the machine's load evenly over the tracers.
    // Arbor's kernels trace each run of rays as a batch (`Traverse::trace_batch`, which
    // the 8-wide kernel interleaves over trees larger than the cache); the peers take
    // one ray per call.
    type Scratch = (trace::TraversalStack, trace::RayStats);
    type Closest<'a> = Box<dyn Fn(&mut Scratch, &[Ray], &mut [Option<(u32, f32)>]) + Sync + 'a>;
    fn one_by_one<'a>(f: impl Fn(&Ray) -> Option<(u32, f32)> + Sync + 'a) -> Closest<'a> {
        Box::new(
            move |_: &mut Scratch, rays: &[Ray], out: &mut [Option<(u32, f32)>]| {
                for (o, r) in out.iter_mut().zip(rays) {
                    *o = f(r);
                }
            },
        )
    }
    // (name, build ms, rays interleaved per thread (None: a peer), the tracer)
    let mut tracers: Vec<(String, f64, Option<usize>, Closest<'_>)> = Vec::new();
    for (name, accel, ms) in &kernels {
        let lanes = match accel {
            Accel::Mbvh8(a) => a.interleave().1,
            _ => 1,
        };
        tracers.push((
            name.clone(),
            *ms,
            Some(lanes),
            Box::new(
                move |(st, stats): &mut Scratch, rays: &[Ray], out: &mut [Option<(u32, f32)>]| {
                    accel.trace_batch(rays, Query::Closest, st, |i, h, s| {
                        out[i] = h.map(|h| (h.prim, h.t));
                        stats.add(s);
                    })
                },
            ),
        ));
    }
    #[cfg(feature = "embree")]
    {
        tracers.push((
            "embree 3 rtcIntersect1 (MEDIUM)".into(),
            embree.0.build_time.as_secs_f64() * 1e3,
            None,
            one_by_one(|r| embree.0.intersect1(r)),
        ));
        tracers.push((
            "embree 3 rtcIntersect1 (MEDIUM, ROBUST)".into(),
            embree.1.build_time.as_secs_f64() * 1e3,
            None,
            one_by_one(|r| embree.1.intersect1(r)),
        ));
    }
    tracers.push((
        "obvhs cwbvh (medium_build)".into(),
        obvhs.build_time.as_secs_f64() * 1e3,
        None,
        one_by_one(|r| obvhs.intersect(r)),
    ));

    let embree_index = tracers
        .iter()
        .position(|t| t.0 == "embree 3 rtcIntersect1 (MEDIUM)");
    let mut rows = Vec::new();
    for (set_name, rays) in [("primary", &sets.primary), ("diffuse", &sets.diffuse)] {
        // An empty set (no bounces asked, or no primary ray hit) has no throughput: no rows.
        if rays.is_empty() {
            continue;
        }
        for &th in threads {
            note(&format!("{set_name} rays, {th} thread(s)"));
            let mut best = vec![f64::INFINITY; tracers.len()];
            let mut best_cpu = vec![f64::INFINITY; tracers.len()];
            let mut round_ms = vec![Vec::new(); tracers.len()];
            let mut answers: Vec<Vec<Option<(u32, f32)>>> = vec![Vec::new(); tracers.len()];
            for round in 0..repeats.max(1) {
                for (k, (_, _, _, f)) in tracers.iter().enumerate() {
                    let out = (round == 0).then_some(&mut answers[k]);
                    let m = measure(
                        rays,
                        th,
                        1,
                        || (trace::TraversalStack::new(), trace::RayStats::default()),
                        |s, rs, out| f(s, rs, out),
                        out,
                    )?;
                    best[k] = best[k].min(m.seconds);
                    best_cpu[k] = best_cpu[k].min(m.cpu_seconds);
                    round_ms[k].push(m.seconds * 1e3);
                }
            }
            let mrays = |k: usize| rays.len() as f64 / best[k] / 1e6;
            let mrays_cpu = |k: usize| rays.len() as f64 / best_cpu[k] / 1e6;
            let embree_m = embree_index.map(mrays);
            let embree_cpu = embree_index.map(mrays_cpu);
            for (k, (name, ms, lanes, _)) in tracers.iter().enumerate() {
                rows.push(TraceRow {
                    scene: scene.name.clone(),
                    tracer: name.clone(),
                    rays: set_name,
                    ray_count: rays.len(),
                    threads: th,
                    mrays_per_s: mrays(k),
                    vs_embree: embree_m.map(|e| mrays(k) / e),
                    mrays_per_cpu_s: mrays_cpu(k),
                    vs_embree_cpu: embree_cpu.map(|e| mrays_cpu(k) / e),
                    agreement: agreement(&answers[0], &answers[k]),
                    build_ms: *ms,
                    interleave: *lanes,
                    round_ms: round_ms[k].clone(),
                });
            }
        }
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Triangle, Vec3};

    #[test]
    fn measure_and_agreement_on_a_tiny_scene() {
        let tris: Vec<Triangle> = (0..200)
            .map(|i| {
                let x = (i % 20) as f32;
                let y = (i / 20) as f32;
                Triangle::new(
                    Vec3::new(x, y, 0.0),
                    Vec3::new(x + 1.0, y, 0.0),
                    Vec3::new(x, y + 1.0, 0.0),
                )
            })
            .collect();
        let tree = bvh::BinnedSahBuilder::default()
            .build(&bvh::triangle_aabbs(&tris))
            .unwrap();
        let accel = trace::Bvh2Accel::new(tree, &tris, Default::default()).unwrap();
        let mut s = RenderSettings::new(scene::Camera {
            eye: Vec3::new(10.0, 5.0, 20.0),
            target: Vec3::new(10.0, 5.0, 0.0),
            up: Vec3::Y,
            vfov_deg: 60.0,
        });
        s.width = 32;
        s.height = 16;
        let shading = Shading {
            triangles: &tris,
            material_ids: &[],
        };
        let sets = RaySets::record(&accel, shading, &s, 2).unwrap();
        assert_eq!(sets.primary.len(), 32 * 16);
        // A flat floor: every bounce escapes, so there is one bounce ray per primary hit.
        let mut res = Vec::new();
        let m = measure(
            &sets.primary,
            2,
            2,
            || (trace::TraversalStack::new(), trace::RayStats::default()),
            |(st, stats), rs, out| {
                for (o, r) in out.iter_mut().zip(rs) {
                    *o = accel.closest_hit(r, st, stats).map(|h| (h.prim, h.t));
                }
            },
            Some(&mut res),
        )
        .unwrap();
        assert_eq!(sets.diffuse.len() as u64, m.hits);
        assert!(m.mrays_per_s > 0.0);
        assert_eq!(agreement(&res, &res), 1.0);
        let none = vec![None; res.len()];
        assert!(agreement(&res, &none) < 1.0);
    }
}
