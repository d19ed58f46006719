//! Reinsertion: an optimizer pass over any [`Bvh2`] that removes subtrees and reinserts them
//! where they cost least in SAH.
//!
//! The move is Meister and Bittner's ("Parallel Reinsertion for Bounding Volume Hierarchy
//! Optimization", Computer Graphics Forum 37(2), 2018): a node `N` (a subtree) is cut
//! from its parent `P`, whose other child `S` takes `P`'s place, and `P` is reused to
//! insert `N` as the sibling of another node `X`. Here the moves are applied one at a time
//! (sequentially, as in the insertion-based optimization of Bittner, Hapala and Havran,
//! "Fast Insertion-Based Optimization of Bounding Volume Hierarchies", CGF 32(1), 2013,
//! not Meister and Bittner's parallel conflict resolution), and the best `X` is found by
//! Bittner et al.'s branch and bound from the root: inserting `N` beside `X` costs the
//! area of `X ∪ N` (the reused node) plus the growth of every ancestor of `X`, and a
//! subtree is skipped when that growth plus `A(N)` already reaches the best cost found.
//!
//! Leaves of the input (which may hold several primitives) are atomic, the node count does
//! not change and the scene box does not either, so the SAH changes only through the sum of
//! the inner nodes' areas, which each accepted move lowers by a relative margin
//! ([`crate::MIN_GAIN`]); a move that would not gain is undone exactly (the same boxes, by
//! the same unions). So the SAH never increases.
//!
//! Which nodes: each pass takes the [`ReinsertConfig::batch`] share of the nodes that have
//! not yet been found settled (a node whose best position was its own) with the largest
//! inefficiency, largest first: Bittner et al.'s product of three measures (the area, the
//! area over the smaller child's and over the children's mean) taken at the node's parent,
//! so a large parent over two small, far-apart children marks both children. Passes
//! repeat until one lowers the SAH by less than [`ReinsertConfig::min_gain`] or
//! [`ReinsertConfig::max_passes`] have run. Then subtrees are collapsed into leaves of up
//! to `max_leaf_size` primitives where the SAH says so (ATRBVH's collapse), and the tree is
//! written in depth-first preorder. Deterministic (one thread), whatever the pool.

use crate::atrbvh::{optimize_checked, AtrbvhConfig, MIN_GAIN};
use crate::bvh2::Bvh2;
use crate::error::{check_input, in_pool, BuildError};
use crate::node::{ChildRef, Node};
use crate::sah::SahParams;
use crate::validate::validate;
use geom::Aabb;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Configuration of the reinsertion optimizer.
#[derive(Clone, Debug, PartialEq)]
pub struct ReinsertConfig {
    /// Share of the nodes (0 < batch <= 1) reinserted per pass, largest area first.
    pub batch: f64,
    /// Most passes.
    pub max_passes: usize,
    /// A pass that lowers the SAH by less than this fraction ends the optimization.
    pub min_gain: f64,
    /// Largest leaf the final SAH leaf collapse may create (0 or 1: no collapsing).
    pub max_leaf_size: u32,
    /// SAH weights of the leaf collapse (the moves' gain does not depend on them).
    pub sah: SahParams,
    /// Worker threads of the final collapse and layout: 0 uses the current rayon pool.
    pub threads: usize,
}

impl Default for ReinsertConfig {
    fn default() -> Self {
        Self {
            batch: 0.02,
            max_passes: 8,
            min_gain: 1e-3,
            max_leaf_size: 8,
            sah: SahParams::THESIS,
            threads: 0,
        }
    }
}

impl ReinsertConfig {
    fn check(&self) -> Result<(), BuildError> {
        if !(self.batch > 0.0 && self.batch <= 1.0) {
            return Err(BuildError::InvalidConfig(format!(
                "reinsertion batch {} is outside (0, 1]",
                self.batch
            )));
        }
        if !(self.min_gain.is_finite() && self.min_gain >= 0.0) {
            return Err(BuildError::InvalidConfig(format!(
                "reinsertion min_gain {} must be finite and non-negative",
                self.min_gain
            )));
        }
        self.sah.check("reinsertion")
    }
}

/// What a reinsertion run did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReinsertWork {
    /// Passes run.
    pub passes: u32,
    /// Nodes removed and searched for.
    pub tried: u64,
    /// Moves kept (the rest went back where they were).
    pub moved: u64,
}

