//! Point octrees from the Morton order, with k-nearest-neighbour and radius queries
//! (issue 18, part 3; thesis lines 482 and 991, Karras 2012 §4).
//!
//! The points are sorted once by their 63-bit Morton codes, exactly as for the k-d tree
//! ([`crate::PointTree`]; the same sort, the same grid). A cell of the Morton grid at depth
//! `d` is a prefix of `3d` code bits (digit `20 - d` is the next 3 bits, bit 2 of a digit
//! the x bit); the points of a cell are a contiguous range of the sorted order. The octree
//! has a node per distinct prefix of `3d` bits, `d = 0..=21`, down to the cells that become
//! leaves: a cell is a leaf when it holds at most `max_leaf` points, or when all its points
//! share one code (no grid plane separates them; its chain of single-child cells down to
//! depth 21 is not stored). Otherwise its children are its non-empty sub-cells, 1 to 8 of
//! them, in octant order (a cell whose points all lie in one sub-cell keeps that one
//! child: Karras's octree has a node for every prefix, and so does this one).
//!
//! Karras (§4) derives the octree from the binary radix tree by grouping its levels: the
//! radix nodes whose highest differing bit lies in the same 3-bit digit make one octree
//! node. Top-down over the sorted codes that is one `partition_point` per octant boundary,
//! the same search the k-d tree makes for its one split; the test
//! `octree_groups_the_radix_tree_levels` checks the correspondence node for node.
//!
//! Nodes are stored with the root first and each node's children contiguous; every node
//! stores its point range and the box of its points, which the queries prune by (the same
//! pruning and tie rule as the k-d tree, so the results equal [`crate::knn_brute`]).

use crate::hlbvh::EmittedNode;
use crate::point_stream::{emit_points, OpenStack, PointSink};
use crate::points::{
    begin_query, box_dist2, checked_sort, unkey, within_leaf, Nearest, PointError, Sorted,
};
use geom::{Aabb, MortonGrid, MortonQuantizer, Vec3};

/// Depth of the finest cells (one full 63-bit code).
pub const OCTREE_MAX_DEPTH: u8 = 21;

/// A node of an [`Octree`]: one cell of the Morton grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OctNode {
    /// Bounds of the node's points.
    pub bounds: Aabb,
    /// First sorted position of the node's points.
    pub first: u32,
    /// Number of points.
    pub count: u32,
    /// Index of the first child (the children are contiguous), 0 for a leaf.
    pub child: u32,
    /// Number of children, 0 for a leaf.
    pub children: u8,
    /// The octants (sub-cells) that the children are, one bit each: bit `o` for the sub-cell
    /// whose next 3 code bits are `o` (x the high bit).
    pub octants: u8,
    /// Depth of the cell: its points share their top `3 * depth` code bits.
    pub depth: u8,
}

impl OctNode {
    /// Whether the node is a leaf.
    pub fn is_leaf(&self) -> bool {
        self.children == 0
    }
}

/// An octree of points built from their Morton order.
#[derive(Clone, Debug)]
pub struct Octree {
    points: Vec<Vec3>,
    ids: Vec<u32>,
    nodes: Vec<OctNode>,
    max_leaf: u32,
}

/// Digit (3 bits) of `code` below a cell of depth `depth`.
#[inline]
fn digit(code: u64, depth: u8) -> u8 {
    ((code >> (3 * (OCTREE_MAX_DEPTH - 1 - depth) as u32)) & 7) as u8
}

struct Build<'a> {
    codes: &'a [u64],
    points: &'a [Vec3],
    max_leaf: usize,
}

impl Build<'_> {
    /// Fills node `id` (already allocated) over sorted positions `lo..hi` (non-empty), a
    /// cell of depth `depth`, and its subtree.
    fn node(&self, id: usize, lo: usize, hi: usize, depth: u8, nodes: &mut Vec<OctNode>) {
        let n = OctNode {
            bounds: Aabb::EMPTY,
            first: lo as u32,
            count: (hi - lo) as u32,
            child: 0,
            children: 0,
            octants: 0,
            depth,
        };
        if hi - lo <= self.max_leaf || self.codes[lo] == self.codes[hi - 1] {
            nodes[id] = OctNode {
                bounds: self.points[lo..hi]
                    .iter()
                    .fold(Aabb::EMPTY, |b, &p| b.grow(p)),
                ..n
            };
            return;
        }
        // The codes share their top 3 * depth bits and differ below (else a leaf above), so
        // depth < 21 and the next digit orders the range.
        let mut ranges = [(0u8, 0usize, 0usize); 8];
        let mut k = 0;
        let mut start = lo;
        while start < hi {
            let o = digit(self.codes[start], depth);
            let end = start + self.codes[start..hi].partition_point(|&c| digit(c, depth) == o);
            ranges[k] = (o, start, end);
            k += 1;
            start = end;
        }
        let base = nodes.len();
        nodes.resize(base + k, n);
        let mut bounds = Aabb::EMPTY;
        let mut octants = 0u8;
        for (i, &(o, a, b)) in ranges[..k].iter().enumerate() {
            self.node(base + i, a, b, depth + 1, nodes);
            bounds = bounds.union(nodes[base + i].bounds);
            octants |= 1 << o;
        }
        nodes[id] = OctNode {
            bounds,
            child: base as u32,
            children: k as u8,
            octants,
            ..n
        };
    }
}

