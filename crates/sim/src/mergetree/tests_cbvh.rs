//! Tests of the CBVH output modes (\[P3\] §5.3): the CBVH the model writes equals the
//! software encoders' bit for bit, the DRAM accesses match the encoder's counts, the
//! backtracking steps are sequential, and the top-down pass follows an unchanged build.

use super::*;
use crate::dram::simple::{SimpleDram, SimpleDramConfig};
use cbvh::Coords;
use proptest::prelude::*;

/// Deterministic pseudo-random boxes, every seventh flat in z (degenerate axes).
fn boxes(n: usize, seed: u64) -> Vec<Aabb> {
    let mut a = super::tests::random_boxes(n, seed);
    for b in a.iter_mut().step_by(7) {
        b.max.z = b.min.z;
    }
    a
}

/// Boxes whose centroids take `distinct` values: long runs of equal codes (big leaves).
fn clustered(n: usize, distinct: usize) -> Vec<Aabb> {
    super::tests::clustered_boxes(n, distinct)
}

fn simple(gbps: u64, lat_ns: u64) -> Box<dyn MemoryPort> {
    Box::new(SimpleDram::new(SimpleDramConfig {
        peak_bytes_per_s: gbps * 1_000_000_000,
        latency_ns: lat_ns,
        ..SimpleDramConfig::lpddr3_1600_1x64_like()
    }))
}

/// Preset `p3` shrunk so that small scenes take a merge pass.
fn p3_small(m: u32) -> MergeTreeConfig {
    MergeTreeConfig {
        m,
        trace_window_cycles: 1000,
        ..MergeTreeConfig::p3()
    }
}

fn stream(mut c: MergeTreeConfig, coords: Coords, treelet: u32) -> MergeTreeConfig {
    c.output = OutputMode::CbvhStream;
    c.cbvh_coords = coords;
    c.cbvh_treelet_depth = treelet;
    c
}

/// Simulates and checks the BVH and the CBVH against software; returns the report.
fn check(a: &[Aabb], c: &MergeTreeConfig, port: Box<dyn MemoryPort>) -> MergeTreeReport {
    let r = simulate(a, c, port).unwrap();
    assert!(tree_matches_software(&r, a).unwrap(), "BVH differs");
    assert_eq!(
        cbvh_matches_software(&r, a).unwrap(),
        Some(true),
        "CBVH differs ({} prims, {:?})",
        a.len(),
        c.output
    );
    r
}

#[test]
fn streaming_cbvh_equals_the_software_encoder_bit_for_bit() {
    let a = boxes(6000, 1);
    for coords in [Coords::Relative, Coords::Modulo] {
        for treelet in [1, 2, 4] {
            let c = stream(p3_small(1024), coords, treelet);
            let r = check(&a, &c, simple(13, 40));
            let cb = r.cbvh.as_ref().unwrap();
            let (sw, stats) = software_cbvh(&a, &c).unwrap().unwrap();
            // The comparison the check made, spelled out.
            assert_eq!(cb.tree.pairs, sw.pairs);
            assert_eq!(cb.tree.prim_ids, sw.prim_ids);
            assert_eq!((cb.tree.root, cb.tree.root_ctx), (sw.root, sw.root_ctx));
            assert_eq!(cb.backtrack_steps, stats.backtrack_steps);
            // Every access the encoder reported went to memory.
            let st = cb.stream.as_ref().unwrap();
            assert_eq!(st.pairs_written, cb.node_pairs);
            assert_eq!(st.backtrack_reads, cb.backtrack_steps);
            assert_eq!(st.backtrack_writes, cb.backtrack_steps);
            assert_eq!(st.nodes_in, r.nodes);
            assert_eq!(r.merge_passes, 1);
            if treelet == 1 {
                assert!(cb.backtrack_steps > 0, "{coords:?}");
            }
        }
    }
}

#[test]
fn one_primitive_per_leaf_and_big_leaves_match() {
    for a in [boxes(3000, 2), clustered(2500, 30), clustered(400, 1)] {
        for combine in [false, true] {
            let mut c = stream(p3_small(512), Coords::Relative, 1);
            c.combine_identical = combine;
            let r = check(&a, &c, simple(13, 40));
            if !combine {
                // One primitive per leaf: n - 1 nodes.
                assert_eq!(r.cbvh.unwrap().node_pairs, a.len() as u64 - 1);
            }
            let mut t = c.clone();
            t.output = OutputMode::CbvhTopdown;
            check(&a, &t, simple(13, 40));
        }
    }
}