/// Optimizes `bvh` (any valid tree over `prims`) in place by reinsertion.
///
/// The tree is validated first (`prims` must be the boxes it was built over); an invalid
/// tree or configuration is an error and leaves `bvh` untouched. The SAH never increases.
pub fn reinsert(
    bvh: &mut Bvh2,
    prims: &[Aabb],
    cfg: &ReinsertConfig,
) -> Result<ReinsertWork, BuildError> {
    cfg.check()?;
    check_input(prims)?;
    validate(bvh, prims, u32::MAX).map_err(|e| {
        BuildError::InvalidConfig(format!("reinsertion input tree is invalid: {e}"))
    })?;
    in_pool(cfg.threads, || reinsert_checked(bvh, cfg))
}

/// [`reinsert`] on a tree the caller knows to be valid.
pub(crate) fn reinsert_checked(bvh: &mut Bvh2, cfg: &ReinsertConfig) -> ReinsertWork {
    let mut work = ReinsertWork::default();
    let Some(mut t) = Tree::from_bvh(bvh) else {
        return work; // empty or one-leaf tree
    };
    let mut settled = vec![false; t.bbox.len()];
    let mut heap = BinaryHeap::new();
    let leaf_cost: f64 = t
        .leaf
        .iter()
        .enumerate()
        .map(|(k, l)| {
            area(&t.bbox[t.inner + k]) as f64 * (cfg.sah.c_leaf + cfg.sah.c_tri * l.1 as f32) as f64
        })
        .sum();
    let ci = cfg.sah.c_inner as f64;
    for _ in 0..cfg.max_passes {
        let before = t.inner_area();
        // Candidates: nodes below the root's children, not settled, largest area first.
        let mut cand: Vec<(f64, u32)> = (0..t.bbox.len() as u32)
            .filter(|&x| {
                let p = t.parent[x as usize];
                !settled[x as usize] && p != NONE && t.parent[p as usize] != NONE
            })
            .map(|x| (t.priority(x), x))
            .collect();
        if cand.is_empty() {
            break;
        }
        let k = ((t.bbox.len() as f64 * cfg.batch).ceil() as usize).clamp(1, cand.len());
        let by = |a: &(f64, u32), b: &(f64, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        if k < cand.len() {
            cand.select_nth_unstable_by(k, by);
            cand.truncate(k);
        }
        cand.sort_unstable_by(by);
        for &(_, x) in &cand {
            work.tried += 1;
            // A node may have become a root child through earlier moves of this pass.
            let p = t.parent[x as usize];
            if p == NONE || t.parent[p as usize] == NONE {
                continue;
            }
            if t.move_node(x, &mut heap) {
                work.moved += 1;
            } else {
                settled[x as usize] = true;
            }
        }
        work.passes += 1;
        let after = t.inner_area();
        let total = ci * before + leaf_cost;
        if total.is_nan() || total <= 0.0 || ci * (before - after) < cfg.min_gain * total {
            break;
        }
    }
    *bvh = t.into_bvh(bvh);
    if cfg.max_leaf_size > 1 {
        let c = AtrbvhConfig {
            iterations: 0,
            max_leaf_size: cfg.max_leaf_size,
            sah: cfg.sah,
            threads: 0,
            ..Default::default()
        };
        optimize_checked(bvh, &c);
    }
    work
}

/// No node (the root's parent).
const NONE: u32 = u32::MAX;

/// Half area, NaN (an overflowing area) mapped to infinity.
#[inline]
fn area(b: &Aabb) -> f32 {
    let a = b.half_area();
    if a.is_nan() {
        f32::INFINITY
    } else {
        a
    }
}

/// The working tree: inner nodes `0..inner`, then the input's leaves.
struct Tree {
    inner: usize,
    root: u32,
    parent: Vec<u32>,
    /// Children of the inner nodes.
    kids: Vec<[u32; 2]>,
    /// Box of every node, leaves included.
    bbox: Vec<Aabb>,
    /// Leaf-table range of every leaf.
    leaf: Vec<(u32, u32)>,
}

/// A search entry: the induced cost of inserting below `node` (min-heap on it).
#[derive(PartialEq)]
struct Entry(f64, u32);

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}

