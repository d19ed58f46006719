//! Plane-only k-d nodes (issue 18, part 3): the inner nodes of a [`PointTree`] stored as
//! a split plane, an axis and two child references in one 16-byte slot ([`PlaneNode`]),
//! with no boxes, and kNN and radius queries that prune by plane distance.
//!
//! # Format
//! A [`PlaneNode`] is `plane` (f32), `meta` (bits 0-1 the axis, [`NO_AXIS`] for a split
//! of one grid cell by index; bits 2-12 and 13-23 the point counts of the left and right
//! child when it is a leaf, 0 when it is an inner node) and the two references `left` and
//! `right` (an inner node's index in the node array, or a leaf's first sorted point).
//! Leaves are not nodes: a leaf of up to [`MAX_PLANE_LEAF`] points is its parent's
//! reference. Nodes are in the [`PointTree`]'s depth-first order (its inner nodes), the
//! root first; a tree that is one leaf has no node. The tree keeps the root's box (the
//! 32-byte root record of the MergeTree output) to start the queries from.
//!
//! # Queries
//! Depth-first, the near side of each plane first, as [`PointTree::knn`]. Each subtree on
//! the stack carries a *clamp point* `c`: the root's is `q` clamped to the root's box;
//! the near child keeps its parent's, the far child's is its parent's with the split axis
//! set to the plane (the cell of the far side is bounded by the plane on `q`'s side, so
//! this is the distance to the subtree's cell, Arya and Mount's incremental distance). The
//! bound `dist2(q, c)` sums the same squares in the same order as a point's distance, and
//! every point `x` of the subtree lies beyond `c` from `q` on every axis (`|q_a - x_a| >=
//! |q_a - c_a|`, and rounding is monotone), so the bound never exceeds a point's computed
//! distance and pruning when it exceeds the k-th best is exact: the results equal
//! [`crate::knn_brute`]'s, ties by index. Index splits ([`NO_AXIS`]) give both children
//! their parent's bound, the left child first.

use crate::points::{
    begin_query, box_dist2, dist2, unkey, within_leaf, Nearest, PointError, PointTree, QueryStats,
    NO_AXIS,
};
use geom::{Aabb, Vec3};

/// Bytes of one [`PlaneNode`].
pub const PLANE_NODE_BYTES: usize = 16;

/// Largest leaf a [`PlaneNode`] reference holds (an 11-bit count).
pub const MAX_PLANE_LEAF: u32 = (1 << 11) - 1;

/// A plane-only k-d node: the split plane, the axis and two child references in 16 bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct PlaneNode {
    /// The split plane on the axis (left points `<=`, right points `>=`; unused with
    /// [`NO_AXIS`]).
    pub plane: f32,
    /// Axis (bits 0-1) and the leaf counts of the left (bits 2-12) and right (bits 13-23)
    /// child, 0 for an inner child.
    pub meta: u32,
    /// Left child: an inner node's index, or a leaf's first sorted point.
    pub left: u32,
    /// Right child, as `left`.
    pub right: u32,
}

const _: () = assert!(std::mem::size_of::<PlaneNode>() == PLANE_NODE_BYTES);

/// A child reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ref {
    Node(u32),
    Leaf { first: u32, count: u32 },
}

impl PlaneNode {
    /// The split axis (0 x, 1 y, 2 z, or [`NO_AXIS`]).
    pub fn axis(&self) -> u8 {
        (self.meta & 3) as u8
    }

    /// Points of child `side` (0 left, 1 right) if it is a leaf, 0 if it is a node.
    pub fn leaf_count(&self, side: usize) -> u32 {
        (self.meta >> (2 + 11 * side)) & MAX_PLANE_LEAF
    }

    fn child(&self, side: usize) -> Ref {
        let r = if side == 0 { self.left } else { self.right };
        match self.leaf_count(side) {
            0 => Ref::Node(r),
            count => Ref::Leaf { first: r, count },
        }
    }
}