#[test]
fn tiny_and_empty_scenes() {
    for n in [1, 2, 3, 17] {
        let a = boxes(n, n as u64);
        for mode in [OutputMode::CbvhStream, OutputMode::CbvhTopdown] {
            let c = MergeTreeConfig {
                output: mode,
                ..p3_small(64)
            };
            let r = check(&a, &c, simple(13, 40));
            assert_eq!(r.cbvh.unwrap().node_pairs, (n as u64 - 1).max(1));
        }
    }
    let c = stream(MergeTreeConfig::p3(), Coords::Modulo, 2);
    let r = simulate(&[], &c, simple(13, 40)).unwrap();
    assert_eq!(r.cycles, 0);
    assert_eq!(cbvh_matches_software(&r, &[]).unwrap(), Some(true));
}

#[test]
fn two_merge_passes_and_a_full_fifo() {
    // M = 256, B = 8: fan-in 16, one pass sorts 4096; 5000 needs two.
    let a = boxes(5000, 3);
    let mut c = stream(p3_small(256), Coords::Relative, 1);
    c.cbvh_fifo = 1;
    let r = check(&a, &c, simple(13, 300));
    assert_eq!(r.merge_passes, 2);
    // A slow memory: the encoder waits for its reads and the emitter for the encoder.
    assert!(r.stalls.emitter.encoder_full_cycles > 0);
    let st = r.cbvh.unwrap().stream.unwrap();
    assert!(st.read_wait_cycles > 0 && st.backtrack_read_latency_cycles > 0);
}

#[test]
fn backtracking_steps_are_sequential() {
    // Every step waits for its read: at least steps x latency cycles of waiting.
    let a = boxes(4000, 4);
    let lat = 500;
    let c = stream(p3_small(1024), Coords::Relative, 1);
    let r = check(&a, &c, simple(100, lat));
    let cb = r.cbvh.as_ref().unwrap();
    let st = cb.stream.as_ref().unwrap();
    assert!(cb.backtrack_steps > 100);
    assert!(st.backtrack_read_latency_cycles >= cb.backtrack_steps * lat);
    assert!(st.read_wait_cycles >= cb.backtrack_steps * (lat - 1));
    assert!(r.cycles > cb.backtrack_steps * lat);
    // Modulo coordinates with depth-4 treelets leave little to backtrack: much faster.
    let m4 = check(
        &a,
        &stream(p3_small(1024), Coords::Modulo, 4),
        simple(100, lat),
    );
    assert!(m4.cbvh.as_ref().unwrap().backtrack_steps < cb.backtrack_steps / 10);
    assert!(m4.cycles < r.cycles / 2, "{} {}", m4.cycles, r.cycles);
}

#[test]
fn traffic_of_the_cbvh_modes() {
    let a = boxes(6000, 5);
    let base = p3_small(1024);
    let plain = simulate(&a, &base, simple(13, 40)).unwrap();
    // Top-down: the build is the plain build, cycle for cycle; the pass then reads every
    // node (64 B) and writes every pair (16 B).
    let td_cfg = MergeTreeConfig {
        output: OutputMode::CbvhTopdown,
        ..base.clone()
    };
    let td = check(&a, &td_cfg, simple(13, 40));
    let cb = td.cbvh.as_ref().unwrap();
    assert_eq!(cb.build_cycles, plain.cycles);
    assert_eq!(cb.build_cycles + cb.compress_cycles, td.cycles);
    let pass = td.phases.last().unwrap();
    assert_eq!(pass.name, "topdown_compress");
    assert_eq!(pass.bytes_read, plain.nodes * 64);
    let bursts = |b: u64| b.div_ceil(64) * 64;
    assert_eq!(pass.bytes_written, bursts(cb.node_pairs * 16));
    assert_eq!(td.bytes_read, plain.bytes_read + plain.nodes * 64);
    assert_eq!(cb.topdown.as_ref().unwrap().node_reads, plain.nodes);
    // Streaming, no backtracking left (M4): the 64-byte nodes become 16-byte pairs.
    let m4 = check(&a, &stream(base.clone(), Coords::Modulo, 4), simple(13, 40));
    let cb4 = m4.cbvh.as_ref().unwrap();
    assert_eq!(cb4.backtrack_steps, 0, "expected no backtracking here");
    assert_eq!(m4.bytes_read, plain.bytes_read);
    assert_eq!(
        m4.bytes_written,
        plain.bytes_written - plain.nodes * 64 + bursts(cb4.node_pairs * 16)
    );
    assert!(m4.cycles < plain.cycles && plain.cycles < td.cycles);
    // Relative, plain: every step adds a 64-byte read and a 64-byte write (and the write
    // buffer's flushes before reads of lines it still held add partial-line writes).
    let r = check(&a, &stream(base, Coords::Relative, 1), simple(13, 40));
    let cbr = r.cbvh.as_ref().unwrap();
    let steps = cbr.backtrack_steps;
    assert_eq!(r.bytes_read, plain.bytes_read + steps * 64);
    let min_written = plain.bytes_written - plain.nodes * 64 + cbr.node_pairs * 16 + steps * 64;
    assert!(r.bytes_written >= min_written);
    let flushes = cbr.stream.as_ref().unwrap().backtrack_flushes;
    assert!(flushes > 0 && flushes <= steps);
    // Each flush splits one burst between two writes at most; the last write is rounded.
    assert!(r.bytes_written <= min_written + (flushes + 1) * 64);
}

