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

/// Keys per chunk below which a pass runs on one chunk (parallel passes pay a
/// synchronisation and a cache-unfriendly split that small inputs do not repay).
const MIN_CHUNK: usize = 1 << 16;

/// An unsigned integer sort key: the code in the high half, the primitive index low.
trait Key: Copy + Send + Sync + 'static {
    /// `n` zero keys (calloc-backed for integers: no pass over the memory).
    fn zeros(n: usize) -> Vec<Self>;
    /// Bits `shift..shift + bits` of the key.
    fn digit(self, shift: u32, bits: u32) -> usize;
}

impl Key for u64 {
    fn zeros(n: usize) -> Vec<Self> {
        vec![0; n]
    }
    #[inline(always)]
    fn digit(self, shift: u32, bits: u32) -> usize {
        ((self >> shift) & ((1 << bits) - 1)) as usize
    }
}

impl Key for u128 {
    fn zeros(n: usize) -> Vec<Self> {
        vec![0; n]
    }
    #[inline(always)]
    fn digit(self, shift: u32, bits: u32) -> usize {
        ((self >> shift) & ((1 << bits) - 1)) as usize
    }
}

/// Sorts `keys` stably by their bits `lo..lo + passes * bits`, `bits` per pass.
fn radix_sort<K: Key>(keys: Vec<K>, lo: u32, bits: u32, passes: u32) -> Vec<K> {
    let n = keys.len();
    let radix = 1usize << bits;
    let chunks = (n / MIN_CHUNK).clamp(1, 4 * rayon::current_num_threads());
    let chunk_len = n.div_ceil(chunks).max(1);
    let mut src = keys;
    let mut dst = K::zeros(n);
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
        std::mem::swap(&mut src, &mut dst);
    }
    src
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
    let cbounds = (0..n)
        .into_par_iter()
        .fold(|| Aabb::EMPTY, |b, i| b.grow(point(i)))
        .reduce(|| Aabb::EMPTY, Aabb::union);
    let q = MortonQuantizer::with_grid(&cbounds, grid);
    let (codes, order) = match bits {
        MortonBits::Bits30 => {
            // Code and index packed in one u64; sorted by the 30 code bits, 10 per pass.
            let keys: Vec<u64> = (0..n)
                .into_par_iter()
                .map(|i| ((q.code30(point(i)) as u64) << 32) | i as u64)
                .collect();
            let keys = radix_sort(keys, 32, 10, 3);
            keys.par_iter().map(|k| (k >> 32, *k as u32)).unzip()
        }
        MortonBits::Bits63 => {
            // Code in the high u64 of a u128; sorted by the 63 code bits, 9 per pass.
            let keys: Vec<u128> = (0..n)
                .into_par_iter()
                .map(|i| ((q.code63(point(i)) as u128) << 64) | i as u128)
                .collect();
            let keys = radix_sort(keys, 64, 9, 7);
            keys.par_iter()
                .map(|k| ((k >> 64) as u64, *k as u32))
                .unzip()
        }
    };
    (codes, order, cbounds)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::soup;

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
                let got = pool.install(|| radix_sort(k.clone(), 32, 10, 3));
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
        assert_eq!(radix_sort(k, 64, 9, 7), want);
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
}
