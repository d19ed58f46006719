//! Traversal of the binary `Bvh2` ([P2] §4.1): a stack-based loop that tests both child
//! boxes of a node, continues with the nearer hit child and pushes the farther one, and
//! culls boxes against the closest hit so far (the slab test's far limit is the closest
//! hit's distance).
//!
//! This is the baseline traversal unit of [P4] §3 (Fig. 3 top): two parallel ray/box
//! tests per node and a compare-and-swap of the two children into front-to-back order.
//!
//! The kernel traverses a private copy of the nodes in a layout made for 4-wide SIMD: per
//! axis one 16-byte row `[min_0, min_1, max_0, max_1]` of the two children, then the two
//! child references, 64 bytes per node like the [P2] node, aligned to 64-byte cache lines
//! (a `Vec<bvh::Node>` is only 4-byte aligned, so half its nodes would straddle two
//! lines). Node `i` of the copy is node `i` of the tree, so counters and logs name the
//! tree's nodes.
//! [P4] keeps the BVH without a distance stack; it can be switched on
//! ([`KernelOptions::distance_stack`]) to measure its effect ([P4] §3.1 reports about 3%
//! for BVH).

use crate::accel::{
    cull_distance, fmax, fmin, huge_page_vec, prefetch, refit_nodes, traverse_child_refs, Hit,
    LeafTriangles, RaySource, TraversalStack, Traverse,
};
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::{Bvh2, ChildRef};
use geom::{Ray, RayPrecomp, Triangle, SLAB_FAR_SCALE};

/// A binary node laid out for the kernel (see the module header).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
struct SoaNode2 {
    /// Per axis: `[min_0, min_1, max_0, max_1]`.
    rows: [[f32; 4]; 3],
    children: [ChildRef; 2],
}

const _: () = assert!(std::mem::size_of::<SoaNode2>() == 64);

impl SoaNode2 {
    fn new(n: &bvh::Node) -> Self {
        let mut rows = [[0f32; 4]; 3];
        for (a, row) in rows.iter_mut().enumerate() {
            for c in 0..2 {
                let (lo, hi) = if n.children[c].is_empty() {
                    // An empty slot becomes the box at +inf on every axis, which keeps
                    // the slab arithmetic free of NaNs (the (+inf, -inf) empty box would
                    // look infinite to the min/max test); the kernel masks it out.
                    (f32::INFINITY, f32::INFINITY)
                } else {
                    (n.bounds[c][a], n.bounds[c][a + 3])
                };
                row[c] = lo;
                row[c + 2] = hi;
            }
        }
        Self {
            rows,
            children: n.children,
        }
    }
}

/// A `Bvh2` with its triangles in leaf order, ready to trace.
#[derive(Clone, Debug)]
pub struct Bvh2Accel {
    nodes: Vec<SoaNode2>,
    leaf: LeafTriangles,
    options: KernelOptions,
}

/// Both child boxes of `n` against the ray: entry distances, and which were hit within
/// `[t_min, t_max]`. Per axis the four plane distances are computed at once; the nearer
/// and farther of each child's pair are its entry and exit on that axis. (The portable
/// form; x86-64 uses [`test2_sse`], which computes the same values.)
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline(always)]
fn test2_portable(
    n: &SoaNode2,
    o: &[f32; 3],
    inv: &[f32; 3],
    t_min: f32,
    t_max: f32,
) -> ([f32; 2], [bool; 2]) {
    let mut near = [t_min; 2];
    let mut far = [f32::INFINITY; 2];
    for a in 0..3 {
        let r = &n.rows[a];
        let t = [
            (r[0] - o[a]) * inv[a],
            (r[1] - o[a]) * inv[a],
            (r[2] - o[a]) * inv[a],
            (r[3] - o[a]) * inv[a],
        ];
        for c in 0..2 {
            near[c] = fmax(near[c], fmin(t[c], t[c + 2]));
            far[c] = fmin(far[c], fmax(t[c], t[c + 2]));
        }
    }
    let hit = [0, 1].map(|c| near[c] <= fmin(far[c] * SLAB_FAR_SCALE, t_max));
    (near, hit)
}

