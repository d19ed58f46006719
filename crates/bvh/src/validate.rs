//! Structural validators: [`validate`] for [`Bvh2`], and one implementation for the wide
//! trees of any width ([`validate_wide`] for the `W`-wide [`WideBvh`] of
//! [`Collapse::collapse_wide`](crate::Collapse::collapse_wide), e.g. the 8-wide trees of
//! the trace crate's `Mbvh8Accel`; [`crate::validate_mbvh4`] for [`crate::Mbvh4`]). Every
//! builder test runs one of them.
//!
//! Each walks the tree from the root with an explicit stack and checks, in this order per
//! node, that: child indices are in range and never point back to the root; each node is
//! reached exactly once and in depth-first preorder (which also rules out cycles); child
//! boxes are finite and inside the parent's box; leaves are non-empty, within the maximum
//! leaf size and inside the leaf table; every primitive is referenced exactly once and lies
//! inside its leaf's box; empty children only appear at the root (binary trees), or, in
//! wide trees, only after the used slots of a node, with the empty box, and with at least
//! two used slots in every node below the root. The first violation is returned as a typed
//! [`ValidationError`] (the same type for every width).

use crate::bvh2::Bvh2;
use crate::collapse::WideBvh;
use crate::node::{ChildRef, TreeNode};
use geom::Aabb;
use thiserror::Error;

/// The first violation of a tree invariant the validator found.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ValidationError {
    /// The node array is empty (a tree always has a root).
    #[error("the tree has no root node")]
    NoRoot,
    /// The leaf table length differs from the number of primitives.
    #[error("leaf table has {table} entries but there are {prims} primitives")]
    LeafTableLength {
        /// Leaf-table length.
        table: usize,
        /// Primitive count.
        prims: usize,
    },
    /// An inner child index is outside the node array (or names the root).
    #[error("node {node} child {slot} points to node {target}, outside 1..{len}")]
    ChildOutOfRange {
        /// Parent node.
        node: usize,
        /// Child slot (0 or 1).
        slot: usize,
        /// Bad target index.
        target: u32,
        /// Node count.
        len: usize,
    },
    /// A node is reached twice (shared subtree or cycle).
    #[error("node {target} is reached a second time (from node {node} child {slot})")]
    NodeReachedTwice {
        /// Parent node of the second reference.
        node: usize,
        /// Child slot.
        slot: usize,
        /// The node reached again.
        target: u32,
    },
    /// Nodes are not stored in depth-first preorder.
    #[error("node {node} is visited at preorder position {position}: nodes are not depth-first")]
    NotDepthFirst {
        /// The node index.
        node: usize,
        /// Its preorder position.
        position: usize,
    },
    /// A node is never reached from the root.
    #[error("node {node} is not reachable from the root")]
    Unreachable {
        /// The unreachable node.
        node: usize,
    },
    /// A child box is NaN/infinite (non-empty children only).
    #[error("node {node} child {slot} has a non-finite box")]
    NonFiniteBox {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// A child box is not inside its parent's box.
    #[error("node {node} child {slot} box is not inside its parent's box")]
    ChildOutsideParent {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// The scene bounds are not the union of the root's child boxes.
    #[error("scene bounds are not the union of the root's child boxes")]
    BoundsMismatch,
    /// An empty child appears below the root, or with a non-empty box.
    #[error(
        "node {node} child {slot} is empty, which is only allowed at the root with an empty box"
    )]
    BadEmptyChild {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// The root has an empty child 0 but a non-empty child 1.
    #[error("the root's child 0 is empty while child 1 is not")]
    RootChildOrder,
    /// A leaf exceeds the configured maximum size.
    #[error("node {node} child {slot} is a leaf of {count} primitives, above the maximum {max}")]
    LeafTooLarge {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
        /// Leaf size.
        count: u32,
        /// Configured maximum.
        max: u32,
    },
    /// A leaf range runs past the end of the leaf table.
    #[error("node {node} child {slot} leaf [{first}, +{count}) runs past the leaf table ({len})")]
    LeafOutOfRange {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
        /// First entry.
        first: u32,
        /// Leaf size.
        count: u32,
        /// Leaf-table length.
        len: usize,
    },
    /// A leaf-table entry names a primitive that does not exist.
    #[error("leaf-table entry {entry} names primitive {prim}, but there are {prims}")]
    PrimOutOfRange {
        /// Leaf-table position.
        entry: usize,
        /// Bad primitive index.
        prim: u32,
        /// Primitive count.
        prims: usize,
    },
    /// A primitive is referenced by two leaf-table entries reached through leaves.
    #[error("primitive {prim} is referenced twice (second time at leaf-table entry {entry})")]
    PrimReferencedTwice {
        /// The primitive.
        prim: u32,
        /// Leaf-table position of the second reference.
        entry: usize,
    },
    /// A primitive is not referenced by any leaf.
    #[error("primitive {prim} is not referenced by any leaf")]
    PrimMissing {
        /// The primitive.
        prim: u32,
    },
    /// A primitive's box is not inside the box of the leaf holding it.
    #[error("primitive {prim} is not inside the box of its leaf (node {node} child {slot})")]
    PrimOutsideLeaf {
        /// The primitive.
        prim: u32,
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
}

/// Checks every invariant of `bvh` built over `prims` with leaves of at most
/// `max_leaf_size` primitives; returns the first violation.
pub fn validate(bvh: &Bvh2, prims: &[Aabb], max_leaf_size: u32) -> Result<(), ValidationError> {
    validate_bvh2(bvh, prims, max_leaf_size, References::Once)
}

/// [`validate`] for a tree with spatial splits ([`crate::SbvhBuilder`]), whose leaf table
/// may name a primitive more than once, each time for a part of it: every primitive is
/// named at least once (the leaf table may be longer than `prims`), and each leaf's box
/// meets the box of every primitive it names (a part lies inside the primitive's box).
/// That the parts cover their primitive is not checked here; the SBVH tests check it by
/// tracing against brute force. The other checks are [`validate`]'s.
pub fn validate_spatial(
    bvh: &Bvh2,
    prims: &[Aabb],
    max_leaf_size: u32,
) -> Result<(), ValidationError> {
    validate_bvh2(bvh, prims, max_leaf_size, References::Parts)
}

/// How a tree's leaves name its primitives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum References {
    /// Each primitive exactly once, inside its leaf's box.
    Once,
    /// Each primitive at least once, its box meeting each leaf box that names it.
    Parts,
}

