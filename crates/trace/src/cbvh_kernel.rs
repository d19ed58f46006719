//! Traversal of a compressed BVH ([P3], `cbvh::Cbvh`): the binary kernel's loop (test
//! both children of a node, continue with the nearer hit child, push the farther, cull
//! against the closest hit) over 16-byte node pairs whose child boxes are decoded on the
//! fly, per node visit, from the pair's quantized coordinates and the node's traversal
//! context, as [P3] Fig. 4 describes.
//!
//! Per visit the kernel unpacks the pair from the packed bit layout (`docs/cbvh-format.md`),
//! decodes both child boxes with `cbvh::codec::decode_boxes` (relative coordinates by
//! Eq. 3, modulo coordinates by Eq. 9; bounds rounded outward to `f32`, so a decoded box
//! encloses the original), tests them with the same slab test as the other kernels
//! (`geom::ray_aabb`), and computes a child's own context (its grid scale, Eq. 2) only for
//! the inner children it enters or pushes. Decoding and contexts are the `cbvh` crate's
//! functions, the ones its encoders and `Cbvh::decode_to_bvh2` use, so the kernel tests
//! exactly the boxes the encoder meant.
//!
//! Each stack entry needs the context of the node it names; the contexts live on a
//! per-thread stack beside [`TraversalStack`]'s entries (same depth, same order), so the
//! kernel allocates nothing per ray. Counters and [`Observer`] events are those of the
//! `Bvh2` kernel (a node is a pair, named by its index; `node_bytes` is the packed pair
//! size, 16 at 6 bits). Decoded boxes only ever enclose the originals, so by the tie-break
//! rule of [`crate::Hit`] the hits are those of every other tree, bit for bit; only the
//! work differs, which is the tree-quality measurement of [P3] §5.4.
//!
//! A [`BoxObserver`] receives each visit's decoded boxes besides the [`Observer`] events: the watertightness
//! check of [P3] §5.5 ([`crate::WatertightCheck`]) uses it.

use crate::accel::{
    cull_distance, huge_page_vec, prefetch, Hit, LeafTriangles, TraversalStack, Traverse,
};
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::ChildRef;
use cbvh::codec::{decode_boxes, slot_ptr, ChildPtr};
use cbvh::format::{pair_bytes, NodePair, Slot};
use cbvh::{Cbvh, Ctx, Params};
use geom::{ray_aabb, Aabb, Ray, RayPrecomp, Triangle};
use std::cell::RefCell;

/// Receives the decoded child boxes of every node pair the CBVH kernel visits, beside
/// the [`Observer`] events (the watertightness check of [P3] §5.5 uses it).
#[allow(unused_variables)]
pub trait BoxObserver {
    /// The children of pair `pair` decoded to `boxes` (`None`: the absent child) and were
    /// tested against the ray over `[t_min, t_max]` (`t_max` already widened by
    /// [`cull_distance`]); bit `i` of `hit` is set for each child the test hit. Called just
    /// before [`Observer::node`] for the same visit.
    #[inline(always)]
    fn boxes(&mut self, pair: u32, boxes: &[Option<Aabb>; 2], t_min: f32, t_max: f32, hit: u8) {}
}

impl BoxObserver for () {}

thread_local! {
    /// Contexts of the entries of the traversal stack in use on this thread.
    static CONTEXTS: RefCell<Vec<Ctx>> = RefCell::new(Vec::with_capacity(64));
}

/// Zero bytes after the last pair (a slot read loads 16 bytes from its first byte).
const PAD_BYTES: usize = 16;

/// A [`Cbvh`] with its triangles in leaf order, ready to trace. The node pairs are kept
/// packed, as in memory ([`Cbvh::to_bytes`]).
#[derive(Clone, Debug)]
pub struct CbvhAccel {
    /// Packed node pairs, `pair_bytes` each.
    bytes: Vec<u8>,
    pair_bytes: usize,
    pairs: usize,
    params: Params,
    root: u32,
    root_ctx: Ctx,
    /// Per primitive-id entry that starts a leaf: the leaf's slot in `leaf` and its length
    /// (from the leaf-end flags of the primitive-id array).
    leaf_of: Vec<[u32; 2]>,
    leaf: LeafTriangles,
    options: KernelOptions,
}

