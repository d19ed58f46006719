//! SAH quality of Arbor's HLBVH-family and binned SAH builders on the real scenes, next to
//! the values [P2] Table III reports for the scenes we share (for docs/sah-vs-thesis.md).
//!
//! `cargo run --release -p bvh --example sah_table -- ../shared/scenes`
//!
//! After the table, one line per scene gives the number of highlevel cells (toplevel
//! primitives) at Arbor's default threshold, to compare with the "ca. 500–2,000 nodes" of
//! the thesis's toplevel trees ([P2] §6.1).
//!
//! Every tree is checked with `bvh::validate`; SAH % is relative to Arbor's own full sweep
//! SAH build of the same primitives, as the thesis normalizes to a full SAH sweep. Nothing
//! here is tuned to the thesis: every builder runs with its default configuration.

use bvh::{
    validate, BinnedSahBuilder, BuildError, Bvh2, HlbvhAtrbvhBuilder, HlbvhBuilder,
    HlbvhSahBuilder, SweepSahBuilder,
};
use geom::Aabb;
use std::path::Path;

/// One thesis value: SAH % relative to a full sweep, and the line of the seed text
/// (`/work/shared/seed/000_9bafb19bf5347228.txt`) it was read from.
type ThesisValue = Option<(u32, u32)>;

/// A scene file and its [P2] Table III values for hlbvh, hlbvh+sah, hlbvh+atrbvh and binned
/// SAH (the hardware builder of Doyle et al. [13]).
struct SceneRow {
    file: &'static str,
    thesis: [ThesisValue; 4],
}

/// The scenes we share with [P2] Table III. Row labels in the seed text: "HW HLBVH
/// (proposed)" at 12.8 GB/s (SAH does not depend on bandwidth), "HW Binned SAH topl.",
/// "TK1 ATRBVH topl." and "HW binned SAH [13]". Sibenik appears in [P1] Table 3 without
/// SAH values, so it has no thesis column.
const SCENES: [SceneRow; 5] = [
    SceneRow {
        file: "bunny.ply",
        thesis: [
            Some((122, 1653)),
            Some((113, 1656)),
            Some((116, 1657)),
            Some((104, 1650)),
        ],
    },
    SceneRow {
        file: "sibenik.ply",
        thesis: [None, None, None, None],
    },
    SceneRow {
        file: "crytek-sponza.ply",
        thesis: [
            Some((142, 1664)),
            Some((109, 1667)),
            Some((99, 1668)),
            Some((107, 1662)),
        ],
    },
    SceneRow {
        file: "conference.ply",
        thesis: [
            Some((154, 1664)),
            Some((106, 1667)),
            Some((89, 1668)),
            Some((103, 1662)),
        ],
    },
    SceneRow {
        file: "dragon.ply",
        thesis: [
            Some((135, 1675)),
            Some((120, 1678)),
            Some((123, 1679)),
            Some((102, 1673)),
        ],
    },
];

/// A named builder with the thesis column it is compared with (index into `thesis`).
type Build = Box<dyn Fn(&[Aabb]) -> Result<Bvh2, BuildError>>;

fn builders() -> Vec<(&'static str, Option<usize>, u32, Build)> {
    let hl_leaf = HlbvhBuilder::default().max_leaf_size;
    let binned = |bins: usize| -> Build {
        Box::new(move |p| {
            BinnedSahBuilder {
                bins,
                ..Default::default()
            }
            .build(p)
        })
    };
    vec![
        (
            "hlbvh",
            Some(0),
            hl_leaf,
            Box::new(|p| HlbvhBuilder::default().build(p)),
        ),
        (
            "hlbvh-large",
            None,
            hl_leaf,
            Box::new(|p| {
                HlbvhBuilder {
                    large_prims: Some(bvh::LARGE_PRIMS_FRACTION),
                    ..Default::default()
                }
                .build(p)
            }),
        ),
        (
            "hlbvh+sah",
            Some(1),
            hl_leaf,
            Box::new(|p| HlbvhSahBuilder::default().build(p)),
        ),
        (
            "hlbvh+atrbvh",
            Some(2),
            hl_leaf,
            Box::new(|p| HlbvhAtrbvhBuilder::default().build(p)),
        ),
        ("binned-sah/8", None, 8, binned(8)),
        ("binned-sah/16", Some(3), 8, binned(16)),
        ("binned-sah/32", None, 8, binned(32)),
    ]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args()
        .nth(1)
        .ok_or("usage: sah_table SCENES_DIR (e.g. ../shared/scenes)")?;
    let mut cells = Vec::new();
    println!("| scene | triangles | builder | SAH | SAH % of sweep (Arbor) | % of sweep, 1-prim leaves (diagnostic) | thesis SAH % ([P2] Table III, line) |");
    println!("|---|---:|---|---:|---:|---:|---|");
    for row in &SCENES {
        let path = Path::new(&dir).join(row.file);
        if !path.exists() {
            eprintln!("skipping {}: not found", path.display());
            continue;
        }
        let spec = path.to_string_lossy().into_owned();
        let scene = scene::open(&spec, &Default::default())?;
        let mesh = scene.mesh_at(0.0)?;
        let prims = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles)?;
        let sweep_cfg = SweepSahBuilder::default();
        let sweep = sweep_cfg.build(&prims)?;
        validate(&sweep, &prims, sweep_cfg.max_leaf_size)?;
        let reference = sweep.sah();
        // Diagnostic only: a sweep reference with one primitive per leaf, in case the
        // thesis's reference used that policy (its leaf policy is not stated).
        let sweep1_cfg = SweepSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        };
        let sweep1 = sweep1_cfg.build(&prims)?;
        validate(&sweep1, &prims, 1)?;
        let reference1 = sweep1.sah();
        println!(
            "| {} | {} | sweep-sah (reference) | {:.2} | 100.0% | {:.1}% | 100% |",
            row.file,
            prims.len(),
            reference,
            100.0 * reference / reference1
        );
        let hl = HlbvhSahBuilder::default().highlevel(&prims)?;
        cells.push((row.file, hl.roots.len()));
        for (name, column, max_leaf, build) in builders() {
            let tree = build(&prims)?;
            validate(&tree, &prims, max_leaf)
                .map_err(|e| format!("{name} on {}: invalid tree: {e}", row.file))?;
            let sah = tree.sah();
            let thesis = match column.and_then(|c| row.thesis[c]) {
                Some((pct, line)) => format!("{pct}% (line {line})"),
                None => "—".to_string(),
            };
            println!(
                "| {} | {} | {} | {:.2} | {:.1}% | {:.1}% | {} |",
                row.file,
                prims.len(),
                name,
                sah,
                100.0 * sah / reference,
                100.0 * sah / reference1,
                thesis
            );
        }
    }
    println!();
    for (file, n) in cells {
        println!(
            "{file}: {n} highlevel cells at threshold {} (top 12 of 30 code bits): a top tree of {} inner nodes",
            bvh::toplevel::default_threshold(bvh::MortonBits::Bits30),
            n.saturating_sub(1)
        );
    }
    Ok(())
}