/// A [`PointTree`] with plane-only nodes (module doc): the nodes, the root's box, and the
/// tree's sorted points and ids.
#[derive(Clone, Debug)]
pub struct PlaneKdTree<'a> {
    tree: &'a PointTree,
    nodes: Vec<PlaneNode>,
    bounds: Aabb,
}

impl<'a> PlaneKdTree<'a> {
    /// The plane-only form of `tree`. Errors: a leaf size above [`MAX_PLANE_LEAF`].
    pub fn new(tree: &'a PointTree) -> Result<Self, PointError> {
        if tree.max_leaf() > MAX_PLANE_LEAF {
            return Err(PointError::Invalid(format!(
                "plane-only nodes hold leaves of at most {MAX_PLANE_LEAF} points, not {}",
                tree.max_leaf()
            )));
        }
        let src = tree.nodes();
        // Index of every inner node among the inner nodes (depth-first order kept).
        let mut at = vec![u32::MAX; src.len()];
        let mut next = 0u32;
        for (i, n) in src.iter().enumerate() {
            if !n.is_leaf() {
                at[i] = next;
                next += 1;
            }
        }
        let nodes = src
            .iter()
            .filter(|n| !n.is_leaf())
            .map(|n| {
                let mut meta = n.axis as u32 & 3;
                let mut refs = [0u32; 2];
                for (side, c) in [n.left, n.right].into_iter().enumerate() {
                    let child = &src[c as usize];
                    if child.is_leaf() {
                        meta |= child.count << (2 + 11 * side);
                        refs[side] = child.first;
                    } else {
                        refs[side] = at[c as usize];
                    }
                }
                PlaneNode {
                    plane: if n.axis == NO_AXIS { 0.0 } else { n.plane },
                    meta,
                    left: refs[0],
                    right: refs[1],
                }
            })
            .collect();
        Ok(Self {
            tree,
            nodes,
            bounds: src.first().map_or(Aabb::EMPTY, |n| n.bounds),
        })
    }

    /// The nodes, the root first.
    pub fn nodes(&self) -> &[PlaneNode] {
        &self.nodes
    }

    /// Bytes of the nodes: [`PLANE_NODE_BYTES`] each.
    pub fn node_bytes(&self) -> usize {
        self.nodes.len() * PLANE_NODE_BYTES
    }

    /// The root's reference: node 0, the whole set as one leaf, or nothing.
    fn root(&self) -> Option<Ref> {
        match (self.nodes.is_empty(), self.tree.len()) {
            (_, 0) => None,
            (true, n) => Some(Ref::Leaf {
                first: 0,
                count: n as u32,
            }),
            (false, _) => Some(Ref::Node(0)),
        }
    }

    /// The clamp point of the root: `q` clamped to the root's box.
    fn root_clamp(&self, q: Vec3) -> Vec3 {
        let b = &self.bounds;
        let c = Vec3::new(
            q.x.max(b.min.x).min(b.max.x),
            q.y.max(b.min.y).min(b.max.y),
            q.z.max(b.min.z).min(b.max.z),
        );
        debug_assert_eq!(dist2(q, c), box_dist2(q, b));
        c
    }

    /// The near and far children of node `n` for `q` with the parent's clamp point `c`:
    /// each with its clamp point.
    fn children(&self, n: &PlaneNode, q: Vec3, c: Vec3) -> [(Ref, Vec3); 2] {
        let (l, r) = (n.child(0), n.child(1));
        let a = n.axis();
        if a == NO_AXIS {
            return [(l, c), (r, c)];
        }
        let mut far = c;
        far[a as usize] = n.plane;
        if q[a as usize] <= n.plane {
            [(l, c), (r, far)]
        } else {
            [(r, c), (l, far)]
        }
    }

