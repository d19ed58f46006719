//! Refit: bottom-up box update of a [`Bvh2`] or [`Mbvh4`] for animated scenes whose
//! topology is stable (same primitives, same ids, moved), and SAH tracking across frames.
//!
//! Rebuilding every frame costs a full build; refitting keeps the tree and recomputes every
//! box from the new primitive boxes in one pass, which is much cheaper but lets quality
//! drift as primitives that were close at build time move apart. [`RefitTracker`] records
//! the SAH of each refitted frame relative to the SAH at build time and advises a rebuild
//! once it has grown past a threshold.
//!
//! Both formats store nodes depth-first (preorder), so every inner child has a larger index
//! than its parent; a single reverse pass over the node array therefore sees every child
//! before its parent and can take a child node's box as the union of its (already updated)
//! child boxes. The pass checks that invariant as it goes, so a corrupt tree gives a
//! [`RefitError`] instead of a panic or a wrong box.

use crate::bvh2::Bvh2;
use crate::mbvh4::Mbvh4;
use crate::node::{ChildRef, TreeNode};
use crate::sah::sah_ratio;
use geom::Aabb;
use thiserror::Error;

/// Why a tree could not be refitted.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum RefitError {
    /// The number of primitive boxes differs from the tree's primitive count (the topology
    /// changed: rebuild instead).
    #[error("the tree holds {tree} primitives but {given} boxes were given: rebuild instead")]
    PrimCountChanged {
        /// Primitives in the tree.
        tree: usize,
        /// Boxes given.
        given: usize,
    },
    /// A primitive box has a NaN or infinite coordinate.
    #[error("primitive {index} has a non-finite bounding box")]
    NonFinite {
        /// Index of the offending primitive.
        index: usize,
    },
    /// A primitive box has `min > max` on some axis.
    #[error("primitive {index} has an empty or inverted bounding box (min > max)")]
    InvertedBox {
        /// Index of the offending primitive.
        index: usize,
    },
    /// A child link or leaf range is out of range, or an inner child does not come after
    /// its parent. The boxes of nodes after `node` may already have been updated.
    #[error("node {node} child {slot} is corrupt (bad link or leaf range)")]
    CorruptTree {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// The tracker threshold is not a finite number above 0.
    #[error("rebuild threshold {0} must be a finite number above 0")]
    BadThreshold(f64),
}

/// Checks the new primitive boxes: same count as the tree, finite, not inverted.
fn check_prims(tree_prims: usize, prims: &[Aabb]) -> Result<(), RefitError> {
    if prims.len() != tree_prims {
        return Err(RefitError::PrimCountChanged {
            tree: tree_prims,
            given: prims.len(),
        });
    }
    for (index, b) in prims.iter().enumerate() {
        if !b.is_finite() {
            return Err(RefitError::NonFinite { index });
        }
        if b.is_empty() {
            return Err(RefitError::InvertedBox { index });
        }
    }
    Ok(())
}

/// The box of the leaf `c` (union of its primitives' boxes), or `None` when its range or a
/// primitive index is out of range.
#[inline]
fn leaf_box(c: ChildRef, table: &[u32], prims: &[Aabb]) -> Option<Aabb> {
    let first = c.index as usize;
    let refs = table.get(first..first + c.count as usize)?;
    let mut b = Aabb::EMPTY;
    for &p in refs {
        b = b.union(*prims.get(p as usize)?);
    }
    Some(b)
}

/// Trees with at least this many nodes are refitted in parallel.
const PAR_REFIT_MIN_NODES: usize = 1 << 15;

/// Refits node `i` (absolute index) of `nodes`, which holds nodes `base..base + len`; its
/// inner children must lie after it inside that window.
#[inline(always)]
fn refit_node<N: TreeNode>(
    nodes: &mut [N],
    base: usize,
    i: usize,
    table: &[u32],
    prims: &[Aabb],
) -> Result<(), RefitError> {
    let end = base + nodes.len();
    for slot in 0..N::WIDTH {
        let c = nodes[i - base].child_refs()[slot];
        let b = if c.is_leaf() {
            leaf_box(c, table, prims)
        } else if c.is_inner() {
            let t = c.index as usize;
            (t > i && t < end).then(|| nodes[t - base].own_box())
        } else {
            continue;
        };
        let b = b.ok_or(RefitError::CorruptTree { node: i, slot })?;
        nodes[i - base].set_slot_aabb(slot, &b);
    }
    Ok(())
}

