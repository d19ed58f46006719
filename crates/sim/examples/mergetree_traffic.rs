//! Where MergeTree's traffic differs from \[P2\] Table VI: the traffic formula checked
//! against the simulation, and the traffic under other Morton grids and units.
//!
//! `cargo run --release -p sim --example mergetree_traffic -- ../shared/scenes`
//!
//! MergeTree's traffic with one merge pass is `32 N` (input) `+ 2 x 32 Npad` (sort runs
//! written and read back) `+ 4 N` (leaf table) `+ 64 (L - 1)` (nodes, for `L` leaves),
//! rounded to whole bursts per request. `L` is set by the Morton codes: primitives with
//! identical codes share a leaf (\[P2\] §5.4). For each scene this prints:
//! - the simulated traffic (preset `p2`, the simple memory model: traffic does not depend
//!   on the memory) and the formula with the simulation's own leaf count, which must agree;
//! - the traffic with one leaf per distinct code (no leaf-size limit) on three grids: the
//!   centroid box split into 2^10 cells per axis (Arbor's codes), a cube over the same box
//!   (cells of equal size on every axis, the size of the longest axis / 2^10), and the box
//!   with 2^9 cells per axis;
//! - each in 10^6 bytes and in 2^20 bytes, against Table VI (`sim::thesis`).
//!
//! Nothing here changes the model: it shows which unstated choices reproduce the printed
//! figures (`docs/mergetree-vs-thesis.md`).

use geom::{morton30, Aabb, MortonQuantizer, Vec3};
use sim::mergetree::{centroid_bounds, simulate, MergeTreeConfig};

/// One leaf per distinct cell of `bits` bits per axis over `bounds`: the number of leaves.
fn distinct_cells(aabbs: &[Aabb], bounds: &Aabb, bits: u32) -> u64 {
    let q = MortonQuantizer::new(bounds);
    let mut codes: Vec<u32> = aabbs
        .iter()
        .map(|a| morton30(q.cell(a.min * 0.5 + a.max * 0.5, bits)))
        .collect();
    codes.sort_unstable();
    codes.dedup();
    codes.len() as u64
}

/// The cube with the corner of `b` and the side of its longest axis.
fn cube(b: &Aabb) -> Aabb {
    let e = b.max - b.min;
    let side = e.x.max(e.y).max(e.z);
    Aabb::new(b.min, b.min + Vec3::splat(side))
}

/// Traffic in bytes of a one-pass build of `n` primitives with `leaves` leaves.
fn formula(n: u64, leaves: u64, b: u64) -> u64 {
    let npad = n.div_ceil(b) * b;
    32 * n + 2 * 32 * npad + 4 * n + 64 * leaves.saturating_sub(1)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args()
        .nth(1)
        .ok_or("usage: mergetree_traffic SCENES_DIR (e.g. ../shared/scenes)")?;
    let cfg = MergeTreeConfig::p2();
    println!(
        "| scene | triangles | simulated MB (leaves) | formula MB | box 10 bits | cube 10 bits | box 9 bits | [P2] Table VI |"
    );
    println!("|---|---:|---|---:|---|---|---|---:|");
    for s in sim::thesis::P2_SCENES {
        let path = std::path::Path::new(&dir).join(format!("{}.ply", s.name));
        if !path.is_file() {
            eprintln!("skipping {}: not found", path.display());
            continue;
        }
        let scene = scene::open(&path.to_string_lossy(), &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        let n = aabbs.len() as u64;
        let port = sim::dram::open("simple:lpddr3-1600-1x64", cfg.period_fs())?;
        let r = simulate(&aabbs, &cfg, port)?;
        assert_eq!(r.merge_passes, 1, "the formula is for one merge pass");
        let sim_bytes = r.bytes_read + r.bytes_written;
        let leaves = r.nodes + 1;
        let f = formula(n, leaves, cfg.b as u64);
        // The formula counts bytes; the port counts whole bursts of partly filled requests.
        let rel = (sim_bytes as f64 / f as f64 - 1.0).abs();
        assert!(
            rel < 0.002,
            "{}: formula {f} vs simulated {sim_bytes}",
            s.name
        );
        let cb = centroid_bounds(&aabbs);
        let variants = [
            distinct_cells(&aabbs, &cb, 10),
            distinct_cells(&aabbs, &cube(&cb), 10),
            distinct_cells(&aabbs, &cb, 9),
        ];
        let cell = |l: u64| {
            let bytes = formula(n, l, cfg.b as u64) as f64;
            format!(
                "{:.1} MB = {:.1} MiB ({:.2} per leaf)",
                bytes / 1e6,
                bytes / (1u64 << 20) as f64,
                n as f64 / l as f64
            )
        };
        println!(
            "| {} | {n} | {:.1} ({:.2} per leaf) | {:.1} | {} | {} | {} | {} |",
            s.name,
            sim_bytes as f64 / 1e6,
            n as f64 / leaves as f64,
            f as f64 / 1e6,
            cell(variants[0]),
            cell(variants[1]),
            cell(variants[2]),
            s.traffic_mb[0]
        );
    }
    Ok(())
}
