//! Plane-only k-d nodes against the box-pruned k-d tree (issue 18 part 3): node bytes,
//! and per query the inner nodes read and points tested, of [`bvh::PlaneKdTree`] (16-byte
//! nodes, pruning by plane distance) and [`bvh::PointTree`] (nodes with child boxes,
//! pruning by box distance), on the point sets of the `point_knn` example.
//!
//! `cargo run --profile test -p bvh --example point_planes -- [SCENE] [N_RANDOM] [QUERIES]`
//! (defaults `../shared/scenes/dragon.ply`, 1000000 and 20000). Leaves of 8 points. Two
//! query sets per point set: random picks of its own points ("own") and uniform points in
//! its box ("box"); k = 1, 8, 32, and radius queries with the squared radius of each
//! query's 8th neighbour. Every result of the two trees is compared (equal, or the run
//! fails), and the first 100 of each set with brute force. Times are one thread, µs per
//! query, both trees timed back to back in one run (compare them with each other only).

use bvh::{knn_brute, PlaneKdTree, PointTree, QueryStats};
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

/// Query number `i` at `q`.
type Query<'a> =
    &'a dyn Fn(usize, Vec3, &mut Vec<(f32, u32)>) -> Result<QueryStats, bvh::PointError>;

/// Every query's result.
type Results = Vec<Vec<(f32, u32)>>;

/// Mean nodes read, points tested and µs per query of `f` over `qs`, with every result.
fn measure(qs: &[Vec3], f: Query) -> Result<(f64, f64, f64, Results), bvh::PointError> {
    let mut out = Vec::new();
    let (mut nodes, mut points) = (0u64, 0u64);
    let mut all = Vec::with_capacity(qs.len());
    let t0 = Instant::now();
    for (i, &q) in qs.iter().enumerate() {
        let s = f(i, q, &mut out)?;
        nodes += s.nodes;
        points += s.points;
        all.push(out.clone());
    }
    let us = t0.elapsed().as_secs_f64() * 1e6 / qs.len() as f64;
    let n = qs.len() as f64;
    Ok((nodes as f64 / n, points as f64 / n, us, all))
}

fn run(name: &str, pts: &[Vec3], n_queries: usize) -> Result<(), Box<dyn std::error::Error>> {
    let tree = PointTree::build(pts, 8)?;
    tree.validate(pts)?;
    let planes = PlaneKdTree::new(&tree)?;
    let inner = planes.nodes().len();
    println!(
        "{name}: {} points, {inner} inner nodes: {:.2} MB with child boxes (64 B), {:.2} MB plane-only (16 B)",
        pts.len(),
        inner as f64 * 64.0 / 1e6,
        planes.node_bytes() as f64 / 1e6
    );
    let b = pts.iter().fold(geom::Aabb::EMPTY, |b, &p| b.grow(p));
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let own: Vec<Vec3> = (0..n_queries)
        .map(|_| pts[((rng.next() as f64 * pts.len() as f64) as usize).min(pts.len() - 1)])
        .collect();
    let boxq: Vec<Vec3> = (0..n_queries)
        .map(|_| b.min + (b.max - b.min) * Vec3::new(rng.next(), rng.next(), rng.next()))
        .collect();
    println!("| set | query | box: nodes read | plane: nodes read | box: points tested | plane: points tested | box µs | plane µs |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for (qname, qs) in [("own", &own), ("box", &boxq)] {
        let mut r2s = Vec::new();
        for k in [1usize, 8, 32] {
            let bq: Query = &|_, q, out| tree.knn_counted(q, k, out);
            let pq: Query = &|_, q, out| planes.knn_counted(q, k, out);
            let (bn, bp, bt, br) = measure(qs, bq)?;
            let (pn, pp, pt, pr) = measure(qs, pq)?;
            if br != pr {
                return Err(format!("{name} {qname} k {k}: the trees' results differ").into());
            }
            for (q, got) in qs.iter().zip(&pr).take(100) {
                if *got != knn_brute(pts, *q, k)? {
                    return Err(format!("{name} {qname} k {k}: differs from brute force").into());
                }
            }
            if k == 8 {
                r2s = pr.iter().map(|v| v.last().map_or(0.0, |x| x.0)).collect();
            }
            println!(
                "| {name} | {qname} k = {k} | {bn:.1} | {pn:.1} | {bp:.1} | {pp:.1} | {bt:.2} | {pt:.2} |"
            );
        }
        let r2 = &r2s;
        let bq: Query = &|i, q, out| tree.within_counted(q, r2[i], out);
        let pq: Query = &|i, q, out| planes.within_counted(q, r2[i], out);
        let (bn, bp, _, br) = measure(qs, bq)?;
        let (pn, pp, _, pr) = measure(qs, pq)?;
        if br != pr {
            return Err(format!("{name} {qname} radius: the trees' results differ").into());
        }
        println!(
            "| {name} | {qname} radius (8th neighbour) | {bn:.1} | {pn:.1} | {bp:.1} | {pp:.1} | – | – |"
        );
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
    let n_queries: usize = args.get(2).map_or(Ok(20_000), |s| s.parse())?;
    let scene = scene::open(&spec, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().map(|&v| mesh.positions[v as usize]).sum::<Vec3>() / 3.0)
        .collect();
    run("Dragon centroids", &centroids, n_queries)?;
    let b = centroids.iter().fold(geom::Aabb::EMPTY, |b, &p| b.grow(p));
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let cloud: Vec<Vec3> = (0..n_random)
        .map(|_| b.min + (b.max - b.min) * Vec3::new(rng.next(), rng.next(), rng.next()))
        .collect();
    run("uniform 1M", &cloud, n_queries)?;
    Ok(())
}