    /// The `k` points nearest to `q` (as [`PointTree::knn`], the same results), pruning by
    /// plane distance; counts the nodes read and the points tested.
    pub fn knn_counted(
        &self,
        q: Vec3,
        k: usize,
        out: &mut Vec<(f32, u32)>,
    ) -> Result<QueryStats, PointError> {
        let mut st = QueryStats::default();
        begin_query(q, out)?;
        let k = k.min(self.tree.len());
        let Some(root) = self.root().filter(|_| k > 0) else {
            return Ok(st);
        };
        let (points, ids) = (self.tree.sorted_points(), self.tree.ids());
        let mut best = Nearest::new(k);
        let c0 = self.root_clamp(q);
        let mut stack: Vec<(Ref, Vec3, f32)> = vec![(root, c0, dist2(q, c0))];
        while let Some((r, c, bound)) = stack.pop() {
            if best.pruned(bound) {
                continue;
            }
            match r {
                Ref::Leaf { first, count } => {
                    let (f, n) = (first as usize, count as usize);
                    st.points += n as u64;
                    best.offer_leaf(q, &points[f..f + n], &ids[f..f + n]);
                }
                Ref::Node(i) => {
                    st.nodes += 1;
                    let [near, far] = self.children(&self.nodes[i as usize], q, c);
                    for (r, c) in [far, near] {
                        let b = dist2(q, c);
                        if !best.pruned(b) {
                            stack.push((r, c, b));
                        }
                    }
                }
            }
        }
        best.finish(out);
        Ok(st)
    }

    /// The `k` points nearest to `q` (see [`PlaneKdTree::knn_counted`]).
    pub fn knn(&self, q: Vec3, k: usize, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        self.knn_counted(q, k, out).map(|_| ())
    }

    /// Every point within squared distance `r2` of `q` (as [`PointTree::within`]),
    /// pruning by plane distance; counts the nodes read and the points tested.
    pub fn within_counted(
        &self,
        q: Vec3,
        r2: f32,
        out: &mut Vec<(f32, u32)>,
    ) -> Result<QueryStats, PointError> {
        let mut st = QueryStats::default();
        begin_query(q, out)?;
        let Some(root) = self.root().filter(|_| !r2.is_nan() && r2 >= 0.0) else {
            return Ok(st);
        };
        let (points, ids) = (self.tree.sorted_points(), self.tree.ids());
        let mut keys = Vec::new();
        let mut stack = vec![(root, self.root_clamp(q))];
        while let Some((r, c)) = stack.pop() {
            if dist2(q, c) > r2 {
                continue;
            }
            match r {
                Ref::Leaf { first, count } => {
                    let (f, n) = (first as usize, count as usize);
                    st.points += n as u64;
                    within_leaf(&mut keys, q, r2, &points[f..f + n], &ids[f..f + n]);
                }
                Ref::Node(i) => {
                    st.nodes += 1;
                    let [near, far] = self.children(&self.nodes[i as usize], q, c);
                    stack.push(far);
                    stack.push(near);
                }
            }
        }
        keys.sort_unstable();
        out.extend(keys.into_iter().map(unkey));
        Ok(st)
    }

    /// Every point within squared distance `r2` of `q` (see
    /// [`PlaneKdTree::within_counted`]).
    pub fn within(&self, q: Vec3, r2: f32, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        self.within_counted(q, r2, out).map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::tests::cloud;
    use crate::points::{key, knn_brute};
    use proptest::prelude::*;

    /// Plane-pruned kNN and radius queries equal brute force (ties by index) and the
    /// box-pruned tree's, reading at least as many nodes.
    fn check(points: &[Vec3], queries: &[Vec3], ks: &[usize], max_leaf: usize) -> [QueryStats; 2] {
        let t = PointTree::build(points, max_leaf).unwrap();
        let p = PlaneKdTree::new(&t).unwrap();
        let inner = t.nodes().iter().filter(|n| !n.is_leaf()).count();
        assert_eq!(p.nodes().len(), inner);
        assert_eq!(p.node_bytes(), 16 * inner);
        let (mut out, mut want) = (Vec::new(), Vec::new());
        let mut sum = [QueryStats::default(); 2];
        for &q in queries {
            for &k in ks {
                let sp = p.knn_counted(q, k, &mut out).unwrap();
                assert_eq!(
                    out,
                    knn_brute(points, q, k).unwrap(),
                    "q {q:?} k {k} leaf {max_leaf}"
                );
                let sb = t.knn_counted(q, k, &mut want).unwrap();
                assert_eq!(out, want);
                // The cell of a subtree holds its points' box: never fewer nodes read.
                assert!(sp.nodes >= sb.nodes, "{sp:?} {sb:?}");
                for (s, x) in sum.iter_mut().zip([sb, sp]) {
                    s.nodes += x.nodes;
                    s.points += x.points;
                }
            }
            if let Some(&(r2, _)) = knn_brute(points, q, 5).unwrap().last() {
                let sp = p.within_counted(q, r2, &mut out).unwrap();
                let sb = t.within_counted(q, r2, &mut want).unwrap();
                assert_eq!(out, want);
                let mut brute: Vec<(f32, u32)> = points
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| (dist2(q, x), i as u32))
                    .filter(|&(d, _)| d <= r2)
                    .collect();
                brute.sort_by_key(|&(d, i)| key(d, i));
                assert_eq!(out, brute);
                assert!(out.len() >= points.len().min(5));
                assert!(sp.nodes >= sb.nodes);
            }
        }
        sum
    }

