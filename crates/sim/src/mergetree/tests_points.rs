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
        assert_eq!(p.node_bytes, cfg.kd_node_bytes() * p.written);
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
            for (cfg, element) in [
                (MergeTreeConfig::p2(), 16),
                (small(1024, 8, 4), 16),
                (small(32, 4, 1), 16),
                (small(32, 4, 1), 32),
            ] {
                let c = MergeTreeConfig {
                    point_element: element,
                    ..octree_mode(cfg, leaf)
                };
                let r = check_points(pts, &c);
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
        // The plain build sorts 32-byte elements: compare with the 32-byte point element.
        let oc = MergeTreeConfig {
            point_element: 32,
            ..octree_mode(cfg, 8)
        };
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
                for element in [16, 32] {
                    let c = MergeTreeConfig {
                        point_element: element,
                        ..points_mode(cfg.clone(), leaf)
                    };
                    check_points(pts, &c);
                }
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
    // Reads: the 4 points once, 16 bytes each (one block, no runs).
    assert_eq!(r.bytes_read, 4 * 16);
}

#[test]
fn traffic_is_the_plain_builds_without_the_collapsed_nodes() {
    let pts = cloud(6000, 4, 3.0);
    let a = point_boxes(&pts).unwrap();
    for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4)] {
        // The plain build sorts 32-byte elements: compare with the 32-byte point element.
        let pc = MergeTreeConfig {
            point_element: 32,
            ..points_mode(cfg, 8)
        };
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
        // 16-byte elements: the same tree from half the sort traffic (6000 points are a
        // multiple of both buffers, and take the same passes here).
        let r16 = check_points(
            &pts,
            &MergeTreeConfig {
                point_element: 16,
                ..pc.clone()
            },
        );
        assert_eq!(r16.merge_passes, r.merge_passes);
        assert_eq!(r16.bytes_read * 2, r.bytes_read);
        let runs = r.merge_passes as u64 * 6000 * 32;
        assert_eq!(r16.bytes_written, r.bytes_written - runs / 2);
        // With runs in DRAM the halved traffic shortens the build; one block (`p2`) sorts
        // on chip, where the element size changes only the presorters' sub-blocks.
        if r.partial_sort_blocks > 1 {
            assert!(r16.cycles < r.cycles, "{} vs {}", r16.cycles, r.cycles);
        }
    }
}

/// The 16-byte point element by hand: 6000 points, M = 256 (8 KB of scratchpad), B = 8
/// (256-byte buffers), fan-in 16. With 32-byte elements the scratchpad holds 256: 24
/// partial-sort runs, two merge passes (24 > 16); the sort reads the input and the runs
/// twice, 3 x 6000 x 32 = 576,000 bytes, and writes the runs twice, 384,000 bytes. With
/// 16-byte elements it holds 512 and a buffer 16: 12 runs, one pass (the largest
/// one-pass scene 8192 points, not 4096); it reads 2 x 6000 x 16 = 192,000 bytes and writes
/// 96,000. The tree, its nodes and leaf table (the other writes) and the emitter's
/// 2n + 1 steps are the same.
#[test]
fn point_element_by_hand() {
    let pts = cloud(6000, 8, 5.0);
    let c32 = MergeTreeConfig {
        point_element: 32,
        ..points_mode(small(256, 8, 4), 8)
    };
    let c16 = MergeTreeConfig {
        point_element: 16,
        ..c32.clone()
    };
    assert_eq!((c32.fan_in(), c32.single_pass_limit()), (16, 4096));
    assert_eq!(
        (
            c16.fan_in(),
            c16.m_elems(),
            c16.b_elems(),
            c16.single_pass_limit()
        ),
        (16, 512, 16, 8192)
    );
    let (a, b) = (check_points(&pts, &c32), check_points(&pts, &c16));
    assert_eq!((a.partial_sort_blocks, a.merge_passes), (24, 2));
    assert_eq!((b.partial_sort_blocks, b.merge_passes), (12, 1));
    assert_eq!((a.bytes_read, b.bytes_read), (576_000, 192_000));
    let tree = a.bytes_written - 384_000;
    assert_eq!(b.bytes_written, tree + 96_000);
    let steps = |r: &MergeTreeReport| {
        r.units
            .iter()
            .find(|u| u.name == "emitter")
            .and_then(|u| u.counters.iter().find(|c| c.0 == "steps"))
            .map(|c| c.1)
    };
    assert_eq!(steps(&a), Some(2 * 6000 + 1));
    assert_eq!(steps(&b), steps(&a));
    assert!(b.cycles < a.cycles);
    // The key and its check.
    let mut c = c16.clone();
    c.set("point_element", "32").unwrap();
    assert_eq!(c, c32);
    assert!(c.set("point_element", "24").is_err());
    // Box modes ignore it.
    let plain = MergeTreeConfig {
        output: OutputMode::Bvh,
        ..c16
    };
    assert_eq!((plain.elem_bytes(), plain.m_elems()), (32, 256));
}

/// Plane-only k-d nodes (`point_node = plane`): the same tree, 16 bytes per written node
/// instead of 64, the same reads and emitter steps. By hand on the 4 points of the x axis
/// with leaves of 1: 3 nodes, 192 bytes with boxes (3 bursts) and 48 with planes (one
/// 64-byte burst), so 320 and 192 bytes written with the leaf entries and the root record.
#[test]
fn plane_nodes_write_a_quarter_of_the_node_bytes() {
    let pts: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
    let boxed = points_mode(MergeTreeConfig::p2(), 1);
    let plane = MergeTreeConfig {
        point_node: KdNode::Plane,
        ..boxed.clone()
    };
    let (b, p) = (check_points(&pts, &boxed), check_points(&pts, &plane));
    let (pb, pp) = (b.points.as_ref().unwrap(), p.points.as_ref().unwrap());
    assert_eq!((pb.written, pb.node_bytes), (3, 192));
    assert_eq!((pp.written, pp.node_bytes), (3, 48));
    assert_eq!((b.bytes_written, p.bytes_written), (320, 192));
    assert_eq!(b.bytes_read, p.bytes_read);
    // A larger set across merge passes: the same tree and reads; the node bytes a
    // quarter, in whole bursts.
    let pts = cloud(6000, 4, 3.0);
    for cfg in [MergeTreeConfig::p2(), small(1024, 8, 4)] {
        let boxed = points_mode(cfg, 8);
        let plane = MergeTreeConfig {
            point_node: KdNode::Plane,
            ..boxed.clone()
        };
        let (b, p) = (check_points(&pts, &boxed), check_points(&pts, &plane));
        let (pb, pp) = (b.points.as_ref().unwrap(), p.points.as_ref().unwrap());
        assert_eq!(pb.written, pp.written);
        assert_eq!(pb.node_bytes, 4 * pp.node_bytes);
        assert_eq!(b.bytes_read, p.bytes_read);
        assert_eq!(
            p.bytes_written,
            b.bytes_written - pb.node_bytes + pp.node_bytes.div_ceil(64) * 64
        );
        assert!(p.cycles <= b.cycles);
    }
    // The key, and only in the k-d mode.
    let mut c = points_mode(MergeTreeConfig::p2(), 8);
    c.set("point_node", "plane").unwrap();
    c.validate().unwrap();
    assert!(c.set("point_node", "sphere").is_err());
    c.output = OutputMode::OctreePoints;
    assert!(c
        .validate()
        .unwrap_err()
        .to_string()
        .contains("kdtree-points"));
}
