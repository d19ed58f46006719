//! Tests of `output = cbvh4` (issue 18 part 2): the streaming collapse unit with the wide
//! CBVH encoder behind it writes the software encoder's compressed tree bit for bit, its
//! traffic is the node counts times the node sizes plus the backtracking lines, and the
//! cycles of a tiny scene by hand.

use super::*;
use crate::mergetree::tests::{clustered_boxes, port, random_boxes, small};

fn cbvh4(c: &MergeTreeConfig) -> MergeTreeConfig {
    MergeTreeConfig {
        output: OutputMode::Cbvh4,
        ..c.clone()
    }
}

/// Simulates and checks the binary tree and the compressed 4-wide tree against software;
/// the decoded tree is a valid 4-wide BVH over the boxes.
fn check(a: &[Aabb], c: &MergeTreeConfig) -> MergeTreeReport {
    let r = simulate(a, c, port(13)).unwrap();
    assert!(tree_matches_software(&r, a).unwrap(), "BVH differs");
    assert_eq!(
        cbvh4_matches_software(&r, a).unwrap(),
        Some(true),
        "compressed 4-wide tree differs ({} prims)",
        a.len()
    );
    let w = r.cbvh4.as_ref().unwrap();
    let d = w.tree.decode_to_mbvh4().unwrap();
    let max_leaf = w.exact.stats().max_leaf_size.max(1);
    assert_eq!(bvh::validate_mbvh4(&d, a, max_leaf), Ok(()));
    assert!(w.sah_decoded >= w.sah);
    r
}

/// The traffic and busy cycles of a run against the plain build of the same scene.
fn check_counts(r: &MergeTreeReport, plain: &MergeTreeReport) {
    let w = r.cbvh4.as_ref().unwrap();
    let col = w.collapse.as_ref().unwrap();
    let enc = w.stream.as_ref().unwrap();
    assert_eq!(w.binary_nodes, plain.nodes);
    assert_eq!(col.nodes_in, plain.nodes);
    // Every wide node the collapse closes goes to the encoder, which writes it once.
    assert_eq!(col.nodes_written, w.wide_nodes);
    assert_eq!(
        (enc.nodes_in, enc.pairs_written),
        (w.wide_nodes, w.wide_nodes)
    );
    assert_eq!(enc.backtrack_reads, w.backtrack_steps);
    assert_eq!(enc.backtrack_writes, w.backtrack_steps);
    // Collapse: a cycle per binary node, one for the root, one per wide node handed on.
    // Encoder: a cycle per wide node taken, per node written, per backtracking write,
    // and one to end the stream (the backtracking reads are waits).
    let think = u64::from(r.config.mbvh4_window.unwrap_or(0));
    assert_eq!(
        col.busy_cycles,
        (col.nodes_in + 1) * (think + 1) + col.nodes_written
    );
    assert_eq!(
        enc.busy_cycles,
        enc.nodes_in + enc.pairs_written + enc.backtrack_writes + 1
    );
    // Bytes: no binary node is written; 32-byte wide nodes instead; a 64-byte line read
    // and written per backtracking step (6 bits: a node never straddles a line).
    assert_eq!(w.node_bytes, 32);
    assert_eq!(r.bytes_read, plain.bytes_read + 64 * w.backtrack_steps);
    // The memory counts whole 64-byte bursts: the last partial chunk of wide nodes is
    // rounded up, and each flush of the write buffer before a backtracking read of a line
    // it still held (`cbvh_flush_before_backtrack`) splits one burst between two writes.
    let exact = plain.bytes_written - 64 * plain.nodes + 32 * w.wide_nodes + 64 * w.backtrack_steps;
    let flushes = enc.backtrack_flushes;
    assert!(flushes <= w.backtrack_steps);
    assert!(
        r.bytes_written >= exact && r.bytes_written <= exact + (flushes + 1) * 64,
        "{} vs {exact}, {flushes} flushes",
        r.bytes_written
    );
    if flushes == 0 {
        assert_eq!(r.bytes_written, exact.div_ceil(64) * 64);
    }
    assert_eq!(w.build_cycles, r.cycles);
}