fn validate_bvh2(
    bvh: &Bvh2,
    prims: &[Aabb],
    max_leaf_size: u32,
    refs: References,
) -> Result<(), ValidationError> {
    use ValidationError as E;
    let Some(root) = bvh.nodes.first() else {
        return Err(E::NoRoot);
    };
    let mut walk = Walk::new(
        bvh.nodes.len(),
        &bvh.prim_indices,
        prims,
        max_leaf_size,
        root.aabb(),
        bvh.bounds,
        refs,
    )?;
    if root.children[0].is_empty() && !root.children[1].is_empty() {
        return Err(E::RootChildOrder);
    }
    while let Some((i, parent_box)) = walk.next_node()? {
        let node = &bvh.nodes[i];
        for slot in [1usize, 0] {
            let c = node.children[slot];
            let b = node.child_aabb(slot);
            if c.is_empty() {
                if i != 0 || !b.is_empty() {
                    return Err(E::BadEmptyChild { node: i, slot });
                }
                continue;
            }
            walk.child(i, slot, c, b, &parent_box)?;
        }
    }
    walk.finish()
}

/// Checks every invariant of a `W`-wide tree over `prims` with leaves of at most
/// `max_leaf_size` primitives; returns the first violation. The checks are those of
/// [`crate::validate_mbvh4`] (one implementation for every width): root present, leaf
/// table as long as `prims`, scene bounds equal to the root's box, nodes reached exactly
/// once in depth-first preorder (no cycles, none unreachable), finite child boxes inside
/// the parent box, leaves non-empty, within the maximum and inside the leaf table, every
/// primitive referenced once and inside its leaf box; an empty slot has the empty box and
/// comes after all used slots, and a node below the root uses at least two slots (both
/// reported as [`ValidationError::BadEmptyChild`]).
pub fn validate_wide<const W: usize>(
    t: &WideBvh<W>,
    prims: &[Aabb],
    max_leaf_size: u32,
) -> Result<(), ValidationError> {
    validate_wide_nodes(&t.nodes, &t.prim_indices, t.bounds, prims, max_leaf_size)
}

