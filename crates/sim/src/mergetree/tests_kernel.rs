//! Tests of the machine on the simulation kernel: the trees equal the software builder's,
//! and a run with the kernel's skipping equals one that steps every unit in every cycle
//! (cycles, phases, memory statistics, every unit's activity and counters, the stall
//! report and the time series) on the simple backend and on DRAMsim3.

use super::tests::{check, clustered_boxes, port, random_boxes, small};
use super::*;
use proptest::prelude::*;

/// Everything simulated must be equal with and without skipping.
fn assert_same(fast: &MergeTreeReport, slow: &MergeTreeReport, what: &str) {
    assert_eq!(fast.cycles, slow.cycles, "{what}");
    assert_eq!(fast.phases, slow.phases, "{what}");
    assert_eq!(fast.memory, slow.memory, "{what}");
    assert_eq!(fast.stalls, slow.stalls, "{what}");
    assert_eq!(fast.units, slow.units, "{what}");
    assert_eq!(fast.trace, slow.trace, "{what}");
    assert_eq!(slow.fast_forward_cycles, 0, "{what}");
    for u in &fast.units {
        assert_eq!(
            u.activity.accounted_cycles(),
            fast.cycles,
            "{what}: {}",
            u.name
        );
    }
}

#[test]
fn kernel_machine_builds_the_software_trees() {
    let a = random_boxes(3000, 1);
    let r = check(&a, &small(4096, 8, 4));
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (1, 0));
    let names: Vec<_> = r.phases.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["sort_and_emit"]);
    let r = check(&random_boxes(5000, 2), &small(1024, 8, 3));
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (5, 1));
    let names: Vec<_> = r.phases.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["partial_sort", "merge_pass_1_and_emit"]);
    let r = check(&random_boxes(5000, 3), &small(256, 8, 2));
    assert_eq!((r.partial_sort_blocks, r.merge_passes), (20, 2));
    let r = check(&clustered_boxes(4000, 7), &small(512, 4, 2));
    assert!(r.merge_passes >= 1);
    for n in [1usize, 2, 3, 7, 9, 17] {
        let r = check(&random_boxes(n, n as u64), &small(64, 4, 2));
        assert_eq!(r.leaf_entries, n as u64);
    }
    let r = simulate(&[], &small(64, 4, 2), port(13)).unwrap();
    assert_eq!(r.cycles, 0);
    // 63-bit codes with the toplevel SAH unit.
    let mut cfg = small(1024, 8, 3);
    cfg.morton_bits = 63;
    cfg.highlevel_threshold = Some(21);
    cfg.toplevel_sah = true;
    let r = check(&random_boxes(5000, 4), &cfg);
    assert!(r.highlevel_roots > 1);
    assert!(r.toplevel_sweeps > 0 && r.toplevel_cycles > r.highlevel_roots);
    assert_eq!(r.phases.last().unwrap().name, "toplevel_sah");
    // Every unit's activity covers the run; phase traffic adds up to the port's.
    for u in &r.units {
        assert_eq!(u.activity.accounted_cycles(), r.cycles, "{}", u.name);
    }
    let phase_bytes: u64 = r
        .phases
        .iter()
        .map(|p| p.bytes_read + p.bytes_written)
        .sum();
    assert_eq!(phase_bytes, r.bytes_read + r.bytes_written);
}

#[test]
fn kernel_skipping_is_exact_on_the_simple_backend() {
    let a = random_boxes(6000, 13);
    for gbps in [3, 13, 43] {
        for (m, b, p, top) in [(512, 8, 3, false), (4096, 8, 4, false), (1024, 8, 2, true)] {
            let mut cfg = small(m, b, p);
            if top {
                cfg.morton_bits = 63;
                cfg.highlevel_threshold = Some(21);
                cfg.toplevel_sah = true;
            }
            let fast = simulate(&a, &cfg, port(gbps)).unwrap();
            cfg.fast_forward = false;
            let slow = simulate(&a, &cfg, port(gbps)).unwrap();
            assert_same(&fast, &slow, &format!("{gbps} GB/s m={m}"));
            assert!(fast.fast_forward_cycles > 0);
            assert!(tree_matches_software(&fast, &a).unwrap());
        }
    }
}

#[test]
fn kernel_skipping_is_exact_on_the_cycle_accurate_memory() {
    let a = random_boxes(3000, 17);
    for system in ["lpddr3-1600-1x64", "lpddr3-1333-4x64"] {
        let mut cfg = small(512, 8, 3);
        let period = cfg.period_fs();
        let open = || crate::dram::open(system, period).unwrap();
        let fast = simulate(&a, &cfg, open()).unwrap();
        cfg.fast_forward = false;
        let slow = simulate(&a, &cfg, open()).unwrap();
        assert_same(&fast, &slow, system);
        assert!(fast.fast_forward_cycles > 0, "{system}");
        assert!(tree_matches_software(&fast, &a).unwrap());
        assert_eq!(fast.memory.unit_cycles, fast.cycles);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    #[test]
    fn kernel_any_small_configuration_builds_the_software_tree(
        n in 1usize..600,
        seed in 0u64..1000,
        b_log in 0u32..4,
        fan_log in 1u32..3,
        presorters in 1u32..5,
        clustered in any::<bool>(),
        dram in 0usize..5,
    ) {
        let a = if clustered { clustered_boxes(n, 1 + seed as usize % 9) } else { random_boxes(n, seed) };
        let b = 1 << b_log;
        let mut c = small((2 * b) << fan_log, b, presorters);
        c.emit_fifo = 1 + (seed % 8) as u32;
        c.presort_slots = 1 + (seed % 3) as u32;
        let open = |c: &MergeTreeConfig| -> Box<dyn MemoryPort> {
            if dram == 0 { port(13) } else {
                let name = crate::dram::MEMORY_SYSTEMS[dram - 1].0;
                crate::dram::open(name, c.period_fs()).unwrap()
            }
        };
        let r = simulate(&a, &c, open(&c)).unwrap();
        prop_assert!(tree_matches_software(&r, &a).unwrap());
        prop_assert!(r.cycles > 0 && r.memory.unit_cycles == r.cycles);
        c.fast_forward = false;
        let slow = simulate(&a, &c, open(&c)).unwrap();
        prop_assert_eq!(r.cycles, slow.cycles);
        prop_assert_eq!(&r.units, &slow.units);
        prop_assert_eq!(&r.stalls, &slow.stalls);
        prop_assert_eq!(&r.memory, &slow.memory);
    }
}
