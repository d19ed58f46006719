//! LBVH: the linear BVH of Karras (2012), one primitive per leaf (\[P2\] §2.1.1, §3).
//!
//! 1. Primitives are sorted by the Morton code of their box centroid, quantized to the
//!    centroid bounds with [`geom::MortonQuantizer`] (30 or 63 bits), ties broken by
//!    primitive index so the order is total and deterministic.
//! 2. Every inner node of the radix tree over the sorted codes is found independently (in
//!    parallel) by Karras's method: inner node `i` finds the direction of its range, its
//!    far end and its split `γ` by binary searches on `δ(i, j)`, the length of the common
//!    prefix of the codes at sorted positions `i` and `j`. Equal codes fall back to the
//!    common prefix of the positions themselves, as Karras does, so duplicate codes still
//!    give a binary tree (balanced over the duplicates).
//! 3. A top-down pass computes the boxes bottom-up on its way back and writes the [`Bvh2`]
//!    directly in depth-first order: a subtree of `k` leaves has exactly `k - 1` nodes, so
//!    each subtree owns a known slice of the node array and the two children of a large
//!    node are emitted in parallel (`rayon::join`) without any copying.
//!
//! Karras computes the boxes with atomic counters on parent pointers; min/max are exact,
//! so the top-down recursion here gives bit-identical boxes without atomics.

use crate::bvh2::Bvh2;
use crate::error::{check_input, in_pool, BuildError};
use crate::node::{ChildRef, Node};
use crate::PARALLEL_MIN_PRIMS;
use geom::Aabb;
use rayon::prelude::*;

/// Length of the Morton codes the LBVH sorts by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MortonBits {
    /// 30-bit codes (10 bits per axis, 1024^3 cells), as in the thesis's GPU comparisons.
    #[default]
    Bits30,
    /// 63-bit codes (21 bits per axis).
    Bits63,
}

impl MortonBits {
    /// Code length in bits (30 or 63).
    pub const fn total_bits(self) -> u32 {
        match self {
            MortonBits::Bits30 => 30,
            MortonBits::Bits63 => 63,
        }
    }
}

/// Configuration of the LBVH builder (leaves always hold one primitive).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct LbvhBuilder {
    /// Morton code length.
    pub bits: MortonBits,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

/// Sorted Morton codes and the primitive at each sorted position.
struct Sorted {
    codes: Vec<u64>,
    order: Vec<u32>,
}

impl LbvhBuilder {
    /// Builds a tree over the primitive boxes `aabbs`.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        check_input(aabbs)?;
        match aabbs.len() {
            0 => Ok(Bvh2::empty()),
            1 => Ok(Bvh2::from_root(
                ChildRef::leaf(0, 1),
                aabbs[0],
                Vec::new(),
                vec![0],
            )),
            _ => in_pool(self.threads, || self.build_checked(aabbs)),
        }
    }

    fn build_checked(&self, aabbs: &[Aabb]) -> Bvh2 {
        let sorted = sort_by_morton(aabbs, self.bits);
        let splits = karras_splits(&sorted.codes);
        let n = aabbs.len();
        // Every node is written by `emit_node`.
        let mut nodes = crate::node::zeroed_nodes(n - 1);
        let ctx = Emit {
            aabbs,
            order: &sorted.order,
            splits: &splits,
        };
        let bounds = ctx.emit_node(0, 0, 0, n - 1, &mut nodes);
        Bvh2 {
            nodes,
            prim_indices: sorted.order,
            bounds,
        }
    }
}

/// Computes the codes of all centroids and sorts (code, primitive index) pairs.
fn sort_by_morton(aabbs: &[Aabb], bits: MortonBits) -> Sorted {
    let (codes, order) = crate::morton_sort::sorted_codes(aabbs, bits, geom::MortonGrid::Box);
    Sorted { codes, order }
}

/// Karras's `δ(i, j)`: common prefix length of the keys at sorted positions `i` and `j`,
/// where a key is the code followed by the 32-bit position; -1 when `j` is out of range.
#[inline]
fn delta(codes: &[u64], i: i64, j: i64) -> i32 {
    if j < 0 || j >= codes.len() as i64 {
        return -1;
    }
    let (a, b) = (codes[i as usize], codes[j as usize]);
    if a != b {
        (a ^ b).leading_zeros() as i32
    } else {
        64 + ((i as u32) ^ (j as u32)).leading_zeros() as i32
    }
}