/// Refits a window of nodes holding whole subtrees, bottom-up (reverse preorder).
fn refit_window<N: TreeNode>(
    nodes: &mut [N],
    base: usize,
    table: &[u32],
    prims: &[Aabb],
) -> Result<(), RefitError> {
    for i in (base..base + nodes.len()).rev() {
        refit_node(nodes, base, i, table, prims)?;
    }
    Ok(())
}

/// Bottom-up refit of a depth-first node array. Large trees: in preorder every subtree is
/// a contiguous index range, so the top of the tree is cut into disjoint subtree windows
/// that are refitted in parallel, then the few nodes above them are refitted in reverse
/// order. The result is the same as the sequential pass (min/max are exact).
fn refit_nodes<N: TreeNode>(
    nodes: &mut [N],
    table: &[u32],
    prims: &[Aabb],
) -> Result<(), RefitError> {
    let n = nodes.len();
    if n < PAR_REFIT_MIN_NODES || rayon::current_num_threads() < 2 {
        return refit_window(nodes, 0, table, prims);
    }
    // Expand subtrees [start, end) from the root until they are small enough.
    let target = n / (8 * rayon::current_num_threads()).max(1);
    let mut top: Vec<usize> = Vec::new();
    let mut windows: Vec<(usize, usize)> = Vec::new();
    let mut work = vec![(0usize, n)];
    while let Some((s, e)) = work.pop() {
        if e - s <= target || top.len() >= 4096 {
            windows.push((s, e));
            continue;
        }
        top.push(s);
        let mut kids: Vec<usize> = (0..N::WIDTH)
            .map(|slot| nodes[s].child_refs()[slot])
            .filter(ChildRef::is_inner)
            .map(|c| c.index as usize)
            .collect();
        kids.sort_unstable();
        if kids.first().is_some_and(|&c| c != s + 1) {
            // Not a preorder tree: leave the checks to the sequential pass.
            return refit_window(nodes, 0, table, prims);
        }
        for (k, &c) in kids.iter().enumerate() {
            let ce = kids.get(k + 1).copied().unwrap_or(e);
            if c <= s || c >= ce {
                // Not a preorder tree: leave the checks to the sequential pass.
                return refit_window(nodes, 0, table, prims);
            }
            work.push((c, ce));
        }
    }
    windows.sort_unstable();
    let mut jobs: Vec<(usize, &mut [N])> = Vec::with_capacity(windows.len());
    let mut rest: &mut [N] = nodes;
    let mut at = 0;
    for &(s, e) in &windows {
        let tail = std::mem::take(&mut rest);
        let (_, tail) = tail.split_at_mut(s - at);
        let (mine, tail) = tail.split_at_mut(e - s);
        jobs.push((s, mine));
        rest = tail;
        at = e;
    }
    {
        use rayon::prelude::*;
        jobs.into_par_iter()
            .try_for_each(|(s, w)| refit_window(w, s, table, prims))?;
    }
    top.sort_unstable_by(|a, b| b.cmp(a));
    for i in top {
        refit_node(nodes, 0, i, table, prims)?;
    }
    Ok(())
}

/// Recomputes every box of `bvh` from the new primitive boxes `prims` (same ids as at
/// build time). Refitting to the boxes the tree was built from gives the identical tree.
/// Trees of at least 32768 nodes are refitted in parallel (same result). On error the
/// topology is unchanged but some boxes may already be updated.
pub fn refit_bvh2(bvh: &mut Bvh2, prims: &[Aabb]) -> Result<(), RefitError> {
    check_prims(bvh.prim_indices.len(), prims)?;
    refit_nodes(&mut bvh.nodes, &bvh.prim_indices, prims)?;
    bvh.bounds = bvh.nodes.first().map_or(Aabb::EMPTY, |r| r.aabb());
    Ok(())
}

/// Recomputes every box of the 4-wide `tree` from the new primitive boxes `prims`; the
/// 4-wide counterpart of [`refit_bvh2`].
pub fn refit_mbvh4(tree: &mut Mbvh4, prims: &[Aabb]) -> Result<(), RefitError> {
    check_prims(tree.prim_indices.len(), prims)?;
    refit_nodes(&mut tree.nodes, &tree.prim_indices, prims)?;
    tree.bounds = tree.nodes.first().map_or(Aabb::EMPTY, |r| r.aabb());
    Ok(())
}

