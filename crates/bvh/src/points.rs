//! Point k-d trees from the Morton order, with k-nearest-neighbour and radius queries
//! (issue 18, part 3; thesis ch. 5 and Karras 2012, "Maximizing parallelism in the
//! construction of BVHs, octrees, and k-d trees").
//!
//! The points are sorted by their 63-bit Morton code over the points' bounds (the sort of
//! the LBVH builders, [`crate::morton_sort`]), and the binary radix tree over the sorted
//! codes is built top-down: a node covering sorted positions `lo..hi` splits where its
//! highest differing code bit turns from 0 to 1. That bit is one bit of one axis's cell
//! coordinate (bit `3i + 2` of x, `3i + 1` of y, `3i` of z), so the split is an
//! axis-aligned plane of the Morton grid: the node is a k-d tree node. Positions sharing one
//! code (the same grid cell) are split by index with no plane, as a radix tree over each
//! point's index inside its run of equal codes (the node over run indices `s..=e` splits
//! where the highest bit of `s ^ e` turns to 1): the tree of the keys (code, run index),
//! which is what the streaming emitter of \[P2\] Algorithm 1 builds from the sorted stream
//! ([`crate::PointStream`]). Ranges of at most `max_leaf` points are leaves (the radix
//! tree's small subtrees collapsed).
//!
//! Each inner node stores its split axis and plane; every node stores its point range and
//! the bounds of its points. The plane is the grid plane clamped between the left child's
//! largest and the right child's smallest coordinate on the axis, so that every point on
//! the left has a coordinate `<= plane` and every point on the right `>= plane` exactly,
//! whatever the rounding of the grid. (The quantizer is monotone, so the children's points
//! are strictly separated on the axis and the clamp only corrects rounding.)
//!
//! Queries descend the near child first and prune a node when the squared distance from
//! the query to its box exceeds the k-th best squared distance found. Results are
//! `(squared distance, point index)` in increasing order of that pair, so ties are broken
//! by index, exactly as [`knn_brute`] does.

use crate::lbvh::MortonBits;
use crate::morton_sort::sorted_codes_of;
use geom::{Aabb, MortonGrid, Vec3};
use std::collections::BinaryHeap;
use thiserror::Error;

/// Cells per axis of the 63-bit Morton grid.
const GRID_BITS: u32 = 21;

/// [`PointNode::axis`] of a leaf, or of an inner node that splits one grid cell by index.
pub const NO_AXIS: u8 = 3;

/// Errors of the point tree.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PointError {
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} is not finite: {point:?}")]
    NonFinite {
        /// Index of the point in the input.
        index: usize,
        /// The point.
        point: Vec3,
    },
    /// More points than a `u32` index can name.
    #[error("{0} points: at most u32::MAX are supported")]
    TooMany(usize),
    /// `max_leaf` of zero.
    #[error("max_leaf must be at least 1")]
    ZeroLeaf,
    /// A query point with a NaN or infinite coordinate.
    #[error("query point is not finite: {0:?}")]
    NonFiniteQuery(Vec3),
    /// The streaming writer ([`crate::PointStream`]) was driven out of step with the
    /// emitter (a node whose children are not its two newest subtrees).
    #[error("point stream: {0}")]
    Stream(String),
    /// [`PointTree::validate`] found a broken invariant.
    #[error("invalid point tree: {0}")]
    Invalid(String),
}

/// Work of one query: inner node records read and points tested
/// ([`PointTree::knn_counted`], [`crate::PlaneKdTree::knn_counted`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryStats {
    /// Inner nodes read (popped and not pruned).
    pub nodes: u64,
    /// Points whose distance was computed (the leaves reached).
    pub points: u64,
}

/// A node of a [`PointTree`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointNode {
    /// Bounds of the node's points.
    pub bounds: Aabb,
    /// First sorted position of the node's points.
    pub first: u32,
    /// Number of points.
    pub count: u32,
    /// Split axis (0 x, 1 y, 2 z), or [`NO_AXIS`] for a leaf or an index split.
    pub axis: u8,
    /// Split plane on `axis` (NaN without one): left points `<=`, right points `>=`.
    pub plane: f32,
    /// Left child (the lower positions), 0 for a leaf (the root is never a child).
    pub left: u32,
    /// Right child, 0 for a leaf.
    pub right: u32,
}

impl PointNode {
    /// Whether the node is a leaf.
    pub fn is_leaf(&self) -> bool {
        self.left == 0
    }
}

/// A k-d tree of points built from their Morton order.
#[derive(Clone, Debug)]
pub struct PointTree {
    /// The points in Morton order.
    pub(crate) points: Vec<Vec3>,
    /// Input index of each sorted point.
    pub(crate) ids: Vec<u32>,
    /// Nodes in depth-first order, the root first (none for no points).
    pub(crate) nodes: Vec<PointNode>,
    pub(crate) max_leaf: u32,
}