impl Tree {
    /// The working form of a valid tree; `None` when the root has an empty child.
    fn from_bvh(bvh: &Bvh2) -> Option<Tree> {
        let root = bvh.nodes.first()?;
        if root.children.iter().any(ChildRef::is_empty) {
            return None;
        }
        let inner = bvh.nodes.len();
        let mut t = Tree {
            inner,
            root: 0,
            parent: vec![NONE; inner],
            kids: vec![[0; 2]; inner],
            bbox: vec![Aabb::EMPTY; inner],
            leaf: Vec::with_capacity(inner + 1),
        };
        t.bbox[0] = bvh.bounds;
        for (i, n) in bvh.nodes.iter().enumerate() {
            for s in 0..2 {
                let c = n.children[s];
                let id = if c.is_leaf() {
                    t.leaf.push((c.index, c.count));
                    t.parent.push(i as u32);
                    t.bbox.push(n.child_aabb(s));
                    (inner + t.leaf.len() - 1) as u32
                } else {
                    t.parent[c.index as usize] = i as u32;
                    t.bbox[c.index as usize] = n.child_aabb(s);
                    c.index
                };
                t.kids[i][s] = id;
            }
        }
        Some(t)
    }

    /// How badly node `x` seems placed: Bittner et al.'s combined inefficiency measure
    /// `M_area M_min M_sum` of its parent `P` (`A(P)`, `A(P) / min A(child)` and
    /// `A(P) / mean A(child)`, multiplied): large when `P` is large and much larger than
    /// its children, i.e. when `x` and its sibling are far apart.
    fn priority(&self, x: u32) -> f64 {
        let p = self.parent[x as usize] as usize;
        let [a, b] =
            self.kids[p].map(|c| (area(&self.bbox[c as usize]) as f64).max(f64::MIN_POSITIVE));
        let ap = area(&self.bbox[p]) as f64;
        ap * (ap / a.min(b)) * (ap / (0.5 * (a + b)))
    }

    fn inner_area(&self) -> f64 {
        self.bbox[..self.inner].iter().map(|b| area(b) as f64).sum()
    }

    /// Recomputes the boxes from `a` up to the root, stopping where a box is unchanged;
    /// returns the total area lost by the recomputed boxes.
    fn refit_up(&mut self, mut a: u32) -> f64 {
        let mut lost = 0.0;
        while a != NONE {
            let [x, y] = self.kids[a as usize];
            let nb = self.bbox[x as usize].union(self.bbox[y as usize]);
            let old = self.bbox[a as usize];
            if nb == old {
                break;
            }
            lost += area(&old) as f64 - area(&nb) as f64;
            self.bbox[a as usize] = nb;
            a = self.parent[a as usize];
        }
        lost
    }

    /// Replaces child `old` of inner node `g` (or the root when `g` is `NONE`) by `new`.
    fn replace_child(&mut self, g: u32, old: u32, new: u32) {
        if g == NONE {
            self.root = new;
        } else {
            let k = &mut self.kids[g as usize];
            let s = usize::from(k[1] == old);
            k[s] = new;
        }
        self.parent[new as usize] = g;
    }

    /// Removes node `n` (whose parent is not the root) and reinserts it where the inner
    /// area sum is least; keeps the move when it gains, else restores the tree. Returns
    /// whether it moved.
    fn move_node(&mut self, n: u32, heap: &mut BinaryHeap<Entry>) -> bool {
        let p = self.parent[n as usize];
        let g = self.parent[p as usize];
        let slot = usize::from(self.kids[p as usize][1] == n);
        let s = self.kids[p as usize][1 - slot];
        // Remove: the sibling takes the parent's place; `p` is free.
        let mut gain = area(&self.bbox[p as usize]) as f64;
        self.replace_child(g, p, s);
        gain += self.refit_up(g);
        // Branch and bound from the root for the cheapest sibling `x`.
        let nb = self.bbox[n as usize];
        let an = area(&nb) as f64;
        let (mut best, mut best_x) = (f64::INFINITY, s);
        heap.clear();
        heap.push(Entry(0.0, self.root));
        while let Some(Entry(ind, x)) = heap.pop() {
            if ind + an >= best {
                break;
            }
            let bx = self.bbox[x as usize];
            let grown = area(&bx.union(nb)) as f64;
            let cost = ind + grown;
            if cost < best {
                best = cost;
                best_x = x;
            }
            if (x as usize) < self.inner {
                let below = cost - area(&bx) as f64;
                if below + an < best {
                    for c in self.kids[x as usize] {
                        heap.push(Entry(below, c));
                    }
                }
            }
        }
        let moved = best < gain * (1.0 - MIN_GAIN);
        let (x, order) = if moved {
            (best_x, [best_x, n])
        } else {
            let mut o = [s, s];
            o[slot] = n;
            (s, o)
        };
        // Insert `n` beside `x`, reusing `p`.
        let gx = self.parent[x as usize];
        self.replace_child(gx, x, p);
        self.kids[p as usize] = order;
        self.parent[x as usize] = p;
        self.parent[n as usize] = p;
        self.bbox[p as usize] = self.bbox[x as usize].union(nb);
        self.refit_up(gx);
        moved
    }