#[test]
fn fast_forward_is_exact_in_the_cbvh_modes() {
    let a = boxes(3000, 6);
    for mode in [OutputMode::CbvhStream, OutputMode::CbvhTopdown] {
        for lat in [40, 400] {
            let mut c = MergeTreeConfig {
                output: mode,
                cbvh_fifo: 2,
                ..p3_small(512)
            };
            let fast = simulate(&a, &c, simple(13, lat)).unwrap();
            c.fast_forward = false;
            let slow = simulate(&a, &c, simple(13, lat)).unwrap();
            assert_eq!(fast.cycles, slow.cycles);
            assert_eq!(fast.stalls, slow.stalls);
            assert_eq!(fast.phases, slow.phases);
            assert_eq!(fast.trace, slow.trace);
            assert_eq!(fast.memory, slow.memory);
            let (f, s) = (fast.cbvh.unwrap(), slow.cbvh.unwrap());
            assert_eq!((f.stream, f.topdown), (s.stream, s.topdown));
            assert!(fast.fast_forward_cycles > 0);
        }
    }
}

#[test]
fn cbvh_mode_errors() {
    let a = boxes(100, 7);
    let mut c = stream(MergeTreeConfig::p3(), Coords::Relative, 1);
    c.highlevel_threshold = Some(20);
    assert!(matches!(
        simulate(&a, &c, simple(13, 40)),
        Err(MergeTreeError::Config(_))
    ));
    // The plain mode has no CBVH to compare.
    let r = simulate(&a, &MergeTreeConfig::p3(), simple(13, 40)).unwrap();
    assert!(r.cbvh.is_none());
    assert_eq!(cbvh_matches_software(&r, &a).unwrap(), None);
    // A changed pair is seen.
    let mut r = simulate(
        &a,
        &stream(MergeTreeConfig::p3(), Coords::Modulo, 1),
        simple(13, 40),
    )
    .unwrap();
    assert_eq!(cbvh_matches_software(&r, &a).unwrap(), Some(true));
    let cb = r.cbvh.as_mut().unwrap();
    cb.tree.pairs[0].slots[0].ptr ^= 1;
    assert_eq!(cbvh_matches_software(&r, &a).unwrap(), Some(false));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    #[test]
    fn any_small_streaming_configuration_matches_software(
        n in 1usize..600,
        seed in 0u64..1000,
        fan_log in 1u32..4,
        bits in 3u32..=8,
        treelet in 1u32..=4,
        modulo in any::<bool>(),
        clustered_in in any::<bool>(),
        fifo in 1u32..4,
        lat in prop_oneof![Just(10u64), Just(200)],
    ) {
        let a = if clustered_in { clustered(n, 1 + seed as usize % 9) } else { boxes(n, seed) };
        let mut c = stream(p3_small(16 << fan_log), if modulo { Coords::Modulo } else { Coords::Relative }, treelet);
        c.cbvh_bits = bits;
        c.cbvh_fifo = fifo;
        let r = simulate(&a, &c, simple(13, lat)).unwrap();
        prop_assert!(tree_matches_software(&r, &a).unwrap());
        prop_assert_eq!(cbvh_matches_software(&r, &a).unwrap(), Some(true));
    }
}

#[test]
fn topdown_build_phase_is_the_plain_build_on_dramsim3() {
    // The report takes the BVH column from the TD run's build phase: equal cycle for cycle
    // on the cycle-accurate memory too (the pass starts once every write is done).
    let a = boxes(3000, 8);
    let open = || crate::dram::open("lpddr3-1600-2x32", 1_000_000).unwrap();
    let base = p3_small(512);
    let plain = simulate(&a, &base, open()).unwrap();
    let td = MergeTreeConfig {
        output: OutputMode::CbvhTopdown,
        ..base
    };
    let r = check(&a, &td, open());
    let cb = r.cbvh.unwrap();
    assert_eq!(cb.build_cycles, plain.cycles);
    assert_eq!(r.phases[..plain.phases.len()], plain.phases[..]);
    assert!(cb.compress_cycles > 0);
}
