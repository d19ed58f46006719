//! `Bvh2`: the binary BVH of \[P2\] §4.1 — 64-byte two-AABB nodes plus a leaf table.
//!
//! - `nodes[0]` is the root; nodes are stored depth-first (preorder, child 0 first), so
//!   an inner child 0 of node `i` is always node `i + 1`.
//! - Leaves are not nodes: a leaf is a child slot with `count > 0` naming the range
//!   `prim_indices[index .. index + count]` of the leaf table, whose entries are primitive
//!   indices into the builder's input (\[P2\] §4.1 uses a reference table so that any
//!   primitive type with an AABB works).
//! - `bounds` is the scene box, the union of the root's child boxes.
//!
//! Small trees: the tree always has a root node, so traversal never special-cases.
//! - 0 primitives: one root node with two empty children (see [`crate::node`]), an empty
//!   leaf table and empty `bounds`.
//! - A tree whose top-level build decision is a single leaf (1 primitive, or a few that
//!   the SAH keeps together): the root holds that leaf in child 0 and an empty child 1.

use crate::node::{ChildRef, Node, TreeNode};
use geom::Aabb;

/// A binary BVH with \[P2\]'s 64-byte nodes and a leaf table of primitive references.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh2 {
    /// Nodes in depth-first preorder; `nodes[0]` is the root (always present).
    pub nodes: Vec<Node>,
    /// Leaf table: primitive indices, each leaf a contiguous range of it.
    pub prim_indices: Vec<u32>,
    /// Scene bounds: the box of the root (empty for an empty tree).
    pub bounds: Aabb,
}

/// Counts that describe a tree's shape.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TreeStats {
    /// Number of nodes (inner nodes; leaves live in child slots).
    pub inner_nodes: usize,
    /// Number of leaf child slots.
    pub leaves: usize,
    /// Largest leaf size.
    pub max_leaf_size: u32,
    /// Longest root-to-leaf path counted in nodes (root alone = 1; 0 for an empty tree).
    pub max_depth: usize,
}

impl Bvh2 {
    /// The tree of zero primitives: a root with two empty children.
    pub fn empty() -> Self {
        Self {
            nodes: vec![Node::EMPTY],
            prim_indices: Vec::new(),
            bounds: Aabb::EMPTY,
        }
    }

    /// Assembles a tree from a builder's root decision: `root` is the child reference of
    /// the whole scene (a leaf, or inner node 0 of `nodes`), `bounds` its box.
    pub(crate) fn from_root(
        root: ChildRef,
        bounds: Aabb,
        nodes: Vec<Node>,
        prim_indices: Vec<u32>,
    ) -> Self {
        let mut t = Self {
            nodes,
            prim_indices,
            bounds,
        };
        t.set_root(root, bounds);
        t
    }

    /// Completes a tree whose `nodes` and `prim_indices` a builder has written in place:
    /// `root` is the child reference of the whole scene (a leaf, or inner node 0 of
    /// `nodes`), `bounds` its box.
    pub(crate) fn set_root(&mut self, root: ChildRef, bounds: Aabb) {
        if root.is_leaf() {
            self.nodes.clear();
            self.nodes
                .push(Node::new(&bounds, root, &Aabb::EMPTY, ChildRef::EMPTY));
        }
        self.bounds = bounds;
    }

    /// Makes this the tree of zero primitives ([`Bvh2::empty`]), keeping its buffers.
    pub(crate) fn clear(&mut self) {
        self.nodes.clear();
        self.nodes.push(Node::EMPTY);
        self.prim_indices.clear();
        self.bounds = Aabb::EMPTY;
    }

    /// Number of primitives (leaf-table entries).
    pub fn prim_count(&self) -> usize {
        self.prim_indices.len()
    }

    /// Shape statistics. Follows child links with an explicit stack and ignores links that
    /// point outside `nodes`, so it never panics, even on a corrupt tree (run
    /// [`crate::validate`] first to trust the numbers).
    pub fn stats(&self) -> TreeStats {
        shape_stats(&self.nodes)
    }
}

/// Shape statistics of a tree of nodes of any width (root = node 0). Follows child links
/// with an explicit stack, at most `nodes.len()` steps, and ignores links outside `nodes`.
pub(crate) fn shape_stats<N: TreeNode>(nodes: &[N]) -> TreeStats {
    let mut s = TreeStats {
        inner_nodes: nodes.len(),
        ..TreeStats::default()
    };
    if nodes.is_empty() {
        return s;
    }
    let mut stack = vec![(0usize, 1usize)];
    let mut steps = 0usize;
    while let Some((i, depth)) = stack.pop() {
        steps += 1;
        if steps > nodes.len() {
            break; // a cycle: the validator reports it
        }
        let Some(node) = nodes.get(i) else {
            continue;
        };
        let mut has_child = false;
        for c in node.child_refs() {
            if c.is_leaf() {
                s.leaves += 1;
                s.max_leaf_size = s.max_leaf_size.max(c.count);
                has_child = true;
            } else if c.is_inner() {
                stack.push((c.index as usize, depth + 1));
                has_child = true;
            }
        }
        if has_child {
            s.max_depth = s.max_depth.max(depth);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    #[test]
    fn empty_tree_has_a_root_with_two_empty_children() {
        let t = Bvh2::empty();
        assert_eq!(t.nodes.len(), 1);
        assert!(t.nodes[0].children.iter().all(ChildRef::is_empty));
        assert!(t.bounds.is_empty());
        let s = t.stats();
        assert_eq!((s.leaves, s.max_depth, s.max_leaf_size), (0, 0, 0));
    }

    #[test]
    fn root_leaf_is_wrapped_in_a_root_node() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let t = Bvh2::from_root(ChildRef::leaf(0, 1), b, Vec::new(), vec![0]);
        assert_eq!(t.nodes.len(), 1);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        assert!(t.nodes[0].children[1].is_empty());
        assert_eq!(t.nodes[0].child_aabb(0), b);
        assert!(t.nodes[0].child_aabb(1).is_empty());
        let s = t.stats();
        assert_eq!((s.leaves, s.max_depth, s.max_leaf_size), (1, 1, 1));
    }
}
