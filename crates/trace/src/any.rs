//! [`Accel`]: any tree format behind one type, for code that picks the format at run
//! time (the `arbor render` command, benchmarks). The per-ray `match` costs one predictable
//! branch.

use crate::accel::{Hit, RaySource, TraversalStack, Traverse};
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{Bvh2Accel, CbvhAccel, Mbvh4Accel, Mbvh8Accel};
use geom::Ray;

/// A traceable tree of any format.
#[derive(Clone, Debug)]
pub enum Accel {
    /// A binary tree.
    Bvh2(Bvh2Accel),
    /// A 4-wide tree.
    Mbvh4(Mbvh4Accel),
    /// An 8-wide tree.
    Mbvh8(Mbvh8Accel),
    /// A compressed binary tree ([P3]).
    Cbvh(CbvhAccel),
}

impl Accel {
    /// `"bvh2"`, `"mbvh4"` or `"cbvh"`.
    pub fn format_name(&self) -> &'static str {
        match self {
            Accel::Bvh2(_) => "bvh2",
            Accel::Mbvh4(_) => "mbvh4",
            Accel::Mbvh8(_) => "mbvh8",
            Accel::Cbvh(_) => "cbvh",
        }
    }

    /// The kernel options.
    pub fn options(&self) -> crate::KernelOptions {
        match self {
            Accel::Bvh2(a) => a.options(),
            Accel::Mbvh4(a) => a.options(),
            Accel::Mbvh8(a) => a.options(),
            Accel::Cbvh(a) => a.options(),
        }
    }

    /// Refits in place to `triangles`, the list the tree was prepared over with its
    /// vertices moved (same topology), giving the same kernel as preparing the refitted
    /// tree afresh. Returns false, changing nothing, for a CBVH: its quantized boxes are
    /// encoded relative to their parents, so a moved CBVH is encoded again instead.
    pub fn refit(&mut self, triangles: &[geom::Triangle]) -> Result<bool, crate::TraceError> {
        match self {
            Accel::Bvh2(a) => a.refit(triangles)?,
            Accel::Mbvh4(a) => a.refit(triangles)?,
            Accel::Mbvh8(a) => a.refit(triangles)?,
            Accel::Cbvh(_) => return Ok(false),
        }
        Ok(true)
    }

    /// Bytes of the tree in memory: nodes plus the leaf table.
    pub fn tree_bytes(&self) -> usize {
        self.node_count() * self.node_bytes() as usize + self.leaf_entries() * 4
    }
}

impl Traverse for Accel {
    #[inline]
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        match self {
            Accel::Bvh2(a) => a.trace_observed(ray, query, stack, stats, obs),
            Accel::Mbvh4(a) => a.trace_observed(ray, query, stack, stats, obs),
            Accel::Mbvh8(a) => a.trace_observed(ray, query, stack, stats, obs),
            Accel::Cbvh(a) => a.trace_observed(ray, query, stack, stats, obs),
        }
    }

    #[inline]
    fn trace_batch<R: RaySource + ?Sized, F: FnMut(usize, Option<Hit>, &RayStats)>(
        &self,
        rays: &R,
        query: Query,
        stack: &mut TraversalStack,
        done: F,
    ) {
        match self {
            Accel::Bvh2(a) => a.trace_batch(rays, query, stack, done),
            Accel::Mbvh4(a) => a.trace_batch(rays, query, stack, done),
            Accel::Mbvh8(a) => a.trace_batch(rays, query, stack, done),
            Accel::Cbvh(a) => a.trace_batch(rays, query, stack, done),
        }
    }

    fn node_bytes(&self) -> u32 {
        match self {
            Accel::Bvh2(a) => a.node_bytes(),
            Accel::Mbvh4(a) => a.node_bytes(),
            Accel::Mbvh8(a) => a.node_bytes(),
            Accel::Cbvh(a) => a.node_bytes(),
        }
    }

    fn width(&self) -> u32 {
        match self {
            Accel::Bvh2(a) => a.width(),
            Accel::Mbvh4(a) => a.width(),
            Accel::Mbvh8(a) => a.width(),
            Accel::Cbvh(a) => a.width(),
        }
    }

    fn node_count(&self) -> usize {
        match self {
            Accel::Bvh2(a) => a.node_count(),
            Accel::Mbvh4(a) => a.node_count(),
            Accel::Mbvh8(a) => a.node_count(),
            Accel::Cbvh(a) => a.node_count(),
        }
    }

    fn source_triangles(&self) -> usize {
        match self {
            Accel::Bvh2(a) => a.source_triangles(),
            Accel::Mbvh4(a) => a.source_triangles(),
            Accel::Mbvh8(a) => a.source_triangles(),
            Accel::Cbvh(a) => a.source_triangles(),
        }
    }

    fn leaf_entries(&self) -> usize {
        match self {
            Accel::Bvh2(a) => a.leaf_entries(),
            Accel::Mbvh4(a) => a.leaf_entries(),
            Accel::Mbvh8(a) => a.leaf_entries(),
            Accel::Cbvh(a) => a.leaf_entries(),
        }
    }
}
