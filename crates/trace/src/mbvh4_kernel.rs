//! Traversal of the 4-wide `Mbvh4` ([P4] §3.1, Fig. 3 bottom): one node fetch tests four
//! child boxes (four slab tests, written lane by lane over the node's structure-of-arrays
//! planes so that they compile to 4-wide SIMD), the hit children are put in front-to-back
//! order by a 4-input sorting network of five comparators ([P4] Fig. 4, Knuth's optimal
//! network of depth 3), traversal continues with the nearest and the others are pushed.
//!
//! With the distance stack ([P4] §3.1, after Ernst and Greiner 2008), each stack entry
//! keeps its entry distance, and an entry farther than the closest hit found since it was
//! pushed is dropped when popped, without fetching its node; [P4] measured about 10% for
//! MBVH. [`KernelOptions::distance_stack`] switches it off to measure that effect.

use crate::accel::{
    cull_distance, huge_page_vec, prefetch, refit_nodes, slab_test4, traverse_child_refs, Hit,
    LeafTriangles, RaySource, Slab, TraversalStack, Traverse,
};
use crate::bvh2_kernel::check_links;
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::{ChildRef, Mbvh4, Node4};
use geom::{Ray, RayPrecomp, Triangle};

/// A node aligned to 64-byte cache lines (a `Vec<Node4>` is only 4-byte aligned, so
/// most of its 128-byte nodes would touch three lines instead of two).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
struct AlignedNode4(Node4);

/// An `Mbvh4` with its triangles in leaf order, ready to trace. The kernel works on an
/// aligned copy of the nodes (node `i` of the copy is node `i` of the tree).
#[derive(Clone, Debug)]
pub struct Mbvh4Accel {
    nodes: Vec<AlignedNode4>,
    leaf: LeafTriangles,
    options: KernelOptions,
}

/// The six box-plane rows of a node (`min_x .. max_z`), four lanes each, as one array.
#[inline(always)]
fn planes(n: &Node4) -> &[f32; 24] {
    const _: () = assert!(std::mem::offset_of!(Node4, max_z) == 20 * 4);
    // SAFETY: `Node4` is `repr(C)` and starts with its six `[f32; 4]` plane rows, in this
    // order and without padding (checked above), so its first 96 bytes are 24 floats.
    unsafe { &*(n as *const Node4 as *const [f32; 24]) }
}

/// The child-box test of the kernel ([`slab_test4`] over the node's plane rows): entry
/// distances, the hit mask, and the mask of non-empty slots, read off the loaded box rows
/// instead of the four child references.
#[inline(always)]
fn test4(slab: &Slab, n: &Node4, t_max: f32) -> ([f32; 4], u8, u8) {
    slab_test4(slab, planes(n), 0, 4, t_max)
}

/// Sorts four keys with the five comparators of the optimal 4-input network ([P4]
/// Fig. 4): (0,1) (2,3), then (0,2) (1,3), then (1,2). Each comparator is a branch-free
/// min/max pair, as in hardware, so traversal order costs no branch mispredictions.
#[inline(always)]
pub fn sort4(k: &mut [u32; 4]) {
    #[inline(always)]
    fn cmp(k: &mut [u32; 4], a: usize, b: usize) {
        let (x, y) = (k[a], k[b]);
        k[a] = x.min(y);
        k[b] = x.max(y);
    }
    cmp(k, 0, 1);
    cmp(k, 2, 3);
    cmp(k, 0, 2);
    cmp(k, 1, 3);
    cmp(k, 1, 2);
}

/// Bits set in a 4-bit mask (a table: the target's baseline has no popcount instruction).
const POPCOUNT4: [u8; 16] = [0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4];

/// Sort keys of the hit children: the entry distance mapped to an order-preserving
/// unsigned integer with its two low bits replaced by the slot number (so a key names its
/// slot, and distances within 4 ulps order by slot); `u32::MAX` for a missed slot.
#[inline(always)]
fn child_keys(dist: &[f32; 4], mask: u8) -> [u32; 4] {
    std::array::from_fn(|i| {
        let b = dist[i].to_bits();
        let ordered = if b & 0x8000_0000 != 0 {
            !b
        } else {
            b | 0x8000_0000
        };
        if mask >> i & 1 != 0 {
            (ordered & !3) | i as u32
        } else {
            u32::MAX
        }
    })
}