/// The split position `γ` of every inner node `0..n-1` of the radix tree (Karras 2012,
/// Fig. 4): the left child covers sorted positions up to `γ`, the right child from `γ + 1`.
fn karras_splits(codes: &[u64]) -> Vec<u32> {
    let n = codes.len();
    (0..n as i64 - 1)
        .into_par_iter()
        .map(|i| {
            let d: i64 = if delta(codes, i, i + 1) > delta(codes, i, i - 1) {
                1
            } else {
                -1
            };
            // Upper bound of the range length, then its exact length by binary search.
            let dmin = delta(codes, i, i - d);
            let mut lmax: i64 = 2;
            while delta(codes, i, i + lmax * d) > dmin {
                lmax *= 2;
            }
            let mut l: i64 = 0;
            let mut t = lmax / 2;
            while t >= 1 {
                if delta(codes, i, i + (l + t) * d) > dmin {
                    l += t;
                }
                t /= 2;
            }
            let j = i + l * d;
            // Split: the last position sharing more than the node's prefix with `i`.
            let dnode = delta(codes, i, j);
            let mut s: i64 = 0;
            let mut t = l;
            loop {
                t = (t + 1) / 2;
                if delta(codes, i, i + (s + t) * d) > dnode {
                    s += t;
                }
                if t <= 1 {
                    break;
                }
            }
            (i + s * d + d.min(0)) as u32
        })
        .collect()
}

/// Top-down emission of the radix tree as depth-first [`Node`]s.
struct Emit<'a> {
    aabbs: &'a [Aabb],
    order: &'a [u32],
    splits: &'a [u32],
}

