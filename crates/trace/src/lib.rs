//! Arbor's ray tracer: traversal kernels for the binary `Bvh2` ([P2] §4.1), the 4-wide
//! `Mbvh4` ([P4] §3.1) and the compressed `Cbvh` ([P3], boxes decoded on the fly, with the
//! watertightness check of [P3] §5.5), closest-hit and any-hit queries with per-ray
//! counters, one ray at a time or in batches ([`Traverse::trace_batch`], which the 8-wide
//! kernel interleaves over trees larger than the cache), custom primitives tested by a callback ([`custom`]), two-level instancing
//! with animated transforms ([`instance`]), a pinhole camera, primary-ray and diffuse
//! path-traced rendering, images (shaded PNG, depth PFM or NPY, a heatmap of traversal
//! cost in the style of the thesis's Fig. 2.2) and traversal logs, the input of the
//! traversal hardware model ([P4] §3.2).
//!
//! # Example
//!
//! ```
//! use trace::{Bvh2Accel, KernelOptions, RayStats, Traverse, TraversalStack};
//! use geom::{Ray, Triangle, Vec3};
//!
//! let tris = vec![
//!     Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y),
//!     Triangle::new(Vec3::new(0.0, 0.0, -1.0), Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 1.0, -1.0)),
//! ];
//! let tree = bvh::SweepSahBuilder::default().build(&bvh::triangle_aabbs(&tris))?;
//! let accel = Bvh2Accel::new(tree, &tris, KernelOptions::default())?;
//! let (mut stack, mut stats) = (TraversalStack::new(), RayStats::default());
//! let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
//! let hit = accel.closest_hit(&ray, &mut stack, &mut stats).unwrap();
//! assert_eq!((hit.prim, hit.t), (0, 1.0));
//! assert_eq!(stats.rays, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

//! # Trees from anywhere
//!
//! A kernel can be prepared over a tree built in memory by any code, not only by the
//! `bvh` builders or the validating file reader. Preparation checks, once and in time
//! linear in the tree, what traversal relies on, and returns a [`TraceError`] otherwise:
//! every inner link names an existing node after its parent (no cycles), no node is linked
//! twice (a shared subtree is walked once per path to it: a chain of 64 shared nodes is
//! 2^64 visits), leaves lie inside the leaf table and together cover at most its length,
//! and every leaf-table entry names an existing triangle. Boxes are not checked (that is
//! `bvh::validate`'s job, and costs a pass over the primitives): NaN, inverted or too
//! small boxes only lose hits. So a prepared kernel traces every ray without a panic or an
//! out-of-bounds read, visits each node at most once per ray, and reports only real hits
//! of existing triangles; over a tree that passes `bvh::validate` (for the wide trees
//! `bvh::validate_mbvh4` and `bvh::validate_wide`) it gives the brute-force hits. Property
//! tests (`tests_hostile.rs`) feed every kernel random mutations of valid trees and
//! hand-made worst cases, and check the brute-force hits for those that still validate.

#![warn(missing_docs)]

mod accel;
mod any;
mod brute;
mod bvh2_kernel;
pub mod camera;
mod cbvh_kernel;
mod cbvh_watertight;
pub mod custom;
pub mod image;
pub mod instance;
pub mod log;
mod mbvh4_kernel;
mod mbvh8_kernel;
mod observer;
pub mod render;
pub mod sampling;
mod stats;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_cbvh;
#[cfg(test)]
mod tests_custom;
#[cfg(test)]
mod tests_hostile;
#[cfg(test)]
mod tests_instance;
#[cfg(test)]
mod tests_log;
#[cfg(test)]
mod tests_refit;
#[cfg(test)]
mod tests_render;
#[cfg(test)]
mod testutil;

pub use accel::{
    cull_distance, enters_own_box, Hit, RaySource, TraversalStack, Traverse, CULL_SLACK,
};
pub use any::Accel;
pub use brute::brute_force;
pub use bvh2_kernel::Bvh2Accel;
pub use camera::PinholeCamera;
pub use cbvh_kernel::{BoxObserver, CbvhAccel};
pub use cbvh_watertight::{WatertightCheck, WatertightStats};
pub use mbvh4_kernel::{sort4, Mbvh4Accel};
pub use mbvh8_kernel::{last_level_cache_bytes, Interleave, Mbvh8Accel, WIDTH8};
pub use observer::{Observer, Query};
pub use render::{
    bounce_ray, facing_normal, render, RayKind, Render, RenderSettings, RenderStats, Shading,
};
pub use stats::{thread_cpu_seconds, RayStats};

use thiserror::Error;

/// Switches of the traversal kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct KernelOptions {
    /// Keep each stack entry's entry distance and drop entries beyond the closest hit when
    /// popped ([P4] §3.1's distance stack).
    pub distance_stack: bool,
}

impl KernelOptions {
    /// The configuration of [P4] §3: the BVH unit without a distance stack, the MBVH4 unit
    /// with one.
    pub fn thesis(width: u32) -> Self {
        Self {
            distance_stack: width > 2,
        }
    }
}

impl Default for KernelOptions {
    /// With the distance stack (it never changes a result, only saves work).
    fn default() -> Self {
        Self {
            distance_stack: true,
        }
    }
}

/// Why a tree cannot be traced, or a trace output cannot be written or read.
#[derive(Debug, Error)]
pub enum TraceError {
    /// A leaf-table entry names a triangle that does not exist.
    #[error("leaf-table entry {entry} names triangle {prim}, but there are {triangles} triangles")]
    PrimitiveOutOfRange {
        /// Leaf-table index.
        entry: usize,
        /// The primitive it names.
        prim: u32,
        /// Triangles given.
        triangles: usize,
    },
    /// The tree's links are malformed.
    #[error("malformed tree: {0}")]
    BadTree(String),
    /// An instance transform is not finite or not invertible.
    #[error("bad transform: {0}")]
    BadTransform(String),
    /// A setting is out of range.
    #[error("{0}")]
    Config(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What went wrong.
        source: std::io::Error,
    },
    /// A traversal log is malformed.
    #[error("{path}: not a valid traversal log: {message}")]
    BadLog {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// Encoding a PNG failed.
    #[error("{path}: cannot encode PNG: {message}")]
    Png {
        /// The file.
        path: String,
        /// The encoder's message.
        message: String,
    },
}
