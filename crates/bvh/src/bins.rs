//! The per-axis bins of a binned SAH split search, shared by the binary and the 4-wide
//! top-down builders: for each axis and bin the corners of the primitives' boxes and their
//! count, as separate arrays (a bin update touches one entry of each); the [`Binner`]
//! that maps centroids to bins, and the binning of primitive references.

use crate::split::PrimRef;
use geom::{Aabb, Vec4};
use rayon::prelude::*;

/// Per-axis bins: box corners and count of the primitives in each of `N` bins per axis.
#[derive(Clone)]
pub(crate) struct Bins<const N: usize> {
    pub(crate) min: [[Vec4; N]; 3],
    pub(crate) max: [[Vec4; N]; 3],
    pub(crate) cnt: [[u32; N]; 3],
}

impl<const N: usize> Bins<N> {
    /// Empty bins.
    pub(crate) fn new() -> Self {
        Self {
            min: [[Vec4::splat(f32::INFINITY); N]; 3],
            max: [[Vec4::splat(f32::NEG_INFINITY); N]; 3],
            cnt: [[0; N]; 3],
        }
    }

    /// The union of two bin sets (exact and order-independent: min, max and counts).
    pub(crate) fn merge(mut self, o: &Self) -> Self {
        for a in 0..3 {
            for i in 0..N {
                self.min[a][i] = self.min[a][i].min(o.min[a][i]);
                self.max[a][i] = self.max[a][i].max(o.max[a][i]);
                self.cnt[a][i] += o.cnt[a][i];
            }
        }
        self
    }
}

/// Maps centroids to bins: `bin = (c - min) * scale`, clamped to `0..=last`.
#[derive(Clone, Copy)]
pub(crate) struct Binner {
    /// The centroid box's minimum corner (lane w 0).
    pub(crate) min: Vec4,
    /// Bins per unit length on each axis; 0 on an axis that offers no plane (lane w 0).
    pub(crate) scale: Vec4,
    /// The last bin.
    pub(crate) last: usize,
}

impl Binner {
    /// The binner of `bins` bins per axis over the centroid box `cbounds`.
    pub(crate) fn new(cbounds: &Aabb, bins: usize) -> Self {
        let e = cbounds.max - cbounds.min;
        let s = |x: f32| {
            let v = bins as f32 / x;
            // Zero or overflowing extent: every centroid lands in bin 0, so the axis
            // offers no plane and is skipped by the sweep (both sides must be non-empty).
            if x > 0.0 && v.is_finite() {
                v
            } else {
                0.0
            }
        };
        Self {
            min: cbounds.min.extend(0.0),
            scale: Vec4::new(s(e.x), s(e.y), s(e.z), 0.0),
            last: bins - 1,
        }
    }

    /// The bins of centroid `c` on the three axes (lane w is 0), in one SIMD pass: the
    /// clamp to `[0, last]` comes first (`max` maps NaN to 0), so truncation is the floor
    /// of an in-range value and equals the scalar `as usize` then `min(last)`.
    #[inline(always)]
    pub(crate) fn bins(&self, c: Vec4) -> [usize; 4] {
        let f = ((c - self.min) * self.scale)
            .max(Vec4::ZERO)
            .min(Vec4::splat(self.last as f32));
        truncate4(f)
    }

    /// The clamped bin coordinate of centroid `c` on `axis`, whose integer part is its bin
    /// (the same arithmetic as [`Binner::bins`]; monotone in the centroid).
    #[inline(always)]
    pub(crate) fn coord(&self, c: Vec4, axis: usize) -> f32 {
        ((c - self.min) * self.scale)
            .max(Vec4::ZERO)
            .min(Vec4::splat(self.last as f32))[axis]
    }

    /// The bin of centroid `c` on `axis` (the same value as [`Binner::bins`]).
    #[inline(always)]
    pub(crate) fn bin(&self, c: Vec4, axis: usize) -> usize {
        self.bins(c)[axis]
    }
}

/// The lanes of `f` (each in `0..2^31`) truncated to integers.
#[inline(always)]
fn truncate4(f: Vec4) -> [usize; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__m128i, _mm_cvttps_epi32, _mm_storeu_si128};
        let mut out = [0u32; 4];
        // SAFETY: SSE2 is part of the x86_64 baseline; `out` is 16 writable bytes and the
        // store is unaligned.
        unsafe {
            let i = _mm_cvttps_epi32(f.into());
            _mm_storeu_si128(out.as_mut_ptr() as *mut __m128i, i);
        }
        out.map(|x| x as usize)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        f.to_array().map(|x| x as usize)
    }
}

