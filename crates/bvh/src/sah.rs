//! Surface area heuristic (SAH) cost of a tree, as the thesis reports tree quality.
//!
//! \[P2\] §6.2: `C = C_i Σ_inner A(N)/A(R) + C_l Σ_leaves A(L)/A(R) + C_t Σ_leaves P·A(L)/A(R)`
//! over all inner nodes (the root included), all leaves with `P` primitives each, and the
//! scene box `R`. The builders use the same parameters to decide splits. The thesis reports
//! costs relative to a full sweep SAH build of the same scene ("SAH %"), see [`sah_ratio`].

use crate::bvh2::Bvh2;
use crate::node::TreeNode;
use geom::Aabb;

/// Cost weights of the SAH.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SahParams {
    /// Cost of traversing an inner node (`C_i`).
    pub c_inner: f32,
    /// Cost of visiting a leaf (`C_l`).
    pub c_leaf: f32,
    /// Cost of one primitive test (`C_t`).
    pub c_tri: f32,
}

impl SahParams {
    /// \[P2\] §6.2: "C_i = 1.2, C_l = 0, C_t = 1", the GPU values of Karras and Aila.
    pub const THESIS: SahParams = SahParams {
        c_inner: 1.2,
        c_leaf: 0.0,
        c_tri: 1.0,
    };
}

impl SahParams {
    /// Checks that every weight is finite and non-negative; `who` names the builder in the
    /// error.
    pub fn check(&self, who: &str) -> Result<(), crate::BuildError> {
        let ok = |w: f32| w.is_finite() && w >= 0.0;
        if ok(self.c_inner) && ok(self.c_leaf) && ok(self.c_tri) {
            Ok(())
        } else {
            Err(crate::BuildError::InvalidConfig(format!(
                "{who} SAH weights must be finite and non-negative: {self:?}"
            )))
        }
    }

    /// These weights for a tree whose nodes test `width` child boxes, in the units of the
    /// binary SAH: `C_i` prices a visit of a binary node, i.e. testing its two child boxes,
    /// so a node that tests `width` boxes costs `C_i · width / 2`; `C_l` and `C_t` stay.
    /// Thesis §4.2: "a four-way MBVH requires twice as many intersection tests to traverse a
    /// node", so a 4-wide node costs `2 C_i` (2.4 with [`SahParams::THESIS`]). A node costs
    /// this whether or not all its slots are used: \[P4\]'s traversal unit (and a SIMD
    /// lane set) tests all four slots at once. The cost is then the expected number of box
    /// tests (at `C_i / 2` each) plus triangle tests per ray, comparable across widths.
    pub fn for_width(&self, width: usize) -> SahParams {
        SahParams {
            c_inner: self.c_inner * width as f32 / 2.0,
            ..*self
        }
    }
}

impl Default for SahParams {
    fn default() -> Self {
        Self::THESIS
    }
}

/// SAH cost of `bvh` with the thesis parameters, normalized by the scene box area.
pub fn sah_cost(bvh: &Bvh2) -> f64 {
    sah_cost_with(bvh, &SahParams::THESIS)
}

/// SAH cost of `bvh` with the given weights, normalized by the scene box area.
///
/// An empty tree costs 0. When the scene box has zero area (all primitives on one point or
/// line), every area ratio is taken as 1, since any ray that reaches the root reaches every
/// node. Child links are trusted as far as they stay inside `nodes` (a validated tree).
pub fn sah_cost_with(bvh: &Bvh2, p: &SahParams) -> f64 {
    wide_sah_cost(&bvh.nodes, &bvh.bounds, p)
}