/// Squared distance, summed in a fixed order (the node bound uses the same sum, so it
/// never exceeds the distance of a point inside the node).
#[inline(always)]
pub(crate) fn dist2(a: Vec3, b: Vec3) -> f32 {
    let (dx, dy, dz) = (a.x - b.x, a.y - b.y, a.z - b.z);
    dx * dx + dy * dy + dz * dz
}

/// Squared distance from `q` to the box `b` (0 inside).
#[inline(always)]
pub(crate) fn box_dist2(q: Vec3, b: &Aabb) -> f32 {
    let c = Vec3::new(
        q.x.max(b.min.x).min(b.max.x),
        q.y.max(b.min.y).min(b.max.y),
        q.z.max(b.min.z).min(b.max.z),
    );
    dist2(q, c)
}

/// Result key: squared distance (non-negative, not NaN, so its bits order like the value)
/// above the index.
#[inline(always)]
pub(crate) fn key(d: f32, id: u32) -> u64 {
    ((d.to_bits() as u64) << 32) | id as u64
}

#[inline(always)]
pub(crate) fn unkey(k: u64) -> (f32, u32) {
    (f32::from_bits((k >> 32) as u32), k as u32)
}

/// The start of every point query: `out` emptied, and a non-finite `q` an error.
pub(crate) fn begin_query(q: Vec3, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
    out.clear();
    if q.is_finite() {
        Ok(())
    } else {
        Err(PointError::NonFiniteQuery(q))
    }
}

/// The k nearest candidates of a query, shared by the point trees' kNN queries: a
/// max-heap of the best `k` result keys (its top is the k-th best).
pub(crate) struct Nearest {
    heap: BinaryHeap<u64>,
    k: usize,
}

impl Nearest {
    pub(crate) fn new(k: usize) -> Self {
        Self {
            heap: BinaryHeap::with_capacity(k),
            k,
        }
    }

    /// Whether a node whose squared-distance bound is `bound` can hold no better point:
    /// the bound exceeds the k-th best (equal is kept: a lower index at the same distance
    /// could still enter).
    #[inline(always)]
    pub(crate) fn pruned(&self, bound: f32) -> bool {
        self.heap.len() == self.k
            && bound.to_bits() > (self.heap.peek().copied().unwrap_or(0) >> 32) as u32
    }

    /// Offers the points of a leaf (`points[i]` with input index `ids[i]`).
    #[inline(always)]
    pub(crate) fn offer_leaf(&mut self, q: Vec3, points: &[Vec3], ids: &[u32]) {
        for (p, &id) in points.iter().zip(ids) {
            let kk = key(dist2(q, *p), id);
            if self.heap.len() < self.k {
                self.heap.push(kk);
            } else if let Some(mut top) = self.heap.peek_mut() {
                if kk < *top {
                    *top = kk;
                }
            }
        }
    }

    /// The results in increasing order into `out`.
    pub(crate) fn finish(self, out: &mut Vec<(f32, u32)>) {
        out.extend(self.heap.into_sorted_vec().into_iter().map(unkey));
    }
}

/// The keys of a leaf's points within squared distance `r2` of `q`, appended to `keys`
/// (the radius queries of the point trees).
#[inline(always)]
pub(crate) fn within_leaf(keys: &mut Vec<u64>, q: Vec3, r2: f32, points: &[Vec3], ids: &[u32]) {
    for (p, &id) in points.iter().zip(ids) {
        let d = dist2(q, *p);
        if d <= r2 {
            keys.push(key(d, id));
        }
    }
}

pub(crate) fn check_points(points: &[Vec3]) -> Result<(), PointError> {
    if points.len() > u32::MAX as usize {
        return Err(PointError::TooMany(points.len()));
    }
    match points.iter().position(|p| !p.is_finite()) {
        Some(index) => Err(PointError::NonFinite {
            index,
            point: points[index],
        }),
        None => Ok(()),
    }
}

/// Checks that `sorted` (with input indices `ids`) is `points` permuted, bit for bit.
pub(crate) fn check_permutation(
    sorted: &[Vec3],
    ids: &[u32],
    points: &[Vec3],
) -> Result<(), PointError> {
    let bad = |s: String| Err(PointError::Invalid(s));
    if sorted.len() != points.len() || ids.len() != points.len() {
        return bad(format!(
            "{} points for {} inputs",
            sorted.len(),
            points.len()
        ));
    }
    let mut seen = vec![false; points.len()];
    for (k, (&id, p)) in ids.iter().zip(sorted).enumerate() {
        let Some(orig) = points.get(id as usize) else {
            return bad(format!("position {k}: id {id} out of range"));
        };
        if std::mem::replace(&mut seen[id as usize], true) {
            return bad(format!("point {id} appears twice"));
        }
        if orig.to_array().map(f32::to_bits) != p.to_array().map(f32::to_bits) {
            return bad(format!("position {k}: point differs from input {id}"));
        }
    }
    Ok(())
}