/// The wide-tree validator over nodes of any width (`Node4`, `WideNode<W>`): see
/// [`validate_wide`].
pub(crate) fn validate_wide_nodes<N: TreeNode>(
    nodes: &[N],
    prim_indices: &[u32],
    bounds: Aabb,
    prims: &[Aabb],
    max_leaf_size: u32,
) -> Result<(), ValidationError> {
    use ValidationError as E;
    let Some(root) = nodes.first() else {
        return Err(E::NoRoot);
    };
    let mut walk = Walk::new(
        nodes.len(),
        prim_indices,
        prims,
        max_leaf_size,
        root.own_box(),
        bounds,
        References::Once,
    )?;
    while let Some((i, parent_box)) = walk.next_node()? {
        let node = &nodes[i];
        let children = node.child_refs();
        // Slot order: used slots first, then empty ones; two or more below the root.
        let used = children.iter().filter(|c| !c.is_empty()).count();
        for (slot, c) in children.iter().enumerate() {
            if c.is_empty() != (slot >= used) || (c.is_empty() && !node.slot_aabb(slot).is_empty())
            {
                return Err(E::BadEmptyChild { node: i, slot });
            }
        }
        if i != 0 && used < 2 {
            return Err(E::BadEmptyChild {
                node: i,
                slot: used,
            });
        }
        for slot in (0..used).rev() {
            walk.child(i, slot, children[slot], node.slot_aabb(slot), &parent_box)?;
        }
    }
    walk.finish()
}

/// A depth-first validation walk over a tree whose nodes hold child boxes and child
/// references (`Bvh2` and the wide trees alike): the checks of every non-empty child slot, of the
/// leaf table, and of reachability. Children must be visited last slot first, so that the
/// walk's stack reproduces the depth-first storage order.
pub(crate) struct Walk<'a> {
    prim_indices: &'a [u32],
    prims: &'a [Aabb],
    max_leaf_size: u32,
    refs: References,
    node_seen: Vec<bool>,
    prim_seen: Vec<bool>,
    /// (node, its box as stored in the parent)
    stack: Vec<(usize, Aabb)>,
    position: usize,
}

impl<'a> Walk<'a> {
    /// Starts a walk over `n_nodes` nodes (at least one) whose root encloses `root_union`
    /// and whose stored bounds are `bounds`.
    pub(crate) fn new(
        n_nodes: usize,
        prim_indices: &'a [u32],
        prims: &'a [Aabb],
        max_leaf_size: u32,
        root_union: Aabb,
        bounds: Aabb,
        refs: References,
    ) -> Result<Self, ValidationError> {
        use ValidationError as E;
        if n_nodes == 0 {
            return Err(E::NoRoot);
        }
        let table_ok = match refs {
            References::Once => prim_indices.len() == prims.len(),
            References::Parts => prim_indices.len() >= prims.len(),
        };
        if !table_ok {
            return Err(E::LeafTableLength {
                table: prim_indices.len(),
                prims: prims.len(),
            });
        }
        let same = (root_union.is_empty() && bounds.is_empty()) || root_union == bounds;
        if !same {
            return Err(E::BoundsMismatch);
        }
        let mut node_seen = vec![false; n_nodes];
        node_seen[0] = true;
        Ok(Walk {
            prim_indices,
            prims,
            max_leaf_size,
            refs,
            node_seen,
            prim_seen: vec![false; prims.len()],
            stack: vec![(0, bounds)],
            position: 0,
        })
    }

