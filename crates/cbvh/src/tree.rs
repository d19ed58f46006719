//! The compressed tree: node pairs, the root's context, the primitive-id array; its decode
//! to a full-precision [`Bvh2`] of the same topology, and the checks that a decoded tree
//! encloses the original geometry (\[P3\] §5.5: "decompressing our bounds to single
//! precision always gave AABBs that enclose the uncompressed AABB").

use crate::codec::{decode_pair, slot_ptr, ChildPtr, Ctx};
use crate::error::CbvhError;
use crate::format::{pair_bytes, NodePair, LEAF_END};
use crate::grid::Params;
use bvh::{Bvh2, ChildRef, Node};
use geom::{Aabb, Vec3};

/// A compressed BVH.
#[derive(Clone, Debug, PartialEq)]
pub struct Cbvh {
    /// Quantization parameters (coordinate bits, minimum scale, encoding).
    pub params: Params,
    /// Node pairs; pointers index this array.
    pub pairs: Vec<NodePair>,
    /// Index of the root's node pair.
    pub root: u32,
    /// Context of the root (stored at full precision beside the tree).
    pub root_ctx: Ctx,
    /// Primitive-id array: primitive indices, the last of each leaf flagged [`LEAF_END`].
    pub prim_ids: Vec<u32>,
}

/// Builds the primitive-id array of a [`Bvh2`]: its leaf table with each leaf's last entry
/// flagged.
pub(crate) fn prim_ids_of(bvh: &Bvh2) -> Result<Vec<u32>, CbvhError> {
    if bvh.prim_indices.len() >= LEAF_END as usize {
        return Err(CbvhError::TooLarge {
            what: "primitive",
            count: bvh.prim_indices.len(),
        });
    }
    let mut ids = bvh.prim_indices.clone();
    for n in &bvh.nodes {
        for c in &n.children {
            if c.is_leaf() {
                let last = (c.index + c.count - 1) as usize;
                let id = ids
                    .get_mut(last)
                    .ok_or_else(|| CbvhError::Corrupt("leaf outside the leaf table".into()))?;
                *id |= LEAF_END;
            }
        }
    }
    Ok(ids)
}

/// The leaf starting at index `first` of the primitive-id array `ids` (it ends at the first
/// id flagged [`LEAF_END`]): `(first, count)`.
pub(crate) fn leaf_range_in(ids: &[u32], first: u32) -> Result<(u32, u32), CbvhError> {
    let mut i = first as usize;
    loop {
        let id = *ids
            .get(i)
            .ok_or_else(|| CbvhError::Corrupt(format!("leaf at {first} has no end")))?;
        if id & LEAF_END != 0 {
            return Ok((first, (i - first as usize + 1) as u32));
        }
        i += 1;
    }
}

/// Where a decoded node's parent links to it: (parent node, child slot).
type Link = (usize, usize);

impl Cbvh {
    /// Bytes of the packed node pairs (16 per pair at 6 bits).
    pub fn node_bytes(&self) -> u64 {
        (self.pairs.len() * pair_bytes(self.params.bits)) as u64
    }

    /// The node pairs packed in the bit layout of [`crate::format`].
    pub fn to_bytes(&self) -> Result<Vec<u8>, CbvhError> {
        let mut out = Vec::with_capacity(self.pairs.len() * pair_bytes(self.params.bits));
        for p in &self.pairs {
            p.pack_into(self.params.bits, &mut out)?;
        }
        Ok(out)
    }

    /// The leaf starting at primitive-id index `first`: `(first, count)`.
    pub fn leaf_range(&self, first: u32) -> Result<(u32, u32), CbvhError> {
        leaf_range_in(&self.prim_ids, first)
    }

