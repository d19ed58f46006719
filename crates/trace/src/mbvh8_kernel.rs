//! Traversal of an 8-wide BVH: beyond the thesis, which stops at four ([P4] §3.1 notes
//! that other branching factors are interesting in custom hardware). An 8-wide tree,
//! made by the same SAH-guided collapse as `Mbvh4` ([`bvh::Collapse::collapse_wide`]),
//! needs fewer dependent node fetches per ray than a 4-wide one, which is what bounds an
//! incoherent ray's time once the tree no longer fits the caches; CPU ray tracers with
//! 8-lane SIMD (Embree's BVH8) use it for that reason.
//!
//! A node is 256 bytes: per box plane one row of the eight children (six 32-byte rows),
//! then the eight child references. A visit tests the eight boxes as two 4-wide halves,
//! continues with the nearest hit child and pushes the others farthest first, with the
//! distance stack (as [`crate::Mbvh4Accel`]). Counters and observer events are those of
//! the other kernels (child masks of eight bits).

use crate::accel::{
    cull_distance, huge_page_vec, prefetch, refit_nodes, traverse, Hit, LeafTriangles, Slab,
    TraversalStack, Traverse,
};
use crate::bvh2_kernel::check_links;
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::{ChildRef, WideBvh};
use geom::{Aabb, Ray, RayPrecomp, Triangle, SLAB_FAR_SCALE};

/// Child slots per node.
pub const WIDTH8: usize = 8;

/// A node: six plane rows (`min_x, min_y, min_z, max_x, max_y, max_z`) of eight lanes,
/// then the child references; 256 bytes on 64-byte cache lines.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
struct Node8 {
    rows: [[f32; WIDTH8]; 6],
    children: [ChildRef; WIDTH8],
}

const _: () = assert!(std::mem::size_of::<Node8>() == 256);

impl Node8 {
    fn new(n: &bvh::WideNode<WIDTH8>) -> Self {
        let mut rows = [[0f32; WIDTH8]; 6];
        for (i, b) in n.boxes.iter().enumerate() {
            // The kernel tells used slots by their boxes: an absent child gets the empty
            // box (never hit, whatever box the tree stored), so it is never entered.
            let b = if n.children[i].is_empty() {
                &Aabb::EMPTY
            } else {
                b
            };
            let v = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
            for p in 0..6 {
                rows[p][i] = v[p];
            }
        }
        Self {
            rows,
            children: n.children,
        }
    }
}

/// An 8-wide BVH with its triangles in leaf order, ready to trace.
#[derive(Clone, Debug)]
pub struct Mbvh8Accel {
    nodes: Vec<Node8>,
    leaf: LeafTriangles,
    options: KernelOptions,
    /// The CPU has AVX (checked once): the kernel then tests all eight boxes in one
    /// 8-lane operation, compiled for AVX.
    avx: bool,
}

/// Entry distances of a node's eight children (`+inf` for a missed or empty slot), the
/// hit mask and the mask of non-empty slots (an empty slot is the only one with
/// `min_x = +inf`).
#[inline(always)]
fn test8(slab: &Slab, n: &Node8, t_max: f32) -> ([f32; WIDTH8], u8, u8) {
    let mut dist = [f32::INFINITY; WIDTH8];
    let (mut mask, mut valid) = (0u8, 0u8);
    for half in 0..2 {
        let (d, m, v) = test_half(slab, n, half * 4, t_max);
        dist[half * 4..half * 4 + 4].copy_from_slice(&d);
        mask |= m << (half * 4);
        valid |= v << (half * 4);
    }
    (dist, mask, valid)
}

/// [`test8`] in AVX: the same operations on all eight lanes at once (the same bits as the
/// two SSE halves: same IEEE operations, `vmaxps`/`vminps` return their second operand on
/// NaN like `maxps`/`minps`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn test8_avx(slab: &Slab, n: &Node8, t_max: f32) -> ([f32; WIDTH8], u8, u8) {
    use std::arch::x86_64::*;
    // SAFETY: the caller runs with AVX enabled (this function's target feature); every
    // load reads one 8-lane row of the node.
    unsafe {
        let row = |p: usize| _mm256_loadu_ps(n.rows[p % 6].as_ptr());
        let o = slab.origin;
        let d = slab.inv_dir;
        let t = |p: usize, a: usize| {
            _mm256_mul_ps(
                _mm256_sub_ps(row(p), _mm256_set1_ps(o[a])),
                _mm256_set1_ps(d[a]),
            )
        };
        let near = _mm256_max_ps(
            _mm256_max_ps(t(slab.near[0], 0), t(slab.near[1], 1)),
            _mm256_max_ps(t(slab.near[2], 2), _mm256_set1_ps(slab.t_min)),
        );
        let far = _mm256_mul_ps(
            _mm256_min_ps(
                _mm256_min_ps(t(slab.far[0], 0), t(slab.far[1], 1)),
                t(slab.far[2], 2),
            ),
            _mm256_set1_ps(SLAB_FAR_SCALE),
        );
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(near, _mm256_min_ps(far, _mm256_set1_ps(t_max)));
        let inf = _mm256_set1_ps(f32::INFINITY);
        let dist = _mm256_blendv_ps(inf, near, hit);
        let mut out = [0f32; WIDTH8];
        _mm256_storeu_ps(out.as_mut_ptr(), dist);
        let valid = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(row(0), inf)) as u8;
        (out, _mm256_movemask_ps(hit) as u8, valid)
    }
}