/// The `k` points nearest to `q` by brute force: `(squared distance, index)` in increasing
/// order, ties by index (the reference for [`PointTree::knn`]).
pub fn knn_brute(points: &[Vec3], q: Vec3, k: usize) -> Result<Vec<(f32, u32)>, PointError> {
    check_points(points)?;
    if !q.is_finite() {
        return Err(PointError::NonFiniteQuery(q));
    }
    let mut keys: Vec<u64> = points
        .iter()
        .enumerate()
        .map(|(i, &p)| key(dist2(q, p), i as u32))
        .collect();
    let k = k.min(keys.len());
    if k == 0 {
        return Ok(Vec::new());
    }
    if k < keys.len() {
        keys.select_nth_unstable(k - 1);
        keys.truncate(k);
    }
    keys.sort_unstable();
    Ok(keys.into_iter().map(unkey).collect())
}

/// The points sorted by Morton code with the grid of their codes: the one sort that the
/// k-d tree, the octree and the streaming writer share.
pub(crate) struct Sorted {
    /// Sorted 63-bit codes.
    pub codes: Vec<u64>,
    /// Input index of each sorted point.
    pub ids: Vec<u32>,
    /// The points in sorted order.
    pub points: Vec<Vec3>,
    /// The grid of the codes.
    pub grid: Grid,
}

/// The planes of the Morton grid of a point set's codes (the box grid over the points'
/// bounds, 2^21 cells per axis): its origin and cell size per axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Grid {
    origin: Vec3,
    cell: [f64; 3],
}

impl Grid {
    /// The grid of the codes over `bounds` (the points' box).
    pub(crate) fn new(bounds: &Aabb) -> Self {
        let ext = bounds.max - bounds.min;
        let cells = (1u64 << GRID_BITS) as f64;
        Self {
            origin: bounds.min,
            cell: [
                ext.x as f64 / cells,
                ext.y as f64 / cells,
                ext.z as f64 / cells,
            ],
        }
    }

    /// The split between two different codes `a < b`: the axis of their highest differing
    /// bit and the grid plane at the low edge of `b`'s cell at that bit's level (the plane
    /// between the two halves of the radix node whose halves `a` ends and `b` starts).
    pub(crate) fn split(&self, a: u64, b: u64) -> (u8, f32) {
        let bit = 63 - (a ^ b).leading_zeros();
        // Bit 3i + 2 is x, 3i + 1 is y, 3i is z.
        let axis = 2 - (bit % 3) as usize;
        let level = bit / 3;
        let c = axis_cell(b, axis) & !((1u32 << level) - 1);
        let plane = self.origin[axis] as f64 + c as f64 * self.cell[axis];
        (axis as u8, plane as f32)
    }
}

/// Sorts `points` (checked finite) by their 63-bit Morton codes over their bounds.
/// The checks every point-tree builder makes ([`check_points`], `max_leaf > 0`), then
/// [`sort_points`].
pub(crate) fn checked_sort(points: &[Vec3], max_leaf: usize) -> Result<Sorted, PointError> {
    check_points(points)?;
    if max_leaf == 0 {
        return Err(PointError::ZeroLeaf);
    }
    Ok(sort_points(points))
}

pub(crate) fn sort_points(points: &[Vec3]) -> Sorted {
    let (codes, ids, bounds) = sorted_codes_of(
        points.len(),
        |i| points[i],
        MortonBits::Bits63,
        MortonGrid::Box,
    );
    let sorted: Vec<Vec3> = ids.iter().map(|&i| points[i as usize]).collect();
    Sorted {
        codes,
        ids,
        points: sorted,
        grid: Grid::new(&bounds),
    }
}

/// Split position of a node over sorted positions `lo..hi` (at least 2) whose codes are
/// all equal, `run_lo` the first position of their run: the radix split of the run indices
/// `lo - run_lo ..= hi - 1 - run_lo`, where their highest differing bit turns to 1.
pub(crate) fn index_split(lo: usize, hi: usize, run_lo: usize) -> usize {
    let (s, e) = (lo - run_lo, hi - 1 - run_lo);
    let bit = usize::BITS - 1 - (s ^ e).leading_zeros();
    run_lo + ((e >> bit) << bit)
}

/// The plane of a split on `axis` at grid plane `grid_plane`, clamped between the left
/// child's largest and the right child's smallest coordinate on the axis.
pub(crate) fn clamp_plane(grid_plane: f32, axis: u8, lb: &Aabb, rb: &Aabb) -> f32 {
    let a = axis as usize;
    grid_plane.max(lb.max[a]).min(rb.min[a])
}

