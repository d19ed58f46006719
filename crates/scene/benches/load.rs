//! Loader throughput: a ~1M-triangle noisy tessellated sphere written once to a temporary
//! directory as binary PLY, ASCII PLY and OBJ, then loaded repeatedly (read + parse).
//! Throughput is reported in bytes; triangles/s is `triangles / time` (printed once).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use geom::Vec3;
use scene::{LoadOptions, Mesh};
use std::path::Path;
use std::time::Duration;

/// A UV sphere with `rings * segments * 2` triangles and a little deterministic radial noise,
/// so coordinates have realistic digit counts in text formats.
fn sphere(rings: u32, segments: u32) -> Mesh {
    let mut positions = Vec::new();
    let mut seed = 0x9e37_79b9u32;
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let ph = std::f32::consts::TAU * s as f32 / segments as f32;
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            let rad = 1.0 + (seed as f32 / u32::MAX as f32) * 0.01;
            positions.push(Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()) * rad);
        }
    }
    let mut triangles = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let a = r * segments + s;
            let b = r * segments + (s + 1) % segments;
            let (c, d) = (a + segments, b + segments);
            triangles.push([a, c, b]);
            triangles.push([b, c, d]);
        }
    }
    let n = triangles.len();
    Mesh {
        positions,
        triangles,
        material_ids: vec![0; n],
        material_names: vec![],
    }
}

fn bench_load(c: &mut Criterion) {
    let mesh = sphere(500, 1000); // 1,000,000 triangles
    let tris = mesh.triangle_count();
    let dir = tempfile::tempdir().expect("tempdir");
    let write =
        |name: &str, f: &dyn Fn(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>| {
            let p = dir.path().join(name);
            let mut w = std::io::BufWriter::new(std::fs::File::create(&p).expect("create"));
            f(&mut w).expect("write");
            drop(w);
            p
        };
    let files = [
        (
            "ply_binary",
            write("m.ply", &|w| scene::ply::write_binary_le(&mesh, w)),
        ),
        (
            "ply_ascii",
            write("m_ascii.ply", &|w| scene::ply::write_ascii(&mesh, w)),
        ),
        ("obj", write("m.obj", &|w| scene::obj::write(&mesh, w))),
    ];
    let opts = LoadOptions::default();
    let mut g = c.benchmark_group("load_1m_triangles");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for (name, path) in &files {
        let bytes = std::fs::metadata(path).expect("metadata").len();
        g.throughput(Throughput::Bytes(bytes));
        let load = |p: &Path| {
            let l = if *name == "obj" {
                scene::obj::load(p, &opts)
            } else {
                scene::ply::load(p, &opts)
            };
            l.expect("load").mesh
        };
        let t0 = std::time::Instant::now();
        let m = load(path);
        let dt = t0.elapsed().as_secs_f64();
        assert_eq!(m.triangle_count(), tris);
        eprintln!(
            "{name}: {:.1} MB, first load {:.3} s = {:.1} MB/s, {:.2} M triangles/s",
            bytes as f64 / 1e6,
            dt,
            bytes as f64 / 1e6 / dt,
            tris as f64 / 1e6 / dt
        );
        g.bench_function(*name, |b| b.iter(|| load(path)));
    }
    g.finish();
}

criterion_group!(benches, bench_load);
criterion_main!(benches);
