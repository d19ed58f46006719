//! The point k-d tree written from a sorted stream, behind the hierarchy emitter of \[P2\]
//! Algorithm 1 (issue 18, part 3: the MergeTree point mode).
//!
//! The thesis (line 991) proposes that "it is straightforward to modify an LBVH builder to
//! output k-d trees of points [Kar12]". The MergeTree emitter ([`crate::Emitter`]) already
//! builds the binary radix tree of its sort keys, one stack operation per step: fed the
//! points' Morton codes with the index inside each run of equal codes as the tie field
//! (every key distinct, one point per leaf), it emits exactly the radix tree that
//! [`crate::PointTree`] builds top-down, bottom-up in postorder. [`PointStream`] is the
//! small unit behind it that turns that stream into the point tree:
//!
//! - It keeps a stack of finished subtrees, mirroring the emitter's: every point read
//!   becomes a one-point subtree, pushed once the emitter has read the point after it (the
//!   emitter reads one point ahead before it joins the subtrees that end before it), and
//!   every emitted node joins the two newest subtrees. The node's child boxes must equal
//!   the two subtrees' boxes (checked: an error if the writer is driven out of step).
//! - **Leaf collapse.** A join of two leaves with at most `max_leaf` points together is a
//!   leaf, with no node written. Since a subtree of at most `max_leaf` points has only such
//!   subtrees below it, this makes exactly the nodes of at most `max_leaf` points leaves,
//!   the top-down rule of [`crate::PointTree`].
//! - **Split plane.** Every subtree carries the codes of its first and last point; a join
//!   of different codes (the left subtree's last and the right's first) splits on the
//!   axis of their highest differing bit at the grid plane of the right half's cell,
//!   clamped between the children's boxes, as [`crate::PointTree`] does; equal codes make
//!   an index split with no plane.
//!
//! Nodes are written in emission order (postorder): [`PointStream::finish`] lays them out
//! in the depth-first order of [`crate::PointTree`], and the result equals
//! [`crate::PointTree::build`] of the same points, field for field (the test
//! `streaming_tree_equals_top_down_tree`).

use crate::hlbvh::{EmittedNode, Emitter, Prim, Step};
use crate::points::{
    checked_sort, clamp_plane, Grid, PointError, PointNode, PointTree, Sorted, NO_AXIS,
};
use geom::{Aabb, Vec3};

/// A child of a written node: another written node or a leaf range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointRef {
    /// The node written `n`-th (0-based, emission order).
    Node(u32),
    /// A leaf of `count` points at sorted positions `first..first + count`.
    Leaf {
        /// First sorted position.
        first: u32,
        /// Number of points.
        count: u32,
    },
}

/// An inner node as [`PointStream`] writes it: what a hardware point k-d node holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WrittenNode {
    /// Boxes of the left and right child's points.
    pub boxes: [Aabb; 2],
    /// Left and right child.
    pub children: [PointRef; 2],
    /// Split axis (0 x, 1 y, 2 z), or [`NO_AXIS`] for an index split.
    pub axis: u8,
    /// Split plane (NaN for an index split): left points `<=`, right points `>=`.
    pub plane: f32,
}

/// A finished subtree on the writer's stack.
#[derive(Clone, Copy, Debug)]
struct Sub {
    first: u32,
    count: u32,
    first_code: u64,
    last_code: u64,
    bounds: Aabb,
    node: Option<u32>,
}

impl Sub {
    fn as_ref(&self) -> PointRef {
        match self.node {
            Some(n) => PointRef::Node(n),
            None => PointRef::Leaf {
                first: self.first,
                count: self.count,
            },
        }
    }
}

/// What [`PointStream::join`] did with an emitted node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Joined {
    /// It wrote an inner node (the `n`-th).
    Written(u32),
    /// Its two children were leaves small enough to make one leaf: nothing written.
    Collapsed,
}

/// What a point writer keeps of the stream (the k-d writer [`PointStream`] and the
/// octree's `OctreeStream` alike): the sorted points read so far (input indices and
/// coordinates), the stack of open subtrees the emitter's joins have not consumed yet, and
/// the newest point's subtree, held until the next read or the end of the stream (the
/// emitter pushes a point only then). `S` is the writer's subtree record.
#[derive(Clone, Debug)]
pub(crate) struct OpenStack<S> {
    /// Input index of each point read, in sorted order.
    pub(crate) ids: Vec<u32>,
    /// The points read, in sorted order.
    pub(crate) points: Vec<Vec3>,
    /// Open subtrees, oldest first.
    pub(crate) stack: Vec<S>,
    pending: Option<S>,
    /// Deepest stack seen.
    pub(crate) max_stack: usize,
}

