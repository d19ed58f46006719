//! Typed errors of the builders and input helpers.

use rayon::prelude::*;
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
    let bad = |b: &geom::Aabb| !b.is_finite() || b.is_empty();
    // The first bad box: chunks are checked in parallel (a serial pass over a large input
    // was a few percent of a 2-thread HLBVH build, with the second thread idle), then the
    // first bad chunk is searched in order, so the error names the same box either way.
    let chunk = crate::PARALLEL_MIN_PRIMS;
    let Some(c) = aabbs
        .par_chunks(chunk)
        .position_first(|c| c.iter().any(bad))
    else {
        return Ok(());
    };
    let index = c * chunk + aabbs[c * chunk..].iter().position(bad).expect("a bad box");
    Err(if aabbs[index].is_finite() {
        BuildError::InvertedBox { index }
    } else {
        BuildError::NonFinite { index }
    })
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

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Aabb, Vec3};

    /// The parallel check names the first bad box, as a serial pass does, wherever the bad
    /// boxes lie against the chunks.
    #[test]
    fn check_input_names_the_first_bad_box() {
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let inverted = Aabb::new(Vec3::ONE, Vec3::ZERO);
        let nan = Aabb::new(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 1.0));
        let chunk = crate::PARALLEL_MIN_PRIMS;
        for (bad, want) in [
            (vec![], Ok(())),
            (vec![(0, nan)], Err(BuildError::NonFinite { index: 0 })),
            (
                vec![(chunk + 1, inverted), (3 * chunk, nan)],
                Err(BuildError::InvertedBox { index: chunk + 1 }),
            ),
            (
                vec![(2 * chunk - 1, nan), (2 * chunk, inverted), (5, unit)],
                Err(BuildError::NonFinite {
                    index: 2 * chunk - 1,
                }),
            ),
            (
                vec![(5 * chunk - 1, inverted), (4 * chunk + 3, nan)],
                Err(BuildError::NonFinite {
                    index: 4 * chunk + 3,
                }),
            ),
        ] {
            let mut boxes = vec![unit; 5 * chunk];
            for &(i, b) in &bad {
                boxes[i] = b;
            }
            assert_eq!(check_input(&boxes), want, "{bad:?}");
            let serial = boxes.iter().position(|b| !b.is_finite() || b.is_empty());
            assert_eq!(serial.is_some(), want.is_err());
        }
    }
}