/// Counts of an [`Octree`]'s nodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OctreeStats {
    /// All nodes.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Inner nodes with a single child (a cell whose points lie in one sub-cell).
    pub single_child: usize,
    /// Leaves holding more than `max_leaf` points (all with one code).
    pub over_full_leaves: usize,
    /// Levels on the longest root-to-leaf path (the root alone is 1; 0 for no points).
    pub depth: usize,
}

impl Octree {
    /// Builds the octree over `points` with leaves of at most `max_leaf` points (except
    /// cells whose points all share one code, which stay one leaf).
    ///
    /// Errors on a non-finite point, on `max_leaf == 0` and on more than `u32::MAX`
    /// points. No points give an empty tree.
    pub fn build(points: &[Vec3], max_leaf: usize) -> Result<Self, PointError> {
        let Sorted {
            codes,
            ids,
            points: sorted,
            ..
        } = checked_sort(points, max_leaf)?;
        let b = Build {
            codes: &codes,
            points: &sorted,
            max_leaf,
        };
        let mut nodes = Vec::with_capacity(2 * points.len() / max_leaf + 1);
        if !points.is_empty() {
            nodes.push(OctNode {
                bounds: Aabb::EMPTY,
                first: 0,
                count: 0,
                child: 0,
                children: 0,
                octants: 0,
                depth: 0,
            });
            b.node(0, 0, points.len(), 0, &mut nodes);
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
    pub fn nodes(&self) -> &[OctNode] {
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

    /// Largest leaf the tree was built with (leaves of one code may exceed it).
    pub fn max_leaf(&self) -> u32 {
        self.max_leaf
    }

    /// Node counts and depth.
    pub fn stats(&self) -> OctreeStats {
        let mut s = OctreeStats {
            nodes: self.nodes.len(),
            ..Default::default()
        };
        for n in &self.nodes {
            if n.is_leaf() {
                s.leaves += 1;
                s.over_full_leaves += (n.count > self.max_leaf) as usize;
                s.depth = s.depth.max(n.depth as usize + 1);
            } else if n.children == 1 {
                s.single_child += 1;
            }
        }
        s
    }

    /// The `k` points nearest to `q` into `out` (cleared first): `(squared distance, input
    /// index)` in increasing order, ties by index, as [`crate::knn_brute`]; all points when
    /// `k >= len`.
    pub fn knn(&self, q: Vec3, k: usize, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        begin_query(q, out)?;
        let k = k.min(self.points.len());
        if k == 0 {
            return Ok(());
        }
        let mut best = Nearest::new(k);
        let mut stack: Vec<(u32, f32)> = Vec::with_capacity(256);
        stack.push((0, box_dist2(q, &self.nodes[0].bounds)));
        let mut kids = [(0u32, 0u32); 8];
        while let Some((n, bound)) = stack.pop() {
            if best.pruned(bound) {
                continue;
            }
            let node = &self.nodes[n as usize];
            if node.is_leaf() {
                let (f, c) = (node.first as usize, node.count as usize);
                best.offer_leaf(q, &self.points[f..f + c], &self.ids[f..f + c]);
                continue;
            }
            // Children by bound, farthest pushed first so the nearest is visited next.
            let m = node.children as usize;
            for (i, kid) in kids[..m].iter_mut().enumerate() {
                let c = node.child + i as u32;
                *kid = (box_dist2(q, &self.nodes[c as usize].bounds).to_bits(), c);
            }
            kids[..m].sort_unstable();
            for &(b, c) in kids[..m].iter().rev() {
                let b = f32::from_bits(b);
                if !best.pruned(b) {
                    stack.push((c, b));
                }
            }
        }
        best.finish(out);
        Ok(())
    }

    /// Every point within squared distance `r2` of `q` into `out` (cleared first):
    /// `(squared distance, input index)` in increasing order.
    pub fn within(&self, q: Vec3, r2: f32, out: &mut Vec<(f32, u32)>) -> Result<(), PointError> {
        begin_query(q, out)?;
        if self.nodes.is_empty() || r2.is_nan() || r2 < 0.0 {
            return Ok(());
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
                within_leaf(
                    &mut keys,
                    q,
                    r2,
                    &self.points[f..f + c],
                    &self.ids[f..f + c],
                );
            } else {
                stack.extend(node.child..node.child + node.children as u32);
            }
        }
        keys.sort_unstable();
        out.extend(keys.into_iter().map(unkey));
        Ok(())
    }

    /// Checks the tree against the `points` it was built from: the sorted points are the
    /// input permuted; the root is the depth-0 cell of every point; each inner node's
    /// children are contiguous, one depth deeper, in increasing octant order, and partition
    /// its range into the points whose next code digit is their octant; every node's points
    /// share their top `3 * depth` code bits (recomputed from the points); leaves hold 1 to
    /// `max_leaf` points or points of one code, inner nodes more than `max_leaf` of several
    /// codes; every node's bounds are its points' box; every node is reachable once.
    pub fn validate(&self, points: &[Vec3]) -> Result<(), PointError> {
        let bad = |s: String| Err(PointError::Invalid(s));
        crate::points::check_permutation(&self.points, &self.ids, points)?;
        if points.is_empty() {
            return if self.nodes.is_empty() {
                Ok(())
            } else {
                bad("nodes without points".into())
            };
        }
        let bounds = points.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p));
        let q = MortonQuantizer::with_grid(&bounds, MortonGrid::Box);
        let codes: Vec<u64> = self.points.iter().map(|&p| q.code63(p)).collect();
        if codes.windows(2).any(|w| w[0] > w[1]) {
            return bad("points are not in Morton order".into());
        }
        // (node, expected first, expected count, expected depth)
        let mut stack = vec![(0usize, 0u32, points.len() as u32, 0u8)];
        let mut visited = 0;
        while let Some((n, first, count, depth)) = stack.pop() {
            visited += 1;
            let Some(node) = self.nodes.get(n) else {
                return bad(format!("node {n} out of range"));
            };
            if node.first != first || node.count != count || node.depth != depth {
                return bad(format!(
                    "node {n}: range {}+{} depth {}, expected {first}+{count} depth {depth}",
                    node.first, node.count, node.depth
                ));
            }
            let (lo, hi) = (first as usize, (first + count) as usize);
            if count == 0 {
                return bad(format!("node {n} is empty"));
            }
            let shift = 3 * (OCTREE_MAX_DEPTH - depth) as u32;
            let prefix = |c: u64| c.checked_shr(shift).unwrap_or(0);
            if depth > OCTREE_MAX_DEPTH || prefix(codes[lo]) != prefix(codes[hi - 1]) {
                return bad(format!("node {n}: points of several depth-{depth} cells"));
            }
            let b = self.points[lo..hi]
                .iter()
                .fold(Aabb::EMPTY, |b, &p| b.grow(p));
            if node.bounds != b {
                return bad(format!("node {n}: bounds are not its points' box"));
            }
            let one_code = codes[lo] == codes[hi - 1];
            if node.is_leaf() {
                if node.child != 0 || node.octants != 0 {
                    return bad(format!("leaf {n} has children"));
                }
                if count > self.max_leaf && !one_code {
                    return bad(format!("leaf {n}: {count} points of several codes"));
                }
                continue;
            }
            if count <= self.max_leaf || one_code {
                return bad(format!("node {n}: {count} points should be a leaf"));
            }
            let (c0, m) = (node.child as usize, node.children as usize);
            if c0 <= n || c0 + m > self.nodes.len() || node.octants.count_ones() as usize != m {
                return bad(format!(
                    "node {n}: children {c0}+{m}, octants {:b}",
                    node.octants
                ));
            }
            let mut at = first;
            let mut octs = (0..8u8).filter(|o| node.octants >> o & 1 == 1);
            for c in c0..c0 + m {
                let ch = &self.nodes[c];
                let o = octs.next().expect("as many octants as children");
                let (a, z) = (at as usize, (at + ch.count) as usize);
                if ch.count == 0 || z > hi {
                    return bad(format!("node {n}: children do not split its range"));
                }
                if let Some(p) = (a..z).find(|&p| digit(codes[p], depth) != o) {
                    return bad(format!("node {n}: position {p} is not in octant {o}"));
                }
                stack.push((c, at, ch.count, depth + 1));
                at += ch.count;
            }
            if at != first + count {
                return bad(format!("node {n}: children do not cover its range"));
            }
        }
        if visited != self.nodes.len() {
            return bad(format!("{} nodes, {visited} reachable", self.nodes.len()));
        }
        Ok(())
    }
}