/// Top-down builder over the sorted codes.
struct Build<'a> {
    codes: &'a [u64],
    points: &'a [Vec3],
    grid: Grid,
    max_leaf: usize,
}

/// Points below which a node's two subtrees are emitted on one thread.
const PARALLEL_MIN_POINTS: usize = 1 << 14;

/// Appends `sub` (a subtree whose child links index `sub`) to `out`; returns its root.
fn append(out: &mut Vec<PointNode>, sub: Vec<PointNode>) -> usize {
    let base = out.len();
    out.extend(sub.into_iter().map(|mut n| {
        if !n.is_leaf() {
            n.left += base as u32;
            n.right += base as u32;
        }
        n
    }));
    base
}

impl Build<'_> {
    /// Emits the node over sorted positions `lo..hi` (non-empty) and its subtree into
    /// `nodes`, depth-first; returns its index. `run_lo` is the first position of the run
    /// of equal codes holding `lo` (used when all of the node's codes are equal). Large
    /// subtrees are emitted in parallel into their own vectors and appended, so the result
    /// is the same for any thread count.
    fn node(&self, lo: usize, hi: usize, run_lo: usize, nodes: &mut Vec<PointNode>) -> usize {
        let id = nodes.len();
        nodes.push(PointNode {
            bounds: Aabb::EMPTY,
            first: lo as u32,
            count: (hi - lo) as u32,
            axis: NO_AXIS,
            plane: f32::NAN,
            left: 0,
            right: 0,
        });
        if hi - lo <= self.max_leaf {
            let b = self.points[lo..hi]
                .iter()
                .fold(Aabb::EMPTY, |b, &p| b.grow(p));
            nodes[id].bounds = b;
            return id;
        }
        let (a, z) = (self.codes[lo], self.codes[hi - 1]);
        let (split, axis, grid_plane, lrun, rrun) = if a != z {
            // Highest differing bit: the codes above it are shared, so the range splits
            // where that bit turns to 1. A split between codes never cuts a run of equal
            // codes, so each child's runs start inside it.
            let bit = 63 - (a ^ z).leading_zeros();
            let split = lo + self.codes[lo..hi].partition_point(|c| (c >> bit) & 1 == 0);
            let (axis, plane) = self.grid.split(self.codes[split - 1], self.codes[split]);
            (split, axis, plane, lo, split)
        } else {
            let split = index_split(lo, hi, run_lo);
            (split, NO_AXIS, f32::NAN, run_lo, run_lo)
        };
        let (l, r) = if hi - lo >= PARALLEL_MIN_POINTS {
            let sub = |a, b, run| {
                let mut v = Vec::with_capacity(2 * (b - a) / self.max_leaf + 1);
                self.node(a, b, run, &mut v);
                v
            };
            let (lv, rv) = rayon::join(|| sub(lo, split, lrun), || sub(split, hi, rrun));
            (append(nodes, lv), append(nodes, rv))
        } else {
            (
                self.node(lo, split, lrun, nodes),
                self.node(split, hi, rrun, nodes),
            )
        };
        let (lb, rb) = (nodes[l].bounds, nodes[r].bounds);
        let n = &mut nodes[id];
        n.bounds = lb.union(rb);
        n.left = l as u32;
        n.right = r as u32;
        n.axis = axis;
        if axis != NO_AXIS {
            n.plane = clamp_plane(grid_plane, axis, &lb, &rb);
        }
        id
    }
}

/// The cell coordinate on `axis` (0 x, 1 y, 2 z) of a 63-bit Morton code.
pub(crate) fn axis_cell(code: u64, axis: usize) -> u32 {
    let shift = 2 - axis as u32;
    (0..GRID_BITS).fold(0, |c, i| {
        c | ((((code >> (3 * i + shift)) & 1) as u32) << i)
    })
}

