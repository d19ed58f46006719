//! `Tree`: a built tree of either width — the binary [`Bvh2`] of \[P2\] §4.1 or the 4-wide
//! [`Mbvh4`] of \[P4\] §3.1 — behind one type, so that a command, a file reader or a ray
//! tracer can hold "the tree" without caring which builder made it.
//!
//! Every method dispatches to the width's own implementation (validator, SAH, refit,
//! statistics); nothing is re-implemented here. The SAH of a `Tree` is
//! [`Tree::normalized_sah`]: for a 4-wide tree it charges each node for its four box tests
//! ([`SahParams::for_width`]), so binary and 4-wide costs are in the same units and can
//! both be divided by a binary sweep SAH build.

use crate::bvh2::{Bvh2, TreeStats};
use crate::mbvh4::{validate_mbvh4, Mbvh4, Node4};
use crate::node::Node;
use crate::refit::{refit_bvh2, refit_mbvh4, RefitError};
use crate::validate::{validate, ValidationError};
use geom::Aabb;

/// Which kind of tree: the binary or the 4-wide format (also the tree file's kind field).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TreeKind {
    /// The binary 64-byte-node tree [`Bvh2`].
    Bvh2 = 1,
    /// The 4-wide 128-byte-node tree [`Mbvh4`] of \[P4\].
    Mbvh4 = 2,
}

impl TreeKind {
    /// Children per node (2 or 4).
    pub const fn width(self) -> usize {
        match self {
            TreeKind::Bvh2 => 2,
            TreeKind::Mbvh4 => crate::mbvh4::MBVH_WIDTH,
        }
    }

    /// Bytes per node in memory and in the tree file (64 or 128).
    pub const fn node_bytes(self) -> usize {
        match self {
            TreeKind::Bvh2 => std::mem::size_of::<Node>(),
            TreeKind::Mbvh4 => std::mem::size_of::<Node4>(),
        }
    }

    /// The format's name (`Bvh2` or `Mbvh4`).
    pub const fn name(self) -> &'static str {
        match self {
            TreeKind::Bvh2 => "Bvh2",
            TreeKind::Mbvh4 => "Mbvh4",
        }
    }
}

impl std::fmt::Display for TreeKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A built tree of either width.
#[derive(Clone, Debug, PartialEq)]
pub enum Tree {
    /// A binary tree.
    Bvh2(Bvh2),
    /// A 4-wide tree.
    Mbvh4(Mbvh4),
}

impl From<Bvh2> for Tree {
    fn from(t: Bvh2) -> Self {
        Tree::Bvh2(t)
    }
}

impl From<Mbvh4> for Tree {
    fn from(t: Mbvh4) -> Self {
        Tree::Mbvh4(t)
    }
}

impl Tree {
    /// The tree's kind.
    pub fn kind(&self) -> TreeKind {
        match self {
            Tree::Bvh2(_) => TreeKind::Bvh2,
            Tree::Mbvh4(_) => TreeKind::Mbvh4,
        }
    }

    /// The binary tree, if this is one.
    pub fn as_bvh2(&self) -> Option<&Bvh2> {
        match self {
            Tree::Bvh2(t) => Some(t),
            Tree::Mbvh4(_) => None,
        }
    }

    /// The 4-wide tree, if this is one.
    pub fn as_mbvh4(&self) -> Option<&Mbvh4> {
        match self {
            Tree::Mbvh4(t) => Some(t),
            Tree::Bvh2(_) => None,
        }
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        match self {
            Tree::Bvh2(t) => t.nodes.len(),
            Tree::Mbvh4(t) => t.nodes.len(),
        }
    }

    /// The leaf table (primitive indices).
    pub fn prim_indices(&self) -> &[u32] {
        match self {
            Tree::Bvh2(t) => &t.prim_indices,
            Tree::Mbvh4(t) => &t.prim_indices,
        }
    }

    /// Number of primitives (leaf-table entries).
    pub fn prim_count(&self) -> usize {
        self.prim_indices().len()
    }

    /// Scene bounds (the root's box).
    pub fn bounds(&self) -> Aabb {
        match self {
            Tree::Bvh2(t) => t.bounds,
            Tree::Mbvh4(t) => t.bounds,
        }
    }

    /// Bytes of the node array plus the leaf table (the tree's memory and file payload).
    pub fn bytes(&self) -> usize {
        self.node_count() * self.kind().node_bytes() + self.prim_count() * 4
    }