    /// The decoded contexts of the children of pair `idx` decoded in context `ctx`.
    pub fn decode_children(&self, idx: u32, ctx: &Ctx) -> Result<[Option<Ctx>; 2], CbvhError> {
        let pair = self
            .pairs
            .get(idx as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("pointer {idx} outside the tree")))?;
        Ok(decode_pair(pair, ctx, &self.params))
    }

    /// The tree with decoded boxes as a [`Bvh2`] of the same topology (nodes renumbered
    /// in depth-first preorder, leaves referencing the same primitive ids), for measuring
    /// tree quality with the full-precision tools.
    pub fn decode_to_bvh2(&self) -> Result<Bvh2, CbvhError> {
        self.root_ctx.check()?;
        let mut nodes: Vec<Node> = Vec::with_capacity(self.pairs.len());
        // An explicit stack (a chain of pairs as long as the tree must not overflow the
        // thread's stack): (pair, its context, where its parent links to it). Children are
        // pushed last slot first, so they are numbered in depth-first preorder.
        let mut stack: Vec<(u32, Ctx, Option<Link>)> = vec![(self.root, self.root_ctx, None)];
        let mut leaf_entries = 0usize;
        while let Some((idx, ctx, parent)) = stack.pop() {
            // Each pair decodes to one node: more nodes than pairs means a pair was
            // reached twice (a cycle, or a shared subtree).
            if nodes.len() >= self.pairs.len() {
                return Err(CbvhError::Corrupt("pointer cycle".into()));
            }
            let at = nodes.len();
            if let Some((p, c)) = parent {
                nodes[p].children[c] = ChildRef::inner(at as u32);
            }
            let kids = self.decode_children(idx, &ctx)?;
            let pair = self.pairs[idx as usize];
            let mut node = Node::EMPTY;
            let mut inner = Vec::new();
            for (c, k) in kids.into_iter().enumerate() {
                let Some(k) = k else { continue };
                node.set_child_aabb(c, &k.aabb());
                node.children[c] = match slot_ptr(&pair.slots[c]) {
                    ChildPtr::Leaf(first) => {
                        let (f, n) = self.leaf_range(first)?;
                        // Leaves partition the primitive-id array: more entries in
                        // leaves than in the array means leaves overlap (and would
                        // multiply the work of everything that walks the leaves).
                        leaf_entries += n as usize;
                        if leaf_entries > self.prim_ids.len() {
                            return Err(CbvhError::Corrupt(format!(
                                "leaves cover more than the {} primitive ids (they overlap)",
                                self.prim_ids.len()
                            )));
                        }
                        ChildRef::leaf(f, n)
                    }
                    ChildPtr::Inner(p) => {
                        inner.push((p, k, Some((at, c))));
                        ChildRef::EMPTY // linked when the child is numbered
                    }
                    ChildPtr::Empty => ChildRef::EMPTY,
                };
            }
            nodes.push(node);
            stack.extend(inner.into_iter().rev());
        }
        let bounds = nodes[0].aabb();
        Ok(Bvh2 {
            nodes,
            prim_indices: self.prim_ids.iter().map(|&i| i & !LEAF_END).collect(),
            bounds,
        })
    }
}