/// A finished subtree that has become a child of an octree node: a leaf range or a
/// written node, with what its parent needs (its points' range, box and first code).
#[derive(Clone, Copy, Debug)]
struct Closed {
    /// The written node, or `None` for a leaf.
    node: Option<u32>,
    first: u32,
    count: u32,
    first_code: u64,
    bounds: Aabb,
}

/// A subtree on the octree writer's stack.
#[derive(Clone, Debug)]
struct OSub {
    first: u32,
    count: u32,
    first_code: u64,
    last_code: u64,
    bounds: Aabb,
    /// The open octree node this subtree's radix joins make: its split digit and the
    /// children gathered so far; `None` for one point, or points of one code.
    group: Option<(u32, Vec<Closed>)>,
}

/// An octree node as [`OctreeStream`] writes it: its depth and its children (1 to 8).
#[derive(Clone, Debug)]
struct WrittenOct {
    depth: u8,
    children: Vec<Closed>,
}

/// The streaming octree writer behind the \[P2\] Algorithm 1 emitter: the octree of
/// [`Octree::build`] from the radix-tree joins the emitter makes, bottom-up (Karras §4's
/// grouping of the radix levels, done as the joins stream out).
///
/// Its stack mirrors the emitter's as [`crate::PointStream`]'s does. A join whose two
/// halves differ first in code digit `t` (the left half's last and the right half's first
/// code) is part of the octree node of digit `t`: it gathers its halves' children, where a
/// half that is itself an open node of digit `t` gives its gathered children and any
/// other half is closed into one child. Closing a subtree under a node of digit `t_p`
/// makes a leaf when it holds at most `max_leaf` points or points of one code; otherwise
/// it writes its open node (digit `t`, depth `20 - t`) and `t_p - t - 1` single-child
/// nodes above it, the cells between. The root is closed under a virtual digit 21. A node
/// is thus written when its parent's digit is known, with at most 8 children held per open
/// node on the stack.
#[derive(Clone, Debug)]
pub struct OctreeStream {
    max_leaf: u32,
    /// The points read and the open subtrees.
    open: OpenStack<OSub>,
    nodes: Vec<WrittenOct>,
    /// Children of the written nodes, in all.
    children: usize,
    /// The closed root, once [`OctreeStream::close_root`] ran.
    root: Option<Closed>,
}

