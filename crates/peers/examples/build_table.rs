//! Build speed and quality of Arbor's builders next to the peers', as a Markdown table.
//!
//! `cargo run --release -p peers --features embree --example build_table -- SCENE...`
//!
//! For every scene (any `scene::open` spec), the triangle boxes of frame 0 are built by
//! each builder on 1 and 2 threads, best wall time of 3 runs (the peer's build call only;
//! conversion to `Bvh2` excluded). Every tree is validated; SAH is Arbor's `Bvh2::sah`
//! with the thesis weights for all builders. "vs sweep" divides by the SAH of Arbor's full
//! sweep SAH tree (skipped above 2M triangles, too slow); "vs Embree LOW" is throughput
//! over Embree's Morton builder at the same thread count (feature `embree`).

use bvh::{BinnedSahBuilder, Bvh2, LbvhBuilder, SweepSahBuilder};
use geom::Aabb;
use peers::{BvhCrateBuilder, ObvhsBuilder, ObvhsPreset, PeerError};
use std::time::{Duration, Instant};

/// Largest scene for which the sweep SAH reference is built.
const SWEEP_MAX: usize = 2_000_000;
/// Runs per measurement (the best is kept).
const RUNS: usize = 3;

/// A build: boxes and thread count in, the tree and its timed part out.
type BuildFn = Box<dyn Fn(&[Aabb], usize) -> Result<(Bvh2, Duration), String>>;

/// One builder: its name, its validator leaf maximum, and a build returning the tree and
/// the timed part.
struct Entry {
    name: String,
    max_leaf: u32,
    build: BuildFn,
}

fn arbor<F>(name: &str, max_leaf: u32, f: F) -> Entry
where
    F: Fn(&[Aabb], usize) -> Result<Bvh2, bvh::BuildError> + 'static,
{
    Entry {
        name: name.to_string(),
        max_leaf,
        build: Box::new(move |a, threads| {
            let start = Instant::now();
            let t = f(a, threads).map_err(|e| e.to_string())?;
            Ok((t, start.elapsed()))
        }),
    }
}

fn peer<F>(name: &str, max_leaf: u32, f: F) -> Entry
where
    F: Fn(&[Aabb], usize) -> Result<peers::PeerBuild, PeerError> + 'static,
{
    Entry {
        name: name.to_string(),
        max_leaf,
        build: Box::new(move |a, threads| {
            let b = f(a, threads).map_err(|e| e.to_string())?;
            Ok((b.bvh, b.build_time))
        }),
    }
}

/// Every builder, for measurements on `threads` threads (Embree's device is created here,
/// once per thread count, so its thread start-up is not in any run).
fn builders(threads: usize) -> Result<Vec<Entry>, String> {
    let mut v = vec![
        arbor("arbor lbvh", 1, |a, threads| {
            LbvhBuilder {
                threads,
                ..Default::default()
            }
            .build(a)
        }),
        arbor("arbor hlbvh", 8, |a, threads| {
            bvh::HlbvhBuilder {
                threads,
                ..Default::default()
            }
            .build(a)
        }),
        arbor("arbor hlbvh+sah", 8, |a, threads| {
            bvh::HlbvhSahBuilder {
                threads,
                ..Default::default()
            }
            .build(a)
        }),
        arbor("arbor hlbvh+atrbvh", 8, |a, threads| {
            bvh::HlbvhAtrbvhBuilder {
                threads,
                ..Default::default()
            }
            .build(a)
        }),
        arbor("arbor atrbvh", 8, |a, threads| {
            bvh::AtrbvhBuilder {
                config: bvh::AtrbvhConfig {
                    threads,
                    ..Default::default()
                },
                ..Default::default()
            }
            .build(a)
        }),
        arbor("arbor binned-sah/16", 8, |a, threads| {
            BinnedSahBuilder {
                bins: 16,
                threads,
                ..Default::default()
            }
            .build(a)
        }),
    ];
    #[cfg(feature = "embree")]
    let device = std::rc::Rc::new(peers::EmbreeDevice::new(threads).map_err(|e| e.to_string())?);
    #[cfg(not(feature = "embree"))]
    let _ = threads;
    #[cfg(feature = "embree")]
    for (name, quality) in [
        ("embree LOW", peers::EmbreeQuality::Low),
        ("embree MEDIUM", peers::EmbreeQuality::Medium),
    ] {
        let device = device.clone();
        v.push(peer(name, 8, move |a, _threads| {
            peers::EmbreeBuilder {
                quality,
                ..Default::default()
            }
            .build_on(&device, a)
        }));
    }
    for (name, preset) in [
        ("obvhs PLOC fastest_build", ObvhsPreset::FastestBuild),
        ("obvhs PLOC fast_build", ObvhsPreset::FastBuild),
    ] {
        v.push(peer(name, preset.max_leaf_size(), move |a, threads| {
            ObvhsBuilder { preset, threads }.build(a)
        }));
    }
    v.push(peer("bvh crate", 1, |a, threads| {
        BvhCrateBuilder { threads }.build(a)
    }));
    Ok(v)
}

