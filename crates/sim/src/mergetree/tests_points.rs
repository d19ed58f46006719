//! Tests of the point mode (`output = kdtree-points`, issue 18 part 3): the tree the unit
//! writes equals the software point k-d tree node for node, and its traffic is the plain
//! build's with the collapsed nodes left out.

use super::tests::{port, small};
use super::*;
use geom::Vec3;

/// Deterministic pseudo-random points in `[0, scale)^3` (xorshift).
fn cloud(n: usize, seed: u64, scale: f32) -> Vec<Vec3> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32 * scale
    };
    (0..n).map(|_| Vec3::new(next(), next(), next())).collect()
}

/// `cfg` in the point mode with leaves of `leaf`.
fn points_mode(mut cfg: MergeTreeConfig, leaf: u32) -> MergeTreeConfig {
    cfg.output = OutputMode::KdtreePoints;
    cfg.morton_bits = 63;
    cfg.morton_grid = geom::MortonGrid::Box;
    cfg.max_leaf_size = leaf;
    cfg
}

/// Runs the point mode and checks its tree against `bvh::PointTree::build`.
fn check_points(pts: &[Vec3], cfg: &MergeTreeConfig) -> MergeTreeReport {
    let a = point_boxes(pts).unwrap();
    let r = simulate(&a, cfg, port(13)).unwrap();
    assert_eq!(points_match_software(&r, &a).unwrap(), Some(true));
    assert!(tree_matches_software(&r, &a).unwrap());
    let p = r.points.as_ref().unwrap();
    match (&p.tree, &p.octree) {
        (Some(t), None) => t.validate(pts).unwrap(),
        (None, Some(t)) => t.validate(pts).unwrap(),
        _ => panic!("one tree"),
    }
    if p.kind == "kdtree" {
        assert_eq!(p.written + p.collapsed, p.emitted);
        assert_eq!(p.node_bytes, 64 * p.written);
    }
    r
}

fn octree_mode(cfg: MergeTreeConfig, leaf: u32) -> MergeTreeConfig {
    MergeTreeConfig {
        output: OutputMode::OctreePoints,
        ..points_mode(cfg, leaf)
    }
}

#[test]
fn octree_equals_software_across_merge_passes() {
    let mut dup = cloud(700, 5, 4.0);
    dup.extend_from_within(..400);
    let chain = vec![Vec3::ZERO, Vec3::new(0.001, 0.0, 0.0), Vec3::splat(8.0)];
    let sets = [
        cloud(3000, 1, 10.0),
        dup,
        chain,
        vec![],
        vec![Vec3::ONE; 300],
    ];
    for pts in &sets {
        for leaf in [1, 8] {
            for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4), small(32, 4, 1)] {
                let r = check_points(pts, &octree_mode(cfg, leaf));
                let p = r.points.as_ref().unwrap();
                let s = p.octree.as_ref().unwrap().stats();
                assert_eq!(p.written, (s.nodes - s.leaves) as u64);
                // Every node but the root is one child of a written node.
                assert_eq!(
                    p.node_bytes,
                    16 * p.written + 32 * (s.nodes as u64).saturating_sub(1)
                );
            }
        }
    }
}

/// 4 points on the x axis, leaves of 1: the root splits x bit 20 into two cells of 2
/// points, each split by x bit 19 into 2 leaves: 3 nodes of 2 children written, 3 x (16 +
/// 2 x 32) = 240 bytes (4 bursts), with the leaf entries and the root record 384 B. The
/// emitter's 9 steps are unchanged: the bytes fit the write buffer as they come.
#[test]
fn octree_hand_derived_counts() {
    let pts: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
    let r = check_points(&pts, &octree_mode(MergeTreeConfig::p2(), 1));
    let p = r.points.as_ref().unwrap();
    assert_eq!((p.written, p.node_bytes, p.tree_nodes), (3, 240, 7));
    assert_eq!(r.bytes_written, 256 + 64 + 64);
    let steps = r
        .units
        .iter()
        .find(|u| u.name == "emitter")
        .and_then(|u| u.counters.iter().find(|c| c.0 == "steps"))
        .map(|c| c.1);
    assert_eq!(steps, Some(9));
}

#[test]
fn octree_traffic_is_the_plain_builds_with_its_nodes() {
    let pts = cloud(6000, 4, 3.0);
    let a = point_boxes(&pts).unwrap();
    let bursts = |b: u64| b.div_ceil(64) * 64;
    for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4)] {
        let oc = octree_mode(cfg, 8);
        let plain_cfg = MergeTreeConfig {
            output: OutputMode::Bvh,
            ..oc.clone()
        };
        let plain = simulate(&a, &plain_cfg, port(13)).unwrap();
        let r = check_points(&pts, &oc);
        let p = r.points.as_ref().unwrap();
        assert_eq!(r.bytes_read, plain.bytes_read);
        assert_eq!(
            r.bytes_written,
            plain.bytes_written - plain.nodes * 64 + bursts(p.node_bytes)
        );
    }
}

