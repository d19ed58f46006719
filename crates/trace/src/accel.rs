//! What every traversal kernel shares: the hit record and its tie-break rule, the reusable
//! traversal stack, the per-ray slab-test setup, leaf intersection and the pop step.
//!
//! # Which hit is "the closest"
//!
//! A kernel returns the hit of smallest distance `t`; among hits at exactly the same `t`
//! (a ray through an edge shared by two triangles) the one with the smallest primitive id
//! wins. The triangle test reports a hit exactly when its returned `t` lies in the ray's
//! range ([`geom::intersect_triangle_watertight`]), and box culling is conservative (see
//! [`cull_distance`]), so the result is a function of the ray and the triangles alone:
//! every tree, of either width, and brute force give the same hit, bit for bit.
//!
//! One more condition makes this hold for rays that start on a surface (secondary rays):
//! a triangle hit counts only when the ray also enters the triangle's own bounding box by
//! then ([`enters_own_box`]). Near a ray's origin the triangle test's distance carries an
//! absolute error of the order of an ulp of the coordinates, so it can report a hit at
//! `t = -0.0` or a few ulps on the wrong side of a box entry, where the slab test (exact
//! up to relative rounding) has already culled every box around the triangle. With the
//! check, such a hit is refused the same way by brute force and by every kernel: if the
//! ray enters a triangle's box in range, it enters every enclosing box too, since the slab
//! test is monotone in the box and in its range.

use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use bvh::ChildRef;
use geom::{intersect_triangles4_watertight, Aabb, Ray, RayPrecomp, Triangle, Triangles4};

/// A ray/triangle hit found by traversal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray, in units of the ray direction.
    pub t: f32,
    /// The primitive (triangle) id: its index in the triangle list the tree was built over.
    pub prim: u32,
    /// The leaf-table entry through which it was found (an index into the tree's
    /// `prim_indices`, which holds `prim` there).
    pub leaf_entry: u32,
    /// Barycentric weights of the triangle's three vertices at the hit.
    pub bary: [f32; 3],
}

impl Hit {
    /// True when this hit should replace `best` under the closest-hit rule: smaller `t`, or
    /// the same `t` and a smaller primitive id.
    #[inline(always)]
    pub fn beats(&self, best: Option<&Hit>) -> bool {
        match best {
            None => true,
            Some(b) => self.t < b.t || (self.t == b.t && self.prim < b.prim),
        }
    }
}

/// Relative slack of box culling against the closest hit so far: a box (or a stack entry)
/// is skipped only when its entry distance exceeds `best_t * CULL_SLACK`. The slab test's
/// entry distance carries about `gamma(3) = 1.8e-7` relative rounding error and the
/// triangle distance a few ulps; `2^-16 = 1.5e-5` covers both many times over, so a box
/// holding a hit tied with the closest one is never culled. Culling later only ever costs
/// work, never a result.
pub const CULL_SLACK: f32 = 1.0 + 1.0 / 65536.0;

/// The distance up to which boxes are still entered when the closest hit so far is at
/// `best_t` (infinite stays infinite).
#[inline(always)]
pub fn cull_distance(best_t: f32) -> f32 {
    best_t * CULL_SLACK
}

/// Whether the ray enters `tri`'s bounding box within `[t_min, cull_distance(t)]`: the
/// second condition of a hit at `t` (see the module header). Only evaluated for triangles
/// the watertight test reports as hit.
#[inline(always)]
pub fn enters_own_box(pre: &RayPrecomp, tri: &Triangle, t_min: f32, t: f32) -> bool {
    geom::ray_aabb(pre, &tri.aabb(), t_min, cull_distance(t)).is_some()
}

/// One traversal stack entry: a child to visit later and its entry distance.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StackEntry {
    pub child: ChildRef,
    pub dist: f32,
}

/// A traversal stack, reused across rays so that tracing does not allocate per ray.
/// It grows as deep as a tree needs (no fixed limit that a deep tree could overflow).
#[derive(Clone, Debug, Default)]
pub struct TraversalStack {
    pub(crate) entries: Vec<StackEntry>,
    /// The 8-wide kernel's stack: 32-bit child references and entry distances, written
    /// eight at a time.
    refs: Vec<u32>,
    dists: Vec<f32>,
    /// One stack per ray of a batch that interleaves rays
    /// ([`crate::Mbvh8Accel::trace_batch`]), made when first needed.
    lanes: Vec<TraversalStack>,
}

impl TraversalStack {
    /// An empty stack with room for 64 entries ([P4] §3: a 64-entry stack rendered all of
    /// its scenes; the deepest used 28).
    pub fn new() -> Self {
        Self {
            entries: Vec::with_capacity(64),
            refs: vec![0; 64],
            dists: vec![0.0; 64],
            lanes: Vec::new(),
        }
    }

    /// `n` stacks for the rays of an interleaved batch, one each.
    pub(crate) fn lanes(&mut self, n: usize) -> &mut [TraversalStack] {
        if self.lanes.len() < n {
            self.lanes.resize_with(n, TraversalStack::new);
        }
        &mut self.lanes[..n]
    }

    /// The stack of a kernel with 32-bit child references (the 8-wide one), empty.
    #[inline(always)]
    pub(crate) fn wide(&mut self) -> WideStack<'_> {
        WideStack {
            refs: &mut self.refs,
            dists: &mut self.dists,
            len: 0,
        }
    }

    /// Pushes `child` (a packed reference, see [`LeafTriangles`]), counting the push and
    /// the depth; the observer sees the tree's own reference.
    #[inline(always)]
    pub(crate) fn push<O: Observer>(
        &mut self,
        child: ChildRef,
        dist: f32,
        leaf: &LeafTriangles,
        stats: &mut RayStats,
        obs: &mut O,
    ) {
        self.entries.push(StackEntry { child, dist });
        stats.pushes += 1;
        stats.max_stack_depth = stats.max_stack_depth.max(self.entries.len() as u64);
        obs.push(leaf.original(child));
    }

    /// Pops the next entry to traverse. With `distance_culling`, entries whose entry
    /// distance lies beyond `cull_distance(best_t)` are popped and skipped.
    #[inline(always)]
    pub(crate) fn pop<O: Observer>(
        &mut self,
        distance_culling: bool,
        best_t: f32,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<ChildRef> {
        while let Some(e) = self.entries.pop() {
            if !culled(distance_culling, e.dist, best_t, stats, obs) {
                return Some(e.child);
            }
        }
        None
    }
}