/// Digit of a cell depth's children (digit `20 - depth`), for the virtual root parent 21.
const ROOT_PARENT_DIGIT: u32 = OCTREE_MAX_DEPTH as u32;

impl OctreeStream {
    /// A writer with leaves of at most `max_leaf` points.
    pub fn new(max_leaf: u32) -> Result<Self, PointError> {
        if max_leaf == 0 {
            return Err(PointError::ZeroLeaf);
        }
        Ok(Self {
            max_leaf,
            open: OpenStack::default(),
            nodes: Vec::new(),
            children: 0,
            root: None,
        })
    }

    /// The emitter read the next sorted point: input index `id`, Morton code `code`.
    pub fn read(&mut self, code: u64, id: u32, p: Vec3) {
        self.open.read(id, p, |first| OSub {
            first,
            count: 1,
            first_code: code,
            last_code: code,
            bounds: Aabb::new(p, p),
            group: None,
        });
    }

    /// The emitter reached the end of the stream.
    pub fn end(&mut self) {
        self.open.end();
    }

    /// Closes `s` into one child of a node of digit `parent`.
    fn close(&mut self, s: OSub, parent: u32) -> Result<Closed, PointError> {
        let mut c = Closed {
            node: None,
            first: s.first,
            count: s.count,
            first_code: s.first_code,
            bounds: s.bounds,
        };
        if s.count <= self.max_leaf || s.first_code == s.last_code {
            return Ok(c);
        }
        let Some((t, children)) = s.group else {
            return Err(PointError::Stream(
                "a subtree of several codes without a node".into(),
            ));
        };
        if t >= parent {
            return Err(PointError::Stream(format!(
                "digit {t} under digit {parent}"
            )));
        }
        let depth = |t: u32| (OCTREE_MAX_DEPTH as u32 - 1 - t) as u8;
        self.children += children.len();
        self.nodes.push(WrittenOct {
            depth: depth(t),
            children,
        });
        c.node = Some(self.nodes.len() as u32 - 1);
        // The single-child cells between this node and its parent's child cell.
        for d in t + 1..parent {
            let inner = c;
            self.children += 1;
            self.nodes.push(WrittenOct {
                depth: depth(d),
                children: vec![inner],
            });
            c.node = Some(self.nodes.len() as u32 - 1);
        }
        Ok(c)
    }