fn main() {
    let specs: Vec<String> = std::env::args().skip(1).collect();
    if specs.is_empty() {
        eprintln!("usage: build_table SCENE...");
        std::process::exit(2);
    }
    println!("| scene | triangles | builder | threads | build ms | Mtris/s | SAH | SAH vs sweep | vs Embree LOW |");
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|");
    for spec in &specs {
        if let Err(e) = table(spec) {
            eprintln!("{spec}: {e}");
            std::process::exit(1);
        }
    }
}

fn table(spec: &str) -> Result<(), String> {
    let scene = scene::open(spec, &Default::default()).map_err(|e| e.to_string())?;
    let mesh = scene.mesh_at(0.0).map_err(|e| e.to_string())?;
    let aabbs =
        bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).map_err(|e| e.to_string())?;
    drop(mesh);
    let n = aabbs.len();
    let name = std::path::Path::new(spec)
        .file_name()
        .map_or(spec.to_string(), |f| f.to_string_lossy().into_owned());
    let sweep_sah = (n <= SWEEP_MAX).then(|| {
        let t = SweepSahBuilder::default()
            .build(&aabbs)
            .expect("sweep build");
        t.sah()
    });
    let sweep_row = |threads: usize| -> Result<(), String> {
        let Some(sah) = sweep_sah else { return Ok(()) };
        let entry = arbor("arbor sweep-sah", 8, |a, threads| {
            SweepSahBuilder {
                threads,
                ..Default::default()
            }
            .build(a)
        });
        let (t, best) = measure(&entry, &aabbs, threads)?;
        debug_assert_eq!(t.sah(), sah);
        row(
            &name,
            n,
            &entry.name,
            threads,
            best,
            t.sah(),
            Some(sah),
            None,
        );
        Ok(())
    };
    for threads in [1, 2] {
        let mut rows = Vec::new();
        for entry in builders(threads)? {
            let (t, best) = measure(&entry, &aabbs, threads)?;
            rows.push((entry.name, best, t.sah()));
        }
        let low = rows
            .iter()
            .find(|r| r.0 == "embree LOW")
            .map(|r| r.1.as_secs_f64());
        for (b, best, sah) in &rows {
            let vs_low = low.map(|l| l / best.as_secs_f64());
            row(&name, n, b, threads, *best, *sah, sweep_sah, vs_low);
        }
        sweep_row(threads)?;
    }
    Ok(())
}

/// Best of [`RUNS`] builds; the tree of the last run is validated and returned.
fn measure(entry: &Entry, aabbs: &[Aabb], threads: usize) -> Result<(Bvh2, Duration), String> {
    let mut best = Duration::MAX;
    let mut tree = None;
    for _ in 0..RUNS {
        let (t, d) = (entry.build)(aabbs, threads).map_err(|e| format!("{}: {e}", entry.name))?;
        best = best.min(d);
        tree = Some(t);
    }
    let tree = tree.expect("RUNS > 0");
    bvh::validate(&tree, aabbs, entry.max_leaf)
        .map_err(|e| format!("{}: invalid tree: {e}", entry.name))?;
    Ok((tree, best))
}

#[allow(clippy::too_many_arguments)]
fn row(
    scene: &str,
    n: usize,
    builder: &str,
    threads: usize,
    best: Duration,
    sah: f64,
    sweep: Option<f64>,
    vs_low: Option<f64>,
) {
    let ms = best.as_secs_f64() * 1e3;
    let mtris = n as f64 / best.as_secs_f64() / 1e6;
    let vs_sweep = sweep.map_or("—".to_string(), |s| format!("{:.3}", sah / s));
    let vs_low = vs_low.map_or("—".to_string(), |r| format!("{r:.2}x"));
    println!(
        "| {scene} | {n} | {builder} | {threads} | {ms:.1} | {mtris:.2} | {sah:.2} | {vs_sweep} | {vs_low} |"
    );
}