/// A kernel's traversal stack, as [`traverse`] uses it.
pub(crate) trait KernelStack {
    /// A child reference as the kernel stores it.
    type Ref: Copy;
    /// Empties the stack for a new ray.
    fn clear(&mut self);
    /// Pops the next entry to traverse; with `distance_culling`, entries whose entry
    /// distance lies beyond `cull_distance(best_t)` are popped and skipped (counted as
    /// culled pops).
    fn pop<O: Observer>(
        &mut self,
        distance_culling: bool,
        best_t: f32,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Self::Ref>;
}

impl KernelStack for TraversalStack {
    type Ref = ChildRef;

    #[inline(always)]
    fn clear(&mut self) {
        self.entries.clear();
    }

    #[inline(always)]
    fn pop<O: Observer>(
        &mut self,
        distance_culling: bool,
        best_t: f32,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<ChildRef> {
        TraversalStack::pop(self, distance_culling, best_t, stats, obs)
    }
}

/// The stack of a kernel with 32-bit child references: references and entry distances in
/// two arrays (borrowed from a [`TraversalStack`], so reused across rays), which a node
/// visit may write several entries at a time ([`WideStack::top`], then
/// [`WideStack::grow`]). It grows as deep as a tree needs.
pub(crate) struct WideStack<'a> {
    refs: &'a mut Vec<u32>,
    dists: &'a mut Vec<f32>,
    len: usize,
}

impl WideStack<'_> {
    /// The free entries above the top, at least `room` of them.
    #[inline(always)]
    pub fn top(&mut self, room: usize) -> (&mut [u32], &mut [f32]) {
        if self.refs.len() < self.len + room {
            let n = (self.len + room).max(2 * self.refs.len());
            self.refs.resize(n, 0);
            self.dists.resize(n, 0.0);
        }
        (&mut self.refs[self.len..], &mut self.dists[self.len..])
    }

    /// Makes the first `n` entries written above the top part of the stack.
    #[inline(always)]
    pub fn grow(&mut self, n: usize) {
        self.len = (self.len + n).min(self.refs.len());
    }

    /// Entries on the stack.
    #[inline(always)]
    pub fn len(&self) -> usize {
        self.len
    }
}

impl KernelStack for WideStack<'_> {
    type Ref = u32;

    #[inline(always)]
    fn clear(&mut self) {
        self.len = 0;
    }

    #[inline(always)]
    fn pop<O: Observer>(
        &mut self,
        distance_culling: bool,
        best_t: f32,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<u32> {
        while self.len > 0 {
            self.len -= 1;
            if !culled(distance_culling, self.dists[self.len], best_t, stats, obs) {
                return Some(self.refs[self.len]);
            }
        }
        None
    }
}

/// A popped entry at entry distance `dist`: whether it is skipped (with
/// `distance_culling`, beyond `cull_distance(best_t)`), counted and reported as a culled or
/// a plain pop.
#[inline(always)]
fn culled<O: Observer>(
    distance_culling: bool,
    dist: f32,
    best_t: f32,
    stats: &mut RayStats,
    obs: &mut O,
) -> bool {
    let skip = distance_culling && dist > cull_distance(best_t);
    if skip {
        stats.culled_pops += 1;
    } else {
        stats.pops += 1;
    }
    obs.pop(skip);
    skip
}

/// Per-ray values of the slab test: for each axis, which box plane the ray enters and
/// leaves through, chosen by the sign of the direction. Plane numbers index the six
/// values `[min.x, min.y, min.z, max.x, max.y, max.z]`. A box whose near plane is at
/// `+inf` (the empty box of an unused child slot) is never hit.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Slab {
    pub origin: [f32; 3],
    pub inv_dir: [f32; 3],
    pub near: [usize; 3],
    pub far: [usize; 3],
    pub t_min: f32,
}

impl Slab {
    #[inline(always)]
    pub fn new(pre: &RayPrecomp, t_min: f32) -> Self {
        let inv = pre.inv_dir.to_array();
        let near = std::array::from_fn(|a| if inv[a] >= 0.0 { a } else { a + 3 });
        let far = std::array::from_fn(|a| if inv[a] >= 0.0 { a + 3 } else { a });
        Slab {
            origin: pre.origin.to_array(),
            inv_dir: inv,
            near,
            far,
            t_min,
        }
    }
}

/// A vector of capacity `n` whose memory the kernel is asked to back with transparent huge
/// pages (Linux, `madvise(MADV_HUGEPAGE)`), before anything is written to it. Traversal
/// touches a tree's nodes and triangles at random; with 4 KiB pages a tree of tens of
/// megabytes misses the TLB on most node fetches, with 2 MiB pages it does not. Elsewhere,
/// or when the advice is refused, it is a plain vector.
pub(crate) fn huge_page_vec<T>(n: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(n);
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = n * std::mem::size_of::<T>();
        if bytes >= 2 * HUGE {
            let start = v.as_ptr() as usize;
            let lo = start.div_ceil(HUGE) * HUGE;
            let hi = (start + bytes) / HUGE * HUGE;
            if hi > lo {
                // SAFETY: the range lies inside the vector's own allocation; the advice
                // changes how pages are backed, never their contents or validity.
                unsafe {
                    libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
                }
            }
        }
    }
    v
}

