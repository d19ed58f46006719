//! Criterion benches of the main builders against the peers, per mesh: Arbor's LBVH,
//! HLBVH (also with large primitives apart, `hlbvh-large`), HLBVH+ATRBVH with the cells
//! restructured (`hlbvh+atrbvh-cells`), binned SAH (16 bins) and 4-wide top-down builder; Embree 3 LOW and MEDIUM
//! (feature `embree`), obvhs PLOC (fastest preset) and the bvh crate, each on one thread
//! (Arbor's builders and obvhs in a 1-thread rayon pool created outside the timing; Embree
//! on a 1-thread device). Throughput is in primitives.
//!
//! `cargo bench -p peers --bench build` (add `--features embree` for the Embree rows).
//! Meshes: a 200K-triangle procedural soup, and `../shared/scenes/dragon.ply` (871K) when
//! it exists; `ARBOR_BENCH_SCENES` (comma-separated `scene::open` specs) replaces them.
//! The timed part of a peer here includes its input copy and its conversion to `Bvh2`
//! (criterion times the whole call); `arbor bench build` times the peer's build call alone
//! and reports peak memory, in one table.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use geom::Aabb;
use std::time::Duration;

/// The meshes: `(name, boxes)`.
fn meshes() -> Vec<(String, Vec<Aabb>)> {
    let specs: Vec<String> = match std::env::var("ARBOR_BENCH_SCENES") {
        Ok(v) => v.split(',').map(str::to_string).collect(),
        Err(_) => {
            let mut v = vec!["proc:soup?n=200000".to_string()];
            let dragon = concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../../shared/scenes/dragon.ply"
            );
            if std::path::Path::new(dragon).exists() {
                v.push(dragon.to_string());
            }
            v
        }
    };
    specs
        .into_iter()
        .map(|spec| {
            let scene = scene::open(&spec, &Default::default()).expect("open scene");
            let mesh = scene.mesh_at(0.0).expect("sample scene");
            let boxes = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)
                .expect("triangle boxes");
            let name = spec.rsplit('/').next().unwrap_or(&spec).to_string();
            (name, boxes)
        })
        .collect()
}

fn bench_builders(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    #[cfg(feature = "embree")]
    let device = peers::EmbreeDevice::new(1).expect("Embree device");
    for (name, boxes) in meshes() {
        let mut g = c.benchmark_group(format!("build/{name}"));
        g.throughput(Throughput::Elements(boxes.len() as u64));
        g.sample_size(10);
        g.warm_up_time(Duration::from_millis(500));
        g.measurement_time(Duration::from_secs(3));
        let b = &boxes;
        let mut arbor = |id: &str, f: &(dyn Fn() -> usize + Sync)| {
            g.bench_function(BenchmarkId::new(id, b.len()), |bn| {
                bn.iter(|| pool.install(f))
            });
        };
        arbor("arbor lbvh", &|| {
            bvh::LbvhBuilder::default().build(b).unwrap().nodes.len()
        });
        arbor("arbor hlbvh", &|| {
            bvh::HlbvhBuilder::default().build(b).unwrap().nodes.len()
        });
        arbor("arbor hlbvh-large", &|| {
            bvh::HlbvhBuilder {
                large_prims: Some(bvh::LARGE_PRIMS_FRACTION),
                ..Default::default()
            }
            .build(b)
            .unwrap()
            .nodes
            .len()
        });
        // Issue 34's goal row: HLBVH+ATRBVH with the cells restructured (one pass), as
        // `arbor build --builder hlbvh+atrbvh-cells`.
        arbor("arbor hlbvh+atrbvh-cells", &|| {
            bvh::HlbvhAtrbvhBuilder {
                cells: Some(bvh::AtrbvhConfig::one_pass()),
                ..Default::default()
            }
            .build(b)
            .unwrap()
            .nodes
            .len()
        });
        arbor("arbor binned-sah", &|| {
            bvh::BinnedSahBuilder::default()
                .build(b)
                .unwrap()
                .nodes
                .len()
        });
        arbor("arbor mbvh4-topdown", &|| {
            bvh::Mbvh4TopDownBuilder::default()
                .build(b)
                .unwrap()
                .nodes
                .len()
        });
        arbor("obvhs PLOC fastest", &|| {
            peers::ObvhsBuilder::default()
                .build(b)
                .unwrap()
                .bvh
                .nodes
                .len()
        });
        arbor("bvh crate", &|| {
            peers::BvhCrateBuilder { threads: 1 }
                .build(b)
                .unwrap()
                .bvh
                .nodes
                .len()
        });
        #[cfg(feature = "embree")]
        for (id, quality) in [
            ("embree LOW", peers::EmbreeQuality::Low),
            ("embree MEDIUM", peers::EmbreeQuality::Medium),
        ] {
            let e = peers::EmbreeBuilder {
                quality,
                ..Default::default()
            };
            g.bench_function(BenchmarkId::new(id, b.len()), |bn| {
                bn.iter(|| e.build_on(&device, b).unwrap().bvh.nodes.len())
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench_builders);
criterion_main!(benches);