impl<S> Default for OpenStack<S> {
    fn default() -> Self {
        Self {
            ids: Vec::new(),
            points: Vec::new(),
            stack: Vec::new(),
            pending: None,
            max_stack: 0,
        }
    }
}

impl<S> OpenStack<S> {
    /// The emitter read point `p` of input index `id`: the previous point's subtree goes
    /// onto the stack and `make(position)` (the point's sorted position) is held.
    pub(crate) fn read(&mut self, id: u32, p: Vec3, make: impl FnOnce(u32) -> S) {
        let pos = self.ids.len() as u32;
        self.ids.push(id);
        self.points.push(p);
        if let Some(s) = self.pending.take() {
            self.push(s);
        }
        self.pending = Some(make(pos));
    }

    /// The end of the stream: the last point's subtree goes onto the stack.
    pub(crate) fn end(&mut self) {
        if let Some(s) = self.pending.take() {
            self.push(s);
        }
    }

    /// Pushes an open subtree.
    pub(crate) fn push(&mut self, s: S) {
        self.stack.push(s);
        self.max_stack = self.max_stack.max(self.stack.len());
    }
}

/// The streaming writer of the point k-d tree behind the emitter (see the module docs).
#[derive(Clone, Debug)]
pub struct PointStream {
    grid: Grid,
    max_leaf: u32,
    /// The points read and the open subtrees.
    open: OpenStack<Sub>,
    nodes: Vec<WrittenNode>,
    collapsed: u64,
}

impl PointStream {
    /// A writer for points whose codes quantize `bounds` (the points' box, as the unit's
    /// configuration register holds it) with leaves of at most `max_leaf` points.
    pub fn new(bounds: &Aabb, max_leaf: u32) -> Result<Self, PointError> {
        if max_leaf == 0 {
            return Err(PointError::ZeroLeaf);
        }
        Ok(Self {
            grid: Grid::new(bounds),
            max_leaf,
            open: OpenStack::default(),
            nodes: Vec::new(),
            collapsed: 0,
        })
    }

    /// The emitter read the next sorted point: input index `id`, Morton code `code`.
    pub fn read(&mut self, code: u64, id: u32, p: Vec3) {
        self.open.read(id, p, |first| Sub {
            first,
            count: 1,
            first_code: code,
            last_code: code,
            bounds: Aabb::new(p, p),
            node: None,
        });
    }

    /// The emitter reached the end of the stream (it read no more points).
    pub fn end(&mut self) {
        self.open.end();
    }

    /// The emitter emitted `n`: join the two newest subtrees.
    pub fn join(&mut self, n: &EmittedNode) -> Result<Joined, PointError> {
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
        let count = l.count + r.count;
        let bounds = l.bounds.union(r.bounds);
        let joined = if l.node.is_none() && r.node.is_none() && count <= self.max_leaf {
            self.collapsed += 1;
            (None, Joined::Collapsed)
        } else {
            let (axis, plane) = if l.last_code != r.first_code {
                let (axis, grid_plane) = self.grid.split(l.last_code, r.first_code);
                (axis, clamp_plane(grid_plane, axis, &l.bounds, &r.bounds))
            } else {
                (NO_AXIS, f32::NAN)
            };
            let id = self.nodes.len() as u32;
            self.nodes.push(WrittenNode {
                boxes: [l.bounds, r.bounds],
                children: [l.as_ref(), r.as_ref()],
                axis,
                plane,
            });
            (Some(id), Joined::Written(id))
        };
        self.open.push(Sub {
            first: l.first,
            count,
            first_code: l.first_code,
            last_code: r.last_code,
            bounds,
            node: joined.0,
        });
        Ok(joined.1)
    }

    /// Inner nodes written so far, in emission order.
    pub fn written(&self) -> &[WrittenNode] {
        &self.nodes
    }

    /// Joins that collapsed into leaves so far.
    pub fn collapsed(&self) -> u64 {
        self.collapsed
    }

    /// Deepest stack so far.
    pub fn max_stack_depth(&self) -> usize {
        self.open.max_stack
    }

    /// The finished tree in [`PointTree`]'s layout (depth-first, leaves as nodes). Errors
    /// unless the stream ended with one subtree (none for no points).
    pub fn finish(mut self) -> Result<PointTree, PointError> {
        self.end();
        let mut nodes = Vec::with_capacity(2 * self.nodes.len() + 1);
        match self.open.stack.as_slice() {
            [] if self.open.ids.is_empty() => {}
            [root] => {
                let root = *root;
                self.lay_out(root.as_ref(), root.bounds, &mut nodes);
            }
            s => {
                return Err(PointError::Stream(format!(
                    "{} subtrees left at the end of the stream",
                    s.len()
                )))
            }
        }
        Ok(PointTree {
            points: self.open.points,
            ids: self.open.ids,
            nodes,
            max_leaf: self.max_leaf,
        })
    }

