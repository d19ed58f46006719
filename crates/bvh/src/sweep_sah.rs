//! Full sweep SAH builder: the quality reference the thesis normalizes SAH costs to
//! (\[P2\] §6.2, "SAH costs are normalized to a full SAH sweep").
//!
//! Top-down: at every node, for each axis, the primitives sorted by centroid are swept once
//! from the right (areas of all right sets) and once from the left, evaluating the SAH of
//! every split between consecutive primitives. The primitive indices are sorted once per
//! axis up front; after choosing a split, the two other sorted lists are partitioned stably
//! (with a scratch array and a per-primitive side flag), so every level costs O(n) and the
//! whole build O(n log n). A node becomes a leaf when it has at most `min_leaf_size`
//! primitives, or when its leaf cost is not worse than the best split and it fits in
//! `max_leaf_size`. Subtrees of at least [`PARALLEL_MIN_PRIMS`](crate::PARALLEL_MIN_PRIMS)
//! primitives are built with `rayon::join`; the result does not depend on the thread count.

use crate::bvh2::Bvh2;
use crate::error::{check_input, in_pool, BuildError};
use crate::frag::Frag;
use crate::node::{ChildRef, Node};
use crate::sah::SahParams;
use crate::split::{left_pass, right_pass, Unit};
use crate::{centroid, ordered_bits, MAX_SAH_DEPTH, PARALLEL_MIN_PRIMS};
use geom::{Aabb, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// Configuration of the full sweep SAH builder.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSahBuilder {
    /// Largest leaf; nodes above it are always split (>= 1).
    pub max_leaf_size: u32,
    /// Nodes of at most this many primitives become leaves without evaluating splits.
    pub min_leaf_size: u32,
    /// SAH weights used to choose splits (the thesis's by default).
    pub sah: SahParams,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

impl Default for SweepSahBuilder {
    fn default() -> Self {
        Self {
            max_leaf_size: 8,
            min_leaf_size: 1,
            sah: SahParams::THESIS,
            threads: 0,
        }
    }
}

/// Read-only data shared by all recursion branches.
struct Ctx<'a> {
    aabbs: &'a [Aabb],
    cent: &'a [Vec3],
    goes_left: &'a [AtomicBool],
    cfg: &'a SweepSahBuilder,
}

/// The mutable slices one subtree owns: its range of the three sorted lists and scratch.
struct Work<'a> {
    lists: [&'a mut [u32]; 3],
    areas: &'a mut [f32],
    tmp: &'a mut [u32],
    first: usize,
}

impl<'a> Work<'a> {
    fn len(&self) -> usize {
        self.areas.len()
    }

    fn split_at(self, k: usize) -> (Work<'a>, Work<'a>) {
        let [l0, l1, l2] = self.lists;
        let (a0, b0) = l0.split_at_mut(k);
        let (a1, b1) = l1.split_at_mut(k);
        let (a2, b2) = l2.split_at_mut(k);
        let (aa, ba) = self.areas.split_at_mut(k);
        let (at, bt) = self.tmp.split_at_mut(k);
        (
            Work {
                lists: [a0, a1, a2],
                areas: aa,
                tmp: at,
                first: self.first,
            },
            Work {
                lists: [b0, b1, b2],
                areas: ba,
                tmp: bt,
                first: self.first + k,
            },
        )
    }
}

