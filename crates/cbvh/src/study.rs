//! The measurements of \[P3\] §5 on one scene: every encoder variant of Table 1 over the
//! LBVH the paper assumes, and over a refit of it, with backtracking counts, depth
//! histograms (Fig. 7), traffic (§5.2) and the decoded tree's SAH against the uncompressed
//! tree (§5.4); and the minimum-scale sweep of Fig. 10. The CLI's `arbor cbvh` and
//! `arbor report cbvh` print what this computes.

use crate::bottomup::{compress_hlbvh, StreamConfig};
use crate::error::CbvhError;
use crate::grid::{Coords, Params};
use crate::refit::refit_streaming;
use crate::topdown::compress_topdown;
use crate::traffic::{self, Counts};
use crate::tree::{boxes_not_enclosing, enclosure_violations, Cbvh};
use crate::EncodeStats;
use bvh::{Bvh2, Highlevel, HlbvhBuilder};
use geom::Aabb;
use serde::Serialize;

/// The LBVH of \[P3\] §5.2: the streaming MergeTree emitter (30-bit Morton codes) with
/// "large leafs when multiple primitives share the same Morton code" (no size limit), with
/// codes on a cube grid as in the MergeTree presets (the grid that gives \[P3\] Table 2's
/// leaf sizes, `docs/mergetree-vs-thesis.md`).
pub fn paper_lbvh() -> HlbvhBuilder {
    HlbvhBuilder {
        combine_identical: true,
        max_leaf_size: u32::MAX,
        grid: geom::MortonGrid::Cube,
        ..HlbvhBuilder::default()
    }
}

/// Which encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoder {
    /// Postprocessing top-down compression (\[P3\] Fig. 2a).
    Topdown,
    /// Streaming bottom-up compression (Algorithm 1, optionally with treelets).
    Bottomup,
}

/// One encoder configuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Variant {
    /// Encoder.
    pub encoder: Encoder,
    /// Coordinates.
    pub coords: Coords,
    /// Treelet depth (1 = none; always 1 for top-down).
    pub treelet_depth: u32,
}

impl Variant {
    /// A short label: `TD`, `R`, `R2`.., `M`, `M2`...
    pub fn label(&self) -> String {
        match self.encoder {
            Encoder::Topdown => "TD".into(),
            Encoder::Bottomup => {
                let c = if self.coords == Coords::Relative {
                    "R"
                } else {
                    "M"
                };
                if self.treelet_depth <= 1 {
                    c.into()
                } else {
                    format!("{c}{}", self.treelet_depth)
                }
            }
        }
    }

    /// The nine columns of \[P3\] Table 1: top-down, then relative and modulo bottom-up
    /// without treelets and with treelet depths 2, 3, 4.
    pub fn table1() -> Vec<Variant> {
        let mut v = vec![Variant {
            encoder: Encoder::Topdown,
            coords: Coords::Relative,
            treelet_depth: 1,
        }];
        for coords in [Coords::Relative, Coords::Modulo] {
            for m in 1..=4 {
                v.push(Variant {
                    encoder: Encoder::Bottomup,
                    coords,
                    treelet_depth: m,
                });
            }
        }
        v
    }
}

/// Results of one variant on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct VariantResult {
    /// The variant.
    pub variant: Variant,
    /// Its label.
    pub label: String,
    /// Construction (LBVH) encoder counts.
    pub build: EncodeStats,
    /// Construction traffic (\[P3\] §5.2).
    pub build_traffic: traffic::Traffic,
    /// Refit (to the same geometry, \[P3\] §5.2) encoder counts.
    pub refit: EncodeStats,
    /// Refit traffic.
    pub refit_traffic: traffic::Traffic,
    /// SAH of the decoded tree over SAH of the uncompressed tree.
    pub sah_vs_uncompressed: f64,
    /// SAH of the decoded tree over SAH of the decoded top-down tree.
    pub sah_vs_topdown: f64,
    /// Decoded child boxes that do not enclose their primitives (must be 0).
    pub enclosure_violations: u64,
    /// Decoded child boxes that do not enclose top-down's (must be 0).
    pub not_enclosing_topdown: u64,
}

