//! Cross-validation of Arbor's controller model ([`super::lpddr`]) against DRAMsim3
//! ([`super::dramsim3`]): identical request streams through the same shared port must give
//! identical responses (tag, accepted and completed unit cycle, in the same order) and
//! identical statistics (command counts, row hits, rank cycle split, energy).

use super::dramsim3::{Dramsim3Port, SYSTEMS};
use super::lpddr::LpddrPort;
use super::{AccessKind, MemRequest, MemResponse, MemStats, MemoryPort};
use crate::clock::PeriodFs;

const GHZ: PeriodFs = 1_000_000;

/// One request of an open-loop stream: offered no earlier than unit cycle `at`, and not
/// before the previous request was accepted.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Timed {
    pub at: u64,
    pub req: MemRequest,
}

fn lcg(state: &mut u64) -> u64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    *state >> 16
}

fn req(tag: u64, addr: u64, bytes: u32, write: bool) -> MemRequest {
    MemRequest {
        tag,
        addr,
        bytes,
        kind: if write {
            AccessKind::Write
        } else {
            AccessKind::Read
        },
    }
}

/// The synthetic patterns: those of `arbor sim dram` (sequential reads, random reads,
/// sequential writes, copy) and mixed traffic, each with stretches of idle time, and
/// same-address traffic that exercises write merging and reads served from the buffer.
pub(crate) fn patterns(n: u64, seed: u64) -> Vec<(&'static str, Vec<Timed>)> {
    let mut out = Vec::new();
    let mut s = seed;
    // Idle bursts: every 997 requests, a gap of 0..3000 unit cycles.
    let timed = |reqs: Vec<MemRequest>, s: &mut u64, rate: u64| -> Vec<Timed> {
        let mut at = 0;
        reqs.into_iter()
            .enumerate()
            .map(|(i, r)| {
                if i % 997 == 996 {
                    at += lcg(s) % 3000;
                } else if rate > 0 {
                    at += lcg(s) % rate;
                }
                Timed { at, req: r }
            })
            .collect()
    };
    let seq: Vec<_> = (0..n).map(|i| req(i, i * 64, 64, false)).collect();
    out.push(("seq", timed(seq, &mut s, 0)));
    let mut r = seed ^ 0x55;
    let random: Vec<_> = (0..n)
        .map(|i| req(i, (lcg(&mut r) % (1 << 30)) / 64 * 64, 64, false))
        .collect();
    out.push(("random", timed(random, &mut s, 3)));
    let writes: Vec<_> = (0..n).map(|i| req(i, i * 128, 128, true)).collect();
    out.push(("write", timed(writes, &mut s, 0)));
    let copy: Vec<_> = (0..n)
        .map(|i| {
            if i % 2 == 0 {
                req(i, (i / 2) * 256, 256, false)
            } else {
                req(i, (i / 2) * 256 + (1 << 29), 256, true)
            }
        })
        .collect();
    out.push(("copy", timed(copy, &mut s, 0)));
    let mixed: Vec<_> = (0..n)
        .map(|i| {
            let x = lcg(&mut r);
            let addr = (x >> 8) % (1 << 28);
            req(i, addr, 1 + (x % 300) as u32, x.is_multiple_of(3))
        })
        .collect();
    out.push(("mixed", timed(mixed, &mut s, 8)));
    // A few hot lines: write merging, reads of buffered writes, duplicate reads.
    let hot: Vec<_> = (0..n)
        .map(|i| {
            let x = lcg(&mut r);
            let addr = (x >> 8) % 24 * 4096 + (x >> 20) % 4 * 64;
            req(i, addr, 64, x % 5 < 2)
        })
        .collect();
    out.push(("hot", timed(hot.clone(), &mut s, 0)));
    out.push(("hot-paced", timed(hot, &mut s, 6)));
    out
}

/// Runs `work` open loop and returns every response, in the order the port gave them,
/// and the final statistics.
pub(crate) fn run_open_loop(
    port: &mut dyn MemoryPort,
    work: &[Timed],
) -> (Vec<MemResponse>, MemStats) {
    let mut out = Vec::with_capacity(work.len());
    let mut next = 0;
    while out.len() < work.len() {
        while next < work.len() && work[next].at <= port.cycle() {
            if port.send(work[next].req).is_err() {
                break;
            }
            next += 1;
        }
        if next < work.len() && work[next].at > port.cycle() && port.outstanding() == 0 {
            let gap = work[next].at - port.cycle();
            port.tick_many(gap);
        } else {
            port.tick();
        }
        while let Some(r) = port.pop_response() {
            out.push(r);
        }
    }
    port.tick_many(1000);
    (out, port.stats())
}