impl Mbvh4Accel {
    /// Prepares `bvh` (built over `triangles`) for tracing. Fails when a leaf-table entry
    /// names a triangle that does not exist, or the links fail the checks of the
    /// crate's "Trees from anywhere" section (out of range, not after the parent, a node
    /// linked twice, overlapping leaves).
    pub fn new(
        bvh: Mbvh4,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        check_links(
            bvh.nodes.iter().flat_map(|n| n.children.iter()),
            4,
            bvh.nodes.len(),
            bvh.prim_indices.len(),
        )?;
        let mut nodes: Vec<AlignedNode4> = huge_page_vec(bvh.nodes.len());
        nodes.extend(bvh.nodes.iter().map(|n| {
            let mut n = *n;
            // The kernel tells used slots by their boxes: an absent child gets the empty
            // box (never hit, whatever box the tree stored), so it is never entered.
            for k in 0..4 {
                if n.children[k].is_empty() {
                    n.set_child_aabb(k, &geom::Aabb::EMPTY);
                }
            }
            AlignedNode4(n)
        }));
        let leaf = LeafTriangles::pack(
            &bvh.prim_indices,
            triangles,
            nodes.iter_mut().flat_map(|n| n.0.children.iter_mut()),
        )
        .map_err(|e| e.into_trace_error(triangles.len()))?;
        Ok(Self {
            nodes,
            leaf,
            options,
        })
    }

    /// The kernel options.
    pub fn options(&self) -> KernelOptions {
        self.options
    }

    /// Refits in place to `triangles`, the list the tree was prepared over with its
    /// vertices moved (same topology); see [`crate::Bvh2Accel::refit`].
    pub fn refit(&mut self, triangles: &[Triangle]) -> Result<(), TraceError> {
        self.leaf.update(triangles)?;
        refit_nodes(
            &mut self.nodes,
            &self.leaf,
            |n| n.0.children,
            |n, c, b| {
                let n = &mut n.0;
                n.min_x[c] = b.min.x;
                n.min_y[c] = b.min.y;
                n.min_z[c] = b.min.z;
                n.max_x[c] = b.max.x;
                n.max_y[c] = b.max.y;
                n.max_z[c] = b.max.z;
            },
        );
        Ok(())
    }

    /// Starts loading a child that traversal will visit later (both cache lines of a node).
    #[inline(always)]
    fn prefetch_child(&self, child: ChildRef) {
        if child.is_leaf() {
            self.leaf.prefetch(child.index);
        } else {
            let p = self.nodes.as_ptr().wrapping_add(child.index as usize);
            prefetch(p);
            prefetch((p as *const u8).wrapping_add(64));
        }
    }

    crate::accel::one_ray_kernel!(inherent);

    /// The traversal of one ray (`EACH` as in [`Self::each`]; it changes no operation).
    #[inline(always)]
    fn traverse_ray<const DIST: bool, const EACH: bool, O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        total: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let slab = Slab::new(&pre, ray.t_min);
        let nodes = &self.nodes;
        let visit = |c: ChildRef,
                     best_t: f32,
                     stack: &mut TraversalStack,
                     stats: &mut RayStats,
                     obs: &mut O| {
            let index = c.index;
            let node = &nodes[index as usize].0;
            let (dist, mask, valid) = test4(&slab, node, cull_distance(best_t));
            let kids = &node.children;
            stats.node_visits += 1;
            stats.box_tests += POPCOUNT4[valid as usize & 15] as u64;
            obs.node(index, valid, mask);
            match POPCOUNT4[mask as usize & 15] {
                0 => None,
                1 => Some(kids[mask.trailing_zeros() as usize & 3]),
                2 => {
                    // Two hits need one comparison, not the whole network.
                    let a = mask.trailing_zeros() as usize & 3;
                    let b = (7 - (mask.leading_zeros() as usize)) & 3;
                    let (near, far) = if dist[b] < dist[a] { (b, a) } else { (a, b) };
                    self.prefetch_child(kids[far]);
                    stack.push(kids[far], dist[far], &self.leaf, stats, obs);
                    Some(kids[near])
                }
                hits => {
                    let hits = hits as usize;
                    let mut keys = child_keys(&dist, mask);
                    sort4(&mut keys);
                    // Push the far ones far-to-near so the nearest of them pops first.
                    for k in (1..hits).rev() {
                        let slot = (keys[k] & 3) as usize;
                        let child = kids[slot];
                        self.prefetch_child(child);
                        stack.push(child, dist[slot], &self.leaf, stats, obs);
                    }
                    Some(kids[(keys[0] & 3) as usize])
                }
            }
        };
        traverse_child_refs::<DIST, O>(&self.leaf, ray, &pre, query, stack, total, obs, visit)
    }
}