/// SAH cost of a tree of nodes of any width, normalized by the area of `bounds`: the root
/// costs `C_i`, every inner child `C_i` times its area ratio, every leaf `C_l + C_t * count`
/// times its area ratio. A zero-area scene box takes every ratio as 1; an empty tree costs
/// 0. Child links are trusted as far as they stay inside `nodes`, and the walk stops after
/// `nodes.len()` steps, so a corrupt tree cannot loop.
pub(crate) fn wide_sah_cost<N: TreeNode>(nodes: &[N], bounds: &Aabb, p: &SahParams) -> f64 {
    let Some(root) = nodes.first() else {
        return 0.0;
    };
    if root.child_refs().iter().all(|c| c.is_empty()) {
        return 0.0;
    }
    let root_area = bounds.half_area() as f64;
    let ratio = |a: f32| {
        if root_area > 0.0 {
            a as f64 / root_area
        } else {
            1.0
        }
    };
    let (ci, cl, ct) = (p.c_inner as f64, p.c_leaf as f64, p.c_tri as f64);
    let mut cost = ci * ratio(bounds.half_area());
    let mut stack = vec![0usize];
    let mut steps = 0usize;
    while let Some(i) = stack.pop() {
        steps += 1;
        let Some(node) = nodes.get(i).filter(|_| steps <= nodes.len()) else {
            continue;
        };
        for (slot, c) in node.child_refs().iter().enumerate() {
            let a = ratio(node.slot_aabb(slot).half_area());
            if c.is_leaf() {
                cost += a * (cl + ct * c.count as f64);
            } else if c.is_inner() {
                cost += a * ci;
                stack.push(c.index as usize);
            }
        }
    }
    cost
}

/// `cost / reference` (1.0 = as good as the reference; the thesis's "SAH %" over 100).
/// Returns 1.0 when both are 0 and infinity when only the reference is 0.
pub fn sah_ratio(cost: f64, reference: f64) -> f64 {
    if reference == 0.0 {
        if cost == 0.0 {
            1.0
        } else {
            f64::INFINITY
        }
    } else {
        cost / reference
    }
}

impl Bvh2 {
    /// SAH cost with the thesis parameters ([`sah_cost`]).
    pub fn sah(&self) -> f64 {
        sah_cost(self)
    }

    /// This tree's SAH relative to `reference` (usually a sweep SAH build of the same scene).
    pub fn sah_vs(&self, reference: &Bvh2) -> f64 {
        sah_ratio(self.sah(), reference.sah())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::node::{ChildRef, Node};
    use geom::{Aabb, Vec3};

    #[test]
    fn hand_built_tree_cost() {
        // Root box [0,2]x[0,1]x[0,1] (half area 2+1+2 = 5) with two unit-cube leaves of 1 and
        // 3 primitives (half area 3 each): 1.2*5/5 + 3/5*1 + 3/5*3 = 1.2 + 2.4 = 3.6.
        let a = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let b = Aabb::new(Vec3::X, Vec3::new(2.0, 1.0, 1.0));
        let t = Bvh2 {
            nodes: vec![Node::new(
                &a,
                ChildRef::leaf(0, 1),
                &b,
                ChildRef::leaf(1, 3),
            )],
            prim_indices: vec![0, 1, 2, 3],
            bounds: a.union(b),
        };
        assert!((t.sah() - 3.6).abs() < 1e-6, "{}", t.sah());
        assert!((t.sah_vs(&t) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn width_scales_only_the_inner_cost() {
        let p = SahParams::THESIS.for_width(4);
        assert_eq!((p.c_inner, p.c_leaf, p.c_tri), (2.4, 0.0, 1.0));
        assert_eq!(SahParams::THESIS.for_width(2), SahParams::THESIS);
    }

    #[test]
    fn empty_and_degenerate_trees() {
        assert_eq!(Bvh2::empty().sah(), 0.0);
        // All primitives on one point: zero root area, ratios taken as 1: 1.2 + 2.
        let p = Aabb::from_point(Vec3::ONE);
        let t = Bvh2 {
            nodes: vec![Node::new(
                &p,
                ChildRef::leaf(0, 2),
                &Aabb::EMPTY,
                ChildRef::EMPTY,
            )],
            prim_indices: vec![0, 1],
            bounds: p,
        };
        assert!((t.sah() - 3.2).abs() < 1e-6);
        assert_eq!(sah_ratio(0.0, 0.0), 1.0);
        assert_eq!(sah_ratio(1.0, 0.0), f64::INFINITY);
        assert_eq!(sah_ratio(3.0, 2.0), 1.5);
    }
}
