//! PLOC: parallel locally-ordered clustering (Meister and Bittner, "Parallel Locally-Ordered
//! Clustering for Bounding Volume Hierarchy Construction", IEEE TVCG 24(3), 2018).
//!
//! 1. Every primitive is a cluster; the clusters are sorted by the Morton code of their
//!    centroid (the same codes and radix sort as LBVH and HLBVH, [`crate::morton_sort`]).
//! 2. Each iteration, every cluster `i` finds its nearest neighbour among the clusters at
//!    sorted positions `i - r ..= i + r` (`r` = [`PlocBuilder::radius`]), the distance
//!    being the surface area of the box of both. Two clusters that are each other's nearest
//!    neighbour are merged into a new inner node, which takes the lower position; the array
//!    is compacted (a prefix sum over the survivors) and the next iteration starts, until
//!    one cluster is left. Search, merge and compaction are parallel (rayon).
//! 3. The tree (one primitive per leaf) is written as a [`Bvh2`] in depth-first preorder,
//!    the subtrees of large nodes in parallel; then, when `max_leaf_size > 1`, subtrees are
//!    collapsed into leaves where the SAH says so, the same collapse as ATRBVH's (a leaf
//!    of `N` primitives costs `A (C_l + N C_t)`, as Karras and Aila's TRBVH and Meister and
//!    Bittner do after clustering).
//!
//! Ties: the distance is symmetric (the union is exact), and a cluster prefers, among
//! equal distances, the pair with the smaller hash of its two positions. That is one total
//! order on pairs, so the globally closest pair is always mutual and every iteration merges
//! at least one pair; the hash (rather than, say, the nearest position) keeps equal boxes
//! (coincident primitives) from forming a chain in which only one pair is mutual per
//! iteration, which would make the build quadratic.
//!
//! Determinism: every step is a pure function of the previous array, and the prefix sums
//! are over fixed chunks, so the tree is the same for any thread count.

use crate::atrbvh::{optimize_checked, AtrbvhConfig};
use crate::bvh2::Bvh2;
use crate::error::{check_input, in_pool, BuildError};
use crate::layout::Kids;
use crate::lbvh::MortonBits;
use crate::node::{zeroed_nodes, ChildRef, Node};
use crate::sah::SahParams;
use geom::{Aabb, MortonGrid, Vec4};
use rayon::prelude::*;

/// Largest search radius accepted: each cluster evaluates `2 r` distances per iteration.
pub const MAX_PLOC_RADIUS: usize = 256;

