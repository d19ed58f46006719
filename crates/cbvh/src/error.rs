//! Typed errors of the CBVH encoders and decoders.

use thiserror::Error;

/// What can go wrong when compressing, refitting or decoding a CBVH.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
pub enum CbvhError {
    /// A parameter is out of its range.
    #[error("invalid CBVH parameters: {0}")]
    InvalidParams(String),
    /// An input box has a NaN or a coordinate beyond the supported magnitude.
    #[error(
        "box {index} has a NaN or a coordinate beyond +-2^120, which the CBVH grids do not support"
    )]
    BadBox {
        /// Index of the box (primitive or node child).
        index: usize,
    },
    /// More node pairs or primitive references than the 27-bit pointers address.
    #[error("{what} count {count} exceeds the 27-bit child pointer range of the CBVH format")]
    TooLarge {
        /// What overflowed.
        what: &'static str,
        /// The count.
        count: usize,
    },
    /// The input stream is not a depth-first bottom-up node order (a child was missing
    /// from the context stack, or subtrees were left over at the end).
    #[error("input is not in bottom-up depth-first order: {0}")]
    BadOrder(String),
    /// The tree or the primitive set does not match (refit with other primitives, corrupt
    /// pointers).
    #[error("corrupt or mismatched tree: {0}")]
    Corrupt(String),
}
