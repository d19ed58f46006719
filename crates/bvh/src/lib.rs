//! Arbor's BVH core: the binary tree format of \[P2\] §4.1, its validator and SAH cost, and
//! the builders that the thesis compares (full sweep SAH, binned SAH, LBVH).
//!
//! Every builder is a small config struct with one `build(&[Aabb]) -> Result<Bvh2, _>`
//! entry point (`Mbvh4` for the 4-wide builders; [`Tree`] holds either kind). Builders take primitive AABBs, so any primitive type works (\[P2\] §4.1);
//! [`triangle_aabbs`] and [`indexed_triangle_aabbs`] make them from triangles. All builders
//! are deterministic: the same input gives the same tree for any thread count.
//!
//! Shared engines (crate-private): `split` evaluates the SAH boundaries of every top-down
//! builder's split search and holds the SIMD primitive reference, `bins` the binning of the
//! binned and 4-wide builders, and `layout` the depth-first preorder writer that the tree
//! writers share: `preorder` where subtree sizes are unknown (build fragments, HLBVH top
//! trees, optimizer write-outs, wide and streaming collapses), `preorder_sized`, parallel,
//! where they are known (PLOC's clustered tree, the ATRBVH working tree).

#![warn(missing_docs)]

mod atrbvh;
mod binned_sah;
mod bins;
mod bvh2;
mod collapse;
mod collapse_sah;
mod error;
#[cfg(test)]
mod fingerprints;
mod frag;
mod hlbvh;
pub mod io;
mod layout;
mod lbvh;
mod mbvh4;
mod mbvh4_topdown;
mod morton_sort;
mod node;
mod octree;
mod plane_kd;
mod ploc;
mod point_stream;
mod points;
mod refit;
mod reinsert;
mod sah;
mod sbvh;
mod split;
mod stream_collapse;
mod sweep_sah;
#[cfg(test)]
mod testutil;
pub mod toplevel;
mod tree;
mod validate;

pub use atrbvh::{optimize, AtrbvhBuilder, AtrbvhConfig, AtrbvhWork, MAX_TREELET_SIZE, MIN_GAIN};
#[doc(hidden)]
pub use binned_sah::SortedSplitBench;
pub use binned_sah::{BinnedSahBuilder, MAX_BINS};
pub use bvh2::{Bvh2, TreeStats};
pub use collapse::{collapse, Collapse, CollapseError, WideBvh, WideNode};
pub use collapse_sah::{
    collapse_optimal, collapse_sah_optimal, collapse_wide_blocks, collapse_wide_optimal,
    CollapseGoal,
};
pub use error::{BuildError, MAX_PRIMITIVES};
pub use geom::MortonGrid;
pub use hlbvh::{
    EmitRef, EmittedNode, Emitter, Highlevel, HighlevelRoot, HlbvhArena, HlbvhBuilder, Prim, Step,
    LARGE_PRIMS_FRACTION,
};
pub use lbvh::{LbvhBuilder, MortonBits};
pub use mbvh4::{mbvh4_sah_cost_with, validate_mbvh4, Mbvh4, Mbvh4Stats, Node4, MBVH_WIDTH};
pub use mbvh4_topdown::Mbvh4TopDownBuilder;
pub use node::{ChildRef, Node, EMPTY_INDEX};
pub use octree::{OctNode, Octree, OctreeStats, OctreeStream, OCTREE_MAX_DEPTH};
pub use plane_kd::{PlaneKdTree, PlaneNode, MAX_PLANE_LEAF, PLANE_NODE_BYTES};
pub use ploc::{PlocBuilder, MAX_PLOC_RADIUS};
pub use point_stream::{Joined, PointRef, PointStream, PointStreamStats, WrittenNode};
pub use points::{knn_brute, PointError, PointNode, PointTree, QueryStats, NO_AXIS};
pub use refit::{refit_bvh2, refit_mbvh4, RefitError, RefitFrame, RefitTracker};
pub use reinsert::{reinsert, ReinsertConfig, ReinsertWork};
pub use sah::{sah_cost, sah_cost_with, sah_ratio, SahParams};
pub use sbvh::SbvhBuilder;
pub use stream_collapse::{
    stream_collapse, stream_collapse_with, StreamCollapse, COLLAPSE_SLOT_BYTES, TREELET_NODE_BYTES,
};
pub use sweep_sah::SweepSahBuilder;
pub use toplevel::{HlbvhAtrbvhBuilder, HlbvhSahBuilder};
pub use tree::{Tree, TreeKind};
pub use validate::{validate, validate_spatial, validate_wide, ValidationError};

use geom::{Aabb, Triangle, Vec3};

/// Subtrees with fewer primitives than this are built on the current thread: below it the
/// cost of a `rayon::join` and of a separate fragment outweighs the parallelism.
pub(crate) const PARALLEL_MIN_PRIMS: usize = 4096;

/// Recursion depth after which the SAH builders stop using the SAH and split at the object
/// median, which halves the primitive count per level. SAH splits can peel one primitive
/// off per level on adversarial inputs (exponentially spaced, or coincident primitives),
/// which would make the depth, and the build's recursion, linear in the input size.
pub(crate) const MAX_SAH_DEPTH: u32 = 96;