#[test]
fn compressed_wide_nodes_equal_the_software_encoder() {
    let a = random_boxes(6000, 11);
    let base = small(1024, 16, 8);
    let plain = simulate(&a, &base, port(13)).unwrap();
    let r = check(&a, &cbvh4(&base));
    check_counts(&r, &plain);
    let w = r.cbvh4.as_ref().unwrap();
    // The same collapse as `output = mbvh4`: the same wide tree, a quarter of its bytes.
    let m = check_mbvh4(&a, &base);
    assert_eq!(w.exact, m.mbvh4.as_ref().unwrap().tree);
    assert!(w.backtrack_steps > 0);
    assert!(r.bytes_written < m.bytes_written);
    // The buffer bound: four held subtrees per open subtree of the greedy collapse.
    let col = w.collapse.as_ref().unwrap();
    assert!(
        w.max_held <= 4 * col.max_open,
        "{} {}",
        w.max_held,
        col.max_open
    );
    assert!(col.max_open <= r.max_stack_depth as u64 + 1);
}

fn check_mbvh4(a: &[Aabb], c: &MergeTreeConfig) -> MergeTreeReport {
    let c = MergeTreeConfig {
        output: OutputMode::Mbvh4,
        ..c.clone()
    };
    let r = simulate(a, &c, port(13)).unwrap();
    assert_eq!(mbvh4_matches_software(&r, a).unwrap(), Some(true));
    r
}

/// Modulo coordinates, treelets and the windowed collapse: each equal to the software,
/// and modulo coordinates with treelets backtrack less than relative ones.
#[test]
fn modulo_treelets_and_the_window() {
    let a = random_boxes(5000, 21);
    let base = small(512, 8, 4);
    let plain = simulate(&a, &base, port(13)).unwrap();
    let mut steps = Vec::new();
    for (coords, treelet, window) in [
        ("relative", 1, None),
        ("modulo", 1, None),
        ("modulo", 3, None),
        ("relative", 1, Some(3)),
    ] {
        let mut c = cbvh4(&base);
        c.set("cbvh_coords", coords).unwrap();
        c.cbvh_treelet_depth = treelet;
        c.mbvh4_window = window;
        c.validate().unwrap();
        let r = check(&a, &c);
        check_counts(&r, &plain);
        steps.push(r.cbvh4.as_ref().unwrap().backtrack_steps);
    }
    assert!(steps[1] < steps[0] && steps[2] <= steps[1], "{steps:?}");
}

/// 16 unit cubes two units apart along x (`tests_mbvh4::sixteen_cubes_by_hand`): 15 binary
/// nodes, collapsed into 5 full wide nodes (four over four cubes each, a root over them).
/// By hand, with relative coordinates: each bottom node's estimated context (x at 2^-3
/// over 8k..8k+7.125, y and z at 2^-5 over 0..1.03125) has the scale and lower bound of
/// the context the root gives it (the root at 2^-1 over 0..31.5 decodes child k to
/// 8k..8k+7.5, scale 2^-3; y and z to 0..1.03125), so nothing backtracks. The collapse is
/// busy 15 + 1 + 5 = 21 cycles, the encoder 5 (nodes in) + 5 (nodes written) + 1 (end) =
/// 11, and the node traffic goes from 15 x 64 = 960 bytes to 5 x 32 = 160 (192 in whole bursts).
#[test]
fn sixteen_cubes_by_hand() {
    let a: Vec<Aabb> = (0..16)
        .map(|i| {
            let x = 2.0 * i as f32;
            Aabb::new(
                geom::Vec3::new(x, 0.0, 0.0),
                geom::Vec3::new(x + 1.0, 1.0, 1.0),
            )
        })
        .collect();
    let base = MergeTreeConfig::p2();
    let plain = simulate(&a, &base, port(13)).unwrap();
    assert_eq!(plain.nodes, 15);
    let r = check(&a, &cbvh4(&base));
    check_counts(&r, &plain);
    let w = r.cbvh4.as_ref().unwrap();
    assert_eq!(
        (w.wide_nodes, w.mean_children, w.backtrack_steps),
        (5, 4.0, 0)
    );
    let (col, enc) = (w.collapse.as_ref().unwrap(), w.stream.as_ref().unwrap());
    assert_eq!((col.busy_cycles, enc.busy_cycles), (21, 11));
    // 160 bytes of wide nodes, written in one request of three 64-byte bursts.
    assert_eq!(r.bytes_written, plain.bytes_written - 960 + 192);
    assert_eq!(r.bytes_read, plain.bytes_read);
    assert_eq!(w.tree.root_ctx.scales(), [-1, -5, -5]);
    assert_eq!(w.tree.root_ctx.aabb().max.x, 31.5);
}

