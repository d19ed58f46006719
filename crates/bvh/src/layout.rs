//! The depth-first preorder layout that every tree writer of the crate shares.
//!
//! All node arrays of the crate ([`Bvh2`](crate::Bvh2), [`Mbvh4`](crate::Mbvh4),
//! [`WideBvh`](crate::WideBvh)) are stored in depth-first preorder, slot 0 first. Writers
//! whose source is another tree (parallel build fragments, the HLBVH top tree over its
//! cells, the ATRBVH and reinsertion working trees, the collapses to wide nodes) all lay it
//! out with [`try_preorder`]: an explicit stack of sources still to place, each with the
//! (parent, slot) whose child reference becomes its position once it is written. The
//! writers differ only in how one source becomes one node, which they pass in.

use crate::collapse::WideNode;
use crate::mbvh4::Node4;
use crate::node::{ChildRef, Node};
use std::convert::Infallible;

/// A node type with child references that the layout patches.
pub(crate) trait Slots {
    /// The node's child references, by slot.
    fn slots_mut(&mut self) -> &mut [ChildRef];
}

impl Slots for Node {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

impl Slots for Node4 {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

impl<const W: usize> Slots for WideNode<W> {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

/// Appends the tree below source `root` to `out` in depth-first preorder (slot 0 first).
///
/// `visit(s, out, kids)` appends the node of source `s` at position `out.len()` (it may
/// append more after it: a block it lays out itself) and pushes onto `kids`, in increasing
/// slot order, `(slot, source)` for each child still to lay out below that node; leaf and
/// empty children are final in the node it wrote. Each such child is laid out right after
/// the subtree of the slot before it, and the node's reference in that slot is set to the
/// child's position. The first error of `visit` stops the layout and is returned.
pub(crate) fn try_preorder<N: Slots, S, E>(
    root: S,
    out: &mut Vec<N>,
    mut visit: impl FnMut(S, &mut Vec<N>, &mut Vec<(usize, S)>) -> Result<(), E>,
) -> Result<(), E> {
    let mut stack: Vec<(S, Option<(usize, usize)>)> = vec![(root, None)];
    let mut kids: Vec<(usize, S)> = Vec::new();
    while let Some((s, patch)) = stack.pop() {
        let at = out.len();
        if let Some((p, slot)) = patch {
            out[p].slots_mut()[slot] = ChildRef::inner(at as u32);
        }
        visit(s, out, &mut kids)?;
        debug_assert!(out.len() > at, "visit must write the node");
        stack.extend(kids.drain(..).rev().map(|(slot, c)| (c, Some((at, slot)))));
    }
    Ok(())
}

/// [`try_preorder`] for a `visit` that cannot fail.
pub(crate) fn preorder<N: Slots, S>(
    root: S,
    out: &mut Vec<N>,
    mut visit: impl FnMut(S, &mut Vec<N>, &mut Vec<(usize, S)>),
) {
    let r: Result<(), Infallible> = try_preorder(root, out, |s, o, k| {
        visit(s, o, k);
        Ok(())
    });
    let Ok(()) = r;
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Aabb, Vec3};

    /// A source tree given as child lists (`None`: a leaf of that id) is laid out in
    /// preorder: positions, patched references and the order of visits.
    #[test]
    fn lays_out_in_preorder_and_patches_children() {
        // 0 -> (1, leaf 7), 1 -> (2, 3), 2 -> (leaf 8, leaf 9), 3 -> (leaf 5, 4), 4 -> leaves.
        let kids: [[Option<u32>; 2]; 5] = [
            [Some(1), None],
            [Some(2), Some(3)],
            [None, None],
            [None, Some(4)],
            [None, None],
        ];
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let mut visited = Vec::new();
        let mut out: Vec<Node> = Vec::new();
        preorder(0u32, &mut out, |s, out, k| {
            visited.push(s);
            let mut refs = [ChildRef::leaf(s, 1); 2];
            for (slot, c) in kids[s as usize].iter().enumerate() {
                if let Some(c) = *c {
                    refs[slot] = ChildRef::EMPTY;
                    k.push((slot, c));
                }
            }
            out.push(Node::new(&b, refs[0], &b, refs[1]));
        });
        assert_eq!(visited, [0, 1, 2, 3, 4]);
        assert_eq!(out[0].children[0], ChildRef::inner(1));
        assert_eq!(out[1].children, [ChildRef::inner(2), ChildRef::inner(3)]);
        assert_eq!(out[3].children[1], ChildRef::inner(4));
        assert_eq!(out[3].children[0], ChildRef::leaf(3, 1));
        assert_eq!(out.len(), 5);
        assert_eq!(out[4].children, [ChildRef::leaf(4, 1); 2]);
    }

    /// The first error stops the layout.
    #[test]
    fn an_error_stops_the_layout() {
        let mut out: Vec<Node> = Vec::new();
        let mut n = 0;
        let r = try_preorder(0u32, &mut out, |s, out, k| {
            n += 1;
            if s == 2 {
                return Err(s);
            }
            out.push(Node::EMPTY);
            k.push((0, s + 1));
            Ok(())
        });
        assert_eq!((r, n, out.len()), (Err(2), 3, 2));
    }
}