/// Hints the CPU to start loading the cache line at `p` (a no-op off x86-64). Kernels
/// prefetch the children they push, so that their fetch overlaps the traversal of the
/// nearer subtree.
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint; it never faults, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch(p as *const i8, std::arch::x86_64::_MM_HINT_T0)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// `max` as a compare and select, which maps to one SIMD max instruction. Slab values are
/// never NaN (finite origin, finite non-zero reciprocal, planes finite or infinite).
#[inline(always)]
pub(crate) fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `min` as a compare and select (see [`fmax`]).
#[inline(always)]
pub(crate) fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// The slab test of four child boxes, the one the 4-wide kernel and the 8-wide kernel's
/// baseline path (two halves of a node) share. Lane `i` of box plane `p` (numbered as in
/// [`Slab`]: `min_x, min_y, min_z, max_x, max_y, max_z`) is `planes[first + p * stride +
/// i]`. Returns the entry distances (`+inf` for a missed or empty slot), the hit mask and
/// the mask of non-empty slots (an empty slot is the only one whose box has
/// `min_x = +inf`: trees over finite primitives have finite boxes). SSE on x86-64
/// ([`slab_test4_sse`]), lane by lane elsewhere ([`slab_test4_portable`]): the same bits.
#[inline(always)]
pub(crate) fn slab_test4(
    slab: &Slab,
    planes: &[f32],
    first: usize,
    stride: usize,
    t_max: f32,
) -> ([f32; 4], u8, u8) {
    #[cfg(target_arch = "x86_64")]
    {
        slab_test4_sse(slab, planes, first, stride, t_max)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        slab_test4_portable(slab, planes, first, stride, t_max)
    }
}

/// [`slab_test4`] lane by lane (compare-and-select `fmax`/`fmin`, which compile to SIMD
/// max and min).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline(always)]
pub(crate) fn slab_test4_portable(
    slab: &Slab,
    planes: &[f32],
    first: usize,
    stride: usize,
    t_max: f32,
) -> ([f32; 4], u8, u8) {
    let o = slab.origin;
    let d = slab.inv_dir;
    let mut dist = [f32::INFINITY; 4];
    let (mut mask, mut valid) = (0u8, 0u8);
    for i in 0..4 {
        let v = |p: usize, a: usize| (planes[first + (p % 6) * stride + i] - o[a]) * d[a];
        let near = fmax(
            fmax(v(slab.near[0], 0), v(slab.near[1], 1)),
            fmax(v(slab.near[2], 2), slab.t_min),
        );
        let far = fmin(
            fmin(v(slab.far[0], 0), v(slab.far[1], 1)),
            v(slab.far[2], 2),
        ) * geom::SLAB_FAR_SCALE;
        let hit = near <= fmin(far, t_max);
        dist[i] = if hit { near } else { f32::INFINITY };
        mask |= (hit as u8) << i;
        valid |= ((planes[first + i] < f32::INFINITY) as u8) << i;
    }
    (dist, mask, valid)
}

