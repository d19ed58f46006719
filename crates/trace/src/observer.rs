//! What a traversal kernel reports while it runs, for traversal logs and hardware models.
//!
//! The kernels are generic over an [`Observer`]; the unit type `()` ignores every event and
//! compiles away, so a plain render pays nothing for the hooks. The events are what the
//! traversal hardware of [P4] §3 does per ray: fetch an inner node and test its child boxes
//! (TRV), push and pop stack entries, fetch a leaf's triangles and test them (IST), and
//! finish with a hit or a miss.

use crate::Hit;
use bvh::ChildRef;
use geom::Ray;

/// The kind of query a ray asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Query {
    /// The closest hit along the ray.
    Closest,
    /// Whether anything is hit (occlusion); traversal stops at the first hit.
    Any,
}

/// Receives a kernel's events in the order they happen.
#[allow(unused_variables)]
pub trait Observer {
    /// A ray starts.
    #[inline(always)]
    fn begin(&mut self, ray: &Ray, query: Query) {}
    /// Inner node `node` was fetched and its child boxes tested: bit `i` of `valid` is set
    /// for each non-empty child slot, bit `i` of `hit` for each slot whose box the ray hit
    /// (within the current closest hit).
    #[inline(always)]
    fn node(&mut self, node: u32, valid: u8, hit: u8) {}
    /// `child` was pushed onto the traversal stack.
    #[inline(always)]
    fn push(&mut self, child: ChildRef) {}
    /// The top stack entry was popped; `culled` when it was skipped because its entry
    /// distance lies beyond the closest hit (distance stack).
    #[inline(always)]
    fn pop(&mut self, culled: bool) {}
    /// The leaf of leaf-table entries `first .. first + count` is visited: its triangles are
    /// fetched and tested (an any-hit query may stop before the last, see [`Observer::end`]).
    #[inline(always)]
    fn leaf(&mut self, first: u32, count: u32) {}
    /// The ray finished with `hit` (for an any-hit query, the first hit found).
    #[inline(always)]
    fn end(&mut self, hit: Option<&Hit>) {}
}

impl Observer for () {}