impl CbvhAccel {
    /// Prepares `cbvh` (compressed from a tree over `triangles`) for tracing. Fails when
    /// its parameters or root context are out of range, a pointer leaves the tree, forms a
    /// cycle or reaches a pair twice, a leaf has no end, leaves overlap, a decoded box is
    /// not finite, or a primitive id names a triangle that does not exist. (The check
    /// decodes the tree once, without recursion, so a tree as deep as it is long is fine.)
    pub fn new(
        cbvh: &Cbvh,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        let bad = |e: cbvh::CbvhError| TraceError::BadTree(e.to_string());
        cbvh.params.check().map_err(bad)?;
        let finite = |b: &Aabb| b.min.is_finite() && b.max.is_finite();
        if !finite(&cbvh.root_ctx.aabb()) {
            return Err(TraceError::BadTree("the root context is not finite".into()));
        }
        // One full decode: pointers in range, no cycles, every leaf ends, finite boxes.
        let decoded = cbvh.decode_to_bvh2().map_err(bad)?;
        for n in &decoded.nodes {
            for c in 0..2 {
                if !n.children[c].is_empty() && !finite(&n.child_aabb(c)) {
                    return Err(TraceError::BadTree("a decoded box is not finite".into()));
                }
            }
        }
        // The leaves in tree order (the decode is in preorder), packed for 4-wide tests;
        // `leaf_of` maps a leaf pointer (its first primitive-id entry) to its slot.
        let mut leaves: Vec<ChildRef> = decoded
            .nodes
            .iter()
            .flat_map(|n| n.children)
            .filter(|c| c.is_leaf())
            .collect();
        let firsts: Vec<u32> = leaves.iter().map(|c| c.index).collect();
        let leaf = LeafTriangles::pack(&decoded.prim_indices, triangles, leaves.iter_mut())
            .map_err(|e| e.into_trace_error(triangles.len()))?;
        drop(decoded);
        let mut leaf_of = vec![[u32::MAX, 0]; cbvh.prim_ids.len()];
        for (first, packed) in firsts.iter().zip(&leaves) {
            leaf_of[*first as usize] = [packed.index, packed.count];
        }
        let packed = cbvh.to_bytes().map_err(bad)?;
        // Padding, so that every slot is read with one 16-byte load.
        let mut bytes = huge_page_vec(packed.len() + PAD_BYTES);
        bytes.extend_from_slice(&packed);
        bytes.resize(packed.len() + PAD_BYTES, 0);
        Ok(Self {
            bytes,
            pair_bytes: pair_bytes(cbvh.params.bits),
            pairs: cbvh.pairs.len(),
            params: cbvh.params,
            root: cbvh.root,
            root_ctx: cbvh.root_ctx,
            leaf_of,
            leaf,
            options,
        })
    }

    /// The kernel options.
    pub fn options(&self) -> KernelOptions {
        self.options
    }

    /// The quantization parameters of the tree.
    pub fn params(&self) -> Params {
        self.params
    }

