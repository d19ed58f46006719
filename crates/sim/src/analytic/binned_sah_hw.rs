//! The binned SAH hardware builder of Doyle et al. \[DFM13\], as \[P2\] §6.1 models it:
//! DRAM traffic from large sweeps and BVH output, and floating-point operations.
//!
//! \[P2\] §6.1 instruments a software binned SAH builder and charges traffic for the BVH
//! output and for *large sweeps*, whose primitives do not fit the unit's on-chip buffers
//! (8,192 AABBs in the instance of \[DFM13\]). Each sweep over a node partitions its
//! primitives by the node's split while it bins them for the two children's splits, so a
//! sweep "simultaneously produces input data for two child sweeps". This module runs the
//! same accounting over a tree built by [`bvh::BinnedSahBuilder`] (the tree is the record
//! of the build: each inner node is one sweep over its subtree's primitives):
//! - a node's primitives live in DRAM when it is the root (the input), when they exceed the
//!   buffer, or when the two children of its parent each fit but not together; then only
//!   the smaller child goes to DRAM (\[P2\] §6.1, the "smaller-child rule"; a leaf child
//!   needs no sweep and is never counted);
//! - a sweep over a node in DRAM reads its primitives (`n * aabb_bytes`); the root is read
//!   twice, because its bins must be filled by a pass of their own before the first
//!   partitioning pass (every other node is binned while its parent is partitioned);
//! - a child placed in DRAM is written once by its parent's sweep (`n * aabb_bytes`);
//! - the BVH output is \[P2\]'s format, which \[P2\] §4 adopts to match \[DFM13\]: 64-B nodes
//!   and a 4-B leaf-table entry per primitive.
//!
//! Floating-point operations follow Wald's binned SAH \[P2\] ref. 51 (see [`SweepFlops`]
//! for the count of each step).
//!
//! Validation (tests below, scenes from `shared/scenes`): \[P2\] Table II prints the traffic
//! of \[DFM13\] and \[P2\]'s estimate for four scenes, and Table VI the estimate for 14;
//! Bunny, Crytek, Conference and Dragon are available here (Toasters and Fairy are not).
//! The ordering \[P2\] states holds on all four: the smaller-child rule lies between fixed
//! thresholds of 8,192 and 4,096. The magnitudes do NOT match: with a 16-bin SAH tree from
//! [`bvh::BinnedSahBuilder`] (leaves of up to 8) the model gives 19.8 / 143.9 / 193.5 /
//! 464.2 MB against the printed 18 / 116 / 125 / 379 MB (1.10x, 1.24x, 1.55x, 1.22x; \[DFM13\]
//! itself reported 120 MB for Conference and 380 MB for Dragon). The
//! sizes of the sweeps, and so the traffic, are set by the software builder's split choices
//! (SAH peels small groups off large nodes, which keeps many levels in DRAM; every
//! primitive that stays in DRAM one level deeper costs 64 B), and \[P2\] does not describe
//! its builder further; leaves of one primitive or 8/32 bins change the figures by under
//! 10 %, and leaving out the root's binning pass by 6 % (Dragon). \[P2\] gives no record
//! size for \[DFM13\]; with 24-B records (bounds only, references kept elsewhere) the
//! ratios would be 0.86 / 0.95 / 1.18 / 0.94, but nothing in the sources supports that
//! choice, so the model keeps \[P2\]'s 32-B AABB records and we report the disagreement
//! rather than adjust the record size or rule to hide it.

use bvh::{Bvh2, ChildRef};

use crate::energy::Flops;

/// Parameters of the modelled unit and formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BinnedSahHwParams {
    /// Primitive AABBs the on-chip buffers hold (\[P2\] §6.1: 8,192 in \[DFM13\]).
    pub buffer_prims: u64,
    /// Bytes of one primitive AABB record in DRAM (\[P2\] §4.2: 32 B).
    pub aabb_bytes: u64,
    /// Bytes of one BVH node (\[P2\] §4.1: 64 B).
    pub node_bytes: u64,
    /// Bytes of one leaf-table entry (\[P2\] §4.2: 4 B).
    pub leaf_entry_bytes: u64,
    /// Bins per axis, for the FLOP count (16, the software builder's default).
    pub bins: u64,
    /// Which children go to DRAM.
    pub rule: LargeSweepRule,
}

