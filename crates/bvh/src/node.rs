//! The 64-byte two-AABB node of \[P2\] §4.1 (Fig. 2).
//!
//! A node does not store its own box: it stores the boxes of its TWO children and, per child,
//! an index and a leaf size. This is what a hardware traversal unit wants: one 64-byte fetch
//! gives both boxes to test (\[P2\] §4.1, "MBVH2" of Afra et al.).
//!
//! Exact byte layout (`#[repr(C)]`, little-endian on every target we build for, no padding):
//!
//! | bytes  | field                | meaning                                   |
//! |--------|----------------------|-------------------------------------------|
//! | 0..12  | `bounds[0][0..3]`    | child 0 box min x, y, z (`f32`)           |
//! | 12..24 | `bounds[0][3..6]`    | child 0 box max x, y, z (`f32`)           |
//! | 24..36 | `bounds[1][0..3]`    | child 1 box min x, y, z (`f32`)           |
//! | 36..48 | `bounds[1][3..6]`    | child 1 box max x, y, z (`f32`)           |
//! | 48..52 | `children[0].index`  | child 0 index (`u32`)                     |
//! | 52..56 | `children[0].count`  | child 0 leaf size (`u32`)                 |
//! | 56..60 | `children[1].index`  | child 1 index (`u32`)                     |
//! | 60..64 | `children[1].count`  | child 1 leaf size (`u32`)                 |
//!
//! Child encoding:
//! - `count == 0`, `index != EMPTY_INDEX`: an inner node; `index` is a node index.
//! - `count > 0`: a leaf; it references `prim_indices[index .. index + count]` of the
//!   [`Bvh2`](crate::Bvh2) leaf table.
//! - `count == 0`, `index == EMPTY_INDEX` (`u32::MAX`): no child. Its box is the empty box
//!   (`min = +inf`, `max = -inf`), which no ray/box slab test can hit, so traversal needs no
//!   special case. Only the root uses it (trees of 0 or 1 leaf, see [`Bvh2`](crate::Bvh2)).

use geom::{Aabb, Vec3};

/// Index value that marks an absent child (together with `count == 0`).
pub const EMPTY_INDEX: u32 = u32::MAX;

/// One child reference of a [`Node`]: an index and a leaf size (0 = inner node).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ChildRef {
    /// Node index (inner child) or first leaf-table entry (leaf child).
    pub index: u32,
    /// Leaf size: number of leaf-table entries; 0 for an inner or empty child.
    pub count: u32,
}

impl ChildRef {
    /// The absent child.
    pub const EMPTY: ChildRef = ChildRef {
        index: EMPTY_INDEX,
        count: 0,
    };

    /// A reference to the inner node at `node`.
    #[inline]
    pub const fn inner(node: u32) -> Self {
        Self {
            index: node,
            count: 0,
        }
    }

    /// A leaf of `count` (> 0) leaf-table entries starting at `first`.
    #[inline]
    pub const fn leaf(first: u32, count: u32) -> Self {
        Self {
            index: first,
            count,
        }
    }

    /// True for a leaf child.
    #[inline]
    pub const fn is_leaf(&self) -> bool {
        self.count > 0
    }

    /// True for the absent child.
    #[inline]
    pub const fn is_empty(&self) -> bool {
        self.count == 0 && self.index == EMPTY_INDEX
    }

    /// True for a child that is an inner node.
    #[inline]
    pub const fn is_inner(&self) -> bool {
        self.count == 0 && self.index != EMPTY_INDEX
    }
}

/// A BVH node of \[P2\] Fig. 2: both child boxes, then both child references (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Child boxes as `[min.x, min.y, min.z, max.x, max.y, max.z]`, child 0 then child 1.
    pub bounds: [[f32; 6]; 2],
    /// Child references, child 0 then child 1.
    pub children: [ChildRef; 2],
}

// [P2] §4.1: "The complete node data structure is 64 bytes long".
const _: () = assert!(std::mem::size_of::<Node>() == 64);
const _: () = assert!(std::mem::align_of::<Node>() == 4);
const _: () = assert!(std::mem::size_of::<ChildRef>() == 8);

// SAFETY: `Node` is `repr(C)` of `f32` and `u32` fields only, without padding (asserted
// above), and all-zero bytes are a valid value of each (0.0 and 0): a zeroed `Node` is
// valid (two zero-size boxes at the origin, both children inner node 0). Builders allocate
// node arrays zeroed (calloc: no fill pass) and then overwrite every node.
unsafe impl bytemuck::Zeroable for Node {}

