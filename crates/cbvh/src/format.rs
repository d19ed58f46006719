//! The CBVH node pair of \[P3\] §5: per child six `N`-bit coordinates, a leaf bit and a
//! 27-bit pointer; 16 bytes per pair at `N = 6`. The bit layout is tabulated in
//! `docs/cbvh-format.md`.
//!
//! Per child slot `c` (0 or 1), `W = 6N + 28` bits starting at bit `c * W` of the pair
//! (little-endian bit order: bit `i` is bit `i % 8` of byte `i / 8`):
//!
//! | bits (from slot start) | field |
//! |---|---|
//! | `0 .. N`        | lower x |
//! | `N .. 2N`       | lower y |
//! | `2N .. 3N`      | lower z |
//! | `3N .. 4N`      | upper x |
//! | `4N .. 5N`      | upper y |
//! | `5N .. 6N`      | upper z |
//! | `6N`            | leaf bit |
//! | `6N+1 .. 6N+28` | pointer (27 bits) |
//!
//! A pair takes `ceil(2W / 8)` bytes: 16 at `N = 6` (\[P3\] §5: "16B per node pair"), 12 at
//! 3, 13 at 4, 15 at 5, 18 at 7 and 19 at 8.
//!
//! Pointers: an inner child points to a node pair (its index); a leaf points to the first
//! entry of the primitive-id array (\[P3\] §5, "Leaf pointers in the CBVH index a primitive
//! ID array"). A leaf ends at the first id with [`LEAF_END`] set, so no count field is
//! needed. The absent child (only at the root of a tree of zero or one leaf) is a leaf
//! with pointer [`EMPTY_PTR`]; it decodes to the empty box.

use crate::error::CbvhError;

/// \[P3\] §5: "a 27-bit child pointer".
pub const PTR_BITS: u32 = 27;
/// Pointer value of the absent child (with the leaf bit set).
pub const EMPTY_PTR: u32 = (1 << PTR_BITS) - 1;
/// Largest usable pointer (node pair index or primitive-id index).
pub const MAX_PTR: u32 = EMPTY_PTR - 1;
/// Flag in a primitive-id array entry: the last id of its leaf.
pub const LEAF_END: u32 = 1 << 31;
/// Bytes of a primitive-id array entry (\[P3\] §5.2: 4 B per primitive).
pub const PRIM_ID_BYTES: u64 = 4;

/// One child of a node pair, unpacked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Slot {
    /// Stored lower-bound coordinates x, y, z (`N` bits each).
    pub lo: [u8; 3],
    /// Stored upper-bound coordinates x, y, z (`N` bits each).
    pub hi: [u8; 3],
    /// Leaf bit.
    pub leaf: bool,
    /// Node pair index (inner) or primitive-id index (leaf), 27 bits.
    pub ptr: u32,
}

impl Slot {
    /// The absent child.
    pub const EMPTY: Slot = Slot {
        lo: [0; 3],
        hi: [0; 3],
        leaf: true,
        ptr: EMPTY_PTR,
    };

    /// True for the absent child.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.leaf && self.ptr == EMPTY_PTR
    }

    /// True for an inner child.
    #[inline]
    pub fn is_inner(&self) -> bool {
        !self.leaf
    }
}

/// A node pair: the two children of one BVH node, unpacked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct NodePair {
    /// Child 0 and child 1.
    pub slots: [Slot; 2],
}

/// Bits of one child slot at `bits` per coordinate.
#[inline]
pub const fn slot_bits(bits: u32) -> u32 {
    6 * bits + 1 + PTR_BITS
}

/// Bytes of a packed node pair at `bits` per coordinate (16 at 6 bits).
#[inline]
pub const fn pair_bytes(bits: u32) -> usize {
    (2 * slot_bits(bits)).div_ceil(8) as usize
}

