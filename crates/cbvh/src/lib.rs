//! Compressed (quantized) BVHs updated in a stream: \[P3\] (Viitanen et al., "Fast Hardware
//! Construction and Refitting of Quantized Bounding Volume Hierarchies", CGF 2017), the
//! thesis's second contribution.
//!
//! - [`format`]: the 16-byte node pair (six `N`-bit coordinates, a leaf bit and a 27-bit
//!   pointer per child), `N = 3..=8`.
//! - [`grid`]: zero-aligned power-of-two grids (Eq. 6), the scale of Eq. 2, the minimum
//!   scale (§4.4), exact outward rounding.
//! - [`coords`]: relative (Eq. 1, 3) and modulo (Eq. 8, 9) coordinates, Fig. 4 and Fig. 5.
//! - [`codec`]: traversal contexts and the encode/decode of a node pair.
//! - [`topdown`]: postprocessing compression of a finished [`bvh::Bvh2`] (Fig. 2a).
//! - [`bottomup`]: streaming bottom-up compression with context estimation, a context
//!   stack and backtracking (Algorithm 1), and treelet-based compression (§4.3), as a
//!   step-by-step consumer of emitted nodes that reports its DRAM accesses.
//! - [`refit`]: streaming CBVH refit (Wald et al. 2007 order) with the same machinery.
//! - [`traffic`]: the memory-traffic model of §5.2.
//! - [`tree`]: the compressed tree, its decode to a [`bvh::Bvh2`] and enclosure checks.
//! - [`wide`]: compressed 4-wide nodes (four child slots in the node's grid, 32 bytes at
//!   `N = 6`), their top-down encoder and the streaming encoder behind
//!   [`bvh::StreamCollapse`] (issue 18 part 2).

#![warn(missing_docs)]

pub mod bottomup;
pub mod codec;
pub mod coords;
mod error;
pub mod format;
pub mod grid;
pub mod refit;
pub mod study;
pub mod topdown;
pub mod traffic;
pub mod tree;
pub mod treelet;
pub mod wide;

pub use bottomup::{compress_bottomup, compress_hlbvh, MemOp, StreamConfig, StreamEncoder};
pub use codec::Ctx;
pub use error::CbvhError;
pub use format::{NodePair, Slot};
pub use grid::{Coords, Params};
pub use refit::refit_streaming;
pub use topdown::compress_topdown;
pub use tree::{enclosure_violations, interval_encloses, node_intervals_enclose, Cbvh};
pub use wide::{
    compress4_bottomup, compress4_topdown, compress_stream_collapse, Cbvh4, QuadNode,
    WideStreamEncoder,
};

use serde::Serialize;

/// What an encoder did: node-pair writes and backtracking (\[P3\] §5.2, Fig. 7).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct EncodeStats {
    /// Node pairs written by the encoder (each pair once; backtracking rewrites are counted
    /// in `backtrack_steps`).
    pub nodes_written: u64,
    /// Backtracking iterations: each decodes and re-encodes one written node pair (one
    /// 64 B DRAM read and one write, \[P3\] §5.2).
    pub backtrack_steps: u64,
    /// Backtracking iterations by recursion depth: entry `d` counts iterations `d + 1`
    /// levels below the node whose encoding invalidated them (\[P3\] Fig. 7).
    pub backtrack_depth_hist: Vec<u64>,
    /// Backtracking iterations that re-encoded a pair to the same bits (counted in
    /// `backtrack_steps`): only the contexts of its children moved. With plane sharing
    /// ([`Coords::PlaneSharing`]) a moved node box must be walked down even where the
    /// stored fields stay valid; an encoder comparing old and new bits could skip these
    /// writes (the traffic model counts a read and a write for every step).
    pub backtrack_unchanged: u64,
    /// Deepest context stack (subtrees waiting for their parent).
    pub max_stack: usize,
}

impl EncodeStats {
    /// Records one backtracking iteration at recursion depth `depth` (1 = a direct child).
    pub(crate) fn record_backtrack(&mut self, depth: usize) {
        self.backtrack_steps += 1;
        let d = depth.max(1) - 1;
        if self.backtrack_depth_hist.len() <= d {
            self.backtrack_depth_hist.resize(d + 1, 0);
        }
        self.backtrack_depth_hist[d] += 1;
    }
}
