//! Build time and k-nearest-neighbour throughput of the Morton-order point k-d tree
//! ([`bvh::PointTree`], issue 18 part 3), checked against brute force.
//!
//! `cargo run --release -p bvh --example point_knn -- [SCENE] [N_RANDOM]`
//! (defaults `../shared/scenes/dragon.ply` and 1000000). Two point sets: the triangle
//! centroids of SCENE and N_RANDOM uniform random points in the scene's box. For each:
//! build time (median of 3), tree size, kNN throughput for k = 1, 8, 32 over two sets of 50K
//! queries (random picks of the set's own points; uniform points in its box), and an exact
//! comparison with brute force on `POINT_CHECK` (default 300) of those queries.

use bvh::{knn_brute, PointTree};
use geom::Vec3;
use std::time::Instant;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn run(name: &str, pts: &[Vec3], checks: usize) -> Result<(), Box<dyn std::error::Error>> {
    let leaf = 8;
    let mut times = Vec::new();
    let mut tree = None;
    for _ in 0..3 {
        let t0 = Instant::now();
        let t = PointTree::build(pts, leaf)?;
        times.push(t0.elapsed().as_secs_f64());
        tree = Some(t);
    }
    let tree = tree.expect("built");
    times.sort_by(f64::total_cmp);
    tree.validate(pts)?;
    let index_splits = tree
        .nodes()
        .iter()
        .filter(|n| !n.is_leaf() && n.axis == bvh::NO_AXIS)
        .count();
    println!(
        "{name}: {} points, build {:.1} ms ({:.1} Mpoints/s), {} nodes, depth {}, {} index splits, valid",
        pts.len(),
        times[1] * 1e3,
        pts.len() as f64 / times[1] / 1e6,
        tree.nodes().len(),
        tree.depth(),
        index_splits,
    );
    // Two query sets: the set's own points (random picks) and uniform points in its box.
    let b = pts.iter().fold(geom::Aabb::EMPTY, |b, &p| b.grow(p));
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let nq = 50_000;
    let own: Vec<Vec3> = (0..nq)
        .map(|_| pts[(rng.next() as f64 * pts.len() as f64) as usize % pts.len()])
        .collect();
    let boxed: Vec<Vec3> = (0..nq)
        .map(|_| b.min + (b.max - b.min) * Vec3::new(rng.next(), rng.next(), rng.next()))
        .collect();
    let mut out = Vec::new();
    for (qname, queries) in [("own points", &own), ("uniform in box", &boxed)] {
        for k in [1usize, 8, 32] {
            let t0 = Instant::now();
            let mut sum = 0.0f64;
            for &q in queries.iter() {
                tree.knn(q, k, &mut out)?;
                sum += out.last().map_or(0.0, |o| o.0 as f64);
            }
            let dt = t0.elapsed().as_secs_f64();
            // Exactness on the first `checks` queries, with brute-force timing.
            let t1 = Instant::now();
            let mut mismatches = 0;
            for &q in &queries[..checks] {
                tree.knn(q, k, &mut out)?;
                if out != knn_brute(pts, q, k)? {
                    mismatches += 1;
                }
            }
            let brute = t1.elapsed().as_secs_f64() / checks as f64;
            println!(
                "  {qname:<14} k {k:>2}: {:.3} Mqueries/s ({:.2} us/query, 1 thread); \
                 brute force {:.2} ms/query; {checks} queries vs brute force: {mismatches} \
                 mismatches (checksum {sum:.4e})",
                nq as f64 / dt / 1e6,
                dt / nq as f64 * 1e6,
                brute * 1e3,
            );
            if mismatches > 0 {
                return Err(format!("{name}: {mismatches} kNN mismatches at k {k}").into());
            }
        }
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args
        .first()
        .cloned()
        .unwrap_or_else(|| "../shared/scenes/dragon.ply".into());
    let n_random: usize = args.get(1).map_or(Ok(1_000_000), |s| s.parse())?;
    let checks: usize = std::env::var("POINT_CHECK").map_or(Ok(300), |s| s.parse())?;
    let scene = scene::open(&spec, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().map(|&v| mesh.positions[v as usize]).sum::<Vec3>() / 3.0)
        .collect();
    run(&format!("{spec} centroids"), &centroids, checks)?;
    let b = centroids.iter().fold(geom::Aabb::EMPTY, |b, &p| b.grow(p));
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let cloud: Vec<Vec3> = (0..n_random)
        .map(|_| b.min + (b.max - b.min) * Vec3::new(rng.next(), rng.next(), rng.next()))
        .collect();
    run("uniform random cloud in the same box", &cloud, checks)?;
    Ok(())
}