impl SweepSahBuilder {
    /// Builds a tree over the primitive boxes `aabbs`.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        if self.max_leaf_size == 0 || self.min_leaf_size > self.max_leaf_size {
            return Err(BuildError::InvalidConfig(format!(
                "sweep SAH needs 1 <= max_leaf_size and min_leaf_size <= max_leaf_size, got {} and {}",
                self.max_leaf_size, self.min_leaf_size
            )));
        }
        check_input(aabbs)?;
        if aabbs.is_empty() {
            return Ok(Bvh2::empty());
        }
        in_pool(self.threads, || self.build_checked(aabbs))
    }

    fn build_checked(&self, aabbs: &[Aabb]) -> Bvh2 {
        let n = aabbs.len();
        let cent: Vec<Vec3> = aabbs.par_iter().map(centroid).collect();
        // Sort keys: centroid coordinate then primitive index, a total order, so the
        // (unstable, parallel) sort is deterministic.
        let sorted = |axis: usize| -> Vec<u32> {
            let mut keys: Vec<u64> = (0..n)
                .map(|i| ((ordered_bits(cent[i][axis]) as u64) << 32) | i as u64)
                .collect();
            keys.par_sort_unstable();
            keys.into_iter().map(|k| k as u32).collect()
        };
        let mut lists = [sorted(0), sorted(1), sorted(2)];
        let mut areas = vec![0f32; n];
        let mut tmp = vec![0u32; n];
        let goes_left: Vec<AtomicBool> = (0..n).map(|_| AtomicBool::new(false)).collect();
        let ctx = Ctx {
            aabbs,
            cent: &cent,
            goes_left: &goes_left,
            cfg: self,
        };
        let [l0, l1, l2] = &mut lists;
        let work = Work {
            lists: [l0, l1, l2],
            areas: &mut areas,
            tmp: &mut tmp,
            first: 0,
        };
        let mut frag = Frag::default();
        let (root, bounds) = build_rec(&ctx, work, 0, &mut frag);
        let [prim_indices, y, z] = lists;
        // The scratch arrays go before the fragments are copied into the final node array.
        drop((y, z, cent, areas, tmp, goes_left));
        Bvh2::from_root(root, bounds, frag.flatten(), prim_indices)
    }
}

/// The chosen split of a node: axis, position in that axis's sorted list.
struct Split {
    axis: usize,
    pos: usize,
}

/// Builds the subtree over `w`; returns its child reference (local to `frag`) and its box.
fn build_rec(ctx: &Ctx, w: Work, depth: u32, frag: &mut Frag) -> (ChildRef, Aabb) {
    let n = w.len();
    let cfg = ctx.cfg;
    let leaf = ChildRef::leaf(w.first as u32, n as u32);
    let mut w = w;
    let (split, bounds) = if n <= cfg.min_leaf_size.max(1) as usize {
        let b = w.lists[0]
            .iter()
            .fold(Aabb::EMPTY, |b, &p| b.union(ctx.aabbs[p as usize]));
        return (leaf, b);
    } else if depth >= MAX_SAH_DEPTH {
        median_split(ctx, &w)
    } else {
        let (best, bounds) = sweep(ctx, &mut w);
        let p = &cfg.sah;
        let leaf_cost = bounds.half_area() * (p.c_leaf + p.c_tri * n as f32);
        match best {
            Some((cost, _)) if n <= cfg.max_leaf_size as usize && leaf_cost <= cost => {
                return (leaf, bounds)
            }
            None if n <= cfg.max_leaf_size as usize => return (leaf, bounds),
            Some((_, s)) => (s, bounds),
            None => median_split(ctx, &w),
        }
    };
    let w = partition(ctx, w, &split);
    let (lw, rw) = w.split_at(split.pos);
    let at = frag.nodes.len();
    frag.nodes.push(Node::EMPTY);
    let ((lc, lb), (rc, rb)) = if n >= PARALLEL_MIN_PRIMS && rayon::current_num_threads() > 1 {
        let ((lc, lb, lf), (rc, rb, rf)) = rayon::join(
            || {
                let mut f = Frag::default();
                let (c, b) = build_rec(ctx, lw, depth + 1, &mut f);
                (c, b, f)
            },
            || {
                let mut f = Frag::default();
                let (c, b) = build_rec(ctx, rw, depth + 1, &mut f);
                (c, b, f)
            },
        );
        ((frag.adopt(lc, lf), lb), (frag.adopt(rc, rf), rb))
    } else {
        let l = build_rec(ctx, lw, depth + 1, frag);
        let r = build_rec(ctx, rw, depth + 1, frag);
        (l, r)
    };
    frag.nodes[at] = Node::new(&lb, lc, &rb, rc);
    debug_assert!(bounds.contains(&lb.union(rb)));
    (ChildRef::inner(at as u32), bounds)
}