/// [`slab_test4_portable`] in SSE (part of every x86-64 CPU): the same operations in the
/// same order (`maxps`/`minps` return their second operand on NaN, as `fmax`/`fmin` do),
/// so the same bits, but the hit mask comes from one `movmskps` and nothing goes through
/// memory lane by lane.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn slab_test4_sse(
    slab: &Slab,
    planes: &[f32],
    first: usize,
    stride: usize,
    t_max: f32,
) -> ([f32; 4], u8, u8) {
    use std::arch::x86_64::*;
    // Every load below reads four floats at `first + p * stride` for p < 6 (folded away
    // where the sizes are constants, as in both kernels).
    assert!(
        first + 5 * stride + 4 <= planes.len(),
        "slab_test4: planes out of range"
    );
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline; the assertion keeps every
    // load inside `planes`.
    unsafe {
        let row = |p: usize| _mm_loadu_ps(planes.as_ptr().add(first + (p % 6) * stride));
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
            _mm_set1_ps(geom::SLAB_FAR_SCALE),
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

/// [`enters_own_box`] for the four triangles of a block at once: bit `i` is set when the
/// ray enters lane `i`'s triangle box within `[t_min, cull_distance(t[i])]`. The boxes are
/// made lane-wise from the vertex rows; per axis both plane distances are computed and
/// ordered with a `min` and a `max`, which for the finite reciprocal of a ray (never zero)
/// gives exactly the distances of the planes the scalar test selects by the direction's
/// sign (the subtraction and the multiplication round monotonically). No NaN arises from
/// vertices without NaN, so every `min`, `max` and comparison has the scalar test's
/// outcome whatever its order, and the mask is the scalar test's lane by lane (tested). A
/// triangle with a NaN vertex, which no validated tree holds, could differ; the watertight
/// test never reports it as hit anyway. It replaces one scalar test per hit lane, with the
/// gather of the triangle and its box (12% of the 8-wide kernel's samples on Conference's
/// primary rays), by one SSE test of the four boxes.
#[inline(always)]
pub(crate) fn enter_own_boxes4(
    pre: &RayPrecomp,
    t_min: f32,
    tris: &Triangles4,
    t: &[f32; 4],
) -> u8 {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline; every load reads a `[f32; 4]`.
    unsafe {
        use std::arch::x86_64::*;
        let v = &tris.v;
        let row = |k: usize, a: usize| _mm_loadu_ps(v[k][a].as_ptr());
        let (origin, inv_dir) = (pre.origin.to_array(), pre.inv_dir.to_array());
        let (mut near, mut far) = (_mm_set1_ps(t_min), _mm_set1_ps(f32::INFINITY));
        for a in 0..3 {
            let lo = _mm_min_ps(_mm_min_ps(row(0, a), row(1, a)), row(2, a));
            let hi = _mm_max_ps(_mm_max_ps(row(0, a), row(1, a)), row(2, a));
            let (o, d) = (_mm_set1_ps(origin[a]), _mm_set1_ps(inv_dir[a]));
            let t_lo = _mm_mul_ps(_mm_sub_ps(lo, o), d);
            let t_hi = _mm_mul_ps(_mm_sub_ps(hi, o), d);
            near = _mm_max_ps(near, _mm_min_ps(t_lo, t_hi));
            far = _mm_min_ps(far, _mm_max_ps(t_lo, t_hi));
        }
        let far = _mm_mul_ps(far, _mm_set1_ps(geom::SLAB_FAR_SCALE));
        let cull = _mm_mul_ps(_mm_loadu_ps(t.as_ptr()), _mm_set1_ps(CULL_SLACK));
        let hit = _mm_and_ps(_mm_cmple_ps(near, far), _mm_cmple_ps(near, cull));
        _mm_movemask_ps(hit) as u8
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut mask = 0u8;
        for (i, &ti) in t.iter().enumerate() {
            mask |= (enters_own_box(pre, &tris.get(i), t_min, ti) as u8) << i;
        }
        mask
    }
}

/// A leaf's triangles packed for 4-wide tests.
///
/// Triangles live in blocks of four ([`Triangles4`], structure of arrays). Leaves are
/// placed in tree order: a leaf of up to four triangles goes into the lanes left free in
/// the current block if it fits there, otherwise it starts a new block; a larger leaf
/// starts a new block and fills as many as it needs. A kernel's private copy of the nodes
/// names a leaf by its *slot* `block * 4 + lane` (and keeps its count), so one leaf is
/// tested with one 4-wide test per block it spans, and trees with one triangle per leaf
/// (LBVH) still pack four to a block. Each slot remembers its leaf-table entry, so hits,
/// counters and logs name the tree's own leaf-table entries.
///
/// A block keeps its lanes' primitive ids and leaf-table entries next to the vertices
/// ([`LeafBlock`], three whole cache lines): a hit reads them from the lines the triangle
/// test has just loaded, where separate tables cost two dependent cache misses per hit.
#[derive(Clone, Debug, Default)]
pub(crate) struct LeafTriangles {
    blocks: Vec<LeafBlock>,
    /// Primitive id of each leaf-table entry (the tree's `prim_indices`).
    prims: Vec<u32>,
    /// Length of the triangle list the tree was built over.
    pub source_len: usize,
}

/// One block of [`LeafTriangles`]: four triangles and, per lane, the primitive id and the
/// leaf-table entry (`u32::MAX` both for an unused lane). 176 bytes padded to 192, on
/// 64-byte boundaries, so a block spans exactly three cache lines.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
struct LeafBlock {
    tris: Triangles4,
    prims: [u32; 4],
    entries: [u32; 4],
}

const _: () = assert!(std::mem::size_of::<LeafBlock>() == 192);

impl LeafBlock {
    /// A block holding `tri` in every lane (lanes 1-3 unused until filled).
    fn new(tri: &Triangle) -> Self {
        Self {
            tris: Triangles4::pack(&[*tri]),
            prims: [u32::MAX; 4],
            entries: [u32::MAX; 4],
        }
    }

    /// Writes `tri`'s vertices into `lane`.
    fn set(&mut self, lane: usize, tri: &Triangle) {
        for (v, vk) in self.tris.v.iter_mut().enumerate() {
            for (a, row) in vk.iter_mut().enumerate() {
                row[lane] = tri.v[v][a];
            }
        }
    }
}

/// Why the triangles of a tree cannot be packed.
pub(crate) enum PackError {
    /// Leaf-table entry `.0` names triangle `.1`, which does not exist.
    Missing(usize, u32),
    /// More slots than a 32-bit slot index addresses.
    TooLarge,
}

impl PackError {
    /// As a [`TraceError`], for a tree over `triangles` triangles.
    pub fn into_trace_error(self, triangles: usize) -> crate::TraceError {
        match self {
            PackError::Missing(entry, prim) => crate::TraceError::PrimitiveOutOfRange {
                entry,
                prim,
                triangles,
            },
            PackError::TooLarge => {
                crate::TraceError::BadTree("too many leaf triangles to address".into())
            }
        }
    }
}

impl LeafTriangles {
    /// Packs the leaves named by the leaf children `leaves` (the kernel's private node
    /// copy, in tree order), rewriting each to name its slot. Leaf ranges must lie inside
    /// `prim_indices` (checked by `check_links` first).
    pub fn pack<'a>(
        prim_indices: &[u32],
        triangles: &[Triangle],
        leaves: impl Iterator<Item = &'a mut ChildRef>,
    ) -> Result<Self, PackError> {
        let mut leaves: Vec<&mut ChildRef> = leaves.filter(|c| c.is_leaf()).collect();
        // Blocks the placement below opens, counted first: the vector is reserved at its
        // final size so that it never reallocates (a reallocation would drop the huge-page
        // advice; partly filled blocks make it more than a quarter of the entries).
        let mut needed = 0usize;
        let mut fill = 4usize; // lanes used in the last block (4: none free)
        for c in &leaves {
            let count = c.count as usize;
            if count > 4 || fill + count > 4 {
                fill = 4;
            }
            for _ in 0..count {
                if fill == 4 {
                    needed += 1;
                    fill = 0;
                }
                fill += 1;
            }
        }
        let mut blocks: Vec<LeafBlock> = huge_page_vec(needed);
        let mut fill = 4usize;
        for c in leaves.iter_mut() {
            let count = c.count as usize;
            if count > 4 || fill + count > 4 {
                fill = 4;
            }
            let mut slot = None;
            for k in 0..count {
                let entry = c.index as usize + k;
                let prim = prim_indices[entry];
                let tri = triangles
                    .get(prim as usize)
                    .ok_or(PackError::Missing(entry, prim))?;
                if fill == 4 {
                    blocks.push(LeafBlock::new(tri));
                    fill = 0;
                }
                let b = blocks.len() - 1;
                blocks[b].set(fill, tri);
                blocks[b].entries[fill] = entry as u32;
                blocks[b].prims[fill] = prim;
                slot.get_or_insert(b * 4 + fill);
                fill += 1;
            }
            c.index = u32::try_from(slot.unwrap_or(0)).map_err(|_| PackError::TooLarge)?;
        }
        debug_assert_eq!(blocks.len(), needed);
        Ok(Self {
            blocks,
            prims: prim_indices.to_vec(),
            source_len: triangles.len(),
        })
    }

    /// Bytes of the packed leaf blocks.
    pub fn block_bytes(&self) -> usize {
        self.blocks.len() * std::mem::size_of::<LeafBlock>()
    }

    /// Leaf-table entries (the tree's `prim_indices.len()`).
    pub fn entry_count(&self) -> usize {
        self.prims.len()
    }

    /// The tree's own reference for a (packed) child: leaves name their first leaf-table
    /// entry again, inner children are unchanged. (Panic-free, so that with the unit
    /// observer, which ignores the result, it compiles away.)
    #[inline(always)]
    pub fn original(&self, c: ChildRef) -> ChildRef {
        if c.is_leaf() {
            let e = self
                .blocks
                .get(c.index as usize / 4)
                .map_or(u32::MAX, |b| b.entries[c.index as usize % 4]);
            ChildRef::leaf(e, c.count)
        } else {
            c
        }
    }

    /// Prefetches the first block of the leaf at `slot`.
    #[inline(always)]
    pub fn prefetch(&self, slot: u32) {
        let p = self.blocks.as_ptr().wrapping_add(slot as usize / 4) as *const u8;
        for line in 0..3 {
            prefetch(p.wrapping_add(64 * line));
        }
    }

    /// Tests the leaf of `count` triangles at `slot`; updates `best` and `best_t`. Returns
    /// true when an any-hit query has found its hit and traversal should stop.
    ///
    /// Counters follow the one-at-a-time semantics of the hardware IST unit and of the
    /// log: every triangle of the leaf is one test, except that an any-hit ray stops at its
    /// hit, so the lanes after it are not counted.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn intersect<O: Observer>(
        &self,
        slot: u32,
        count: u32,
        pre: &RayPrecomp,
        t_min: f32,
        query: Query,
        best: &mut Option<Hit>,
        best_t: &mut f32,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> bool {
        stats.leaf_visits += 1;
        obs.leaf(self.original(ChildRef::leaf(slot, count)).index, count);
        let mut block = slot as usize / 4;
        let mut lane = slot as usize % 4;
        let mut left = count as usize;
        while left > 0 {
            // A malformed tree cannot send us past the blocks (leaves were packed from
            // checked ranges), but stay panic-free regardless.
            let Some(blk) = self.blocks.get(block) else {
                break;
            };
            let tris = &blk.tris;
            let n = left.min(4 - lane);
            let lanes = (((1u32 << n) - 1) << lane) as u8;
            let h = intersect_triangles4_watertight(pre, tris, lanes, t_min, *best_t);
            let mut m = h.mask;
            if m != 0 {
                m &= enter_own_boxes4(pre, t_min, tris, &h.t);
            }
            let mut tested = n as u64;
            while m != 0 {
                let i = m.trailing_zeros() as usize;
                m &= m - 1;
                let hit = Hit {
                    t: h.t[i],
                    prim: blk.prims[i],
                    leaf_entry: blk.entries[i],
                    bary: [h.bary[0][i], h.bary[1][i], h.bary[2][i]],
                };
                if hit.beats(best.as_ref()) {
                    *best_t = hit.t;
                    *best = Some(hit);
                    if query == Query::Any {
                        tested = (i - lane + 1) as u64;
                        stats.tri_tests += tested;
                        return true;
                    }
                }
            }
            stats.tri_tests += tested;
            left -= n;
            lane = 0;
            block += 1;
        }
        false
    }
}

/// Starts `ray` at `root`: the observer's begin, the stack emptied, the ray counted in
/// `stats`. Returns the reference to visit first: `root`, or `None` for a ray with a
/// non-finite origin or direction (it hits nothing: the slab tests assume finite values).
/// The ray's closest hit starts empty at `best_t = ray.t_max`.
#[inline(always)]
pub(crate) fn begin<O: Observer, S: KernelStack>(
    ray: &Ray,
    query: Query,
    root: S::Ref,
    stack: &mut S,
    stats: &mut RayStats,
    obs: &mut O,
) -> Option<S::Ref> {
    obs.begin(ray, query);
    stats.rays += 1;
    stack.clear();
    let finite = geom::is_finite3(ray.origin) && geom::is_finite3(ray.dir);
    finite.then_some(root)
}

/// What a ray does after one [`step`].
pub(crate) enum Next<R> {
    /// Visit this reference (the node visit's chosen child).
    Visit(R),
    /// Pop the stack ([`KernelStack::pop`]).
    Pop,
    /// The ray is done (an any-hit query found its hit).
    Done,
}

/// One step of a ray's traversal at reference `c`: tests the leaf through `leaf`
/// (updating `best` and `best_t`), or visits the inner node (`visit(r, best_t, stack,
/// stats, obs)` tests node `r` against the cull distance of `best_t`, pushes the hit
/// children it does not continue with, and returns the one it continues with, or
/// `None`). `as_leaf(r)` says whether reference `r` is a leaf (and which packed slots).
/// The caller then pops the stack (culled by the closest hit when `DIST`) whenever the
/// step continues nowhere.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn step<O: Observer, S: KernelStack>(
    c: S::Ref,
    leaf: &LeafTriangles,
    ray: &Ray,
    pre: &RayPrecomp,
    query: Query,
    best: &mut Option<Hit>,
    best_t: &mut f32,
    stack: &mut S,
    stats: &mut RayStats,
    obs: &mut O,
    as_leaf: impl Fn(S::Ref) -> Option<ChildRef>,
    mut visit: impl FnMut(S::Ref, f32, &mut S, &mut RayStats, &mut O) -> Option<S::Ref>,
) -> Next<S::Ref> {
    if let Some(l) = as_leaf(c) {
        let stop = leaf.intersect(
            l.index, l.count, pre, ray.t_min, query, best, best_t, stats, obs,
        );
        if stop {
            return Next::Done;
        }
    } else if let Some(next) = visit(c, *best_t, stack, stats, obs) {
        return Next::Visit(next);
    }
    Next::Pop
}

