//! How large the toplevel builds' trees are for each cell level: the number of populated
//! cells (the toplevel build's primitives) and the toplevel tree's nodes, for the top 9,
//! 12 and 15 Morton code bits, with MergeTree's grid (preset `p2`).
//!
//! `cargo run --release -p sim --example toplevel_cells -- ../shared/scenes/bunny.ply ...`
//!
//! \[P2\] §6.1 gives the toplevel trees' size ("ca. 500–2,000 nodes in our test scenes"),
//! not the cell level; this shows which level gives that size on our scenes
//! (`docs/energy-vs-thesis.md`, `toplevel_bits`).

use sim::mergetree::{software_builder, MergeTreeConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        return Err("usage: toplevel_cells SCENE...".into());
    }
    println!("| scene | triangles | top bits | cells | toplevel tree nodes |");
    println!("|---|---:|---:|---:|---:|");
    for path in &paths {
        let scene = scene::open(path, &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let aabbs = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        let cfg = MergeTreeConfig::p2();
        for top in [9, 12, 15] {
            let mut b = software_builder(&cfg);
            b.highlevel_threshold = Some(cfg.morton_bits - top);
            let cells = b.build_highlevel(&aabbs)?.roots.len();
            let name = std::path::Path::new(path)
                .file_stem()
                .map_or(path.clone(), |s| s.to_string_lossy().into_owned());
            println!(
                "| {name} | {} | {top} | {cells} | {} |",
                aabbs.len(),
                2 * cells.max(1) - 1
            );
        }
    }
    Ok(())
}