/// Makes `v` hold `n` elements that the caller overwrites, without a pass over the memory:
/// a buffer with room keeps its old contents (only a growth past its length is filled),
/// one without is replaced by calloc'd zero pages, which the writer touches first. The
/// builders that reuse their buffers from one build to the next size them with this, so a
/// reused buffer is neither zero-filled nor faulted in again.
pub(crate) fn size_for_overwrite<T: bytemuck::Zeroable + Clone>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        // Free the old buffer first: both are never held at once.
        *v = Vec::new();
        *v = bytemuck::zeroed_vec(n);
    } else {
        v.truncate(n);
        v.resize(n, T::zeroed());
    }
}

/// The bounding box of every triangle.
pub fn triangle_aabbs(triangles: &[Triangle]) -> Vec<Aabb> {
    triangles.iter().map(Triangle::aabb).collect()
}

/// The bounding box of every indexed triangle (e.g. `scene::Mesh::{positions, triangles}`).
pub fn indexed_triangle_aabbs(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
) -> Result<Vec<Aabb>, BuildError> {
    triangles
        .iter()
        .enumerate()
        .map(|(t, idx)| {
            let mut b = Aabb::EMPTY;
            for &v in idx {
                let p = positions
                    .get(v as usize)
                    .ok_or(BuildError::VertexOutOfRange {
                        triangle: t,
                        vertex: v,
                        vertices: positions.len(),
                    })?;
                b = b.grow(*p);
            }
            Ok(b)
        })
        .collect()
}

/// Centroid of a box, computed without overflowing for huge finite coordinates.
#[inline]
pub(crate) fn centroid(b: &Aabb) -> Vec3 {
    b.min * 0.5 + b.max * 0.5
}

/// Bit 30 of an f32, the top bit of its exponent (see [`index_lane`]).
const LANE_TAG: u32 = 1 << 30;

/// The value a primitive index takes in the spare `w` lane of a SIMD box (the binned SAH
/// and top-down MBVH4 builders' primitive references), read back by [`lane_index`].
///
/// That lane goes through the same SIMD arithmetic as x, y and z (box extents, area
/// products, centroids), so its float value matters: the raw index bits are a subnormal
/// for every index below 2^23, and Intel cores take a microcode assist for each subnormal
/// operand or result, which made those builders 2x slower there (issue 17). So the lane
/// holds the index with bit 30 forced on and the index's own bit 30 moved to the sign bit:
/// the exponent is at least 128, so for every index below 2^31
/// ([`MAX_PRIMITIVES`](crate::MAX_PRIMITIVES) < 2^31) the lane is a float of magnitude at
/// least 2 (or an infinity or NaN from index 0x3F80_0000 on), never zero or subnormal, and
/// products with box extents do not underflow.
#[inline(always)]
pub(crate) fn index_lane(index: u32) -> f32 {
    debug_assert!(index < 1 << 31);
    f32::from_bits(index | LANE_TAG | ((index & LANE_TAG) << 1))
}

/// The index stored by [`index_lane`].
#[inline(always)]
pub(crate) fn lane_index(w: f32) -> u32 {
    let b = w.to_bits();
    (b & !(LANE_TAG | 1 << 31)) | ((b >> 1) & LANE_TAG)
}