    /// The next node to check with the box its parent stores for it, or None at the end.
    pub(crate) fn next_node(&mut self) -> Result<Option<(usize, Aabb)>, ValidationError> {
        let Some((i, parent_box)) = self.stack.pop() else {
            return Ok(None);
        };
        if i != self.position {
            return Err(ValidationError::NotDepthFirst {
                node: i,
                position: self.position,
            });
        }
        self.position += 1;
        Ok(Some((i, parent_box)))
    }

    /// Checks the non-empty child `c` in `slot` of node `i`, with box `b`, inside
    /// `parent_box`; queues an inner child for its own visit.
    pub(crate) fn child(
        &mut self,
        i: usize,
        slot: usize,
        c: ChildRef,
        b: Aabb,
        parent_box: &Aabb,
    ) -> Result<(), ValidationError> {
        use ValidationError as E;
        if !b.is_finite() {
            return Err(E::NonFiniteBox { node: i, slot });
        }
        if b.is_empty() || !parent_box.contains(&b) {
            return Err(E::ChildOutsideParent { node: i, slot });
        }
        let n_nodes = self.node_seen.len();
        if c.is_inner() {
            let t = c.index as usize;
            if t == 0 || t >= n_nodes {
                return Err(E::ChildOutOfRange {
                    node: i,
                    slot,
                    target: c.index,
                    len: n_nodes,
                });
            }
            if self.node_seen[t] {
                return Err(E::NodeReachedTwice {
                    node: i,
                    slot,
                    target: c.index,
                });
            }
            self.node_seen[t] = true;
            self.stack.push((t, b));
            return Ok(());
        }
        if c.count > self.max_leaf_size {
            return Err(E::LeafTooLarge {
                node: i,
                slot,
                count: c.count,
                max: self.max_leaf_size,
            });
        }
        let first = c.index as usize;
        let end = first + c.count as usize; // both < 2^32: no overflow on 64-bit
        if end > self.prim_indices.len() {
            return Err(E::LeafOutOfRange {
                node: i,
                slot,
                first: c.index,
                count: c.count,
                len: self.prim_indices.len(),
            });
        }
        for (entry, &p) in self.prim_indices[first..end].iter().enumerate() {
            let entry = first + entry;
            let Some(pb) = self.prims.get(p as usize) else {
                return Err(E::PrimOutOfRange {
                    entry,
                    prim: p,
                    prims: self.prims.len(),
                });
            };
            let once = self.refs == References::Once;
            if once && self.prim_seen[p as usize] {
                return Err(E::PrimReferencedTwice { prim: p, entry });
            }
            self.prim_seen[p as usize] = true;
            let inside = if once {
                b.contains(pb)
            } else {
                !b.intersection(*pb).is_empty()
            };
            if !inside {
                return Err(E::PrimOutsideLeaf {
                    prim: p,
                    node: i,
                    slot,
                });
            }
        }
        Ok(())
    }