    /// The children that half `s` gives a node of digit `t`.
    fn expand(&mut self, mut s: OSub, t: u32, into: &mut Vec<Closed>) -> Result<(), PointError> {
        match s.group.take() {
            Some((g, kids)) if g == t => into.extend(kids),
            group => {
                s.group = group;
                let c = self.close(s, t)?;
                into.push(c);
            }
        }
        Ok(())
    }

    /// The emitter emitted `n`: join the two newest subtrees.
    pub fn join(&mut self, n: &EmittedNode) -> Result<(), PointError> {
        let (Some(r), Some(l)) = (self.open.stack.pop(), self.open.stack.pop()) else {
            return Err(PointError::Stream(
                "a node with fewer than two subtrees".into(),
            ));
        };
        if n.aabbs != [l.bounds, r.bounds] || l.first + l.count != r.first {
            return Err(PointError::Stream(format!(
                "node over {}+{} and {}+{} differs from the emitter's",
                l.first, l.count, r.first, r.count
            )));
        }
        let mut s = OSub {
            first: l.first,
            count: l.count + r.count,
            first_code: l.first_code,
            last_code: r.last_code,
            bounds: l.bounds.union(r.bounds),
            group: None,
        };
        if l.last_code != r.first_code {
            let t = (63 - (l.last_code ^ r.first_code).leading_zeros()) / 3;
            let mut kids = Vec::with_capacity(8);
            self.expand(l, t, &mut kids)?;
            self.expand(r, t, &mut kids)?;
            if kids.len() > 8 {
                return Err(PointError::Stream(format!("{} children", kids.len())));
            }
            s.group = Some((t, kids));
        }
        self.open.push(s);
        Ok(())
    }

    /// Octree nodes written so far (single-child cells included).
    pub fn written(&self) -> usize {
        self.nodes.len()
    }

    /// Children of the nodes written so far, in all.
    pub fn written_children(&self) -> usize {
        self.children
    }

    /// Ends the stream and closes the root, writing its node (and the single-child cells
    /// above it) now rather than in [`OctreeStream::finish`]. Errors unless the stream
    /// ended with one subtree or none.
    pub fn close_root(&mut self) -> Result<(), PointError> {
        self.end();
        if self.root.is_some() {
            return Ok(());
        }
        match self.open.stack.len() {
            0 if self.open.ids.is_empty() => Ok(()),
            1 => {
                let s = self.open.stack.pop().expect("one subtree");
                self.root = Some(self.close(s, ROOT_PARENT_DIGIT)?);
                Ok(())
            }
            k => Err(PointError::Stream(format!(
                "{k} subtrees left at the end of the stream"
            ))),
        }
    }

    /// Deepest stack so far.
    pub fn max_stack_depth(&self) -> usize {
        self.open.max_stack
    }

    /// The finished octree in [`Octree`]'s layout, and the number of nodes written in all
    /// (the root's included). Errors unless the stream ended with one subtree (none for no
    /// points).
    pub fn finish(mut self) -> Result<(Octree, usize), PointError> {
        self.close_root()?;
        let mut out = Vec::with_capacity(self.nodes.len() * 9 / 8 + 1);
        if let Some(root) = self.root {
            out.push(placeholder());
            self.lay_out(&root, 0, 0, &mut out)?;
        }
        let written = self.nodes.len();
        Ok((
            Octree {
                points: self.open.points,
                ids: self.open.ids,
                nodes: out,
                max_leaf: self.max_leaf,
            },
            written,
        ))
    }