impl Cbvh {
    /// The full-precision box of each child of each node pair, indexed like
    /// [`Cbvh::pairs`]: the union of the boxes `prims` (by primitive id) of the primitives
    /// below the child, which is the child's box in the uncompressed tree the CBVH was
    /// made from (builders and refit make tight boxes). The empty child gets
    /// [`Aabb::EMPTY`]. This is the "original box" of the \[P3\] §5.5 watertightness check
    /// ([`interval_encloses`]), for a tracer that knows only the compressed tree.
    pub fn original_child_boxes(&self, prims: &[Aabb]) -> Result<Vec<[Aabb; 2]>, CbvhError> {
        let mut out = vec![[Aabb::EMPTY; 2]; self.pairs.len()];
        // Iterative postorder: (pair, children done); a pair is finished after both of
        // its inner children, so their boxes are ready.
        let mut stack = vec![(self.root, false)];
        let mut steps = 0usize;
        while let Some((idx, expanded)) = stack.pop() {
            steps += 1;
            if steps > 2 * self.pairs.len() {
                return Err(CbvhError::Corrupt("pointer cycle".into()));
            }
            let pair = self
                .pairs
                .get(idx as usize)
                .ok_or_else(|| CbvhError::Corrupt(format!("pointer {idx} outside the tree")))?;
            if !expanded {
                stack.push((idx, true));
                for s in &pair.slots {
                    if let ChildPtr::Inner(k) = slot_ptr(s) {
                        stack.push((k, false));
                    }
                }
                continue;
            }
            for c in 0..2 {
                out[idx as usize][c] = match slot_ptr(&pair.slots[c]) {
                    ChildPtr::Empty => Aabb::EMPTY,
                    ChildPtr::Inner(k) => {
                        let [a, b] = out.get(k as usize).ok_or_else(|| {
                            CbvhError::Corrupt(format!("pointer {k} outside the tree"))
                        })?;
                        a.union(*b)
                    }
                    ChildPtr::Leaf(first) => {
                        let (f, n) = self.leaf_range(first)?;
                        let mut b = Aabb::EMPTY;
                        for &id in &self.prim_ids[f as usize..(f + n) as usize] {
                            let id = id & !LEAF_END;
                            b = b.union(*prims.get(id as usize).ok_or_else(|| {
                                CbvhError::Corrupt(format!("primitive {id} missing"))
                            })?);
                        }
                        b
                    }
                };
            }
        }
        Ok(out)
    }
}

/// Checks that every child box of `decoded` encloses the union of the boxes of the
/// primitives below it (`prims` indexed by the leaf table). Returns the number of child
/// boxes that do not (0 for a correct tree).
pub fn enclosure_violations(decoded: &Bvh2, prims: &[Aabb]) -> Result<u64, CbvhError> {
    let mut bad = 0u64;
    subtree_box(decoded, 0, prims, &mut bad, 0)?;
    Ok(bad)
}

fn subtree_box(
    t: &Bvh2,
    i: usize,
    prims: &[Aabb],
    bad: &mut u64,
    depth: usize,
) -> Result<Aabb, CbvhError> {
    let n = t
        .nodes
        .get(i)
        .ok_or_else(|| CbvhError::Corrupt(format!("node {i} outside the tree")))?;
    if depth > t.nodes.len() {
        return Err(CbvhError::Corrupt("cycle".into()));
    }
    let mut total = Aabb::EMPTY;
    for c in 0..2 {
        let r = n.children[c];
        let b = if r.is_leaf() {
            let mut b = Aabb::EMPTY;
            for k in r.index..r.index + r.count {
                let id = *t
                    .prim_indices
                    .get(k as usize)
                    .ok_or_else(|| CbvhError::Corrupt("leaf outside the leaf table".into()))?;
                b = b.union(
                    *prims
                        .get(id as usize)
                        .ok_or_else(|| CbvhError::Corrupt(format!("primitive {id} missing")))?,
                );
            }
            b
        } else if r.is_inner() {
            subtree_box(t, r.index as usize, prims, bad, depth + 1)?
        } else {
            continue;
        };
        if !n.child_aabb(c).contains(&b) {
            *bad += 1;
        }
        total = total.union(b);
    }
    Ok(total)
}

/// Counts child boxes of `a` that do not enclose the same child box of `b` (two trees of
/// the same topology, e.g. a bottom-up and a top-down compression decoded to [`Bvh2`]).
pub fn boxes_not_enclosing(a: &Bvh2, b: &Bvh2) -> Result<u64, CbvhError> {
    if a.nodes.len() != b.nodes.len() {
        return Err(CbvhError::Corrupt("trees differ in node count".into()));
    }
    let mut bad = 0;
    for (x, y) in a.nodes.iter().zip(&b.nodes) {
        if x.children != y.children {
            return Err(CbvhError::Corrupt("trees differ in topology".into()));
        }
        for c in 0..2 {
            if !y.children[c].is_empty() && !x.child_aabb(c).contains(&y.child_aabb(c)) {
                bad += 1;
            }
        }
    }
    Ok(bad)
}

