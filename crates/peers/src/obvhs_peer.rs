//! Adapter for the `obvhs` crate (0.4): its PLOC builder (Meister and Bittner 2018), with
//! optional reinsertion and leaf collapse as its presets configure them.
//!
//! The build goes through `obvhs::bvh2::builder::build_bvh2`, which runs PLOC, then
//! reinsertion, leaf collapse and a second reinsertion, each skipped when its preset
//! parameter disables it. Presets with `pre_split` (its spatial splits, which reference a
//! primitive from several leaves and so cannot be a valid Arbor tree) are not offered.
//! obvhs uses rayon's current pool (feature `parallel`), so the thread count is that of
//! the private pool it runs in.

use crate::convert::{to_bvh2, PeerNode};
use crate::{check_input, with_threads, BuildProbe, NoProbe, PeerBuild, PeerError};
use geom::Aabb;
use obvhs::aabb::Aabb as OAabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::{Boundable, BvhBuildParams};
use obvhs_glam::Vec3A;
use std::time::{Duration, Instant};

/// Which obvhs parameter preset to build with (the names of `obvhs::BvhBuildParams`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ObvhsPreset {
    /// `fastest_build`: PLOC with search radius 1, no reinsertion, one primitive per leaf.
    #[default]
    FastestBuild,
    /// `very_fast_build`: radius 1, reinsertion of 1% of nodes, collapse to leaves of up
    /// to 8 (collapse traversal cost 3).
    VeryFastBuild,
    /// `fast_build`: radius 6 near the root, 2% reinsertion, collapse to leaves of up to 8.
    FastBuild,
    /// `medium_build` ("around the same build time as embree"): radius 14 near the root,
    /// 5% reinsertion before and 10% after collapse to leaves of up to 8.
    MediumBuild,
}

impl ObvhsPreset {
    /// The obvhs parameters of this preset.
    pub fn params(self) -> BvhBuildParams {
        match self {
            Self::FastestBuild => BvhBuildParams::fastest_build(),
            Self::VeryFastBuild => BvhBuildParams::very_fast_build(),
            Self::FastBuild => BvhBuildParams::fast_build(),
            Self::MediumBuild => BvhBuildParams::medium_build(),
        }
    }

    /// The largest leaf this preset produces (the validator's maximum).
    pub fn max_leaf_size(self) -> u32 {
        self.params().max_prims_per_leaf.clamp(1, 255)
    }
}

/// The obvhs PLOC builder.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObvhsBuilder {
    /// Parameter preset.
    pub preset: ObvhsPreset,
    /// Worker threads: 0 uses the current rayon pool, `n` a private pool of `n` threads.
    pub threads: usize,
}

/// A primitive box in obvhs's types.
struct Prim(OAabb);

impl Boundable for Prim {
    fn aabb(&self) -> OAabb {
        self.0
    }
}

fn from_obvhs(b: &OAabb) -> Aabb {
    Aabb::new(
        geom::Vec3::new(b.min.x, b.min.y, b.min.z),
        geom::Vec3::new(b.max.x, b.max.y, b.max.z),
    )
}

impl ObvhsBuilder {
    /// Builds obvhs's tree over `aabbs` and converts it to Arbor's format. The build time
    /// is obvhs's own "core build time" (PLOC and post-passes, not its debug validation).
    pub fn build(&self, aabbs: &[Aabb]) -> Result<PeerBuild, PeerError> {
        self.build_probed(aabbs, &NoProbe)
    }

    /// [`ObvhsBuilder::build`] with `probe` run around obvhs's build call.
    pub fn build_probed(
        &self,
        aabbs: &[Aabb],
        probe: &dyn BuildProbe,
    ) -> Result<PeerBuild, PeerError> {
        check_input(aabbs)?;
        if aabbs.is_empty() {
            // obvhs has no tree of zero primitives.
            return Ok(PeerBuild {
                bvh: bvh::Bvh2::empty(),
                build_time: Duration::ZERO,
                convert_time: Duration::ZERO,
            });
        }
        let prims: Vec<Prim> = aabbs
            .iter()
            .map(|b| {
                Prim(OAabb::new(
                    Vec3A::new(b.min.x, b.min.y, b.min.z),
                    Vec3A::new(b.max.x, b.max.y, b.max.z),
                ))
            })
            .collect();
        let params = self.preset.params();
        let mut build_time = Duration::ZERO;
        probe.before_build();
        let tree = with_threads(self.threads, || build_bvh2(&prims, params, &mut build_time));
        probe.after_build();
        let tree = tree?;
        let start = Instant::now();
        let bvh = convert(&tree, aabbs.len())?;
        Ok(PeerBuild {
            bvh,
            build_time,
            convert_time: start.elapsed(),
        })
    }
}