/// Which nodes' primitives are kept in DRAM ("large sweeps").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LargeSweepRule {
    /// \[P2\] §6.1: children larger than the buffer, and the smaller of two children that
    /// fit one by one but not together.
    SmallerChild,
    /// Every node of more than this many primitives, regardless of its sibling (the
    /// fixed thresholds \[P2\] §6.1 compares with: 4,096 over-, 8,192 underestimates).
    FixedThreshold(u64),
}

impl Default for BinnedSahHwParams {
    fn default() -> Self {
        Self {
            buffer_prims: 8192,
            aabb_bytes: 32,
            node_bytes: 64,
            leaf_entry_bytes: 4,
            bins: 16,
            rule: LargeSweepRule::SmallerChild,
        }
    }
}

/// The model's counts for one build.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BinnedSahHwTraffic {
    /// Sweeps whose primitives are read from DRAM (the root counted once).
    pub large_sweeps: u64,
    /// Bytes read by large sweeps (including the root's binning pass).
    pub sweep_read_bytes: u64,
    /// Bytes of child primitive lists written to DRAM.
    pub sweep_write_bytes: u64,
    /// Bytes of BVH nodes and leaf table written.
    pub bvh_bytes: u64,
    /// Floating-point operations of all sweeps.
    pub flops: u64,
}

impl BinnedSahHwTraffic {
    /// All DRAM traffic in bytes.
    pub fn total_bytes(&self) -> u64 {
        self.sweep_read_bytes + self.sweep_write_bytes + self.bvh_bytes
    }
}

/// Floating-point operations of Wald's binned SAH, per primitive and per sweep.
///
/// Per primitive in a sweep: its centroid (3 adds, 3 multiplies), its bin on each axis
/// (3 subtracts, 3 multiplies), growing the box of its bin on each of the three axes
/// (3 x 6 min/max; the counts are integer adds), and the partition test against the
/// parent's plane (1 compare) with the child's centroid bounds (6 min/max): 37. Per sweep: the bin scale per axis (3 subtracts, 3 divides), then per
/// axis and candidate plane (`bins - 1` of them) the left and right box sweeps (2 x 6
/// min/max), their half areas (2 x 8: 3 subtracts, 3 multiplies, 2 adds), the cost
/// `nL aL + nR aR` (3) and the comparison with the best (1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepFlops;

impl SweepFlops {
    /// Operations per primitive per sweep.
    pub const PER_PRIM: u64 = 6 + 6 + 3 * 6 + 1 + 6;

    /// Operations per sweep independent of its size, for `bins` bins per axis.
    pub fn per_sweep(bins: u64) -> u64 {
        6 + 3 * bins.saturating_sub(1) * (12 + 16 + 3 + 1)
    }
}

/// Primitives under each node (index = node index). Nodes are in depth-first preorder, so
/// children come after parents and one reverse pass suffices.
fn subtree_prims(bvh: &Bvh2) -> Vec<u64> {
    let mut n = vec![0u64; bvh.nodes.len()];
    for i in (0..bvh.nodes.len()).rev() {
        n[i] = bvh.nodes[i]
            .children
            .iter()
            .map(|c| child_prims(c, &n))
            .sum();
    }
    n
}

fn child_prims(c: &ChildRef, n: &[u64]) -> u64 {
    if c.is_leaf() {
        c.count as u64
    } else if c.is_inner() {
        n.get(c.index as usize).copied().unwrap_or(0)
    } else {
        0
    }
}

