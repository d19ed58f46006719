//! Criterion bench of the binned SAH builder's exact small-node split (`sorted_split`, a
//! quarter of a binned build), per primitive, with small against large input indices.
//!
//! `cargo bench -p bvh --bench split`. The primitive references carry their input index in
//! the `w` lane of a SIMD box, and that lane goes through the box arithmetic with x, y and
//! z. When the stored bits were the raw index, every index below 2^23 was a subnormal
//! float, and Intel cores take a microcode assist per subnormal operand: there the
//! small-index rows ran 2-3x slower than the large-index rows (issue 17). The two rows
//! should stay equal; a gap between them means that lane (or another one) is subnormal
//! again. Input: a 64K-triangle procedural soup, in nodes of 8 and 16 references.

use bvh::SortedSplitBench;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::time::Duration;

fn bench_sorted_split(c: &mut Criterion) {
    let scene = scene::open("proc:soup?n=65536", &Default::default()).expect("soup");
    let mesh = scene.mesh_at(0.0).expect("sample soup");
    let boxes = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).expect("boxes");
    for node in [8, 16] {
        let mut g = c.benchmark_group(format!("sorted_split/{node}"));
        g.throughput(Throughput::Elements(boxes.len() as u64));
        g.sample_size(20);
        g.warm_up_time(Duration::from_millis(500));
        g.measurement_time(Duration::from_secs(2));
        // Indices from 0 (raw bits subnormal below 2^23) and from 2^29 (raw bits a normal
        // float near 1e-19, whose products with box extents stay normal).
        for (name, first) in [("small-index", 0u32), ("large-index", 1 << 29)] {
            let mut b = SortedSplitBench::new(&boxes, first, node);
            g.bench_function(BenchmarkId::from_parameter(name), |bch| {
                bch.iter(|| std::hint::black_box(b.run()))
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench_sorted_split);
criterion_main!(benches);