/// The bits of `src` from bit `at` on, as a little-endian `u128` (bits past the end of
/// `src` read as zero). One slot (`6N + 28 <= 76` bits) starts at most 7 bits into its
/// first byte, so it always fits the window.
#[inline(always)]
fn window(src: &[u8], at: u32) -> u128 {
    let byte = (at / 8) as usize;
    let rest = src.get(byte..).unwrap_or(&[]);
    let v = match rest.first_chunk::<16>() {
        // One 16-byte load (a kernel pads its pair array so that this is the usual case).
        Some(b) => u128::from_le_bytes(*b),
        None => {
            let mut buf = [0u8; 16];
            buf[..rest.len()].copy_from_slice(rest);
            u128::from_le_bytes(buf)
        }
    };
    v >> (at % 8)
}

/// Bytes of a packed node of `k` child slots at `bits` per coordinate: a node pair
/// (`k = 2`, [`pair_bytes`]) or a compressed 4-wide node (`k = 4`, [`crate::wide`]: 32 bytes
/// at 6 bits).
#[inline]
pub const fn node_bytes(k: u32, bits: u32) -> usize {
    (k * slot_bits(bits)).div_ceil(8) as usize
}

/// Packs child slots one after another (slot `c` from bit `c * W`, `W` = [`slot_bits`])
/// into `node_bytes(slots.len(), bits)` bytes appended to `out`: the layout of a node pair
/// and of a compressed 4-wide node.
pub fn pack_slots(slots: &[Slot], bits: u32, out: &mut Vec<u8>) -> Result<(), CbvhError> {
    let base = out.len();
    out.resize(base + node_bytes(slots.len() as u32, bits), 0);
    let dst = &mut out[base..];
    let w = slot_bits(bits);
    let limit = 1u32 << bits;
    for (c, s) in slots.iter().enumerate() {
        let mut v = 0u128;
        for (i, &f) in s.lo.iter().chain(s.hi.iter()).enumerate() {
            if u32::from(f) >= limit {
                return Err(CbvhError::Corrupt(format!(
                    "coordinate {f} does not fit {bits} bits"
                )));
            }
            v |= u128::from(f) << (i as u32 * bits);
        }
        if s.ptr > EMPTY_PTR {
            return Err(CbvhError::TooLarge {
                what: "pointer",
                count: s.ptr as usize,
            });
        }
        v |= u128::from(s.leaf) << (6 * bits);
        v |= u128::from(s.ptr) << (6 * bits + 1);
        // The slot's bits from its first byte on (it starts at most 7 bits in).
        let at = c as u32 * w;
        let v = v << (at % 8);
        for (k, byte) in dst[(at / 8) as usize..].iter_mut().take(16).enumerate() {
            *byte |= (v >> (8 * k)) as u8;
        }
    }
    Ok(())
}

/// Unpacks `K` child slots from the first `node_bytes(K, bits)` bytes of `src` (two
/// 128-bit windows and shifts per pair, no per-bit loop).
#[inline(always)]
pub fn unpack_slots<const K: usize>(bits: u32, src: &[u8]) -> Result<[Slot; K], CbvhError> {
    if src.len() < node_bytes(K as u32, bits) {
        return Err(CbvhError::Corrupt("truncated node".into()));
    }
    let w = slot_bits(bits);
    let field = (1u128 << bits) - 1;
    let mut slots = [Slot::default(); K];
    for (c, s) in slots.iter_mut().enumerate() {
        let v = window(src, c as u32 * w);
        for i in 0..3 {
            s.lo[i] = ((v >> (i as u32 * bits)) & field) as u8;
            s.hi[i] = ((v >> ((3 + i as u32) * bits)) & field) as u8;
        }
        s.leaf = (v >> (6 * bits)) & 1 == 1;
        s.ptr = ((v >> (6 * bits + 1)) & ((1u128 << PTR_BITS) - 1)) as u32;
    }
    Ok(slots)
}

impl NodePair {
    /// Packs the pair into `pair_bytes(bits)` bytes appended to `out`.
    pub fn pack_into(&self, bits: u32, out: &mut Vec<u8>) -> Result<(), CbvhError> {
        pack_slots(&self.slots, bits, out)
    }