/// Binning of [`PrimRef`]s, shared by the binary and the 4-wide builders.
impl<const N: usize> Bins<N> {
    /// Drops `refs` into the bins.
    #[inline(always)]
    fn add(&mut self, refs: &[PrimRef], binner: &Binner) {
        for r in refs {
            let idx = binner.bins(r.centroid4());
            for (axis, &k) in idx.iter().take(3).enumerate() {
                // `k <= last < N`; the mask (N is a power of two) only drops the check.
                let i = k & (N - 1);
                self.min[axis][i] = self.min[axis][i].min(r.min);
                self.max[axis][i] = self.max[axis][i].max(r.max);
                self.cnt[axis][i] += 1;
            }
        }
    }

    /// Bins `refs`. Large nodes are binned in parallel chunks, and medium ones into two
    /// interleaved sets, so that runs of primitives in the same bin (common: meshes are
    /// spatially coherent) do not chain every update on the previous one's store. The
    /// result is the same bins either way. Where the CPU has AVX, each chunk is binned by
    /// [`avx::fill`] (one 256-bit update per bin instead of two 128-bit ones), which gives
    /// the same bins, bit for bit.
    pub(crate) fn fill(refs: &[PrimRef], binner: &Binner) -> Self {
        if refs.len() >= PAR_BIN_MIN && rayon::current_num_threads() > 1 {
            return refs
                .par_chunks(PAR_BIN_MIN / 4)
                .map(|c| Self::fill(c, binner))
                .reduce(Self::new, |a, b| a.merge(&b));
        }
        #[cfg(target_arch = "x86_64")]
        if avx::available() {
            // SAFETY: the CPU has AVX (checked at run time).
            return unsafe { avx::fill(refs, binner) };
        }
        Self::fill_scalar(refs, binner)
    }

    /// [`Bins::fill`] of one chunk with 128-bit updates (the x86-64 baseline): one set of
    /// bins, or two interleaved sets from [`DUAL_BINS_MIN`] primitives.
    pub(crate) fn fill_scalar(refs: &[PrimRef], binner: &Binner) -> Self {
        let mut a = Self::new();
        if refs.len() < DUAL_BINS_MIN {
            a.add(refs, binner);
            return a;
        }
        let mut b = Self::new();
        let mut pairs = refs.chunks_exact(2);
        for p in &mut pairs {
            a.add(&p[..1], binner);
            b.add(&p[1..], binner);
        }
        a.add(pairs.remainder(), binner);
        a.merge(&b)
    }
}

/// Binning with 256-bit AVX updates, chosen at run time (the crate compiles for the
/// x86-64 baseline). A bin holds its box as one 8-lane vector `(min, -max)`, so that one
/// `vminps` updates both corners; the negation is exact and `-min(-a, -b)` picks the same
/// operand as `max(a, b)` in every case (equal values and signed zeros: the second; NaN:
/// the second), so the bins are those of [`Bins::fill_scalar`] bit for bit, with the same
/// sets and the same merge order.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx {
    use super::{Binner, Bins, DUAL_BINS_MIN};
    use crate::split::PrimRef;
    use geom::Vec4;
    use std::arch::x86_64::*;

    /// Whether this CPU runs [`fill`] (AVX; detected once, then a cached load).
    #[inline(always)]
    pub(crate) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx")
    }

    /// Bins as `(min, -max)` vectors and counts. (The `target_feature` functions are
    /// `unsafe fn`: safe ones need Rust 1.86, the workspace supports 1.85.)
    struct Wide<const N: usize> {
        b: [[__m256; N]; 3],
        cnt: [[u32; N]; 3],
    }

    impl<const N: usize> Wide<N> {
        /// Empty bins: min +inf, -max +inf.
        #[target_feature(enable = "avx")]
        #[inline]
        unsafe fn new() -> Self {
            Self {
                b: [[_mm256_set1_ps(f32::INFINITY); N]; 3],
                cnt: [[0; N]; 3],
            }
        }

        /// Drops `refs` into the bins, in order (as [`Bins::add`]).
        #[target_feature(enable = "avx")]
        #[inline]
        unsafe fn add(&mut self, refs: &[PrimRef], binner: &Binner) {
            for r in refs {
                let idx = binner.bins(r.centroid4());
                let v = _mm256_insertf128_ps(
                    _mm256_castps128_ps256(r.min.into()),
                    // Negation flips the sign bit only: exact.
                    (-r.max).into(),
                    1,
                );
                for (axis, &k) in idx.iter().take(3).enumerate() {
                    // `k <= last < N`; the mask (N is a power of two) only drops the check.
                    let i = k & (N - 1);
                    self.b[axis][i] = _mm256_min_ps(self.b[axis][i], v);
                    self.cnt[axis][i] += 1;
                }
            }
        }

        /// The bins in [`Bins`]' layout.
        #[target_feature(enable = "avx")]
        #[inline]
        unsafe fn bins(&self) -> Bins<N> {
            let mut out = Bins::new();
            for a in 0..3 {
                for i in 0..N {
                    let v = self.b[a][i];
                    out.min[a][i] = Vec4::from(_mm256_castps256_ps128(v));
                    out.max[a][i] = -Vec4::from(_mm256_extractf128_ps(v, 1));
                }
            }
            out.cnt = self.cnt;
            out
        }
    }

    /// [`Bins::fill_scalar`] with 256-bit updates: the same sets, order and merge.
    ///
    /// # Safety
    ///
    /// The CPU must have AVX ([`available`]).
    #[target_feature(enable = "avx")]
    pub(crate) unsafe fn fill<const N: usize>(refs: &[PrimRef], binner: &Binner) -> Bins<N> {
        let mut a = Wide::<N>::new();
        if refs.len() < DUAL_BINS_MIN {
            a.add(refs, binner);
            return a.bins();
        }
        let mut b = Wide::<N>::new();
        let mut pairs = refs.chunks_exact(2);
        for p in &mut pairs {
            a.add(&p[..1], binner);
            b.add(&p[1..], binner);
        }
        a.add(pairs.remainder(), binner);
        a.bins().merge(&b.bins())
    }
}

