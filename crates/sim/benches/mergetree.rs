//! Simulation speed of the MergeTree model, in simulated unit cycles per second on one core
//! (criterion's "elem/s"), on the simple model of each \[P2\] memory system (so the time is
//! the model's own; DRAMsim3's cost is measured by the `dram` bench), beside the software
//! HLBVH builder on the same boxes (one thread, "elem/s" = triangles per second), so the
//! report gives their ratio from one run.
//!
//! `cargo bench -p sim --bench mergetree`. The goal is 20 M cycles per second.

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

criterion_group!(benches, bench);
criterion_main!(benches);