    /// The tree as a [`Bvh2`] in depth-first preorder, with the leaf table in the same
    /// order (`old` supplies the leaves' primitive indices and the scene box).
    fn into_bvh(self, old: &Bvh2) -> Bvh2 {
        let mut nodes: Vec<Node> = Vec::with_capacity(self.inner);
        let mut prims: Vec<u32> = Vec::with_capacity(old.prim_indices.len());
        crate::layout::preorder(self.root, &mut nodes, |i, nodes, kids| {
            let k = self.kids[i as usize];
            let mut refs = [ChildRef::EMPTY; 2];
            for s in 0..2 {
                let c = k[s] as usize;
                if c >= self.inner {
                    let (f, cnt) = self.leaf[c - self.inner];
                    let first = prims.len() as u32;
                    prims.extend_from_slice(&old.prim_indices[f as usize..(f + cnt) as usize]);
                    refs[s] = ChildRef::leaf(first, cnt);
                } else {
                    kids.push((s, k[s]));
                }
            }
            nodes.push(Node::new(
                &self.bbox[k[0] as usize],
                refs[0],
                &self.bbox[k[1] as usize],
                refs[1],
            ));
        });
        Bvh2 {
            nodes,
            prim_indices: prims,
            bounds: old.bounds,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use crate::{HlbvhBuilder, LbvhBuilder, PlocBuilder, SweepSahBuilder};
    use geom::Vec3;
    use proptest::prelude::*;

    fn cfg(leaf: u32) -> ReinsertConfig {
        ReinsertConfig {
            max_leaf_size: leaf,
            ..Default::default()
        }
    }

    fn optimized(name: &str, t: &Bvh2, prims: &[Aabb], c: &ReinsertConfig) -> Bvh2 {
        let mut o = t.clone();
        reinsert(&mut o, prims, c).unwrap();
        let leaf = t.stats().max_leaf_size.max(c.max_leaf_size).max(1);
        assert_valid(name, &o, prims, leaf);
        assert!(
            o.sah().is_nan() || o.sah() <= t.sah() * (1.0 + 1e-12),
            "{name}: SAH {} -> {}",
            t.sah(),
            o.sah()
        );
        o
    }

    /// A deliberately bad tree: the primitives of a line in a random order, built as a
    /// Morton tree over shuffled positions (a balanced tree over unrelated neighbours).
    fn bad_tree(n: usize) -> (Bvh2, Vec<Aabb>) {
        let xs: Vec<f32> = (0..n).map(|i| i as f32 * 2.0).collect();
        let prims = cubes_at(&xs);
        // Balanced tree over primitive indices in a scrambled order.
        let mut rng = crate::testutil::Rng::new(5);
        let mut order: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            let j = (rng.f32() * (i + 1) as f32) as usize % (i + 1);
            order.swap(i, j);
        }
        fn rec(o: &[u32], prims: &[Aabb], nodes: &mut Vec<Node>, base: u32) -> (ChildRef, Aabb) {
            if o.len() == 1 {
                return (ChildRef::leaf(base, 1), prims[o[0] as usize]);
            }
            let at = nodes.len();
            nodes.push(Node::EMPTY);
            let m = o.len() / 2;
            let (a, ab) = rec(&o[..m], prims, nodes, base);
            let (b, bb) = rec(&o[m..], prims, nodes, base + m as u32);
            nodes[at] = Node::new(&ab, a, &bb, b);
            (ChildRef::inner(at as u32), ab.union(bb))
        }
        let mut nodes = Vec::new();
        let (_, bounds) = rec(&order, &prims, &mut nodes, 0);
        let t = Bvh2 {
            nodes,
            prim_indices: order,
            bounds,
        };
        assert_valid("bad", &t, &prims, 1);
        (t, prims)
    }

    #[test]
    fn a_bad_tree_gets_much_better() {
        let (t, prims) = bad_tree(512);
        let c = ReinsertConfig {
            batch: 1.0,
            max_passes: 100,
            min_gain: 0.0,
            max_leaf_size: 1,
            ..Default::default()
        };
        let o = optimized("bad", &t, &prims, &c);
        let sweep = SweepSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        assert!(o.sah() < 0.5 * t.sah(), "{} -> {}", t.sah(), o.sah());
        // Measured: 330.7 -> 11.40 against the sweep's 11.26.
        assert!(o.sah_vs(&sweep) < 1.05, "{} x sweep", o.sah_vs(&sweep));
    }

    #[test]
    fn builders_trees_never_get_worse() {
        for spec in ["proc:cloth?n=5000", "proc:soup?n=20000"] {
            let prims = proc_scene(spec);
            let trees = [
                ("lbvh", LbvhBuilder::default().build(&prims).unwrap()),
                ("hlbvh", HlbvhBuilder::default().build(&prims).unwrap()),
                ("ploc", PlocBuilder::default().build(&prims).unwrap()),
                ("sweep", SweepSahBuilder::default().build(&prims).unwrap()),
            ];
            for (name, t) in &trees {
                let o = optimized(name, t, &prims, &cfg(8));
                // Measured: every tree of the soup gains (0.6-4%); on the cloth only
                // PLOC's (the grid's Morton and SAH trees are reinsertion optima).
                if spec.contains("soup") || *name == "ploc" {
                    assert!(
                        o.sah() < t.sah(),
                        "{spec} {name}: {} -> {}",
                        t.sah(),
                        o.sah()
                    );
                }
                // No collapse: the leaves stay as they were.
                let o1 = optimized(name, t, &prims, &cfg(1));
                assert_eq!(o1.stats().leaves, t.stats().leaves);
            }
        }
    }

    #[test]
    fn adversarial_and_tiny_trees() {
        for (name, prims) in adversarial() {
            let t = LbvhBuilder::default().build(&prims).unwrap();
            optimized(name, &t, &prims, &cfg(1));
            optimized(name, &t, &prims, &cfg(4));
        }
        let mut e = Bvh2::empty();
        assert_eq!(
            reinsert(&mut e, &[], &cfg(8)).unwrap(),
            ReinsertWork::default()
        );
        assert_eq!(e, Bvh2::empty());
    }

    #[test]
    fn bad_configs_and_trees_are_errors_and_leave_the_tree_alone() {
        let prims = soup(100, 1.0, 3);
        let t = LbvhBuilder::default().build(&prims).unwrap();
        for bad in [
            ReinsertConfig {
                batch: 0.0,
                ..Default::default()
            },
            ReinsertConfig {
                batch: 1.5,
                ..Default::default()
            },
            ReinsertConfig {
                min_gain: f64::NAN,
                ..Default::default()
            },
        ] {
            let mut o = t.clone();
            assert!(matches!(
                reinsert(&mut o, &prims, &bad),
                Err(BuildError::InvalidConfig(_))
            ));
            assert_eq!(o, t);
        }
        let mut o = t.clone();
        let other = soup(100, 1.0, 4);
        assert!(reinsert(&mut o, &other, &cfg(8)).is_err());
        assert_eq!(o, t);
        let nan = [Aabb::new(Vec3::ZERO, Vec3::splat(f32::NAN))];
        assert!(reinsert(&mut o, &nan, &cfg(8)).is_err());
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = soup(20_000, 1.0, 9);
        let t = HlbvhBuilder::default().build(&prims).unwrap();
        let run = |threads| {
            let mut o = t.clone();
            reinsert(
                &mut o,
                &prims,
                &ReinsertConfig {
                    threads,
                    ..Default::default()
                },
            )
            .unwrap();
            o
        };
        assert_eq!(run(1), run(2));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn random_trees_stay_valid_and_never_worse(n in 0usize..800, size in 0.0f32..20.0,
                                                   seed: u64, leaf in 1u32..6) {
            let prims = soup(n, size, seed);
            let t = HlbvhBuilder { max_leaf_size: leaf, ..Default::default() }.build(&prims).unwrap();
            let mut o = t.clone();
            reinsert(&mut o, &prims, &ReinsertConfig { max_leaf_size: leaf, batch: 0.2, ..Default::default() }).unwrap();
            prop_assert_eq!(validate(&o, &prims, leaf), Ok(()));
            prop_assert!(o.sah() <= t.sah() * (1.0 + 1e-12));
        }
    }
}