    #[test]
    fn plane_queries_equal_brute_force() {
        for (n, leaf) in [(1, 1), (2, 1), (17, 4), (1000, 1), (1000, 8), (5000, 16)] {
            let pts = cloud(n, n as u64 + 3, 10.0);
            let mut qs = cloud(12, 7, 12.0);
            qs.extend_from_slice(&pts[..pts.len().min(4)]);
            qs.push(Vec3::splat(-50.0));
            check(&pts, &qs, &[0, 1, 2, 7, 32, n + 5], leaf);
        }
        // Duplicates, a lattice of many equal distances, identical points (index splits).
        let mut dup = cloud(300, 5, 4.0);
        dup.extend_from_within(..);
        let lattice: Vec<Vec3> = cloud(2000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 40];
        let qs = [Vec3::ZERO, Vec3::splat(2.0), Vec3::new(1.5, 0.5, 3.0)];
        for leaf in [1, 3, 8] {
            check(&dup, &qs, &[1, 2, 10, 100], leaf);
            check(&lattice, &qs, &[1, 3, 10, 2000], leaf);
            check(&same, &qs, &[1, 5, 40], leaf);
        }
        // Flat and collinear sets.
        let flat: Vec<Vec3> = cloud(500, 8, 3.0)
            .into_iter()
            .map(|p| Vec3::new(p.x, p.y, 1.0))
            .collect();
        let line: Vec<Vec3> = (0..300)
            .map(|i| Vec3::new(i as f32 * 0.5, 0.0, 0.0))
            .collect();
        check(&flat, &qs, &[1, 4, 50], 4);
        check(&line, &qs, &[1, 4, 50], 4);
    }

    /// Plane pruning reads more nodes than box pruning on a random cloud (the cells are
    /// larger than the boxes of their points), but stores a quarter of the bytes.
    #[test]
    fn planes_read_more_nodes_in_a_quarter_of_the_bytes() {
        let pts = cloud(20_000, 11, 10.0);
        let qs = cloud(200, 12, 10.0);
        let [b, p] = check(&pts, &qs, &[1, 8], 8);
        assert!(p.nodes > b.nodes && p.points >= b.points, "{b:?} {p:?}");
        let t = PointTree::build(&pts, 8).unwrap();
        let plane = PlaneKdTree::new(&t).unwrap();
        assert_eq!(plane.node_bytes() * 4, plane.nodes().len() * 64);
    }

