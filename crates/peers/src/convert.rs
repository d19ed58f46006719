//! Conversion of any peer's binary tree into Arbor's [`Bvh2`].
//!
//! Every peer describes its tree as nodes that are either inner (two children, each with
//! its box) or leaves (a list of primitive indices). [`to_bvh2`] walks such a tree from
//! the root with an explicit stack (peer trees can be deep) and writes Arbor's layout:
//! nodes in depth-first preorder with child 0 at `i + 1`, leaves as contiguous ranges of
//! the leaf table, and a root leaf wrapped in a root node with an empty second child.
//! The peer's own child boxes are kept, so the SAH measured is that of the peer's tree.
//! Malformed peer trees (cycles, more entries than primitives) are reported, not followed.

use crate::PeerError;
use bvh::{Bvh2, ChildRef, Node};
use geom::Aabb;

/// One node of a peer's tree, as seen by the converter.
pub(crate) enum PeerNode<'a, N> {
    /// An inner node: both children with their boxes.
    Inner([(N, Aabb); 2]),
    /// A leaf: the input indices of its primitives.
    Leaf(&'a [u32]),
}

/// Converts a peer tree of `prims` primitives into a [`Bvh2`].
///
/// `root` is the peer's root and `root_box` its box (used only when the root is a leaf);
/// `view` describes one peer node. Fails when the tree references more leaf entries than
/// there are primitives or has more inner nodes than a binary tree over them can (which
/// also stops cycles); the validator catches the remaining errors (duplicates, boxes).
pub(crate) fn to_bvh2<'a, N: Copy>(
    peer: &'static str,
    prims: usize,
    root: N,
    root_box: Aabb,
    view: impl Fn(N) -> PeerNode<'a, N>,
) -> Result<Bvh2, PeerError> {
    if prims == 0 {
        return Ok(Bvh2::empty());
    }
    let malformed = |message: String| PeerError::Malformed { peer, message };
    let mut prim_indices: Vec<u32> = Vec::with_capacity(prims);
    // A binary tree over `prims` leaves entries has at most `prims - 1` inner nodes.
    let max_nodes = prims.max(2) - 1;
    let mut nodes: Vec<Node> = Vec::with_capacity(max_nodes);
    let push_leaf = |ids: &[u32], prim_indices: &mut Vec<u32>| -> Result<ChildRef, PeerError> {
        if ids.is_empty() || prim_indices.len() + ids.len() > prims {
            return Err(malformed(format!(
                "a leaf of {} primitives after {} leaf entries, with {prims} primitives",
                ids.len(),
                prim_indices.len()
            )));
        }
        let first = prim_indices.len() as u32;
        prim_indices.extend_from_slice(ids);
        Ok(ChildRef::leaf(first, ids.len() as u32))
    };

    let (c0, c1) = match view(root) {
        PeerNode::Leaf(ids) => {
            let leaf = push_leaf(ids, &mut prim_indices)?;
            return Ok(Bvh2 {
                nodes: vec![Node::new(&root_box, leaf, &Aabb::EMPTY, ChildRef::EMPTY)],
                prim_indices,
                bounds: root_box,
            });
        }
        PeerNode::Inner([c0, c1]) => (c0, c1),
    };
    let bounds = c0.1.union(c1.1);

    // Stack entries: a peer inner node and the slot of its parent that will point to it.
    let mut stack: Vec<(N, usize, usize)> = Vec::new();
    let visit = |children: [(N, Aabb); 2],
                 nodes: &mut Vec<Node>,
                 stack: &mut Vec<(N, usize, usize)>,
                 prim_indices: &mut Vec<u32>|
     -> Result<(), PeerError> {
        if nodes.len() >= max_nodes {
            return Err(malformed(format!(
                "more than {max_nodes} inner nodes for {prims} primitives (a cycle?)"
            )));
        }
        let me = nodes.len();
        let mut node = Node::new(
            &children[0].1,
            ChildRef::EMPTY,
            &children[1].1,
            ChildRef::EMPTY,
        );
        let mut inner = [None, None];
        for (slot, (child, _)) in children.into_iter().enumerate() {
            match view(child) {
                PeerNode::Leaf(ids) => node.children[slot] = push_leaf(ids, prim_indices)?,
                PeerNode::Inner(_) => inner[slot] = Some(child),
            }
        }
        nodes.push(node);
        // Child 1 below child 0 on the stack: child 0's subtree is written first, at me + 1.
        for slot in [1, 0] {
            if let Some(child) = inner[slot] {
                stack.push((child, me, slot));
            }
        }
        Ok(())
    };
    visit([c0, c1], &mut nodes, &mut stack, &mut prim_indices)?;
    while let Some((n, parent, slot)) = stack.pop() {
        nodes[parent].children[slot] = ChildRef::inner(nodes.len() as u32);
        match view(n) {
            PeerNode::Inner(children) => {
                visit(children, &mut nodes, &mut stack, &mut prim_indices)?
            }
            PeerNode::Leaf(_) => unreachable!("only inner children are pushed"),
        }
    }
    if prim_indices.len() != prims {
        return Err(malformed(format!(
            "{} leaf entries for {prims} primitives",
            prim_indices.len()
        )));
    }
    Ok(Bvh2 {
        nodes,
        prim_indices,
        bounds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::Vec3;

    /// A tiny explicit peer tree: index -> node.
    enum T {
        I(usize, usize),
        L(Vec<u32>),
    }

    fn boxes(n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0)))
            .collect()
    }

    /// Converts a test tree; every node gets the scene box (loose but valid, and defined
    /// even for the cyclic trees of the error tests).
    fn convert(tree: &[T], prims: &[Aabb]) -> Result<Bvh2, PeerError> {
        let scene = prims.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        to_bvh2("test", prims.len(), 0usize, scene, |i| match &tree[i] {
            T::I(a, b) => PeerNode::Inner([(*a, scene), (*b, scene)]),
            T::L(ids) => PeerNode::Leaf(ids),
        })
    }

    #[test]
    fn nested_tree_becomes_preorder_with_contiguous_leaves() {
        let prims = boxes(5);
        let tree = vec![
            T::I(1, 2),
            T::I(3, 4),
            T::I(5, 6),
            T::L(vec![0, 1]),
            T::L(vec![2]),
            T::L(vec![3]),
            T::L(vec![4]),
        ];
        let t = convert(&tree, &prims).unwrap();
        assert_eq!(bvh::validate(&t, &prims, 2), Ok(()));
        assert_eq!(t.nodes.len(), 3);
        assert_eq!(
            t.nodes[0].children,
            [ChildRef::inner(1), ChildRef::inner(2)]
        );
        assert_eq!(
            t.nodes[1].children,
            [ChildRef::leaf(0, 2), ChildRef::leaf(2, 1)]
        );
        assert_eq!(t.prim_indices, vec![0, 1, 2, 3, 4]);
    }

    #[test]
    fn root_leaf_is_wrapped() {
        let prims = boxes(3);
        let t = convert(&[T::L(vec![2, 0, 1])], &prims).unwrap();
        assert_eq!(bvh::validate(&t, &prims, 3), Ok(()));
        assert_eq!(t.nodes.len(), 1);
        assert!(t.nodes[0].children[1].is_empty());
    }

    #[test]
    fn cycles_and_extra_entries_are_errors_not_hangs() {
        let prims = boxes(2);
        let cyclic = vec![T::I(1, 2), T::I(0, 2), T::L(vec![0])];
        assert!(matches!(
            convert(&cyclic, &prims),
            Err(PeerError::Malformed { .. })
        ));
        let extra = vec![T::I(1, 2), T::L(vec![0, 1]), T::L(vec![1])];
        assert!(matches!(
            convert(&extra, &prims),
            Err(PeerError::Malformed { .. })
        ));
        let missing = vec![T::I(1, 2), T::L(vec![0]), T::L(vec![])];
        assert!(matches!(
            convert(&missing, &prims),
            Err(PeerError::Malformed { .. })
        ));
    }
}
