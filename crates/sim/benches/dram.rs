//! Simulation speed of the memory backends (Arbor's controller model under the bare names,
//! DRAMsim3 under `dramsim3:`, the simple model under `simple:`), in simulated unit cycles per second (1 GHz unit
//! clock, one core). Throughput is reported in unit cycles ("elem/s"); the DRAM clock runs
//! at 0.8 (LPDDR3-1600), 0.667 (LPDDR3-1333) or 1.6 (LPDDR4-3200) cycles per unit cycle.
//!
//! - `stream/*`: a sequential 64-B read stream kept as busy as the port allows (the
//!   DRAM-bound case a MergeTree build spends most of its time in);
//! - `idle/*`: ticks with nothing outstanding (DRAMsim3 still runs its clock and refresh).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use sim::dram::{open, AccessKind, MemRequest, MemoryPort};
use std::time::Duration;

const GHZ: u64 = 1_000_000;

/// Streams `requests` sequential 64-B reads through `port`; returns the unit cycles it took.
fn stream(port: &mut dyn MemoryPort, requests: u64) -> u64 {
    let start = port.cycle();
    let (mut sent, mut got) = (0, 0);
    while got < requests {
        while sent < requests
            && port
                .send(MemRequest {
                    tag: sent,
                    addr: sent * 64,
                    bytes: 64,
                    kind: AccessKind::Read,
                })
                .is_ok()
        {
            sent += 1;
        }
        port.tick();
        while port.pop_response().is_some() {
            got += 1;
        }
    }
    port.cycle() - start
}

fn bench(c: &mut Criterion) {
    let requests = 4096;
    let mut g = c.benchmark_group("stream");
    g.measurement_time(Duration::from_secs(3)).sample_size(10);
    for name in [
        "lpddr3-1600-1x64",
        "lpddr3-1600-2x64",
        "lpddr3-1333-4x64",
        "lpddr3-1600-2x32",
        "lpddr4-3200-4x16",
        "dramsim3:lpddr3-1600-1x64",
        "dramsim3:lpddr3-1333-4x64",
        "simple:lpddr3-1600-1x64",
    ] {
        // The cycle count is deterministic: measure it once for the throughput.
        let cycles = stream(open(name, GHZ).unwrap().as_mut(), requests);
        g.throughput(Throughput::Elements(cycles));
        g.bench_with_input(BenchmarkId::from_parameter(name), &name, |b, name| {
            b.iter_with_setup(
                || open(name, GHZ).unwrap(),
                |mut p| stream(p.as_mut(), requests),
            )
        });
    }
    g.finish();

    let mut g = c.benchmark_group("idle");
    g.measurement_time(Duration::from_secs(3)).sample_size(10);
    let cycles = 200_000;
    g.throughput(Throughput::Elements(cycles));
    for name in [
        "lpddr3-1600-1x64",
        "lpddr3-1333-4x64",
        "dramsim3:lpddr3-1600-1x64",
        "simple:lpddr3-1600-1x64",
    ] {
        let mut port = open(name, GHZ).unwrap();
        g.bench_with_input(BenchmarkId::from_parameter(name), &name, |b, _| {
            b.iter(|| {
                port.tick_many(cycles);
                port.cycle()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