/// Ends a ray: its hit (the closest, or for `Query::Any` the first found), counted in
/// `stats` and reported to the observer.
#[inline(always)]
pub(crate) fn finish<O: Observer>(
    best: Option<Hit>,
    stats: &mut RayStats,
    obs: &mut O,
) -> Option<Hit> {
    stats.hits += best.is_some() as u64;
    obs.end(best.as_ref());
    best
}

/// The traversal loop shared by the kernels over uncompressed trees (`Bvh2`, `Mbvh4`,
/// `Mbvh8`): one ray from `root` to the end ([`begin`], [`step`] until done, [`finish`]),
/// its closest hit and counters kept in locals (registers), the counters added to `total`
/// once. The kernels differ only in their node visit and in how they store references
/// and stack entries ([`KernelStack`]). Inlined into each kernel, so each keeps its own
/// code.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn traverse<const DIST: bool, O: Observer, S: KernelStack>(
    leaf: &LeafTriangles,
    ray: &Ray,
    pre: &RayPrecomp,
    query: Query,
    stack: &mut S,
    total: &mut RayStats,
    obs: &mut O,
    root: S::Ref,
    as_leaf: impl Fn(S::Ref) -> Option<ChildRef>,
    mut visit: impl FnMut(S::Ref, f32, &mut S, &mut RayStats, &mut O) -> Option<S::Ref>,
) -> Option<Hit> {
    let mut ray_stats = RayStats::default();
    let stats = &mut ray_stats;
    let mut cur = begin(ray, query, root, stack, stats, obs);
    let mut best: Option<Hit> = None;
    let mut best_t = ray.t_max;
    while let Some(c) = cur {
        let next = step::<O, S>(
            c,
            leaf,
            ray,
            pre,
            query,
            &mut best,
            &mut best_t,
            stack,
            stats,
            obs,
            &as_leaf,
            &mut visit,
        );
        match next {
            Next::Visit(n) => {
                cur = Some(n);
                continue;
            }
            Next::Done => break,
            Next::Pop => {}
        }
        cur = stack.pop(DIST, best_t, stats, obs);
    }
    let best = finish(best, stats, obs);
    total.add(stats);
    best
}

