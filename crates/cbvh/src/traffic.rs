//! The memory-traffic model of \[P3\] §5.2, from counts of primitives, node pairs and
//! backtracking steps.
//!
//! LBVH (the builder of \[VKJ*15\], emitting large leaves for equal Morton codes): read the
//! input primitives (40 B each: three vertices and an id), sort their boxes (2 x 32 B per
//! primitive), write the tree (16 B per CBVH node pair) and the primitive-id array (4 B per
//! primitive). Refit (Wald et al.): read the tree (16 B per node pair), the id array and the
//! primitives, write the tree. Streaming bottom-up compression adds one 64 B read and one
//! 64 B write per backtracking step.
//!
//! The top-down baseline (\[P3\] Fig. 2a) first writes a full-precision tree, 64 B per node
//! (\[P2\] §4.1 node), which the compressor reads back (64 B) before writing the CBVH (16 B).
//! Its refitter reads only the 16 B of child references of each full-precision node (boxes
//! are recomputed, not read) and writes the whole 64 B node. The paper does not spell these
//! two baseline sizes out; they are the ones that give its Fig. 1 ratios at one primitive
//! per leaf: 252 B vs 124 B per primitive for LBVH ("up to ca. 2x") and 204 B vs 76 B for
//! refit ("2.6x").

use serde::Serialize;

/// \[P3\] §5.2: "Input primitive data ... three vertices (á 36B) and a primitive ID (4B)".
pub const PRIM_BYTES: u64 = 40;
/// \[P3\] §5.2: "sorts their AABBs (2x32B per primitive)".
pub const SORT_BYTES_PER_PRIM: u64 = 2 * 32;
/// \[P3\] §5: "a memory footprint of 16B per node pair".
pub const CBVH_PAIR_BYTES: u64 = 16;
/// \[P3\] §5.2: "primitive ID array (4B per primitive)".
pub const PRIM_ID_BYTES: u64 = 4;
/// \[P2\] §4.1: the full-precision 64-byte node (a pair of child boxes).
pub const BVH_NODE_BYTES: u64 = 64;
/// Child-reference part of a \[P2\] node that a full-precision refit reads.
pub const BVH_NODE_REFS_BYTES: u64 = 16;
/// \[P3\] §5.2: "one minimum-size DRAM read and write" per backtracking step, 64 B each.
pub const BACKTRACK_BYTES: u64 = 2 * 64;

/// Inputs of the traffic model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    /// Primitives (triangles).
    pub prims: u64,
    /// Node pairs of the tree.
    pub node_pairs: u64,
    /// Backtracking steps (0 for top-down).
    pub backtrack_steps: u64,
}

/// Traffic split by source, in bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Traffic {
    /// Builder or refitter traffic (inputs, sort, tree and id array).
    pub update_bytes: u64,
    /// Separate top-down compression pass (read the full-precision tree, write the CBVH).
    pub compression_bytes: u64,
    /// Backtracking reads and writes.
    pub backtrack_bytes: u64,
}

impl Traffic {
    /// Total bytes.
    pub fn total_bytes(&self) -> u64 {
        self.update_bytes + self.compression_bytes + self.backtrack_bytes
    }
}

/// LBVH construction with a separate top-down compression pass.
pub fn lbvh_topdown(c: &Counts) -> Traffic {
    Traffic {
        update_bytes: c.prims * (PRIM_BYTES + SORT_BYTES_PER_PRIM + PRIM_ID_BYTES)
            + c.node_pairs * BVH_NODE_BYTES,
        compression_bytes: c.node_pairs * (BVH_NODE_BYTES + CBVH_PAIR_BYTES),
        backtrack_bytes: 0,
    }
}

/// LBVH construction with streaming bottom-up compression.
pub fn lbvh_bottomup(c: &Counts) -> Traffic {
    Traffic {
        update_bytes: c.prims * (PRIM_BYTES + SORT_BYTES_PER_PRIM + PRIM_ID_BYTES)
            + c.node_pairs * CBVH_PAIR_BYTES,
        compression_bytes: 0,
        backtrack_bytes: c.backtrack_steps * BACKTRACK_BYTES,
    }
}

/// Full-precision LBVH construction without compression (for reference).
pub fn lbvh_uncompressed(c: &Counts) -> Traffic {
    Traffic {
        update_bytes: c.prims * (PRIM_BYTES + SORT_BYTES_PER_PRIM + PRIM_ID_BYTES)
            + c.node_pairs * BVH_NODE_BYTES,
        ..Traffic::default()
    }
}

/// Full-precision refit followed by top-down compression.
pub fn refit_topdown(c: &Counts) -> Traffic {
    Traffic {
        update_bytes: c.prims * (PRIM_ID_BYTES + PRIM_BYTES)
            + c.node_pairs * (BVH_NODE_REFS_BYTES + BVH_NODE_BYTES),
        compression_bytes: c.node_pairs * (BVH_NODE_BYTES + CBVH_PAIR_BYTES),
        backtrack_bytes: 0,
    }
}

/// Streaming CBVH refit.
pub fn refit_bottomup(c: &Counts) -> Traffic {
    Traffic {
        update_bytes: c.prims * (PRIM_ID_BYTES + PRIM_BYTES) + c.node_pairs * 2 * CBVH_PAIR_BYTES,
        compression_bytes: 0,
        backtrack_bytes: c.backtrack_steps * BACKTRACK_BYTES,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One primitive per leaf (`n - 1` node pairs ~ `n`): the ratios of \[P3\] Fig. 1.
    #[test]
    fn fig1_ratios_at_one_primitive_per_leaf() {
        let c = Counts {
            prims: 1_000_000,
            node_pairs: 1_000_000,
            backtrack_steps: 0,
        };
        let td = lbvh_topdown(&c).total_bytes() as f64;
        let bu = lbvh_bottomup(&c).total_bytes() as f64;
        assert_eq!(td / 1e6, 252.0);
        assert_eq!(bu / 1e6, 124.0);
        let r = refit_topdown(&c).total_bytes() as f64 / refit_bottomup(&c).total_bytes() as f64;
        assert!((r - 2.68).abs() < 0.01, "{r}"); // "2.6x"
        let steps = Counts {
            backtrack_steps: 10,
            ..c
        };
        assert_eq!(lbvh_bottomup(&steps).backtrack_bytes, 1280);
    }
}
