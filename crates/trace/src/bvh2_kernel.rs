//! Traversal of the binary `Bvh2` ([P2] §4.1): a stack-based loop that tests both child
//! boxes of a node, continues with the nearer hit child and pushes the farther one, and
//! culls boxes against the closest hit so far (the slab test's far limit is the closest
//! hit's distance).
//!
//! This is the baseline traversal unit of [P4] §3 (Fig. 3 top): two parallel ray/box
//! tests per node and a compare-and-swap of the two children into front-to-back order.
//! [P4] keeps the BVH without a distance stack; it can be switched on
//! ([`KernelOptions::distance_stack`]) to measure its effect ([P4] §3.1 reports about 3%
//! for BVH).

use crate::accel::{cull_distance, Hit, LeafTriangles, Slab, TraversalStack, Traverse};
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::{Bvh2, ChildRef};
use geom::{Ray, RayPrecomp, Triangle};

/// A `Bvh2` with its triangles in leaf order, ready to trace.
#[derive(Clone, Debug)]
pub struct Bvh2Accel {
    bvh: Bvh2,
    leaf: LeafTriangles,
    options: KernelOptions,
}

impl Bvh2Accel {
    /// Prepares `bvh` (built over `triangles`) for tracing. Fails when a leaf-table entry
    /// names a triangle that does not exist, or a child link points outside the tree.
    pub fn new(
        bvh: Bvh2,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        let leaf = LeafTriangles::new(&bvh.prim_indices, triangles).map_err(|(entry, prim)| {
            TraceError::PrimitiveOutOfRange {
                entry,
                prim,
                triangles: triangles.len(),
            }
        })?;
        check_links(
            bvh.nodes.iter().flat_map(|n| n.children.iter()),
            2,
            bvh.nodes.len(),
            bvh.prim_indices.len(),
        )?;
        Ok(Self { bvh, leaf, options })
    }

    /// The tree.
    pub fn bvh(&self) -> &Bvh2 {
        &self.bvh
    }

    /// The kernel options.
    pub fn options(&self) -> KernelOptions {
        self.options
    }

    fn run<const DIST: bool, O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let slab = Slab::new(&pre, ray.t_min);
        let nodes = &self.bvh.nodes;
        obs.begin(ray, query);
        stats.rays += 1;
        stack.entries.clear();
        let mut best: Option<Hit> = None;
        let mut best_t = ray.t_max;
        // A ray with a NaN or infinite origin or direction hits nothing (the slab test
        // assumes finite values; a NaN would make every box, even an empty slot, "hit").
        let finite = geom::is_finite3(ray.origin) && geom::is_finite3(ray.dir);
        let mut cur = finite.then_some(ChildRef::inner(0));
        while let Some(c) = cur {
            if c.is_leaf() {
                let stop = self.leaf.intersect(
                    c.index,
                    c.count,
                    &pre,
                    ray.t_min,
                    query,
                    &mut best,
                    &mut best_t,
                    stats,
                    obs,
                );
                if stop {
                    break;
                }
            } else {
                let node = &nodes[c.index as usize];
                let cull = cull_distance(best_t);
                let d0 = slab.test(&node.bounds[0], cull);
                let d1 = slab.test(&node.bounds[1], cull);
                let [c0, c1] = node.children;
                let valid = (!c0.is_empty()) as u8 | ((!c1.is_empty()) as u8) << 1;
                stats.node_visits += 1;
                stats.box_tests += valid.count_ones() as u64;
                obs.node(
                    c.index,
                    valid,
                    d0.is_some() as u8 | (d1.is_some() as u8) << 1,
                );
                match (d0, d1) {
                    (Some(a), Some(b)) => {
                        // Front to back: continue with the nearer child, push the other.
                        let (near, far, far_d) = if b < a { (c1, c0, a) } else { (c0, c1, b) };
                        stack.push(far, far_d, stats, obs);
                        cur = Some(near);
                        continue;
                    }
                    (Some(_), None) => {
                        cur = Some(c0);
                        continue;
                    }
                    (None, Some(_)) => {
                        cur = Some(c1);
                        continue;
                    }
                    (None, None) => {}
                }
            }
            cur = stack.pop(DIST, best_t, stats, obs);
        }
        stats.hits += best.is_some() as u64;
        obs.end(best.as_ref());
        best
    }
}

impl Traverse for Bvh2Accel {
    #[inline]
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        if self.options.distance_stack {
            self.run::<true, O>(ray, query, stack, stats, obs)
        } else {
            self.run::<false, O>(ray, query, stack, stats, obs)
        }
    }

    fn node_bytes(&self) -> u32 {
        std::mem::size_of::<bvh::Node>() as u32
    }

    fn width(&self) -> u32 {
        2
    }

    fn node_count(&self) -> usize {
        self.bvh.nodes.len()
    }

    fn source_triangles(&self) -> usize {
        self.leaf.source_len
    }

    fn leaf_entries(&self) -> usize {
        self.leaf.prims.len()
    }
}

/// Checks that every child link stays inside the tree: inner children name an existing
/// node, leaves a range of the leaf table. Traversal also needs the tree to be acyclic to
/// terminate: Arbor's trees are stored depth-first, so every inner child has a larger index
/// than its parent, and this is checked too. `children` lists the `width` child slots of
/// each node in node order.
pub(crate) fn check_links<'a>(
    children: impl Iterator<Item = &'a ChildRef>,
    width: usize,
    nodes: usize,
    entries: usize,
) -> Result<(), TraceError> {
    for (i, c) in children.enumerate() {
        let parent = i / width;
        if c.is_inner() && (c.index as usize >= nodes || c.index as usize <= parent) {
            return Err(TraceError::BadTree(format!(
                "node {parent} links to inner node {} (nodes: {nodes}; children must follow their parent)",
                c.index
            )));
        }
        if c.is_leaf() && c.index as u64 + c.count as u64 > entries as u64 {
            return Err(TraceError::BadTree(format!(
                "node {parent} has a leaf of entries {}..{} (leaf table: {entries})",
                c.index,
                c.index as u64 + c.count as u64
            )));
        }
    }
    if nodes == 0 {
        return Err(TraceError::BadTree("the tree has no root node".into()));
    }
    Ok(())
}
