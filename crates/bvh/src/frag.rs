//! Fragments: how the parallel top-down builders emit nodes deterministically.
//!
//! A sequential recursion emits nodes in depth-first preorder simply by pushing the parent
//! before recursing into its children. Two subtrees built in parallel (`rayon::join`) cannot
//! share one vector without making the node order depend on scheduling, so each parallel
//! branch writes its own [`Frag`]; a parent refers to a child fragment with [`FORK_BIT`]
//! set in the child index. [`Frag::flatten`] then lays all fragments out in one depth-first
//! pass, so the result is identical for any thread count. A single-threaded build has no
//! forks and its only fragment is already the final node array (no copy).

use crate::layout::preorder;
use crate::node::{ChildRef, Node};

/// Set in an inner child's index when it names a sub-fragment rather than a local node.
pub(crate) const FORK_BIT: u32 = 1 << 31;

/// A depth-first node array plus the sub-fragments its fork children refer to.
#[derive(Default)]
pub(crate) struct Frag {
    /// Nodes in depth-first preorder; node 0 is the fragment's root.
    pub nodes: Vec<Node>,
    /// Fragments referenced by `FORK_BIT | k` child indices.
    pub subs: Vec<Frag>,
}

impl Frag {
    /// Total node count over this fragment and all sub-fragments.
    fn total_len(&self) -> usize {
        self.nodes.len() + self.subs.iter().map(Frag::total_len).sum::<usize>()
    }

    /// Appends a child fragment built in parallel and returns the child reference to store
    /// in the parent: a leaf stays a leaf, an inner root becomes a fork reference.
    pub fn adopt(&mut self, child: ChildRef, sub: Frag) -> ChildRef {
        if child.is_inner() {
            debug_assert_eq!(child.index, 0, "a fragment's root is its node 0");
            self.subs.push(sub);
            ChildRef::inner(FORK_BIT | (self.subs.len() as u32 - 1))
        } else {
            child
        }
    }

    /// Lays out all fragments as one depth-first (preorder, child 0 first) node array.
    pub fn flatten(self) -> Vec<Node> {
        if self.subs.is_empty() {
            return self.nodes;
        }
        let mut out: Vec<Node> = Vec::with_capacity(self.total_len());
        preorder((&self, 0u32), &mut out, |(frag, local), out, kids| {
            let node = frag.nodes[local as usize];
            out.push(node);
            for (slot, c) in node.children.iter().enumerate() {
                if c.is_inner() {
                    kids.push(if c.index & FORK_BIT != 0 {
                        (slot, (&frag.subs[(c.index & !FORK_BIT) as usize], 0))
                    } else {
                        (slot, (frag, c.index))
                    });
                }
            }
        });
        out
    }
}