/// [`traverse`] for the kernels that keep [`ChildRef`]s (`Bvh2`, `Mbvh4`): from the root
/// node, leaves told by their count.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn traverse_child_refs<const DIST: bool, O: Observer>(
    leaf: &LeafTriangles,
    ray: &Ray,
    pre: &RayPrecomp,
    query: Query,
    stack: &mut TraversalStack,
    total: &mut RayStats,
    obs: &mut O,
    visit: impl FnMut(ChildRef, f32, &mut TraversalStack, &mut RayStats, &mut O) -> Option<ChildRef>,
) -> Option<Hit> {
    traverse::<DIST, O, _>(
        leaf,
        ray,
        pre,
        query,
        stack,
        total,
        obs,
        ChildRef::inner(0),
        |c| c.is_leaf().then_some(c),
        visit,
    )
}

/// The rays of a batch query ([`Traverse::trace_batch`]), read by index: a slice of
/// [`Ray`]s, or rays kept some other way (columns of origins, directions and ranges, as
/// the Python binding has them), so that a batch need not be copied into `Ray`s first.
pub trait RaySource {
    /// Number of rays.
    fn len(&self) -> usize;

    /// Ray `i` (below [`RaySource::len`]).
    fn ray(&self, i: usize) -> Ray;

    /// True when there are no rays.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl RaySource for [Ray] {
    #[inline(always)]
    fn len(&self) -> usize {
        <[Ray]>::len(self)
    }

    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        self[i]
    }
}

/// One ray through `t`, kept out of line: inlined into a batch's loop, the kernel was
/// compiled as part of that loop and came out 8-25% slower in three alternations of
/// `kernel_cost` with `mbvh4-batch` against `mbvh4` (Bunny's diffuse rays); out of line
/// the two are within the noise, and callgrind counts the same instructions a ray.
#[inline(never)]
fn trace_one<T: Traverse + ?Sized>(
    t: &T,
    ray: &Ray,
    query: Query,
    stack: &mut TraversalStack,
    stats: &mut RayStats,
) -> Option<Hit> {
    t.trace_observed(ray, query, stack, stats, &mut ())
}

/// The loop of a batch traced one ray after the other ([`Traverse::trace_batch`]): for
/// each ray `i` of `$rays`, `$trace` (an expression of `$ray: &Ray` and of `$stats: &mut
/// RayStats`, fresh counters) traces it and `$done(i, hit, counters)` takes its answer.
/// The kernels put their one-ray traversal, inlined and instantiated for this loop alone,
/// into `$trace`, so that each hit reaches `done` in registers: returned through memory by
/// an out-of-line call, the caller's wide copy of it waited on the callee's narrower stores
/// once a ray (docs/ray-tracing.md, "A batch's hits handed back in registers"). A macro
/// rather than a function taking the traversal as a closure: that form left the traversal
/// out of line (Conference's primary rays in a batch: `bvh2` 199-201 against 150-156 ns a
/// ray, `mbvh4` 180-181 against 136-137).
macro_rules! each_ray {
    ($rays:expr, $done:expr, |$ray:ident, $stats:ident| $trace:expr) => {
        for i in 0..$rays.len() {
            let mut stats = RayStats::default();
            let hit = {
                let $ray = &$rays.ray(i);
                let $stats = &mut stats;
                $trace
            };
            ($done)(i, hit, &stats);
        }
    };
}
pub(crate) use each_ray;