/// One recorded frame of a [`RefitTracker`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefitFrame {
    /// Frame number (0-based, in recording order since the last rebuild or creation).
    pub frame: usize,
    /// SAH of the refitted tree.
    pub sah: f64,
    /// `sah` over the SAH at build time (1.0 = no degradation).
    pub ratio: f64,
    /// Whether `ratio` exceeds the tracker's threshold.
    pub rebuild_advised: bool,
}

/// Records the SAH of a refitted tree frame by frame, relative to the SAH when the tree was
/// built, and advises a rebuild when the ratio exceeds a threshold.
///
/// The SAH is normalized by the scene box area, so the ratio measures how much worse the
/// refitted tree is for rays that hit the scene, independent of the scene growing.
#[derive(Clone, Debug, PartialEq)]
pub struct RefitTracker {
    build_sah: f64,
    threshold: f64,
    frames: Vec<RefitFrame>,
}

impl RefitTracker {
    /// Default rebuild threshold: advise a rebuild once the SAH is 30% above the build's.
    pub const DEFAULT_THRESHOLD: f64 = 1.3;

    /// A tracker for a tree whose SAH right after the build is `build_sah`; a rebuild is
    /// advised once `sah / build_sah > threshold`.
    pub fn new(build_sah: f64, threshold: f64) -> Result<Self, RefitError> {
        if !(threshold.is_finite() && threshold > 0.0) {
            return Err(RefitError::BadThreshold(threshold));
        }
        Ok(Self {
            build_sah,
            threshold,
            frames: Vec::new(),
        })
    }

    /// A tracker with [`Self::DEFAULT_THRESHOLD`].
    pub fn with_default_threshold(build_sah: f64) -> Self {
        Self {
            build_sah,
            threshold: Self::DEFAULT_THRESHOLD,
            frames: Vec::new(),
        }
    }

    /// Records the SAH of the next refitted frame and returns its record.
    pub fn record(&mut self, sah: f64) -> RefitFrame {
        let ratio = sah_ratio(sah, self.build_sah);
        let f = RefitFrame {
            frame: self.frames.len(),
            sah,
            ratio,
            // NaN ratios (NaN SAH) also advise a rebuild: the tree cannot be trusted.
            rebuild_advised: ratio.is_nan() || ratio > self.threshold,
        };
        self.frames.push(f);
        f
    }

    /// Records the SAH of a refitted [`Bvh2`].
    pub fn record_bvh2(&mut self, bvh: &Bvh2) -> RefitFrame {
        self.record(bvh.sah())
    }

    /// Records the SAH of a refitted [`Mbvh4`].
    pub fn record_mbvh4(&mut self, tree: &Mbvh4) -> RefitFrame {
        self.record(tree.sah())
    }

    /// Starts over after a rebuild whose SAH is `build_sah` (clears the history).
    pub fn rebuilt(&mut self, build_sah: f64) {
        self.build_sah = build_sah;
        self.frames.clear();
    }

    /// Whether the latest frame advises a rebuild (false before any frame).
    pub fn rebuild_advised(&self) -> bool {
        self.frames.last().is_some_and(|f| f.rebuild_advised)
    }

    /// SAH at build time.
    pub fn build_sah(&self) -> f64 {
        self.build_sah
    }

    /// The rebuild threshold.
    pub fn threshold(&self) -> f64 {
        self.threshold
    }

    /// The frames recorded since creation or the last rebuild.
    pub fn frames(&self) -> &[RefitFrame] {
        &self.frames
    }