    /// Four points on the x axis, leaves of 1 (`points`' hand-derived planes x = 1.5,
    /// 0.75, 2.25): three nodes, the root first, each with two one-point leaves below the
    /// two lower ones; a query at x = 0.2 for k = 1 reads the root and the left node, tests
    /// point 0 (0.2^2 = 0.04), then prunes point 1's leaf by the plane at 0.75 (0.55^2 =
    /// 0.3025 > 0.04) and the right subtree by the plane at 1.5 (1.3^2 = 1.69): 2 nodes,
    /// 1 point.
    #[test]
    fn hand_derived_nodes_and_query() {
        let pts: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let t = PointTree::build(&pts, 1).unwrap();
        let p = PlaneKdTree::new(&t).unwrap();
        let n = p.nodes();
        assert_eq!(n.len(), 3);
        assert_eq!(
            (
                n[0].plane,
                n[0].axis(),
                n[0].leaf_count(0),
                n[0].leaf_count(1)
            ),
            (1.5, 0, 0, 0)
        );
        assert_eq!((n[0].left, n[0].right), (1, 2));
        assert_eq!(
            (n[1].plane, n[1].leaf_count(0), n[1].left, n[1].right),
            (0.75, 1, 0, 1)
        );
        assert_eq!(
            (n[2].plane, n[2].leaf_count(1), n[2].left, n[2].right),
            (2.25, 1, 2, 3)
        );
        let mut out = Vec::new();
        let st = p
            .knn_counted(Vec3::new(0.2, 0.0, 0.0), 1, &mut out)
            .unwrap();
        assert_eq!(out, [(0.2f32 * 0.2, 0)]);
        assert_eq!(
            st,
            QueryStats {
                nodes: 2,
                points: 1
            }
        );
        // One leaf: no nodes; bad leaf sizes and queries.
        let one = PointTree::build(&pts, 4).unwrap();
        let p1 = PlaneKdTree::new(&one).unwrap();
        assert!(p1.nodes().is_empty());
        p1.knn(Vec3::ZERO, 2, &mut out).unwrap();
        assert_eq!(out, [(0.0, 0), (1.0, 1)]);
        assert!(p1.knn(Vec3::splat(f32::NAN), 1, &mut out).is_err());
        let big = PointTree::build(&cloud(10, 1, 1.0), 4096).unwrap();
        assert!(PlaneKdTree::new(&big).is_err());
        let empty = PointTree::build(&[], 2).unwrap();
        let pe = PlaneKdTree::new(&empty).unwrap();
        pe.knn(Vec3::ZERO, 3, &mut out).unwrap();
        assert!(out.is_empty());
        pe.within(Vec3::ZERO, 1.0, &mut out).unwrap();
        assert!(out.is_empty());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Half-integer lattices (many duplicates and equal distances) and finite
        /// coordinates over many magnitudes, up to distances that overflow: plane-pruned
        /// kNN and radius queries equal brute force.
        #[test]
        fn plane_queries_equal_brute_force_on_lattices_and_wide_floats(
            raw in prop::collection::vec(prop::array::uniform3(-4i32..4), 1..200),
            wide in prop::collection::vec(prop::array::uniform3(-1e20f32..1e20), 1..100),
            scale in prop::sample::select(vec![1e-30f32, 1e-3, 1.0, 1e15, 1e18]),
            q in prop::array::uniform3(-1e20f32..1e20),
            k in 0usize..30,
            leaf in 1usize..6,
        ) {
            let lattice: Vec<Vec3> = raw
                .iter()
                .map(|a| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32) * 0.5)
                .collect();
            let wide: Vec<Vec3> = wide.iter().map(|a| Vec3::from(*a) * scale).collect();
            let ql = Vec3::new(q[0].signum(), q[1].signum(), q[2].signum()) * 1.25;
            for (pts, q) in [(&lattice, ql), (&wide, Vec3::from(q) * scale)] {
                let t = PointTree::build(pts, leaf).unwrap();
                let p = PlaneKdTree::new(&t).unwrap();
                let mut out = Vec::new();
                p.knn(q, k, &mut out).unwrap();
                let want = knn_brute(pts, q, k).unwrap();
                prop_assert_eq!(&out, &want);
                if let Some(&(r2, _)) = want.last() {
                    p.within(q, r2, &mut out).unwrap();
                    let n = knn_brute(pts, q, pts.len())
                        .unwrap()
                        .into_iter()
                        .filter(|o| o.0 <= r2)
                        .count();
                    prop_assert_eq!(out.len(), n);
                    prop_assert_eq!(&out[..want.len()], &want[..]);
                }
            }
        }
    }
}