/// The entry points of a kernel whose one-ray traversal is its own
/// `traverse_ray::<DIST, EACH, O>` (`Bvh2`, `Mbvh4`), written once for them as code, not
/// as a shared closure (which left the traversal out of line). `one_ray_kernel!(inherent)`
/// in the kernel's `impl` gives `run`, one ray, kept out of line (inlined into its callers
/// it slowed `Mbvh4`'s one-ray path), and `each`, a batch traced one ray after the other
/// with the traversal inlined in the loop ([`each_ray`]; `EACH` makes that instantiation
/// its own). `one_ray_kernel!(traverse)` in its `Traverse` impl gives `trace_observed` and
/// `trace_batch`, choosing `DIST` from `self.options.distance_stack`.
macro_rules! one_ray_kernel {
    (inherent) => {
        #[inline(never)]
        fn run<const DIST: bool, O: Observer>(
            &self,
            ray: &Ray,
            query: Query,
            stack: &mut TraversalStack,
            total: &mut RayStats,
            obs: &mut O,
        ) -> Option<Hit> {
            self.traverse_ray::<DIST, false, O>(ray, query, stack, total, obs)
        }

        fn each<
            const DIST: bool,
            R: RaySource + ?Sized,
            F: FnMut(usize, Option<Hit>, &RayStats),
        >(
            &self,
            rays: &R,
            query: Query,
            stack: &mut TraversalStack,
            mut done: F,
        ) {
            $crate::accel::each_ray!(rays, done, |ray, stats| {
                self.traverse_ray::<DIST, true, ()>(ray, query, stack, stats, &mut ())
            });
        }
    };
    (traverse) => {
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

        #[inline]
        fn trace_batch<R: RaySource + ?Sized, F: FnMut(usize, Option<Hit>, &RayStats)>(
            &self,
            rays: &R,
            query: Query,
            stack: &mut TraversalStack,
            done: F,
        ) {
            if self.options.distance_stack {
                self.each::<true, R, F>(rays, query, stack, done)
            } else {
                self.each::<false, R, F>(rays, query, stack, done)
            }
        }
    };
}
pub(crate) use one_ray_kernel;

/// [`Traverse::trace_batch`] one ray after the other (each through [`trace_one`]).
#[inline]
pub(crate) fn trace_each<T: Traverse + ?Sized, R: RaySource + ?Sized>(
    t: &T,
    rays: &R,
    query: Query,
    stack: &mut TraversalStack,
    mut done: impl FnMut(usize, Option<Hit>, &RayStats),
) {
    each_ray!(rays, done, |ray, stats| trace_one(
        t, ray, query, stack, stats
    ));
}

/// A tree that rays can be traced through.
pub trait Traverse: Send + Sync {
    /// Traces `ray` for `query`, reporting events to `obs` and adding the ray's counters
    /// to `stats`. Returns the closest hit (`Query::Closest`) or the first hit found
    /// (`Query::Any`).
    fn trace_observed<O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit>;

    /// The closest hit along `ray`.
    #[inline]
    fn closest_hit(
        &self,
        ray: &Ray,
        stack: &mut TraversalStack,
        stats: &mut RayStats,
    ) -> Option<Hit> {
        self.trace_observed(ray, Query::Closest, stack, stats, &mut ())
    }

    /// True when anything lies along `ray` within its range (occlusion).
    #[inline]
    fn occluded(&self, ray: &Ray, stack: &mut TraversalStack, stats: &mut RayStats) -> bool {
        self.trace_observed(ray, Query::Any, stack, stats, &mut ())
            .is_some()
    }

    /// Traces every ray of `rays` for `query` and calls `done(i, hit, counters)` once for
    /// each ray `i`, with the ray's own counters; the calls may come in any order. Each
    /// ray's answer and counters are exactly those of [`Traverse::trace_observed`]. Here
    /// the rays are traced one after the other; the 8-wide kernel can interleave several
    /// rays on one thread, so that one ray's node fetches overlap another's work
    /// ([`crate::Mbvh8Accel::trace_batch`]).
    #[inline]
    fn trace_batch<R: RaySource + ?Sized, F: FnMut(usize, Option<Hit>, &RayStats)>(
        &self,
        rays: &R,
        query: Query,
        stack: &mut TraversalStack,
        done: F,
    ) {
        trace_each(self, rays, query, stack, done)
    }

    /// The closest hits of `rays` into `out` (as long as `rays`), their counters added to
    /// `stats`: [`Traverse::trace_batch`] for `Query::Closest`.
    ///
    /// ```
    /// use trace::{Mbvh8Accel, RayStats, Traverse, TraversalStack};
    /// use geom::{Ray, Triangle, Vec3};
    ///
    /// let tris = vec![Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)];
    /// let tree = bvh::SweepSahBuilder::default().build(&bvh::triangle_aabbs(&tris))?;
    /// let accel = Mbvh8Accel::from_bvh2(&tree, &tris, Default::default())?;
    /// let rays: Vec<Ray> = (0..100)
    ///     .map(|i| Ray::new(Vec3::new(0.005 + 0.01 * i as f32, 0.25, 1.0), -Vec3::Z))
    ///     .collect();
    /// let mut hits = vec![None; rays.len()];
    /// let mut stats = RayStats::default();
    /// accel.closest_hits(&rays, &mut TraversalStack::new(), &mut hits, &mut stats);
    /// assert_eq!(hits.iter().filter(|h| h.is_some()).count(), 75); // x + y <= 1
    /// assert_eq!(stats.rays, 100);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    fn closest_hits(
        &self,
        rays: &[Ray],
        stack: &mut TraversalStack,
        out: &mut [Option<Hit>],
        stats: &mut RayStats,
    ) {
        assert_eq!(rays.len(), out.len(), "closest_hits: one output per ray");
        self.trace_batch(rays, Query::Closest, stack, |i, h, s| {
            out[i] = h;
            stats.add(s);
        });
    }

    /// Bytes of one node in this tree's format (64 for `Bvh2`, 128 for `Mbvh4`).
    fn node_bytes(&self) -> u32;

    /// Child slots per node (2 or 4).
    fn width(&self) -> u32;

    /// Number of inner nodes.
    fn node_count(&self) -> usize;

    /// Length of the triangle list the tree was built over (hit primitive ids are below it).
    fn source_triangles(&self) -> usize;

    /// Leaf-table entries.
    fn leaf_entries(&self) -> usize;
}