    /// [`Traverse::trace_observed`] with a [`BoxObserver`] that also receives every
    /// visit's decoded child boxes.
    #[inline]
    pub fn trace_boxes<O: Observer, B: BoxObserver>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
        boxes: &mut B,
    ) -> Option<Hit> {
        CONTEXTS.with(|cell| match cell.try_borrow_mut() {
            Ok(mut ctxs) => self.dispatch(ray, query, stack, stats, obs, boxes, &mut ctxs),
            // Only reachable when an observer traces a ray from inside a traversal.
            Err(_) => self.dispatch(ray, query, stack, stats, obs, boxes, &mut Vec::new()),
        })
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn dispatch<O: Observer, B: BoxObserver>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
        boxes: &mut B,
        ctxs: &mut Vec<Ctx>,
    ) -> Option<Hit> {
        if self.options.distance_stack {
            self.run::<true, O, B>(ray, query, stack, stats, obs, boxes, ctxs)
        } else {
            self.run::<false, O, B>(ray, query, stack, stats, obs, boxes, ctxs)
        }
    }

    /// Pair `i`, unpacked (pointers were checked at construction; a pair that cannot be
    /// read acts as one without children).
    #[inline(always)]
    fn pair(&self, i: u32) -> NodePair {
        self.bytes
            .get(i as usize * self.pair_bytes..)
            .and_then(|b| NodePair::unpack(self.params.bits, b).ok())
            .unwrap_or(NodePair {
                slots: [Slot::EMPTY; 2],
            })
    }

    /// The child a slot names: an inner pair, or a leaf (its packed slot and length).
    #[inline(always)]
    fn child(&self, s: &Slot) -> ChildRef {
        match slot_ptr(s) {
            ChildPtr::Inner(k) => ChildRef::inner(k),
            ChildPtr::Leaf(first) => {
                // Every leaf of the tree was packed at construction.
                let [slot, count] = self
                    .leaf_of
                    .get(first as usize)
                    .copied()
                    .unwrap_or([u32::MAX, 1]);
                ChildRef::leaf(slot, count.max(1))
            }
            ChildPtr::Empty => ChildRef::EMPTY,
        }
    }

    /// The context of child `c` (decoded box `b`) when it is an inner node; the parent's
    /// `ctx` otherwise (a leaf needs none, the slot just keeps the stacks in step).
    #[inline(always)]
    fn child_ctx(&self, child: ChildRef, b: &Aabb, ctx: &Ctx) -> Ctx {
        if child.is_inner() {
            Ctx::from_decoded(b, &self.params)
        } else {
            *ctx
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn run<const DIST: bool, O: Observer, B: BoxObserver>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        total: &mut RayStats,
        obs: &mut O,
        box_obs: &mut B,
        ctxs: &mut Vec<Ctx>,
    ) -> Option<Hit> {
        let mut ray_stats = RayStats::default();
        let stats = &mut ray_stats;
        let pre = RayPrecomp::new(ray);
        obs.begin(ray, query);
        stats.rays += 1;
        stack.entries.clear();
        ctxs.clear();
        let mut best: Option<Hit> = None;
        let mut best_t = ray.t_max;
        // A ray with a NaN or infinite origin or direction hits nothing (as in Bvh2).
        let finite = geom::is_finite3(ray.origin) && geom::is_finite3(ray.dir);
        let mut cur = finite.then_some((ChildRef::inner(self.root), self.root_ctx));
        while let Some((c, ctx)) = cur {
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
                let pair = self.pair(c.index);
                let boxes = decode_boxes(&pair, &ctx, &self.params);
                let t_max = cull_distance(best_t);
                let test = |b: &Option<Aabb>| b.and_then(|b| ray_aabb(&pre, &b, ray.t_min, t_max));
                let d = [test(&boxes[0]), test(&boxes[1])];
                let valid = boxes[0].is_some() as u8 | (boxes[1].is_some() as u8) << 1;
                let hit = d[0].is_some() as u8 | (d[1].is_some() as u8) << 1;
                stats.node_visits += 1;
                stats.box_tests += valid.count_ones() as u64;
                box_obs.boxes(c.index, &boxes, ray.t_min, t_max, hit);
                obs.node(c.index, valid, hit);
                let enter = |k: usize| {
                    let child = self.child(&pair.slots[k]);
                    // A hit slot always has a box.
                    let b = boxes[k].unwrap_or(Aabb::EMPTY);
                    (child, self.child_ctx(child, &b, &ctx))
                };
                match d {
                    [Some(d0), Some(d1)] => {
                        // Front to back: continue with the nearer child, push the other.
                        let (near, far, far_d) = if d1 < d0 { (1, 0, d0) } else { (0, 1, d1) };
                        let (fc, fctx) = enter(far);
                        if fc.is_leaf() {
                            self.leaf.prefetch(fc.index);
                        } else {
                            prefetch(
                                self.bytes
                                    .as_ptr()
                                    .wrapping_add(fc.index as usize * self.pair_bytes),
                            );
                        }
                        stack.push(fc, far_d, &self.leaf, stats, obs);
                        ctxs.push(fctx);
                        cur = Some(enter(near));
                        continue;
                    }
                    [Some(_), None] => {
                        cur = Some(enter(0));
                        continue;
                    }
                    [None, Some(_)] => {
                        cur = Some(enter(1));
                        continue;
                    }
                    [None, None] => {}
                }
            }
            cur = stack.pop(DIST, best_t, stats, obs).map(|c| {
                // The popped entry (and any culled above it) leaves both stacks.
                let k = stack.entries.len();
                let ctx = ctxs[k];
                ctxs.truncate(k);
                (c, ctx)
            });
        }
        stats.hits += best.is_some() as u64;
        total.add(stats);
        obs.end(best.as_ref());
        best
    }
}

impl Traverse for CbvhAccel {
    #[inline]
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        self.trace_boxes(ray, query, stack, stats, obs, &mut ())
    }

    fn node_bytes(&self) -> u32 {
        self.pair_bytes as u32
    }

    fn width(&self) -> u32 {
        2
    }

    fn node_count(&self) -> usize {
        self.pairs
    }

    fn source_triangles(&self) -> usize {
        self.leaf.source_len
    }

    fn leaf_entries(&self) -> usize {
        self.leaf.entry_count()
    }
}