impl PointTree {
    /// Builds the tree over `points` with at most `max_leaf` points per leaf.
    ///
    /// Errors on a non-finite point (the Morton grid and distances need finite points), on
    /// `max_leaf == 0` and on more than `u32::MAX` points. No points give an empty tree.
    pub fn build(points: &[Vec3], max_leaf: usize) -> Result<Self, PointError> {
        let Sorted {
            codes,
            ids,
            points: sorted,
            grid,
        } = checked_sort(points, max_leaf)?;
        let b = Build {
            codes: &codes,
            points: &sorted,
            grid,
            max_leaf,
        };
        let mut nodes = Vec::with_capacity(2 * points.len() / max_leaf + 1);
        if !points.is_empty() {
            b.node(0, points.len(), 0, &mut nodes);
        }
        Ok(Self {
            points: sorted,
            ids,
            nodes,
            max_leaf: max_leaf as u32,
        })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the tree has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The nodes, root first.
    pub fn nodes(&self) -> &[PointNode] {
        &self.nodes
    }

    /// The points in Morton order.
    pub fn sorted_points(&self) -> &[Vec3] {
        &self.points
    }

    /// Input index of each point in Morton order.
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// Largest leaf the tree was built with.
    pub fn max_leaf(&self) -> u32 {
        self.max_leaf
    }

    /// Whether `other` is the same tree: the same points in the same order, the same leaf
    /// size, and node for node the same ranges, children, axes, boxes and planes (compared
    /// as values: NaN planes of leaves and index splits are equal).
    pub fn same_as(&self, other: &PointTree) -> bool {
        let plane = |n: &PointNode| (!n.plane.is_nan()).then_some(n.plane);
        self.ids == other.ids
            && self.points == other.points
            && self.max_leaf == other.max_leaf
            && self.nodes.len() == other.nodes.len()
            && self.nodes.iter().zip(&other.nodes).all(|(a, b)| {
                (
                    a.first,
                    a.count,
                    a.axis,
                    a.left,
                    a.right,
                    a.bounds,
                    plane(a),
                ) == (
                    b.first,
                    b.count,
                    b.axis,
                    b.left,
                    b.right,
                    b.bounds,
                    plane(b),
                )
            })
    }

    /// Depth of the deepest leaf (the root alone is depth 1; 0 for no points).
    pub fn depth(&self) -> usize {
        fn go(t: &PointTree, n: usize) -> usize {
            let node = &t.nodes[n];
            if node.is_leaf() {
                1
            } else {
                1 + go(t, node.left as usize).max(go(t, node.right as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            go(self, 0)
        }
    }

    /// The `k` points nearest to `q` into `out` (cleared first): `(squared distance, input
    /// index)` in increasing order, ties by index; all points when `k >= len`.
    pub fn knn(&self, q: Vec3, k: usize, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        self.knn_counted(q, k, out).map(|_| ())
    }

    /// [`PointTree::knn`], counting the inner nodes it reads (popped and not pruned: the
    /// records whose child boxes it compares) and the points it tests.
    pub fn knn_counted(
        &self,
        q: Vec3,
        k: usize,
        out: &mut Vec<(f32, u32)>,
    ) -> Result<QueryStats, PointError> {
        let mut st = QueryStats::default();
        begin_query(q, out)?;
        let k = k.min(self.points.len());
        if k == 0 {
            return Ok(st);
        }
        let mut best = Nearest::new(k);
        // Nodes to visit with their squared-distance bound.
        let mut stack: Vec<(u32, f32)> = Vec::with_capacity(128);
        stack.push((0, box_dist2(q, &self.nodes[0].bounds)));
        while let Some((n, bound)) = stack.pop() {
            if best.pruned(bound) {
                continue;
            }
            let node = &self.nodes[n as usize];
            if node.is_leaf() {
                let (f, c) = (node.first as usize, node.count as usize);
                st.points += c as u64;
                best.offer_leaf(q, &self.points[f..f + c], &self.ids[f..f + c]);
                continue;
            }
            st.nodes += 1;
            let (l, r) = (node.left, node.right);
            let lb = box_dist2(q, &self.nodes[l as usize].bounds);
            let rb = box_dist2(q, &self.nodes[r as usize].bounds);
            // Near child: the side of the plane holding `q`, else the closer box.
            let left_first = if node.axis != NO_AXIS {
                q[node.axis as usize] <= node.plane
            } else {
                lb <= rb
            };
            let (near, far) = if left_first {
                ((l, lb), (r, rb))
            } else {
                ((r, rb), (l, lb))
            };
            if !best.pruned(far.1) {
                stack.push(far);
            }
            if !best.pruned(near.1) {
                stack.push(near);
            }
        }
        best.finish(out);
        Ok(st)
    }

    /// Every point within squared distance `r2` of `q` into `out` (cleared first):
    /// `(squared distance, input index)` in increasing order.
    pub fn within(&self, q: Vec3, r2: f32, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        self.within_counted(q, r2, out).map(|_| ())
    }

    /// [`PointTree::within`], counting the inner nodes it reads and the points it tests
    /// (as [`PointTree::knn_counted`]).
    pub fn within_counted(
        &self,
        q: Vec3,
        r2: f32,
        out: &mut Vec<(f32, u32)>,
    ) -> Result<QueryStats, PointError> {
        let mut st = QueryStats::default();
        begin_query(q, out)?;
        if self.nodes.is_empty() || r2.is_nan() || r2 < 0.0 {
            return Ok(st);
        }
        let mut keys = Vec::new();
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            if box_dist2(q, &node.bounds) > r2 {
                continue;
            }
            if node.is_leaf() {
                let (f, c) = (node.first as usize, node.count as usize);
                st.points += c as u64;
                within_leaf(
                    &mut keys,
                    q,
                    r2,
                    &self.points[f..f + c],
                    &self.ids[f..f + c],
                );
            } else {
                st.nodes += 1;
                stack.push(node.right);
                stack.push(node.left);
            }
        }
        keys.sort_unstable();
        out.extend(keys.into_iter().map(unkey));
        Ok(st)
    }

    /// Checks the tree against the `points` it was built from: the sorted points are the
    /// input permuted, every point lies in exactly one leaf (children partition their
    /// parent's range; leaves hold 1 to `max_leaf` points), every node's bounds hold its
    /// points and are the union of its children's, and every point lies on its side of every
    /// ancestor's plane.
    pub fn validate(&self, points: &[Vec3]) -> Result<(), PointError> {
        let bad = |s: String| Err(PointError::Invalid(s));
        check_permutation(&self.points, &self.ids, points)?;
        if points.is_empty() {
            return if self.nodes.is_empty() {
                Ok(())
            } else {
                bad("nodes without points".into())
            };
        }
        // (node, expected first, expected count)
        let mut stack = vec![(0usize, 0u32, points.len() as u32)];
        let mut visited = 0;
        while let Some((n, first, count)) = stack.pop() {
            visited += 1;
            let Some(node) = self.nodes.get(n) else {
                return bad(format!("node {n} out of range"));
            };
            if node.first != first || node.count != count {
                return bad(format!(
                    "node {n}: range {}+{}, expected {first}+{count}",
                    node.first, node.count
                ));
            }
            let pts = &self.points[first as usize..(first + count) as usize];
            let b = pts.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p));
            if node.is_leaf() {
                if node.right != 0 || node.axis != NO_AXIS {
                    return bad(format!("leaf {n} has a child or a split"));
                }
                if count == 0 || count > self.max_leaf {
                    return bad(format!("leaf {n}: {count} points, max {}", self.max_leaf));
                }
                if node.bounds != b {
                    return bad(format!("leaf {n}: bounds are not its points' box"));
                }
                continue;
            }
            let (l, r) = (node.left as usize, node.right as usize);
            if l <= n || r <= n || l >= self.nodes.len() || r >= self.nodes.len() {
                return bad(format!("node {n}: children {l}, {r}"));
            }
            let (ln, rn) = (&self.nodes[l], &self.nodes[r]);
            if ln.count == 0 || rn.count == 0 || ln.count + rn.count != count {
                return bad(format!("node {n}: children do not split its range"));
            }
            if node.bounds != b || node.bounds != ln.bounds.union(rn.bounds) {
                return bad(format!("node {n}: bounds are not its points' box"));
            }
            if node.axis != NO_AXIS {
                let a = node.axis as usize;
                if a > 2 || node.plane.is_nan() {
                    return bad(format!("node {n}: axis {a}, plane {}", node.plane));
                }
                let split = (first + ln.count) as usize;
                let lo = &self.points[first as usize..split];
                let hi = &self.points[split..(first + count) as usize];
                if let Some(p) = lo.iter().find(|p| p[a] > node.plane) {
                    return bad(format!(
                        "node {n}: left point {p:?} above plane {}",
                        node.plane
                    ));
                }
                if let Some(p) = hi.iter().find(|p| p[a] < node.plane) {
                    return bad(format!(
                        "node {n}: right point {p:?} below plane {}",
                        node.plane
                    ));
                }
            } else if !node.plane.is_nan() {
                return bad(format!("node {n}: a plane without an axis"));
            }
            stack.push((r, first + ln.count, rn.count));
            stack.push((l, first, ln.count));
        }
        if visited != self.nodes.len() {
            return bad(format!("{} nodes, {visited} reachable", self.nodes.len()));
        }
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Deterministic pseudo-random points in `[0, scale)^3`.
    pub(crate) fn cloud(n: usize, seed: u64, scale: f32) -> Vec<Vec3> {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32 * scale
        };
        (0..n).map(|_| Vec3::new(next(), next(), next())).collect()
    }

    /// Builds, validates and checks kNN (and radius queries) against brute force.
    fn check(points: &[Vec3], queries: &[Vec3], ks: &[usize], max_leaf: usize) {
        let t = PointTree::build(points, max_leaf).unwrap();
        t.validate(points).unwrap();
        let mut out = Vec::new();
        for &q in queries {
            for &k in ks {
                t.knn(q, k, &mut out).unwrap();
                let want = knn_brute(points, q, k).unwrap();
                assert_eq!(
                    out,
                    want,
                    "q {q:?} k {k} n {} leaf {max_leaf}",
                    points.len()
                );
            }
            // Radius: the distance of the 5th neighbour (ties at the boundary included).
            if let Some(&(r2, _)) = knn_brute(points, q, 5).unwrap().last() {
                t.within(q, r2, &mut out).unwrap();
                let mut want: Vec<_> = points
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| (dist2(q, p), i as u32))
                    .filter(|&(d, _)| d <= r2)
                    .collect();
                want.sort_by_key(|&(d, i)| key(d, i));
                assert_eq!(out, want);
            }
        }
    }

