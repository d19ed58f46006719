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

/// Nodes per block of a [`Blocks`] store (256 KiB).
const BLOCK_NODES: usize = 1 << 12;

/// A growable node array kept in blocks of [`BLOCK_NODES`] nodes: pushing never moves the
/// nodes already stored, so the store never holds an old and a new copy of itself, which a
/// vector grown by doubling does at every move (issue 34: in a 1-thread binned SAH build
/// that moment, next to the primitive references, was the peak memory). The first block
/// grows as a vector up to [`BLOCK_NODES`], so a small fragment takes little room.
#[derive(Default)]
pub(crate) struct Blocks {
    blocks: Vec<Vec<Node>>,
    len: usize,
}

impl Blocks {
    /// Number of nodes.
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Appends a node.
    #[inline]
    pub fn push(&mut self, node: Node) {
        let b = self.len / BLOCK_NODES;
        if b == self.blocks.len() {
            let room = if b == 0 { 0 } else { BLOCK_NODES };
            self.blocks.push(Vec::with_capacity(room));
        }
        self.blocks[b].push(node);
        self.len += 1;
    }

    /// Frees the spare room of the last block (the first block of a small fragment grows by
    /// doubling, so up to half of it can be spare).
    pub fn shrink_to_fit(&mut self) {
        if let Some(b) = self.blocks.last_mut() {
            b.shrink_to_fit();
        }
    }

    /// The nodes as one vector of exactly their number, freeing each block once copied.
    pub fn into_vec(mut self) -> Vec<Node> {
        if self.blocks.len() <= 1 {
            let mut v = self.blocks.pop().unwrap_or_default();
            v.shrink_to_fit();
            return v;
        }
        let mut out = Vec::with_capacity(self.len);
        for b in self.blocks {
            out.extend_from_slice(&b);
        }
        out
    }
}

impl std::ops::Index<usize> for Blocks {
    type Output = Node;
    #[inline]
    fn index(&self, i: usize) -> &Node {
        &self.blocks[i / BLOCK_NODES][i % BLOCK_NODES]
    }
}

impl std::ops::IndexMut<usize> for Blocks {
    #[inline]
    fn index_mut(&mut self, i: usize) -> &mut Node {
        &mut self.blocks[i / BLOCK_NODES][i % BLOCK_NODES]
    }
}

/// A depth-first node array plus the sub-fragments its fork children refer to.
#[derive(Default)]
pub(crate) struct Frag {
    /// Nodes in depth-first preorder; node 0 is the fragment's root.
    pub nodes: Blocks,
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
    pub fn adopt(&mut self, child: ChildRef, mut sub: Frag) -> ChildRef {
        if child.is_inner() {
            // Complete now: its spare room would only add to the peak of the flatten.
            sub.nodes.shrink_to_fit();
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
            return self.nodes.into_vec();
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

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Aabb, Vec3};

    /// A distinct node per position (its leaf child names the position).
    fn node(i: usize) -> Node {
        let b = Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0));
        Node::new(&b, ChildRef::leaf(i as u32, 1), &b, ChildRef::EMPTY)
    }

    /// Pushes, reads and overwrites across block boundaries agree with a vector, also after
    /// trimming, and the store comes out as that vector, with no spare capacity, for sizes
    /// up to and past one and several blocks.
    #[test]
    fn blocks_behave_as_a_vector() {
        for n in [
            0,
            1,
            5,
            BLOCK_NODES - 1,
            BLOCK_NODES,
            BLOCK_NODES + 1,
            3 * BLOCK_NODES + 7,
        ] {
            let mut b = Blocks::default();
            let mut v = Vec::new();
            for i in 0..n {
                assert_eq!(b.len(), i);
                b.push(node(i));
                v.push(node(i));
                // Overwrite an earlier node, as a builder fills in its parent.
                let j = i / 2;
                b[j] = node(j + 1000);
                v[j] = node(j + 1000);
                assert_eq!(b[i], v[i]);
            }
            assert_eq!(b.len(), n);
            // Trimming keeps the nodes, and the store still grows after it.
            b.shrink_to_fit();
            assert!((0..n).all(|i| b[i] == v[i]), "n = {n}");
            b.push(node(n));
            v.push(node(n));
            let out = b.into_vec();
            assert_eq!(out, v, "n = {n}");
            assert_eq!(out.capacity(), n + 1, "n = {n}");
        }
    }
}