    /// Appends subtree `r` (with box `bounds`) in depth-first order; returns its index.
    fn lay_out(&self, r: PointRef, bounds: Aabb, out: &mut Vec<PointNode>) -> u32 {
        let id = out.len();
        match r {
            PointRef::Leaf { first, count } => out.push(PointNode {
                bounds,
                first,
                count,
                axis: NO_AXIS,
                plane: f32::NAN,
                left: 0,
                right: 0,
            }),
            PointRef::Node(n) => {
                let w = self.nodes[n as usize];
                out.push(PointNode {
                    bounds,
                    first: 0,
                    count: 0,
                    axis: w.axis,
                    plane: w.plane,
                    left: 0,
                    right: 0,
                });
                let l = self.lay_out(w.children[0], w.boxes[0], out);
                let r = self.lay_out(w.children[1], w.boxes[1], out);
                let (ln, rn) = (out[l as usize], out[r as usize]);
                let node = &mut out[id];
                node.first = ln.first;
                node.count = ln.count + rn.count;
                node.left = l;
                node.right = r;
            }
        }
        id as u32
    }
}

/// Counts of a streaming build ([`PointTree::build_streaming`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PointStreamStats {
    /// Emitter steps (one stack operation each: what a unit does per cycle).
    pub steps: u64,
    /// Nodes the emitter emitted (one per point minus one).
    pub emitted: u64,
    /// Inner nodes written.
    pub written: u64,
    /// Emitted nodes collapsed into leaves.
    pub collapsed: u64,
    /// Deepest emitter stack.
    pub max_stack_depth: usize,
}

/// The emitter's tie field for the points: the index inside each run of equal codes.
pub(crate) fn run_ties(codes: &[u64]) -> impl Iterator<Item = u32> + '_ {
    let mut run = 0u32;
    codes.iter().enumerate().map(move |(i, &c)| {
        run = if i > 0 && codes[i - 1] == c {
            run + 1
        } else {
            0
        };
        run
    })
}

/// A writer behind the emitter of the point modes ([`PointStream`], the octree's
/// `OctreeStream`): it sees every point read, the end of the stream and every emitted node.
pub(crate) trait PointSink {
    /// A point read from the sorted stream.
    fn read_point(&mut self, code: u64, id: u32, p: Vec3);
    /// The end of the stream.
    fn end_of_stream(&mut self);
    /// An emitted node; true when the writer writes it as a node of its own.
    fn join_node(&mut self, n: &EmittedNode) -> Result<bool, PointError>;
}

impl PointSink for PointStream {
    fn read_point(&mut self, code: u64, id: u32, p: Vec3) {
        self.read(code, id, p);
    }
    fn end_of_stream(&mut self) {
        self.end();
    }
    fn join_node(&mut self, n: &EmittedNode) -> Result<bool, PointError> {
        Ok(matches!(self.join(n)?, Joined::Written(_)))
    }
}

/// Streams sorted points (`codes`, their input `ids`, the `sorted` points) through the
/// \[P2\] Algorithm 1 emitter ([`Emitter`], keys (code, index in the code's run)), one
/// step at a time, into `w`: the software model of the MergeTree point modes. Counts the
/// steps, the emitted and written nodes and the deepest stack (`collapsed` is left 0: the
/// writer knows it).
pub(crate) fn emit_points(
    codes: &[u64],
    ids: &[u32],
    sorted: &[Vec3],
    w: &mut impl PointSink,
) -> Result<PointStreamStats, PointError> {
    let mut em = Emitter::new(None);
    let mut input = codes
        .iter()
        .zip(run_ties(codes))
        .zip(ids.iter().zip(sorted));
    let mut st = PointStreamStats::default();
    loop {
        let prim = if em.needs_input() {
            match input.next() {
                Some(((&code, tie), (&id, &p))) => {
                    w.read_point(code, id, p);
                    Some(Prim {
                        code,
                        tie,
                        aabb: Aabb::new(p, p),
                    })
                }
                None => {
                    w.end_of_stream();
                    None
                }
            }
        } else {
            None
        };
        st.steps += 1;
        match em.step(prim) {
            Step::Emitted(n) => {
                st.emitted += 1;
                if w.join_node(&n)? {
                    st.written += 1;
                }
            }
            Step::Done => break,
            Step::Combined => {
                return Err(PointError::Stream("equal keys in the point stream".into()))
            }
            Step::Loaded | Step::Pushed | Step::Highlevel(_) => {}
        }
    }
    st.max_stack_depth = em.max_stack_depth();
    Ok(st)
}