    /// Ends the walk: every node reached and every primitive referenced.
    pub(crate) fn finish(self) -> Result<(), ValidationError> {
        if let Some(node) = self.node_seen.iter().position(|&s| !s) {
            return Err(ValidationError::Unreachable { node });
        }
        if let Some(p) = self.prim_seen.iter().position(|&s| !s) {
            return Err(ValidationError::PrimMissing { prim: p as u32 });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::node::{ChildRef, Node};
    use crate::testutil::soup;
    use crate::SweepSahBuilder;
    use geom::Vec3;

    fn tree() -> (Bvh2, Vec<Aabb>) {
        let prims = soup(300, 3.0, 5);
        let t = SweepSahBuilder {
            max_leaf_size: 4,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        validate(&t, &prims, 4).unwrap();
        assert!(t.nodes.len() > 10);
        (t, prims)
    }

    /// The last (node, slot) holding a child that satisfies `f` (never the root, whose
    /// boxes are also checked against the scene bounds).
    fn find(t: &Bvh2, f: impl Fn(&ChildRef) -> bool) -> (usize, usize) {
        for (i, n) in t.nodes.iter().enumerate().skip(1).rev() {
            for s in 0..2 {
                if f(&n.children[s]) {
                    return (i, s);
                }
            }
        }
        panic!("no such child");
    }

    /// Applies `corrupt` to a valid tree and returns the validator's verdict.
    fn check(corrupt: impl FnOnce(&mut Bvh2, &mut Vec<Aabb>)) -> ValidationError {
        let (mut t, mut prims) = tree();
        corrupt(&mut t, &mut prims);
        validate(&t, &prims, 4).expect_err("corruption not detected")
    }

    #[test]
    fn catches_missing_root_and_table_length() {
        assert_eq!(check(|t, _| t.nodes.clear()), ValidationError::NoRoot);
        assert!(matches!(
            check(|t, _| {
                t.prim_indices.pop();
            }),
            ValidationError::LeafTableLength { .. }
        ));
    }

    #[test]
    fn catches_bad_primitive_references() {
        // A duplicate inside one leaf (so it is inside the leaf box).
        let e = check(|t, _| {
            let (i, s) = find(t, |c| c.count >= 2);
            let first = t.nodes[i].children[s].index as usize;
            t.prim_indices[first + 1] = t.prim_indices[first];
        });
        assert!(
            matches!(e, ValidationError::PrimReferencedTwice { .. }),
            "{e}"
        );
        let e = check(|t, _| t.prim_indices[3] = 300);
        assert!(
            matches!(e, ValidationError::PrimOutOfRange { prim: 300, .. }),
            "{e}"
        );
        // A leaf shrunk by one entry leaves that primitive unreferenced.
        let e = check(|t, _| {
            let (i, s) = find(t, |c| c.count >= 2);
            t.nodes[i].children[s].count -= 1;
        });
        assert!(matches!(e, ValidationError::PrimMissing { .. }), "{e}");
        let e = check(|t, prims| {
            // A primitive moved far away is outside its leaf box.
            let p = t.prim_indices[0] as usize;
            prims[p] = Aabb::from_point(Vec3::splat(-50.0));
        });
        assert!(matches!(e, ValidationError::PrimOutsideLeaf { .. }), "{e}");
    }

    #[test]
    fn catches_box_violations() {
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            let mut b = t.nodes[i].child_aabb(s);
            b.min.x -= 1000.0;
            t.nodes[i].set_child_aabb(s, &b);
        });
        assert!(
            matches!(e, ValidationError::ChildOutsideParent { .. }),
            "{e}"
        );
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            let mut b = t.nodes[i].child_aabb(s);
            b.max = b.min;
            t.nodes[i].set_child_aabb(s, &b);
        });
        assert!(matches!(e, ValidationError::PrimOutsideLeaf { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].bounds[s][4] = f32::NAN;
        });
        assert!(matches!(e, ValidationError::NonFiniteBox { .. }), "{e}");
        let e = check(|t, _| t.bounds.max.x += 1.0);
        assert_eq!(e, ValidationError::BoundsMismatch);
    }

    #[test]
    fn catches_bad_links_and_cycles() {
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            t.nodes[i].children[s].index = t.nodes.len() as u32;
        });
        assert!(matches!(e, ValidationError::ChildOutOfRange { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            t.nodes[i].children[s].index = 0;
        });
        assert!(
            matches!(e, ValidationError::ChildOutOfRange { target: 0, .. }),
            "{e}"
        );
        // A deep node pointing back at node 1 makes a cycle (and a second reference).
        let e = check(|t, _| {
            let last = t.nodes.len() - 1;
            let mut fixed = t.nodes[last];
            fixed.children[0] = ChildRef::inner(1);
            fixed.set_child_aabb(0, &t.nodes[last].aabb());
            t.nodes[last] = fixed;
        });
        assert!(
            matches!(
                e,
                ValidationError::NodeReachedTwice { target: 1, .. }
                    | ValidationError::ChildOutsideParent { .. }
            ),
            "{e}"
        );
        let e = check(|t, _| t.nodes.push(t.nodes[1]));
        assert!(matches!(e, ValidationError::Unreachable { .. }), "{e}");
        // Swapping the root's children keeps every link valid but breaks preorder.
        let e = check(|t, _| {
            let r = t.nodes[0];
            t.nodes[0] = Node::new(
                &r.child_aabb(1),
                r.children[1],
                &r.child_aabb(0),
                r.children[0],
            );
        });
        assert!(matches!(e, ValidationError::NotDepthFirst { .. }), "{e}");
    }

    #[test]
    fn catches_cycle_with_consistent_boxes() {
        // Node 1 (child 0 of the root) made to point at itself: same box, so only the
        // visit bookkeeping can catch it.
        let (mut t, prims) = tree();
        assert!(t.nodes[0].children[0].is_inner());
        let own = t.nodes[1].aabb();
        t.nodes[1].children[0] = ChildRef::inner(1);
        t.nodes[1].set_child_aabb(0, &own);
        let e = validate(&t, &prims, 4).unwrap_err();
        assert!(
            matches!(e, ValidationError::NodeReachedTwice { target: 1, .. }),
            "{e}"
        );
    }

    #[test]
    fn catches_leaf_violations() {
        let (t, prims) = tree();
        let max = t.stats().max_leaf_size;
        assert!(max >= 2);
        let e = validate(&t, &prims, max - 1).unwrap_err();
        assert!(matches!(e, ValidationError::LeafTooLarge { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].children[s].index = t.prim_indices.len() as u32;
        });
        assert!(matches!(e, ValidationError::LeafOutOfRange { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].children[s] = ChildRef::EMPTY;
        });
        assert!(matches!(e, ValidationError::BadEmptyChild { .. }), "{e}");
    }

    #[test]
    fn root_child_rules() {
        let one = vec![Aabb::new(Vec3::ZERO, Vec3::ONE)];
        let t = Bvh2 {
            nodes: vec![Node::new(
                &Aabb::EMPTY,
                ChildRef::EMPTY,
                &one[0],
                ChildRef::leaf(0, 1),
            )],
            prim_indices: vec![0],
            bounds: one[0],
        };
        assert_eq!(validate(&t, &one, 1), Err(ValidationError::RootChildOrder));
        let e = validate(&Bvh2::empty(), &one, 1).unwrap_err();
        assert!(matches!(e, ValidationError::LeafTableLength { .. }));
        assert_eq!(validate(&Bvh2::empty(), &[], 1), Ok(()));
    }
}