/// Lanes `lo .. lo + 4` of [`test8`] in SSE (the x86-64 baseline).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn test_half(slab: &Slab, n: &Node8, lo: usize, t_max: f32) -> ([f32; 4], u8, u8) {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of the x86-64 baseline; `lo` is 0 or 4, so every load reads
    // four floats inside one 8-lane row of the node.
    unsafe {
        let row = |p: usize| _mm_loadu_ps(n.rows[p % 6].as_ptr().add(lo));
        let o = slab.origin;
        let d = slab.inv_dir;
        let t = |p: usize, a: usize| {
            _mm_mul_ps(_mm_sub_ps(row(p), _mm_set1_ps(o[a])), _mm_set1_ps(d[a]))
        };
        let near = _mm_max_ps(
            _mm_max_ps(t(slab.near[0], 0), t(slab.near[1], 1)),
            _mm_max_ps(t(slab.near[2], 2), _mm_set1_ps(slab.t_min)),
        );
        let far = _mm_mul_ps(
            _mm_min_ps(
                _mm_min_ps(t(slab.far[0], 0), t(slab.far[1], 1)),
                t(slab.far[2], 2),
            ),
            _mm_set1_ps(SLAB_FAR_SCALE),
        );
        let hit = _mm_cmple_ps(near, _mm_min_ps(far, _mm_set1_ps(t_max)));
        let inf = _mm_set1_ps(f32::INFINITY);
        let dist = _mm_or_ps(_mm_and_ps(hit, near), _mm_andnot_ps(hit, inf));
        let mut out = [0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), dist);
        let valid = _mm_movemask_ps(_mm_cmplt_ps(row(0), inf)) as u8;
        (out, _mm_movemask_ps(hit) as u8, valid)
    }
}

/// Lanes `lo .. lo + 4` of [`test8`], lane by lane (off x86-64).
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn test_half(slab: &Slab, n: &Node8, lo: usize, t_max: f32) -> ([f32; 4], u8, u8) {
    use crate::accel::{fmax, fmin};
    let o = slab.origin;
    let d = slab.inv_dir;
    let mut dist = [f32::INFINITY; 4];
    let (mut mask, mut valid) = (0u8, 0u8);
    for i in 0..4 {
        let v = |p: usize, a: usize| (n.rows[p % 6][lo + i] - o[a]) * d[a];
        let near = fmax(
            fmax(v(slab.near[0], 0), v(slab.near[1], 1)),
            fmax(v(slab.near[2], 2), slab.t_min),
        );
        let far = fmin(
            fmin(v(slab.far[0], 0), v(slab.far[1], 1)),
            v(slab.far[2], 2),
        ) * SLAB_FAR_SCALE;
        let hit = near <= fmin(far, t_max);
        dist[i] = if hit { near } else { f32::INFINITY };
        mask |= (hit as u8) << i;
        valid |= ((n.rows[0][lo + i] < f32::INFINITY) as u8) << i;
    }
    (dist, mask, valid)
}

/// Bits set in each byte (a table: the x86-64 baseline has no popcount instruction).
const POPCOUNT8: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = (i as u32).count_ones() as u8;
        i += 1;
    }
    t
};

/// A sort key per hit child: the entry distance as an order-preserving integer with the
/// slot in its three low bits (distances within 8 ulps order by slot).
#[inline(always)]
fn key(dist: f32, slot: usize) -> u32 {
    let b = dist.to_bits();
    let ordered = if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    };
    (ordered & !7) | slot as u32
}

impl Mbvh8Accel {
    /// Prepares an 8-wide tree (built over `triangles`) for tracing. Fails when a leaf
    /// names a triangle that does not exist, or the links fail the checks of the
    /// crate's "Trees from anywhere" section (out of range, not after the parent, a node
    /// linked twice, overlapping leaves).
    pub fn new(
        bvh: WideBvh<WIDTH8>,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        check_links(
            bvh.nodes.iter().flat_map(|n| n.children.iter()),
            WIDTH8,
            bvh.nodes.len(),
            bvh.prim_indices.len(),
        )?;
        let mut nodes: Vec<Node8> = huge_page_vec(bvh.nodes.len());
        nodes.extend(bvh.nodes.iter().map(Node8::new));
        let leaf = LeafTriangles::pack(
            &bvh.prim_indices,
            triangles,
            nodes.iter_mut().flat_map(|n| n.children.iter_mut()),
        )
        .map_err(|e| e.into_trace_error(triangles.len()))?;
        #[cfg(target_arch = "x86_64")]
        let avx = std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("bmi1")
            && std::arch::is_x86_feature_detected!("bmi2")
            && std::arch::is_x86_feature_detected!("popcnt")
            && std::arch::is_x86_feature_detected!("lzcnt");
        #[cfg(not(target_arch = "x86_64"))]
        let avx = false;
        Ok(Self {
            nodes,
            leaf,
            options,
            avx,
        })
    }

