//! Traversal of an 8-wide BVH: beyond the thesis, which stops at four ([P4] §3.1 notes
//! that other branching factors are interesting in custom hardware). An 8-wide tree
//! needs fewer dependent node fetches per ray than a 4-wide one, which is what bounds an
//! incoherent ray's time once the tree no longer fits the caches; CPU ray tracers with
//! 8-lane SIMD (Embree's BVH8) use it for that reason. [`Mbvh8Accel::from_bvh2`] makes it
//! by the SAH-optimal collapse of a binary tree ([`Mbvh8Accel::collapse`]); any valid
//! 8-wide tree can be given to [`Mbvh8Accel::new`].
//!
//! A node is 256 bytes: per box plane one row of the eight children (six 32-byte rows),
//! then the eight child references in 32 bits each. A visit tests the eight boxes,
//! continues with the nearest hit child and pushes the others farthest first, with the
//! distance stack (as [`crate::Mbvh4Accel`]). On CPUs with AVX2 the visit has no branch
//! on the hit children beyond their count: one 8-lane box test, a bitonic sorting network
//! over distance keys, and two 8-lane stores onto the kernel's own stack of 32-bit
//! references and distances; elsewhere the same order comes from a scalar insertion sort
//! (tested to give the same counters ray by ray). Counters and observer events are those
//! of the other kernels (child masks of eight bits). Batches of rays
//! ([`Traverse::trace_batch`]) are traced several at a time per thread, a node visit each in
//! turn, when the tree is larger than the last-level cache ([`Interleave`]).

use crate::accel::{
    self, cull_distance, huge_page_vec, prefetch, refit_nodes, slab_test4, traverse, Hit,
    KernelStack, LeafTriangles, RaySource, Slab, TraversalStack, Traverse, WideStack,
};
use crate::bvh2_kernel::check_links;
use crate::observer::{Observer, Query};
use crate::stats::RayStats;
use crate::{KernelOptions, TraceError};
use bvh::{ChildRef, WideBvh};
use geom::{Aabb, Ray, RayPrecomp, Triangle, SLAB_FAR_SCALE};

/// Child slots per node.
pub const WIDTH8: usize = 8;

/// A node: six plane rows (`min_x, min_y, min_z, max_x, max_y, max_z`) of eight lanes
/// and the eight child references in 32 bits each ([`child8`]), padded to 256 bytes on
/// 64-byte cache lines (the rows fill three lines, the references half the fourth).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
struct Node8 {
    rows: [[f32; WIDTH8]; 6],
    children: [u32; WIDTH8],
}

const _: () = assert!(std::mem::size_of::<Node8>() == 256);

/// A child reference in 32 bits: an inner node's index (bit 31 clear), or a leaf (bit 31
/// set) with `count - 1` in bits 26-30 and its first packed slot in bits 0-25. Leaves that
/// do not fit (more than 31 triangles, or slots past `2^26`) set bits 26-30 to all ones
/// and keep in bits 0-25 an index into the accelerator's table of large leaves. The empty
/// slot is `u32::MAX`.
mod child8 {
    pub const LEAF: u32 = 1 << 31;
    pub const SLOT_BITS: u32 = 26;
    pub const SLOT_MASK: u32 = (1 << SLOT_BITS) - 1;
    pub const COUNT_ESCAPE: u32 = 31;
    pub const EMPTY: u32 = u32::MAX;
}

impl Node8 {
    /// The node of `n` with its children encoded; `big` collects the large leaves.
    fn new(n: &bvh::WideNode<WIDTH8>, big: &mut Vec<ChildRef>) -> Result<Self, TraceError> {
        let mut node = Self {
            rows: [[0f32; WIDTH8]; 6],
            children: [child8::EMPTY; WIDTH8],
        };
        for (i, b) in n.boxes.iter().enumerate() {
            // The kernel tells used slots by their boxes: an absent child gets the empty
            // box (never hit, whatever box the tree stored), so it is never entered.
            let b = if n.children[i].is_empty() {
                &Aabb::EMPTY
            } else {
                b
            };
            node.set_box(i, b);
            node.children[i] = encode(n.children[i], big)?;
        }
        Ok(node)
    }

    fn set_box(&mut self, i: usize, b: &Aabb) {
        let v = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
        for (p, x) in v.into_iter().enumerate() {
            self.rows[p][i] = x;
        }
    }
}

/// Encodes a (packed) child reference in 32 bits (see [`child8`]).
fn encode(c: ChildRef, big: &mut Vec<ChildRef>) -> Result<u32, TraceError> {
    let too_large = || TraceError::BadTree("too many nodes or leaves to address".into());
    if c.is_empty() {
        Ok(child8::EMPTY)
    } else if c.is_inner() {
        if c.index & child8::LEAF != 0 {
            return Err(too_large());
        }
        Ok(c.index)
    } else if c.count < child8::COUNT_ESCAPE + 1 && c.index <= child8::SLOT_MASK {
        Ok(child8::LEAF | (c.count - 1) << child8::SLOT_BITS | c.index)
    } else {
        let i = u32::try_from(big.len())
            .ok()
            .filter(|&i| i <= child8::SLOT_MASK)
            .ok_or_else(too_large)?;
        big.push(c);
        Ok(child8::LEAF | child8::COUNT_ESCAPE << child8::SLOT_BITS | i)
    }
}

/// The (packed) reference of a 32-bit child reference; `big` is the accelerator's table
/// of large leaves.
#[inline(always)]
fn decode(c: u32, big: &[ChildRef]) -> ChildRef {
    if c & child8::LEAF == 0 {
        ChildRef::inner(c)
    } else if c == child8::EMPTY {
        ChildRef::EMPTY
    } else {
        let count = c >> child8::SLOT_BITS & 31;
        let index = c & child8::SLOT_MASK;
        if count == child8::COUNT_ESCAPE {
            // Written by `encode`, so in range; stay panic-free regardless.
            big.get(index as usize).copied().unwrap_or(ChildRef::EMPTY)
        } else {
            ChildRef::leaf(index, count + 1)
        }
    }
}