/// [`validate_wide`] on 8-wide trees from [`Collapse::collapse_wide`](crate::Collapse).
#[cfg(test)]
mod wide_tests {
    use super::*;
    use crate::collapse::WideNode;
    use crate::testutil::{adversarial, soup};
    use crate::{BinnedSahBuilder, Collapse, LbvhBuilder};
    use geom::Vec3;
    use ValidationError as E;

    type W8 = WideBvh<8>;

    fn tree() -> (W8, Vec<Aabb>) {
        let prims = soup(400, 3.0, 7);
        let b = BinnedSahBuilder::default().build(&prims).unwrap();
        validate(&b, &prims, 8).unwrap();
        let w = Collapse::default().collapse_wide::<8>(&b).unwrap();
        assert_eq!(validate_wide(&w, &prims, 8), Ok(()));
        assert!(w.nodes.len() > 5);
        (w, prims)
    }

    /// The last (node, slot) below the root holding a child that satisfies `f`.
    fn find(t: &W8, f: impl Fn(&ChildRef) -> bool) -> (usize, usize) {
        for (i, n) in t.nodes.iter().enumerate().skip(1).rev() {
            if let Some(s) = n.children.iter().position(&f) {
                return (i, s);
            }
        }
        panic!("no such child");
    }

    /// Applies `corrupt` to a valid tree and returns the validator's verdict.
    fn check(corrupt: impl FnOnce(&mut W8, &mut Vec<Aabb>)) -> ValidationError {
        let (mut t, mut prims) = tree();
        corrupt(&mut t, &mut prims);
        validate_wide(&t, &prims, 8).expect_err("corruption not detected")
    }