/// All variants on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneStudy {
    /// Primitives.
    pub prims: u64,
    /// Node pairs of the LBVH.
    pub node_pairs: u64,
    /// Leaves of the LBVH.
    pub leaves: u64,
    /// Average primitives per leaf (\[P3\] Table 2's "leaf size").
    pub avg_leaf_size: f64,
    /// SAH of the uncompressed LBVH.
    pub sah_uncompressed: f64,
    /// One entry per variant.
    pub variants: Vec<VariantResult>,
}

/// The LBVH emission of \[P3\] §5.2 over `prims` (stream and full-precision tree).
pub fn build_lbvh(prims: &[Aabb]) -> Result<(Highlevel, Bvh2), CbvhError> {
    let hl = paper_lbvh()
        .build_highlevel(prims)
        .map_err(|e| CbvhError::InvalidParams(format!("LBVH build failed: {e}")))?;
    let bvh = hl.to_bvh2();
    Ok((hl, bvh))
}

/// Runs one variant: construction over the emitter stream (or top-down over the built
/// tree), and refit of the top-down tree to `refit_prims` (the same geometry in \[P3\]).
pub fn run_variant(
    hl: &Highlevel,
    bvh: &Bvh2,
    refit_prims: &[Aabb],
    v: &Variant,
    params: &Params,
) -> Result<(Cbvh, EncodeStats, EncodeStats), CbvhError> {
    let params = Params {
        coords: v.coords,
        ..*params
    };
    let cfg = StreamConfig {
        params,
        treelet_depth: v.treelet_depth,
        ..StreamConfig::default()
    };
    let (built, bst) = match v.encoder {
        Encoder::Topdown => compress_topdown(bvh, &params)?,
        Encoder::Bottomup => compress_hlbvh(hl, &cfg)?,
    };
    let rst = match v.encoder {
        Encoder::Topdown => EncodeStats {
            nodes_written: built.pairs.len() as u64,
            ..EncodeStats::default()
        },
        Encoder::Bottomup => {
            let (td, _) = compress_topdown(bvh, &params)?;
            refit_streaming(&td, refit_prims, &cfg)?.1
        }
    };
    Ok((built, bst, rst))
}

/// Runs every variant of `variants` on `prims`, calling `progress` after each.
pub fn study_scene(
    prims: &[Aabb],
    params: &Params,
    variants: &[Variant],
    mut progress: impl FnMut(&str),
) -> Result<SceneStudy, CbvhError> {
    let (hl, bvh) = build_lbvh(prims)?;
    let st = bvh.stats();
    let sah_unc = bvh::sah_cost(&bvh);
    let counts = |steps: u64| Counts {
        prims: prims.len() as u64,
        node_pairs: bvh.nodes.len() as u64,
        backtrack_steps: steps,
    };
    let (td, _) = compress_topdown(&bvh, params)?;
    let td_dec = td.decode_to_bvh2()?;
    let sah_td = bvh::sah_cost(&td_dec);
    let mut out = Vec::new();
    for v in variants {
        let (built, bst, rst) = run_variant(&hl, &bvh, prims, v, params)?;
        let dec = built.decode_to_bvh2()?;
        let sah = bvh::sah_cost(&dec);
        let (build_traffic, refit_traffic) = match v.encoder {
            Encoder::Topdown => (
                traffic::lbvh_topdown(&counts(0)),
                traffic::refit_topdown(&counts(0)),
            ),
            Encoder::Bottomup => (
                traffic::lbvh_bottomup(&counts(bst.backtrack_steps)),
                traffic::refit_bottomup(&counts(rst.backtrack_steps)),
            ),
        };
        let topdown_dec = if v.coords == td.params.coords {
            td_dec.clone()
        } else {
            compress_topdown(
                &bvh,
                &Params {
                    coords: v.coords,
                    ..*params
                },
            )?
            .0
            .decode_to_bvh2()?
        };
        out.push(VariantResult {
            variant: *v,
            label: v.label(),
            build: bst,
            build_traffic,
            refit: rst,
            refit_traffic,
            sah_vs_uncompressed: ratio(sah, sah_unc),
            sah_vs_topdown: ratio(sah, sah_td),
            enclosure_violations: enclosure_violations(&dec, prims)?,
            not_enclosing_topdown: boxes_not_enclosing(&dec, &topdown_dec)?,
        });
        progress(&v.label());
    }
    Ok(SceneStudy {
        prims: prims.len() as u64,
        node_pairs: bvh.nodes.len() as u64,
        leaves: st.leaves as u64,
        avg_leaf_size: if st.leaves > 0 {
            prims.len() as f64 / st.leaves as f64
        } else {
            0.0
        },
        sah_uncompressed: sah_unc,
        variants: out,
    })
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        1.0
    }
}