impl PointTree {
    /// Builds the tree as the MergeTree point mode does: the sorted points stream through
    /// the \[P2\] Algorithm 1 emitter ([`Emitter`], keys (code, index in the code's run)),
    /// one step at a time, into a [`PointStream`]. Equal to [`PointTree::build`]; the same
    /// errors.
    pub fn build_streaming(
        points: &[Vec3],
        max_leaf: usize,
    ) -> Result<(PointTree, PointStreamStats), PointError> {
        let Sorted {
            codes,
            ids,
            points: sorted,
            ..
        } = checked_sort(points, max_leaf)?;
        let bounds = points.iter().fold(Aabb::EMPTY, |b, &p| b.grow(p));
        let mut w = PointStream::new(&bounds, max_leaf.min(u32::MAX as usize) as u32)?;
        let mut st = emit_points(&codes, &ids, &sorted, &mut w)?;
        st.collapsed = w.collapsed();
        Ok((w.finish()?, st))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hlbvh::EmitRef;
    use crate::points::tests::cloud;

    #[test]
    fn streaming_tree_equals_top_down_tree() {
        let mut dup = cloud(300, 5, 4.0);
        dup.extend_from_within(..);
        dup.extend_from_within(..150);
        let lattice: Vec<Vec3> = cloud(3000, 6, 4.0).into_iter().map(|p| p.floor()).collect();
        let sets = [
            vec![],
            vec![Vec3::ONE],
            cloud(2, 1, 1.0),
            cloud(1000, 2, 10.0),
            cloud(40_000, 3, 1.0),
            dup,
            lattice,
            vec![Vec3::new(1.0, 2.0, 3.0); 1000],
        ];
        for pts in &sets {
            for leaf in [1, 2, 3, 8, 16] {
                let top = PointTree::build(pts, leaf).unwrap();
                let (st, stats) = PointTree::build_streaming(pts, leaf).unwrap();
                st.validate(pts).unwrap();
                assert!(top.same_as(&st), "n {} leaf {leaf}", pts.len());
                let inner = top.nodes().iter().filter(|n| !n.is_leaf()).count() as u64;
                assert_eq!(stats.written, inner);
                assert_eq!(stats.emitted, pts.len().saturating_sub(1) as u64);
                assert_eq!(stats.written + stats.collapsed, stats.emitted);
            }
        }
    }

    #[test]
    fn hand_derived_stream_on_four_points() {
        // Four points on the x axis at 0, 1, 2, 3 (y = z = 0): x cells 0, 699050, 1398101
        // and 2^21 - 1 (bits 20 and 19: 00, 01, 10, 11). Keys differ first in x bit 20
        // between 1 and 2 and in x bit 19 inside each pair: the tree ((0 1) (2 3)).
        // Emitter steps: load 0; read 1 (level of bit 19) push 0; read 2 (bit 20): pop and
        // emit (0 1), push it; read 3 (bit 19): push 2; end: emit (2 3), emit the root,
        // root to the high-level output; done. 9 steps, 3 nodes.
        let pts: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let (t, s) = PointTree::build_streaming(&pts, 1).unwrap();
        assert_eq!(
            s,
            PointStreamStats {
                steps: 9,
                emitted: 3,
                written: 3,
                collapsed: 0,
                max_stack_depth: 2,
            }
        );
        let planes: Vec<(u8, f32)> = t
            .nodes()
            .iter()
            .filter(|n| !n.is_leaf())
            .map(|n| (n.axis, n.plane))
            .collect();
        // Grid planes at x = 1.5 (root), 0.75 and 2.25, clamped into [0, 1] and [2, 3].
        assert_eq!(planes, [(0, 1.5), (0, 0.75), (0, 2.25)]);
        // With leaves of 2 the two pair nodes collapse: one node written.
        let (t2, s2) = PointTree::build_streaming(&pts, 2).unwrap();
        assert_eq!((s2.written, s2.collapsed), (1, 2));
        assert_eq!(t2.nodes().len(), 3);
    }

    #[test]
    fn writer_rejects_an_out_of_step_stream() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let mut w = PointStream::new(&b, 1).unwrap();
        w.read(0, 0, Vec3::ZERO);
        w.read(7, 1, Vec3::ONE);
        let n = EmittedNode {
            aabbs: [b, b],
            children: [
                EmitRef::Leaf { first: 0, count: 1 },
                EmitRef::Leaf { first: 1, count: 1 },
            ],
        };
        // Only one subtree is finished (the second point is still the emitter's input).
        assert!(matches!(w.join(&n), Err(PointError::Stream(_))));
        assert!(PointStream::new(&b, 0).is_err());
        let mut w = PointStream::new(&b, 1).unwrap();
        w.read(0, 0, Vec3::ZERO);
        w.read(7, 1, Vec3::ONE);
        w.read(7, 2, Vec3::ONE);
        w.end();
        assert!(matches!(w.finish(), Err(PointError::Stream(_))));
    }
}
