//! Closed-loop cross-check of Arbor's DRAM controller model against DRAMsim3 on the real
//! scenes: the MergeTree model (preset p2) on each scene and each \[P2\]/\[P3\] LPDDR3
//! system, once on `dramsim3:NAME` and once on the model (the bare `NAME`), with the cycle
//! counts, their difference, whether every memory statistic agrees, and the thread CPU
//! seconds of each run.
//!
//! `cargo run --release -p sim --example dram_crosscheck -- [SCENE_DIR] [SCENE...]`
//! (default `../shared/scenes`, the scenes bunny, crytek-sponza, conference and dragon;
//! prints a note and exits when the directory is missing). Prints a Markdown table.

use scene::LoadOptions;
use sim::mergetree::{simulate, MergeTreeConfig};

fn thread_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(f64::NAN, |ns| ns as f64 * 1e-9)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = std::path::PathBuf::from(args.first().map_or("../shared/scenes", |s| s));
    let names: Vec<String> = if args.len() > 1 {
        args[1..].to_vec()
    } else {
        ["bunny", "crytek-sponza", "conference", "dragon"]
            .map(String::from)
            .to_vec()
    };
    if !dir.is_dir() {
        println!(
            "note: scene directory {} not found; nothing to check",
            dir.display()
        );
        return Ok(());
    }
    let cfg = MergeTreeConfig::p2();
    println!("| scene | system | DRAMsim3 cycles | model cycles | difference | stats equal | DRAMsim3 cpu s | model cpu s |");
    println!("|---|---|---:|---:|---:|---|---:|---:|");
    for name in &names {
        let path = dir.join(format!("{name}.ply"));
        let scene = scene::open(path.to_str().unwrap_or_default(), &LoadOptions::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        for (system, _, _) in sim::dram::MEMORY_SYSTEMS {
            let run = |spec: &str| -> Result<_, Box<dyn std::error::Error>> {
                let port = sim::dram::open(spec, cfg.period_fs())?;
                let c0 = thread_cpu_s();
                let r = simulate(&aabbs, &cfg, port)?;
                Ok((r, thread_cpu_s() - c0))
            };
            let (a, ta) = run(&format!("dramsim3:{system}"))?;
            let (b, tb) = run(system)?;
            let diff = (b.cycles as f64 - a.cycles as f64) / a.cycles as f64 * 100.0;
            println!(
                "| {name} | {system} | {} | {} | {diff:+.3}% | {} | {ta:.2} | {tb:.2} |",
                a.cycles,
                b.cycles,
                a.memory == b.memory && a.phases == b.phases
            );
        }
    }
    Ok(())
}