/// A float mapped to an unsigned integer with the same order (for sorting keys).
#[inline]
pub(crate) fn ordered_bits(f: f32) -> u32 {
    let b = f.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_helpers_agree() {
        let pos = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let idx = vec![[0, 1, 2], [1, 2, 3]];
        let tris: Vec<Triangle> = idx
            .iter()
            .map(|t| Triangle::new(pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]))
            .collect();
        assert_eq!(
            indexed_triangle_aabbs(&pos, &idx).unwrap(),
            triangle_aabbs(&tris)
        );
        assert_eq!(
            indexed_triangle_aabbs(&pos, &[[0, 1, 9]]),
            Err(BuildError::VertexOutOfRange {
                triangle: 0,
                vertex: 9,
                vertices: 4
            })
        );
    }

    /// Every index a builder can see round-trips through the `w` lane, and the lane is
    /// never zero or subnormal (issue 17), so no arithmetic on it takes a subnormal assist.
    #[test]
    fn index_lane_round_trips_and_is_never_subnormal() {
        let edges = [
            0,
            1,
            2,
            1 << 22,
            (1 << 23) - 1,
            1 << 23,
            0x3F7F_FFFF,
            0x3F80_0000,
        ];
        let edges = edges
            .into_iter()
            .chain([0x3FFF_FFFF, 1 << 30, (1 << 30) + 1]);
        let edges = edges.chain([(1 << 30) + (1 << 23), MAX_PRIMITIVES as u32 - 1]);
        let all = (0..1 << 16)
            .chain((0..1 << 16).map(|i| i * 32_749))
            .chain(edges);
        for i in all {
            let w = index_lane(i);
            assert_eq!(lane_index(w), i);
            assert!(!w.is_subnormal() && w != 0.0, "{i:#x}: lane {w:e}");
            assert!(w.abs() >= 2.0 || !w.is_finite(), "{i:#x}: lane {w:e}");
        }
    }

    #[test]
    fn centroid_of_huge_boxes_is_finite() {
        let b = Aabb::new(Vec3::splat(f32::MAX), Vec3::splat(f32::MAX));
        assert!(centroid(&b).is_finite());
    }

    /// Scale check of the "20M triangles": every fast builder on a 20M-triangle
    /// soup passes the validator. Run by hand (several GB of memory, about a minute):
    /// `cargo test --release -p bvh --lib -- --ignored twenty_million`
    /// (`BVH_SCALE_N` overrides the triangle count).
    #[test]
    #[ignore]
    fn twenty_million_triangles() {
        let n: usize = std::env::var("BVH_SCALE_N")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(20_000_000);
        let prims = crate::testutil::proc_scene(&format!("proc:soup?n={n}"));
        assert_eq!(prims.len(), n);
        let t = BinnedSahBuilder::default().build(&prims).unwrap();
        crate::testutil::assert_valid("binned", &t, &prims, 8);
        drop(t);
        let t = LbvhBuilder::default().build(&prims).unwrap();
        crate::testutil::assert_valid("lbvh", &t, &prims, 1);
    }

    /// A finite box from six arbitrary finite floats (huge, tiny, denormal, signed zero).
    fn any_box() -> impl proptest::strategy::Strategy<Value = Aabb> {
        use proptest::prelude::*;
        let f = prop_oneof![
            proptest::num::f32::NORMAL | proptest::num::f32::SUBNORMAL | proptest::num::f32::ZERO,
            -10.0f32..10.0,
            Just(f32::MAX),
            Just(f32::MIN),
        ];
        proptest::array::uniform6(f).prop_map(|v| {
            let a = Vec3::new(v[0], v[1], v[2]);
            let b = Vec3::new(v[3], v[4], v[5]);
            Aabb::new(a.min(b), a.max(b))
        })
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Any finite input, however extreme, gives a valid tree from every builder (no
        /// panic, no NaN-driven wrong split): overflowing areas fall back to median splits.
        #[test]
        fn extreme_finite_boxes_give_valid_trees(prims in proptest::collection::vec(any_box(), 0..300)) {
            let sweep = SweepSahBuilder { max_leaf_size: 4, ..Default::default() }.build(&prims).unwrap();
            proptest::prop_assert_eq!(validate(&sweep, &prims, 4), Ok(()));
            for bins in [8, 32] {
                let b = BinnedSahBuilder { bins, max_leaf_size: 4, ..Default::default() }.build(&prims).unwrap();
                proptest::prop_assert_eq!(validate(&b, &prims, 4), Ok(()));
            }
            for bits in [MortonBits::Bits30, MortonBits::Bits63] {
                let l = LbvhBuilder { bits, threads: 0 }.build(&prims).unwrap();
                proptest::prop_assert_eq!(validate(&l, &prims, 1), Ok(()));
            }
        }
    }

    /// Every real scene gives valid trees from the fast builders.
    #[test]
    fn real_scenes_give_valid_trees() {
        let Some(scenes) = crate::testutil::real_scenes() else {
            return;
        };
        assert!(!scenes.is_empty());
        for (name, prims) in &scenes {
            let t = BinnedSahBuilder::default().build(prims).unwrap();
            crate::testutil::assert_valid(name, &t, prims, 8);
            let t = LbvhBuilder::default().build(prims).unwrap();
            crate::testutil::assert_valid(name, &t, prims, 1);
        }
    }

    /// SAH of every builder on every real scene, relative to the sweep SAH build, printed as
    /// a Markdown table (all trees validated). Run by hand:
    /// `cargo test --release -p bvh --lib -- --ignored --nocapture real_scene_sah_table`
    #[test]
    #[ignore]
    fn real_scene_sah_table() {
        let Some(scenes) = crate::testutil::real_scenes() else {
            return;
        };
        println!("| scene | triangles | sweep SAH | binned/8 | binned/16 | binned/32 | lbvh/30 | lbvh/63 |");
        println!("|---|---|---|---|---|---|---|---|");
        for (name, prims) in &scenes {
            let sweep = SweepSahBuilder::default().build(prims).unwrap();
            crate::testutil::assert_valid(name, &sweep, prims, 8);
            let mut row = format!("| {name} | {} | {:.2} |", prims.len(), sweep.sah());
            for bins in [8, 16, 32] {
                let t = BinnedSahBuilder {
                    bins,
                    ..Default::default()
                }
                .build(prims)
                .unwrap();
                crate::testutil::assert_valid(name, &t, prims, 8);
                row += &format!(" {:.3} |", t.sah_vs(&sweep));
            }
            for bits in [MortonBits::Bits30, MortonBits::Bits63] {
                let t = LbvhBuilder { bits, threads: 0 }.build(prims).unwrap();
                crate::testutil::assert_valid(name, &t, prims, 1);
                row += &format!(" {:.3} |", t.sah_vs(&sweep));
            }
            println!("{row}");
        }
    }
}