impl LeafTriangles {
    /// Rewrites the packed triangles from `triangles`: the list the tree was prepared
    /// over, with its vertices moved (same length, same order). Every block is rebuilt
    /// exactly as [`LeafTriangles::pack`] builds it (unused lanes repeat the block's first
    /// triangle), so the result is bit for bit the packing of a freshly prepared tree.
    pub fn update(&mut self, triangles: &[Triangle]) -> Result<(), crate::TraceError> {
        if triangles.len() != self.source_len {
            return Err(crate::TraceError::Config(format!(
                "cannot refit in place: the tree was prepared over {} triangles, {} given",
                self.source_len,
                triangles.len()
            )));
        }
        let Self { blocks, prims, .. } = self;
        let tri = |entry: u32| -> Result<&Triangle, crate::TraceError> {
            let prim = prims.get(entry as usize).copied().unwrap_or(u32::MAX);
            triangles
                .get(prim as usize)
                .ok_or(crate::TraceError::PrimitiveOutOfRange {
                    entry: entry as usize,
                    prim,
                    triangles: triangles.len(),
                })
        };
        for block in blocks.iter_mut() {
            // Lane 0 of every block is used: a block is opened for the triangle it holds.
            // Primitive ids and entries stay (same topology).
            block.tris = Triangles4::pack(&[*tri(block.entries[0])?]);
            for lane in 1..4 {
                let entry = block.entries[lane];
                if entry == u32::MAX {
                    continue;
                }
                block.set(lane, tri(entry)?);
            }
        }
        Ok(())
    }

    /// The bounding box of the (packed) leaf child `c`: the union of its triangles' boxes,
    /// read from the packed blocks.
    pub fn leaf_box(&self, c: ChildRef) -> Aabb {
        let mut b = Aabb::EMPTY;
        for slot in c.index as usize..c.index as usize + c.count as usize {
            if let Some(block) = self.blocks.get(slot / 4) {
                b = b.union(block.tris.get(slot % 4).aabb());
            }
        }
        b
    }
}

/// Refits a kernel's private node copy to the triangles of `leaf` (already updated with
/// [`LeafTriangles::update`]): every non-empty child box becomes the union of the boxes
/// below it. Nodes are visited from the last to the first, which is children before
/// parents (every kernel checks at preparation that children follow their parent). Box
/// unions are exact (min and max), so the boxes equal those of the same topology refitted
/// by `bvh` and prepared afresh. `children` reads a node's (packed) child references;
/// `set_box` writes child `k`'s box into the node's layout.
pub(crate) fn refit_nodes<N, const W: usize>(
    nodes: &mut [N],
    leaf: &LeafTriangles,
    children: impl Fn(&N) -> [ChildRef; W],
    mut set_box: impl FnMut(&mut N, usize, &Aabb),
) {
    let mut boxes = vec![Aabb::EMPTY; nodes.len()];
    for i in (0..nodes.len()).rev() {
        let mut total = Aabb::EMPTY;
        for (k, c) in children(&nodes[i]).iter().enumerate() {
            let b = if c.is_empty() {
                continue;
            } else if c.is_leaf() {
                leaf.leaf_box(*c)
            } else {
                boxes.get(c.index as usize).copied().unwrap_or(Aabb::EMPTY)
            };
            set_box(&mut nodes[i], k, &b);
            total = total.union(b);
        }
        boxes[i] = total;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;
    use proptest::prelude::*;

    /// A coordinate: mostly small values on a coarse grid (shared planes, zeros, ties with
    /// the ray's origin), sometimes huge or infinite.
    fn coord() -> impl Strategy<Value = f32> {
        prop_oneof![
            8 => (-8i32..=8).prop_map(|k| k as f32 * 0.5),
            4 => -10.0f32..10.0,
            1 => Just(-0.0f32),
            1 => Just(3.0e38f32),
            1 => Just(-3.0e38f32),
            1 => Just(f32::INFINITY),
            1 => Just(f32::NEG_INFINITY),
        ]
    }

    fn vec3<S: Strategy<Value = f32>>(c: impl Fn() -> S) -> impl Strategy<Value = Vec3> {
        (c(), c(), c()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    /// A finite coordinate of the same kinds.
    fn finite() -> impl Strategy<Value = f32> {
        coord().prop_filter("finite", |x| x.is_finite())
    }

    /// A distance to test against: the lane's hit distance in the kernel.
    fn dist() -> impl Strategy<Value = f32> {
        prop_oneof![
            Just(0.0f32),
            Just(-0.0f32),
            Just(f32::INFINITY),
            Just(1e-30f32),
            0.0f32..20.0,
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// The four-lane own-box check answers as the scalar one lane by lane, for
        /// triangles with finite or infinite vertices and rays of any direction
        /// (axis-aligned ones included).
        #[test]
        fn own_boxes_of_a_block_match_the_scalar_check(
            verts in proptest::collection::vec(vec3(coord), 12),
            origin in vec3(finite),
            dir in vec3(finite).prop_filter("non-zero", |d| d.x != 0.0 || d.y != 0.0 || d.z != 0.0),
            t_min in prop_oneof![Just(0.0f32), Just(1e-4f32), 0.0f32..3.0],
            t in proptest::array::uniform4(dist()),
        ) {
            let tris: Vec<Triangle> = verts
                .chunks(3)
                .map(|v| Triangle::new(v[0], v[1], v[2]))
                .collect();
            let block = Triangles4::pack(&tris);
            let pre = RayPrecomp::new(&Ray::new(origin, dir));
            let got = enter_own_boxes4(&pre, t_min, &block, &t);
            for (i, tri) in tris.iter().enumerate() {
                let want = enters_own_box(&pre, tri, t_min, t[i]);
                prop_assert_eq!(got >> i & 1 == 1, want, "lane {} of {:?}", i, tri);
            }
        }
    }
}