/// Converts obvhs's node array (root at 0; an inner node's children at `first_index` and
/// `first_index + 1`, each with its own box; a leaf names a range of `primitive_indices`).
fn convert(tree: &obvhs::bvh2::Bvh2, prims: usize) -> Result<bvh::Bvh2, PeerError> {
    let nodes = &tree.nodes;
    let table = &tree.primitive_indices;
    // Check every link once up front so the view below cannot index out of range.
    for (i, n) in nodes.iter().enumerate() {
        let (first, count) = (n.first_index as usize, n.prim_count as usize);
        let ok = if n.is_leaf() {
            first
                .checked_add(count)
                .is_some_and(|end| end <= table.len())
        } else {
            first.checked_add(1).is_some_and(|end| end < nodes.len())
        };
        if !ok {
            return Err(PeerError::Malformed {
                peer: "obvhs",
                message: format!("node {i} links outside the node or primitive arrays"),
            });
        }
    }
    let Some(root) = nodes.first() else {
        return Err(PeerError::Malformed {
            peer: "obvhs",
            message: "no root node".into(),
        });
    };
    to_bvh2("obvhs", prims, 0usize, from_obvhs(root.aabb()), |i| {
        let n = &nodes[i];
        let first = n.first_index as usize;
        if n.is_leaf() {
            PeerNode::Leaf(&table[first..first + n.prim_count as usize])
        } else {
            PeerNode::Inner([
                (first, from_obvhs(nodes[first].aabb())),
                (first + 1, from_obvhs(nodes[first + 1].aabb())),
            ])
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testinputs::{adversarial, soup};

    const PRESETS: [ObvhsPreset; 4] = [
        ObvhsPreset::FastestBuild,
        ObvhsPreset::VeryFastBuild,
        ObvhsPreset::FastBuild,
        ObvhsPreset::MediumBuild,
    ];

    #[test]
    fn soups_give_valid_trees_for_every_preset() {
        for (n, seed) in [(1, 1), (2, 2), (3, 3), (100, 4), (5000, 5)] {
            let prims = soup(n, 2.0, seed);
            for preset in PRESETS {
                for threads in [1, 2] {
                    let b = ObvhsBuilder { preset, threads }.build(&prims).unwrap();
                    let max = preset.max_leaf_size();
                    assert_eq!(
                        bvh::validate(&b.bvh, &prims, max),
                        Ok(()),
                        "n={n} {preset:?}"
                    );
                    assert!(b.bvh.sah().is_finite() && b.bvh.sah() > 0.0);
                }
            }
        }
    }

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for (name, prims) in adversarial() {
            for preset in [ObvhsPreset::FastestBuild, ObvhsPreset::FastBuild] {
                let b = ObvhsBuilder { preset, threads: 2 }.build(&prims).unwrap();
                let max = preset.max_leaf_size();
                assert_eq!(
                    bvh::validate(&b.bvh, &prims, max),
                    Ok(()),
                    "{name} {preset:?}"
                );
            }
        }
    }

    #[test]
    fn huge_coordinates_give_a_valid_tree() {
        let prims = crate::testinputs::huge_coordinates();
        let b = ObvhsBuilder::default().build(&prims).unwrap();
        assert_eq!(bvh::validate(&b.bvh, &prims, 1), Ok(()));
    }

    #[test]
    fn empty_input_gives_the_empty_tree() {
        let b = ObvhsBuilder::default().build(&[]).unwrap();
        assert_eq!(b.bvh, bvh::Bvh2::empty());
    }
}