impl Emit<'_> {
    /// Emits radix node `id` covering sorted positions `lo..=hi` (`lo < hi`) into `out`
    /// (exactly `hi - lo` nodes, `out[0]` at absolute index `base`); returns its box.
    fn emit_node(&self, base: usize, id: usize, lo: usize, hi: usize, out: &mut [Node]) -> Aabb {
        debug_assert_eq!(out.len(), hi - lo);
        let g = self.splits[id] as usize;
        let (this, rest) = out.split_at_mut(1);
        let (lout, rout) = rest.split_at_mut(g - lo);
        let left_base = base + 1;
        let right_base = base + 1 + (g - lo);
        let leaf = &|p: usize| {
            (
                ChildRef::leaf(p as u32, 1),
                self.aabbs[self.order[p] as usize],
            )
        };
        let mut left = move || {
            if lo == g {
                leaf(g)
            } else {
                let b = self.emit_node(left_base, g, lo, g, lout);
                (ChildRef::inner(left_base as u32), b)
            }
        };
        let mut right = move || {
            if hi == g + 1 {
                leaf(g + 1)
            } else {
                let b = self.emit_node(right_base, g + 1, g + 1, hi, rout);
                (ChildRef::inner(right_base as u32), b)
            }
        };
        let ((lc, lb), (rc, rb)) = if hi - lo >= PARALLEL_MIN_PRIMS {
            rayon::join(left, right)
        } else {
            (left(), right())
        };
        this[0] = Node::new(&lb, lc, &rb, rc);
        lb.union(rb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use crate::{validate, SweepSahBuilder};
    use geom::Vec3;
    use proptest::prelude::*;

    /// Straightforward recursive reference of the same radix tree: split each range of
    /// sorted keys (code, then 32-bit position) at its highest differing bit.
    fn reference(aabbs: &[Aabb], bits: MortonBits) -> Bvh2 {
        let s = sort_by_morton(aabbs, bits);
        let key = |k: usize| ((s.codes[k] as u128) << 32) | k as u128;
        let mut nodes = Vec::new();
        fn rec(
            lo: usize,
            hi: usize,
            key: &dyn Fn(usize) -> u128,
            s: &Sorted,
            aabbs: &[Aabb],
            nodes: &mut Vec<Node>,
        ) -> (ChildRef, Aabb) {
            if lo == hi {
                return (ChildRef::leaf(lo as u32, 1), aabbs[s.order[lo] as usize]);
            }
            let bit = 127 - (key(lo) ^ key(hi)).leading_zeros();
            let first_one = (lo..=hi).find(|&k| (key(k) >> bit) & 1 == 1).unwrap();
            let at = nodes.len();
            nodes.push(Node::EMPTY);
            let (lc, lb) = rec(lo, first_one - 1, key, s, aabbs, nodes);
            let (rc, rb) = rec(first_one, hi, key, s, aabbs, nodes);
            nodes[at] = Node::new(&lb, lc, &rb, rc);
            (ChildRef::inner(at as u32), lb.union(rb))
        }
        let (root, bounds) = rec(0, aabbs.len() - 1, &key, &s, aabbs, &mut nodes);
        Bvh2::from_root(root, bounds, nodes, s.order)
    }

    fn build(prims: &[Aabb], bits: MortonBits, threads: usize) -> Bvh2 {
        LbvhBuilder { bits, threads }.build(prims).unwrap()
    }

    #[test]
    fn adversarial_inputs_give_valid_trees_equal_to_reference() {
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for (name, prims) in adversarial() {
                let t = build(&prims, bits, 0);
                assert_valid(name, &t, &prims, 1);
                if prims.len() >= 2 {
                    assert_eq!(t, reference(&prims, bits), "{name} {bits:?}");
                }
                // Depth is bounded by the code length plus the position bits.
                assert!(t.stats().max_depth <= 64 + 32, "{name}");
            }
        }
    }

    #[test]
    fn duplicate_codes_give_a_balanced_subtree() {
        // 1024 coincident centroids: one Morton code, so the tree is built on position
        // bits alone: perfectly balanced, depth log2(1024) = 10.
        let prims = cubes_at(&[0.0; 1024]);
        let t = build(&prims, MortonBits::Bits30, 0);
        assert_valid("dups", &t, &prims, 1);
        assert_eq!(t.stats().max_depth, 10);
        assert_eq!(t.stats().leaves, 1024);
    }

    #[test]
    fn zero_one_two_primitives() {
        let b = LbvhBuilder::default();
        assert_eq!(b.build(&[]).unwrap(), Bvh2::empty());
        let one = cubes_at(&[1.0]);
        let t = b.build(&one).unwrap();
        assert_valid("one", &t, &one, 1);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        // Two primitives in reverse Morton order: the leaf table is sorted by code.
        let two = cubes_at(&[10.0, 0.0]);
        let t = b.build(&two).unwrap();
        assert_valid("two", &t, &two, 1);
        assert_eq!(t.prim_indices, vec![1, 0]);
        assert_eq!(t.nodes.len(), 1);
    }

    #[test]
    fn karras_splits_of_a_known_sequence() {
        // Karras 2012 Fig. 3 keys: 00001 00010 00100 00101 10011 11000 11001 11110.
        let codes = [1u64, 2, 4, 5, 19, 24, 25, 30];
        let s = karras_splits(&codes);
        // Root splits between 00101 and 10011 (position 3), node 3 = [0,3] splits at 1,
        // node 4 = [4,7] splits at 4, node 1 = [0,1] at 0, node 2 = [2,3] at 2, node 5 =
        // [5,7] at 6 (11001 | 11110), node 6 = [5,6] at 5.
        assert_eq!(s, vec![3, 0, 2, 1, 4, 6, 5]);
    }

    #[test]
    fn deterministic_across_thread_counts_and_bits() {
        let prims = soup(40_000, 1.0, 29);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let t1 = build(&prims, bits, 1);
            assert_valid("soup", &t1, &prims, 1);
            assert_eq!(t1, build(&prims, bits, 2));
            assert_eq!(t1, build(&prims, bits, 4));
            assert_eq!(t1, reference(&prims, bits));
        }
    }

    #[test]
    fn quality_is_sane_against_sweep() {
        let prims = proc_scene("proc:cloth?n=5000");
        let t = build(&prims, MortonBits::Bits30, 0);
        assert_valid("cloth", &t, &prims, 1);
        let sweep = SweepSahBuilder::default().build(&prims).unwrap();
        let r = t.sah_vs(&sweep);
        // One primitive per leaf and Morton splits: worse than the sweep, not absurdly.
        assert!(r > 1.0 && r < 2.5, "LBVH SAH {r} x sweep");
    }

    #[test]
    fn bad_input_is_an_error() {
        let prims = [Aabb::new(Vec3::ZERO, Vec3::splat(f32::NAN))];
        assert_eq!(
            LbvhBuilder::default().build(&prims),
            Err(BuildError::NonFinite { index: 0 })
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn random_soups_match_reference(n in 0usize..2000, size in 0.0f32..20.0, seed: u64, wide: bool) {
            let prims = soup(n, size, seed);
            let bits = if wide { MortonBits::Bits63 } else { MortonBits::Bits30 };
            let t = build(&prims, bits, 0);
            prop_assert_eq!(validate(&t, &prims, 1), Ok(()));
            if n >= 2 {
                prop_assert_eq!(t, reference(&prims, bits));
            }
        }
    }
}