/// Runs \[P2\] §6.1's model over the tree `bvh` (see the module documentation).
pub fn model(bvh: &Bvh2, p: &BinnedSahHwParams) -> BinnedSahHwTraffic {
    let prims = subtree_prims(bvh);
    let mut t = BinnedSahHwTraffic {
        bvh_bytes: bvh.nodes.len() as u64 * p.node_bytes
            + bvh.prim_count() as u64 * p.leaf_entry_bytes,
        ..Default::default()
    };
    if bvh.nodes.is_empty() || prims[0] == 0 {
        return t;
    }
    // Whether each inner node's primitives are in DRAM when its sweep starts.
    let mut in_dram = vec![false; bvh.nodes.len()];
    in_dram[0] = true;
    // The root's own binning pass.
    t.sweep_read_bytes += prims[0] * p.aabb_bytes;
    for i in 0..bvh.nodes.len() {
        let n = prims[i];
        t.flops += n * SweepFlops::PER_PRIM + SweepFlops::per_sweep(p.bins);
        if in_dram[i] {
            t.large_sweeps += 1;
            t.sweep_read_bytes += n * p.aabb_bytes;
        }
        let kids = bvh.nodes[i].children;
        let sizes = kids.map(|c| child_prims(&c, &prims));
        let threshold = match p.rule {
            LargeSweepRule::SmallerChild => p.buffer_prims,
            LargeSweepRule::FixedThreshold(t) => t,
        };
        let mut to_dram = [false; 2];
        for k in 0..2 {
            to_dram[k] = kids[k].is_inner() && sizes[k] > threshold;
        }
        if p.rule == LargeSweepRule::SmallerChild
            && !to_dram[0]
            && !to_dram[1]
            && sizes[0] + sizes[1] > p.buffer_prims
        {
            // Each fits, both do not: the smaller goes to DRAM (child 1 on a tie).
            let smaller = if sizes[0] < sizes[1] { 0 } else { 1 };
            to_dram[smaller] = kids[smaller].is_inner();
        }
        for k in 0..2 {
            if to_dram[k] {
                in_dram[kids[k].index as usize] = true;
                t.sweep_write_bytes += sizes[k] * p.aabb_bytes;
            }
        }
    }
    t
}

/// The operations of [`SweepFlops`] by kind, for the energy model (\[P2\] §6.4): per
/// primitive 31 adds, subtracts, compares or min/max and 6 multiplies; per sweep the bin
/// scales' 3 subtracts and 3 divisions, each a reciprocal (3 FLOPs, \[P2\] §6.4 after its
/// ref. 33) and a multiply, then per axis and candidate plane 24 adds and 8 multiplies (the
/// half areas' 3 multiplies each and the cost's 2). The totals differ from [`SweepFlops`]'s
/// op counts only by the divisions' weight.
pub const PER_PRIM_FLOPS: Flops = Flops {
    adds: 31.0,
    muls: 6.0,
};

/// The per-sweep part of [`PER_PRIM_FLOPS`]'s model for `bins` bins per axis.
pub fn per_sweep_flops(bins: u64) -> Flops {
    let candidates = 3.0 * bins.saturating_sub(1) as f64;
    Flops {
        adds: 3.0 + 24.0 * candidates,
        muls: 3.0 * (3.0 + 1.0) + 8.0 * candidates,
    }
}

