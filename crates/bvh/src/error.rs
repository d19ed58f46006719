//! Typed errors of the builders and input helpers.

use thiserror::Error;

/// Why a tree could not be built.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum BuildError {
    /// A primitive box has a NaN or infinite coordinate.
    #[error("primitive {index} has a non-finite bounding box")]
    NonFinite {
        /// Index of the offending primitive.
        index: usize,
    },
    /// A primitive box has `min > max` on some axis (empty or inverted).
    #[error("primitive {index} has an empty or inverted bounding box (min > max)")]
    InvertedBox {
        /// Index of the offending primitive.
        index: usize,
    },
    /// More primitives than 32-bit leaf-table indices can address.
    #[error("{count} primitives exceed the 32-bit index limit of {limit}")]
    TooManyPrimitives {
        /// Number of primitives given.
        count: usize,
        /// Largest supported count.
        limit: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "triangle {triangle} refers to vertex {vertex}, but there are only {vertices} vertices"
    )]
    VertexOutOfRange {
        /// Triangle index.
        triangle: usize,
        /// The bad vertex index.
        vertex: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A builder configuration value is out of its allowed range.
    #[error("invalid builder configuration: {0}")]
    InvalidConfig(String),
    /// The local rayon thread pool could not be created.
    #[error("cannot create a thread pool: {0}")]
    ThreadPool(String),
}

/// Largest primitive count a tree can hold: leaf-table indices are `u32`, and the top bit
/// is reserved by the builders' fragment encoding, so counts stay below `2^31`.
pub const MAX_PRIMITIVES: usize = (1 << 31) - 1;

/// Rejects inputs the builders cannot handle: too many, non-finite or inverted boxes.
pub(crate) fn check_input(aabbs: &[geom::Aabb]) -> Result<(), BuildError> {
    if aabbs.len() > MAX_PRIMITIVES {
        return Err(BuildError::TooManyPrimitives {
            count: aabbs.len(),
            limit: MAX_PRIMITIVES,
        });
    }
    for (index, b) in aabbs.iter().enumerate() {
        if !b.is_finite() {
            return Err(BuildError::NonFinite { index });
        }
        if b.is_empty() {
            return Err(BuildError::InvertedBox { index });
        }
    }
    Ok(())
}

/// Runs `f` in a local pool of `threads` threads, or in the current pool when `threads == 0`.
pub(crate) fn in_pool<T: Send>(
    threads: usize,
    f: impl FnOnce() -> T + Send,
) -> Result<T, BuildError> {
    if threads == 0 {
        return Ok(f());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| BuildError::ThreadPool(e.to_string()))?;
    Ok(pool.install(f))
}
