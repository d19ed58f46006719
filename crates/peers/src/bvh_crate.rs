//! Adapter for the `bvh` crate (svenstaro/bvh 0.13), renamed `bvh_peer` here because
//! Arbor's own crate is called `bvh`.
//!
//! Its builder is a top-down binned SAH (6 buckets) with one shape per leaf, parallel
//! through `rayon::join` when built with its `rayon_executor`. Its tree is a flat array of
//! enum nodes (inner nodes store both child boxes, as Arbor's do), converted here.

use crate::convert::{to_bvh2, PeerNode};
use crate::{check_input, with_threads, BuildProbe, NoProbe, PeerBuild, PeerError};
use bvh_peer::aabb::{Aabb as PAabb, Bounded};
use bvh_peer::bounding_hierarchy::BHShape;
use bvh_peer::bvh::{rayon_executor, Bvh, BvhNode};
use geom::{Aabb, Vec3};
use nalgebra::Point3;
use std::time::Instant;

/// The `bvh` crate's SAH builder (one primitive per leaf).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BvhCrateBuilder {
    /// Worker threads: 1 runs its sequential build; 0 (current rayon pool) or `n` (a
    /// private pool of `n`) runs its rayon executor.
    pub threads: usize,
}

/// A primitive as the `bvh` crate wants it: a box and the node that references it.
struct Shape {
    aabb: PAabb<f32, 3>,
    node: usize,
}

impl Bounded<f32, 3> for Shape {
    fn aabb(&self) -> PAabb<f32, 3> {
        self.aabb
    }
}

impl BHShape<f32, 3> for Shape {
    fn set_bh_node_index(&mut self, i: usize) {
        self.node = i;
    }
    fn bh_node_index(&self) -> usize {
        self.node
    }
}

fn to_peer(b: &Aabb) -> PAabb<f32, 3> {
    PAabb::with_bounds(
        Point3::new(b.min.x, b.min.y, b.min.z),
        Point3::new(b.max.x, b.max.y, b.max.z),
    )
}

fn from_peer(b: &PAabb<f32, 3>) -> Aabb {
    Aabb::new(
        Vec3::new(b.min.x, b.min.y, b.min.z),
        Vec3::new(b.max.x, b.max.y, b.max.z),
    )
}

impl BvhCrateBuilder {
    /// Builds the `bvh` crate's tree over `aabbs` and converts it to Arbor's format.
    pub fn build(&self, aabbs: &[Aabb]) -> Result<PeerBuild, PeerError> {
        self.build_probed(aabbs, &NoProbe)
    }

    /// [`BvhCrateBuilder::build`] with `probe` run around the crate's build call.
    pub fn build_probed(
        &self,
        aabbs: &[Aabb],
        probe: &dyn BuildProbe,
    ) -> Result<PeerBuild, PeerError> {
        check_input(aabbs)?;
        let mut shapes: Vec<Shape> = aabbs
            .iter()
            .map(|b| Shape {
                aabb: to_peer(b),
                node: 0,
            })
            .collect();
        probe.before_build();
        let start = Instant::now();
        // The crate panics on some finite inputs (boxes near f32::MAX overflow its bucket
        // arithmetic to NaN and it unwraps); that becomes an error here, never a panic.
        let tree = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            if self.threads == 1 {
                Ok(Bvh::<f32, 3>::build(&mut shapes))
            } else {
                with_threads(self.threads, || {
                    Bvh::build_with_executor(&mut shapes, rayon_executor)
                })
            }
        }));
        let build_time = start.elapsed();
        probe.after_build();
        let tree = tree.map_err(|_| PeerError::Peer {
            peer: "bvh crate",
            message: "the build panicked (coordinates too large for its arithmetic?)".into(),
        })??;
        let start = Instant::now();
        let bvh = convert(&tree, aabbs)?;
        Ok(PeerBuild {
            bvh,
            build_time,
            convert_time: start.elapsed(),
        })
    }
}

/// Converts the crate's node array (root at 0) to Arbor's format.
fn convert(tree: &Bvh<f32, 3>, aabbs: &[Aabb]) -> Result<bvh::Bvh2, PeerError> {
    if aabbs.is_empty() {
        return Ok(bvh::Bvh2::empty());
    }
    // Leaves name one shape by `usize`; the converter wants slices of `u32` ids.
    let ids: Vec<u32> = (0..aabbs.len() as u32).collect();
    let bad = |i: usize| PeerError::Malformed {
        peer: "bvh crate",
        message: format!("node index {i} outside {} nodes", tree.nodes.len()),
    };
    // Check every link once up front so the view below cannot index out of range.
    for n in &tree.nodes {
        match *n {
            BvhNode::Leaf { shape_index, .. } if shape_index >= ids.len() => {
                return Err(bad(shape_index))
            }
            BvhNode::Node {
                child_l_index,
                child_r_index,
                ..
            } if child_l_index.max(child_r_index) >= tree.nodes.len() => {
                return Err(bad(child_l_index.max(child_r_index)))
            }
            _ => {}
        }
    }
    if tree.nodes.is_empty() {
        return Err(bad(0));
    }
    let root_box = match tree.nodes[0] {
        BvhNode::Leaf { shape_index, .. } => aabbs[shape_index],
        BvhNode::Node {
            child_l_aabb,
            child_r_aabb,
            ..
        } => from_peer(&child_l_aabb).union(from_peer(&child_r_aabb)),
    };
    to_bvh2("bvh crate", aabbs.len(), 0usize, root_box, |i| {
        match tree.nodes[i] {
            BvhNode::Leaf { shape_index, .. } => PeerNode::Leaf(&ids[shape_index..shape_index + 1]),
            BvhNode::Node {
                child_l_index,
                child_l_aabb,
                child_r_index,
                child_r_aabb,
                ..
            } => PeerNode::Inner([
                (child_l_index, from_peer(&child_l_aabb)),
                (child_r_index, from_peer(&child_r_aabb)),
            ]),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testinputs::{adversarial, soup};

    #[test]
    fn soups_give_valid_trees_on_one_and_two_threads() {
        for (n, seed) in [(1, 1), (2, 2), (100, 3), (5000, 4)] {
            let prims = soup(n, 2.0, seed);
            for threads in [1, 2] {
                let b = BvhCrateBuilder { threads }.build(&prims).unwrap();
                assert_eq!(bvh::validate(&b.bvh, &prims, 1), Ok(()), "n={n}");
                assert!(b.bvh.sah().is_finite() && b.bvh.sah() > 0.0);
            }
        }
    }

    #[test]
    fn adversarial_inputs_give_valid_trees() {
        for (name, prims) in adversarial() {
            let b = BvhCrateBuilder { threads: 2 }.build(&prims).unwrap();
            assert_eq!(bvh::validate(&b.bvh, &prims, 1), Ok(()), "{name}");
        }
    }

    #[test]
    fn overflowing_coordinates_are_an_error_not_a_panic() {
        let prims = crate::testinputs::huge_coordinates();
        for threads in [1, 2] {
            assert!(matches!(
                BvhCrateBuilder { threads }.build(&prims),
                Err(PeerError::Peer { .. })
            ));
        }
    }

    #[test]
    fn empty_input_gives_the_empty_tree() {
        let b = BvhCrateBuilder::default().build(&[]).unwrap();
        assert_eq!(b.bvh, bvh::Bvh2::empty());
    }
}