/// The floating-point work of a binned SAH build that made `bvh` (one sweep per inner node
/// over its subtree's primitives), by kind.
pub fn energy_flops(bvh: &Bvh2, bins: u64) -> Flops {
    let prims = subtree_prims(bvh);
    let sweep = per_sweep_flops(bins);
    prims.iter().fold(Flops::default(), |f, &n| {
        f.plus(PER_PRIM_FLOPS.times(n as f64)).plus(sweep)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvh::{BinnedSahBuilder, Node};
    use geom::{Aabb, Vec3};

    fn leaf(first: u32, count: u32) -> ChildRef {
        ChildRef::leaf(first, count)
    }

    /// A hand-made tree: root -> (A: 10 prims in two leaves of 5, B: 7 prims as one leaf
    /// and inner C of 2 leaves 1 + 1).
    fn small_tree() -> Bvh2 {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let nodes = vec![
            Node::new(&b, ChildRef::inner(1), &b, ChildRef::inner(2)),
            Node::new(&b, leaf(0, 5), &b, leaf(5, 5)),
            Node::new(&b, leaf(10, 5), &b, ChildRef::inner(3)),
            Node::new(&b, leaf(15, 1), &b, leaf(16, 1)),
        ];
        Bvh2 {
            nodes,
            prim_indices: (0..17).collect(),
            bounds: b,
        }
    }

    #[test]
    fn subtree_counts() {
        assert_eq!(subtree_prims(&small_tree()), vec![17, 10, 7, 2]);
    }

    #[test]
    fn energy_flops_split_the_op_counts() {
        // Same operations as SweepFlops, the three divisions weighted 4 (reciprocal + mul).
        assert_eq!(
            PER_PRIM_FLOPS.adds + PER_PRIM_FLOPS.muls,
            SweepFlops::PER_PRIM as f64
        );
        for bins in [1u64, 4, 16] {
            let f = per_sweep_flops(bins);
            assert_eq!(f.total(), (SweepFlops::per_sweep(bins) + 3 * 3) as f64);
        }
        // Hand count on the small tree: 17 + 10 + 7 + 2 primitives over 4 sweeps.
        let f = energy_flops(&small_tree(), 4);
        let want = PER_PRIM_FLOPS
            .times(36.0)
            .plus(per_sweep_flops(4).times(4.0));
        assert_eq!(f, want);
        let t = model(
            &small_tree(),
            &BinnedSahHwParams {
                bins: 4,
                ..Default::default()
            },
        );
        assert_eq!(f.total(), (t.flops + 4 * 9) as f64);
    }

    #[test]
    fn accounting_on_a_hand_made_tree() {
        let bvh = small_tree();
        let p = |buffer_prims| BinnedSahHwParams {
            buffer_prims,
            aabb_bytes: 32,
            node_bytes: 64,
            leaf_entry_bytes: 4,
            bins: 4,
            rule: LargeSweepRule::SmallerChild,
        };
        let bvh_bytes = 4 * 64 + 17 * 4;
        // Everything fits: only the root is in DRAM (read twice).
        let t = model(&bvh, &p(100));
        assert_eq!(
            (t.large_sweeps, t.sweep_read_bytes, t.sweep_write_bytes),
            (1, 2 * 17 * 32, 0)
        );
        assert_eq!(t.bvh_bytes, bvh_bytes);
        // Buffer of 12: the children (10 + 7) each fit but not together; the smaller (B, 7)
        // goes to DRAM and is written once and read once.
        let t = model(&bvh, &p(12));
        assert_eq!(t.large_sweeps, 2);
        assert_eq!(t.sweep_write_bytes, 7 * 32);
        assert_eq!(t.sweep_read_bytes, (2 * 17 + 7) * 32);
        // Buffer of 6: A (10) and B (7) are too large; within B the leaf of 5 and C (2)
        // together are too large, but the smaller is C, an inner node: it goes too. A's
        // children are leaves and need no sweep.
        let t = model(&bvh, &p(6));
        assert_eq!(t.large_sweeps, 4);
        assert_eq!(t.sweep_write_bytes, (10 + 7 + 2) * 32);
        assert_eq!(t.sweep_read_bytes, (2 * 17 + 10 + 7 + 2) * 32);
        assert_eq!(
            t.total_bytes(),
            t.sweep_read_bytes + t.sweep_write_bytes + bvh_bytes
        );
        // FLOPs: 4 sweeps over 17 + 10 + 7 + 2 primitives.
        assert_eq!(
            t.flops,
            36 * SweepFlops::PER_PRIM + 4 * SweepFlops::per_sweep(4)
        );
    }

    #[test]
    fn flop_constants() {
        // 3 + 3 centroid, 3 + 3 bin indices, 3 x 6 bin-box min/max, 1 partition compare,
        // 6 centroid-bound min/max.
        assert_eq!(SweepFlops::PER_PRIM, 37);
        // 16 bins: 6 + 3 axes x 15 planes x 32.
        assert_eq!(SweepFlops::per_sweep(16), 1446);
    }

    /// Builds the scene's binned SAH tree and runs the model with the \[P2\] rule and with
    /// the two fixed thresholds; `None` when the shared scenes are absent.
    fn scene_traffic(file: &str) -> Option<[BinnedSahHwTraffic; 3]> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/scenes")
            .join(file);
        if !path.is_file() {
            println!("skipping: {} not found", path.display());
            return None;
        }
        let s = scene::open(path.to_str()?, &Default::default()).expect("scene");
        let m = s.mesh_at(0.0).expect("mesh");
        let boxes = bvh::indexed_triangle_aabbs(&m.positions, &m.triangles).expect("boxes");
        let tree = BinnedSahBuilder::default().build(&boxes).expect("build");
        let with = |rule| {
            model(
                &tree,
                &BinnedSahHwParams {
                    rule,
                    ..Default::default()
                },
            )
        };
        Some([
            with(LargeSweepRule::SmallerChild),
            with(LargeSweepRule::FixedThreshold(8192)),
            with(LargeSweepRule::FixedThreshold(4096)),
        ])
    }

    /// Checks one scene against \[P2\]'s printed traffic (MB).
    ///
    /// What must hold exactly is \[P2\] §6.1's ordering: the smaller-child rule lies
    /// between a fixed 8,192 threshold (too low) and a fixed 4,096 threshold (too high).
    /// The magnitude does not reproduce \[P2\]'s figures: on these scenes the model gives
    /// 1.10x (Bunny), 1.24x (Crytek), 1.55x (Conference; 1.61x \[DFM13\]'s own 120 MB) and
    /// 1.22x (Dragon) the printed figures, always above them. The sweep sizes come from our binned SAH tree, and SAH
    /// trees peel small groups off large nodes, so the number of levels that stay in DRAM
    /// depends on the builder's split choices (Conference, with large flat walls among
    /// small furniture, is the most unbalanced); \[P2\] does not describe its software
    /// builder beyond "binned SAH". The bound below (0.9x to 1.65x) is not a validation: it
    /// records today's disagreement so that a change that moves the model further away
    /// fails.
    fn check(file: &str, printed_mb: &[f64]) {
        let Some([rule, fixed_8k, fixed_4k]) = scene_traffic(file) else {
            return;
        };
        let mb = rule.total_bytes() as f64 / 1e6;
        println!(
            "{file}: {mb:.1} MB (printed {printed_mb:?}; fixed 8192 {:.1}, fixed 4096 {:.1}), {} large sweeps, {:.2} GFLOP",
            fixed_8k.total_bytes() as f64 / 1e6,
            fixed_4k.total_bytes() as f64 / 1e6,
            rule.large_sweeps,
            rule.flops as f64 / 1e9
        );
        assert!(fixed_8k.total_bytes() <= rule.total_bytes());
        assert!(rule.total_bytes() <= fixed_4k.total_bytes());
        assert!(fixed_8k.total_bytes() < fixed_4k.total_bytes());
        for &want in printed_mb {
            let ratio = mb / want;
            assert!(
                (0.9..=1.65).contains(&ratio),
                "{file}: {mb:.1} MB vs printed {want} MB"
            );
        }
    }

    /// The printed figures for scene `name`: its Table VI binned SAH traffic, and Table
    /// II's traffic reported by [DFM13] where the scene is there.
    fn printed(name: &str) -> Vec<f64> {
        let mut v = vec![crate::thesis::p2_scene(name).unwrap().traffic_mb[1]];
        v.extend(
            crate::thesis::P2_TABLE_II
                .iter()
                .filter(|t| t.0 == name)
                .map(|t| t.1),
        );
        v
    }

    #[test]
    fn p2_table_vi_bunny() {
        check("bunny.ply", &printed("bunny"));
    }

    #[test]
    fn p2_table_vi_crytek() {
        check("crytek-sponza.ply", &printed("crytek-sponza"));
    }

    #[test]
    fn p2_tables_ii_and_vi_conference() {
        // Table II: [DFM13] reported 120 MB, [P2]'s model 125 MB (Table VI: 125).
        assert_eq!(printed("conference"), vec![125.0, 120.0]);
        check("conference.ply", &printed("conference"));
    }

    #[test]
    fn p2_tables_ii_and_vi_dragon() {
        // Table II: [DFM13] reported 380 MB, [P2]'s model 379 MB (Table VI: 379).
        assert_eq!(printed("dragon"), vec![379.0, 380.0]);
        check("dragon.ply", &printed("dragon"));
    }
}
