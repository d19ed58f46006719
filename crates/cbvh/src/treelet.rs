//! Treelet-based compression (\[P3\] §4.3). The treelet collection lives in the streaming
//! encoder ([`crate::bottomup`], `StreamConfig::treelet_depth`): each subtree on the context
//! stack keeps its top `M - 1` levels unwritten, every new node re-encodes that treelet
//! top-down from its own estimated context and writes the nodes `M` levels below it.
//! Depth 1 is plain Algorithm 1. This module names the depths the paper evaluates.

use crate::bottomup::StreamConfig;
use crate::grid::{Coords, Params};

/// \[P3\] Table 1: treelet depths evaluated ("-" = 1, then 2, 3, 4).
pub const PAPER_TREELET_DEPTHS: [u32; 4] = [1, 2, 3, 4];

/// On-chip nodes a treelet of depth `m` holds at most: `2^m - 1` (\[P3\] §4.3 prints
/// "M^2 - 1", which agrees for M = 2 and 3 only; a binary treelet of depth M has
/// 2^M - 1 nodes).
pub const fn treelet_nodes(m: u32) -> u32 {
    (1 << m) - 1
}

/// The nine encoder variants of \[P3\] Table 1 after top-down: relative and modulo
/// coordinates, each without treelets and with depths 2, 3, 4.
pub fn paper_variants(params: &Params) -> Vec<StreamConfig> {
    let mut v = Vec::new();
    for coords in [Coords::Relative, Coords::Modulo] {
        for m in PAPER_TREELET_DEPTHS {
            v.push(StreamConfig {
                params: Params { coords, ..*params },
                treelet_depth: m,
                ..StreamConfig::default()
            });
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bottomup::{compress_bottomup, tests::soup};
    use crate::topdown::compress_topdown;

    #[test]
    fn treelet_sizes() {
        assert_eq!([1, 2, 3, 4].map(treelet_nodes), [1, 3, 7, 15]);
        assert_eq!(paper_variants(&Params::default()).len(), 8);
    }

    /// With treelets deeper than the tree, nothing is written before the end of the
    /// stream, so the result is exactly the top-down compression (no backtracking).
    #[test]
    fn a_treelet_holding_the_whole_tree_is_top_down() {
        let prims = soup(20, 4, false);
        let bvh = bvh::LbvhBuilder::default().build(&prims).unwrap();
        let depth = bvh.stats().max_depth as u32;
        assert!(depth < crate::bottomup::MAX_TREELET_DEPTH);
        for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
            let p = Params {
                coords,
                ..Params::default()
            };
            let (td, _) = compress_topdown(&bvh, &p).unwrap();
            let cfg = StreamConfig {
                params: p,
                treelet_depth: depth + 1,
                ..StreamConfig::default()
            };
            let (bu, st) = compress_bottomup(&bvh, &cfg).unwrap();
            assert_eq!(st.backtrack_steps, 0);
            assert_eq!(bu.decode_to_bvh2().unwrap(), td.decode_to_bvh2().unwrap());
        }
    }
}