    /// Largest ratio recorded so far (1.0 before any frame).
    pub fn worst_ratio(&self) -> f64 {
        self.frames.iter().map(|f| f.ratio).fold(1.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mbvh4::validate_mbvh4;
    use crate::testutil::{adversarial, soup};
    use crate::{collapse, validate, BinnedSahBuilder, LbvhBuilder, Mbvh4TopDownBuilder};
    use geom::Vec3;

    /// Boxes of a procedural scene at time `t`.
    fn frame(s: &dyn scene::Scene, t: f32) -> Vec<Aabb> {
        let m = s.mesh_at(t).unwrap();
        crate::indexed_triangle_aabbs(&m.positions, &m.triangles).unwrap()
    }

    /// Reference refit: boxes recomputed top-down by plain recursion.
    fn reference(bvh: &Bvh2, prims: &[Aabb]) -> Bvh2 {
        fn rec(t: &mut Bvh2, c: ChildRef, prims: &[Aabb]) -> Aabb {
            if c.is_leaf() {
                let s = c.index as usize;
                return t.prim_indices[s..s + c.count as usize]
                    .iter()
                    .fold(Aabb::EMPTY, |b, &p| b.union(prims[p as usize]));
            }
            let i = c.index as usize;
            let mut all = Aabb::EMPTY;
            for slot in 0..2 {
                let k = t.nodes[i].children[slot];
                if !k.is_empty() {
                    let b = rec(t, k, prims);
                    t.nodes[i].set_child_aabb(slot, &b);
                    all = all.union(b);
                }
            }
            all
        }
        let mut t = bvh.clone();
        t.bounds = rec(&mut t, ChildRef::inner(0), prims);
        t
    }

    #[test]
    fn refit_to_the_same_boxes_is_the_identity() {
        let mut inputs = adversarial();
        inputs.push(("soup", soup(3000, 2.0, 4)));
        inputs.push(("none", Vec::new()));
        for (name, prims) in inputs {
            for t in [
                BinnedSahBuilder::default().build(&prims).unwrap(),
                LbvhBuilder::default().build(&prims).unwrap(),
            ] {
                let mut r = t.clone();
                refit_bvh2(&mut r, &prims).unwrap();
                assert_eq!(r, t, "{name}");
                let m = collapse(&t).unwrap();
                let mut r = m.clone();
                refit_mbvh4(&mut r, &prims).unwrap();
                assert_eq!(r, m, "{name}");
            }
            let m = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
            let mut r = m.clone();
            refit_mbvh4(&mut r, &prims).unwrap();
            assert_eq!(r, m, "{name}");
        }
    }

    #[test]
    fn refit_after_motion_is_valid_and_equals_a_fresh_computation() {
        let s = scene::open("proc:cloth?n=5000", &Default::default()).unwrap();
        let d = s.info().timeline.duration_s;
        let p0 = frame(s.as_ref(), 0.0);
        let bvh = BinnedSahBuilder::default().build(&p0).unwrap();
        let m4 = Mbvh4TopDownBuilder::default().build(&p0).unwrap();
        for t in [0.25 * d, 0.5 * d, d] {
            let p = frame(s.as_ref(), t);
            assert_ne!(p, p0);
            let mut r = bvh.clone();
            refit_bvh2(&mut r, &p).unwrap();
            assert_eq!(validate(&r, &p, 8), Ok(()));
            assert_eq!(r, reference(&bvh, &p));
            // A collapsed tree refits validly too, and a 4-wide tree refitted back to
            // frame 0 is the original again.
            let mut c = collapse(&bvh).unwrap();
            refit_mbvh4(&mut c, &p).unwrap();
            assert_eq!(validate_mbvh4(&c, &p, 8), Ok(()));
            let mut m = m4.clone();
            refit_mbvh4(&mut m, &p).unwrap();
            assert_eq!(validate_mbvh4(&m, &p, 8), Ok(()));
            refit_mbvh4(&mut m, &p0).unwrap();
            assert_eq!(m, m4);
        }
    }

    /// Refits a tree built at t = 0 over 11 frames of `spec`; returns the tracker and,
    /// per frame, the refitted SAH over the SAH of a fresh build of that frame.
    fn track(spec: &str) -> (RefitTracker, Vec<f64>) {
        let s = scene::open(spec, &Default::default()).unwrap();
        let tl = s.info().timeline;
        let p0 = frame(s.as_ref(), 0.0);
        let mut bvh = BinnedSahBuilder::default().build(&p0).unwrap();
        let mut tr = RefitTracker::with_default_threshold(bvh.sah());
        let mut vs_rebuild = Vec::new();
        let frames = tl.frame_count().min(12);
        for k in 1..frames {
            let t = tl.duration_s * k as f32 / (frames - 1) as f32;
            let p = frame(s.as_ref(), t);
            refit_bvh2(&mut bvh, &p).unwrap();
            assert_eq!(validate(&bvh, &p, 8), Ok(()), "{spec} t={t}");
            tr.record_bvh2(&bvh);
            let fresh = BinnedSahBuilder::default().build(&p).unwrap();
            vs_rebuild.push(bvh.sah_vs(&fresh));
        }
        (tr, vs_rebuild)
    }

    #[test]
    fn tracker_separates_explode_from_cloth() {
        let (ex, ex_fresh) = track("proc:explode?n=5000");
        let ratios: Vec<f64> = ex.frames().iter().map(|f| f.ratio).collect();
        println!("explode SAH vs build {ratios:.2?}\n        vs rebuild {ex_fresh:.2?}");
        assert!(ex.rebuild_advised(), "explode: {ratios:?}");
        assert!(ex.worst_ratio() > 2.5, "explode: {ratios:?}");
        assert!(
            ratios.windows(2).all(|w| w[1] >= w[0]),
            "explode grows: {ratios:?}"
        );
        assert!(
            ex_fresh.last().unwrap() > &2.5,
            "explode vs rebuild: {ex_fresh:?}"
        );
        let (cl, cl_fresh) = track("proc:cloth?n=5000");
        let ratios: Vec<f64> = cl.frames().iter().map(|f| f.ratio).collect();
        println!("cloth SAH vs build {ratios:.2?}\n      vs rebuild {cl_fresh:.2?}");
        // The cloth folds, so even its fresh builds change SAH; refit stays moderate.
        assert!(cl.worst_ratio() < 1.6, "cloth: {ratios:?}");
        assert!(!cl.frames()[0].rebuild_advised, "cloth: {ratios:?}");
        assert!(
            cl_fresh.iter().all(|&r| r < 1.6),
            "cloth vs rebuild: {cl_fresh:?}"
        );
    }

    /// Real animated scenes (horse-gallop keyframes, skinned glTF): a tree built at t = 0
    /// refits over the animation and stays valid; real static scenes collapse and build
    /// 4-wide validly. Skips when the shared scene folder is absent.
    #[test]
    fn real_scenes_refit_and_build_4_wide() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
        if !dir.is_dir() {
            println!("skipping: {} not found", dir.display());
            return;
        }
        for name in ["horse-gallop", "gltf/BrainStem.glb", "gltf/CesiumMan.glb"] {
            let s = scene::open(dir.join(name).to_str().unwrap(), &Default::default()).unwrap();
            let tl = s.info().timeline;
            let p0 = frame(s.as_ref(), 0.0);
            let mut bvh = BinnedSahBuilder::default().build(&p0).unwrap();
            let mut m = Mbvh4TopDownBuilder::default().build(&p0).unwrap();
            let mut tr = RefitTracker::with_default_threshold(bvh.sah());
            for k in 1..=6 {
                let t = tl.duration_s * k as f32 / 6.0;
                let p = frame(s.as_ref(), t);
                refit_bvh2(&mut bvh, &p).unwrap();
                refit_mbvh4(&mut m, &p).unwrap();
                assert_eq!(validate(&bvh, &p, 8), Ok(()), "{name} t={t}");
                assert_eq!(validate_mbvh4(&m, &p, 8), Ok(()), "{name} t={t}");
                tr.record_bvh2(&bvh);
            }
            println!("{name}: refit SAH ratio worst {:.2}", tr.worst_ratio());
        }
        let Some(scenes) = crate::testutil::real_scenes() else {
            return;
        };
        for (name, prims) in scenes.iter().filter(|(_, p)| p.len() < 400_000) {
            let c = collapse(&BinnedSahBuilder::default().build(prims).unwrap()).unwrap();
            assert_eq!(validate_mbvh4(&c, prims, 8), Ok(()), "{name} collapse");
            let t = Mbvh4TopDownBuilder::default().build(prims).unwrap();
            assert_eq!(validate_mbvh4(&t, prims, 8), Ok(()), "{name} top-down");
        }
    }

    /// Release timings of refit, collapse and the top-down build, printed. Run by hand:
    /// `cargo test --release -p bvh --lib -- --ignored --nocapture mbvh4_refit_timings`
    #[test]
    #[ignore]
    fn mbvh4_refit_timings() {
        use std::time::Instant;
        fn ms(t: Instant) -> f64 {
            t.elapsed().as_secs_f64() * 1e3
        }
        let threads = rayon::current_num_threads();
        let dragon = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/scenes/dragon.ply");
        let mut inputs = vec![(
            "soup 1M".to_string(),
            crate::testutil::proc_scene("proc:soup?n=1000000"),
        )];
        if dragon.is_file() {
            let s = scene::open(dragon.to_str().unwrap(), &Default::default()).unwrap();
            inputs.insert(0, ("dragon.ply".to_string(), frame(s.as_ref(), 0.0)));
        }
        for (name, prims) in &inputs {
            let t = Instant::now();
            let bvh = BinnedSahBuilder::default().build(prims).unwrap();
            let binned_ms = ms(t);
            let mut r = bvh.clone();
            let mut best = f64::MAX;
            for _ in 0..5 {
                let t = Instant::now();
                refit_bvh2(&mut r, prims).unwrap();
                best = best.min(ms(t));
            }
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            let mut best1 = f64::MAX;
            for _ in 0..5 {
                let t = Instant::now();
                one.install(|| refit_bvh2(&mut r, prims)).unwrap();
                best1 = best1.min(ms(t));
            }
            let t = Instant::now();
            let c = collapse(&bvh).unwrap();
            let collapse_ms = ms(t);
            let mut rc = c.clone();
            let mut best4 = f64::MAX;
            for _ in 0..5 {
                let t = Instant::now();
                refit_mbvh4(&mut rc, prims).unwrap();
                best4 = best4.min(ms(t));
            }
            let mut td = Vec::new();
            for th in [1, 2] {
                let b = Mbvh4TopDownBuilder {
                    threads: th,
                    ..Default::default()
                };
                let t = Instant::now();
                let m = b.build(prims).unwrap();
                td.push((th, ms(t), m.sah(), m.nodes.len()));
            }
            println!(
                "{name}: {} prims, pool {threads} threads | binned {binned_ms:.0} ms, {} nodes, SAH {:.2} | \
                 refit Bvh2 {best:.1} ms (1 thread {best1:.1} ms) | collapse {collapse_ms:.1} ms -> {} nodes, SAH {:.2} | \
                 refit Mbvh4 {best4:.1} ms | top-down {td:.1?}",
                prims.len(),
                bvh.nodes.len(),
                bvh.sah(),
                c.nodes.len(),
                c.sah()
            );
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// Any tree refitted to randomly moved boxes validates and equals the recursive
        /// reference; its collapsed and native 4-wide trees refit validly too.
        #[test]
        fn random_motion_refits_exactly(n in 0usize..600, seed: u64, shift in 0.0f32..50.0) {
            let p0 = soup(n, 2.0, seed);
            let mut rng = crate::testutil::Rng::new(seed ^ 0xABCD);
            let p1: Vec<Aabb> = p0
                .iter()
                .map(|b| {
                    let d = (rng.point(2.0) - Vec3::ONE) * shift;
                    let g = rng.point(1.0);
                    Aabb::new(b.min + d - g, b.max + d)
                })
                .collect();
            let bvh = LbvhBuilder::default().build(&p0).unwrap();
            let mut r = bvh.clone();
            refit_bvh2(&mut r, &p1).unwrap();
            proptest::prop_assert_eq!(validate(&r, &p1, 1), Ok(()));
            proptest::prop_assert_eq!(&r, &reference(&bvh, &p1));
            let mut c = collapse(&bvh).unwrap();
            refit_mbvh4(&mut c, &p1).unwrap();
            proptest::prop_assert_eq!(validate_mbvh4(&c, &p1, 1), Ok(()));
            let mut m = Mbvh4TopDownBuilder::default().build(&p0).unwrap();
            refit_mbvh4(&mut m, &p1).unwrap();
            proptest::prop_assert_eq!(validate_mbvh4(&m, &p1, 8), Ok(()));
        }
    }

    /// The parallel refit of a large tree (2 and 4 threads) equals the sequential pass.
    #[test]
    fn parallel_refit_equals_sequential() {
        let p0 = soup(100_000, 2.0, 21);
        let p1 = soup(100_000, 3.0, 22);
        let bvh = LbvhBuilder::default().build(&p0).unwrap();
        assert!(bvh.nodes.len() >= PAR_REFIT_MIN_NODES);
        let mut seq = bvh.clone();
        refit_window(&mut seq.nodes, 0, &seq.prim_indices, &p1).unwrap();
        seq.bounds = seq.nodes[0].aabb();
        let m0 = collapse(&bvh).unwrap();
        assert!(m0.nodes.len() >= PAR_REFIT_MIN_NODES);
        let mut mseq = m0.clone();
        refit_window(&mut mseq.nodes, 0, &mseq.prim_indices, &p1).unwrap();
        mseq.bounds = mseq.nodes[0].aabb();
        for threads in [2, 4] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut par = bvh.clone();
            pool.install(|| refit_bvh2(&mut par, &p1)).unwrap();
            assert_eq!(par, seq, "{threads} threads");
            let mut m = m0.clone();
            pool.install(|| refit_mbvh4(&mut m, &p1)).unwrap();
            assert_eq!(m, mseq, "{threads} threads");
            assert_eq!(validate_mbvh4(&m, &p1, 1), Ok(()));
            // A corrupt link inside a window is still an error.
            let mut c = bvh.clone();
            let last = c.nodes.len() - 1;
            c.nodes[last].children[0] = ChildRef::inner(5);
            let got = pool.install(|| refit_bvh2(&mut c, &p1));
            assert!(
                matches!(got, Err(RefitError::CorruptTree { .. })),
                "{got:?}"
            );
        }
    }

    #[test]
    fn tracker_bookkeeping() {
        assert!(RefitTracker::new(1.0, f64::NAN).is_err());
        assert!(RefitTracker::new(1.0, 0.0).is_err());
        let mut t = RefitTracker::new(10.0, 1.5).unwrap();
        assert!(!t.rebuild_advised());
        assert_eq!(t.record(12.0).ratio, 1.2);
        assert!(!t.rebuild_advised());
        let f = t.record(16.0);
        assert!(f.rebuild_advised && f.frame == 1);
        assert!(t.record(f64::NAN).rebuild_advised);
        t.rebuilt(16.0);
        assert!(t.frames().is_empty() && t.build_sah() == 16.0);
        assert!(!t.record(16.0).rebuild_advised);
        // An empty scene (SAH 0) stays at ratio 1.
        let mut z = RefitTracker::with_default_threshold(0.0);
        assert_eq!(z.record(0.0).ratio, 1.0);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let prims = soup(500, 2.0, 8);
        let mut bvh = BinnedSahBuilder::default().build(&prims).unwrap();
        let mut m = collapse(&bvh).unwrap();
        assert_eq!(
            refit_bvh2(&mut bvh, &prims[..499]),
            Err(RefitError::PrimCountChanged {
                tree: 500,
                given: 499
            })
        );
        let mut more = prims.clone();
        more.push(prims[0]);
        assert!(matches!(
            refit_mbvh4(&mut m, &more),
            Err(RefitError::PrimCountChanged { .. })
        ));
        let mut nan = prims.clone();
        nan[7].max.y = f32::NAN;
        assert_eq!(
            refit_bvh2(&mut bvh, &nan),
            Err(RefitError::NonFinite { index: 7 })
        );
        let mut inv = prims.clone();
        inv[9] = Aabb::new(Vec3::ONE, Vec3::ZERO);
        assert_eq!(
            refit_mbvh4(&mut m, &inv),
            Err(RefitError::InvertedBox { index: 9 })
        );
        // Corrupt links: a back edge, an out-of-range node, a leaf past the table, a bad
        // primitive id.
        let mut c = bvh.clone();
        c.nodes[2].children[0] = ChildRef::inner(1);
        assert!(matches!(
            refit_bvh2(&mut c, &prims),
            Err(RefitError::CorruptTree { .. })
        ));
        let mut c = bvh.clone();
        c.nodes[2].children[1] = ChildRef::inner(u32::MAX - 1);
        assert!(matches!(
            refit_bvh2(&mut c, &prims),
            Err(RefitError::CorruptTree { .. })
        ));
        let mut c = m.clone();
        c.nodes[0].children[0] = ChildRef::leaf(u32::MAX - 1, 9);
        assert!(matches!(
            refit_mbvh4(&mut c, &prims),
            Err(RefitError::CorruptTree { .. })
        ));
        let mut c = m.clone();
        c.prim_indices[3] = 10_000;
        assert!(matches!(
            refit_mbvh4(&mut c, &prims),
            Err(RefitError::CorruptTree { .. })
        ));
        let mut c = Bvh2 {
            nodes: Vec::new(),
            ..Bvh2::empty()
        };
        refit_bvh2(&mut c, &[]).unwrap();
        assert!(c.bounds.is_empty());
    }
}
