//! Forecasting read scheduling (`read_schedule = forecast`, \[P2\] §7): capacity, the tree
//! against the software builder, and traffic against double buffering.

use super::config::ReadSchedule;
use super::tests::{check, clustered_boxes, port, random_boxes, small};
use super::*;
use proptest::prelude::*;

fn forecast(mut c: MergeTreeConfig, spares: u32) -> MergeTreeConfig {
    c.read_schedule = ReadSchedule::Forecast;
    c.forecast_spares = spares;
    c
}

#[test]
fn forecast_fits_twice_the_runs_per_pass() {
    for (m, b) in [(8192u32, 16u32), (16384, 16), (4096, 8), (8192, 8)] {
        let mut d = MergeTreeConfig::p2();
        d.m = m;
        d.b = b;
        let f = forecast(d.clone(), 16);
        f.validate().unwrap();
        // Two buffers per run against one: the runs and the spares fill the buffers that
        // double buffering gives its runs.
        assert_eq!(f.fan_in() + 16, 2 * d.fan_in(), "M {m} B {b}");
        assert_eq!(f.single_pass_limit(), m as u64 * (m as u64 / b as u64 - 16));
        assert!(f.single_pass_limit() as f64 >= 1.93 * d.single_pass_limit() as f64);
    }
    // [P2] §6.2 (256 KB, B = 16): 2M double-buffered, 496 runs = 4,063,232 forecast;
    // [P2] §7 (512 KB): 8M double-buffered, 1008 runs = 16,515,072 forecast.
    let p2 = MergeTreeConfig::p2();
    assert_eq!(p2.read_schedule, ReadSchedule::Double);
    assert_eq!(forecast(p2.clone(), 16).single_pass_limit(), 4_063_232);
    let mut big = p2;
    big.m = 16384;
    assert_eq!(big.single_pass_limit(), 8 << 20);
    assert_eq!(forecast(big, 16).single_pass_limit(), 16_515_072);
}

#[test]
fn forecast_keys_parse_and_validate() {
    let mut c = MergeTreeConfig::p2();
    c.set("read_schedule", "forecast").unwrap();
    c.set("forecast_spares", "32").unwrap();
    assert_eq!(c.read_schedule, ReadSchedule::Forecast);
    assert_eq!(c.fan_in(), 480);
    c.validate().unwrap();
    c.set("forecast_spares", "257").unwrap();
    assert!(c
        .validate()
        .unwrap_err()
        .to_string()
        .contains("forecast_spares"));
    c.set("forecast_spares", "256").unwrap();
    c.validate().unwrap();
    assert!(c.set("forecast_spares", "0").is_err());
    assert!(c.set("read_schedule", "lru").is_err());
    c.set("read_schedule", "double").unwrap();
    assert_eq!(c.fan_in(), 256);
}

#[test]
fn forecast_one_pass_matches_software_with_the_same_traffic() {
    let a = random_boxes(5000, 2);
    let d = check(&a, &small(1024, 8, 4)); // 5 blocks, one pass either way
    let f = check(&a, &forecast(small(1024, 8, 4), 4));
    assert_eq!((f.partial_sort_blocks, f.merge_passes), (5, 1));
    // Every block is read once in both schedules: only the timing differs.
    assert_eq!(
        (f.bytes_read, f.bytes_written),
        (d.bytes_read, d.bytes_written)
    );
    assert_eq!(f.highlevel, d.highlevel);
}

#[test]
fn forecast_halves_the_passes_where_double_buffering_needs_two() {
    // M = 256, B = 8: double-buffered fan-in 16 (4096 elements), forecast with 2 spares
    // fan-in 30 (7680): 5000 boxes in 20 blocks take two passes or one.
    let a = random_boxes(5000, 3);
    let d = check(&a, &small(256, 8, 2));
    let fc = forecast(small(256, 8, 2), 2);
    assert_eq!(fc.fan_in(), 30);
    let f = check(&a, &fc);
    assert_eq!((d.merge_passes, f.merge_passes), (2, 1));
    // One pass less: one read and one write of the whole scene less.
    assert_eq!(d.bytes_read - f.bytes_read, 5000 * 32);
    assert_eq!(d.bytes_written - f.bytes_written, 5000 * 32);
    assert!(f.cycles < d.cycles);
}

#[test]
fn forecast_several_passes_match_software() {
    let a = random_boxes(3000, 4);
    let r = check(&a, &forecast(small(32, 4, 1), 1)); // fan-in 7: 94 -> 14 -> 2 -> 1
    assert_eq!(r.merge_passes, 3);
    let c = clustered_boxes(4000, 7);
    check(&c, &forecast(small(64, 4, 2), 3));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn forecast_any_small_configuration_builds_the_software_tree(
        n in 1usize..700,
        seed in 0u64..1000,
        b_log in 0u32..4,
        fan_log in 1u32..4,
        spares_pick in 0u32..100,
        clustered in any::<bool>(),
        gbps in prop_oneof![Just(2u64), Just(13), Just(200)],
    ) {
        let a = if clustered { clustered_boxes(n, 1 + seed as usize % 9) } else { random_boxes(n, seed) };
        let b = 1 << b_log;
        let c = small((2 * b) << fan_log, b, 2);
        let spares = 1 + spares_pick % (c.fan_in() as u32);
        let c = forecast(c, spares);
        let r = simulate(&a, &c, port(gbps)).unwrap();
        prop_assert!(tree_matches_software(&r, &a).unwrap());
    }
}