    #[test]
    fn collapsed_trees_of_every_width_pass() {
        for (name, prims) in adversarial() {
            for b in [
                BinnedSahBuilder::default().build(&prims).unwrap(),
                LbvhBuilder::default().build(&prims).unwrap(),
            ] {
                let c = Collapse::default();
                let w = c.collapse_wide::<8>(&b).unwrap();
                assert_eq!(validate_wide(&w, &prims, 8), Ok(()), "{name}");
                let w = c.collapse_wide::<3>(&b).unwrap();
                assert_eq!(validate_wide(&w, &prims, 8), Ok(()), "{name}");
                let w = c.collapse_wide::<16>(&b).unwrap();
                assert_eq!(validate_wide(&w, &prims, 8), Ok(()), "{name}");
            }
        }
        // Merged leaves stay within the merge bound.
        let prims = soup(2000, 2.0, 3);
        let b = LbvhBuilder::default().build(&prims).unwrap();
        let merged = Collapse {
            merge_leaves_up_to: 6,
            ..Default::default()
        }
        .collapse_wide::<8>(&b)
        .unwrap();
        assert_eq!(validate_wide(&merged, &prims, 6), Ok(()));
        let empty = Collapse::default()
            .collapse_wide::<8>(&Bvh2::empty())
            .unwrap();
        assert_eq!(validate_wide(&empty, &[], 1), Ok(()));
    }

    #[test]
    fn catches_root_table_and_bounds() {
        assert_eq!(check(|t, _| t.nodes.clear()), E::NoRoot);
        let e = check(|t, _| {
            t.prim_indices.pop();
        });
        assert!(matches!(e, E::LeafTableLength { .. }), "{e}");
        assert_eq!(check(|t, _| t.bounds.max.y += 1.0), E::BoundsMismatch);
    }

    #[test]
    fn catches_bad_primitive_references() {
        let e = check(|t, _| {
            let (i, s) = find(t, |c| c.count >= 2);
            let first = t.nodes[i].children[s].index as usize;
            t.prim_indices[first + 1] = t.prim_indices[first];
        });
        assert!(matches!(e, E::PrimReferencedTwice { .. }), "{e}");
        let e = check(|t, _| t.prim_indices[5] = 400);
        assert!(matches!(e, E::PrimOutOfRange { prim: 400, .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, |c| c.count >= 2);
            t.nodes[i].children[s].count -= 1;
        });
        assert!(matches!(e, E::PrimMissing { .. }), "{e}");
        let e = check(|t, prims| {
            let p = t.prim_indices[0] as usize;
            prims[p] = Aabb::from_point(Vec3::splat(-50.0));
        });
        assert!(matches!(e, E::PrimOutsideLeaf { .. }), "{e}");
    }