    /// Unpacks a pair from the first `pair_bytes(bits)` bytes of `src` (a traversal kernel
    /// calls this once per node visit: two 128-bit windows and shifts, no per-bit loop).
    #[inline(always)]
    pub fn unpack(bits: u32, src: &[u8]) -> Result<Self, CbvhError> {
        if src.len() < pair_bytes(bits) {
            return Err(CbvhError::Corrupt("truncated node pair".into()));
        }
        Ok(NodePair {
            slots: unpack_slots::<2>(bits, src)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn sizes_match_the_paper() {
        assert_eq!(pair_bytes(6), 16);
        assert_eq!(slot_bits(6), 64);
        assert_eq!(
            (3..=8).map(pair_bytes).collect::<Vec<_>>(),
            vec![12, 13, 15, 16, 18, 19]
        );
    }

    #[test]
    fn layout_matches_the_doc_table_at_six_bits() {
        let mut p = NodePair::default();
        p.slots[0].lo = [1, 0, 0];
        p.slots[0].hi = [0, 0, 63];
        p.slots[0].leaf = true;
        p.slots[1].ptr = EMPTY_PTR;
        let mut b = Vec::new();
        p.pack_into(6, &mut b).unwrap();
        let w0 = u64::from_le_bytes(b[0..8].try_into().unwrap());
        let w1 = u64::from_le_bytes(b[8..16].try_into().unwrap());
        assert_eq!(w0 & 0x3f, 1); // lower x in bits 0..6
        assert_eq!((w0 >> 30) & 0x3f, 63); // upper z in bits 30..36
        assert_eq!((w0 >> 36) & 1, 1); // leaf bit 36
        assert_eq!(w1 >> 37, u64::from(EMPTY_PTR)); // pointer in bits 37..64
    }

    fn any_pair(bits: u32) -> impl Strategy<Value = NodePair> {
        let m = (1u32 << bits) - 1;
        let slot = (
            proptest::array::uniform3(0..=m),
            proptest::array::uniform3(0..=m),
            any::<bool>(),
            0..=EMPTY_PTR,
        )
            .prop_map(|(lo, hi, leaf, ptr)| Slot {
                lo: lo.map(|v| v as u8),
                hi: hi.map(|v| v as u8),
                leaf,
                ptr,
            });
        proptest::array::uniform2(slot).prop_map(|slots| NodePair { slots })
    }

    proptest! {
        #[test]
        fn pack_round_trips(bits in 3u32..=8, seed in any::<u64>()) {
            use proptest::strategy::ValueTree;
            use proptest::test_runner::{Config, TestRunner, RngAlgorithm, TestRng};
            let mut runner = TestRunner::new_with_rng(Config::default(), TestRng::from_seed(RngAlgorithm::ChaCha, &{
                let mut s = [0u8; 32]; s[..8].copy_from_slice(&seed.to_le_bytes()); s }));
            let p = any_pair(bits).new_tree(&mut runner).unwrap().current();
            let mut b = Vec::new();
            p.pack_into(bits, &mut b).unwrap();
            prop_assert_eq!(b.len(), pair_bytes(bits));
            prop_assert_eq!(NodePair::unpack(bits, &b).unwrap(), p);
        }
    }

    /// The windowed reader reads what a plain bit-by-bit reader reads, at every offset.
    #[test]
    fn window_reads_every_bit_position() {
        let src: Vec<u8> = (0..19u32).map(|i| (i * 37 + 11) as u8).collect();
        let bit =
            |b: u32| u128::from((src.get((b / 8) as usize).copied().unwrap_or(0) >> (b % 8)) & 1);
        for at in 0..152 {
            let v = window(&src, at);
            for k in 0..(128 - 7) {
                assert_eq!((v >> k) & 1, bit(at + k), "at {at} bit {k}");
            }
        }
    }

    #[test]
    fn out_of_range_fields_are_errors() {
        let mut p = NodePair::default();
        p.slots[0].lo[0] = 8;
        assert!(p.pack_into(3, &mut Vec::new()).is_err());
        let mut p = NodePair::default();
        p.slots[1].ptr = EMPTY_PTR + 1;
        assert!(p.pack_into(6, &mut Vec::new()).is_err());
        assert!(NodePair::unpack(6, &[0; 15]).is_err());
    }
}