/// One point of the minimum-scale sweep (\[P3\] Fig. 10).
#[derive(Clone, Debug, Serialize)]
pub struct MinScalePoint {
    /// Minimum scale exponent.
    pub min_scale_exp: i32,
    /// Backtracking steps of plain bottom-up (relative, no treelets) per primitive.
    pub backtrack_per_prim: f64,
    /// Backtracking steps of modulo bottom-up with treelet depth 4, per primitive.
    pub backtrack_per_prim_m4: f64,
    /// SAH of the decoded (top-down) tree.
    pub sah: f64,
}

/// \[P3\] Fig. 10: backtracking and tree quality against the minimum scale.
pub fn min_scale_sweep(
    prims: &[Aabb],
    base: &Params,
    exps: &[i32],
) -> Result<Vec<MinScalePoint>, CbvhError> {
    let (hl, bvh) = build_lbvh(prims)?;
    let n = prims.len().max(1) as f64;
    let mut out = Vec::new();
    for &e in exps {
        let p = Params {
            min_scale_exp: e,
            ..*base
        };
        let run = |coords, m| -> Result<u64, CbvhError> {
            let cfg = StreamConfig {
                params: Params { coords, ..p },
                treelet_depth: m,
                ..StreamConfig::default()
            };
            Ok(compress_hlbvh(&hl, &cfg)?.1.backtrack_steps)
        };
        let (td, _) = compress_topdown(&bvh, &p)?;
        out.push(MinScalePoint {
            min_scale_exp: e,
            backtrack_per_prim: run(Coords::Relative, 1)? as f64 / n,
            backtrack_per_prim_m4: run(Coords::Modulo, 4)? as f64 / n,
            sah: bvh::sah_cost(&td.decode_to_bvh2()?),
        });
    }
    Ok(out)
}

/// One point of the coordinate-bits study.
#[derive(Clone, Debug, Serialize)]
pub struct BitsPoint {
    /// Bits per coordinate `N`.
    pub bits: u32,
    /// Bytes of a packed node pair.
    pub pair_bytes: usize,
    /// SAH of the decoded (top-down) tree over the uncompressed tree.
    pub sah_vs_uncompressed: f64,
    /// Backtracking steps of plain bottom-up (relative, no treelets) per primitive.
    pub backtrack_per_prim: f64,
    /// Backtracking steps of modulo bottom-up with treelet depth 4, per primitive.
    pub backtrack_per_prim_m4: f64,
}