/// Parametric slab interval `(t_near, t_far)` of a ray against a box, in `f64` (exact
/// enough to compare two boxes' intervals; `None` when the ray misses the box in
/// `t_min..t_max`).
pub fn slab_interval(
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    b: &Aabb,
) -> Option<(f64, f64)> {
    if b.is_empty() {
        return None;
    }
    let (mut tn, mut tf) = (t_min as f64, t_max as f64);
    for i in 0..3 {
        let o = origin[i] as f64;
        let d = dir[i] as f64;
        let (lo, hi) = (b.min[i] as f64, b.max[i] as f64);
        if d == 0.0 {
            if o < lo || o > hi {
                return None;
            }
            continue;
        }
        let (mut t0, mut t1) = ((lo - o) / d, (hi - o) / d);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        tn = tn.max(t0);
        tf = tf.min(t1);
    }
    (tn <= tf).then_some((tn, tf))
}

/// The watertightness criterion of \[P3\] §5.5 for one box test: the decoded box's
/// parametric interval encloses the original box's (trivially true when the ray misses the
/// original). To be wired into a tracer that visits (original, decoded) box pairs.
pub fn interval_encloses(
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    original: &Aabb,
    decoded: &Aabb,
) -> bool {
    match slab_interval(origin, dir, t_min, t_max, original) {
        None => true,
        Some((n0, f0)) => match slab_interval(origin, dir, t_min, t_max, decoded) {
            None => false,
            Some((n1, f1)) => n1 <= n0 && f1 >= f0,
        },
    }
}

/// [`interval_encloses`] for both child boxes of a node: `original` is a node of the
/// uncompressed tree, `decoded` the same node of [`Cbvh::decode_to_bvh2`] (same preorder
/// index when the CBVH was compressed from that tree). For a tracer that visits both trees
/// in lockstep (\[P3\] §5.5).
pub fn node_intervals_enclose(
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    original: &Node,
    decoded: &Node,
) -> [bool; 2] {
    [0, 1].map(|c| {
        interval_encloses(
            origin,
            dir,
            t_min,
            t_max,
            &original.child_aabb(c),
            &decoded.child_aabb(c),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bottomup::{compress_bottomup, StreamConfig};
    use crate::topdown::compress_topdown;

    /// The original child boxes recomputed from the primitives are the uncompressed
    /// tree's, pair for pair (top-down keeps the numbering; bottom-up is matched through
    /// its decoded tree, which is in preorder like the builder's).
    #[test]
    #[allow(clippy::needless_range_loop)] // two child slots of parallel arrays
    fn original_child_boxes_are_the_uncompressed_boxes() {
        let prims = crate::bottomup::tests::soup(3000, 5, false);
        let bvh = crate::study::paper_lbvh().build(&prims).unwrap();
        let (td, _) = compress_topdown(&bvh, &Params::default()).unwrap();
        let orig = td.original_child_boxes(&prims).unwrap();
        for (i, n) in bvh.nodes.iter().enumerate() {
            for c in 0..2 {
                if !n.children[c].is_empty() {
                    assert_eq!(orig[i][c], n.child_aabb(c), "pair {i} child {c}");
                }
            }
        }
        let (bu, _) = compress_bottomup(&bvh, &StreamConfig::default()).unwrap();
        let orig = bu.original_child_boxes(&prims).unwrap();
        let mut found = 0;
        // Walk both trees from their roots in lockstep.
        let mut stack = vec![(0u32, bu.root)];
        while let Some((n, p)) = stack.pop() {
            let node = &bvh.nodes[n as usize];
            for c in 0..2 {
                if node.children[c].is_empty() {
                    continue;
                }
                assert_eq!(orig[p as usize][c], node.child_aabb(c));
                found += 1;
                if let ChildPtr::Inner(k) = slot_ptr(&bu.pairs[p as usize].slots[c]) {
                    stack.push((node.children[c].index, k));
                }
            }
        }
        assert_eq!(found, 2 * bvh.nodes.len());
        // A primitive id beyond the boxes given is an error, not a panic.
        assert!(td.original_child_boxes(&prims[..10]).is_err());
    }
}
