//! `arbor build --builder kdtree-points | octree-points` (issue 18, part 3): the point
//! k-d tree (`bvh::PointTree`) or octree (`bvh::Octree`) over the triangles' centroids
//! (vertex means), built from their Morton order, validated, and checked against brute
//! force on k-nearest-neighbour queries. The JSON form (`arbor.build.points.v1`) is
//! documented in `docs/cli-json.md`.

use super::{BuildArgs, MAX_LEAF_LIMIT, MAX_THREADS};
use crate::cmd::{ms, open_scene, thousands};
use crate::progress::Ui;
use anyhow::Context;
use bvh::{knn_brute, Octree, PointError, PointTree};
use geom::{Aabb, Vec3};
use serde::Serialize;
use std::time::Instant;

/// The point builders' names.
pub const POINT_BUILDERS: [&str; 2] = ["kdtree-points", "octree-points"];

/// Leaf size of the point trees when `--max-leaf` is not given.
pub const POINT_DEFAULT_LEAF: u32 = 8;

/// Queries of the brute-force check: half the set's own points, half uniform in its box.
pub const POINT_CHECK_QUERIES: usize = 200;

/// Neighbours per query of the brute-force check.
pub const POINT_CHECK_K: usize = 8;

/// The JSON document `arbor build --builder kdtree-points|octree-points --json` prints.
#[derive(Serialize, Debug)]
pub struct PointBuildJson {
    /// `"arbor.build.points.v1"`.
    pub schema: &'static str,
    /// Scene spec as given.
    pub scene: String,
    /// Builder name.
    pub builder: String,
    /// Time sampled, after clamping.
    pub time_s: f32,
    /// `--frame` if given.
    pub frame: Option<u32>,
    /// Points built over (the triangles' centroids).
    pub points: usize,
    /// Largest leaf (cells whose points share one code may exceed it in the octree).
    pub max_leaf: u32,
    /// Worker threads of the pool the builder ran in.
    pub threads: usize,
    /// Build time (sort and tree), milliseconds.
    pub build_ms: f64,
    /// Nodes, leaves included.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Levels of the deepest leaf (the root alone is 1).
    pub depth: usize,
    /// k-d tree: inner nodes that split one code's points by index (null for the octree).
    pub index_splits: Option<usize>,
    /// Octree: inner nodes with one child (null for the k-d tree).
    pub single_child: Option<usize>,
    /// Octree: leaves over `max_leaf` (all of one code; null for the k-d tree).
    pub over_full_leaves: Option<usize>,
    /// Queries compared with brute force.
    pub knn_checks: usize,
    /// Neighbours per checked query.
    pub knn_k: usize,
    /// Checked queries whose result differs from brute force (0, else the command fails).
    pub knn_mismatches: usize,
}

/// Runs `arbor build` with a point builder.
pub fn run_points(a: &BuildArgs, ui: &Ui) -> anyhow::Result<()> {
    for (given, flag) in [
        (a.collapse_from.is_some(), "--collapse-from"),
        (a.bins.is_some(), "--bins"),
        (a.out.is_some(), "--out"),
        (a.refit_from.is_some(), "--refit-from"),
        (a.sah_reference, "--sah-reference"),
    ] {
        anyhow::ensure!(!given, "{flag} does not apply to --builder {}", a.builder);
    }
    if let Some(t) = a.threads {
        anyhow::ensure!(
            (1..=MAX_THREADS).contains(&t),
            "--threads must be between 1 and {MAX_THREADS}, got {t}"
        );
    }
    let max_leaf = a.max_leaf.unwrap_or(POINT_DEFAULT_LEAF);
    anyhow::ensure!(
        (1..=MAX_LEAF_LIMIT).contains(&max_leaf),
        "--max-leaf must be between 1 and {MAX_LEAF_LIMIT}, got {max_leaf}"
    );
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = a.threads {
            b = b.num_threads(t);
        }
        b.build().context("cannot create the worker thread pool")?
    };
    let (scene, _) = open_scene(&a.scene, ui)?;
    let time_s = crate::cmd::resolve_time(scene.info(), a.time, a.frame)?;
    let mesh = scene
        .mesh_at(time_s)
        .with_context(|| format!("cannot sample the scene at t = {time_s} s"))?;
    let pts = crate::cmd::sim_mergetree::scene_points(&mesh, None);
    drop(mesh);
    let leaf = max_leaf as usize;
    let spinner = ui.spinner(&format!(
        "building {} over {} points",
        a.builder,
        thousands(pts.len() as u64)
    ));
    let s = Instant::now();
    let built = pool.install(|| -> Result<Built, PointError> {
        Ok(if a.builder == POINT_BUILDERS[0] {
            Built::Kd(PointTree::build(&pts, leaf)?)
        } else {
            Built::Oct(Octree::build(&pts, leaf)?)
        })
    });
    let build_ms = ms(s.elapsed());
    drop(spinner);
    let built = built.with_context(|| format!("builder {} failed", a.builder))?;
    match &built {
        Built::Kd(t) => t.validate(&pts),
        Built::Oct(t) => t.validate(&pts),
    }
    .with_context(|| format!("builder {} produced an invalid tree", a.builder))?;
    let knn_mismatches = check_knn(&built, &pts)?;
    let (nodes, leaves, depth, index_splits, single_child, over_full_leaves) = match &built {
        Built::Kd(t) => (
            t.nodes().len(),
            t.nodes().iter().filter(|n| n.is_leaf()).count(),
            t.depth(),
            Some(
                t.nodes()
                    .iter()
                    .filter(|n| !n.is_leaf() && n.axis == bvh::NO_AXIS)
                    .count(),
            ),
            None,
            None,
        ),
        Built::Oct(t) => {
            let s = t.stats();
            (
                s.nodes,
                s.leaves,
                s.depth,
                None,
                Some(s.single_child),
                Some(s.over_full_leaves),
            )
        }
    };
    let j = PointBuildJson {
        schema: "arbor.build.points.v1",
        scene: a.scene.scene.clone(),
        builder: a.builder.clone(),
        time_s,
        frame: a.frame,
        points: pts.len(),
        max_leaf,
        threads: pool.current_num_threads(),
        build_ms,
        nodes,
        leaves,
        depth,
        index_splits,
        single_child,
        over_full_leaves,
        knn_checks: check_queries(pts.len()),
        knn_k: POINT_CHECK_K,
        knn_mismatches,
    };
    if a.json {
        ui.emit_json(&j)?;
    } else {
        println!(
            "{} over {} points ({} centroids at t = {} s): {:.1} ms on {} threads",
            j.builder,
            thousands(j.points as u64),
            j.scene,
            j.time_s,
            j.build_ms,
            j.threads
        );
        let extra = match (j.index_splits, j.single_child, j.over_full_leaves) {
            (Some(i), _, _) => format!("{i} index splits"),
            (_, Some(s), Some(o)) => format!("{s} single-child cells, {o} over-full leaves"),
            _ => String::new(),
        };
        println!(
            "{} nodes ({} leaves of at most {}), depth {}, {extra}; valid",
            thousands(j.nodes as u64),
            thousands(j.leaves as u64),
            j.max_leaf,
            j.depth
        );
        println!(
            "kNN (k = {}) on {} queries against brute force: {} mismatches",
            j.knn_k, j.knn_checks, j.knn_mismatches
        );
    }
    anyhow::ensure!(
        knn_mismatches == 0,
        "{} of {} kNN queries differ from brute force",
        knn_mismatches,
        j.knn_checks
    );
    Ok(())
}