/// [`test2_portable`] in SSE (part of every x86-64 CPU): per axis one subtract and one
/// multiply for the four planes, a half swap, and `minps`/`maxps` (which, like `fmin` and
/// `fmax`, return their second operand on ties), so the same bits.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn test2_sse(
    n: &SoaNode2,
    o: &[f32; 3],
    inv: &[f32; 3],
    t_min: f32,
    t_max: f32,
) -> ([f32; 2], [bool; 2]) {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of the x86-64 baseline; each load reads one [f32; 4] row.
    unsafe {
        let mut near = _mm_set1_ps(t_min);
        let mut far = _mm_set1_ps(f32::INFINITY);
        for a in 0..3 {
            let t = _mm_mul_ps(
                _mm_sub_ps(_mm_loadu_ps(n.rows[a].as_ptr()), _mm_set1_ps(o[a])),
                _mm_set1_ps(inv[a]),
            );
            // [t2, t3, t0, t1]: each child's other plane on this axis.
            let swapped = _mm_shuffle_ps::<0b01_00_11_10>(t, t);
            near = _mm_max_ps(near, _mm_min_ps(t, swapped));
            far = _mm_min_ps(far, _mm_max_ps(t, swapped));
        }
        let limit = _mm_min_ps(
            _mm_mul_ps(far, _mm_set1_ps(SLAB_FAR_SCALE)),
            _mm_set1_ps(t_max),
        );
        let mask = _mm_movemask_ps(_mm_cmple_ps(near, limit));
        let mut d = [0f32; 4];
        _mm_storeu_ps(d.as_mut_ptr(), near);
        ([d[0], d[1]], [mask & 1 != 0, mask & 2 != 0])
    }
}

/// The child-box test of the kernel.
#[inline(always)]
fn test2(
    n: &SoaNode2,
    o: &[f32; 3],
    inv: &[f32; 3],
    t_min: f32,
    t_max: f32,
) -> ([f32; 2], [bool; 2]) {
    #[cfg(target_arch = "x86_64")]
    {
        test2_sse(n, o, inv, t_min, t_max)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        test2_portable(n, o, inv, t_min, t_max)
    }
}