/// Nodes of at least this many primitives are binned in parallel chunks.
const PAR_BIN_MIN: usize = 1 << 15;

/// Nodes of at least this many primitives are binned into two interleaved bin sets.
const DUAL_BINS_MIN: usize = 256;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{adversarial, soup};
    use geom::{Aabb, Vec3};

    /// The bins as bit patterns (equal floats of different sign, or NaN, differ).
    fn bits<const N: usize>(b: &Bins<N>) -> Vec<u32> {
        let mut v = Vec::new();
        for a in 0..3 {
            for i in 0..N {
                v.extend(b.min[a][i].to_array().map(f32::to_bits));
                v.extend(b.max[a][i].to_array().map(f32::to_bits));
                v.push(b.cnt[a][i]);
            }
        }
        v
    }

    /// Every chunk size around the single/dual set threshold, and sets with signed zeros
    /// and equal corners (where `min`/`max` pick an operand by position).
    fn inputs() -> Vec<Vec<Aabb>> {
        let mut sets: Vec<Vec<Aabb>> = [1, 2, 17, 255, 256, 257, 1000, 5001]
            .iter()
            .map(|&n| soup(n, 5.0, n as u64))
            .collect();
        let zeros: Vec<Aabb> = (0..600)
            .map(|i| {
                let z = |k: u32| if (i >> k) & 1 == 0 { 0.0f32 } else { -0.0 };
                let x = (i % 7) as f32 - 3.0;
                Aabb::new(
                    Vec3::new(z(0).min(x), z(1), z(2)),
                    Vec3::new(z(3).max(x), z(4), z(5) + (i % 3) as f32),
                )
            })
            .collect();
        sets.push(zeros);
        sets.extend(adversarial().into_iter().map(|(_, b)| b));
        sets
    }

    fn same_as_scalar<const N: usize>(bins: usize) {
        for (k, boxes) in inputs().iter().enumerate() {
            let refs: Vec<PrimRef> = (boxes.iter().enumerate())
                .map(|(i, b)| PrimRef::new(b, i as u32))
                .collect();
            let cb = refs.iter().fold(Aabb::EMPTY, |c, r| c.grow(r.centroid()));
            let binner = Binner::new(&cb, bins);
            let want = bits(&Bins::<N>::fill_scalar(&refs, &binner));
            assert_eq!(bits(&Bins::<N>::fill(&refs, &binner)), want, "set {k}");
            #[cfg(target_arch = "x86_64")]
            if avx::available() {
                // SAFETY: the CPU has AVX.
                let got = unsafe { avx::fill::<N>(&refs, &binner) };
                assert_eq!(bits(&got), want, "set {k}, {bins} bins");
            }
        }
    }

    /// The AVX bins are the baseline's bit for bit (on a CPU without AVX only the
    /// dispatch is tested: `fill` then is `fill_scalar`).
    #[test]
    fn avx_bins_equal_the_baseline_bins() {
        #[cfg(target_arch = "x86_64")]
        if !avx::available() {
            eprintln!("no AVX on this CPU: the AVX path is not tested here");
        }
        same_as_scalar::<8>(8);
        same_as_scalar::<16>(16);
        same_as_scalar::<16>(11);
        same_as_scalar::<32>(32);
        same_as_scalar::<64>(64);
    }
}
