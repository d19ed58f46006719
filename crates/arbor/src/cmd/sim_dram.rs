//! `arbor sim dram` drives one memory system with a synthetic access pattern and reports
//! bandwidth, latency, row hits, commands and energy. The JSON form (`arbor.sim.dram.v1`)
//! is documented in `docs/cli-json.md`.

use crate::progress::{Ui, Unit};
use serde::Serialize;
use sim::dram::{AccessKind, DramEnergy, MemRequest, MemStats};
use std::time::Instant;

/// Access patterns of `arbor sim dram`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    /// Sequential reads from address 0.
    Seq,
    /// Reads at uniformly random aligned addresses in the first GiB.
    Random,
    /// Sequential writes from address 0.
    Write,
    /// Sequential reads and writes, alternating, to two separate arrays.
    Copy,
}

/// Arguments of `arbor sim dram`.
#[derive(clap::Args, Debug)]
pub struct DramArgs {
    /// Memory system: a name from the list below, `simple:NAME`, or
    /// `simple:bw=BYTES_PER_S,lat=NS`. Systems: lpddr3-1600-1x64, lpddr3-1600-2x64,
    /// lpddr3-1333-4x64, lpddr3-1600-2x32, lpddr4-3200-4x16.
    #[arg(long, default_value = "lpddr3-1600-1x64")]
    system: String,
    /// Access pattern.
    #[arg(long, value_enum, default_value = "seq")]
    pattern: Pattern,
    /// Bytes to move in all (at most 16 GiB).
    #[arg(long, default_value_t = 1 << 20)]
    bytes: u64,
    /// Bytes per request (1 to 65536).
    #[arg(long, default_value_t = 64, value_name = "BYTES")]
    request_bytes: u32,
    /// Unit clock in MHz (the MergeTree unit runs at 1000).
    #[arg(long, default_value_t = 1000.0, value_name = "MHZ")]
    unit_mhz: f64,
    /// Seed of the random pattern.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print JSON (schema `arbor.sim.dram.v1`) instead of text.
    #[arg(long)]
    json: bool,
}

/// The JSON document `arbor sim dram --json` prints (`arbor.sim.dram.v1`).
#[derive(Serialize)]
pub struct DramJson {
    pub schema: &'static str,
    pub system: String,
    pub backend: String,
    pub pattern: Pattern,
    pub requests: u64,
    pub request_bytes: u32,
    pub unit_mhz: f64,
    pub unit_cycles: u64,
    pub dram_cycles: u64,
    pub sim_ns: f64,
    pub bandwidth_gb_s: f64,
    pub peak_gb_s: f64,
    pub utilization: f64,
    pub latency_ns: LatencyJson,
    pub stats: MemStats,
    pub energy_pj_per_bit: Option<f64>,
    pub wall_s: f64,
    pub unit_cycles_per_s: f64,
}

/// Request latency from acceptance to completion, in nanoseconds.
#[derive(Serialize)]
pub struct LatencyJson {
    pub min: f64,
    pub mean: f64,
    pub median: f64,
    pub max: f64,
}

/// 64-bit LCG (Knuth's MMIX constants), high bits.
fn lcg(state: &mut u64) -> u64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    *state >> 17
}

/// Checks the options of `a` (ranges and the memory system) without simulating: what a
/// sweep checks before it runs.
pub fn check_dram(a: &DramArgs) -> anyhow::Result<()> {
    check_ranges(a)?;
    sim::dram::open(&a.system, sim::clock::period_fs_from_hz(a.unit_mhz * 1e6))?;
    Ok(())
}

fn check_ranges(a: &DramArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.unit_mhz.is_finite() && a.unit_mhz >= 1.0 && a.unit_mhz <= 100_000.0,
        "--unit-mhz must be between 1 and 100000, got {}",
        a.unit_mhz
    );
    anyhow::ensure!(
        (1..=65536).contains(&a.request_bytes),
        "--request-bytes must be between 1 and 65536, got {}",
        a.request_bytes
    );
    anyhow::ensure!(
        a.bytes >= 1 && a.bytes <= 16 << 30,
        "--bytes must be between 1 and 16 GiB, got {}",
        a.bytes
    );
    Ok(())
}