#[test]
fn tiny_empty_and_big_leaf_scenes() {
    for n in [0, 1, 2, 3, 17] {
        let a = random_boxes(n, n as u64 + 1);
        let r = check(&a, &cbvh4(&small(64, 8, 2)));
        assert!(r.cbvh4.as_ref().unwrap().wide_nodes >= 1);
    }
    for a in [clustered_boxes(2500, 30), clustered_boxes(400, 1)] {
        for combine in [false, true] {
            let mut c = cbvh4(&small(512, 8, 4));
            c.combine_identical = combine;
            check(&a, &c);
        }
    }
}

/// A one-entry FIFO between the collapse and the encoder (and before the collapse), and a
/// one-chunk write buffer, change only the timing; skipping cycles changes nothing.
#[test]
fn a_full_fifo_and_a_small_write_buffer_change_only_the_timing() {
    let a = random_boxes(3000, 14);
    let mut c = cbvh4(&small(512, 8, 4));
    let r = check(&a, &c);
    c.cbvh_fifo = 1;
    c.node_buffer_bytes = c.write_chunk_bytes;
    let t = check(&a, &c);
    let (rw, tw) = (r.cbvh4.as_ref().unwrap(), t.cbvh4.as_ref().unwrap());
    assert_eq!(rw.tree, tw.tree);
    assert_eq!(
        (r.bytes_read, r.bytes_written),
        (t.bytes_read, t.bytes_written)
    );
    assert!(t.cycles >= r.cycles);
    assert!(tw.collapse.as_ref().unwrap().encoder_full_cycles > 0);
    c.fast_forward = false;
    let u = check(&a, &c);
    assert_eq!((u.cycles, u.bytes_written), (t.cycles, t.bytes_written));
}

#[test]
fn cbvh4_mode_errors() {
    let mut c = MergeTreeConfig::p2();
    c.set("output", "cbvh4").unwrap();
    assert_eq!(c.output, OutputMode::Cbvh4);
    assert!(c.output.collapses_stream() && !c.output.is_cbvh() && !c.output.is_mbvh4());
    assert_eq!(c.output.name(), "cbvh4");
    c.validate().unwrap();
    c.highlevel_threshold = Some(20);
    assert!(matches!(c.validate(), Err(ConfigError::Inconsistent(_))));
    c.highlevel_threshold = None;
    c.cbvh_bits = 9;
    assert!(c.validate().is_err());
    c.cbvh_bits = 6;
    c.cbvh_treelet_depth = 0;
    assert!(c.validate().is_err());
    c.cbvh_treelet_depth = 1;
    c.cbvh_fifo = (1 << 20) + 1;
    assert!(c.validate().is_err());
    // Another mode: no compressed 4-wide result to compare.
    let a = random_boxes(100, 1);
    let r = simulate(&a, &MergeTreeConfig::p2(), port(13)).unwrap();
    assert_eq!(cbvh4_matches_software(&r, &a).unwrap(), None);
}