    #[test]
    fn knn_matches_brute_force_on_random_clouds() {
        for (n, leaf) in [(1, 1), (2, 1), (17, 4), (1000, 1), (1000, 8), (20_000, 16)] {
            let pts = cloud(n, n as u64, 10.0);
            let mut qs = cloud(20, 99, 12.0);
            qs.extend_from_slice(&pts[..pts.len().min(5)]);
            qs.push(Vec3::splat(-50.0));
            check(&pts, &qs, &[0, 1, 2, 7, 32, n, n + 5], leaf);
        }
    }

    #[test]
    fn duplicates_and_identical_points_tie_by_index() {
        // Many exact duplicates, and points on a coarse lattice (many equal distances).
        let mut pts = cloud(300, 5, 4.0);
        pts.extend_from_within(..);
        pts.extend_from_within(..150);
        let lattice: Vec<Vec3> = cloud(2000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
        let qs = [Vec3::ZERO, Vec3::splat(2.0), Vec3::new(1.5, 0.5, 3.0)];
        for leaf in [1, 3, 8] {
            check(&pts, &qs, &[1, 2, 3, 10, 100], leaf);
            check(&lattice, &qs, &[1, 2, 3, 10, 100, 2000], leaf);
        }
        // All points identical: one Morton code, the tree is split by index only.
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 1000];
        let t = PointTree::build(&same, 4).unwrap();
        t.validate(&same).unwrap();
        assert!(t.nodes().iter().all(|n| n.axis == NO_AXIS));
        assert!(t.depth() <= 10);
        check(&same, &qs, &[0, 1, 5, 999, 1000, 1001], 4);
        let mut out = Vec::new();
        t.knn(Vec3::ZERO, 3, &mut out).unwrap();
        assert_eq!(out.iter().map(|o| o.1).collect::<Vec<_>>(), [0, 1, 2]);
        // Index splits are radix splits of the run indices: 5 equal points split 4 + 1
        // (bit 2 of 0 ^ 4), then 2 + 2, then 1 + 1.
        let t = PointTree::build(&same[..5], 1).unwrap();
        let counts: Vec<u32> = t.nodes().iter().map(|n| n.count).collect();
        assert_eq!(counts, [5, 4, 2, 1, 1, 2, 1, 1, 1]);
        assert_eq!(index_split(3, 9, 1), 5);
    }