    /// Writes `c` as node `id` (allocated) at `depth`, its children contiguous at the end,
    /// in the allocation order of [`Octree::build`].
    fn lay_out(
        &self,
        c: &Closed,
        depth: u8,
        id: usize,
        out: &mut Vec<OctNode>,
    ) -> Result<(), PointError> {
        let mut n = OctNode {
            bounds: c.bounds,
            first: c.first,
            count: c.count,
            child: 0,
            children: 0,
            octants: 0,
            depth,
        };
        if let Some(k) = c.node {
            let w = &self.nodes[k as usize];
            if w.depth != depth {
                return Err(PointError::Stream(format!(
                    "node written at depth {}, placed at {depth}",
                    w.depth
                )));
            }
            let base = out.len();
            out.resize(base + w.children.len(), placeholder());
            for (i, ch) in w.children.iter().enumerate() {
                n.octants |= 1 << digit(ch.first_code, depth);
                self.lay_out(ch, depth + 1, base + i, out)?;
            }
            n.child = base as u32;
            n.children = w.children.len() as u8;
        }
        out[id] = n;
        Ok(())
    }
}

fn placeholder() -> OctNode {
    OctNode {
        bounds: Aabb::EMPTY,
        first: 0,
        count: 0,
        child: 0,
        children: 0,
        octants: 0,
        depth: 0,
    }
}

impl PointSink for OctreeStream {
    fn read_point(&mut self, code: u64, id: u32, p: Vec3) {
        self.read(code, id, p);
    }
    fn end_of_stream(&mut self) {
        self.end();
    }
    /// Every emitted node joins a group; when the octree writes a node is decided later,
    /// so none counts as written here (`finish` reports the nodes written).
    fn join_node(&mut self, n: &EmittedNode) -> Result<bool, PointError> {
        self.join(n).map(|()| false)
    }
}

impl Octree {
    /// Builds the octree as a MergeTree octree mode would: the sorted points stream
    /// through the \[P2\] Algorithm 1 emitter (keys (code, index in the code's run)) into an
    /// [`OctreeStream`]. Equal to [`Octree::build`]; returns the tree and the number of
    /// nodes written. The same errors.
    pub fn build_streaming(
        points: &[Vec3],
        max_leaf: usize,
    ) -> Result<(Octree, usize), PointError> {
        let Sorted {
            codes,
            ids,
            points: sorted,
            ..
        } = checked_sort(points, max_leaf)?;
        let mut w = OctreeStream::new(max_leaf.min(u32::MAX as usize) as u32)?;
        emit_points(&codes, &ids, &sorted, &mut w)?;
        w.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::{dist2, key, sort_points, tests::cloud};
    use crate::{knn_brute, PointTree};
    use proptest::prelude::*;

    /// Builds, validates and checks kNN and radius queries against brute force.
    fn check(points: &[Vec3], queries: &[Vec3], ks: &[usize], max_leaf: usize) {
        let t = Octree::build(points, max_leaf).unwrap();
        t.validate(points).unwrap();
        let mut out = Vec::new();
        for &q in queries {
            for &k in ks {
                t.knn(q, k, &mut out).unwrap();
                assert_eq!(out, knn_brute(points, q, k).unwrap(), "q {q:?} k {k}");
            }
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
            let pts = cloud(n, n as u64 + 7, 10.0);
            let mut qs = cloud(20, 98, 12.0);
            qs.extend_from_slice(&pts[..pts.len().min(5)]);
            qs.push(Vec3::splat(-50.0));
            check(&pts, &qs, &[0, 1, 2, 7, 32, n, n + 5], leaf);
        }
    }

    #[test]
    fn duplicates_lattices_and_identical_points() {
        let mut pts = cloud(300, 5, 4.0);
        pts.extend_from_within(..);
        pts.extend_from_within(..150);
        let lattice: Vec<Vec3> = cloud(2000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
        let qs = [Vec3::ZERO, Vec3::splat(2.0), Vec3::new(1.5, 0.5, 3.0)];
        for leaf in [1, 3, 8] {
            check(&pts, &qs, &[1, 2, 3, 10, 100], leaf);
            check(&lattice, &qs, &[1, 2, 3, 10, 100, 2000], leaf);
        }
        // All points identical: one code, so the root is one leaf of every point.
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 1000];
        let t = Octree::build(&same, 4).unwrap();
        t.validate(&same).unwrap();
        assert_eq!(t.nodes().len(), 1);
        assert_eq!(t.stats().over_full_leaves, 1);
        check(&same, &qs, &[0, 1, 5, 999, 1000, 1001], 4);
        let line: Vec<Vec3> = (0..500)
            .map(|i| Vec3::new(0.5, i as f32 * 0.1, -2.0))
            .collect();
        check(&line, &qs, &[1, 2, 9, 600], 1);
        check(&line, &qs, &[1, 2, 9, 600], 4);
    }

    #[test]
    fn lattice_gives_the_exact_octree() {
        // A 4^3 lattice over [0, 3]: the depth-1 cells are its 2x2x2 blocks and the
        // depth-2 cells single points.
        let pts: Vec<Vec3> = (0..64)
            .map(|i| Vec3::new((i % 4) as f32, (i / 4 % 4) as f32, (i / 16) as f32))
            .collect();
        let t = Octree::build(&pts, 1).unwrap();
        t.validate(&pts).unwrap();
        let s = t.stats();
        assert_eq!((s.nodes, s.leaves, s.single_child, s.depth), (73, 64, 0, 3));
        assert_eq!(t.nodes()[0].octants, 0xff);
        // Octant 0b100 (x high, y and z low) of the root is the block x in 2..=3, y, z in 0..=1.
        let c = &t.nodes()[t.nodes()[0].child as usize + 4];
        assert_eq!(
            c.bounds,
            Aabb::new(Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.0, 1.0, 1.0))
        );
        let t8 = Octree::build(&pts, 8).unwrap();
        t8.validate(&pts).unwrap();
        assert_eq!((t8.stats().nodes, t8.stats().depth), (9, 2));
        // Two points close together and one far: a chain of single-child cells. B's x cell
        // is floor(0.001 / 8 * 2^21) = 262 = 0b1_0000_0110, so A and B first differ in
        // digit 8 (x bit 8), below the cell of depth 12. Nodes: the root, leaf C, the
        // cells of depth 1..=11 holding A and B (single children), the depth-12 cell, and
        // the two leaves.
        let chain = [Vec3::ZERO, Vec3::new(0.001, 0.0, 0.0), Vec3::splat(8.0)];
        let t = Octree::build(&chain, 1).unwrap();
        t.validate(&chain).unwrap();
        let s = t.stats();
        assert_eq!(
            (s.nodes, s.leaves, s.single_child, s.depth),
            (16, 3, 11, 14)
        );
        assert_eq!(t.nodes()[0].octants, 0b1000_0001);
    }