/// Defines three entry points of [`Mbvh8Accel`] for one instruction set: `$run`
/// ([`Mbvh8Accel::run`] for one ray), `$each` (a batch traced one ray after the other,
/// each through `run`) and `$batch` ([`Mbvh8Accel::batch`], interleaving rays), each
/// compiled with the target features `$features` (the doc lines say what they give);
/// `$avx512` and the `EACH` parameter of `run` make the instantiation of the generic
/// traversal each entry point runs its own (see `run`).
macro_rules! simd_entry_points {
    ($(#[doc = $doc:literal])* $run:ident, $each:ident, $batch:ident, $avx512:literal, $features:literal) => {
        /// [`Self::run`]
        $(#[doc = $doc])*
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $run<const DIST: bool, O: Observer>(
            &self,
            ray: &Ray,
            query: Query,
            stack: &mut TraversalStack,
            total: &mut RayStats,
            obs: &mut O,
        ) -> Option<Hit> {
            self.run::<DIST, true, $avx512, false, O>(ray, query, stack, total, obs)
        }

        /// [`Traverse::trace_batch`] one ray after the other ([`accel::each_ray`]), the
        /// traversal and `done` inlined here: one call into the instruction set's code a
        /// batch (one call a ray into `$run` cost about 20% of a primary ray's time on
        /// Conference).
        $(#[doc = $doc])*
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $each<
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
            accel::each_ray!(rays, done, |ray, stats| {
                self.run::<DIST, true, $avx512, true, ()>(ray, query, stack, stats, &mut ())
            });
        }

        /// [`Self::batch`]
        $(#[doc = $doc])*
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $batch<
            const DIST: bool,
            R: RaySource + ?Sized,
            F: FnMut(usize, Option<Hit>, &RayStats),
        >(
            &self,
            rays: &R,
            query: Query,
            stack: &mut TraversalStack,
            done: F,
        ) {
            self.batch::<DIST, true, $avx512, R, F>(rays, query, stack, done)
        }
    };
}

/// Returns from the calling method through the entry point of the kernel's instruction
/// set and distance-stack setting (`$avx512` or `$avx`, with `DIST` and then the generic
/// arguments `$g`, called with `$args`); on the baseline instruction set (or off x86-64)
/// it does nothing and the caller goes on with its portable path.
macro_rules! simd_dispatch {
    ($self:ident, $avx512:ident, $avx:ident, [$($g:ty),*], ($($arg:expr),*)) => {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` names only instruction sets the CPU has (`Isa::detect`).
        match ($self.isa, $self.options.distance_stack) {
            (Isa::Avx512, true) => return unsafe { $self.$avx512::<true, $($g),*>($($arg),*) },
            (Isa::Avx512, false) => return unsafe { $self.$avx512::<false, $($g),*>($($arg),*) },
            (Isa::Avx2, true) => return unsafe { $self.$avx::<true, $($g),*>($($arg),*) },
            (Isa::Avx2, false) => return unsafe { $self.$avx::<false, $($g),*>($($arg),*) },
            (Isa::Baseline, _) => {}
        }
    };
}

/// The instruction set of the 8-wide kernel, in increasing order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Isa {
    /// SSE on x86-64 (the 4-lane slab test twice), portable code elsewhere.
    Baseline,
    /// AVX2 with FMA, BMI1/2, POPCNT and LZCNT (which every AVX2 CPU has): all eight boxes
    /// and the order of the hit children in 8-lane operations.
    Avx2,
    /// The AVX2 program compiled with AVX-512F/VL/BW/DQ as well, for its 32 registers.
    Avx512,
}

impl Isa {
    /// Its name in reports.
    fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// The best the CPU has.
    fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            let avx2 = has!("avx2")
                && has!("fma")
                && has!("bmi1")
                && has!("bmi2")
                && has!("popcnt")
                && has!("lzcnt");
            let avx512 =
                has!("avx512f") && has!("avx512vl") && has!("avx512bw") && has!("avx512dq");
            match (avx2, avx512) {
                (true, true) => Isa::Avx512,
                (true, false) => Isa::Avx2,
                _ => Isa::Baseline,
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        Isa::Baseline
    }
}

/// An 8-wide BVH with its triangles in leaf order, ready to trace.
#[derive(Clone, Debug)]
pub struct Mbvh8Accel {
    nodes: Vec<Node8>,
    leaf: LeafTriangles,
    /// Leaves whose count or first slot does not fit a 32-bit reference.
    big: Vec<ChildRef>,
    options: KernelOptions,
    /// The instruction set the kernel runs with, the best the CPU has (checked once).
    isa: Isa,
    /// The setting of [`Mbvh8Accel::with_interleave`].
    interleave: Interleave,
}

/// How many rays [`Mbvh8Accel::trace_batch`] traces at once on one thread, taking turns
/// node visit by node visit: while one ray waits for a node from memory, the others work
/// (the node it will visit next is prefetched as soon as it is known). This pays once the
/// tree no longer fits the caches, where a ray's time goes to dependent loads from DRAM;
/// on a tree held in the cache the turns only cost (register state is saved and restored,
/// and the branches of different rays mix), so the default interleaves by the tree's size.
/// Measured in `docs/ray-tracing.md` ("Interleaved rays").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
pub enum Interleave {
    /// [`Interleave::DEFAULT_RAYS`] rays when the tree (nodes and leaf blocks) is larger
    /// than the CPU's last-level cache ([`last_level_cache_bytes`]; 32 MiB assumed where
    /// the system does not say), else one.
    #[default]
    Auto,
    /// This many rays at once (1: one after the other; at most [`Interleave::MAX_RAYS`]).
    Rays(usize),
}

impl Interleave {
    /// The rays interleaved where [`Interleave::Auto`] interleaves (measured best of 4, 8
    /// and 16 on Dragon; see `docs/ray-tracing.md`).
    pub const DEFAULT_RAYS: usize = 8;
    /// The most rays one thread interleaves.
    pub const MAX_RAYS: usize = 32;

    /// The rays to interleave over a tree of `tree_bytes`.
    pub fn rays_for(self, tree_bytes: usize) -> usize {
        match self {
            Interleave::Auto => {
                let cache = last_level_cache_bytes().unwrap_or(32 << 20);
                if tree_bytes > cache {
                    Self::DEFAULT_RAYS
                } else {
                    1
                }
            }
            Interleave::Rays(n) => n.clamp(1, Self::MAX_RAYS),
        }
    }
}

/// The size of the CPU's last-level cache, as the operating system reports it (Linux:
/// the highest-level cache of CPU 0 in `/sys/devices/system/cpu/cpu0/cache`); `None`
/// elsewhere or when it cannot be read. Read once.
pub fn last_level_cache_bytes() -> Option<usize> {
    static BYTES: std::sync::OnceLock<Option<usize>> = std::sync::OnceLock::new();
    *BYTES.get_or_init(|| {
        let dir = std::fs::read_dir("/sys/devices/system/cpu/cpu0/cache").ok()?;
        let mut best: Option<(u32, usize)> = None;
        for e in dir.flatten() {
            let read = |f: &str| std::fs::read_to_string(e.path().join(f)).ok();
            let (Some(level), Some(size)) = (read("level"), read("size")) else {
                continue;
            };
            let (Ok(level), Some(bytes)) = (level.trim().parse::<u32>(), parse_cache_size(&size))
            else {
                continue;
            };
            if best.is_none_or(|(l, _)| level > l) {
                best = Some((level, bytes));
            }
        }
        best.map(|(_, b)| b)
    })
}

/// A cache size as Linux writes it (`32768K`, `1M`, `512`).
fn parse_cache_size(s: &str) -> Option<usize> {
    let s = s.trim();
    let (digits, unit) = match s.char_indices().find(|(_, c)| !c.is_ascii_digit()) {
        Some((i, _)) => s.split_at(i),
        None => (s, ""),
    };
    let n: usize = digits.parse().ok()?;
    let scale = match unit {
        "" => 1,
        "K" => 1 << 10,
        "M" => 1 << 20,
        "G" => 1 << 30,
        _ => return None,
    };
    n.checked_mul(scale)
}

/// Entry distances of a node's eight children (`+inf` for a missed or empty slot), the
/// hit mask and the mask of non-empty slots (an empty slot is the only one with
/// `min_x = +inf`).
#[inline(always)]
fn test8(slab: &Slab, n: &Node8, t_max: f32) -> ([f32; WIDTH8], u8, u8) {
    let mut dist = [f32::INFINITY; WIDTH8];
    let (mut mask, mut valid) = (0u8, 0u8);
    for half in 0..2 {
        let (d, m, v) = slab_test4(slab, n.rows.as_flattened(), half * 4, WIDTH8, t_max);
        dist[half * 4..half * 4 + 4].copy_from_slice(&d);
        mask |= m << (half * 4);
        valid |= v << (half * 4);
    }
    (dist, mask, valid)
}

/// [`test8`] in AVX2: the entry distances (lanes of missed slots hold whatever the test
/// computed), the hit lanes (all ones), the hit mask and the mask of non-empty slots. The
/// same IEEE operations as the SSE halves (`vmaxps`/`vminps` return their second operand
/// on NaN like `maxps`/`minps`), so the same bits.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2")]
#[inline]
unsafe fn test8_avx(
    slab: &Slab,
    n: &Node8,
    t_max: f32,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256, u8, u8) {
    use std::arch::x86_64::*;
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
    let valid = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(
        row(0),
        _mm256_set1_ps(f32::INFINITY),
    )) as u8;
    (near, hit, _mm256_movemask_ps(hit) as u8, valid)
}

/// One layer of the sorting network of [`push_sorted_avx`]: each lane meets the lane its
/// shuffle brings, and keeps the larger where `MAX` has its bit set.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2")]
#[inline]
unsafe fn sort_layer<const MAX: i32>(
    k: std::arch::x86_64::__m256i,
    partner: std::arch::x86_64::__m256i,
) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    _mm256_blend_epi32::<MAX>(_mm256_min_epu32(k, partner), _mm256_max_epu32(k, partner))
}

/// Writes the hit children of a node visit (from [`test8_avx`], at least one) farthest
/// first: with `hits` of them, child references to `refs[0..hits]` and entry distances to
/// `dists[0..hits]` (eight lanes are written whatever the count); returns the nearest
/// child's reference (the one written last). The order is that of [`sort_key`]: entry
/// distance, ties by slot, sorted by a bitonic network of six layers on the keys (a missed
/// lane's key is 0, below every hit's). The nearest comes from a horizontal minimum of the
/// keys (three layers), so the next node's address does not wait for the whole network
/// (3-9% faster in `kernel_cost` than reading it from the sorted lanes).
///
/// # Safety
/// The CPU must have AVX2, at least one lane of `hit` must be set, and `refs` and `dists`
/// must be valid for eight writes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2")]
#[inline]
unsafe fn push_sorted_avx(
    n: &Node8,
    near: std::arch::x86_64::__m256,
    hit: std::arch::x86_64::__m256,
    refs: *mut u32,
    dists: *mut f32,
) -> u32 {
    use std::arch::x86_64::*;
    // `sort_key` in eight lanes: flip the bits of negative distances and set the sign
    // bit of the others, then put the slot in the three low bits.
    let b = _mm256_castps_si256(near);
    let ordered = _mm256_xor_si256(
        b,
        _mm256_or_si256(_mm256_srai_epi32::<31>(b), _mm256_set1_epi32(i32::MIN)),
    );
    let slot = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let k = _mm256_and_si256(
        _mm256_or_si256(_mm256_andnot_si256(_mm256_set1_epi32(7), ordered), slot),
        _mm256_castps_si256(hit),
    );
    // The nearest hit child by a horizontal minimum (missed lanes at the top), three
    // layers instead of the network's six: the next node's address is known sooner.
    let m = _mm256_or_si256(
        k,
        _mm256_xor_si256(_mm256_castps_si256(hit), _mm256_set1_epi32(-1)),
    );
    let m = _mm256_min_epu32(m, _mm256_permute2x128_si256::<1>(m, m));
    let m = _mm256_min_epu32(m, _mm256_shuffle_epi32::<0b01_00_11_10>(m));
    let m = _mm256_min_epu32(m, _mm256_shuffle_epi32::<0b10_11_00_01>(m));
    let nearest = n.children[(_mm256_cvtsi256_si32(m) & 7) as usize];
    // Bitonic sort, descending (layer masks: lanes that keep the larger key).
    let k = sort_layer::<0b1001_1001>(k, _mm256_shuffle_epi32::<0b10_11_00_01>(k));
    let k = sort_layer::<0b1100_0011>(k, _mm256_shuffle_epi32::<0b01_00_11_10>(k));
    let k = sort_layer::<0b1010_0101>(k, _mm256_shuffle_epi32::<0b10_11_00_01>(k));
    let k = sort_layer::<0b0000_1111>(k, _mm256_permute2x128_si256::<1>(k, k));
    let k = sort_layer::<0b0011_0011>(k, _mm256_shuffle_epi32::<0b01_00_11_10>(k));
    let k = sort_layer::<0b0101_0101>(k, _mm256_shuffle_epi32::<0b10_11_00_01>(k));
    let slots = _mm256_and_si256(k, _mm256_set1_epi32(7));
    let kids = _mm256_permutevar8x32_epi32(
        _mm256_loadu_si256(n.children.as_ptr() as *const __m256i),
        slots,
    );
    _mm256_storeu_si256(refs as *mut __m256i, kids);
    _mm256_storeu_ps(dists, _mm256_permutevar8x32_ps(near, slots));
    nearest
}

/// The key that orders a node's hit children: the entry distance as an order-preserving
/// integer with the slot in its three low bits (distances within 8 ulps order by slot).
#[inline(always)]
fn sort_key(dist: f32, slot: usize) -> u32 {
    let b = dist.to_bits();
    let ordered = if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    };
    (ordered & !7) | slot as u32
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

impl Mbvh8Accel {
    /// Prepares an 8-wide tree (built over `triangles`) for tracing. Fails when a leaf
    /// names a triangle that does not exist, or the links fail the checks of the
    /// crate's "Trees from anywhere" section (out of range, not after the parent, a node
    /// linked twice, overlapping leaves).
    pub fn new(
        mut bvh: WideBvh<WIDTH8>,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        check_links(
            bvh.nodes.iter().flat_map(|n| n.children.iter()),
            WIDTH8,
            bvh.nodes.len(),
            bvh.prim_indices.len(),
        )?;
        let leaf = LeafTriangles::pack(
            &bvh.prim_indices,
            triangles,
            bvh.nodes.iter_mut().flat_map(|n| n.children.iter_mut()),
        )
        .map_err(|e| e.into_trace_error(triangles.len()))?;
        let mut big = Vec::new();
        let mut nodes: Vec<Node8> = huge_page_vec(bvh.nodes.len());
        for n in &bvh.nodes {
            nodes.push(Node8::new(n, &mut big)?);
        }
        Ok(Self {
            nodes,
            leaf,
            big,
            options,
            isa: Isa::detect(),
            interleave: Interleave::Auto,
        })
    }

    /// The same tree with batches interleaving rays as `interleave` says (the default is
    /// [`Interleave::Auto`]).
    pub fn with_interleave(mut self, interleave: Interleave) -> Self {
        self.interleave = interleave;
        self
    }

    /// The interleave setting, and the rays a batch interleaves per thread for this tree
    /// (1: one ray after the other).
    pub fn interleave(&self) -> (Interleave, usize) {
        (
            self.interleave,
            self.interleave.rays_for(self.memory_bytes()),
        )
    }

    /// Bytes that traversal reads from: the nodes, the leaf blocks and the large-leaf
    /// table.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node8>()
            + self.leaf.block_bytes()
            + self.big.len() * std::mem::size_of::<ChildRef>()
    }

    /// The same tree traced without AVX even where the CPU has it (to test and measure
    /// both paths).
    pub fn without_avx(mut self) -> Self {
        self.isa = Isa::Baseline;
        self
    }

    /// The same tree traced with AVX2 but without the AVX-512 registers even where the CPU
    /// has them (to test and measure both paths; no change elsewhere).
    pub fn without_avx512(mut self) -> Self {
        self.isa = self.isa.min(Isa::Avx2);
        self
    }

    /// The instruction set traversal uses: `"avx512"` (the AVX2 kernel compiled with
    /// AVX-512's 32 vector registers), `"avx2"` or `"baseline"` (SSE, or portable code).
    pub fn isa(&self) -> &'static str {
        self.isa.name()
    }

    /// The instruction set a new kernel uses on this CPU (as [`Mbvh8Accel::isa`]).
    pub fn detected_isa() -> &'static str {
        Isa::detect().name()
    }

    /// An 8-wide tree collapsed from a binary one by [`Mbvh8Accel::collapse`].
    pub fn from_bvh2(
        bvh: &bvh::Bvh2,
        triangles: &[Triangle],
        options: KernelOptions,
    ) -> Result<Self, TraceError> {
        Self::new(Self::collapse(bvh)?, triangles, options)
    }

    /// The 8-wide tree this kernel traces for a binary tree: its SAH-optimal collapse
    /// keeping the binary leaves ([`bvh::collapse_wide_optimal`], the wide nodes of least
    /// total area; on the Crytek Sponza binned SAH tree 36% fewer nodes and 9% fewer node
    /// visits per diffuse ray than the greedy collapse, [`bvh::Collapse::collapse_wide`]).
    /// [`bvh::collapse_wide_blocks`] also merges small subtrees into leaves of one block:
    /// faster on Crytek Sponza, Sibenik, Bunny and Dragon, slower on Conference, so it is
    /// not the default (see `docs/ray-tracing.md`); its trees can be given to
    /// [`Mbvh8Accel::new`].
    pub fn collapse(bvh: &bvh::Bvh2) -> Result<WideBvh<WIDTH8>, TraceError> {
        bvh::collapse_wide_optimal::<WIDTH8>(bvh, &bvh::SahParams::THESIS, bvh::CollapseGoal::Sah)
            .map_err(|e| TraceError::BadTree(e.to_string()))
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
            |n| n.children.map(|c| decode(c, &self.big)),
            |n, c, b| n.set_box(c, b),
        );
        Ok(())
    }

    /// Starts loading a child that traversal will visit later (all four cache lines of a
    /// node, or the first block of a leaf).
    #[inline(always)]
    fn prefetch_child(&self, child: u32) {
        if child & child8::LEAF != 0 {
            self.leaf.prefetch(child & child8::SLOT_MASK);
        } else {
            let p = self.nodes.as_ptr().wrapping_add(child as usize) as *const u8;
            for line in 0..4 {
                prefetch(p.wrapping_add(64 * line));
            }
        }
    }

    simd_entry_points! {
        /// compiled for AVX2 (with FMA, BMI1/2, POPCNT and LZCNT, which every AVX2 CPU
        /// has), with the AVX2 node visit. Rust never contracts a multiply and an add into
        /// an FMA, so the results are those of the baseline path bit for bit.
        run_avx, each_avx, batch_avx, false, "avx,avx2,fma,bmi1,bmi2,popcnt,lzcnt"
    }

    simd_entry_points! {
        /// compiled as the AVX2 entry points with AVX-512 as well: the same 8-lane
        /// (256-bit) program, which then has 32 vector registers instead of 16, so the
        /// ray's broadcast origin, reciprocal direction and ranges stay in registers
        /// through a node visit instead of being reloaded from the stack. Same results bit
        /// for bit (no operation changes).
        run_avx512, each_avx512, batch_avx512, true,
        "avx,avx2,fma,bmi1,bmi2,popcnt,lzcnt,avx512f,avx512vl,avx512bw,avx512dq"
    }

    /// Traversal ([`traverse`]) with the 8-wide node visit ([`Self::visit`]). `AVX512` and
    /// `EACH` change no operation: they make each entry point's instantiation (and so its
    /// closures) its own (`EACH`: the one-ray-after-the-other batch), so that they inline
    /// there rather than stay one out-of-line function between two entry points.
    #[inline(always)]
    fn run<const DIST: bool, const AVX: bool, const AVX512: bool, const EACH: bool, O: Observer>(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut TraversalStack,
        total: &mut RayStats,
        obs: &mut O,
    ) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let slab = Slab::new(&pre, ray.t_min);
        traverse::<DIST, O, _>(
            &self.leaf,
            ray,
            &pre,
            query,
            &mut stack.wide(),
            total,
            obs,
            0,
            |c| self.as_leaf(c),
            |c, best_t, st, stats, obs| self.visit::<AVX, O>(&slab, c, best_t, st, stats, obs),
        )
    }

    /// The leaf a reference names, if it names one.
    #[inline(always)]
    fn as_leaf(&self, c: u32) -> Option<ChildRef> {
        (c & child8::LEAF != 0).then(|| decode(c, &self.big))
    }

    /// The 8-wide node visit of inner node `cur` against the cull distance of `best_t`:
    /// with more than one hit child, writes them, farthest first, on top of the stack; the
    /// last written (nearest) is returned to be visited next and the others stay pushed.
    #[inline(always)]
    fn visit<const AVX: bool, O: Observer>(
        &self,
        slab: &Slab,
        cur: u32,
        best_t: f32,
        st: &mut WideStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<u32> {
        let node = &self.nodes[cur as usize];
        let t_max = cull_distance(best_t);
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: `AVX` is only set by the `_avx` entry points, which run with AVX2
            // enabled (and are only called where the CPU has it); `top` hands out at
            // least eight entries, all that `push_sorted_avx` writes.
            return unsafe {
                let (near, hit, mask, valid) = test8_avx(slab, node, t_max);
                let hits = Self::visited(cur, valid, mask, stats, obs);
                if hits == 0 {
                    return None;
                }
                self.prefetch_hits(node, mask);
                if hits == 1 {
                    return Some(node.children[mask.trailing_zeros() as usize & 7]);
                }
                let (refs, dists) = st.top(WIDTH8);
                let next = push_sorted_avx(node, near, hit, refs.as_mut_ptr(), dists.as_mut_ptr());
                self.pushed(&refs[..hits - 1], stats, obs);
                st.grow(hits - 1);
                stats.max_stack_depth = stats.max_stack_depth.max(st.len() as u64);
                Some(next)
            };
        }
        self.visit8(slab, node, cur, t_max, st, stats, obs)
    }

    /// Traces `rays` [`Self::lanes`] at a time on this thread, round robin: each ray in
    /// turn takes one step of its [`Walk`] (a node visit, which prefetches the children it
    /// will visit, or a leaf test), so that while one ray's next node is on its way from
    /// memory the others work. A finished ray hands its lane to the next ray of the batch.
    /// Each ray's steps are those it takes alone, so its answer and counters are too.
    /// `AVX512` as in [`Self::run`].
    #[inline(always)]
    fn batch<
        const DIST: bool,
        const AVX: bool,
        const AVX512: bool,
        R: RaySource + ?Sized,
        F: FnMut(usize, Option<Hit>, &RayStats),
    >(
        &self,
        rays: &R,
        query: Query,
        stack: &mut TraversalStack,
        mut done: F,
    ) {
        struct Lane<'s> {
            /// The index of the ray traced in this lane (`usize::MAX`: none, the batch is
            /// ending), and the ray.
            index: usize,
            ray: Ray,
            /// The reference it visits next (`None`: the ray is done).
            cur: Option<u32>,
            pre: RayPrecomp,
            slab: Slab,
            /// The closest hit so far (`best_t`: its distance, or the ray's end).
            best: Option<Hit>,
            best_t: f32,
            stats: RayStats,
            stack: WideStack<'s>,
        }
        let start = |i: usize, stack: &mut WideStack<'_>| {
            let ray = rays.ray(i);
            let pre = RayPrecomp::new(&ray);
            let slab = Slab::new(&pre, ray.t_min);
            let mut stats = RayStats::default();
            let cur = accel::begin(&ray, query, 0, stack, &mut stats, &mut ());
            (ray, pre, slab, stats, cur)
        };
        let n = self.interleave().1.min(rays.len());
        let mut lanes: Vec<Lane> = stack
            .lanes(n)
            .iter_mut()
            .enumerate()
            .map(|(i, st)| {
                let mut stack = st.wide();
                let (ray, pre, slab, stats, cur) = start(i, &mut stack);
                Lane {
                    index: i,
                    ray,
                    cur,
                    pre,
                    slab,
                    best: None,
                    best_t: ray.t_max,
                    stats,
                    stack,
                }
            })
            .collect();
        let mut next = n;
        let mut live = n;
        while live > 0 {
            for l in lanes.iter_mut() {
                if l.index == usize::MAX {
                    continue;
                }
                let slab = &l.slab;
                if let Some(c) = l.cur {
                    l.cur = match accel::step::<(), _>(
                        c,
                        &self.leaf,
                        &l.ray,
                        &l.pre,
                        query,
                        &mut l.best,
                        &mut l.best_t,
                        &mut l.stack,
                        &mut l.stats,
                        &mut (),
                        |c| self.as_leaf(c),
                        |c, best_t, st, stats, obs| {
                            self.visit::<AVX, ()>(slab, c, best_t, st, stats, obs)
                        },
                    ) {
                        accel::Next::Visit(next) => Some(next),
                        accel::Next::Pop => {
                            KernelStack::pop(&mut l.stack, DIST, l.best_t, &mut l.stats, &mut ())
                        }
                        accel::Next::Done => None,
                    };
                    if l.cur.is_some() {
                        continue;
                    }
                }
                let hit = accel::finish(l.best.take(), &mut l.stats, &mut ());
                done(l.index, hit, &l.stats);
                if next < rays.len() {
                    (l.ray, l.pre, l.slab, l.stats, l.cur) = start(next, &mut l.stack);
                    l.best_t = l.ray.t_max;
                    l.index = next;
                    next += 1;
                } else {
                    l.index = usize::MAX;
                    live -= 1;
                }
            }
        }
    }

    /// Counts a visit of node `index` (its non-empty slots `valid` as box tests) and
    /// reports it with its hit children `mask` to the observer; returns how many children
    /// were hit. Both node visits start with it.
    #[inline(always)]
    fn visited<O: Observer>(
        index: u32,
        valid: u8,
        mask: u8,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> usize {
        stats.node_visits += 1;
        stats.box_tests += POPCOUNT8[valid as usize] as u64;
        obs.node(index, valid, mask);
        POPCOUNT8[mask as usize] as usize
    }

    /// Prefetches the hit children of `node` (`mask`), the one visited next included.
    #[inline(always)]
    fn prefetch_hits(&self, node: &Node8, mask: u8) {
        let mut m = mask;
        while m != 0 {
            let slot = m.trailing_zeros() as usize & 7;
            m &= m - 1;
            self.prefetch_child(node.children[slot]);
        }
    }

    /// Counts the pushes of `refs` and reports them to the observer.
    #[inline(always)]
    fn pushed<O: Observer>(&self, refs: &[u32], stats: &mut RayStats, obs: &mut O) {
        for &r in refs {
            obs.push(self.leaf.original(decode(r, &self.big)));
        }
        stats.pushes += refs.len() as u64;
    }

    /// The node visit of the AVX2 path without AVX: the same box test (two SSE halves)
    /// and the same order of the hit children (by [`sort_key`], farthest pushed first).
    /// Pushes all hit children but the nearest and returns the nearest.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn visit8<O: Observer>(
        &self,
        slab: &Slab,
        node: &Node8,
        index: u32,
        t_max: f32,
        st: &mut WideStack,
        stats: &mut RayStats,
        obs: &mut O,
    ) -> Option<u32> {
        let (dist, mask, valid) = test8(slab, node, t_max);
        let hits = Self::visited(index, valid, mask, stats, obs);
        if hits == 0 {
            return None;
        }
        self.prefetch_hits(node, mask);
        // Insertion sort of the hit children's keys, largest first.
        let mut keys = [0u32; WIDTH8];
        let mut n = 0;
        let mut m = mask;
        while m != 0 {
            let slot = m.trailing_zeros() as usize;
            m &= m - 1;
            let k = sort_key(dist[slot], slot);
            let mut j = n;
            while j > 0 && keys[j - 1] < k {
                keys[j] = keys[j - 1];
                j -= 1;
            }
            keys[j] = k;
            n += 1;
        }
        let (refs, dists) = st.top(WIDTH8);
        for (i, &k) in keys[..hits].iter().enumerate() {
            let slot = (k & 7) as usize;
            refs[i] = node.children[slot];
            dists[i] = dist[slot];
        }
        let next = refs[hits - 1];
        self.pushed(&refs[..hits - 1], stats, obs);
        st.grow(hits - 1);
        stats.max_stack_depth = stats.max_stack_depth.max(st.len() as u64);
        Some(next)
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
        simd_dispatch!(
            self,
            run_avx512,
            run_avx,
            [O],
            (ray, query, stack, stats, obs)
        );
        if self.options.distance_stack {
            self.run::<true, false, false, false, O>(ray, query, stack, stats, obs)
        } else {
            self.run::<false, false, false, false, O>(ray, query, stack, stats, obs)
        }
    }

    /// As [`Traverse::trace_batch`], interleaving the rays [`Mbvh8Accel::interleave`]
    /// says on this thread (see [`Interleave`]).
    fn trace_batch<R: RaySource + ?Sized, F: FnMut(usize, Option<Hit>, &RayStats)>(
        &self,
        rays: &R,
        query: Query,
        stack: &mut TraversalStack,
        done: F,
    ) {
        if rays.len() <= 1 || self.interleave().1 <= 1 {
            simd_dispatch!(
                self,
                each_avx512,
                each_avx,
                [R, F],
                (rays, query, stack, done)
            );
            return accel::trace_each(self, rays, query, stack, done);
        }
        simd_dispatch!(
            self,
            batch_avx512,
            batch_avx,
            [R, F],
            (rays, query, stack, done)
        );
        if self.options.distance_stack {
            self.batch::<true, false, false, R, F>(rays, query, stack, done)
        } else {
            self.batch::<false, false, false, R, F>(rays, query, stack, done)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{all_mbvh8, random_rays, soup};
    use bvh::WideNode;
    use geom::Vec3;

    #[test]
    fn child_references_round_trip_and_large_leaves_escape() {
        let mut big = Vec::new();
        let cases = [
            ChildRef::inner(1),
            ChildRef::inner((1 << 31) - 1),
            ChildRef::leaf(0, 1),
            ChildRef::leaf(child8::SLOT_MASK, 31),
            ChildRef::leaf(7, 32),
            ChildRef::leaf(child8::SLOT_MASK + 1, 1),
            ChildRef::leaf(3, u32::MAX),
            ChildRef::EMPTY,
        ];
        let coded: Vec<u32> = cases
            .iter()
            .map(|&c| encode(c, &mut big).unwrap())
            .collect();
        // The three that do not fit went to the table, in order.
        assert_eq!(big, vec![cases[4], cases[5], cases[6]]);
        assert_eq!(coded[3], (1 << 31) | (30 << 26) | child8::SLOT_MASK);
        for (c, &k) in cases.iter().zip(&coded) {
            assert_eq!(decode(k, &big), *c);
        }
        // An inner index with the leaf bit cannot be written.
        assert!(encode(ChildRef::inner(1 << 31), &mut Vec::new()).is_err());
        // The test trees of `all_mbvh8` include leaves that need the table.
        let tris = soup(1500, 1.5, 11);
        let big_leaves = all_mbvh8(&tris)
            .into_iter()
            .filter(|(n, _)| n.starts_with("big-leaves"))
            .collect::<Vec<_>>();
        assert!(!big_leaves.is_empty());
        assert!(big_leaves.iter().all(|(_, a)| !a.big.is_empty()));
    }

    /// A ray along +x through three leaves meets them nearest first, along -x the other
    /// way round; both paths (AVX2 and baseline) alike.
    #[test]
    fn rays_visit_leaves_nearest_first() {
        #[derive(Default)]
        struct Leaves(Vec<u32>);
        impl Observer for Leaves {
            fn leaf(&mut self, first: u32, _count: u32) {
                self.0.push(first);
            }
        }
        let tri = |x: f32| Triangle {
            v: [
                Vec3::new(x + 0.5, -1.0, -1.0),
                Vec3::new(x + 0.5, 3.0, -1.0),
                Vec3::new(x + 0.5, -1.0, 3.0),
            ],
        };
        // Triangles (prims) 0, 1, 2 at x = 10.5, 20.5, 0.5; leaf k holds prim k.
        let tris = [tri(10.0), tri(20.0), tri(0.0)];
        let mut n = WideNode::<WIDTH8> {
            boxes: [Aabb::EMPTY; WIDTH8],
            children: [ChildRef::EMPTY; WIDTH8],
        };
        for (slot, t) in tris.iter().enumerate() {
            n.boxes[slot] = t.aabb();
            n.children[slot] = ChildRef::leaf(slot as u32, 1);
        }
        let bvh = WideBvh {
            nodes: vec![n],
            prim_indices: vec![0, 1, 2],
            bounds: tris.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb())),
        };
        let opts = KernelOptions {
            distance_stack: false,
        };
        let a = Mbvh8Accel::new(bvh, &tris, opts).unwrap();
        for accel in [a.clone(), a.clone().without_avx512(), a.without_avx()] {
            for (origin, dir, order) in [(-5.0, 1.0, [2, 0, 1]), (30.0, -1.0, [1, 0, 2])] {
                let ray = Ray::new(Vec3::new(origin, 0.5, 0.5), Vec3::new(dir, 0.01, 0.02));
                let mut obs = Leaves::default();
                let mut stats = RayStats::default();
                let hit = accel.trace_observed(
                    &ray,
                    Query::Closest,
                    &mut TraversalStack::new(),
                    &mut stats,
                    &mut obs,
                );
                assert_eq!(obs.0, order);
                assert_eq!(hit.map(|h| h.prim), Some(order[0]));
                assert_eq!((stats.node_visits, stats.pushes, stats.pops), (1, 2, 2));
            }
        }
    }

    /// The AVX2 node visit and the baseline one give the same answers and the same
    /// counters ray by ray (same box bits, same order of the hit children).
    /// Batches (interleaved or not, any number of rays per lane, with rays that start
    /// non-finite among them) answer each ray exactly once, with the hit and counters it
    /// gets alone, on every test tree and both paths.
    #[test]
    fn interleaved_batches_trace_each_ray_as_alone() {
        let tris = soup(1200, 1.5, 11);
        let mut rays = random_rays(700, Vec3::ZERO, 2.0, 5);
        rays[3].origin.x = f32::NAN;
        rays[500].dir = Vec3::new(f32::INFINITY, 0.0, 0.0);
        rays[9].t_max = 0.5;
        for (name, accel) in all_mbvh8(&tris) {
            let mut stack = TraversalStack::new();
            for q in [Query::Closest, Query::Any] {
                let alone: Vec<_> = rays
                    .iter()
                    .map(|r| {
                        let mut s = RayStats::default();
                        (accel.trace_observed(r, q, &mut stack, &mut s, &mut ()), s)
                    })
                    .collect();
                for lanes in [1, 2, 3, 8, 31, 32, 1000] {
                    let a = accel.clone().with_interleave(Interleave::Rays(lanes));
                    assert_eq!(a.interleave().1, lanes.min(Interleave::MAX_RAYS));
                    for len in [0, 1, 5, rays.len()] {
                        let mut got = vec![None; len];
                        a.trace_batch(&rays[..len], q, &mut stack, |i, h, s| {
                            assert!(got[i].is_none(), "{name}: ray {i} answered twice");
                            got[i] = Some((h, *s));
                        });
                        for (i, g) in got.iter().enumerate() {
                            assert_eq!(
                                g.as_ref(),
                                Some(&alone[i]),
                                "{name} {q:?} x{lanes}: ray {i}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// A batch reads its rays through `RaySource`: rays kept as columns trace exactly as
    /// the same rays in a slice.
    #[test]
    fn batches_read_rays_from_any_source() {
        struct Columns {
            o: Vec<Vec3>,
            d: Vec<Vec3>,
            range: Vec<[f32; 2]>,
        }
        impl RaySource for Columns {
            fn len(&self) -> usize {
                self.o.len()
            }
            fn ray(&self, i: usize) -> Ray {
                Ray::with_range(self.o[i], self.d[i], self.range[i][0], self.range[i][1])
            }
        }
        let tris = soup(800, 1.5, 4);
        let rays = random_rays(300, Vec3::ZERO, 2.0, 8);
        let cols = Columns {
            o: rays.iter().map(|r| r.origin).collect(),
            d: rays.iter().map(|r| r.dir).collect(),
            range: rays.iter().map(|r| [r.t_min, r.t_max]).collect(),
        };
        assert!(!cols.is_empty() && RaySource::is_empty(&rays[..0]));
        let (_, a) = all_mbvh8(&tris).swap_remove(3);
        let mut stack = TraversalStack::new();
        for lanes in [1, 8] {
            let a = a.clone().with_interleave(Interleave::Rays(lanes));
            let (mut x, mut y) = (vec![None; 300], vec![None; 300]);
            a.trace_batch(&rays[..], Query::Closest, &mut stack, |i, h, _| x[i] = h);
            a.trace_batch(&cols, Query::Closest, &mut stack, |i, h, _| y[i] = h);
            assert_eq!(x, y);
            assert!(x.iter().any(|h| h.is_some()));
        }
    }

    /// `Auto` interleaves exactly when the tree is larger than the last-level cache.
    #[test]
    fn auto_interleaves_trees_larger_than_the_cache() {
        let cache = last_level_cache_bytes().unwrap_or(32 << 20);
        assert_eq!(Interleave::Auto.rays_for(cache), 1);
        assert_eq!(
            Interleave::Auto.rays_for(cache + 1),
            Interleave::DEFAULT_RAYS
        );
        assert_eq!(Interleave::Rays(0).rays_for(1), 1);
        assert_eq!(Interleave::Rays(1 << 40).rays_for(1), Interleave::MAX_RAYS);
        // A small tree is not interleaved unless asked.
        let tris = soup(100, 1.0, 2);
        let (_, a) = all_mbvh8(&tris).swap_remove(1);
        assert_eq!(a.interleave(), (Interleave::Auto, 1));
        assert!(a.memory_bytes() >= a.node_count() * 256);
        assert_eq!(
            a.with_interleave(Interleave::Rays(4)).interleave(),
            (Interleave::Rays(4), 4)
        );
    }

    #[test]
    fn cache_sizes_parse_as_linux_writes_them() {
        assert_eq!(parse_cache_size("32768K\n"), Some(32 << 20));
        assert_eq!(parse_cache_size("1M"), Some(1 << 20));
        assert_eq!(parse_cache_size("512"), Some(512));
        assert_eq!(parse_cache_size("2G"), Some(2 << 30));
        assert_eq!(parse_cache_size("12Q"), None);
        assert_eq!(parse_cache_size(""), None);
        assert_eq!(parse_cache_size("99999999999999999999999K"), None);
    }

    #[test]
    fn avx_and_baseline_paths_count_alike() {
        let tris = soup(1500, 1.5, 7);
        let rays = random_rays(3000, Vec3::ZERO, 2.0, 3);
        let all = all_mbvh8(&tris);
        // Each tree's baseline path, then its AVX2 and (where the CPU has it) AVX-512 ones.
        let mut pairs = Vec::new();
        for (sse_name, sse) in all.iter().filter(|(n, _)| n.ends_with("/sse")) {
            let base = sse_name.trim_end_matches("sse");
            for (name, avx) in all
                .iter()
                .filter(|(n, _)| n.starts_with(base) && n != sse_name)
            {
                pairs.push((name, sse, avx));
            }
        }
        let baselines = all.iter().filter(|(n, _)| n.ends_with("/sse")).count();
        assert!(baselines > 0);
        assert_eq!(
            pairs.len(),
            all.len() - baselines,
            "every other path compared with its tree's baseline"
        );
        for (name, sse, avx) in pairs {
            let mut stack = TraversalStack::new();
            for ray in &rays {
                for q in [Query::Closest, Query::Any] {
                    let (mut s1, mut s2) = (RayStats::default(), RayStats::default());
                    let h1 = sse.trace_observed(ray, q, &mut stack, &mut s1, &mut ());
                    let h2 = avx.trace_observed(ray, q, &mut stack, &mut s2, &mut ());
                    assert_eq!(h1, h2, "{name}");
                    assert_eq!(s1, s2, "{name}");
                }
            }
        }
    }

    /// The AVX2 sorting network writes the hit children in the order of the scalar sort
    /// (`sort_key` descending), on random distances with ties, signed zeros, infinities
    /// and every hit mask.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sorting_network_orders_like_the_keys() {
        use std::arch::x86_64::*;
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: this CPU has no AVX2 (the baseline path is tested elsewhere)");
            return;
        }
        let mut rng = crate::testutil::Rng::new(5);
        let pool = [0.0f32, -0.0, 1.0, 1.0, 2.5, f32::INFINITY, 1e-30, 7.0];
        let node = Node8 {
            rows: [[0.0; WIDTH8]; 6],
            children: std::array::from_fn(|i| 100 + i as u32),
        };
        for case in 0..20_000 {
            let mask = (case % 256) as u8;
            let near: [f32; WIDTH8] = std::array::from_fn(|_| {
                if rng.f32() < 0.5 {
                    pool[(rng.f32() * 8.0) as usize & 7]
                } else {
                    rng.f32() * 10.0
                }
            });
            let hits = mask.count_ones() as usize;
            if hits == 0 {
                continue;
            }
            let mut order: Vec<usize> = (0..WIDTH8).filter(|&i| mask >> i & 1 == 1).collect();
            order.sort_by_key(|&i| std::cmp::Reverse(sort_key(near[i], i)));
            let (mut refs, mut dists) = ([0u32; WIDTH8], [0f32; WIDTH8]);
            // SAFETY: AVX2 is present (checked above); both outputs hold eight lanes.
            let next = unsafe {
                let hit_lanes: [u32; WIDTH8] =
                    std::array::from_fn(|i| if mask >> i & 1 == 1 { u32::MAX } else { 0 });
                push_sorted_avx(
                    &node,
                    _mm256_loadu_ps(near.as_ptr()),
                    _mm256_castsi256_ps(_mm256_loadu_si256(hit_lanes.as_ptr() as *const __m256i)),
                    refs.as_mut_ptr(),
                    dists.as_mut_ptr(),
                )
            };
            let want: Vec<u32> = order.iter().map(|&i| 100 + i as u32).collect();
            assert_eq!(refs[..hits], want[..], "{near:?} {mask:08b}");
            for (k, &i) in order.iter().enumerate() {
                assert_eq!(dists[k].to_bits(), near[i].to_bits());
            }
            assert_eq!(next, want[hits - 1]);
        }
    }
}