impl Traverse for Mbvh4Accel {
    crate::accel::one_ray_kernel!(traverse);

    fn node_bytes(&self) -> u32 {
        std::mem::size_of::<Node4>() as u32
    }

    fn width(&self) -> u32 {
        4
    }

    fn node_count(&self) -> usize {
        self.nodes.len()
    }

    fn source_triangles(&self) -> usize {
        self.leaf.source_len
    }

    fn leaf_entries(&self) -> usize {
        self.leaf.entry_count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::{slab_test4_portable, slab_test4_sse};

    /// The SSE box test computes the portable test's values bit for bit.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse_box_test_equals_the_portable_one() {
        let mut r = crate::testutil::Rng::new(5);
        for _ in 0..20_000 {
            let mut n = Node4::EMPTY;
            for i in 0..(1 + (r.f32() * 4.0) as usize).min(4) {
                let a = r.vec() * 3.0;
                let b = a + (r.vec() + geom::Vec3::ONE) * if r.f32() < 0.2 { 0.0 } else { 1.0 };
                n.set_child_aabb(i, &geom::Aabb::new(a.min(b), a.max(b)));
            }
            let mut d = r.vec();
            if r.f32() < 0.2 {
                d.x = 0.0;
            }
            let ray = Ray::with_range(r.vec() * 5.0, d, r.f32() * 0.1, 1.0 + r.f32() * 20.0);
            let pre = RayPrecomp::new(&ray);
            let slab = Slab::new(&pre, ray.t_min);
            let t_max = if r.f32() < 0.5 {
                ray.t_max
            } else {
                f32::INFINITY
            };
            let (a, ma, va) = slab_test4_portable(&slab, planes(&n), 0, 4, t_max);
            let (b, mb, vb) = slab_test4_sse(&slab, planes(&n), 0, 4, t_max);
            assert_eq!((ma, va), (mb, vb));
            // The valid mask names exactly the slots that were given a box.
            let given = n
                .min_x
                .iter()
                .enumerate()
                .fold(0u8, |v, (i, &x)| v | ((x != f32::INFINITY) as u8) << i);
            assert_eq!(va, given);
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        }
    }

    /// The five-comparator network sorts every ordering of four distinct keys, and the
    /// child keys order hit slots by distance (misses last, ties by slot).
    #[test]
    fn sorting_network_sorts_all_permutations() {
        let base = [3u32, 10, 11, u32::MAX];
        let mut count = 0;
        for a in 0..4 {
            for b in 0..4 {
                for c in 0..4 {
                    for d in 0..4 {
                        let p = [a, b, c, d];
                        let mut seen = [false; 4];
                        if p.iter().any(|&i| std::mem::replace(&mut seen[i], true)) {
                            continue;
                        }
                        count += 1;
                        let mut keys = p.map(|i| base[i]);
                        sort4(&mut keys);
                        assert_eq!(keys, base, "{p:?}");
                    }
                }
            }
        }
        assert_eq!(count, 24);
        let mut k = child_keys(&[5.0, 1.0, 1.0, -2.0], 0b0111);
        sort4(&mut k);
        assert_eq!(k.map(|k| k & 3)[..3], [1, 2, 0]);
        assert_eq!(k[3], u32::MAX);
        let mut k = child_keys(&[-1.0, -3.0, 0.0, 2.0], 0b1111);
        sort4(&mut k);
        assert_eq!(k.map(|k| k & 3), [1, 0, 2, 3]);
    }
}