/// Evaluates every split on every axis; returns the cheapest (cost, split), if any has a
/// finite cost, and the node's box.
fn sweep(ctx: &Ctx, w: &mut Work) -> (Option<(f32, Split)>, Aabb) {
    let n = w.len();
    let p = &ctx.cfg.sah;
    let mut best: Option<(f32, Split)> = None;
    let mut bounds = Aabb::EMPTY;
    let areas = &mut *w.areas;
    for (axis, list) in w.lists.iter().enumerate() {
        // Right pass: areas[i] = area of the box of list[i..], for i in 1..n; the node's
        // box is needed to price the first split, so the engine's passes run separately.
        let item = |i: usize| (ctx.aabbs[list[i] as usize], 1);
        let right = &mut Unit(&mut *areas, n);
        let rbox = right_pass(n, item, right);
        bounds = rbox.union(ctx.aabbs[list[0] as usize]);
        let base = p.c_inner * bounds.half_area();
        // Left pass: evaluate the split before list[i].
        left_pass(n, item, &*right, |i, lbox, _, ra, _| {
            let nl = i as f32;
            let nr = (n - i) as f32;
            let cost = base
                + lbox.half_area() * (p.c_leaf + p.c_tri * nl)
                + ra * (p.c_leaf + p.c_tri * nr);
            // Strictly smaller wins; an exact tie goes to the more balanced split (coincident
            // primitives), then to the earlier axis and position (determinism).
            let better = |(c, s): &(f32, Split)| {
                cost < *c || (cost == *c && (2 * i).abs_diff(n) < (2 * s.pos).abs_diff(n))
            };
            if cost.is_finite() && best.as_ref().is_none_or(better) {
                best = Some((cost, Split { axis, pos: i }));
            }
        });
    }
    (best, bounds)
}

/// Object-median split on the axis of largest centroid extent (halves the node), and the
/// node's box.
fn median_split(ctx: &Ctx, w: &Work) -> (Split, Aabb) {
    let mut bounds = Aabb::EMPTY;
    let mut cbounds = Aabb::EMPTY;
    for &prim in w.lists[0].iter() {
        bounds = bounds.union(ctx.aabbs[prim as usize]);
        cbounds = cbounds.grow(ctx.cent[prim as usize]);
    }
    let split = Split {
        axis: cbounds.largest_axis(),
        pos: w.len() / 2,
    };
    (split, bounds)
}

