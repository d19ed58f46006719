//! `Mbvh4`: the 4-wide BVH of \[P4\] §3.1 — 128-byte nodes with four child boxes — plus its
//! validator and SAH cost.
//!
//! \[P4\] replaces the 64-byte two-child node by a 128-byte node with four children, so one
//! fetch of twice the size serves the box tests that would take about two binary nodes
//! (Fig. 1 of \[P4\]: six 64 B nodes become two 128 B nodes). Like [`Bvh2`](crate::Bvh2), a
//! node stores its children's boxes, not its own, and leaves are ranges of a leaf table of
//! primitive references.
//!
//! Exact byte layout of [`Node4`] (`#[repr(C)]`, little-endian, no padding). Boxes are
//! stored structure-of-arrays, one 16-byte row of four lanes per box plane, so a 4-wide
//! SIMD unit (or \[P4\]'s four box-test units) reads one plane of all children at once:
//!
//! | bytes    | field          | meaning                                       |
//! |----------|----------------|-----------------------------------------------|
//! | 0..16    | `min_x[0..4]`  | box min x of children 0..3 (`f32`)            |
//! | 16..32   | `min_y[0..4]`  | box min y of children 0..3                    |
//! | 32..48   | `min_z[0..4]`  | box min z of children 0..3                    |
//! | 48..64   | `max_x[0..4]`  | box max x of children 0..3                    |
//! | 64..80   | `max_y[0..4]`  | box max y of children 0..3                    |
//! | 80..96   | `max_z[0..4]`  | box max z of children 0..3                    |
//! | 96..128  | `children[0..4]` | per child `index: u32` then `count: u32` (8 B each) |
//!
//! Child encoding (the same [`ChildRef`] as the binary node):
//! - `count == 0`, `index != EMPTY_INDEX`: inner child, `index` is a node index;
//! - `count > 0`: leaf of `prim_indices[index .. index + count]`;
//! - `count == 0`, `index == EMPTY_INDEX`: empty slot, with the empty box (`min = +inf`,
//!   `max = -inf`) that no slab test hits. Empty slots come after all used slots. Every
//!   node below the root has at least two children; the root may have fewer (trees of 0
//!   primitives, or a single root leaf).
//!
//! Nodes are stored depth-first (preorder, slot 0 first), so every inner child has a
//! larger index than its parent, which a bottom-up refit relies on ([`crate::refit_mbvh4`]).

use crate::node::{ChildRef, TreeNode};
use crate::sah::SahParams;
use crate::validate::{validate_wide_nodes, ValidationError};
use geom::{Aabb, Vec3};

/// Branching factor of [`Node4`].
pub const MBVH_WIDTH: usize = 4;

/// A 4-wide node of \[P4\]: four child boxes (structure of arrays) and four child refs.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node4 {
    /// Box min x of each child.
    pub min_x: [f32; 4],
    /// Box min y of each child.
    pub min_y: [f32; 4],
    /// Box min z of each child.
    pub min_z: [f32; 4],
    /// Box max x of each child.
    pub max_x: [f32; 4],
    /// Box max y of each child.
    pub max_y: [f32; 4],
    /// Box max z of each child.
    pub max_z: [f32; 4],
    /// Child references; empty slots ([`ChildRef::EMPTY`]) come last.
    pub children: [ChildRef; 4],
}

// [P4] §3.1: 128-byte MBVH4 nodes, twice the 64-byte binary node.
const _: () = assert!(std::mem::size_of::<Node4>() == 128);
const _: () = assert!(std::mem::align_of::<Node4>() == 4);

impl Node4 {
    /// A node whose four slots are empty.
    pub const EMPTY: Node4 = Node4 {
        min_x: [f32::INFINITY; 4],
        min_y: [f32::INFINITY; 4],
        min_z: [f32::INFINITY; 4],
        max_x: [f32::NEG_INFINITY; 4],
        max_y: [f32::NEG_INFINITY; 4],
        max_z: [f32::NEG_INFINITY; 4],
        children: [ChildRef::EMPTY; 4],
    };

    /// A node from up to four (box, child) pairs; the remaining slots are empty.
    pub fn from_children(kids: &[(Aabb, ChildRef)]) -> Self {
        debug_assert!(kids.len() <= MBVH_WIDTH);
        let mut n = Self::EMPTY;
        for (i, (b, c)) in kids.iter().take(MBVH_WIDTH).enumerate() {
            n.set_child_aabb(i, b);
            n.children[i] = *c;
        }
        n
    }