    #[test]
    fn collinear_and_flat_points() {
        let line: Vec<Vec3> = (0..500)
            .map(|i| Vec3::new(0.5, i as f32 * 0.1, -2.0))
            .collect();
        let flat: Vec<Vec3> = cloud(800, 3, 5.0)
            .into_iter()
            .map(|p| Vec3::new(p.x, 1.0, p.z))
            .collect();
        let qs = [
            Vec3::new(0.5, 7.05, -2.0),
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::splat(2.5),
        ];
        for leaf in [1, 4] {
            check(&line, &qs, &[1, 2, 9, 600], leaf);
            check(&flat, &qs, &[1, 2, 9, 600], leaf);
        }
        let t = PointTree::build(&line, 1).unwrap();
        assert!(t.nodes().iter().all(|n| n.axis == NO_AXIS || n.axis == 1));
    }

    #[test]
    fn empty_input_k_zero_and_bad_input() {
        let t = PointTree::build(&[], 4).unwrap();
        t.validate(&[]).unwrap();
        assert!(t.is_empty());
        let mut out = vec![(1.0, 1)];
        t.knn(Vec3::ZERO, 5, &mut out).unwrap();
        assert!(out.is_empty());
        t.within(Vec3::ZERO, 1.0, &mut out).unwrap();
        assert!(out.is_empty());
        let pts = cloud(10, 1, 1.0);
        let t = PointTree::build(&pts, 4).unwrap();
        t.knn(Vec3::ZERO, 0, &mut out).unwrap();
        assert!(out.is_empty());
        assert!(matches!(
            t.knn(Vec3::new(f32::NAN, 0.0, 0.0), 1, &mut out),
            Err(PointError::NonFiniteQuery(_))
        ));
        assert!(matches!(
            t.knn(Vec3::new(0.0, f32::INFINITY, 0.0), 1, &mut out),
            Err(PointError::NonFiniteQuery(_))
        ));
        let mut bad = pts.clone();
        bad[7].y = f32::NAN;
        assert!(matches!(
            PointTree::build(&bad, 4),
            Err(PointError::NonFinite { index: 7, .. })
        ));
        assert!(matches!(
            knn_brute(&bad, Vec3::ZERO, 1),
            Err(PointError::NonFinite { index: 7, .. })
        ));
        bad[7].y = f32::NEG_INFINITY;
        assert!(PointTree::build(&bad, 4).is_err());
        assert_eq!(PointTree::build(&pts, 0).unwrap_err(), PointError::ZeroLeaf);
    }