pub fn run_dram(a: &DramArgs, ui: &Ui) -> anyhow::Result<()> {
    check_ranges(a)?;
    let unit_period_fs = sim::clock::period_fs_from_hz(a.unit_mhz * 1e6);
    let mut port = sim::dram::open(&a.system, unit_period_fs)?;
    let requests = a.bytes.div_ceil(a.request_bytes as u64);
    let rb = a.request_bytes as u64;
    let mut state = a.seed;
    let mut request = |i: u64| -> MemRequest {
        let (addr, kind) = match a.pattern {
            Pattern::Seq => (i * rb, AccessKind::Read),
            Pattern::Write => (i * rb, AccessKind::Write),
            Pattern::Random => ((lcg(&mut state) % (1 << 30)) / rb * rb, AccessKind::Read),
            Pattern::Copy => {
                let (kind, base) = if i.is_multiple_of(2) {
                    (AccessKind::Read, 0)
                } else {
                    (AccessKind::Write, 1 << 29)
                };
                ((i / 2) * rb + base, kind)
            }
        };
        MemRequest {
            tag: i,
            addr,
            bytes: a.request_bytes,
            kind,
        }
    };
    let bar = ui.progress(&format!("simulating {}", a.system), Unit::Items);
    let start = Instant::now();
    let mut latencies = Vec::with_capacity(requests.min(1 << 24) as usize);
    let mut pending: Option<MemRequest> = None;
    let (mut sent, mut got) = (0u64, 0u64);
    while got < requests {
        loop {
            let r = match pending.take() {
                Some(r) => r,
                None if sent < requests => {
                    sent += 1;
                    request(sent - 1)
                }
                None => break,
            };
            if let Err(back) = port.send(r) {
                pending = Some(back);
                break;
            }
        }
        port.tick();
        while let Some(r) = port.pop_response() {
            got += 1;
            latencies.push(r.completed_cycle - r.accepted_cycle);
        }
        if port.cycle().is_multiple_of(65536) {
            bar.update(got, requests);
        }
    }
    bar.finish();
    let wall_s = start.elapsed().as_secs_f64();
    let stats = port.stats();
    let unit_ns = unit_period_fs as f64 * 1e-6;
    latencies.sort_unstable();
    let to_ns = |c: u64| c as f64 * unit_ns;
    let latency_ns = LatencyJson {
        min: to_ns(latencies[0]),
        mean: latencies.iter().sum::<u64>() as f64 / latencies.len() as f64 * unit_ns,
        median: to_ns(latencies[latencies.len() / 2]),
        max: to_ns(latencies[latencies.len() - 1]),
    };
    let sim_ns = stats.unit_cycles as f64 * unit_ns;
    let moved = (stats.bytes_read + stats.bytes_written) as f64;
    let peak_gb_s = port.peak_bytes_per_unit_cycle() / unit_ns;
    let energy_pj_per_bit = stats
        .energy_pj
        .map(|e: DramEnergy| e.total_pj() / (moved * 8.0));
    let out = DramJson {
        schema: "arbor.sim.dram.v1",
        system: a.system.clone(),
        backend: port.name(),
        pattern: a.pattern,
        requests,
        request_bytes: a.request_bytes,
        unit_mhz: a.unit_mhz,
        unit_cycles: stats.unit_cycles,
        dram_cycles: stats.dram_cycles,
        sim_ns,
        bandwidth_gb_s: moved / sim_ns,
        peak_gb_s,
        utilization: stats.bus_utilization(port.peak_bytes_per_unit_cycle()),
        latency_ns,
        energy_pj_per_bit,
        wall_s,
        unit_cycles_per_s: stats.unit_cycles as f64 / wall_s.max(1e-9),
        stats,
    };
    if a.json {
        ui.emit_json(&out)?;
        return Ok(());
    }
    print_text(&out);
    Ok(())
}

fn print_text(o: &DramJson) {
    let s = &o.stats;
    let pattern = match o.pattern {
        Pattern::Seq => "sequential read",
        Pattern::Random => "random read",
        Pattern::Write => "sequential write",
        Pattern::Copy => "copy (read + write)",
    };
    println!("{} ({}), {pattern}", o.system, o.backend);
    println!(
        "  {} requests of {} B: {:.1} KB read, {:.1} KB written",
        o.requests,
        o.request_bytes,
        s.bytes_read as f64 / 1e3,
        s.bytes_written as f64 / 1e3
    );
    println!(
        "  time      {:.1} us ({} unit cycles at {} MHz, {} DRAM cycles)",
        o.sim_ns / 1e3,
        o.unit_cycles,
        o.unit_mhz,
        o.dram_cycles
    );
    println!(
        "  bandwidth {:.2} GB/s of {:.2} GB/s peak ({:.1} %)",
        o.bandwidth_gb_s,
        o.peak_gb_s,
        o.utilization * 100.0
    );
    let l = &o.latency_ns;
    println!(
        "  latency   min {:.1} / median {:.1} / mean {:.1} / max {:.1} ns",
        l.min, l.median, l.mean, l.max
    );
    if s.act_commands + s.read_commands + s.write_commands > 0 {
        println!(
            "  rows      {} hits, {} misses ({:.1} % hits)",
            s.row_hits,
            s.row_misses,
            100.0 * s.row_hits as f64 / (s.row_hits + s.row_misses).max(1) as f64
        );
        println!(
            "  commands  ACT {} RD {} WR {} REF {}",
            s.act_commands, s.read_commands, s.write_commands, s.refresh_commands
        );
    }
    if let (Some(e), Some(pj_bit)) = (s.energy_pj, o.energy_pj_per_bit) {
        println!(
            "  energy    {:.1} nJ ({:.2} pJ/bit), {:.1} nJ above idle: ACT+PRE {:.1}, RD {:.1}, WR {:.1}, REF {:.1}, background {:.1} nJ",
            e.total_pj() / 1e3,
            pj_bit,
            e.above_idle_pj() / 1e3,
            e.act_pre_pj / 1e3,
            e.read_pj / 1e3,
            e.write_pj / 1e3,
            e.refresh_pj / 1e3,
            e.background_pj / 1e3
        );
    }
    println!(
        "  simulated {:.2} M unit cycles/s ({:.2} s wall)",
        o.unit_cycles_per_s / 1e6,
        o.wall_s
    );
}
