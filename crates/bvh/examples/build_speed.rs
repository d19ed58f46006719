//! Quick build-speed check of every builder on one scene (not a benchmark suite; the
//! criterion benches and peer comparisons live elsewhere).
//!
//! `cargo run --release -p bvh --example build_speed -- [SCENE] [THREADS...]`
//! (default `proc:soup?n=1000000`, threads 1 and 2). Prints build time, throughput, SAH and
//! SAH relative to the full sweep build, and whether the validator accepts the tree.
//! `BVH_ONLY=name` runs only builders whose name contains it; `BVH_SKIP_SWEEP=1` skips the
//! sweep reference and `BVH_RUNS=n` sets the runs per row (default 3; for profiling).

use bvh::{
    validate, AtrbvhConfig, BinnedSahBuilder, BuildError, Bvh2, HlbvhAtrbvhBuilder, HlbvhBuilder,
    HlbvhSahBuilder, LbvhBuilder, MortonBits, SweepSahBuilder,
};
use geom::Aabb;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args
        .first()
        .cloned()
        .unwrap_or_else(|| "proc:soup?n=1000000".into());
    let threads: Vec<usize> = if args.len() > 1 {
        args[1..]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?
    } else {
        vec![1, 2]
    };
    let scene = scene::open(&spec, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let prims = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
    println!("{spec}: {} primitives", prims.len());
    let reference = match std::env::var("BVH_SKIP_SWEEP") {
        Ok(_) => f64::NAN,
        Err(_) => SweepSahBuilder::default().build(&prims)?.sah(),
    };
    println!(
        "{:<14} {:>3} {:>9} {:>9} {:>8} {:>8} {:>5} {:>8} {:>5}",
        "builder", "thr", "ms", "Mprims/s", "SAH", "vs sweep", "valid", "nodes", "depth"
    );
    type Build = Box<dyn Fn(&[Aabb], usize) -> Result<Bvh2, BuildError>>;
    let builders: Vec<(&str, u32, Build)> = vec![
        (
            "sweep-sah",
            8,
            Box::new(|p, t| {
                SweepSahBuilder {
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "binned-sah/8",
            8,
            Box::new(|p, t| {
                BinnedSahBuilder {
                    bins: 8,
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "binned-sah/16",
            8,
            Box::new(|p, t| {
                BinnedSahBuilder {
                    bins: 16,
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "binned-sah/32",
            8,
            Box::new(|p, t| {
                BinnedSahBuilder {
                    bins: 32,
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "lbvh/30",
            1,
            Box::new(|p, t| {
                LbvhBuilder {
                    bits: MortonBits::Bits30,
                    threads: t,
                }
                .build(p)
            }),
        ),
        (
            "lbvh/63",
            1,
            Box::new(|p, t| {
                LbvhBuilder {
                    bits: MortonBits::Bits63,
                    threads: t,
                }
                .build(p)
            }),
        ),
        (
            "hlbvh/30",
            8,
            Box::new(|p, t| {
                HlbvhBuilder {
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "hlbvh/63",
            8,
            Box::new(|p, t| {
                HlbvhBuilder {
                    bits: MortonBits::Bits63,
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "hlbvh+sah",
            8,
            Box::new(|p, t| {
                HlbvhSahBuilder {
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "hlbvh+atrbvh-cells",
            8,
            Box::new(|p, t| {
                HlbvhAtrbvhBuilder {
                    cells: Some(AtrbvhConfig::one_pass()),
                    threads: t,
                    ..Default::default()
                }
                .build(p)
            }),
        ),
    ];
    // BVH_ONLY=substring restricts the run to matching builders (for profiling).
    let only = std::env::var("BVH_ONLY").unwrap_or_default();
    let runs: usize = std::env::var("BVH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3)
        .max(1);
    for (name, max_leaf, build) in builders.iter().filter(|b| b.0.contains(&only)) {
        for &t in &threads {
            // Best of `runs` runs (the pool is created inside `build` and is included).
            let mut best = f64::INFINITY;
            let mut tree = None;
            for _ in 0..runs {
                let start = Instant::now();
                let b = build(&prims, t)?;
                best = best.min(start.elapsed().as_secs_f64());
                tree = Some(b);
            }
            let tree = tree.expect("built");
            let sah = tree.sah();
            println!(
                "{:<14} {:>3} {:>9.1} {:>9.2} {:>8.2} {:>8.3} {:>5} {:>8} {:>5}",
                name,
                t,
                best * 1e3,
                prims.len() as f64 / best / 1e6,
                sah,
                sah / reference,
                validate(&tree, &prims, *max_leaf).is_ok(),
                tree.nodes.len(),
                tree.stats().max_depth
            );
        }
    }
    Ok(())
}