/// Applies `split`: marks each primitive's side from the split axis's list, then
/// partitions the two other lists stably so that all three stay sorted on each side.
fn partition<'a>(ctx: &Ctx, w: Work<'a>, split: &Split) -> Work<'a> {
    let k = split.pos;
    for (i, &prim) in w.lists[split.axis].iter().enumerate() {
        ctx.goes_left[prim as usize].store(i < k, Ordering::Relaxed);
    }
    let Work {
        lists,
        areas,
        tmp,
        first,
    } = w;
    let mut lists = lists;
    for (axis, list) in lists.iter_mut().enumerate() {
        if axis == split.axis {
            continue;
        }
        let (mut l, mut r) = (0usize, 0usize);
        for i in 0..list.len() {
            let prim = list[i];
            if ctx.goes_left[prim as usize].load(Ordering::Relaxed) {
                list[l] = prim;
                l += 1;
            } else {
                tmp[r] = prim;
                r += 1;
            }
        }
        debug_assert_eq!(l, k);
        list[l..].copy_from_slice(&tmp[..r]);
    }
    Work {
        lists,
        areas,
        tmp,
        first,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use crate::validate;
    use proptest::prelude::*;

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for max_leaf in [1, 4, 8] {
            let b = SweepSahBuilder {
                max_leaf_size: max_leaf,
                ..Default::default()
            };
            for (name, prims) in adversarial() {
                let t = b.build(&prims).unwrap();
                assert_valid(name, &t, &prims, max_leaf);
                assert!(
                    t.stats().max_depth <= 130,
                    "{name}: depth {}",
                    t.stats().max_depth
                );
            }
        }
    }

    #[test]
    fn zero_one_and_two_primitives() {
        let b = SweepSahBuilder::default();
        let t = b.build(&[]).unwrap();
        assert_eq!(t, Bvh2::empty());
        validate(&t, &[], 8).unwrap();
        let one = cubes_at(&[0.0]);
        let t = b.build(&one).unwrap();
        assert_eq!(t.nodes.len(), 1);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        assert!(t.nodes[0].children[1].is_empty());
        assert_eq!(t.bounds, one[0]);
        let two = cubes_at(&[0.0, 10.0]);
        let t = b.build(&two).unwrap();
        assert_valid("two", &t, &two, 1);
        assert_eq!(t.nodes.len(), 1);
    }

    #[test]
    fn sah_of_known_configurations_matches_hand_computation() {
        let b = SweepSahBuilder::default();
        // Two cubes 10 apart: root [0,11]x[0,1]^2 has half area 23; splitting costs
        // 1.2*23 + 3 + 3 = 33.6 < 2*23 for a leaf. Normalized SAH = 1.2 + 6/23.
        let t = b.build(&cubes_at(&[0.0, 10.0])).unwrap();
        assert!((t.sah() - (1.2 + 6.0 / 23.0)).abs() < 1e-6, "{}", t.sah());
        // Two coincident cubes: a leaf (cost 2*3) beats a split (1.2*3 + 3 + 3): 1.2 + 2.
        let t = b.build(&cubes_at(&[0.0, 0.0])).unwrap();
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 2));
        assert!((t.sah() - 3.2).abs() < 1e-6);
        // Two pairs of touching cubes: root half area 25, pairs have half area 5 and stay
        // leaves (2*5 = 10 < 1.2*5 + 3 + 3). SAH = 1.2 + (5*2 + 5*2)/25 = 2.0.
        let four = cubes_at(&[0.0, 1.0, 10.0, 11.0]);
        let t = b.build(&four).unwrap();
        assert_eq!(t.nodes.len(), 1);
        assert!((t.sah() - 2.0).abs() < 1e-6, "{}", t.sah());
        let mut leaf0: Vec<u32> = t.prim_indices[..2].to_vec();
        leaf0.sort();
        assert_eq!(leaf0, vec![0, 1]);
        // With min_leaf_size = 4 the same input is one leaf: SAH = 1.2 + 4.
        let t = SweepSahBuilder {
            min_leaf_size: 4,
            ..Default::default()
        }
        .build(&four)
        .unwrap();
        assert!((t.sah() - 5.2).abs() < 1e-6);
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = soup(20_000, 2.0, 11);
        let b1 = SweepSahBuilder {
            threads: 1,
            ..Default::default()
        };
        let b4 = SweepSahBuilder {
            threads: 4,
            ..Default::default()
        };
        let t1 = b1.build(&prims).unwrap();
        assert_valid("soup", &t1, &prims, 8);
        assert_eq!(t1, b1.build(&prims).unwrap());
        assert_eq!(t1, b4.build(&prims).unwrap());
    }

    #[test]
    fn bad_inputs_and_configs_are_errors() {
        let b = SweepSahBuilder::default();
        let mut prims = cubes_at(&[0.0, 1.0, 2.0]);
        prims[1].max.y = f32::NAN;
        assert_eq!(b.build(&prims), Err(BuildError::NonFinite { index: 1 }));
        prims[1] = Aabb::new(Vec3::ONE, Vec3::ZERO);
        assert_eq!(b.build(&prims), Err(BuildError::InvertedBox { index: 1 }));
        let bad = SweepSahBuilder {
            max_leaf_size: 0,
            ..Default::default()
        };
        assert!(matches!(bad.build(&[]), Err(BuildError::InvalidConfig(_))));
    }

    #[test]
    fn procedural_scene_gives_valid_tree() {
        let prims = proc_scene("proc:cloth?n=5000");
        let t = SweepSahBuilder::default().build(&prims).unwrap();
        assert_valid("cloth", &t, &prims, 8);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn random_soups_give_valid_trees(n in 0usize..2000, size in 0.0f32..20.0, seed: u64, max_leaf in 1u32..10) {
            let prims = soup(n, size, seed);
            let t = SweepSahBuilder { max_leaf_size: max_leaf, ..Default::default() }.build(&prims).unwrap();
            prop_assert_eq!(validate(&t, &prims, max_leaf), Ok(()));
        }
    }
}