/// Queries [`check_knn`] makes over `n` points.
fn check_queries(n: usize) -> usize {
    if n == 0 {
        0
    } else {
        (POINT_CHECK_QUERIES / 2).min(n) + POINT_CHECK_QUERIES / 2
    }
}

enum Built {
    Kd(PointTree),
    Oct(Octree),
}

/// kNN of the tree against brute force on [`POINT_CHECK_QUERIES`] queries (half the set's
/// own points at even strides, half uniform in its box from a fixed seed): the number of
/// mismatches. A check, not a benchmark (`cargo run -p bvh --example point_knn` times the
/// queries).
fn check_knn(t: &Built, pts: &[Vec3]) -> anyhow::Result<usize> {
    if pts.is_empty() {
        return Ok(0);
    }
    let half = POINT_CHECK_QUERIES / 2;
    let b = pts.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p));
    let mut s: u64 = 0x2545_f491_4f6c_dd1d;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    debug_assert_eq!(check_queries(pts.len()), half.min(pts.len()) + half);
    let mut queries: Vec<Vec3> = (0..half.min(pts.len()))
        .map(|i| pts[i * pts.len() / half.min(pts.len())])
        .collect();
    queries.extend((0..half).map(|_| b.min + (b.max - b.min) * Vec3::new(next(), next(), next())));
    let (mut out, mut mismatches) = (Vec::new(), 0);
    for &q in &queries {
        match t {
            Built::Kd(t) => t.knn(q, POINT_CHECK_K, &mut out)?,
            Built::Oct(t) => t.knn(q, POINT_CHECK_K, &mut out)?,
        }
        mismatches += (out != knn_brute(pts, q, POINT_CHECK_K)?) as usize;
    }
    Ok(mismatches)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-made cloud: both trees pass the brute-force check, and a tree whose query
    /// results are wrong (a k-d tree of other points) fails it.
    #[test]
    fn knn_check_counts_mismatches() {
        let pts: Vec<Vec3> = (0..500)
            .map(|i| {
                Vec3::new(
                    (i % 10) as f32,
                    (i / 10 % 10) as f32 * 0.5,
                    (i / 100) as f32,
                )
            })
            .collect();
        assert_eq!(check_queries(pts.len()), 200);
        assert_eq!(check_queries(3), 103);
        assert_eq!(check_queries(0), 0);
        for t in [
            Built::Kd(PointTree::build(&pts, 4).unwrap()),
            Built::Oct(Octree::build(&pts, 4).unwrap()),
        ] {
            assert_eq!(check_knn(&t, &pts).unwrap(), 0);
        }
        let shifted: Vec<Vec3> = pts.iter().map(|&p| p + Vec3::splat(0.25)).collect();
        let wrong = Built::Kd(PointTree::build(&shifted, 4).unwrap());
        assert!(check_knn(&wrong, &pts).unwrap() > 100);
        assert_eq!(check_knn(&wrong, &[]).unwrap(), 0);
    }
}