    /// The box of child `i` (0..4).
    #[inline]
    pub fn child_aabb(&self, i: usize) -> Aabb {
        Aabb::new(
            Vec3::new(self.min_x[i], self.min_y[i], self.min_z[i]),
            Vec3::new(self.max_x[i], self.max_y[i], self.max_z[i]),
        )
    }

    /// Sets the box of child `i`.
    #[inline]
    pub fn set_child_aabb(&mut self, i: usize, b: &Aabb) {
        self.min_x[i] = b.min.x;
        self.min_y[i] = b.min.y;
        self.min_z[i] = b.min.z;
        self.max_x[i] = b.max.x;
        self.max_y[i] = b.max.y;
        self.max_z[i] = b.max.z;
    }

    /// The union of the child boxes (this node's own box).
    #[inline]
    pub fn aabb(&self) -> Aabb {
        (0..MBVH_WIDTH).fold(Aabb::EMPTY, |a, i| a.union(self.child_aabb(i)))
    }

    /// Number of used (non-empty) slots.
    #[inline]
    pub fn child_count(&self) -> usize {
        self.children.iter().filter(|c| !c.is_empty()).count()
    }
}

/// A 4-wide BVH: 128-byte [`Node4`]s in depth-first order plus a leaf table.
#[derive(Clone, Debug, PartialEq)]
pub struct Mbvh4 {
    /// Nodes in depth-first preorder; `nodes[0]` is the root (always present).
    pub nodes: Vec<Node4>,
    /// Leaf table: primitive indices, each leaf a contiguous range of it.
    pub prim_indices: Vec<u32>,
    /// Scene bounds: the box of the root (empty for an empty tree).
    pub bounds: Aabb,
}

/// Shape statistics of an [`Mbvh4`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Mbvh4Stats {
    /// Number of nodes.
    pub inner_nodes: usize,
    /// Number of leaf child slots.
    pub leaves: usize,
    /// Largest leaf size.
    pub max_leaf_size: u32,
    /// Longest root-to-leaf path in nodes (root alone = 1; 0 for an empty tree).
    pub max_depth: usize,
    /// Mean number of used slots per node (4 = every node full).
    pub mean_children: f64,
}

impl Mbvh4 {
    /// The tree of zero primitives: a root with four empty slots.
    pub fn empty() -> Self {
        Self {
            nodes: vec![Node4::EMPTY],
            prim_indices: Vec::new(),
            bounds: Aabb::EMPTY,
        }
    }

    /// Number of primitives (leaf-table entries).
    pub fn prim_count(&self) -> usize {
        self.prim_indices.len()
    }

    /// Shape statistics; bounded walk that never panics on a corrupt tree.
    pub fn stats(&self) -> Mbvh4Stats {
        let t = crate::bvh2::shape_stats(&self.nodes);
        let used: usize = self.nodes.iter().map(Node4::child_count).sum();
        Mbvh4Stats {
            inner_nodes: t.inner_nodes,
            leaves: t.leaves,
            max_leaf_size: t.max_leaf_size,
            max_depth: t.max_depth,
            mean_children: if self.nodes.is_empty() {
                0.0
            } else {
                used as f64 / self.nodes.len() as f64
            },
        }
    }

    /// SAH cost with the thesis parameters as they stand ([`mbvh4_sah_cost_with`]): each
    /// 4-wide node costs `C_i` = 1.2, like a binary node. This undercounts the box tests of
    /// a 4-wide node; compare widths with [`Mbvh4::normalized_sah`].
    pub fn sah(&self) -> f64 {
        mbvh4_sah_cost_with(self, &SahParams::THESIS)
    }

    /// SAH cost in the binary SAH's units: the thesis parameters with each 4-wide node
    /// costing `2 C_i` = 2.4 for its four box tests ([`SahParams::for_width`]). This is the
    /// cost to divide by a binary sweep SAH build (`arbor build`'s `sah_vs_sweep` for the
    /// 4-wide builders). Pulling the two binary children (areas `A_l`, `A_r`) of a node of
    /// area `A` up into a 4-wide node changes the cost by `C_i (A - A_l - A_r)`: collapsing
    /// lowers it only where `A_l + A_r > A` (large, overlapping children).
    pub fn normalized_sah(&self) -> f64 {
        mbvh4_sah_cost_with(self, &SahParams::THESIS.for_width(MBVH_WIDTH))
    }
}