/// `n` zeroed nodes, to be overwritten (see the `Zeroable` impl): the operating system's
/// zero pages, with no pass over the memory.
pub(crate) fn zeroed_nodes(n: usize) -> Vec<Node> {
    bytemuck::zeroed_vec(n)
}

/// Packs a box into the six floats of a node slot.
#[inline]
fn pack(b: &Aabb) -> [f32; 6] {
    [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z]
}

impl Node {
    /// A node with two empty children (the root of an empty tree).
    pub const EMPTY: Node = Node {
        bounds: [[
            f32::INFINITY,
            f32::INFINITY,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NEG_INFINITY,
            f32::NEG_INFINITY,
        ]; 2],
        children: [ChildRef::EMPTY; 2],
    };

    /// A node from its two children and their boxes.
    #[inline]
    pub fn new(b0: &Aabb, c0: ChildRef, b1: &Aabb, c1: ChildRef) -> Self {
        Self {
            bounds: [pack(b0), pack(b1)],
            children: [c0, c1],
        }
    }

    /// The box of child `i` (0 or 1).
    #[inline]
    pub fn child_aabb(&self, i: usize) -> Aabb {
        let b = &self.bounds[i];
        Aabb::new(Vec3::new(b[0], b[1], b[2]), Vec3::new(b[3], b[4], b[5]))
    }

    /// Sets the box of child `i`.
    #[inline]
    pub fn set_child_aabb(&mut self, i: usize, b: &Aabb) {
        self.bounds[i] = pack(b);
    }

    /// The union of both child boxes (this node's own box).
    #[inline]
    pub fn aabb(&self) -> Aabb {
        self.child_aabb(0).union(self.child_aabb(1))
    }
}

/// What the tree walks (SAH cost, statistics, refit, validation) need from a node of any
/// width: the binary [`Node`], the 4-wide `Node4` and the `W`-wide `WideNode` implement
/// it, so each walk is written once.
pub(crate) trait TreeNode: Copy + Send + Sync {
    /// Child slots per node.
    const WIDTH: usize;
    /// The child references, empty slots included.
    fn child_refs(&self) -> &[ChildRef];
    /// The box stored for child `slot`.
    fn slot_aabb(&self, slot: usize) -> Aabb;
    /// Stores the box of child `slot`.
    fn set_slot_aabb(&mut self, slot: usize, b: &Aabb);
    /// The union of the child boxes (the node's own box).
    fn own_box(&self) -> Aabb;
}

impl TreeNode for Node {
    const WIDTH: usize = 2;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_layout_matches_module_doc() {
        let n = Node::new(
            &Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)),
            ChildRef::inner(7),
            &Aabb::new(Vec3::new(8.0, 9.0, 10.0), Vec3::new(11.0, 12.0, 13.0)),
            ChildRef::leaf(14, 15),
        );
        let base = &n as *const Node as usize;
        let off = |p: *const u8| p as usize - base;
        assert_eq!(off(&n.bounds[0][0] as *const f32 as *const u8), 0);
        assert_eq!(off(&n.bounds[0][3] as *const f32 as *const u8), 12);
        assert_eq!(off(&n.bounds[1][0] as *const f32 as *const u8), 24);
        assert_eq!(off(&n.bounds[1][3] as *const f32 as *const u8), 36);
        assert_eq!(off(&n.children[0].index as *const u32 as *const u8), 48);
        assert_eq!(off(&n.children[0].count as *const u32 as *const u8), 52);
        assert_eq!(off(&n.children[1].index as *const u32 as *const u8), 56);
        assert_eq!(off(&n.children[1].count as *const u32 as *const u8), 60);
        assert_eq!(n.child_aabb(1).max, Vec3::new(11.0, 12.0, 13.0));
        assert_eq!(
            n.aabb(),
            Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(11.0, 12.0, 13.0))
        );
    }

    #[test]
    fn zeroed_nodes_are_zero() {
        let v = zeroed_nodes(3);
        assert_eq!(v.len(), 3);
        let zero = Aabb::new(Vec3::ZERO, Vec3::ZERO);
        assert!(v
            .iter()
            .all(|n| n.child_aabb(1) == zero && n.children == [ChildRef::inner(0); 2]));
    }

    #[test]
    fn child_kinds_are_exclusive() {
        for c in [ChildRef::EMPTY, ChildRef::inner(3), ChildRef::leaf(0, 2)] {
            let kinds = [c.is_empty(), c.is_inner(), c.is_leaf()];
            assert_eq!(kinds.iter().filter(|&&k| k).count(), 1, "{c:?}");
        }
        assert!(Node::EMPTY.child_aabb(0).is_empty());
        assert!(Node::EMPTY.children[1].is_empty());
    }
}
