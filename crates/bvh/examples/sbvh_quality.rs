//! Spatial splits (`bvh::SbvhBuilder`) against the binned SAH builder on real scenes: SAH
//! (relative to Arbor's full sweep SAH build, as docs/sah-vs-thesis.md normalizes), build
//! time and the references per triangle the spatial splits add.
//!
//! `cargo run --release -p bvh@0.1.0 --example sbvh_quality -- ../shared/scenes/crytek-sponza.ply ...`
//!
//! Times are one build each on whatever the machine is doing: indicative, not a
//! benchmark record (`arbor bench build` is that).

use bvh::{validate, validate_spatial, BinnedSahBuilder, SbvhBuilder, SweepSahBuilder};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files: Vec<String> = std::env::args().skip(1).collect();
    if files.is_empty() {
        return Err("usage: sbvh_quality SCENE.ply [SCENE.ply ...]".into());
    }
    println!(
        "| scene | triangles | builder | SAH % of sweep | references per triangle | build ms |"
    );
    println!("|---|---:|---|---:|---:|---:|");
    for file in files {
        let scene = scene::open(&file, &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let tris: Vec<geom::Triangle> = mesh.triangles_iter().collect();
        let prims = bvh::triangle_aabbs(&tris);
        let sweep = bvh::sah_cost(&SweepSahBuilder::default().build(&prims)?);
        let name = std::path::Path::new(&file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or(file.clone());
        let row = |builder: &str, t: &bvh::Bvh2, ms: f64| {
            println!(
                "| {name} | {} | {builder} | {:.1} | {:.3} | {ms:.0} |",
                tris.len(),
                100.0 * bvh::sah_cost(t) / sweep,
                t.prim_indices.len() as f64 / tris.len() as f64
            )
        };
        let s = Instant::now();
        let binned = BinnedSahBuilder::default().build(&prims)?;
        let ms = s.elapsed().as_secs_f64() * 1e3;
        validate(&binned, &prims, 8)?;
        row("binned-sah", &binned, ms);
        // alpha >= 1: no spatial split, so the object splits alone (as a check).
        for (label, growth, alpha) in [
            ("sbvh", 1.0f32, 1e-5f32),
            ("sbvh growth 0.25", 0.25, 1e-5),
            ("sbvh object splits only", 0.0, 1.0),
        ] {
            let s = Instant::now();
            let t = SbvhBuilder {
                max_growth: growth,
                alpha,
                ..Default::default()
            }
            .build(&tris)?;
            let ms = s.elapsed().as_secs_f64() * 1e3;
            validate_spatial(&t, &prims, 8)?;
            row(label, &t, ms);
        }
    }
    Ok(())
}