    /// Karras §4: with distinct codes and one point per leaf, the octree's nodes with two
    /// or more children are the radix tree's nodes that are the topmost of their split
    /// digit (the root, or a node whose parent splits in a higher digit).
    #[test]
    fn octree_groups_the_radix_tree_levels() {
        for (n, seed) in [(50, 1u64), (3000, 2), (20_000, 3)] {
            let pts = cloud(n, seed, 1.0);
            let s = sort_points(&pts);
            assert!(s.codes.windows(2).all(|w| w[0] < w[1]), "distinct codes");
            let kd = PointTree::build(&pts, 1).unwrap();
            let digit_of = |k: &crate::PointNode| {
                let (a, z) = (
                    s.codes[k.first as usize],
                    s.codes[(k.first + k.count - 1) as usize],
                );
                (63 - (a ^ z).leading_zeros()) / 3
            };
            let mut tops = 0;
            let mut stack = vec![(0usize, u32::MAX)];
            while let Some((i, parent_digit)) = stack.pop() {
                let k = &kd.nodes()[i];
                if k.is_leaf() {
                    continue;
                }
                let d = digit_of(k);
                tops += (d != parent_digit) as usize;
                stack.push((k.left as usize, d));
                stack.push((k.right as usize, d));
            }
            let oct = Octree::build(&pts, 1).unwrap();
            oct.validate(&pts).unwrap();
            let st = oct.stats();
            assert_eq!(st.nodes - st.leaves - st.single_child, tops, "n {n}");
            assert_eq!(st.leaves, n);
            assert_eq!(oct.ids(), kd.ids());
        }
    }