/// Runs `work` on both backends of `system`; panics on the first difference.
pub(crate) fn compare(system: &str, name: &str, work: &[Timed]) -> u64 {
    let mut a = Dramsim3Port::open(system, GHZ).unwrap();
    let mut b = LpddrPort::open(system, GHZ).unwrap();
    let (ra, sa) = run_open_loop(&mut a, work);
    let (rb, sb) = run_open_loop(&mut b, work);
    for (i, (x, y)) in ra.iter().zip(&rb).enumerate() {
        assert_eq!(x, y, "{system} {name}: response {i} differs");
    }
    assert_eq!(ra.len(), rb.len());
    assert_eq!(sa, sb, "{system} {name}: statistics differ");
    ra.iter().map(|r| r.completed_cycle).max().unwrap_or(0)
}

#[test]
fn every_pattern_on_every_system_matches_dramsim3_exactly() {
    for sys in SYSTEMS {
        for (name, work) in patterns(6_000, 17) {
            let end = compare(sys.name, name, &work);
            println!("{} {name}: {end} unit cycles, identical", sys.name);
        }
    }
}

#[test]
fn isolated_and_long_idle_traffic_matches_dramsim3() {
    // Single requests far apart (refreshes in between, closed and open rows).
    let work: Vec<Timed> = (0..200u64)
        .map(|i| Timed {
            at: i * 1777,
            req: req(i, (i * 7919) % 64 * 8192 + i % 3 * 64, 64, i % 4 == 3),
        })
        .collect();
    for sys in SYSTEMS {
        compare(sys.name, "isolated", &work);
    }
}

#[test]
fn tick_many_and_ticks_agree_on_the_model() {
    let (_, work) = patterns(1500, 3).swap_remove(4);
    let mut a = LpddrPort::open("lpddr3-1333-4x64", GHZ).unwrap();
    let mut b = LpddrPort::open("lpddr3-1333-4x64", GHZ).unwrap();
    for (i, t) in work.iter().enumerate() {
        let (ra, rb) = (a.send(t.req), b.send(t.req));
        assert_eq!(ra.is_ok(), rb.is_ok());
        let n = 1 + (i as u64 % 7);
        for _ in 0..n {
            a.tick();
        }
        b.tick_many(n);
    }
    a.tick_many(50_000);
    for _ in 0..50_000 {
        b.tick();
    }
    let ra: Vec<_> = std::iter::from_fn(|| a.pop_response()).collect();
    let rb: Vec<_> = std::iter::from_fn(|| b.pop_response()).collect();
    assert_eq!(ra, rb);
    assert_eq!(a.stats(), b.stats());
}

/// Deterministic pseudo-random boxes in a 100-unit cube.
fn boxes(n: usize, seed: u64) -> Vec<geom::Aabb> {
    let mut s = seed;
    let mut next = move || (lcg(&mut s) >> 24) as f32 / (1u64 << 24) as f32;
    (0..n)
        .map(|_| {
            let c = geom::Vec3::new(next(), next(), next()) * 100.0;
            let e = geom::Vec3::new(next(), next(), next()) + geom::Vec3::splat(0.01);
            geom::Aabb::new(c - e, c + e)
        })
        .collect()
}

/// Closed loop: the MergeTree model (small inputs, presets p1 to p3, the CBVH stream
/// output) on every LPDDR3 system takes the same cycles and moves the same commands on
/// both backends.
#[test]
fn mergetree_runs_are_identical_on_both_backends() {
    use crate::mergetree::{simulate, MergeTreeConfig, OutputMode};
    let configs = [
        MergeTreeConfig {
            m: 512,
            ..MergeTreeConfig::p1()
        },
        MergeTreeConfig {
            m: 1024,
            ..MergeTreeConfig::p2()
        },
        MergeTreeConfig {
            m: 512,
            output: OutputMode::CbvhStream,
            ..MergeTreeConfig::p3()
        },
    ];
    for (k, cfg) in configs.iter().enumerate() {
        let boxes = boxes(6000 + 2000 * k, 40 + k as u64);
        for (name, _, _) in super::MEMORY_SYSTEMS {
            let a = simulate(
                &boxes,
                cfg,
                Box::new(Dramsim3Port::open(name, cfg.period_fs()).unwrap()),
            )
            .unwrap();
            let b = simulate(
                &boxes,
                cfg,
                Box::new(LpddrPort::open(name, cfg.period_fs()).unwrap()),
            )
            .unwrap();
            assert_eq!(a.cycles, b.cycles, "{name} config {k}");
            assert_eq!(a.memory, b.memory, "{name} config {k}");
            assert_eq!(a.phases, b.phases, "{name} config {k}");
            println!("{name} config {k}: {} cycles on both", a.cycles);
        }
    }
}