impl Bvh2Accel {
    /// Prepares `bvh` (built over `triangles`) for tracing. Fails when a leaf-table entry
    /// names a triangle that does not exist, or the links fail the checks of the
    /// crate's "Trees from anywhere" section (out of range, not after the parent, a node
    /// linked twice, overlapping leaves).
    pub fn new(
        bvh: Bvh2,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        check_links(
            bvh.nodes.iter().flat_map(|n| n.children.iter()),
            2,
            bvh.nodes.len(),
            bvh.prim_indices.len(),
        )?;
        let mut nodes: Vec<SoaNode2> = huge_page_vec(bvh.nodes.len());
        nodes.extend(bvh.nodes.iter().map(SoaNode2::new));
        let leaf = LeafTriangles::pack(
            &bvh.prim_indices,
            triangles,
            nodes.iter_mut().flat_map(|n| n.children.iter_mut()),
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
    /// vertices moved (same topology): the packed triangles are rewritten and every box
    /// recomputed bottom-up, giving the same kernel as preparing the refitted tree afresh.
    pub fn refit(&mut self, triangles: &[Triangle]) -> Result<(), TraceError> {
        self.leaf.update(triangles)?;
        refit_nodes(
            &mut self.nodes,
            &self.leaf,
            |n| n.children,
            |n, c, b| {
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                for a in 0..3 {
                    n.rows[a][c] = lo[a];
                    n.rows[a][c + 2] = hi[a];
                }
            },
        );
        Ok(())
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
        let o = pre.origin.to_array();
        let inv = pre.inv_dir.to_array();
        let nodes = &self.nodes;
        let visit = |c: ChildRef,
                     best_t: f32,
                     stack: &mut TraversalStack,
                     stats: &mut RayStats,
                     obs: &mut O| {
            let index = c.index;
            let node = &nodes[index as usize];
            let (d, hit) = test2(node, &o, &inv, ray.t_min, cull_distance(best_t));
            let [c0, c1] = node.children;
            let valid = (!c0.is_empty()) as u8 | ((!c1.is_empty()) as u8) << 1;
            // An empty slot is never hit (its box at +inf could be "entered at
            // infinity" by an unbounded ray).
            let hit = [hit[0] && valid & 1 != 0, hit[1] && valid & 2 != 0];
            stats.node_visits += 1;
            stats.box_tests += valid.count_ones() as u64;
            obs.node(index, valid, hit[0] as u8 | (hit[1] as u8) << 1);
            match hit {
                [true, true] => {
                    // Front to back: continue with the nearer child, push the other.
                    let (near, far, far_d) = if d[1] < d[0] {
                        (c1, c0, d[0])
                    } else {
                        (c0, c1, d[1])
                    };
                    if far.is_leaf() {
                        self.leaf.prefetch(far.index);
                    } else {
                        prefetch(nodes.as_ptr().wrapping_add(far.index as usize));
                    }
                    stack.push(far, far_d, &self.leaf, stats, obs);
                    Some(near)
                }
                [true, false] => Some(c0),
                [false, true] => Some(c1),
                [false, false] => None,
            }
        };
        traverse_child_refs::<DIST, O>(&self.leaf, ray, &pre, query, stack, total, obs, visit)
    }
}

impl Traverse for Bvh2Accel {
    crate::accel::one_ray_kernel!(traverse);

    fn node_bytes(&self) -> u32 {
        std::mem::size_of::<bvh::Node>() as u32
    }

    fn width(&self) -> u32 {
        2
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

/// Checks the links of a tree built anywhere (the checks a tracer needs, O(nodes), not the
/// full `bvh::validate`), so that traversal never indexes outside the tree and always
/// terminates within one visit per node and ray:
///
/// - inner children name an existing node after their parent (Arbor's trees are stored
///   depth-first), which rules out cycles;
/// - no node is linked twice: a subtree shared by two parents is visited once per path
///   to it, and a chain of shared nodes makes a ray's work exponential in the depth;
/// - leaves name a range of the leaf table, and all leaves together no more entries than
///   the table holds (leaves partition it; overlapping leaves would multiply the packed
///   triangles, up to nodes x entries of them).
///
/// `children` lists the `width` child slots of each node in node order.
pub(crate) fn check_links<'a>(
    children: impl Iterator<Item = &'a ChildRef>,
    width: usize,
    nodes: usize,
    entries: usize,
) -> Result<(), TraceError> {
    if nodes == 0 {
        return Err(TraceError::BadTree("the tree has no root node".into()));
    }
    let mut linked = vec![false; nodes];
    let mut in_leaves = 0u64;
    for (i, c) in children.enumerate() {
        let parent = i / width;
        if c.is_inner() {
            let k = c.index as usize;
            if k >= nodes || k <= parent {
                return Err(TraceError::BadTree(format!(
                    "node {parent} links to inner node {} (nodes: {nodes}; children must follow their parent)",
                    c.index
                )));
            }
            if std::mem::replace(&mut linked[k], true) {
                return Err(TraceError::BadTree(format!(
                    "node {k} is linked twice (the second time from node {parent}): subtrees cannot be shared"
                )));
            }
        }
        if c.is_leaf() {
            let end = c.index as u64 + c.count as u64;
            if end > entries as u64 {
                return Err(TraceError::BadTree(format!(
                    "node {parent} has a leaf of entries {}..{end} (leaf table: {entries})",
                    c.index
                )));
            }
            in_leaves += c.count as u64;
            if in_leaves > entries as u64 {
                return Err(TraceError::BadTree(format!(
                    "the leaves up to node {parent} hold {in_leaves} entries, more than the leaf table's {entries}: leaves overlap"
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SSE box test computes the portable test's values bit for bit.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse_box_test_equals_the_portable_one() {
        let mut r = crate::testutil::Rng::new(7);
        for _ in 0..20_000 {
            let boxes = [0, 1].map(|_| {
                let a = r.vec() * 3.0;
                let b = a + (r.vec() + geom::Vec3::ONE) * if r.f32() < 0.2 { 0.0 } else { 1.0 };
                geom::Aabb::new(a.min(b), a.max(b))
            });
            let c1 = if r.f32() < 0.1 {
                ChildRef::EMPTY
            } else {
                ChildRef::leaf(0, 1)
            };
            let node = bvh::Node::new(&boxes[0], ChildRef::leaf(0, 1), &boxes[1], c1);
            let n = SoaNode2::new(&node);
            let mut d = r.vec();
            if r.f32() < 0.2 {
                d.y = 0.0;
            }
            let pre = RayPrecomp::new(&Ray::new(r.vec() * 5.0, d));
            let (o, inv) = (pre.origin.to_array(), pre.inv_dir.to_array());
            let t_min = r.f32() * 0.1;
            let t_max = if r.f32() < 0.5 {
                1.0 + r.f32() * 20.0
            } else {
                f32::INFINITY
            };
            let (a, ha) = test2_portable(&n, &o, &inv, t_min, t_max);
            let (b, hb) = test2_sse(&n, &o, &inv, t_min, t_max);
            assert_eq!(ha, hb);
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        }
    }
}