#[test]
fn point_tree_equals_software_across_merge_passes() {
    let mut dup = cloud(700, 5, 4.0);
    dup.extend_from_within(..400);
    let lattice: Vec<Vec3> = cloud(3000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
    let sets = [
        cloud(3000, 1, 10.0),
        dup,
        lattice,
        vec![Vec3::new(1.0, 2.0, 3.0); 300],
    ];
    for pts in &sets {
        for leaf in [1, 8] {
            // One block; one merge pass (fan-in 64); several passes (fan-in 4).
            for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4), small(32, 4, 1)] {
                check_points(pts, &points_mode(cfg, leaf));
            }
        }
    }
}

#[test]
fn tiny_inputs_and_bad_input() {
    let cfg = points_mode(MergeTreeConfig::p2(), 2);
    for n in [0, 1, 2, 3] {
        let r = check_points(&cloud(n, 9, 1.0), &cfg);
        assert_eq!(r.points.as_ref().unwrap().points, n as u64);
    }
    assert!(matches!(
        point_boxes(&[Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)]),
        Err(MergeTreeError::Points(bvh::PointError::NonFinite {
            index: 1,
            ..
        }))
    ));
    // An odd multiple of the smallest subnormal loses its last bit when halved.
    assert!(point_boxes(&[Vec3::new(0.0, f32::from_bits(3), 0.0)]).is_err());
    assert!(point_boxes(&[Vec3::new(0.0, f32::from_bits(4), 0.0)]).is_ok());
    // The mode's own grid and leaf size.
    let mut c = MergeTreeConfig::p2();
    c.set("output", "kdtree-points").unwrap();
    assert!(c.validate().is_err(), "the presets' 30-bit cube grid");
    c.set("morton_bits", "63").unwrap();
    c.set("morton_grid", "box").unwrap();
    assert!(c.validate().is_err(), "the presets' unlimited leaves");
    c.set("max_leaf_size", "8").unwrap();
    c.validate().unwrap();
    c.set("highlevel_threshold", "20").unwrap();
    assert!(c.validate().is_err());
}

/// Hand-derived counts on 4 points on the x axis (the keys of `bvh`'s
/// `hand_derived_stream_on_four_points`): the emitter takes 2n + 1 = 9 steps (a load,
/// 3 pushes, 3 joins, the root to the high-level output, the final step that finds it
/// done); with leaves of 2 the two pairs collapse and one 64-byte node is written.
#[test]
fn hand_derived_counts_on_four_points() {
    let pts: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
    let r = check_points(&pts, &points_mode(MergeTreeConfig::p2(), 2));
    let steps = r
        .units
        .iter()
        .find(|u| u.name == "emitter")
        .and_then(|u| u.counters.iter().find(|c| c.0 == "steps"))
        .map(|c| c.1);
    assert_eq!(steps, Some(9));
    let p = r.points.as_ref().unwrap();
    assert_eq!(
        (p.emitted, p.written, p.collapsed, p.tree_nodes),
        (3, 1, 2, 3)
    );
    // Writes: one 64-byte node, the 4-byte leaf entries (one 64-byte burst) and the
    // 32-byte root record (one burst).
    assert_eq!(r.bytes_written, 64 + 64 + 64);
}

#[test]
fn traffic_is_the_plain_builds_without_the_collapsed_nodes() {
    let pts = cloud(6000, 4, 3.0);
    let a = point_boxes(&pts).unwrap();
    for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4)] {
        let pc = points_mode(cfg, 8);
        // The plain BVH build of the same boxes on the same grid (distinct codes: n - 1
        // nodes).
        let plain_cfg = MergeTreeConfig {
            output: OutputMode::Bvh,
            ..pc.clone()
        };
        let plain = simulate(&a, &plain_cfg, port(13)).unwrap();
        assert_eq!(plain.nodes, pts.len() as u64 - 1);
        let r = check_points(&pts, &pc);
        let p = r.points.as_ref().unwrap();
        assert!(
            p.written < plain.nodes / 3,
            "{} of {}",
            p.written,
            plain.nodes
        );
        assert_eq!(r.bytes_read, plain.bytes_read);
        assert_eq!(
            r.bytes_written,
            plain.bytes_written - (plain.nodes - p.written) * 64
        );
        assert!(r.cycles <= plain.cycles, "{} > {}", r.cycles, plain.cycles);
    }
}
