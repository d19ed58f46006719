//! DRAM traffic per primitive of an LBVH build, by sorting strategy: \[P1\] §3 Table 1 and
//! \[P2\] §4.2 Table I.
//!
//! Any LBVH builder reads each primitive once and writes the hierarchy; in between it sorts
//! either Morton code/reference pairs or whole AABBs. Per primitive:
//! - primitive read: `prim_read_bytes`;
//! - sorting, with elements of `e` bytes:
//!   - radix-16 counting sort (a GPU parallel prefix sort): one pass per 4 key bits, eight
//!     passes for 32-bit keys, each reading the array twice and writing it once:
//!     `3 * 8 * e` (\[P2\] §4.2: `3 x 8 x 8B = 192B` for pairs);
//!   - multi-merge sort (Aggarwal and Vitter): the partial sort writes its sorted blocks
//!     once and each multi-merge pass reads them once; input AABBs stream on chip into the
//!     partial sort and the last merge streams into hierarchy emission, so one pass costs
//!     `2 * e` and each further pass another `2 * e` (\[P2\] §4.2: 16 B, "an additional 16B
//!     per pass");
//! - hierarchy output: `bvh_write_bytes` (nodes and leaf table, one primitive per leaf);
//! - when pairs are sorted, hierarchy emission must fetch each referenced primitive again
//!   to build node boxes: `refetch_bytes` more (\[P1\] counts it in the BVH column).
//!
//! The two papers differ only in record sizes:
//! - \[P1\] (Table 1, in 32-bit words): primitives of 40 B, AABB elements of 28 B, pairs of
//!   8 B (\[P1\] §3); hierarchy output 56 B per primitive. \[P1\] does not state the node
//!   size; 56 B is a node with two child boxes (2 x 24 B) and two 4-B child references, one
//!   node per primitive, the only reading that reproduces the table's BVH column (14 words).
//! - \[P2\] (Table I, in bytes): AABB input of 32 B (§5.1: 256-bit AABB records), AABB
//!   elements of 32 B, pairs of 8 B, 64-B nodes plus a 4-B leaf-table entry per primitive
//!   (§4.2: "64B per input AABB for nodes and 4B for the leaf table").

/// What is sorted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SortElement {
    /// Morton code and primitive reference pairs.
    MortonPairs,
    /// Whole AABB records.
    Aabbs,
}

/// How it is sorted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SortAlgorithm {
    /// Least-significant-digit radix sort with 4-bit digits over `key_bits`-bit keys.
    Radix16 {
        /// Key width in bits (32 in both tables).
        key_bits: u32,
    },
    /// Partial sorts of scratchpad-sized blocks, then `passes` multi-merge passes.
    MultiMerge {
        /// Multi-merge passes (see [`multimerge_passes`]).
        passes: u32,
    },
}

/// Record sizes of one paper's setup, in bytes per primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordSizes {
    /// Input primitive read once at the start.
    pub prim_read_bytes: u64,
    /// One AABB sort element.
    pub aabb_bytes: u64,
    /// One Morton code/reference pair.
    pub pair_bytes: u64,
    /// Hierarchy output (nodes and leaf table) per primitive.
    pub bvh_write_bytes: u64,
    /// Primitive data fetched again by hierarchy emission when pairs are sorted.
    pub refetch_bytes: u64,
}

/// \[P1\] §3: 40-B primitives, 28-B AABBs, 8-B pairs; 56-B hierarchy output (see module docs).
pub const P1_SIZES: RecordSizes = RecordSizes {
    prim_read_bytes: 40,
    aabb_bytes: 28,
    pair_bytes: 8,
    bvh_write_bytes: 56,
    refetch_bytes: 40,
};

/// \[P2\] §4.2, §5.1: 32-B AABB records in and sorted, 8-B pairs, 64-B nodes + 4-B leaf table.
pub const P2_SIZES: RecordSizes = RecordSizes {
    prim_read_bytes: 32,
    aabb_bytes: 32,
    pair_bytes: 8,
    bvh_write_bytes: 64 + 4,
    refetch_bytes: 32,
};

/// Traffic per primitive, split as \[P1\] Table 1 splits it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SortTraffic {
    /// Reading the input primitives.
    pub prim_read_bytes: u64,
    /// Sorting.
    pub sorting_bytes: u64,
    /// Hierarchy output, plus the primitive refetch when pairs are sorted.
    pub bvh_write_bytes: u64,
}

impl SortTraffic {
    /// All traffic per primitive.
    pub fn total_bytes(&self) -> u64 {
        self.prim_read_bytes + self.sorting_bytes + self.bvh_write_bytes
    }
}

/// Bytes per primitive that sorting elements of `element_bytes` costs with `algorithm`.
pub fn sorting_bytes(algorithm: SortAlgorithm, element_bytes: u64) -> u64 {
    match algorithm {
        // [P2] 4.2: each pass reads the array twice and writes it once.
        SortAlgorithm::Radix16 { key_bits } => 3 * key_bits.div_ceil(4) as u64 * element_bytes,
        // [P2] 4.2: blocks written once and read once per pass.
        SortAlgorithm::MultiMerge { passes } => 2 * passes as u64 * element_bytes,
    }
}

