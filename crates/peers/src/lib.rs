//! Peer BVH builders behind Arbor's interface, for like-for-like comparisons (issue 3,
//! "Speed and quality, measured against peers").
//!
//! Each adapter builds a tree with a peer library over the same primitive AABBs that
//! Arbor's builders take, then converts the peer's tree into Arbor's [`bvh::Bvh2`]. The
//! SAH is therefore computed by the same code ([`bvh::Bvh2::sah`]) and every tree passes
//! the same validator ([`bvh::validate`]), so quality ratios compare like with like.
//! Build time ([`PeerBuild::build_time`]) covers only the peer's build call; the conversion
//! is timed separately ([`PeerBuild::convert_time`]) and excluded from throughput.
//!
//! Peers:
//! - `EmbreeBuilder` (feature `embree`, needs `libembree3`): Embree 3's `rtcBuildBVH`,
//!   quality `LOW` (Morton builder) or `MEDIUM` (binned SAH), through a hand-written FFI.
//! - [`ObvhsBuilder`]: the PLOC builder of the `obvhs` crate (0.4), with one of its presets.
//! - [`BvhCrateBuilder`]: the binned SAH builder of the `bvh` crate (0.13, svenstaro/bvh).

#![warn(missing_docs)]

mod bvh_crate;
mod convert;
#[cfg(feature = "embree")]
mod embree;
#[cfg(feature = "embree")]
mod embree_ffi;
#[cfg(feature = "embree")]
mod embree_rt;
mod obvhs_peer;
mod obvhs_rt;
#[cfg(test)]
mod testinputs;
pub mod trace_bench;

pub use bvh_crate::BvhCrateBuilder;
#[cfg(feature = "embree")]
pub use embree::{EmbreeBuilder, EmbreeDevice, EmbreeQuality};
#[cfg(feature = "embree")]
pub use embree_rt::{EmbreeRefitScene, EmbreeScene, EmbreeSceneConfig};
pub use obvhs_peer::{ObvhsBuilder, ObvhsPreset};
pub use obvhs_rt::ObvhsTracer;

use bvh::{BuildError, Bvh2, MAX_PRIMITIVES};
use geom::Aabb;
use std::time::Duration;
use thiserror::Error;

/// A peer's tree converted to Arbor's format, with the peer's build time.
#[derive(Clone, Debug)]
pub struct PeerBuild {
    /// The peer's tree in Arbor's format.
    pub bvh: Bvh2,
    /// Wall time of the peer's build call alone (what throughput is computed from).
    pub build_time: Duration,
    /// Wall time of the conversion to [`Bvh2`] (not part of the peer's build).
    pub convert_time: Duration,
}

/// Hooks that a caller runs right around a peer's build call alone — after the adapter has
/// copied the input into the peer's format and before the tree is converted to [`Bvh2`] —
/// e.g. to read a counting allocator's peak over exactly the peer's build (`arbor bench
/// build` does).
pub trait BuildProbe: Sync {
    /// Called right before the peer's build call.
    fn before_build(&self);
    /// Called right after it.
    fn after_build(&self);
}

/// The probe that does nothing (what the plain `build` methods use).
pub struct NoProbe;

impl BuildProbe for NoProbe {
    fn before_build(&self) {}
    fn after_build(&self) {}
}

/// Why a peer build failed.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PeerError {
    /// The input is not buildable (non-finite or inverted box, too many primitives).
    #[error(transparent)]
    Input(#[from] BuildError),
    /// The peer library reported an error.
    #[error("{peer}: {message}")]
    Peer {
        /// Which peer.
        peer: &'static str,
        /// What it said.
        message: String,
    },
    /// The peer returned a tree that does not describe the input (a conversion bug or a
    /// peer bug; the message says which invariant broke).
    #[error("{peer}: malformed tree: {message}")]
    Malformed {
        /// Which peer.
        peer: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The rayon thread pool for the requested thread count could not be created.
    #[error("cannot create a thread pool: {0}")]
    ThreadPool(String),
}

/// Rejects inputs that Arbor's builders reject too, so peers see the same valid inputs:
/// non-finite or inverted boxes and more primitives than 32-bit indices address.
pub(crate) fn check_input(aabbs: &[Aabb]) -> Result<(), BuildError> {
    if aabbs.len() > MAX_PRIMITIVES {
        return Err(BuildError::TooManyPrimitives {
            count: aabbs.len(),
            limit: MAX_PRIMITIVES,
        });
    }
    for (index, b) in aabbs.iter().enumerate() {
        if !(b.min.is_finite() && b.max.is_finite()) {
            return Err(BuildError::NonFinite { index });
        }
        if b.min.cmpgt(b.max).any() {
            return Err(BuildError::InvertedBox { index });
        }
    }
    Ok(())
}

/// Runs `f` on a private rayon pool of `threads` threads (0: the current pool), so that a
/// peer that uses rayon's global pool is measured at the requested thread count.
pub(crate) fn with_threads<R: Send>(
    threads: usize,
    f: impl FnOnce() -> R + Send,
) -> Result<R, PeerError> {
    if threads == 0 {
        return Ok(f());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| PeerError::ThreadPool(e.to_string()))?;
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    #[test]
    fn bad_inputs_are_rejected_like_arbor_does() {
        let ok = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(check_input(&[ok, ok]), Ok(()));
        let nan = Aabb::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE);
        assert_eq!(
            check_input(&[ok, nan]),
            Err(BuildError::NonFinite { index: 1 })
        );
        let inv = Aabb::new(Vec3::ONE, Vec3::ZERO);
        assert_eq!(
            check_input(&[inv]),
            Err(BuildError::InvertedBox { index: 0 })
        );
    }

    #[test]
    fn with_threads_runs_on_the_requested_pool() {
        assert_eq!(with_threads(2, rayon::current_num_threads).unwrap(), 2);
        assert_eq!(with_threads(0, || 7).unwrap(), 7);
    }

    /// A box with corners from a small grid (so duplicates, shared centroids and flat
    /// boxes are common) or from a continuous range.
    fn any_box() -> impl proptest::strategy::Strategy<Value = Aabb> {
        use proptest::prelude::*;
        let f = prop_oneof![(-4i32..4).prop_map(|i| i as f32), -1e3f32..1e3];
        proptest::array::uniform6(f).prop_map(|v| {
            let a = Vec3::new(v[0], v[1], v[2]);
            let b = Vec3::new(v[3], v[4], v[5]);
            Aabb::new(a.min(b), a.max(b))
        })
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// Every adapter turns any valid input into a tree the validator accepts.
        #[test]
        fn any_input_gives_valid_trees(prims in proptest::collection::vec(any_box(), 0..300)) {
            for threads in [1, 2] {
                let o = ObvhsBuilder { preset: ObvhsPreset::FastBuild, threads }.build(&prims).unwrap();
                let max = ObvhsPreset::FastBuild.max_leaf_size();
                proptest::prop_assert_eq!(bvh::validate(&o.bvh, &prims, max), Ok(()));
                let c = BvhCrateBuilder { threads }.build(&prims).unwrap();
                proptest::prop_assert_eq!(bvh::validate(&c.bvh, &prims, 1), Ok(()));
            }
            #[cfg(feature = "embree")]
            for quality in [EmbreeQuality::Low, EmbreeQuality::Medium] {
                let e = EmbreeBuilder { quality, ..Default::default() }.build(&prims, 2).unwrap();
                proptest::prop_assert_eq!(bvh::validate(&e.bvh, &prims, 8), Ok(()));
            }
        }
    }
}