    #[test]
    fn empty_bad_input_and_broken_trees() {
        let t = Octree::build(&[], 4).unwrap();
        t.validate(&[]).unwrap();
        let mut out = vec![(1.0, 1)];
        t.knn(Vec3::ZERO, 5, &mut out).unwrap();
        assert!(out.is_empty());
        t.within(Vec3::ZERO, 1.0, &mut out).unwrap();
        assert!(out.is_empty());
        let pts = cloud(100, 1, 1.0);
        let mut bad = pts.clone();
        bad[7].z = f32::INFINITY;
        assert!(matches!(
            Octree::build(&bad, 4),
            Err(PointError::NonFinite { index: 7, .. })
        ));
        assert_eq!(Octree::build(&pts, 0).unwrap_err(), PointError::ZeroLeaf);
        let t = Octree::build(&pts, 4).unwrap();
        assert!(matches!(
            t.knn(Vec3::new(0.0, f32::NAN, 0.0), 1, &mut out),
            Err(PointError::NonFiniteQuery(_))
        ));
        let mut b = t.clone();
        b.ids.swap(0, 1);
        assert!(b.validate(&pts).is_err());
        let mut b = t.clone();
        let leaf = b.nodes.iter().position(|n| n.is_leaf()).unwrap();
        b.nodes[leaf].count += 1;
        assert!(b.validate(&pts).is_err());
        let mut b = t.clone();
        b.max_leaf = 1;
        assert!(b.validate(&pts).is_err());
        let mut b = t.clone();
        b.nodes[0].octants ^= 0x81;
        assert!(b.validate(&pts).is_err());
        let mut b = t.clone();
        b.nodes[1].bounds.max.x += 1.0;
        assert!(b.validate(&pts).is_err());
    }

    #[test]
    fn streaming_octree_equals_top_down_octree() {
        let mut dup = cloud(300, 5, 4.0);
        dup.extend_from_within(..);
        dup.extend_from_within(..150);
        let lattice: Vec<Vec3> = cloud(3000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
        let lat4: Vec<Vec3> = (0..64)
            .map(|i| Vec3::new((i % 4) as f32, (i / 4 % 4) as f32, (i / 16) as f32))
            .collect();
        let sets = [
            vec![],
            vec![Vec3::ONE],
            cloud(2, 1, 1.0),
            cloud(1000, 2, 10.0),
            cloud(30_000, 3, 1.0),
            dup,
            lattice,
            lat4,
            vec![Vec3::ZERO, Vec3::new(0.001, 0.0, 0.0), Vec3::splat(8.0)],
            vec![Vec3::new(1.0, 2.0, 3.0); 1000],
        ];
        for pts in &sets {
            for leaf in [1, 2, 3, 8, 16] {
                let top = Octree::build(pts, leaf).unwrap();
                let (st, written) = Octree::build_streaming(pts, leaf).unwrap();
                st.validate(pts).unwrap();
                assert_eq!(st.ids, top.ids, "n {} leaf {leaf}", pts.len());
                assert_eq!(st.nodes, top.nodes, "n {} leaf {leaf}", pts.len());
                assert_eq!(written, top.stats().nodes - top.stats().leaves);
            }
        }
        // The chain case by hand: 13 inner nodes written (the root, 11 single-child cells
        // and the depth-12 cell).
        let chain = [Vec3::ZERO, Vec3::new(0.001, 0.0, 0.0), Vec3::splat(8.0)];
        assert_eq!(Octree::build_streaming(&chain, 1).unwrap().1, 13);
        let mut w = OctreeStream::new(1).unwrap();
        w.read(0, 0, Vec3::ZERO);
        w.read(7, 1, Vec3::ONE);
        w.end();
        w.read(9, 2, Vec3::ONE);
        w.end();
        assert!(matches!(w.finish(), Err(PointError::Stream(_))));
        assert!(OctreeStream::new(0).is_err());
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
            let pts: Vec<Vec3> = raw.iter().map(|a| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32) * 0.5).collect();
            let q = Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32) * 0.25;
            let t = Octree::build(&pts, leaf).unwrap();
            prop_assert!(t.validate(&pts).is_ok());
            let mut out = Vec::new();
            t.knn(q, k, &mut out).unwrap();
            prop_assert_eq!(out, knn_brute(&pts, q, k).unwrap());
        }

        #[test]
        fn knn_equals_brute_force_on_wide_floats(
            raw in prop::collection::vec(prop::array::uniform3(-1e20f32..1e20), 1..120),
            scale in prop::sample::select(vec![1e-30f32, 1e-3, 1.0, 1e15, 1e18]),
            q in prop::array::uniform3(-1e20f32..1e20),
            k in 0usize..20,
        ) {
            let pts: Vec<Vec3> = raw.iter().map(|a| Vec3::from(*a) * scale).collect();
            let q = Vec3::from(q) * scale;
            let t = Octree::build(&pts, 2).unwrap();
            prop_assert!(t.validate(&pts).is_ok());
            let mut out = Vec::new();
            t.knn(q, k, &mut out).unwrap();
            prop_assert_eq!(out, knn_brute(&pts, q, k).unwrap());
        }
    }
}
