//! Structural validator for [`Bvh2`], run by every builder test.
//!
//! It walks the tree from the root with an explicit stack and checks, in this order per
//! node, that: child indices are in range and never point back to the root; each node is
//! reached exactly once and in depth-first preorder (which also rules out cycles); child
//! boxes are finite and inside the parent's box; leaves are non-empty, within the maximum
//! leaf size and inside the leaf table; every primitive is referenced exactly once and lies
//! inside its leaf's box; empty children only appear at the root. The first violation is
//! returned as a typed [`ValidationError`].

use crate::bvh2::Bvh2;
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
    use ValidationError as E;
    let n_nodes = bvh.nodes.len();
    if n_nodes == 0 {
        return Err(E::NoRoot);
    }
    if bvh.prim_indices.len() != prims.len() {
        return Err(E::LeafTableLength {
            table: bvh.prim_indices.len(),
            prims: prims.len(),
        });
    }
    let root = &bvh.nodes[0];
    let root_union = root.aabb();
    let same = |a: &Aabb, b: &Aabb| (a.is_empty() && b.is_empty()) || a == b;
    if !same(&root_union, &bvh.bounds) {
        return Err(E::BoundsMismatch);
    }
    if root.children[0].is_empty() && !root.children[1].is_empty() {
        return Err(E::RootChildOrder);
    }
    let mut node_seen = vec![false; n_nodes];
    let mut prim_seen = vec![false; prims.len()];
    node_seen[0] = true;
    let mut position = 0usize;
    // (node, its box as stored in the parent)
    let mut stack: Vec<(usize, Aabb)> = vec![(0, bvh.bounds)];
    while let Some((i, parent_box)) = stack.pop() {
        if i != position {
            return Err(E::NotDepthFirst { node: i, position });
        }
        position += 1;
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
            if !b.is_finite() {
                return Err(E::NonFiniteBox { node: i, slot });
            }
            if b.is_empty() || !parent_box.contains(&b) {
                return Err(E::ChildOutsideParent { node: i, slot });
            }
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
                if node_seen[t] {
                    return Err(E::NodeReachedTwice {
                        node: i,
                        slot,
                        target: c.index,
                    });
                }
                node_seen[t] = true;
                stack.push((t, b));
                continue;
            }
            if c.count > max_leaf_size {
                return Err(E::LeafTooLarge {
                    node: i,
                    slot,
                    count: c.count,
                    max: max_leaf_size,
                });
            }
            let first = c.index as usize;
            let end = first + c.count as usize; // both < 2^32: no overflow on 64-bit
            if end > bvh.prim_indices.len() {
                return Err(E::LeafOutOfRange {
                    node: i,
                    slot,
                    first: c.index,
                    count: c.count,
                    len: bvh.prim_indices.len(),
                });
            }
            for (entry, &p) in bvh.prim_indices[first..end].iter().enumerate() {
                let entry = first + entry;
                let Some(pb) = prims.get(p as usize) else {
                    return Err(E::PrimOutOfRange {
                        entry,
                        prim: p,
                        prims: prims.len(),
                    });
                };
                if prim_seen[p as usize] {
                    return Err(E::PrimReferencedTwice { prim: p, entry });
                }
                prim_seen[p as usize] = true;
                if !b.contains(pb) {
                    return Err(E::PrimOutsideLeaf {
                        prim: p,
                        node: i,
                        slot,
                    });
                }
            }
        }
    }
    if let Some(node) = node_seen.iter().position(|&s| !s) {
        return Err(E::Unreachable { node });
    }
    if let Some(p) = prim_seen.iter().position(|&s| !s) {
        return Err(E::PrimMissing { prim: p as u32 });
    }
    Ok(())
}
