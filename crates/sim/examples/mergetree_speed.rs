//! Speed of the MergeTree model: simulated cycles per second on one core.
//!
//! `cargo run --release -p sim --example mergetree_speed -- [SCENE] [DRAM]`
//! (default: `proc:cloth?n=1000000`, about 1M triangles, on the simple model of each of the
//! three \[P2\] memory systems, `simple:lpddr3-1600-1x64` etc., so that the time is the
//! MergeTree model's own; a bare system name measures it on DRAMsim3, whose own cost is
//! far larger, see `cargo bench -p sim --bench dram`). Reports cycles per second of thread
//! CPU time (from
//! `/proc/thread-self/schedstat`, so time the thread waits for a core does not count) and
//! of wall time, the best of `REPEATS` runs each (the machine may be shared). The
//! simulation runs on the calling thread only.

use std::time::Instant;

use scene::LoadOptions;
use sim::mergetree::{simulate, MergeTreeConfig};

/// Runs per memory system; the fastest is reported.
const REPEATS: usize = 3;

/// CPU time of this thread in nanoseconds (Linux), if available.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args
        .first()
        .cloned()
        .unwrap_or_else(|| "proc:cloth?n=1000000".to_string());
    let drams: Vec<String> = match args.get(1) {
        Some(d) => vec![d.clone()],
        None => sim::thesis::P2_SYSTEMS
            .map(|s| format!("simple:{s}"))
            .to_vec(),
    };
    let scene = scene::open(&spec, &LoadOptions::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
    let cfg = MergeTreeConfig::p2();
    println!("scene {spec}: {} triangles, preset p2", aabbs.len());
    println!("dram                cycles       cpu_s   wall_s   Mcycles/cpu_s  Mcycles/wall_s");
    for d in &drams {
        let (mut best_cpu, mut best_wall, mut cycles) = (f64::MAX, f64::MAX, 0);
        for _ in 0..REPEATS {
            let port = sim::dram::open(d, cfg.period_fs())?;
            let cpu0 = thread_cpu_ns();
            let t0 = Instant::now();
            let r = simulate(&aabbs, &cfg, port)?;
            let wall = t0.elapsed().as_secs_f64();
            let cpu = match (cpu0, thread_cpu_ns()) {
                (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
                _ => wall,
            };
            best_cpu = best_cpu.min(cpu);
            best_wall = best_wall.min(wall);
            cycles = r.cycles;
        }
        println!(
            "{d:<18} {:>10} {:>9.3} {:>8.3} {:>14.1} {:>15.1}",
            cycles,
            best_cpu,
            best_wall,
            cycles as f64 / best_cpu / 1e6,
            cycles as f64 / best_wall / 1e6
        );
    }
    Ok(())
}