/// Tree quality and backtracking against the number of coordinate bits.
pub fn bits_sweep(
    prims: &[Aabb],
    base: &Params,
    bits: &[u32],
) -> Result<Vec<BitsPoint>, CbvhError> {
    let (hl, bvh) = build_lbvh(prims)?;
    let sah_unc = bvh::sah_cost(&bvh);
    let n = prims.len().max(1) as f64;
    let mut out = Vec::new();
    for &b in bits {
        let p = Params { bits: b, ..*base };
        let run = |coords, m| -> Result<u64, CbvhError> {
            let cfg = StreamConfig {
                params: Params { coords, ..p },
                treelet_depth: m,
                ..StreamConfig::default()
            };
            Ok(compress_hlbvh(&hl, &cfg)?.1.backtrack_steps)
        };
        let (td, _) = compress_topdown(&bvh, &p)?;
        out.push(BitsPoint {
            bits: b,
            pair_bytes: crate::format::pair_bytes(b),
            sah_vs_uncompressed: ratio(bvh::sah_cost(&td.decode_to_bvh2()?), sah_unc),
            backtrack_per_prim: run(Coords::Relative, 1)? as f64 / n,
            backtrack_per_prim_m4: run(Coords::Modulo, 4)? as f64 / n,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every variant on every real scene (when `/work/shared/scenes` or `ARBOR_SCENES`
    /// exists): no enclosure violation, bottom-up encloses top-down, SAH within 1%.
    /// Run by hand (minutes): `cargo test --release -p cbvh -- --ignored real_scenes`.
    #[test]
    #[ignore]
    fn real_scenes_every_variant() {
        let dir = std::env::var("ARBOR_SCENES").unwrap_or_else(|_| "/work/shared/scenes".into());
        for name in [
            "bunny.ply",
            "conference.ply",
            "crytek-sponza.ply",
            "dragon.ply",
            "sibenik.ply",
        ] {
            let path = format!("{dir}/{name}");
            let Ok(s) = scene::open(&path, &Default::default()) else {
                continue;
            };
            let mesh = s.mesh_at(0.0).unwrap();
            let prims = bvh::indexed_triangle_aabbs(&mesh.positions, &mesh.triangles).unwrap();
            let st = study_scene(&prims, &Params::default(), &Variant::table1(), |_| {}).unwrap();
            for v in &st.variants {
                println!(
                    "{name} {} steps {} refit {} sah {:.5} td {:.5}",
                    v.label,
                    v.build.backtrack_steps,
                    v.refit.backtrack_steps,
                    v.sah_vs_uncompressed,
                    v.sah_vs_topdown
                );
                assert_eq!(v.enclosure_violations, 0);
                assert_eq!(v.not_enclosing_topdown, 0);
                assert!(v.sah_vs_topdown < 1.01);
            }
        }
    }

    #[test]
    fn small_study_is_consistent() {
        let prims = crate::bottomup::tests::soup(4000, 21, false);
        let st = study_scene(&prims, &Params::default(), &Variant::table1(), |_| {}).unwrap();
        assert_eq!(st.variants.len(), 9);
        let td = &st.variants[0];
        assert_eq!(td.label, "TD");
        assert_eq!(td.build.backtrack_steps, 0);
        for v in &st.variants {
            assert_eq!(v.enclosure_violations, 0, "{}", v.label);
            assert_eq!(v.not_enclosing_topdown, 0, "{}", v.label);
            assert!(
                v.sah_vs_topdown >= 1.0 - 1e-9 && v.sah_vs_topdown < 1.02,
                "{} {}",
                v.label,
                v.sah_vs_topdown
            );
            assert!(v.sah_vs_uncompressed >= 1.0);
            assert_eq!(v.build.nodes_written, st.node_pairs);
            if v.variant.encoder == Encoder::Bottomup {
                assert!(v.build_traffic.total_bytes() < td.build_traffic.total_bytes());
                assert!(v.refit_traffic.total_bytes() < td.refit_traffic.total_bytes());
            }
        }
        let bits = bits_sweep(&prims, &Params::default(), &[3, 6, 8]).unwrap();
        // More bits, tighter boxes.
        assert!(bits[0].sah_vs_uncompressed > bits[1].sah_vs_uncompressed);
        assert!(bits[1].sah_vs_uncompressed >= bits[2].sah_vs_uncompressed);
        assert_eq!(bits[1].pair_bytes, 16);
        let sweep = min_scale_sweep(&prims, &Params::default(), &[-60, -30, -10]).unwrap();
        assert_eq!(sweep.len(), 3);
        // A coarser minimum scale never makes the tree tighter.
        assert!(sweep[2].sah >= sweep[0].sah - 1e-9);
    }
}

#[cfg(test)]
mod min_scale_tests {
    use super::*;
    use crate::bottomup::tests::soup;

    /// \[P3\] §4.4: large subtrees with a degenerate axis, joined with geometry that is not
    /// flat, backtrack down towards the minimum scale; a coarser minimum scale cuts that.
    #[test]
    fn flat_geometry_backtracks_down_to_the_minimum_scale() {
        // A sheet exactly at z = 0 (where f32 spacing does not limit the scale, \[P3\]
        // §4.4) with some non-flat geometry around it.
        let mut prims: Vec<Aabb> = soup(6000, 3, true)
            .into_iter()
            .map(|b| {
                Aabb::new(
                    b.min * geom::Vec3::new(1.0, 1.0, 0.0),
                    b.max * geom::Vec3::new(1.0, 1.0, 0.0),
                )
            })
            .collect();
        prims.extend(soup(300, 4, false));
        let pts = min_scale_sweep(&prims, &Params::default(), &[-126, -30, -10]).unwrap();
        assert!(
            pts[0].backtrack_per_prim > 1.5 * pts[1].backtrack_per_prim
                && pts[0].backtrack_per_prim_m4 > 4.0 * pts[1].backtrack_per_prim_m4,
            "{pts:?}"
        );
        assert!(
            pts[1].backtrack_per_prim >= pts[2].backtrack_per_prim,
            "{pts:?}"
        );
    }
}