/// Configuration of the PLOC builder.
#[derive(Clone, Debug, PartialEq)]
pub struct PlocBuilder {
    /// Search radius `r` (1..=[`MAX_PLOC_RADIUS`]): each cluster looks for its nearest
    /// neighbour among the `r` clusters before and the `r` after it in Morton order.
    /// The radius is the paper's speed/quality knob; the default is 16 (measured against
    /// 1, 4 and 32 on the shared scenes in docs/builders.md).
    pub radius: usize,
    /// Morton code length of the initial order.
    pub bits: MortonBits,
    /// Largest leaf the SAH leaf collapse may create (1: one primitive per leaf).
    pub max_leaf_size: u32,
    /// SAH weights of the leaf collapse.
    pub sah: SahParams,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

impl Default for PlocBuilder {
    fn default() -> Self {
        Self {
            radius: 16,
            bits: MortonBits::Bits30,
            // The sweep SAH builder's default maximum, so SAH ratios compare like with like.
            max_leaf_size: 8,
            sah: SahParams::THESIS,
            threads: 0,
        }
    }
}

/// A cluster: its box (w lanes zero) and its node id (`< n`: the primitive at that sorted
/// position; `n + k`: inner node `k`).
#[derive(Clone, Copy, Debug)]
struct Cluster {
    min: Vec4,
    max: Vec4,
    id: u32,
}

impl Cluster {
    #[inline(always)]
    fn merged_area(&self, o: &Cluster) -> f32 {
        let e = self.max.max(o.max) - self.min.min(o.min);
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    fn aabb(&self) -> Aabb {
        Aabb::new(self.min.truncate(), self.max.truncate())
    }
}

/// Clusters per chunk of the parallel search and compaction.
const CHUNK: usize = 4096;

/// An iteration that merges fewer than one cluster in this many pairs neighbours instead
/// (the fallback for degenerate input; real meshes merge a fifth or more per iteration).
const MIN_MERGE_SHARE: usize = 64;

/// Per chunk of [`CHUNK`] clusters: (survivors, merges) for nearest neighbours `nn`.
fn merge_counts(nn: &[u32]) -> Vec<(usize, usize)> {
    (0..nn.len().div_ceil(CHUNK))
        .into_par_iter()
        .map(|k| {
            let (mut keep, mut merge) = (0, 0);
            for i in k * CHUNK..((k + 1) * CHUNK).min(nn.len()) {
                let j = nn[i] as usize;
                let mutual = nn[j] as usize == i;
                keep += usize::from(!mutual || i < j);
                merge += usize::from(mutual && i < j);
            }
            (keep, merge)
        })
        .collect()
}

/// Tie-break hash of the pair of positions `a < b` (splitmix64's finalizer).
#[inline]
fn pair_hash(a: usize, b: usize) -> u64 {
    let mut z = ((a as u64) << 32 | b as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Whether candidate `j` at distance `d` is a better neighbour for cluster `i` than the
/// current best `b` at `bd` (`usize::MAX`: none yet). One total order on pairs: the
/// distance, then the nearer position, then [`pair_hash`], then the lower position.
#[inline(always)]
fn better(i: usize, j: usize, d: f32, b: usize, bd: f32) -> bool {
    if b == usize::MAX || d < bd {
        return true;
    }
    if d > bd {
        return false;
    }
    let (dj, db) = (j.abs_diff(i), b.abs_diff(i));
    if dj != db {
        return dj < db;
    }
    let (hj, hb) = (pair_hash(i.min(j), i.max(j)), pair_hash(i.min(b), i.max(b)));
    if hj != hb {
        return hj < hb;
    }
    j < b
}

/// The distance of two clusters: the half area of their union, NaN (from overflowing
/// boxes) as infinity.
#[inline(always)]
fn distance(a: &Cluster, b: &Cluster) -> f32 {
    let d = a.merged_area(b);
    if d.is_nan() {
        f32::INFINITY
    } else {
        d
    }
}

/// Leaves under each inner node of a tree as PLOC writes one (leaf ids `0..n`, inner node
/// `k` has id `n + k` and children made before it), for [`crate::layout::preorder_sized`].
pub(crate) fn leaf_counts(children: &[[u32; 2]], n: usize) -> Vec<u32> {
    let mut leaves = vec![0u32; children.len()];
    for k in 0..children.len() {
        leaves[k] = children[k]
            .iter()
            .map(|&c| {
                if (c as usize) < n {
                    1
                } else {
                    leaves[c as usize - n]
                }
            })
            .sum();
    }
    leaves
}

/// The nearest neighbour of cluster `i` within `r` positions (the reference of
/// [`nearest_chunk`], which computes the same).
#[cfg(test)]
fn nearest(c: &[Cluster], i: usize, r: usize) -> u32 {
    let lo = i.saturating_sub(r);
    let hi = (i + r).min(c.len() - 1);
    let (mut b, mut bd) = (usize::MAX, f32::INFINITY);
    for j in lo..=hi {
        if j != i {
            let d = distance(&c[i], &c[j]);
            if better(i, j, d, b, bd) {
                (b, bd) = (j, d);
            }
        }
    }
    b as u32
}

/// The nearest neighbours (within `r` positions) of the clusters `a..a + out.len()`,
/// computing each pair's distance once, as Meister and Bittner do: pair `(i, j)`, `i < j`,
/// is offered to both ends.
fn nearest_chunk(c: &[Cluster], a: usize, r: usize, out: &mut [u32]) {
    let b = a + out.len();
    let mut best: Vec<(usize, f32)> = vec![(usize::MAX, f32::INFINITY); out.len()];
    for i in a.saturating_sub(r)..b {
        let me = &c[i];
        let hi = (i + r).min(c.len() - 1);
        for j in (i + 1).max(a)..=hi {
            let d = distance(me, &c[j]);
            if i >= a {
                let e = &mut best[i - a];
                if better(i, j, d, e.0, e.1) {
                    *e = (j, d);
                }
            }
            if j < b {
                let e = &mut best[j - a];
                if better(j, i, d, e.0, e.1) {
                    *e = (i, d);
                }
            }
        }
    }
    for (o, e) in out.iter_mut().zip(best) {
        *o = e.0 as u32;
    }
}

impl PlocBuilder {
    fn check(&self) -> Result<(), BuildError> {
        if !(1..=MAX_PLOC_RADIUS).contains(&self.radius) {
            return Err(BuildError::InvalidConfig(format!(
                "PLOC radius {} is outside 1..={MAX_PLOC_RADIUS}",
                self.radius
            )));
        }
        if self.max_leaf_size == 0 {
            return Err(BuildError::InvalidConfig(
                "PLOC max_leaf_size must be at least 1".into(),
            ));
        }
        self.sah.check("PLOC")
    }

    /// Builds a tree over the primitive boxes `aabbs`.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        self.check()?;
        check_input(aabbs)?;
        match aabbs.len() {
            0 => Ok(Bvh2::empty()),
            1 => Ok(Bvh2::from_root(
                ChildRef::leaf(0, 1),
                aabbs[0],
                Vec::new(),
                vec![0],
            )),
            _ => in_pool(self.threads, || {
                let mut t = self.cluster(aabbs);
                if self.max_leaf_size > 1 {
                    let cfg = AtrbvhConfig {
                        iterations: 0,
                        max_leaf_size: self.max_leaf_size,
                        sah: self.sah,
                        threads: 0,
                        ..Default::default()
                    };
                    optimize_checked(&mut t, &cfg);
                }
                t
            }),
        }
    }

    /// The clustering and the one-primitive-per-leaf tree (`aabbs.len() >= 2`).
    fn cluster(&self, aabbs: &[Aabb]) -> Bvh2 {
        let n = aabbs.len();
        let (_, order) = crate::morton_sort::sorted_codes(aabbs, self.bits, MortonGrid::Box);
        let mut cur: Vec<Cluster> = order
            .par_iter()
            .enumerate()
            .with_min_len(CHUNK)
            .map(|(p, &o)| {
                let b = &aabbs[o as usize];
                Cluster {
                    min: b.min.extend(0.0),
                    max: b.max.extend(0.0),
                    id: p as u32,
                }
            })
            .collect();
        // Inner node k: its two children's ids, written when it is created.
        let mut children: Vec<[u32; 2]> = vec![[0; 2]; n - 1];
        let mut inner_boxes: Vec<Aabb> = vec![Aabb::EMPTY; n - 1];
        let mut next = Vec::with_capacity(n);
        let mut made = 0usize;
        let r = self.radius;
        while cur.len() > 1 {
            let c = &cur;
            let mut nn: Vec<u32> = vec![0; c.len()];
            nn.par_chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(k, out)| nearest_chunk(c, k * CHUNK, r, out));
            let chunks = c.len().div_ceil(CHUNK);
            let mut counts = merge_counts(&nn);
            let mut merges: usize = counts.iter().map(|x| x.1).sum();
            if merges * MIN_MERGE_SHARE < c.len() {
                // Degenerate input (e.g. nested boxes around one centroid, where every
                // cluster's nearest neighbour is one below it): pair neighbours instead.
                nn.par_iter_mut().enumerate().for_each(|(i, x)| {
                    *x = if (i ^ 1) < c.len() { i ^ 1 } else { i - 1 } as u32;
                });
                counts = merge_counts(&nn);
                merges = counts.iter().map(|x| x.1).sum();
            }
            let survivors: usize = counts.iter().map(|x| x.0).sum();
            debug_assert!(merges >= 1, "the closest pair is always mutual");
            next.clear();
            next.resize(
                survivors,
                Cluster {
                    min: Vec4::ZERO,
                    max: Vec4::ZERO,
                    id: 0,
                },
            );
            // Each chunk writes its own ranges of `next` and of the new inner nodes.
            let mut outs = Vec::with_capacity(chunks);
            let (mut rest_c, mut rest_k, mut rest_b) = (
                next.as_mut_slice(),
                &mut children[made..made + merges],
                &mut inner_boxes[made..made + merges],
            );
            let mut first = made;
            for &(keep, merge) in &counts {
                let (a, t) = rest_c.split_at_mut(keep);
                let (b, u) = rest_k.split_at_mut(merge);
                let (d, v) = rest_b.split_at_mut(merge);
                outs.push((a, b, d, first));
                (rest_c, rest_k, rest_b) = (t, u, v);
                first += merge;
            }
            outs.into_par_iter()
                .enumerate()
                .for_each(|(k, (out, kids, boxes, first))| {
                    let (mut o, mut m) = (0, 0);
                    for i in k * CHUNK..((k + 1) * CHUNK).min(c.len()) {
                        let j = nn[i] as usize;
                        let mutual = nn[j] as usize == i;
                        if !mutual {
                            out[o] = c[i];
                            o += 1;
                        } else if i < j {
                            let (a, b) = (&c[i], &c[j]);
                            let merged = Cluster {
                                min: a.min.min(b.min),
                                max: a.max.max(b.max),
                                id: (n + first + m) as u32,
                            };
                            kids[m] = [a.id, b.id];
                            boxes[m] = merged.aabb();
                            out[o] = merged;
                            o += 1;
                            m += 1;
                        }
                    }
                });
            made += merges;
            std::mem::swap(&mut cur, &mut next);
        }
        debug_assert_eq!(made, n - 1);
        let root = cur[0].id as usize - n;
        let leaves = leaf_counts(&children, n);
        let mut nodes = zeroed_nodes(n - 1);
        let mut prims = vec![0u32; n];
        let e = Emit {
            n,
            children: &children,
            boxes: &inner_boxes,
            leaves: &leaves,
            order: &order,
            aabbs,
        };
        crate::layout::preorder_sized(root, &mut nodes, &mut prims, &e);
        Bvh2 {
            nodes,
            prim_indices: prims,
            bounds: inner_boxes[root],
        }
    }
}

/// The node writer of the clustered tree, for [`crate::layout::preorder_sized`] (a
/// subtree of `m` leaves takes `m - 1` nodes and `m` leaf-table entries). A
/// [`SizedVisit`](crate::layout::SizedVisit) with its node inlined into the layout loop,
/// not a closure, which the compiler called per node.
struct Emit<'a> {
    n: usize,
    children: &'a [[u32; 2]],
    boxes: &'a [Aabb],
    leaves: &'a [u32],
    order: &'a [u32],
    aabbs: &'a [Aabb],
}

impl crate::layout::SizedVisit<usize, u32, Node> for Emit<'_> {
    /// The node of inner cluster `k`, its children placed through `kids` in slot order: a
    /// primitive gets the next leaf-table entry, an inner cluster the next node range.
    #[inline(always)]
    fn node(&self, k: usize, kids: &mut Kids<'_, usize, u32>) -> Node {
        let mut refs = [ChildRef::EMPTY; 2];
        let mut boxes = [Aabb::EMPTY; 2];
        for (s, &c) in self.children[k].iter().enumerate() {
            let c = c as usize;
            if c < self.n {
                let o = self.order[c];
                let (first, entry) = kids.leaf(1);
                entry[0] = o;
                (refs[s], boxes[s]) = (ChildRef::leaf(first, 1), self.aabbs[o as usize]);
            } else {
                let m = self.leaves[c - self.n];
                let at = kids.inner(c - self.n, m - 1, m);
                (refs[s], boxes[s]) = (ChildRef::inner(at), self.boxes[c - self.n]);
            }
        }
        Node::new(&boxes[0], refs[0], &boxes[1], refs[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use crate::{validate, LbvhBuilder, SweepSahBuilder};
    use geom::Vec3;
    use proptest::prelude::*;

    fn ploc(max_leaf: u32, threads: usize) -> PlocBuilder {
        PlocBuilder {
            max_leaf_size: max_leaf,
            threads,
            ..Default::default()
        }
    }

    /// Brute-force reference of one clustering step sequence: the same algorithm written
    /// plainly (sequential, no chunks), giving the same tree shape.
    fn reference_merges(aabbs: &[Aabb], r: usize) -> Vec<(u32, u32)> {
        let n = aabbs.len();
        let (_, order) =
            crate::morton_sort::sorted_codes(aabbs, MortonBits::Bits30, MortonGrid::Box);
        let mut cur: Vec<Cluster> = order
            .iter()
            .enumerate()
            .map(|(p, &o)| Cluster {
                min: aabbs[o as usize].min.extend(0.0),
                max: aabbs[o as usize].max.extend(0.0),
                id: p as u32,
            })
            .collect();
        let mut merges = Vec::new();
        while cur.len() > 1 {
            let nn: Vec<usize> = (0..cur.len())
                .map(|i| nearest(&cur, i, r) as usize)
                .collect();
            let mut next = Vec::new();
            for i in 0..cur.len() {
                let j = nn[i];
                if nn[j] != i {
                    next.push(cur[i]);
                } else if i < j {
                    merges.push((cur[i].id, cur[j].id));
                    next.push(Cluster {
                        min: cur[i].min.min(cur[j].min),
                        max: cur[i].max.max(cur[j].max),
                        id: (n + merges.len() - 1) as u32,
                    });
                }
            }
            cur = next;
        }
        merges
    }

    #[test]
    fn nearest_neighbour_is_the_brute_force_minimum() {
        // Random boxes, then all ties, then runs of three equal boxes.
        let steps: Vec<f32> = (0..200).map(|i| (i / 3) as f32).collect();
        for prims in [soup(300, 3.0, 7), cubes_at(&[0.0; 100]), cubes_at(&steps)] {
            nearest_neighbours_of(&prims);
        }
    }

    fn nearest_neighbours_of(prims: &[Aabb]) {
        let c: Vec<Cluster> = prims
            .iter()
            .enumerate()
            .map(|(i, b)| Cluster {
                min: b.min.extend(0.0),
                max: b.max.extend(0.0),
                id: i as u32,
            })
            .collect();
        for r in [1, 4, 16] {
            for chunk in [1, 7, 64, 300] {
                let mut nn = vec![0u32; c.len()];
                for (k, out) in nn.chunks_mut(chunk).enumerate() {
                    nearest_chunk(&c, k * chunk, r, out);
                }
                let want: Vec<u32> = (0..c.len()).map(|i| nearest(&c, i, r)).collect();
                assert_eq!(nn, want, "r {r} chunk {chunk}");
            }
            for i in 0..c.len() {
                let j = nearest(&c, i, r) as usize;
                assert!(j != i && j.abs_diff(i) <= r);
                let d = c[i].aabb().union(c[j].aabb()).half_area();
                for k in i.saturating_sub(r)..=(i + r).min(c.len() - 1) {
                    if k != i {
                        assert!(d <= c[i].aabb().union(c[k].aabb()).half_area() * (1.0 + 1e-6));
                    }
                }
            }
        }
    }

    #[test]
    fn tree_is_the_reference_clustering() {
        // With one primitive per leaf, the tree's inner nodes are exactly the reference's
        // merges: check the merged pairs' boxes as a multiset of node boxes.
        for (n, seed) in [(2, 1), (3, 2), (100, 3), (9000, 4)] {
            let prims = soup(n, 2.0, seed);
            let t = ploc(1, 0).build(&prims).unwrap();
            assert_valid("soup", &t, &prims, 1);
            let merges = reference_merges(&prims, 16);
            assert_eq!(merges.len(), t.nodes.len());
            let key =
                |b: Aabb| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits);
            let mut got: Vec<_> = t.nodes.iter().map(|nd| key(nd.aabb())).collect();
            // Boxes of the reference's inner nodes.
            let (_, order) =
                crate::morton_sort::sorted_codes(&prims, MortonBits::Bits30, MortonGrid::Box);
            let mut boxes: Vec<Aabb> = order.iter().map(|&o| prims[o as usize]).collect();
            for &(a, b) in &merges {
                let u = boxes[a as usize].union(boxes[b as usize]);
                boxes.push(u);
            }
            let mut want: Vec<_> = boxes[n..].iter().map(|&b| key(b)).collect();
            got.sort();
            want.sort();
            assert_eq!(got, want, "n = {n}");
        }
    }

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for (name, prims) in adversarial() {
            for leaf in [1, 4, 8] {
                let t = ploc(leaf, 0).build(&prims).unwrap();
                assert_valid(name, &t, &prims, leaf);
            }
        }
    }

    #[test]
    fn degenerate_inputs() {
        let b = ploc(8, 0);
        assert_eq!(b.build(&[]).unwrap(), Bvh2::empty());
        let one = cubes_at(&[1.0]);
        let t = b.build(&one).unwrap();
        assert_valid("one", &t, &one, 8);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        // 20000 coincident boxes: all distances tie; the hash tie-break keeps the tree
        // shallow (a chain would be 20000 deep).
        let same = cubes_at(&[0.0; 20_000]);
        for leaf in [1, 8] {
            let t = ploc(leaf, 0).build(&same).unwrap();
            assert_valid("same", &t, &same, leaf);
            assert!(t.stats().max_depth < 200, "depth {}", t.stats().max_depth);
        }
        // Equal centroids, different sizes.
        let nested: Vec<Aabb> = (1..3000)
            .map(|i| Aabb::new(Vec3::splat(-(i as f32)), Vec3::splat(i as f32)))
            .collect();
        // Every cluster's nearest neighbour is the one below it, so only one pair is
        // mutual per iteration: the neighbour-pairing fallback keeps it shallow.
        let t = ploc(1, 0).build(&nested).unwrap();
        assert_valid("nested", &t, &nested, 1);
        assert!(t.stats().max_depth < 200, "depth {}", t.stats().max_depth);
        let t = b.build(&nested).unwrap();
        assert_valid("nested", &t, &nested, 8);
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = soup(60_000, 1.0, 11);
        for leaf in [1, 8] {
            let t1 = ploc(leaf, 1).build(&prims).unwrap();
            assert_valid("soup", &t1, &prims, leaf);
            assert_eq!(t1, ploc(leaf, 2).build(&prims).unwrap());
            assert_eq!(t1, ploc(leaf, 3).build(&prims).unwrap());
        }
    }

    /// Quality sanity on synthetic scenes. Not a comparison with LBVH: on a uniform soup
    /// and on the regular grid of the cloth, greedy clustering with r = 16 is a few percent
    /// worse than the Morton tree (see docs/builders.md); real meshes are tested below.
    #[test]
    fn near_sweep_on_synthetic_scenes() {
        for spec in ["proc:cloth?n=5000", "proc:soup?n=20000"] {
            let prims = proc_scene(spec);
            let sweep = SweepSahBuilder::default().build(&prims).unwrap();
            let t = ploc(8, 0).build(&prims).unwrap();
            assert_valid(spec, &t, &prims, 8);
            let r = t.sah_vs(&sweep);
            assert!(r > 0.9 && r < 1.4, "{spec}: PLOC {r} x sweep");
        }
    }

    #[test]
    fn bad_input_and_config_are_errors() {
        let prims = [Aabb::new(Vec3::ZERO, Vec3::splat(f32::NAN))];
        assert_eq!(
            PlocBuilder::default().build(&prims),
            Err(BuildError::NonFinite { index: 0 })
        );
        let ok = cubes_at(&[0.0, 1.0]);
        for bad in [
            PlocBuilder {
                radius: 0,
                ..Default::default()
            },
            PlocBuilder {
                radius: MAX_PLOC_RADIUS + 1,
                ..Default::default()
            },
            PlocBuilder {
                max_leaf_size: 0,
                ..Default::default()
            },
        ] {
            assert!(
                matches!(bad.build(&ok), Err(BuildError::InvalidConfig(_))),
                "{bad:?}"
            );
        }
    }

    /// On the shared scenes' small meshes, PLOC with LBVH's leaf rule (one primitive per
    /// leaf) has a lower SAH than LBVH, and the collapsed tree a lower one still.
    #[test]
    fn real_scenes_beat_lbvh() {
        let Some(scenes) = real_scenes() else {
            return;
        };
        for (name, prims) in &scenes {
            if prims.len() > 100_000 {
                continue; // the small meshes only (debug builds)
            }
            let lbvh = LbvhBuilder::default().build(prims).unwrap();
            let p1 = ploc(1, 0).build(prims).unwrap();
            assert_valid(name, &p1, prims, 1);
            let p8 = ploc(8, 0).build(prims).unwrap();
            assert_valid(name, &p8, prims, 8);
            assert!(
                p1.sah() < lbvh.sah(),
                "{name}: {} vs LBVH {}",
                p1.sah(),
                lbvh.sah()
            );
            assert!(p8.sah() <= p1.sah(), "{name}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn random_soups_give_valid_trees(n in 0usize..1500, size in 0.0f32..20.0, seed: u64,
                                         radius in 1usize..40, leaf in 1u32..9) {
            let prims = soup(n, size, seed);
            let b = PlocBuilder { radius, max_leaf_size: leaf, ..Default::default() };
            let t = b.build(&prims).unwrap();
            prop_assert_eq!(validate(&t, &prims, leaf), Ok(()));
        }
    }
}

#[cfg(test)]
mod probe {
    use super::*;

    /// SAH over sweep SAH and build time of PLOC by radius and leaf limit on every shared
    /// scene. Run by hand:
    /// `cargo test --release -p bvh --lib -- --ignored --nocapture ploc_radius_table`
    #[test]
    #[ignore]
    fn ploc_radius_table() {
        let Some(mut scenes) = crate::testutil::real_scenes() else {
            return;
        };
        for spec in ["proc:cloth?n=5000", "proc:soup?n=20000"] {
            scenes.push((spec.to_string(), crate::testutil::proc_scene(spec)));
        }
        // PLOC_SCENES=substring restricts the table to matching scenes.
        let only = std::env::var("PLOC_SCENES").unwrap_or_default();
        scenes.retain(|(name, _)| name.contains(&only));
        for (name, prims) in &scenes {
            let sweep = crate::SweepSahBuilder::default().build(prims).unwrap();
            let lbvh = crate::LbvhBuilder::default().build(prims).unwrap();
            let mut row = format!("{name} lbvh/sweep {:.3}", lbvh.sah_vs(&sweep));
            for r in [1, 4, 16, 32] {
                for leaf in [1, 8] {
                    let s = std::time::Instant::now();
                    let t = PlocBuilder {
                        radius: r,
                        max_leaf_size: leaf,
                        ..Default::default()
                    }
                    .build(prims)
                    .unwrap();
                    row += &format!(
                        " r{r}/l{leaf} {:.3} ({:.0} ms)",
                        t.sah_vs(&sweep),
                        s.elapsed().as_secs_f64() * 1e3
                    );
                }
            }
            println!("{row}");
        }
    }
}
