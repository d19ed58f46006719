//! The tree as the accelerator sees it: node boxes and links for the TRV units' tests, and
//! the memory image the caches read: nodes from address 0 (64 B per BVH node, 128 B per
//! MBVH4 node, [P4] Fig. 1), then the 48-byte precomputed triangles of Wald (2004) in leaf
//! order, packed without padding so that a triangle may straddle two 64-byte lines ([P4]
//! §3's reason for the two-bank primitive cache).

use bvh::{Bvh2, ChildRef, Mbvh4};
use geom::{Aabb, Triangle};

use super::config::{TreeKind, TRIANGLE_BYTES};

/// Nodes of either width.
#[derive(Clone, Debug)]
enum Nodes {
    Bvh2(Vec<bvh::Node>),
    Mbvh4(Vec<bvh::Node4>),
}

/// A tree laid out in the accelerator's memory.
#[derive(Clone, Debug)]
pub struct TreeImage {
    nodes: Nodes,
    /// Triangles in leaf order (entry `e` is the triangle of leaf-table entry `e`).
    triangles: Vec<Triangle>,
    /// Leaf-table entry to primitive id.
    prims: Vec<u32>,
    node_bytes: u64,
    triangle_base: u64,
    root: u32,
}

/// Alignment of the triangle array: a DRAM page (any value that is a multiple of every
/// line size works).
const TRIANGLE_ALIGN: u64 = 4096;

impl TreeImage {
    fn with(nodes: Nodes, prims: &[u32], triangles: &[Triangle], kind: TreeKind) -> Self {
        let count = match &nodes {
            Nodes::Bvh2(n) => n.len(),
            Nodes::Mbvh4(n) => n.len(),
        } as u64;
        let node_bytes = kind.node_bytes() as u64;
        Self {
            nodes,
            triangles: prims.iter().map(|&p| triangles[p as usize]).collect(),
            prims: prims.to_vec(),
            node_bytes,
            triangle_base: (count * node_bytes).div_ceil(TRIANGLE_ALIGN) * TRIANGLE_ALIGN,
            root: 0,
        }
    }

    /// A compressed tree: node `i` of the image is pair `i` of `c` (16 bytes at 6 bits,
    /// [`TreeKind::Cbvh`]), holding the child boxes the TRV unit's decoder produces (the
    /// `cbvh` crate's own decoder, so the boxes are those the software CBVH kernel tests).
    pub fn cbvh(c: &cbvh::Cbvh, triangles: &[Triangle]) -> Result<Self, cbvh::CbvhError> {
        let mut nodes = vec![bvh::Node::EMPTY; c.pairs.len()];
        let mut seen = vec![false; c.pairs.len()];
        let mut stack = vec![(c.root, c.root_ctx)];
        while let Some((idx, ctx)) = stack.pop() {
            let (Some(pair), Some(s)) = (c.pairs.get(idx as usize), seen.get_mut(idx as usize))
            else {
                return Err(cbvh::CbvhError::Corrupt(format!(
                    "pointer {idx} outside the tree"
                )));
            };
            if std::mem::replace(s, true) {
                return Err(cbvh::CbvhError::Corrupt("a pair reached twice".into()));
            }
            let kids = c.decode_children(idx, &ctx)?;
            let mut node = bvh::Node::EMPTY;
            for (k, kid) in kids.iter().enumerate() {
                let Some(kc) = *kid else { continue };
                node.set_child_aabb(k, &kc.aabb());
                node.children[k] = match cbvh::codec::slot_ptr(&pair.slots[k]) {
                    cbvh::codec::ChildPtr::Leaf(first) => {
                        let (f, n) = c.leaf_range(first)?;
                        ChildRef::leaf(f, n)
                    }
                    cbvh::codec::ChildPtr::Inner(p) => {
                        stack.push((p, kc));
                        ChildRef::inner(p)
                    }
                    cbvh::codec::ChildPtr::Empty => ChildRef::EMPTY,
                };
            }
            nodes[idx as usize] = node;
        }
        let prims = c.decode_to_bvh2()?.prim_indices;
        let mut image = Self::with(Nodes::Bvh2(nodes), &prims, triangles, TreeKind::Cbvh);
        image.root = c.root;
        Ok(image)
    }

    /// The root node.
    #[inline]
    pub fn root(&self) -> u32 {
        self.root
    }

    /// A binary tree over `triangles` (its links already checked by the software tracer).
    pub fn bvh2(tree: &Bvh2, triangles: &[Triangle]) -> Self {
        Self::with(
            Nodes::Bvh2(tree.nodes.clone()),
            &tree.prim_indices,
            triangles,
            TreeKind::Bvh2,
        )
    }

    /// A 4-wide tree over `triangles` (its links already checked by the software tracer).
    pub fn mbvh4(tree: &Mbvh4, triangles: &[Triangle]) -> Self {
        Self::with(
            Nodes::Mbvh4(tree.nodes.clone()),
            &tree.prim_indices,
            triangles,
            TreeKind::Mbvh4,
        )
    }

    /// Bytes of one node.
    #[inline]
    pub fn node_bytes(&self) -> u32 {
        self.node_bytes as u32
    }

    /// Byte address of node `n`.
    #[inline]
    pub fn node_addr(&self, n: u32) -> u64 {
        n as u64 * self.node_bytes
    }

    /// Byte address of the triangle of leaf-table entry `e`.
    #[inline]
    pub fn triangle_addr(&self, e: u32) -> u64 {
        self.triangle_base + e as u64 * TRIANGLE_BYTES as u64
    }

    /// The triangle of leaf-table entry `e`.
    #[inline]
    pub fn triangle(&self, e: u32) -> &Triangle {
        &self.triangles[e as usize]
    }

    /// The primitive id of leaf-table entry `e`.
    #[inline]
    pub fn prim_of(&self, e: u32) -> u32 {
        self.prims[e as usize]
    }

    /// Bytes of the memory image (nodes, padding, triangles).
    pub fn bytes(&self) -> u64 {
        self.triangle_base + self.triangles.len() as u64 * TRIANGLE_BYTES as u64
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        match &self.nodes {
            Nodes::Bvh2(n) => n.len(),
            Nodes::Mbvh4(n) => n.len(),
        }
    }

    /// Calls `f(box, child)` for every used child slot of node `n`; returns the number of
    /// box tests the TRV unit performs (all its test units fire on every visit).
    #[inline]
    pub fn for_children(&self, n: u32, mut f: impl FnMut(&Aabb, ChildRef)) -> u64 {
        match &self.nodes {
            Nodes::Bvh2(nodes) => {
                let node = &nodes[n as usize];
                for c in 0..2 {
                    if !node.children[c].is_empty() {
                        f(&node.child_aabb(c), node.children[c]);
                    }
                }
                2
            }
            Nodes::Mbvh4(nodes) => {
                let node = &nodes[n as usize];
                for c in 0..4 {
                    if !node.children[c].is_empty() {
                        f(&node.child_aabb(c), node.children[c]);
                    }
                }
                4
            }
        }
    }
}
