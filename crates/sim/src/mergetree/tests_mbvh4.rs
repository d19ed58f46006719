//! Tests of the MBVH4 output modes (issue 18 part 2): the tree the model writes equals the
//! software collapse's node for node, the traffic is the node counts times the node sizes,
//! the collapse pass follows an unchanged build, and the counts of a tiny scene by hand.

use super::*;
use crate::mergetree::config::MAX_MBVH4_WINDOW;
use crate::mergetree::mbvh4_unit::{collapse_pass_writes, emission_index};
use crate::mergetree::tests::{clustered_boxes, port, random_boxes, small};

fn with(c: &MergeTreeConfig, output: OutputMode) -> MergeTreeConfig {
    MergeTreeConfig {
        output,
        ..c.clone()
    }
}

/// Simulates and checks the binary tree and the MBVH4 against software.
fn check(a: &[Aabb], c: &MergeTreeConfig) -> MergeTreeReport {
    let r = simulate(a, c, port(13)).unwrap();
    assert!(tree_matches_software(&r, a).unwrap(), "BVH differs");
    assert_eq!(
        mbvh4_matches_software(&r, a).unwrap(),
        Some(true),
        "MBVH4 differs ({} prims, {:?})",
        a.len(),
        c.output
    );
    let m = &r.mbvh4.as_ref().unwrap().tree;
    let max_leaf = m.stats().max_leaf_size.max(1);
    assert_eq!(bvh::validate_mbvh4(m, a, max_leaf), Ok(()));
    r
}

/// Unit-edge cubes two units apart along x.
fn cubes(n: usize) -> Vec<Aabb> {
    (0..n)
        .map(|i| {
            let x = 2.0 * i as f32;
            Aabb::new(
                geom::Vec3::new(x, 0.0, 0.0),
                geom::Vec3::new(x + 1.0, 1.0, 1.0),
            )
        })
        .collect()
}

#[test]
fn streaming_mbvh4_equals_the_software_collapse_and_saves_the_node_traffic() {
    let a = random_boxes(6000, 11);
    let base = small(1024, 16, 8);
    let plain = simulate(&a, &base, port(13)).unwrap();
    let r = check(&a, &with(&base, OutputMode::Mbvh4));
    let m = r.mbvh4.as_ref().unwrap();
    let (sw, sc) =
        bvh::stream_collapse(&software_builder(&base).build_highlevel(&a).unwrap()).unwrap();
    // The comparison the check made, spelled out.
    assert_eq!(m.tree, sw);
    assert_eq!(m.binary_nodes, plain.nodes);
    let st = m.stream.as_ref().unwrap();
    assert_eq!(st.nodes_in, plain.nodes);
    assert_eq!(st.nodes_written, m.wide_nodes);
    assert_eq!(st.max_open, sc.max_open() as u64);
    // The buffer bound: open subtrees were on the emitter's stack or in its register.
    assert!(st.max_open <= r.max_stack_depth as u64 + 1);
    // One cycle per binary node, one for the root, one per wide node written.
    assert_eq!(st.busy_cycles, st.nodes_in + 1 + st.nodes_written);
    // Same reads; 128-byte wide nodes written instead of 64-byte binary nodes.
    assert_eq!(r.merge_passes, 1);
    assert_eq!(r.bytes_read, plain.bytes_read);
    assert_eq!(
        r.bytes_written,
        plain.bytes_written - plain.nodes * 64 + m.wide_nodes * 128
    );
    assert!(m.wide_nodes * 128 < plain.nodes * 64);
    assert_eq!(m.sah, sw.normalized_sah());
    assert_eq!(m.collapse_cycles, 0);
    assert_eq!(m.build_cycles, r.cycles);
}

