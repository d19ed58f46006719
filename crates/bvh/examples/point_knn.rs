//! Build time and k-nearest-neighbour throughput of the Morton-order point k-d tree
//! ([`bvh::PointTree`]) and octree ([`bvh::Octree`]) of issue 18 part 3, checked against
//! brute force, and the streaming build of the MergeTree point mode
//! ([`bvh::PointTree::build_streaming`], checked equal to the top-down build).
//!
//! `cargo run --release -p bvh --example point_knn -- [SCENE] [N_RANDOM]`
//! (defaults `../shared/scenes/dragon.ply` and 1000000). Two point sets: the triangle
//! centroids of SCENE and N_RANDOM uniform random points in the scene's box. For each:
//! build time (median of 3) and size of both trees, kNN throughput of both for k = 1, 8, 32
//! over two sets of 50K queries (random picks of the set's own points; uniform points in
//! its box), and an exact comparison of both with brute force on `POINT_CHECK` (default
//! 300) of those queries.

use bvh::{knn_brute, Octree, PointTree};
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

/// Median of 3 runs of `f` in seconds, and its last result.
fn median3<T>(
    mut f: impl FnMut() -> Result<T, bvh::PointError>,
) -> Result<(f64, T), bvh::PointError> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t0 = Instant::now();
        let t = f()?;
        times.push(t0.elapsed().as_secs_f64());
        last = Some(t);
    }
    times.sort_by(f64::total_cmp);
    Ok((times[1], last.expect("3 runs")))
}

type Knn<'a> = &'a dyn Fn(Vec3, usize, &mut Vec<(f32, u32)>) -> Result<(), bvh::PointError>;

fn run(name: &str, pts: &[Vec3], checks: usize) -> Result<(), Box<dyn std::error::Error>> {
    let leaf = 8;
    let (kd_time, tree) = median3(|| PointTree::build(pts, leaf))?;
    tree.validate(pts)?;
    let index_splits = tree
        .nodes()
        .iter()
        .filter(|n| !n.is_leaf() && n.axis == bvh::NO_AXIS)
        .count();
    println!(
        "{name}: {} points\n  k-d tree: build {:.1} ms ({:.1} Mpoints/s), {} nodes, depth {}, {} index splits, valid",
        pts.len(),
        kd_time * 1e3,
        pts.len() as f64 / kd_time / 1e6,
        tree.nodes().len(),
        tree.depth(),
        index_splits,
    );
    let (st_time, (streamed, st)) = median3(|| PointTree::build_streaming(pts, leaf))?;
    let same = streamed.same_as(&tree);
    println!(
        "  streaming (emitter + point writer, 1 thread after the sort): build {:.1} ms, {} steps, \
         {} nodes emitted, {} written, {} collapsed, stack {}, equal to the top-down tree: {same}",
        st_time * 1e3,
        st.steps,
        st.emitted,
        st.written,
        st.collapsed,
        st.max_stack_depth,
    );
    if !same {
        return Err(format!("{name}: the streaming tree differs").into());
    }
    let (oc_time, oct) = median3(|| Octree::build(pts, leaf))?;
    oct.validate(pts)?;
    let (os_time, (oct_streamed, oct_written)) = median3(|| Octree::build_streaming(pts, leaf))?;
    let oct_same = oct_streamed.ids() == oct.ids() && oct_streamed.nodes() == oct.nodes();
    println!(
        "  streaming octree (emitter + octree writer): build {:.1} ms, {} nodes written, \
         equal to the top-down octree: {oct_same}",
        os_time * 1e3,
        oct_written
    );
    if !oct_same {
        return Err(format!("{name}: the streaming octree differs").into());
    }
    let s = oct.stats();
    println!(
        "  octree: build {:.1} ms ({:.1} Mpoints/s), {} nodes ({} leaves, {} single-child, {} over-full leaves), depth {}, valid",
        oc_time * 1e3,
        pts.len() as f64 / oc_time / 1e6,
        s.nodes,
        s.leaves,
        s.single_child,
        s.over_full_leaves,
        s.depth,
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
    let kd: Knn = &|q, k, out| tree.knn(q, k, out);
    let oc: Knn = &|q, k, out| oct.knn(q, k, out);
    let mut out = Vec::new();
    for (qname, queries) in [("own points", &own), ("uniform in box", &boxed)] {
        for k in [1usize, 8, 32] {
            let mut line = format!("  {qname:<14} k {k:>2}:");
            for (tname, knn) in [("k-d", kd), ("octree", oc)] {
                let t0 = Instant::now();
                let mut sum = 0.0f64;
                for &q in queries.iter() {
                    knn(q, k, &mut out)?;
                    sum += out.last().map_or(0.0, |o| o.0 as f64);
                }
                let dt = t0.elapsed().as_secs_f64();
                line += &format!(
                    " {tname} {:.2} us/query (checksum {sum:.4e});",
                    dt / nq as f64 * 1e6
                );
            }
            // Exactness on the first `checks` queries, with brute-force timing.
            let t1 = Instant::now();
            let mut mismatches = 0;
            for &q in &queries[..checks] {
                let want = knn_brute(pts, q, k)?;
                for knn in [kd, oc] {
                    knn(q, k, &mut out)?;
                    mismatches += (out != want) as usize;
                }
            }
            let brute = t1.elapsed().as_secs_f64() / checks as f64;
            println!(
                "{line} brute force {:.2} ms/query; {checks} queries x 2 trees vs brute force: \
                 {mismatches} mismatches",
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