    /// The same tree traced without AVX even where the CPU has it (to test and measure
    /// both paths).
    pub fn without_avx(mut self) -> Self {
        self.avx = false;
        self
    }

    /// An 8-wide tree collapsed from a binary one ([`bvh::Collapse::collapse_wide`]).
    pub fn from_bvh2(
        bvh: &bvh::Bvh2,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        let wide = bvh::Collapse::default()
            .collapse_wide::<WIDTH8>(bvh)
            .map_err(|e| TraceError::BadTree(e.to_string()))?;
        Self::new(wide, triangles, options)
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
            |n| n.children,
            |n, c, b| {
                let v = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
                for (p, x) in v.into_iter().enumerate() {
                    n.rows[p][c] = x;
                }
            },
        );
        Ok(())
    }

    /// Starts loading a child that traversal will visit later (all four cache lines of a
    /// node).
    #[inline(always)]
    fn prefetch_child(&self, child: ChildRef) {
        if child.is_leaf() {
            self.leaf.prefetch(child.index);
        } else {
            let p = self.nodes.as_ptr().wrapping_add(child.index as usize) as *const u8;
            for line in 0..4 {
                prefetch(p.wrapping_add(64 * line));
            }
        }
    }

    /// [`Self::run`] compiled for AVX2 (with FMA, BMI1/2, POPCNT and LZCNT, which every
    /// AVX2 CPU has), with the AVX box test. Rust never contracts a multiply and an add
    /// into an FMA, so the results are those of the baseline path bit for bit.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,popcnt,lzcnt")]
    fn run_avx<const DIST: bool, O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        total: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        self.run::<DIST, true, O>(ray, query, stack, total, obs)
    }

    #[inline(always)]
    fn run<const DIST: bool, const AVX: bool, O: Observer>(
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
        let visit = |index: u32,
                     best_t: f32,
                     stack: &mut TraversalStack,
                     stats: &mut RayStats,
                     obs: &mut O| {
            let node = &nodes[index as usize];
            #[cfg(target_arch = "x86_64")]
            let (dist, mask, valid) = if AVX {
                // SAFETY: `AVX` is only set by `run_avx`, which runs with AVX enabled
                // (and is only called where the CPU has it).
                unsafe { test8_avx(&slab, node, cull_distance(best_t)) }
            } else {
                test8(&slab, node, cull_distance(best_t))
            };
            #[cfg(not(target_arch = "x86_64"))]
            let (dist, mask, valid) = test8(&slab, node, cull_distance(best_t));
            let kids = &node.children;
            stats.node_visits += 1;
            stats.box_tests += POPCOUNT8[valid as usize] as u64;
            obs.node(index, valid, mask);
            match POPCOUNT8[mask as usize] {
                0 => None,
                1 => Some(kids[mask.trailing_zeros() as usize & 7]),
                2 => {
                    let a = mask.trailing_zeros() as usize & 7;
                    let b = (7 - mask.leading_zeros() as usize) & 7;
                    let (near, far) = if dist[b] < dist[a] { (b, a) } else { (a, b) };
                    self.prefetch_child(kids[far]);
                    stack.push(kids[far], dist[far], &self.leaf, stats, obs);
                    Some(kids[near])
                }
                hits => {
                    // Insertion sort of the hit children's keys (at most eight).
                    let mut keys = [0u32; WIDTH8];
                    let mut n = 0;
                    let mut m = mask;
                    while m != 0 {
                        let slot = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let k = key(dist[slot], slot);
                        let mut j = n;
                        while j > 0 && keys[j - 1] > k {
                            keys[j] = keys[j - 1];
                            j -= 1;
                        }
                        keys[j] = k;
                        n += 1;
                    }
                    debug_assert_eq!(n, hits as usize);
                    for &k in keys[1..n].iter().rev() {
                        let slot = (k & 7) as usize;
                        self.prefetch_child(kids[slot]);
                        stack.push(kids[slot], dist[slot], &self.leaf, stats, obs);
                    }
                    Some(kids[(keys[0] & 7) as usize])
                }
            }
        };
        traverse::<DIST, O>(&self.leaf, ray, &pre, query, stack, total, obs, visit)
    }
}

impl Traverse for Mbvh8Accel {
    #[inline]
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if self.avx {
            // SAFETY: `avx` is set only where the CPU has AVX.
            return unsafe {
                if self.options.distance_stack {
                    self.run_avx::<true, O>(ray, query, stack, stats, obs)
                } else {
                    self.run_avx::<false, O>(ray, query, stack, stats, obs)
                }
            };
        }
        if self.options.distance_stack {
            self.run::<true, false, O>(ray, query, stack, stats, obs)
        } else {
            self.run::<false, false, O>(ray, query, stack, stats, obs)
        }
    }

    fn node_bytes(&self) -> u32 {
        std::mem::size_of::<Node8>() as u32
    }

    fn width(&self) -> u32 {
        WIDTH8 as u32
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