    /// Shape statistics (bounded walk; never panics on a corrupt tree).
    pub fn stats(&self) -> TreeStats {
        match self {
            Tree::Bvh2(t) => t.stats(),
            Tree::Mbvh4(t) => {
                let s = t.stats();
                TreeStats {
                    inner_nodes: s.inner_nodes,
                    leaves: s.leaves,
                    max_leaf_size: s.max_leaf_size,
                    max_depth: s.max_depth,
                }
            }
        }
    }

    /// Mean number of used child slots per node (2 for any non-trivial binary tree).
    pub fn mean_children(&self) -> f64 {
        match self {
            Tree::Bvh2(t) => {
                let used: usize = t
                    .nodes
                    .iter()
                    .map(|n| n.children.iter().filter(|c| !c.is_empty()).count())
                    .sum();
                used as f64 / t.nodes.len().max(1) as f64
            }
            Tree::Mbvh4(t) => t.stats().mean_children,
        }
    }

    /// SAH cost in the binary SAH's units: [`Bvh2::sah`] for a binary tree,
    /// [`Mbvh4::normalized_sah`] for a 4-wide one. Divide by a binary sweep SAH build's cost
    /// for the thesis's "SAH %".
    pub fn normalized_sah(&self) -> f64 {
        match self {
            Tree::Bvh2(t) => t.sah(),
            Tree::Mbvh4(t) => t.normalized_sah(),
        }
    }

    /// Checks every invariant over `prims` with leaves of at most `max_leaf_size`
    /// ([`validate`] or [`validate_mbvh4`]).
    pub fn validate(&self, prims: &[Aabb], max_leaf_size: u32) -> Result<(), ValidationError> {
        match self {
            Tree::Bvh2(t) => validate(t, prims, max_leaf_size),
            Tree::Mbvh4(t) => validate_mbvh4(t, prims, max_leaf_size),
        }
    }

    /// Refits the boxes to `prims` (same topology; [`refit_bvh2`] or [`refit_mbvh4`]).
    pub fn refit(&mut self, prims: &[Aabb]) -> Result<(), RefitError> {
        match self {
            Tree::Bvh2(t) => refit_bvh2(t, prims),
            Tree::Mbvh4(t) => refit_mbvh4(t, prims),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::soup;
    use crate::{collapse, BinnedSahBuilder, Mbvh4TopDownBuilder};

    #[test]
    fn both_kinds_dispatch_to_their_own_implementation() {
        let prims = soup(3000, 2.0, 4);
        let b = BinnedSahBuilder::default().build(&prims).unwrap();
        let m = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
        let c = collapse(&b).unwrap();
        let tb = Tree::from(b.clone());
        let tm = Tree::from(m.clone());
        assert_eq!(tb.kind(), TreeKind::Bvh2);
        assert_eq!(tm.kind(), TreeKind::Mbvh4);
        assert_eq!((tb.kind().width(), tm.kind().width()), (2, 4));
        assert_eq!((tb.kind().node_bytes(), tm.kind().node_bytes()), (64, 128));
        assert_eq!(tb.normalized_sah(), b.sah());
        assert_eq!(tm.normalized_sah(), m.normalized_sah());
        assert_eq!(tb.bytes(), 64 * b.nodes.len() + 4 * 3000);
        assert_eq!(tm.bytes(), 128 * m.nodes.len() + 4 * 3000);
        assert_eq!(tb.stats(), b.stats());
        assert_eq!(tm.stats().inner_nodes, m.nodes.len());
        assert_eq!(tb.validate(&prims, 8), Ok(()));
        assert_eq!(tm.validate(&prims, 8), Ok(()));
        assert!(tm.validate(&prims[..10], 8).is_err());
        assert!((tb.mean_children() - 2.0).abs() < 1e-12);
        assert!(tm.mean_children() > 3.0 && tm.mean_children() <= 4.0);
        assert_eq!(tb.as_bvh2(), Some(&b));
        assert_eq!(Tree::from(c.clone()).as_mbvh4(), Some(&c));
        assert!(tb.as_mbvh4().is_none() && tm.as_bvh2().is_none());
        assert_eq!(tm.prim_count(), 3000);
        assert_eq!(tm.bounds(), m.bounds);
        // Refit to moved boxes keeps the tree valid over them.
        let moved: Vec<Aabb> = prims
            .iter()
            .map(|p| Aabb::new(p.min * 2.0, p.max * 2.0))
            .collect();
        for mut t in [tb, tm] {
            t.refit(&moved).unwrap();
            assert_eq!(t.validate(&moved, 8), Ok(()));
            assert_eq!(
                t.bounds(),
                moved.iter().fold(Aabb::EMPTY, |a, b| a.union(*b))
            );
        }
        assert_eq!(TreeKind::Mbvh4.to_string(), "Mbvh4");
    }
}