    #[test]
    fn splits_are_morton_grid_planes() {
        // Points on an 8^3 lattice over [0, 7]: the grid's top-level planes are at 3.5.
        let pts: Vec<Vec3> = (0..512)
            .map(|i| Vec3::new((i % 8) as f32, (i / 8 % 8) as f32, (i / 64) as f32))
            .collect();
        let t = PointTree::build(&pts, 1).unwrap();
        t.validate(&pts).unwrap();
        let root = t.nodes()[0];
        assert_eq!(root.axis, 0, "x is the most significant Morton axis");
        assert_eq!(root.plane, 3.5);
        assert_eq!(t.nodes()[root.left as usize].axis, 1);
        assert_eq!(t.nodes()[root.left as usize].plane, 3.5);
        // A full lattice of 2^9 points splits into a perfect tree.
        assert_eq!(t.depth(), 10);
        let mut bad = t.clone();
        bad.nodes[0].plane = 2.5;
        assert!(bad.validate(&pts).is_err());
    }

    #[test]
    fn tree_is_the_same_for_any_thread_count() {
        let pts = cloud(150_000, 11, 3.0);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| PointTree::build(&pts, 4).unwrap());
        let many = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| PointTree::build(&pts, 4).unwrap());
        one.validate(&pts).unwrap();
        assert_eq!(one.ids, many.ids);
        let bits = |t: &PointTree| {
            t.nodes
                .iter()
                .map(|n| {
                    (
                        n.first,
                        n.count,
                        n.axis,
                        n.plane.to_bits(),
                        n.left,
                        n.right,
                        n.bounds,
                    )
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&one), bits(&many));
        // Left children follow their parent (depth-first order).
        assert!(one
            .nodes
            .iter()
            .enumerate()
            .all(|(i, n)| n.is_leaf() || n.left as usize == i + 1));
        let mut out = Vec::new();
        for q in cloud(50, 12, 3.0) {
            many.knn(q, 10, &mut out).unwrap();
            assert_eq!(out, knn_brute(&pts, q, 10).unwrap());
        }
    }

    #[test]
    fn validate_rejects_broken_trees() {
        let pts = cloud(100, 2, 1.0);
        let t = PointTree::build(&pts, 4).unwrap();
        let mut bad = t.clone();
        bad.ids.swap(0, 1);
        assert!(bad.validate(&pts).is_err());
        let mut bad = t.clone();
        let leaf = bad.nodes.iter().position(|n| n.is_leaf()).unwrap();
        bad.nodes[leaf].count += 1;
        assert!(bad.validate(&pts).is_err());
        let mut bad = t.clone();
        bad.max_leaf = 1;
        assert!(bad.validate(&pts).is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn knn_equals_brute_force(
            raw in prop::collection::vec(prop::array::uniform3(-4i32..4), 0..300),
            q in prop::array::uniform3(-5i32..5),
            k in 0usize..40,
            leaf in 1usize..6,
        ) {
            // Small integer coordinates halved: many duplicates and equal distances.
            let pts: Vec<Vec3> = raw.iter().map(|a| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32) * 0.5).collect();
            let q = Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32) * 0.25;
            let t = PointTree::build(&pts, leaf).unwrap();
            prop_assert!(t.validate(&pts).is_ok());
            let mut out = Vec::new();
            t.knn(q, k, &mut out).unwrap();
            prop_assert_eq!(out, knn_brute(&pts, q, k).unwrap());
        }

        /// Arbitrary finite coordinates over many magnitudes, up to distances that
        /// overflow to infinity: kNN and radius queries equal brute force.
        #[test]
        fn knn_equals_brute_force_on_wide_floats(
            raw in prop::collection::vec(prop::array::uniform3(-1e20f32..1e20), 1..120),
            scale in prop::sample::select(vec![1e-30f32, 1e-3, 1.0, 1e15, 1e18]),
            q in prop::array::uniform3(-1e20f32..1e20),
            k in 0usize..20,
        ) {
            let pts: Vec<Vec3> = raw.iter().map(|a| Vec3::from(*a) * scale).collect();
            let q = Vec3::from(q) * scale;
            let t = PointTree::build(&pts, 2).unwrap();
            prop_assert!(t.validate(&pts).is_ok());
            let mut out = Vec::new();
            t.knn(q, k, &mut out).unwrap();
            let want = knn_brute(&pts, q, k).unwrap();
            prop_assert_eq!(&out, &want);
            if let Some(&(r2, _)) = want.last() {
                t.within(q, r2, &mut out).unwrap();
                let n = knn_brute(&pts, q, pts.len()).unwrap().into_iter().filter(|o| o.0 <= r2).count();
                prop_assert_eq!(out.len(), n);
                prop_assert_eq!(&out[..want.len()], &want[..]);
            }
        }
    }
}