    #[test]
    fn catches_box_violations() {
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            t.nodes[i].boxes[s].min.x -= 1000.0;
        });
        assert!(matches!(e, E::ChildOutsideParent { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            let b = &mut t.nodes[i].boxes[s];
            b.max = b.min;
        });
        assert!(matches!(e, E::PrimOutsideLeaf { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].boxes[s].max.y = f32::NAN;
        });
        assert!(matches!(e, E::NonFiniteBox { .. }), "{e}");
        // An inverted child box (empty) is never inside its parent.
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            let b = &mut t.nodes[i].boxes[s];
            std::mem::swap(&mut b.min, &mut b.max);
        });
        assert!(matches!(e, E::ChildOutsideParent { .. }), "{e}");
    }

    #[test]
    fn catches_bad_links_and_cycles() {
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            t.nodes[i].children[s].index = t.nodes.len() as u32;
        });
        assert!(matches!(e, E::ChildOutOfRange { .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_inner);
            t.nodes[i].children[s].index = 0;
        });
        assert!(matches!(e, E::ChildOutOfRange { target: 0, .. }), "{e}");
        // A node made to point at itself with its own box: only the visit bookkeeping
        // can catch it.
        let e = check(|t, _| {
            let (i, s) = find(t, |c| !c.is_empty());
            let own = t.nodes[i].own_box();
            t.nodes[i].children[s] = ChildRef::inner(i as u32);
            t.nodes[i].boxes[s] = own;
        });
        assert!(matches!(e, E::NodeReachedTwice { .. }), "{e}");
        // A second link to the last node (shared subtree), its box kept consistent.
        let e = check(|t, _| {
            let last = t.nodes.len() - 1;
            let b = t.nodes[last].own_box();
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].children[s] = ChildRef::inner(last as u32);
            t.nodes[i].boxes[s] = b;
        });
        assert!(
            matches!(
                e,
                E::NodeReachedTwice { .. } | E::ChildOutsideParent { .. } | E::NotDepthFirst { .. }
            ),
            "{e}"
        );
        let e = check(|t, _| t.nodes.push(t.nodes[1]));
        assert!(matches!(e, E::Unreachable { .. }), "{e}");
        // Swapping two inner children of the root keeps the links but breaks preorder.
        let e = check(|t, _| {
            let r = &mut t.nodes[0];
            let inner: Vec<usize> = (0..8).filter(|&k| r.children[k].is_inner()).collect();
            assert!(inner.len() >= 2);
            r.children.swap(inner[0], inner[1]);
            r.boxes.swap(inner[0], inner[1]);
        });
        assert!(matches!(e, E::NotDepthFirst { .. }), "{e}");
    }

    #[test]
    fn catches_leaf_and_slot_violations() {
        let (t, prims) = tree();
        let e = validate_wide(&t, &prims, 1).unwrap_err();
        assert!(matches!(e, E::LeafTooLarge { max: 1, .. }), "{e}");
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_leaf);
            t.nodes[i].children[s].index = t.prim_indices.len() as u32;
        });
        assert!(matches!(e, E::LeafOutOfRange { .. }), "{e}");
        // An absent child before a used one.
        let e = check(|t, _| {
            let (i, s) = find(t, |c| !c.is_empty());
            t.nodes[i].children[s] = ChildRef::EMPTY;
            t.nodes[i].boxes[s] = Aabb::EMPTY;
            let used = t.nodes[i].children.iter().filter(|c| !c.is_empty()).count();
            assert!(used >= 1);
            // Move the hole in front of a used slot if it is not already.
            if s >= used {
                t.nodes[i].children.swap(0, s);
                t.nodes[i].boxes.swap(0, s);
            }
        });
        assert!(matches!(e, E::BadEmptyChild { .. }), "{e}");
        // An absent child with a real box.
        let e = check(|t, _| {
            let (i, s) = find(t, ChildRef::is_empty);
            t.nodes[i].boxes[s] = t.nodes[i].boxes[0];
        });
        assert!(matches!(e, E::BadEmptyChild { .. }), "{e}");
        // A node below the root with a single used slot.
        let (t, prims) = tree();
        let mut c = t.clone();
        let (i, _) = find(&c, |_| true);
        let keep = c.nodes[i];
        c.nodes[i] = WideNode {
            boxes: [Aabb::EMPTY; 8],
            children: [ChildRef::EMPTY; 8],
        };
        c.nodes[i].boxes[0] = keep.boxes[0];
        c.nodes[i].children[0] = keep.children[0];
        let e = validate_wide(&c, &prims, 8).unwrap_err();
        assert!(matches!(e, E::BadEmptyChild { slot: 1, .. }), "{e}");
    }
}
