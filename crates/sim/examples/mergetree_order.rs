//! MergeTree's build time with the scene's triangles in another order, to separate the
//! effect of the scanned meshes' triangle order (`docs/mergetree-vs-thesis.md`, "Fast
//! system: what the gap is made of").
//!
//! `cargo run --release -p sim --example mergetree_order -- SCENE DRAM ORDER`, ORDER one of
//! `file` (as stored), `shuffle` (a fixed pseudo-random permutation, seed 1) or `reverse`.
//! Simulates preset `p2` on memory system DRAM (any `dram::open` name, what-if options
//! included) and prints the build time, the final merge's cycles and mean read latency,
//! and the mean number of reads in flight during it (Little's law: reads x latency /
//! cycles). The tree is the same for every order up to the order of equal codes, so it is
//! not checked here.

use sim::mergetree::{simulate, MergeTreeConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, dram, order] = &args[..] else {
        return Err("usage: mergetree_order SCENE DRAM file|shuffle|reverse".into());
    };
    let scene = scene::open(path, &Default::default())?;
    let mesh = scene.mesh_at(0.0)?;
    let mut aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
    match order.as_str() {
        "file" => {}
        "reverse" => aabbs.reverse(),
        "shuffle" => {
            // Fisher-Yates with a 64-bit LCG (high bits), seed 1.
            let mut s = 1u64;
            for i in (1..aabbs.len()).rev() {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                aabbs.swap(i, ((s >> 33) % (i as u64 + 1)) as usize);
            }
        }
        _ => return Err(format!("unknown order '{order}'").into()),
    }
    let cfg = MergeTreeConfig::p2();
    let report = simulate(&aabbs, &cfg, sim::dram::open(dram, cfg.period_fs())?)?;
    let fm = report.phases.last().ok_or("no phases")?;
    let cycles = (fm.end_cycle - fm.start_cycle) as f64;
    println!(
        "{path} {dram} {order}: {:.3} ms, final merge {:.3} M cycles, read latency {:.0} \
         cycles, {:.2} reads in flight, queue dry {:.3} M cycles",
        report.ms,
        cycles / 1e6,
        fm.read_latency_mean_cycles,
        fm.reads as f64 * fm.read_latency_mean_cycles / cycles,
        report.stalls.merge.queue_dry_cycles as f64 / 1e6
    );
    Ok(())
}