#[test]
fn collapse_pass_follows_an_unchanged_build() {
    let a = random_boxes(6000, 12);
    let base = small(1024, 16, 8);
    let plain = simulate(&a, &base, port(13)).unwrap();
    let r = check(&a, &with(&base, OutputMode::Mbvh4Collapse));
    let m = r.mbvh4.as_ref().unwrap();
    assert_eq!(m.tree, bvh::collapse(&plain.tree().unwrap()).unwrap());
    assert_eq!(m.build_cycles, plain.cycles);
    assert_eq!(m.build_cycles + m.collapse_cycles, r.cycles);
    let pass = r.phases.last().unwrap();
    assert_eq!(pass.name, "topdown_compress");
    assert_eq!(pass.bytes_read, plain.nodes * 64);
    assert_eq!(pass.bytes_written, m.wide_nodes * 128);
    assert_eq!(r.bytes_read, plain.bytes_read + plain.nodes * 64);
    assert_eq!(r.bytes_written, plain.bytes_written + m.wide_nodes * 128);
    let p = m.pass.as_ref().unwrap();
    assert_eq!((p.node_reads, p.pairs_written), (plain.nodes, m.wide_nodes));
    // The streaming unit against the pass: fewer bytes and fewer cycles.
    let s = check(&a, &with(&base, OutputMode::Mbvh4));
    assert!(s.bytes_read + s.bytes_written < r.bytes_read + r.bytes_written);
    assert!(s.cycles < r.cycles, "{} vs {}", s.cycles, r.cycles);
}

/// 16 cubes in a row: a perfect binary tree of 15 nodes, collapsed by both modes into the
/// same 5 full wide nodes (bvh's `sixteen_leaves_equal_the_offline_collapse`). By hand:
/// the streaming unit is busy 15 + 1 + 5 cycles and holds at most 4 open subtrees (the
/// left halves 0..8, 8..12, 12..14 and the pair 14, 15); the node traffic goes from
/// 15 x 64 = 960 bytes to 5 x 128 = 640, and the pass reads 960 and writes 640 more.
#[test]
fn sixteen_cubes_by_hand() {
    let a = cubes(16);
    let base = MergeTreeConfig::p2();
    let plain = simulate(&a, &base, port(13)).unwrap();
    assert_eq!(plain.nodes, 15);
    let s = check(&a, &with(&base, OutputMode::Mbvh4));
    let p = check(&a, &with(&base, OutputMode::Mbvh4Collapse));
    let (ms, mp) = (s.mbvh4.as_ref().unwrap(), p.mbvh4.as_ref().unwrap());
    assert_eq!(ms.tree, mp.tree);
    assert_eq!((ms.wide_nodes, ms.mean_children), (5, 4.0));
    let st = ms.stream.as_ref().unwrap();
    assert_eq!(
        (st.nodes_in, st.nodes_written, st.busy_cycles, st.max_open),
        (15, 5, 21, 4)
    );
    assert_eq!(s.bytes_written, plain.bytes_written - 960 + 640);
    assert_eq!(s.bytes_read, plain.bytes_read);
    assert_eq!(p.bytes_written, plain.bytes_written + 640);
    assert_eq!(p.bytes_read, plain.bytes_read + 960);
    // The pass consumes 15 nodes, writing at the 5 wide roots.
    let writes = collapse_pass_writes(&p.highlevel).unwrap();
    assert_eq!(writes.len(), 15);
    assert_eq!(writes.iter().filter(|&&b| b == 128).count(), 5);
    // Its first position is the root (emitted last), a wide root.
    assert_eq!(writes[0], 128);
}

#[test]
fn emission_index_inverts_the_preorder_layout() {
    let a = random_boxes(2000, 13);
    let hl = software_builder(&MergeTreeConfig::p2())
        .build_highlevel(&a)
        .unwrap();
    let bvh = hl.to_bvh2();
    let rank = emission_index(&bvh);
    let mut seen = vec![false; rank.len()];
    for (i, &e) in rank.iter().enumerate() {
        assert!(!std::mem::replace(&mut seen[e as usize], true));
        let em = &hl.nodes[e as usize];
        assert_eq!(
            em.aabbs,
            [bvh.nodes[i].child_aabb(0), bvh.nodes[i].child_aabb(1)]
        );
    }
    let total: u64 = collapse_pass_writes(&hl).unwrap().iter().sum();
    assert_eq!(total, 128 * bvh::collapse(&bvh).unwrap().nodes.len() as u64);
}

