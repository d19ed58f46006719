//! The watertightness check of [P3] §5.5 over real traversals: for every box test the
//! CBVH kernel makes, the same test on the original, full-precision box.
//!
//! [P3] §5.5 verifies, over every box test of path-traced renders, the criterion under
//! which Vaidyanathan et al.'s reduced-precision traversal is proven watertight: the
//! parametric interval `[t_near, t_far]` of the decoded box encloses the exact interval
//! of the uncompressed box. [`WatertightCheck`] is a [`Traverse`] that traces with a
//! [`CbvhAccel`] and, through the kernel's [`BoxObserver`] hook, checks each tested child:
//!
//! - the criterion itself, with `cbvh::interval_encloses` (both intervals in `f64`, over
//!   the range the kernel tested, `[t_min, cull_distance(best_t)]`);
//! - that the kernel's own `f32` slab test did not miss the decoded box while the same
//!   test hits the original box: a false miss, which is what watertightness protects
//!   against.
//!
//! The original box of each child is the union of the primitive boxes below it
//! (`Cbvh::original_child_boxes`), the box the uncompressed tree has. Rendering through the
//! check gives the same image as the kernel alone; the counts accumulate over all rays.

use crate::accel::{Hit, TraversalStack, Traverse};
use crate::cbvh_kernel::{BoxObserver, CbvhAccel};
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use cbvh::Cbvh;
use geom::{ray_aabb, Aabb, Ray, RayPrecomp, Triangle};
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};

/// Counts of the [P3] §5.5 check.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct WatertightStats {
    /// Rays traced through the check.
    pub rays: u64,
    /// Box tests checked (one per non-empty child of each visited node pair).
    pub box_tests: u64,
    /// Of those, tests whose original box the ray overlaps within the tested range (the
    /// exact `f64` interval is not empty): the tests the criterion constrains.
    pub original_hits: u64,
    /// Tests where the decoded box's parametric interval does not enclose the original
    /// box's ([P3] §5.5's criterion; expected 0).
    pub interval_violations: u64,
    /// Tests where the kernel's slab test missed the decoded box although the same test
    /// hits the original box (a false miss; expected 0).
    pub false_misses: u64,
}

impl WatertightStats {
    /// True when no test violated either condition.
    pub fn watertight(&self) -> bool {
        self.interval_violations == 0 && self.false_misses == 0
    }
}

/// A [`CbvhAccel`] whose every box test is checked against the original box (see the
/// module header). Trace or render through it like any tree; read the counts with
/// [`WatertightCheck::stats`].
#[derive(Debug)]
pub struct WatertightCheck {
    accel: CbvhAccel,
    original: Vec<[Aabb; 2]>,
    counts: [AtomicU64; 5],
}

impl WatertightCheck {
    /// Prepares `cbvh` (compressed from a tree over `triangles`) for checked tracing; the
    /// original boxes are the triangles' boxes.
    pub fn new(
        cbvh: &Cbvh,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        let prims: Vec<Aabb> = triangles.iter().map(|t| t.aabb()).collect();
        Self::with_primitive_boxes(cbvh, triangles, &prims, options)
    }

    /// [`WatertightCheck::new`] with the original boxes made from `prims` (by primitive
    /// id) instead of the triangles' boxes: for a tree built over other boxes than the
    /// triangles it is traced against.
    pub fn with_primitive_boxes(
        cbvh: &Cbvh,
        triangles: &[Triangle],
        prims: &[Aabb],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        let accel = CbvhAccel::new(cbvh, triangles, options)?;
        let original = cbvh
            .original_child_boxes(prims)
            .map_err(|e| TraceError::BadTree(e.to_string()))?;
        Ok(Self {
            accel,
            original,
            counts: Default::default(),
        })
    }

    /// The kernel traced through.
    pub fn accel(&self) -> &CbvhAccel {
        &self.accel
    }

    /// The counts so far, over every ray traced through the check.
    pub fn stats(&self) -> WatertightStats {
        let c = |i: usize| self.counts[i].load(Ordering::Relaxed);
        WatertightStats {
            rays: c(0),
            box_tests: c(1),
            original_hits: c(2),
            interval_violations: c(3),
            false_misses: c(4),
        }
    }
}

/// The per-ray checker of the boxes.
struct Checker<'a> {
    original: &'a [[Aabb; 2]],
    ray: &'a Ray,
    pre: RayPrecomp,
    counts: [u64; 5],
}

impl BoxObserver for Checker<'_> {
    fn boxes(&mut self, pair: u32, boxes: &[Option<Aabb>; 2], t_min: f32, t_max: f32, hit: u8) {
        let Some(orig) = self.original.get(pair as usize) else {
            return;
        };
        let (o, d) = (self.ray.origin, self.ray.dir);
        for c in 0..2 {
            let Some(decoded) = &boxes[c] else { continue };
            let original = &orig[c];
            self.counts[1] += 1;
            if cbvh::tree::slab_interval(o, d, t_min, t_max, original).is_some() {
                self.counts[2] += 1;
            }
            if !cbvh::interval_encloses(o, d, t_min, t_max, original, decoded) {
                self.counts[3] += 1;
            }
            let kernel_hit = hit >> c & 1 != 0;
            if !kernel_hit && ray_aabb(&self.pre, original, t_min, t_max).is_some() {
                self.counts[4] += 1;
            }
        }
    }
}

impl Traverse for WatertightCheck {
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        let mut ck = Checker {
            original: &self.original,
            ray,
            pre: RayPrecomp::new(ray),
            counts: [1, 0, 0, 0, 0],
        };
        let hit = self
            .accel
            .trace_boxes(ray, query, stack, stats, obs, &mut ck);
        for (total, n) in self.counts.iter().zip(ck.counts) {
            total.fetch_add(n, Ordering::Relaxed);
        }
        hit
    }

    fn node_bytes(&self) -> u32 {
        self.accel.node_bytes()
    }

    fn width(&self) -> u32 {
        self.accel.width()
    }

    fn node_count(&self) -> usize {
        self.accel.node_count()
    }

    fn source_triangles(&self) -> usize {
        self.accel.source_triangles()
    }

    fn leaf_entries(&self) -> usize {
        self.accel.leaf_entries()
    }
}
