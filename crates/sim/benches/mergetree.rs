//! Simulation speed of the MergeTree model, in simulated unit cycles per second on one core
//! (criterion's "elem/s"), on the simple model of each \[P2\] memory system (so the time is
//! the model's own; DRAMsim3's cost is measured by the `dram` bench), beside the software
//! HLBVH builder on the same boxes (one thread, "elem/s" = triangles per second), so the
//! report gives their ratio from one run.
//!
//! A second group, `mergetree/dragon`, runs the model on the Dragon scan
//! (`../shared/scenes/dragon.ply`, about 871 k triangles, preset p2) on the slow system,
//! once on Arbor's DRAM controller model (`lpddr3-1600-1x64`, the default, timing equal to
//! DRAMsim3's) and once on `simple:lpddr3-1600-1x64`; it prints a note and is skipped when
//! the scene is missing. DRAMsim3 itself (`dramsim3:lpddr3-1600-1x64`, about 5x slower) is
//! left to `cargo run --release -p sim --example mergetree_speed -- ../shared/scenes/dragon.ply
//! dramsim3:lpddr3-1600-1x64`.
//!
//! `cargo bench -p sim --bench mergetree`. The goal is 20 M cycles per second on the
//! simple model; the DRAM model's is 5 M cycles per second on Dragon.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use sim::mergetree::{simulate, MergeTreeConfig};
use std::time::Duration;

/// Scenes: a coherent mesh (the procedural cloth, triangles in grid order) and a random
/// soup (no input-order coherence: the merge reads every run evenly).
const SCENES: [&str; 2] = ["proc:cloth?n=200000", "proc:soup?n=200000"];

fn boxes(spec: &str) -> Vec<geom::Aabb> {
    let scene = scene::open(spec, &Default::default()).expect("procedural scene");
    let mesh = scene.mesh_at(0.5).expect("mesh");
    bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).expect("boxes")
}

fn bench(c: &mut Criterion) {
    let cfg = MergeTreeConfig::p2();
    for spec in SCENES {
        let aabbs = boxes(spec);
        let name = spec
            .split('?')
            .next()
            .unwrap_or(spec)
            .trim_start_matches("proc:");
        let mut g = c.benchmark_group(format!("mergetree/{name}"));
        g.measurement_time(Duration::from_secs(4)).sample_size(10);
        for system in sim::thesis::P2_SYSTEMS {
            let dram = format!("simple:{system}");
            let open = || sim::dram::open(&dram, cfg.period_fs()).unwrap();
            // The cycle count is deterministic: measure it once for the throughput.
            let cycles = simulate(&aabbs, &cfg, open()).unwrap().cycles;
            g.throughput(Throughput::Elements(cycles));
            g.bench_with_input(BenchmarkId::new("model", &dram), &dram, |b, _| {
                b.iter_with_setup(open, |port| simulate(&aabbs, &cfg, port).unwrap().cycles)
            });
        }
        let hl = bvh::HlbvhBuilder {
            threads: 1,
            ..Default::default()
        };
        g.throughput(Throughput::Elements(aabbs.len() as u64));
        g.bench_function("software_hlbvh", |b| b.iter(|| hl.build(&aabbs).unwrap()));
        g.finish();
    }
}

/// Where the real scenes are, relative to the crate (cargo runs benches in the crate
/// directory) or to the workspace root.
fn dragon() -> Option<std::path::PathBuf> {
    [
        "../../../shared/scenes/dragon.ply",
        "../shared/scenes/dragon.ply",
    ]
    .iter()
    .map(std::path::PathBuf::from)
    .find(|p| p.is_file())
}

fn bench_dragon(c: &mut Criterion) {
    let Some(path) = dragon() else {
        println!("note: ../shared/scenes/dragon.ply not found; mergetree/dragon skipped");
        return;
    };
    let scene =
        scene::open(path.to_str().unwrap_or_default(), &Default::default()).expect("dragon scene");
    let mesh = scene.mesh_at(0.0).expect("mesh");
    let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).expect("boxes");
    let cfg = MergeTreeConfig::p2();
    let mut g = c.benchmark_group("mergetree/dragon");
    g.measurement_time(Duration::from_secs(10)).sample_size(10);
    for dram in ["lpddr3-1600-1x64", "simple:lpddr3-1600-1x64"] {
        let open = || sim::dram::open(dram, cfg.period_fs()).unwrap();
        let cycles = simulate(&aabbs, &cfg, open()).unwrap().cycles;
        g.throughput(Throughput::Elements(cycles));
        g.bench_with_input(BenchmarkId::new("model", dram), &dram, |b, _| {
            b.iter_with_setup(open, |port| simulate(&aabbs, &cfg, port).unwrap().cycles)
        });
    }
    g.finish();
}

criterion_group!(benches, bench, bench_dragon);
criterion_main!(benches);