#[test]
fn tiny_empty_and_big_leaf_scenes() {
    for n in [0, 1, 2, 3, 17] {
        let a = random_boxes(n, n as u64 + 1);
        for mode in [OutputMode::Mbvh4, OutputMode::Mbvh4Collapse] {
            let r = check(&a, &with(&small(64, 8, 2), mode));
            let want = if n == 0 {
                1
            } else {
                (n as u64 - 1).clamp(1, n as u64)
            };
            let m = r.mbvh4.unwrap();
            assert!(m.wide_nodes >= 1 && m.wide_nodes <= want, "{n} {mode:?}");
        }
    }
    for a in [clustered_boxes(2500, 30), clustered_boxes(400, 1)] {
        for combine in [false, true] {
            for mode in [OutputMode::Mbvh4, OutputMode::Mbvh4Collapse] {
                let mut c = with(&small(512, 8, 4), mode);
                c.combine_identical = combine;
                check(&a, &c);
            }
        }
    }
}

#[test]
fn a_full_fifo_and_a_small_write_buffer_change_only_the_timing() {
    let a = random_boxes(3000, 14);
    let mut c = with(&small(512, 8, 4), OutputMode::Mbvh4);
    let r = check(&a, &c);
    c.cbvh_fifo = 1;
    c.node_buffer_bytes = c.write_chunk_bytes;
    let t = check(&a, &c);
    assert_eq!(
        r.mbvh4.as_ref().unwrap().tree,
        t.mbvh4.as_ref().unwrap().tree
    );
    assert_eq!(r.bytes_written, t.bytes_written);
    assert!(t.cycles >= r.cycles);
    // The same with and without skipping cycles.
    c.fast_forward = false;
    let u = check(&a, &c);
    assert_eq!((u.cycles, u.bytes_written), (t.cycles, t.bytes_written));
}

#[test]
fn mbvh4_mode_errors() {
    let mut c = MergeTreeConfig::p2();
    c.set("output", "mbvh4").unwrap();
    assert_eq!(c.output, OutputMode::Mbvh4);
    assert!(c.output.is_mbvh4() && !c.output.is_cbvh());
    c.set("output", "mbvh4-collapse").unwrap();
    assert_eq!(c.output.name(), "mbvh4-collapse");
    assert!(c.set("output", "mbvh8").is_err());
    c.highlevel_threshold = Some(20);
    assert!(matches!(c.validate(), Err(ConfigError::Inconsistent(_))));
    c.highlevel_threshold = None;
    c.output = OutputMode::Mbvh4;
    c.cbvh_fifo = (1 << 20) + 1;
    assert!(c.validate().is_err());
}

/// `mbvh4_window = L`: the windowed rule, equal to the software's, L more cycles per node
/// and at the end, and a lower SAH than the greedy rule here.
#[test]
fn windowed_rule_in_the_unit() {
    let a = random_boxes(4000, 15);
    let base = with(&small(512, 8, 4), OutputMode::Mbvh4);
    let greedy = check(&a, &base);
    let mut c = base.clone();
    c.set("mbvh4_window", "3").unwrap();
    assert_eq!(c.mbvh4_window, Some(3));
    let r = check(&a, &c);
    let m = r.mbvh4.as_ref().unwrap();
    let st = m.stream.as_ref().unwrap();
    assert_eq!(st.busy_cycles, (st.nodes_in + 1) * 4 + st.nodes_written);
    assert!(st.max_treelet_nodes > 0);
    assert_eq!(
        greedy
            .mbvh4
            .as_ref()
            .unwrap()
            .stream
            .as_ref()
            .unwrap()
            .max_treelet_nodes,
        0
    );
    assert!(m.sah < greedy.mbvh4.as_ref().unwrap().sah);
    assert_eq!(r.bytes_read, greedy.bytes_read);
    c.set("mbvh4_window", "none").unwrap();
    assert_eq!(c.mbvh4_window, None);
    c.mbvh4_window = Some(MAX_MBVH4_WINDOW + 1);
    assert!(c.validate().is_err());
}
