//! Morton codes of primitive centroids, sorted: the first stage of LBVH and HLBVH
//! (thesis §2.1.1; \[P2\] §4.2).
//!
//! Every primitive's centroid is quantized over the centroid bounds
//! ([`geom::MortonQuantizer`], 30 or 63 bits) and the (code, primitive index) keys are
//! sorted by a least-significant-digit radix sort over the code bits only. LSD radix sort
//! is stable and the keys start in index order, so equal codes keep increasing indices: the
//! order is the total (code, index) order, the same for any thread count.
//!
//! The sort is parallel: each pass splits the keys into equal chunks, counts the digits of
//! each chunk in parallel, and scatters each chunk into its own ranges of the output
//! (the ranges follow from the counts, bucket-major then chunk by chunk), so no two threads
//! write the same place and the result is the same for any chunking. Passes whose digit is
//! the same for every key are skipped.

use crate::centroid;
use crate::lbvh::MortonBits;
use geom::{Aabb, MortonGrid, MortonQuantizer, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Keys per chunk below which a pass runs on one chunk (parallel passes pay a
/// synchronisation and a cache-unfriendly split that small inputs do not repay).
const MIN_CHUNK: usize = 1 << 16;

/// An unsigned integer sort key: the code in the high half, the primitive index low.
trait Key: Copy + Send + Sync + bytemuck::Zeroable + 'static {
    /// Bits `shift..shift + bits` of the key.
    fn digit(self, shift: u32, bits: u32) -> usize;
}

impl Key for u64 {
    #[inline(always)]
    fn digit(self, shift: u32, bits: u32) -> usize {
        ((self >> shift) & ((1 << bits) - 1)) as usize
    }
}

impl Key for u128 {
    #[inline(always)]
    fn digit(self, shift: u32, bits: u32) -> usize {
        ((self >> shift) & ((1 << bits) - 1)) as usize
    }
}

/// The key arrays of [`sorted_codes_into`] (the keys and the radix sort's second buffer,
/// for 30-bit and for 63-bit codes), kept between sorts so that a sort after the first
/// allocates nothing and touches no fresh page.
#[derive(Debug, Default)]
pub(crate) struct SortBuffers {
    narrow: [Vec<u64>; 2],
    wide: [Vec<u128>; 2],
}

impl SortBuffers {
    /// Bytes held.
    pub(crate) fn capacity_bytes(&self) -> usize {
        self.narrow.iter().map(|v| v.capacity() * 8).sum::<usize>()
            + self.wide.iter().map(|v| v.capacity() * 16).sum::<usize>()
    }
}

/// Sorts `src` stably by its keys' bits `lo..lo + passes * bits`, `bits` per pass; `dst`
/// is the second buffer of the passes (its contents are overwritten; the two may be
/// swapped, the sorted keys end in `src`).
fn radix_sort<K: Key>(src: &mut Vec<K>, dst: &mut Vec<K>, lo: u32, bits: u32, passes: u32) {
    let n = src.len();
    let radix = 1usize << bits;
    let chunks = (n / MIN_CHUNK).clamp(1, 4 * rayon::current_num_threads());
    let chunk_len = n.div_ceil(chunks).max(1);
    crate::size_for_overwrite(dst, n);
    for pass in 0..passes {
        let shift = lo + pass * bits;
        let counts: Vec<Vec<u32>> = src
            .par_chunks(chunk_len)
            .map(|c| {
                let mut h = vec![0u32; radix];
                for &k in c {
                    h[k.digit(shift, bits)] += 1;
                }
                h
            })
            .collect();
        // A digit shared by every key sorts nothing.
        if (0..radix).any(|d| counts.iter().map(|h| h[d] as usize).sum::<usize>() == n) {
            continue;
        }
        // Output ranges, bucket-major then chunk by chunk: chunk c's keys of digit d.
        let mut outs: Vec<Vec<std::slice::IterMut<'_, K>>> = (0..counts.len())
            .map(|_| Vec::with_capacity(radix))
            .collect();
        let mut rest = dst.as_mut_slice();
        for d in 0..radix {
            for (c, h) in counts.iter().enumerate() {
                let (mine, tail) = rest.split_at_mut(h[d] as usize);
                outs[c].push(mine.iter_mut());
                rest = tail;
            }
        }
        src.par_chunks(chunk_len)
            .zip(outs.into_par_iter())
            .for_each(|(c, mut out)| {
                for &k in c {
                    // The counts sized each range for exactly its keys.
                    *out[k.digit(shift, bits)].next().expect("counted") = k;
                }
            });
        std::mem::swap(src, dst);
    }
}

/// The Morton code of every centroid over the centroid bounds, sorted with the primitive
/// indices: `(codes, order)`, `codes[k]` the `k`-th smallest code and `order[k]` its
/// primitive (ties in index order).
pub(crate) fn sorted_codes(
    aabbs: &[Aabb],
    bits: MortonBits,
    grid: MortonGrid,
) -> (Vec<u64>, Vec<u32>) {
    let (codes, order, _) = sorted_codes_of(aabbs.len(), |i| centroid(&aabbs[i]), bits, grid);
    (codes, order)
}

/// [`sorted_codes`] over `n` points given by `point(i)` (primitive centroids, or the points
/// of a point cloud): `(codes, order, bounds)`, `bounds` the points' box that the codes
/// quantize.
pub(crate) fn sorted_codes_of(
    n: usize,
    point: impl Fn(usize) -> Vec3 + Sync,
    bits: MortonBits,
    grid: MortonGrid,
) -> (Vec<u64>, Vec<u32>, Aabb) {
    let (mut codes, mut order) = (Vec::new(), Vec::new());
    let mut buffers = SortBuffers::default();
    let bounds = sorted_codes_into(n, point, bits, grid, &mut buffers, &mut codes, &mut order);
    (codes, order, bounds)
}

/// [`sorted_codes_of`] into `codes` and `order` (their old contents are replaced), with
/// the key arrays of `buffers`: with buffers kept from an earlier sort of as many points
/// or more, nothing is allocated. Returns the points' box.
pub(crate) fn sorted_codes_into(
    n: usize,
    point: impl Fn(usize) -> Vec3 + Sync,
    bits: MortonBits,
    grid: MortonGrid,
    buffers: &mut SortBuffers,
    codes: &mut Vec<u64>,
    order: &mut Vec<u32>,
) -> Aabb {
    sorted_tagged_codes_into(n, point, |_| |_| false, bits, grid, buffers, codes, order)
}

/// [`sorted_codes_into`] with a tag bit above the code: `tag(&bounds)` (`bounds` the
/// points' box) gives the test `t`, point `i` is tagged when `t(i)`, and a tagged point's
/// code has bit `bits.total_bits()` set, so the order is the total (tag, code, index)
/// order. The tags cost a test in the coding pass; when any point is tagged, one more
/// pass over the sorted keys moves the tagged ones, in their order, after the others.
#[allow(clippy::too_many_arguments)]
pub(crate) fn sorted_tagged_codes_into<T: Fn(usize) -> bool + Sync>(
    n: usize,
    point: impl Fn(usize) -> Vec3 + Sync,
    tag: impl FnOnce(&Aabb) -> T,
    bits: MortonBits,
    grid: MortonGrid,
    buffers: &mut SortBuffers,
    codes: &mut Vec<u64>,
    order: &mut Vec<u32>,
) -> Aabb {
    let cbounds = (0..n)
        .into_par_iter()
        .fold(|| Aabb::EMPTY, |b, i| b.grow(point(i)))
        .reduce(|| Aabb::EMPTY, Aabb::union);
    let q = MortonQuantizer::with_grid(&cbounds, grid);
    let tagged = AtomicUsize::new(0);
    let test = tag(&cbounds);
    let tag = |i: usize| {
        let t = test(i);
        if t {
            tagged.fetch_add(1, Ordering::Relaxed);
        }
        t
    };
    match bits {
        MortonBits::Bits30 => {
            // Code and index packed in one u64; sorted by the 30 code bits, 10 per pass.
            let [keys, tmp] = &mut buffers.narrow;
            (0..n)
                .into_par_iter()
                .map(|i| {
                    let code = q.code30(point(i)) as u64 | (tag(i) as u64) << 30;
                    (code << 32) | i as u64
                })
                .collect_into_vec(keys);
            radix_sort(keys, tmp, 32, 10, 3);
            tagged_last(keys, tmp, tagged.into_inner(), |k| k >> 62 != 0);
            keys.par_iter()
                .map(|k| (k >> 32, *k as u32))
                .unzip_into_vecs(codes, order);
        }
        MortonBits::Bits63 => {
            // Code in the high u64 of a u128; sorted by the 63 code bits, 9 per pass.
            let [keys, tmp] = &mut buffers.wide;
            (0..n)
                .into_par_iter()
                .map(|i| {
                    let code = q.code63(point(i)) as u128 | (tag(i) as u128) << 63;
                    (code << 64) | i as u128
                })
                .collect_into_vec(keys);
            radix_sort(keys, tmp, 64, 9, 7);
            tagged_last(keys, tmp, tagged.into_inner(), |k| k >> 127 != 0);
            keys.par_iter()
                .map(|k| ((k >> 64) as u64, *k as u32))
                .unzip_into_vecs(codes, order);
        }
    }
    cbounds
}

/// Moves the `count` keys of `keys` for which `is_tagged` holds after all others, both in
/// their order (a stable partition through `tmp`, the radix sort's second buffer); nothing
/// when `count` is 0.
fn tagged_last<K: Key>(
    keys: &mut Vec<K>,
    tmp: &mut Vec<K>,
    count: usize,
    is_tagged: impl Fn(K) -> bool,
) {
    if count == 0 {
        return;
    }
    let n = keys.len();
    crate::size_for_overwrite(tmp, n);
    let (mut small, mut large) = (0, n - count);
    for &k in keys.iter() {
        if is_tagged(k) {
            tmp[large] = k;
            large += 1;
        } else {
            tmp[small] = k;
            small += 1;
        }
    }
    debug_assert_eq!((small, large), (n - count, n));
    std::mem::swap(keys, tmp);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::soup;

    /// `radix_sort` of `keys` with a fresh second buffer.
    fn sort<K: Key>(mut keys: Vec<K>, lo: u32, bits: u32, passes: u32) -> Vec<K> {
        radix_sort(&mut keys, &mut Vec::new(), lo, bits, passes);
        keys
    }

    /// Deterministic pseudo-random keys with many repeated digits.
    fn keys(n: usize, seed: u64, bits: u32) -> Vec<u64> {
        let mut s = seed | 1;
        (0..n as u64)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s % (1u64 << bits)) << 32) | i
            })
            .collect()
    }

    #[test]
    fn sorts_like_a_comparison_sort_for_any_chunking() {
        for (n, bits) in [
            (0, 30),
            (1, 30),
            (7, 3),
            (1000, 30),
            (200_000, 30),
            (300_000, 2),
        ] {
            let k = keys(n, n as u64 + 3, bits);
            let mut want = k.clone();
            want.sort_unstable();
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| sort(k.clone(), 32, 10, 3));
                assert_eq!(got, want, "n {n} bits {bits} threads {threads}");
            }
        }
        // u128 keys, 63-bit codes.
        let k: Vec<u128> = keys(150_000, 9, 30)
            .into_iter()
            .map(|v| {
                let code = (v >> 32).wrapping_mul(0x9e37_79b9_7f4a) & ((1 << 63) - 1);
                ((code as u128) << 64) | (v as u32) as u128
            })
            .collect();
        let mut want = k.clone();
        want.sort_unstable();
        assert_eq!(sort(k, 64, 9, 7), want);
    }

    #[test]
    fn sorted_codes_are_the_total_code_index_order() {
        let prims = soup(100_000, 1.0, 4);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let (codes, order) = sorted_codes(&prims, bits, MortonGrid::Box);
            assert_eq!(codes.len(), prims.len());
            let mut seen = vec![false; prims.len()];
            for (c, o) in codes.windows(2).zip(order.windows(2)) {
                assert!((c[0], o[0]) < (c[1], o[1]));
            }
            for &i in &order {
                assert!(!std::mem::replace(&mut seen[i as usize], true));
            }
        }
        // All codes equal: the identity order.
        let same = vec![prims[0]; 70_000];
        let (codes, order) = sorted_codes(&same, MortonBits::Bits30, MortonGrid::Box);
        assert!(codes.iter().all(|&c| c == codes[0]));
        assert!(order.iter().enumerate().all(|(k, &i)| k as u32 == i));
    }

    #[test]
    fn tagged_codes_are_the_total_tag_code_index_order() {
        let prims = soup(100_000, 1.0, 6);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let (codes, order, _) =
                sorted_codes_of(prims.len(), |i| centroid(&prims[i]), bits, MortonGrid::Box);
            let tag_bit = 1u64 << bits.total_bits();
            // None, a few and all points tagged; the tags' bit over the untagged codes.
            for every in [0usize, 997, 1] {
                let tag = |i: usize| every != 0 && i.is_multiple_of(every);
                let (mut tcodes, mut torder) = (Vec::new(), Vec::new());
                let mut buffers = SortBuffers::default();
                let b = sorted_tagged_codes_into(
                    prims.len(),
                    |i| centroid(&prims[i]),
                    |_| tag,
                    bits,
                    MortonGrid::Box,
                    &mut buffers,
                    &mut tcodes,
                    &mut torder,
                );
                assert_eq!(
                    b,
                    prims.iter().fold(Aabb::EMPTY, |b, p| b.grow(centroid(p)))
                );
                let mut want: Vec<(u64, u32)> = codes
                    .iter()
                    .zip(&order)
                    .map(|(&c, &i)| (c | if tag(i as usize) { tag_bit } else { 0 }, i))
                    .collect();
                want.sort_unstable();
                let got: Vec<(u64, u32)> = tcodes.into_iter().zip(torder).collect();
                assert_eq!(got, want, "{bits:?} every {every}");
            }
        }
    }
}