/// SAH cost of an [`Mbvh4`] with the given weights, normalized by the scene box area: the
/// formula of [`crate::sah_cost_with`] with 4-wide nodes (each node, the root included,
/// costs `C_i` times its area ratio; each leaf `C_l + C_t · count` times its area ratio).
/// A zero-area scene box takes every ratio as 1; an empty tree costs 0.
pub fn mbvh4_sah_cost_with(t: &Mbvh4, p: &SahParams) -> f64 {
    crate::sah::wide_sah_cost(&t.nodes, &t.bounds, p)
}

impl TreeNode for Node4 {
    const WIDTH: usize = MBVH_WIDTH;
    #[inline(always)]
    fn child_refs(&self) -> &[ChildRef] {
        &self.children
    }
    #[inline(always)]
    fn slot_aabb(&self, slot: usize) -> Aabb {
        self.child_aabb(slot)
    }
    #[inline(always)]
    fn set_slot_aabb(&mut self, slot: usize, b: &Aabb) {
        self.set_child_aabb(slot, b)
    }
    #[inline(always)]
    fn own_box(&self) -> Aabb {
        self.aabb()
    }
}

/// Checks every invariant of an [`Mbvh4`] over `prims` with leaves of at most
/// `max_leaf_size`, the same checks as [`crate::validate`]: root present, leaf table as long
/// as `prims`, scene bounds equal to the root's box, nodes reached exactly once in
/// depth-first preorder (no cycles, none unreachable), finite child boxes inside the parent
/// box, leaves non-empty, within the maximum and inside the leaf table, every primitive
/// referenced once and inside its leaf box. Slot rules specific to 4-wide nodes are
/// reported as [`ValidationError::BadEmptyChild`]: an empty slot must have the empty box and
/// come after all used slots, and a node below the root must use at least two slots. The
/// same implementation checks trees of any width ([`crate::validate_wide`]).
pub fn validate_mbvh4(
    t: &Mbvh4,
    prims: &[Aabb],
    max_leaf_size: u32,
) -> Result<(), ValidationError> {
    validate_wide_nodes(&t.nodes, &t.prim_indices, t.bounds, prims, max_leaf_size)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(x: f32) -> Aabb {
        Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
    }

    /// Root with two inner children, each with two single-primitive leaves.
    fn small() -> (Mbvh4, Vec<Aabb>) {
        let prims: Vec<Aabb> = (0..5).map(|i| unit(i as f32 * 2.0)).collect();
        let l = |i: usize| (prims[i], ChildRef::leaf(i as u32, 1));
        let n1 = Node4::from_children(&[l(0), l(1)]);
        let n2 = Node4::from_children(&[l(2), l(3)]);
        let root = Node4::from_children(&[
            (n1.aabb(), ChildRef::inner(1)),
            (n2.aabb(), ChildRef::inner(2)),
            l(4),
        ]);
        let t = Mbvh4 {
            bounds: root.aabb(),
            nodes: vec![root, n1, n2],
            prim_indices: (0..5).collect(),
        };
        (t, prims)
    }

    #[test]
    fn byte_layout_matches_module_doc() {
        let mut n = Node4::EMPTY;
        n.set_child_aabb(
            2,
            &Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)),
        );
        n.children[3] = ChildRef::leaf(7, 8);
        let base = &n as *const Node4 as usize;
        let off = |p: *const u8| p as usize - base;
        assert_eq!(off(&n.min_x[0] as *const f32 as *const u8), 0);
        assert_eq!(off(&n.min_y[0] as *const f32 as *const u8), 16);
        assert_eq!(off(&n.min_z[2] as *const f32 as *const u8), 40);
        assert_eq!(off(&n.max_x[0] as *const f32 as *const u8), 48);
        assert_eq!(off(&n.max_z[3] as *const f32 as *const u8), 92);
        assert_eq!(off(&n.children[0].index as *const u32 as *const u8), 96);
        assert_eq!(off(&n.children[3].count as *const u32 as *const u8), 124);
        assert_eq!(n.min_z[2], 3.0);
        assert_eq!(n.child_aabb(2).max, Vec3::new(4.0, 5.0, 6.0));
        assert!(n.child_aabb(0).is_empty());
    }

    #[test]
    fn valid_tree_passes_and_has_expected_cost() {
        let (t, prims) = small();
        assert_eq!(validate_mbvh4(&t, &prims, 1), Ok(()));
        let s = t.stats();
        assert_eq!(
            (s.inner_nodes, s.leaves, s.max_depth, s.max_leaf_size),
            (3, 5, 2, 1)
        );
        // Root area ratio 1 (x1.2), two inner nodes, five unit-cube leaves.
        let ra = t.bounds.half_area() as f64;
        let a1 = t.nodes[0].child_aabb(0).half_area() as f64 / ra;
        let leaf = unit(0.0).half_area() as f64 / ra;
        let want = 1.2 + 2.0 * 1.2 * a1 + 5.0 * leaf;
        assert!(
            (t.sah() - want).abs() < 1e-6 * want,
            "{} vs {want}",
            t.sah()
        );
        // Normalized: each of the three nodes costs 2.4 instead of 1.2.
        let want_norm = 2.4 + 2.0 * 2.4 * a1 + 5.0 * leaf;
        assert!((t.normalized_sah() - want_norm).abs() < 1e-6 * want_norm);
        assert_eq!(Mbvh4::empty().sah(), 0.0);
        assert_eq!(Mbvh4::empty().normalized_sah(), 0.0);
        assert_eq!(validate_mbvh4(&Mbvh4::empty(), &[], 1), Ok(()));
    }

    #[test]
    fn corruptions_are_reported() {
        use ValidationError as E;
        let (t, prims) = small();
        let check = |f: &dyn Fn(&mut Mbvh4), want: fn(&ValidationError) -> bool| {
            let mut c = t.clone();
            f(&mut c);
            let got = validate_mbvh4(&c, &prims, 1);
            assert!(matches!(&got, Err(e) if want(e)), "got {got:?}");
        };
        check(&|c| c.nodes[1].children[1] = ChildRef::inner(0), |e| {
            matches!(e, E::ChildOutOfRange { .. })
        });
        check(&|c| c.nodes[1].children[1] = ChildRef::inner(2), |e| {
            matches!(e, E::NotDepthFirst { .. } | E::NodeReachedTwice { .. })
        });
        check(&|c| c.nodes[0].children[2] = ChildRef::leaf(4, 2), |e| {
            matches!(e, E::LeafTooLarge { .. })
        });
        check(&|c| c.prim_indices[4] = 0, |e| {
            matches!(e, E::PrimReferencedTwice { .. } | E::PrimOutsideLeaf { .. })
        });
        check(&|c| c.prim_indices[4] = 9, |e| {
            matches!(e, E::PrimOutOfRange { .. })
        });
        check(&|c| c.nodes[1].max_x[0] = 0.5, |e| {
            matches!(e, E::PrimOutsideLeaf { .. })
        });
        check(&|c| c.nodes[0].max_x[0] = 0.5, |e| {
            matches!(e, E::ChildOutsideParent { .. })
        });
        check(&|c| c.nodes[0].min_x[1] = f32::NAN, |e| {
            matches!(e, E::NonFiniteBox { .. } | E::BoundsMismatch)
        });
        check(&|c| c.nodes[0].children.swap(2, 3), |e| {
            matches!(e, E::BadEmptyChild { .. })
        });
        check(
            &|c| {
                c.nodes[2].children[1] = ChildRef::EMPTY;
                c.nodes[2].set_child_aabb(1, &Aabb::EMPTY);
            },
            |e| matches!(e, E::BadEmptyChild { .. }),
        );
        check(&|c| c.nodes.push(Node4::EMPTY), |e| {
            matches!(e, E::Unreachable { .. })
        });
        check(&|c| c.bounds = unit(0.0), |e| {
            matches!(e, E::BoundsMismatch)
        });
        check(&|c| c.nodes[0].children[2] = ChildRef::leaf(9, 1), |e| {
            matches!(e, E::LeafOutOfRange { .. })
        });
        check(&|c| c.nodes.clear(), |e| matches!(e, E::NoRoot));
    }
}