/// Traffic per primitive of an LBVH build with the given records, element and algorithm.
pub fn lbvh_traffic(
    sizes: &RecordSizes,
    element: SortElement,
    algorithm: SortAlgorithm,
) -> SortTraffic {
    let (element_bytes, refetch) = match element {
        SortElement::MortonPairs => (sizes.pair_bytes, sizes.refetch_bytes),
        SortElement::Aabbs => (sizes.aabb_bytes, 0),
    };
    SortTraffic {
        prim_read_bytes: sizes.prim_read_bytes,
        sorting_bytes: sorting_bytes(algorithm, element_bytes),
        bvh_write_bytes: sizes.bvh_write_bytes + refetch,
    }
}

/// Multi-merge passes needed to sort `n` elements with a scratchpad of `m` elements read in
/// runs of `b` elements (\[P2\] §4.2, §7).
///
/// Partial sorts leave `ceil(n / m)` sorted blocks. A pass merges up to `m / (2 b)` blocks
/// at once (each block needs a double-buffered run of `b` in the scratchpad), so one pass
/// sorts up to `m^2 / (2 b)` elements: 1M with \[P1\]'s M = 4096, B = 8 and 2M with \[P2\]'s
/// M = 8192, B = 16, as the papers state. The tables assume at least one pass, so this
/// returns at least 1.
///
/// # Panics
/// If `m < 2 b` or `b == 0` (no merge is possible).
pub fn multimerge_passes(n: u64, m: u64, b: u64) -> u32 {
    assert!(
        b > 0 && m >= 4 * b,
        "scratchpad of {m} cannot merge runs of {b}"
    );
    let fan_in = m / (2 * b);
    let mut blocks = n.div_ceil(m).max(1);
    let mut passes = 0;
    while blocks > 1 || passes == 0 {
        blocks = blocks.div_ceil(fan_in);
        passes += 1;
    }
    passes
}

#[cfg(test)]
mod tests {
    use super::*;
    use SortAlgorithm::*;
    use SortElement::*;

    const RADIX: SortAlgorithm = Radix16 { key_bits: 32 };
    const MM1: SortAlgorithm = MultiMerge { passes: 1 };
    const MM2: SortAlgorithm = MultiMerge { passes: 2 };

    #[test]
    fn p1_table_1_every_cell() {
        // [P1] Table 1, 32-bit words per primitive: prim. read, sorting, BVH write, total.
        let printed: [(SortElement, SortAlgorithm, [u64; 4]); 6] = [
            (MortonPairs, RADIX, [10, 48, 24, 82]),
            (MortonPairs, MM1, [10, 4, 24, 38]),
            (MortonPairs, MM2, [10, 8, 24, 42]),
            (Aabbs, RADIX, [10, 168, 14, 192]),
            (Aabbs, MM1, [10, 14, 14, 38]),
            (Aabbs, MM2, [10, 28, 14, 52]),
        ];
        for (element, algorithm, words) in printed {
            let t = lbvh_traffic(&P1_SIZES, element, algorithm);
            let got = [
                t.prim_read_bytes,
                t.sorting_bytes,
                t.bvh_write_bytes,
                t.total_bytes(),
            ];
            assert!(got.iter().all(|b| b % 4 == 0));
            assert_eq!(got.map(|b| b / 4), words, "{element:?} {algorithm:?}");
        }
    }

    #[test]
    fn p2_table_i_every_cell() {
        // [P2] Table I, total bytes per primitive (the text extraction kept only this
        // column), rows in the order of [P1] Table 1.
        let printed: [(SortElement, SortAlgorithm, u64); 6] = [
            (MortonPairs, RADIX, 324),
            (MortonPairs, MM1, 148),
            (MortonPairs, MM2, 164),
            (Aabbs, RADIX, 868),
            (Aabbs, MM1, 164),
            (Aabbs, MM2, 228),
        ];
        for (element, algorithm, total) in printed {
            let t = lbvh_traffic(&P2_SIZES, element, algorithm);
            assert_eq!(t.total_bytes(), total, "{element:?} {algorithm:?}");
        }
        // The figures the [P2] 4.2 text quotes: 192 B of radix sorting, 16 B for a one-pass
        // multi-merge of pairs, 48 B more for sorting AABBs instead, ~11 % more in total.
        assert_eq!(
            lbvh_traffic(&P2_SIZES, MortonPairs, RADIX).sorting_bytes,
            192
        );
        assert_eq!(lbvh_traffic(&P2_SIZES, MortonPairs, MM1).sorting_bytes, 16);
        let extra = lbvh_traffic(&P2_SIZES, Aabbs, MM1).sorting_bytes
            - lbvh_traffic(&P2_SIZES, MortonPairs, MM1).sorting_bytes;
        assert_eq!(extra, 48);
        let ratio = 164.0 / 148.0;
        assert!((ratio - 1.11_f64).abs() < 0.005);
    }

    #[test]
    fn one_pass_capacities_match_the_papers() {
        // [P1] 5: M = 4096, B = 8 "handles up to 1M triangles in one pass".
        assert_eq!(multimerge_passes(1 << 20, 4096, 8), 1);
        assert_eq!(multimerge_passes((1 << 20) + 1, 4096, 8), 2);
        // [P2] 4.2/7: M = 8192, B = 16, 2M triangles in one pass.
        assert_eq!(multimerge_passes(2 << 20, 8192, 16), 1);
        assert_eq!(multimerge_passes((2 << 20) + 1, 8192, 16), 2);
        assert_eq!(multimerge_passes(1, 8192, 16), 1);
        // Two passes reach M / 2B = 256 times further.
        assert_eq!(multimerge_passes(256 * (2 << 20), 8192, 16), 2);
        assert_eq!(multimerge_passes(256 * (2 << 20) + 1, 8192, 16), 3);
    }
}
