//! Streaming collapse of the hierarchy emitter's binary nodes into 4-wide [`Mbvh4`] nodes
//! (issue 18 part 2): a collapse that consumes the nodes of \[P2\] Algorithm 1 in the order
//! the emitter outputs them (every node after both of its children, [`crate::Emitter`]) and
//! writes 128-byte [`Node4`]s (\[P4\] §3.1) with a bounded buffer.
//!
//! The thesis leaves this open: \[P4\] builds its MBVH4s with Wald's top-down splitting
//! because it "appears straightforward to implement in hardware by adding extra bookkeeping
//! to the builder unit by Doyle" (thesis line 2493), and ch. 5 asks whether "stream
//! representation could stretch further to compute ... hierarchy collapsing into an MBVH"
//! (line 987).
//!
//! # Why not the offline collapse
//! The greedy collapse of [`crate::Collapse`] (thesis line 917: pull up the child of
//! largest area) works top-down: whether a binary node becomes a wide node or is pulled
//! into its parent's depends on the role of its parent and grandparent, and so on up to the
//! root, which the emitter outputs last. Streaming it exactly would hold the whole tree.
//!
//! # The rule
//! Bottom-up instead: every binary subtree whose parent has not arrived yet is kept *open*,
//! as the up-to-four (box, reference) slots it would give a wide node. When binary node `b`
//! arrives with children `c0`, `c1` (a leaf takes one slot; an inner child is one of the
//! open subtrees), `b` takes its inner children's slots (*opens* them) if they fit in four;
//! otherwise it *closes* children, writing each closed child's slots as one wide node that
//! then takes one slot of `b`:
//! 1. both children open if their slots fit (`s0 + s1 <= 4`);
//! 2. else, with two inner children, close the one of smaller box area (`c1` on a tie), and
//!    if the other still does not fit (`s + 1 > 4`), close the larger one instead;
//! 3. else close every inner child (two closed children take two slots).
//!
//! Closing the smaller child first is the SAH's preference: a wide node costs in
//! proportion to its box area, so the node kept (opened) should be the large one, the same
//! preference as the offline collapse's largest-area pull-up. The root's slots are written
//! last, as the root node. Slots keep the emitter's (Morton) order.
//!
//! The rule packs the bottom of the tree: its first wide nodes are full (four leaves),
//! while the offline collapse fills the top and leaves what remains at the bottom. On a
//! perfect binary tree of 16 leaves both give the same tree (tested); on one of 8 leaves
//! the streaming collapse gives 3 nodes (a root over two full nodes) where the offline one
//! gives 5 (a full root over four nodes of two leaves).
//!
//! # Buffer bound
//! The open subtrees are the completed inner subtrees whose parent has not been consumed.
//! After any prefix of the emission order these are subtrees that were, at that point of
//! emission, on the emitter's stack or in its input register (a subtree leaves both only by
//! being joined into its parent), so at most `D + 1` are open, `D` the emitter's deepest
//! stack ([`crate::Emitter::max_stack_depth`], at most 96 levels of the sort key); they form
//! a stack (a node's inner children are the last two opened). Each holds at most four
//! 32-byte slots (a 24-byte box and an 8-byte reference): one 128-byte node of storage per
//! open subtree, `128 (D + 1)` bytes in all. [`StreamCollapse::max_open`] reports the peak.
//!
//! # Output order
//! Wide nodes are written in closing order, every node after the nodes it references
//! (emission order, like the binary nodes of the plain output); [`StreamCollapse::tree`]
//! renumbers them into the depth-first preorder of [`Mbvh4`], as
//! [`crate::Highlevel::to_bvh2`] does for the binary tree. Leaves are the emitter's leaves,
//! ranges of the sorted order, so the leaf table is the emitter's.

use crate::collapse::CollapseError;
use crate::hlbvh::{EmitRef, EmittedNode, Highlevel, HighlevelRoot};
use crate::mbvh4::{Mbvh4, Node4, MBVH_WIDTH};
use crate::node::ChildRef;
use geom::Aabb;

/// An open subtree: the emission index of its binary root and the slots it would give.
#[derive(Clone, Copy, Debug)]
struct Open {
    id: u32,
    len: usize,
    slots: [(Aabb, ChildRef); MBVH_WIDTH],
}

/// A child of the binary node being consumed: a leaf slot or an open subtree.
#[derive(Clone, Copy, Debug)]
enum Kid {
    Slot(Aabb, ChildRef),
    Open(Aabb, Open),
}

impl Kid {
    /// Slots it takes when opened.
    fn len(&self) -> usize {
        match self {
            Kid::Slot(..) => 1,
            Kid::Open(_, o) => o.len,
        }
    }
}

/// The streaming collapse as a step machine: [`StreamCollapse::push`] consumes one emitted
/// binary node, [`StreamCollapse::end`] the stream's root; each reports how many wide nodes
/// it wrote, so a cycle model can charge their writes.
///
/// ```
/// use bvh::{HlbvhBuilder, StreamCollapse, validate_mbvh4};
/// use geom::{Aabb, Vec3};
/// let prims: Vec<Aabb> = (0..16)
///     .map(|i| Aabb::new(Vec3::new(2.0 * i as f32, 0.0, 0.0), Vec3::new(2.0 * i as f32 + 1.0, 1.0, 1.0)))
///     .collect();
/// let hl = HlbvhBuilder::default().build_highlevel(&prims).unwrap();
/// let mut sc = StreamCollapse::new();
/// let mut written = 0;
/// for n in &hl.nodes {
///     written += sc.push(n).unwrap();
/// }
/// written += sc.end(&hl.roots).unwrap();
/// let t = sc.tree(hl.order.clone()).unwrap();
/// assert_eq!((written, t.nodes.len()), (5, 5)); // 16 leaves: a root over four full nodes
/// assert_eq!(validate_mbvh4(&t, &prims, 1), Ok(()));
/// ```
#[derive(Clone, Debug, Default)]
pub struct StreamCollapse {
    /// Open subtrees, the last opened on top.
    open: Vec<Open>,
    /// Wide nodes in write order; inner references are write indices.
    written: Vec<Node4>,
    /// Binary nodes consumed (the next one's emission index).
    consumed: u32,
    /// Peak number of open subtrees.
    max_open: usize,
    /// Box of the root, once the stream has ended.
    bounds: Option<Aabb>,
}

impl StreamCollapse {
    /// A collapse before its first node.
    pub fn new() -> Self {
        Self::default()
    }

    /// Wide nodes written so far, in write order (inner references are write indices).
    pub fn written(&self) -> &[Node4] {
        &self.written
    }

    /// Binary nodes consumed so far.
    pub fn consumed(&self) -> u32 {
        self.consumed
    }

    /// Peak number of open subtrees held (each at most one node's 128 bytes of slots).
    pub fn max_open(&self) -> usize {
        self.max_open
    }

    /// Consumes the next emitted binary node; returns the number of wide nodes it wrote
    /// (0, 1 or 2). Errors: a child that is not the last open subtree (the input is not in
    /// emission order) or an empty leaf, or a node after the end of the stream.
    pub fn push(&mut self, e: &EmittedNode) -> Result<usize, CollapseError> {
        let id = self.consumed as usize;
        if self.bounds.is_some() {
            return Err(CollapseError::StreamOrder { node: id, slot: 0 });
        }
        // An inner child 1 is on top of the open stack, an inner child 0 below it.
        let mut kids = [Kid::Slot(Aabb::EMPTY, ChildRef::EMPTY); 2];
        for slot in (0..2).rev() {
            let b = e.aabbs[slot];
            kids[slot] = match e.children[slot] {
                EmitRef::Leaf { first, count } => {
                    if count == 0 {
                        return Err(CollapseError::EmptyLeaf { node: id, slot });
                    }
                    Kid::Slot(b, ChildRef::leaf(first, count))
                }
                EmitRef::Node(c) => match self.open.pop() {
                    Some(o) if o.id == c => Kid::Open(b, o),
                    _ => return Err(CollapseError::StreamOrder { node: id, slot }),
                },
            };
        }
        let close = decide(&kids);
        let before = self.written.len();
        let mut node = Open {
            id: self.consumed,
            len: 0,
            slots: [(Aabb::EMPTY, ChildRef::EMPTY); MBVH_WIDTH],
        };
        for (slot, kid) in kids.iter().enumerate() {
            match *kid {
                Kid::Slot(b, c) => node.put(b, c),
                Kid::Open(b, o) if close[slot] => {
                    let at = self.write(&o);
                    node.put(b, ChildRef::inner(at));
                }
                Kid::Open(_, o) => {
                    for &(b, c) in &o.slots[..o.len] {
                        node.put(b, c);
                    }
                }
            }
        }
        self.open.push(node);
        self.max_open = self.max_open.max(self.open.len());
        self.consumed += 1;
        Ok(self.written.len() - before)
    }

    /// Ends the stream at its root (the emitter's single high-level output; none for an
    /// empty scene) and writes the root node; returns the number of wide nodes written (1,
    /// or 0 for an empty scene). Errors: more than one root (a high-level threshold cut the
    /// tree), or open subtrees other than the root's.
    pub fn end(&mut self, roots: &[HighlevelRoot]) -> Result<usize, CollapseError> {
        if self.bounds.is_some() {
            return Err(CollapseError::StreamOrder {
                node: self.consumed as usize,
                slot: 0,
            });
        }
        let root = match roots {
            [] => {
                if !self.open.is_empty() || self.consumed > 0 {
                    return Err(CollapseError::StreamEnd {
                        open: self.open.len(),
                    });
                }
                self.bounds = Some(Aabb::EMPTY);
                return Ok(0);
            }
            [r] => r,
            _ => return Err(CollapseError::ManyRoots { roots: roots.len() }),
        };
        let top = match root.root {
            EmitRef::Leaf { first, count } if self.open.is_empty() && count > 0 => {
                let mut o = Open {
                    id: 0,
                    len: 0,
                    slots: [(Aabb::EMPTY, ChildRef::EMPTY); MBVH_WIDTH],
                };
                o.put(root.aabb, ChildRef::leaf(first, count));
                o
            }
            EmitRef::Node(c) if self.open.len() == 1 && self.open[0].id == c => self.open[0],
            _ => {
                return Err(CollapseError::StreamEnd {
                    open: self.open.len(),
                })
            }
        };
        self.open.clear();
        self.write(&top);
        self.bounds = Some(root.aabb);
        Ok(1)
    }

    /// The collapsed tree in the depth-first preorder of [`Mbvh4`] over the leaf table
    /// `order` (the emitter's: the primitive at each sorted position). Errors: the stream
    /// has not ended, or a leaf runs past `order`.
    pub fn tree(&self, order: Vec<u32>) -> Result<Mbvh4, CollapseError> {
        let Some(bounds) = self.bounds else {
            return Err(CollapseError::StreamEnd {
                open: self.open.len(),
            });
        };
        let Some(root) = self.written.len().checked_sub(1) else {
            return Ok(Mbvh4 {
                prim_indices: order,
                ..Mbvh4::empty()
            });
        };
        // Preorder position of every written node (slot 0 first).
        let mut pre = vec![u32::MAX; self.written.len()];
        let mut stack = vec![root];
        let mut next = 0u32;
        while let Some(k) = stack.pop() {
            pre[k] = next;
            next += 1;
            for c in self.written[k].children.iter().rev() {
                if c.is_inner() {
                    stack.push(c.index as usize);
                }
            }
        }
        let mut nodes = vec![Node4::EMPTY; self.written.len()];
        for (k, n) in self.written.iter().enumerate() {
            let mut m = *n;
            for (slot, c) in m.children.iter_mut().enumerate() {
                if c.is_inner() {
                    *c = ChildRef::inner(pre[c.index as usize]);
                } else if c.is_leaf() && c.index as u64 + c.count as u64 > order.len() as u64 {
                    return Err(CollapseError::BadLeaf { node: k, slot });
                }
            }
            nodes[pre[k] as usize] = m;
        }
        Ok(Mbvh4 {
            nodes,
            prim_indices: order,
            bounds,
        })
    }

    /// Writes the slots of `o` as a wide node; returns its write index.
    fn write(&mut self, o: &Open) -> u32 {
        self.written.push(Node4::from_children(&o.slots[..o.len]));
        (self.written.len() - 1) as u32
    }
}

impl Open {
    fn put(&mut self, b: Aabb, c: ChildRef) {
        debug_assert!(self.len < MBVH_WIDTH, "the rule keeps four slots at most");
        self.slots[self.len] = (b, c);
        self.len += 1;
    }
}

/// Which children of a binary node to close (see the module doc's rule).
fn decide(kids: &[Kid; 2]) -> [bool; 2] {
    let inner = [
        matches!(kids[0], Kid::Open(..)),
        matches!(kids[1], Kid::Open(..)),
    ];
    let (s0, s1) = (kids[0].len(), kids[1].len());
    if s0 + s1 <= MBVH_WIDTH {
        return [false; 2];
    }
    if inner[0] && inner[1] {
        let area = |k: &Kid| match k {
            Kid::Open(b, _) => b.half_area(),
            Kid::Slot(b, _) => b.half_area(),
        };
        // The smaller child (child 1 on a tie) is closed first.
        let small = usize::from(area(&kids[0]) < area(&kids[1])) ^ 1;
        let big = 1 - small;
        if kids[big].len() < MBVH_WIDTH {
            return if small == 0 {
                [true, false]
            } else {
                [false, true]
            };
        }
        if kids[small].len() < MBVH_WIDTH {
            return if big == 0 {
                [true, false]
            } else {
                [false, true]
            };
        }
        return [true, true];
    }
    // One inner child and a leaf that do not fit: close the inner child.
    inner
}

/// The streaming collapse of an emitter's whole output (one root, no high-level
/// threshold): [`StreamCollapse`] fed `hl`'s nodes in emission order.
pub fn stream_collapse(hl: &Highlevel) -> Result<(Mbvh4, StreamCollapse), CollapseError> {
    let mut sc = StreamCollapse::new();
    for n in &hl.nodes {
        sc.push(n)?;
    }
    sc.end(&hl.roots)?;
    Ok((sc.tree(hl.order.clone())?, sc))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{adversarial, cubes_at, proc_scene, soup};
    use crate::{
        collapse, collapse_optimal, collapse_sah_optimal, validate_mbvh4, CollapseGoal,
        HlbvhBuilder, SahParams,
    };

    /// Builds with the HLBVH emitter, collapses the stream, and checks the result against
    /// the binary tree: valid, same leaves and bounds, open subtrees within the bound.
    fn check(name: &str, prims: &[Aabb], b: &HlbvhBuilder) -> (Mbvh4, crate::Bvh2, usize) {
        let hl = b.build_highlevel(prims).unwrap();
        let bvh = hl.to_bvh2();
        let (m, sc) = stream_collapse(&hl).unwrap_or_else(|e| panic!("{name}: {e}"));
        let max_leaf = bvh.stats().max_leaf_size.max(1);
        if let Err(e) = validate_mbvh4(&m, prims, max_leaf) {
            panic!("{name}: streamed tree invalid: {e}");
        }
        assert_eq!(m.bounds, bvh.bounds, "{name}");
        assert_eq!(m.stats().leaves, bvh.stats().leaves, "{name}: leaves kept");
        assert_eq!(m.prim_indices, hl.order, "{name}: the emitter's leaf table");
        // Open subtrees are left siblings on a root path: at most the tree's depth.
        assert!(
            sc.max_open() <= bvh.stats().max_depth.max(1),
            "{name}: {} open, depth {}",
            sc.max_open(),
            bvh.stats().max_depth
        );
        assert_eq!(sc.written().len(), m.nodes.len());
        (m, bvh, sc.max_open())
    }

    /// A perfect binary tree of 16 leaves: the streaming and offline collapses agree.
    #[test]
    fn sixteen_leaves_equal_the_offline_collapse() {
        let prims = cubes_at(&(0..16).map(|i| i as f32 * 3.0).collect::<Vec<_>>());
        let (m, bvh, _) = check("cubes16", &prims, &HlbvhBuilder::default());
        assert_eq!(bvh.nodes.len(), 15);
        assert_eq!(m.nodes.len(), 5);
        assert!(m.nodes.iter().all(|n| n.child_count() == 4));
        assert_eq!(m, collapse(&bvh).unwrap());
    }

    /// A perfect binary tree of 8 leaves: the streaming collapse fills the bottom (a root
    /// of two slots over two full nodes), the offline one the top (a full root over four
    /// nodes of two leaves).
    #[test]
    fn eight_leaves_pack_the_bottom() {
        let prims = cubes_at(&(0..8).map(|i| i as f32 * 3.0).collect::<Vec<_>>());
        let (m, bvh, open) = check("cubes8", &prims, &HlbvhBuilder::default());
        let counts: Vec<usize> = m.nodes.iter().map(Node4::child_count).collect();
        assert_eq!(counts, [2, 4, 4]);
        let off = collapse(&bvh).unwrap();
        let counts: Vec<usize> = off.nodes.iter().map(Node4::child_count).collect();
        assert_eq!(counts, [4, 2, 2, 2, 2]);
        // Leaves 0..3 in the first wide node, in Morton order.
        for s in 0..4 {
            assert_eq!(m.nodes[1].children[s], ChildRef::leaf(s as u32, 1));
        }
        assert_eq!(m.nodes[0].children[1], ChildRef::inner(2));
        // Open at once: the left half while the right half's subtrees are built.
        assert_eq!(open, 3);
    }

    /// Hand-traced rule 2: a node whose children hold 3 and 2 slots closes the smaller
    /// child, and one whose children hold 4 and 4 closes both.
    #[test]
    fn closing_rule_by_hand() {
        let bx = |x0: f32, x1: f32| {
            Aabb::new(geom::Vec3::new(x0, 0.0, 0.0), geom::Vec3::new(x1, 1.0, 1.0))
        };
        let leaf = |i: u32| EmitRef::Leaf { first: i, count: 1 };
        let node = |a: Aabb, l: EmitRef, b: Aabb, r: EmitRef| EmittedNode {
            aabbs: [a, b],
            children: [l, r],
        };
        let (mut sc, mut w) = (StreamCollapse::new(), Vec::new());
        // Node 0 = (0, 1), node 1 = (node 0, 2): 3 slots over x in 0..3.
        w.push(
            sc.push(&node(bx(0.0, 1.0), leaf(0), bx(1.0, 2.0), leaf(1)))
                .unwrap(),
        );
        w.push(
            sc.push(&node(bx(0.0, 2.0), EmitRef::Node(0), bx(2.0, 3.0), leaf(2)))
                .unwrap(),
        );
        // Node 2 = (3, 4): 2 slots over x in 3..5 (smaller than 0..3).
        w.push(
            sc.push(&node(bx(3.0, 4.0), leaf(3), bx(4.0, 5.0), leaf(4)))
                .unwrap(),
        );
        // Node 3 = (node 1, node 2): 3 + 2 > 4, node 2 is smaller: closed, 4 slots.
        w.push(
            sc.push(&node(
                bx(0.0, 3.0),
                EmitRef::Node(1),
                bx(3.0, 5.0),
                EmitRef::Node(2),
            ))
            .unwrap(),
        );
        assert_eq!(w, [0, 0, 0, 1]);
        assert_eq!(
            sc.written()[0].children[..2],
            [ChildRef::leaf(3, 1), ChildRef::leaf(4, 1)]
        );
        assert_eq!(sc.open.last().unwrap().len, 4);
        assert_eq!(sc.end(&[]), Err(CollapseError::StreamEnd { open: 1 }));
        let root = HighlevelRoot {
            aabb: bx(0.0, 5.0),
            root: EmitRef::Node(3),
            key: (0, 0),
        };
        assert_eq!(sc.end(&[root]).unwrap(), 1);
        let t = sc.tree((0..5).collect()).unwrap();
        let prims: Vec<Aabb> = (0..5).map(|i| bx(i as f32, i as f32 + 1.0)).collect();
        assert_eq!(validate_mbvh4(&t, &prims, 1), Ok(()));
        assert_eq!(t.nodes[0].children[3], ChildRef::inner(1));
    }

    #[test]
    fn bad_streams_are_errors() {
        let prims = soup(300, 2.0, 3);
        let hl = HlbvhBuilder::default().build_highlevel(&prims).unwrap();
        // A node out of order: its children are not the open subtrees.
        let mut sc = StreamCollapse::new();
        let last = hl.nodes.len() - 1;
        assert!(matches!(
            sc.push(&hl.nodes[last]),
            Err(CollapseError::StreamOrder { .. }) | Ok(0)
        ));
        let mut swapped = hl.nodes.clone();
        let k = swapped
            .iter()
            .position(|n| matches!(n.children, [EmitRef::Node(_), EmitRef::Node(_)]))
            .unwrap();
        swapped[k].children.swap(0, 1);
        let mut sc = StreamCollapse::new();
        let r: Result<Vec<usize>, _> = swapped.iter().map(|n| sc.push(n)).collect();
        assert!(matches!(r, Err(CollapseError::StreamOrder { node, .. }) if node == k));
        // Several roots (a high-level threshold) are refused.
        let cut = HlbvhBuilder {
            highlevel_threshold: Some(27),
            ..Default::default()
        }
        .build_highlevel(&prims)
        .unwrap();
        assert!(cut.roots.len() > 1);
        assert!(matches!(
            stream_collapse(&cut),
            Err(CollapseError::ManyRoots { .. }) | Err(CollapseError::StreamOrder { .. })
        ));
        // Not ended; a leaf past the table; an empty leaf.
        let mut sc = StreamCollapse::new();
        for n in &hl.nodes {
            sc.push(n).unwrap();
        }
        assert!(matches!(
            sc.tree(hl.order.clone()),
            Err(CollapseError::StreamEnd { .. })
        ));
        sc.end(&hl.roots).unwrap();
        assert!(matches!(
            sc.tree(vec![0; 10]),
            Err(CollapseError::BadLeaf { .. })
        ));
        assert!(sc.push(&hl.nodes[0]).is_err());
        let mut e = hl.nodes[0];
        e.children[0] = EmitRef::Leaf { first: 0, count: 0 };
        assert!(matches!(
            StreamCollapse::new().push(&e),
            Err(CollapseError::EmptyLeaf { .. }) | Err(CollapseError::StreamOrder { .. })
        ));
    }

    #[test]
    fn empty_and_single_leaf_scenes() {
        let (m, _) =
            stream_collapse(&HlbvhBuilder::default().build_highlevel(&[]).unwrap()).unwrap();
        assert_eq!(m, Mbvh4::empty());
        let one = cubes_at(&[0.0]);
        let (m, _, _) = check("one", &one, &HlbvhBuilder::default());
        assert_eq!(m.nodes.len(), 1);
        assert_eq!(m.nodes[0].children[0], ChildRef::leaf(0, 1));
    }

    #[test]
    fn adversarial_and_random_inputs_collapse_validly() {
        for (name, prims) in adversarial() {
            for combine in [true, false] {
                let b = HlbvhBuilder {
                    combine_identical: combine,
                    max_leaf_size: 4,
                    ..Default::default()
                };
                check(name, &prims, &b);
            }
        }
        for seed in 0..4 {
            check(
                "soup",
                &soup(3000, 1.0 + seed as f32, seed),
                &HlbvhBuilder::default(),
            );
        }
    }

    /// Against the optimal collapses of the same binary tree, which bound it from below:
    /// no collapse keeping the leaves has fewer nodes than `FewestNodes`, or a lower 4-wide
    /// SAH than `collapse_sah_optimal`. The streamed tree's node count also stays within
    /// the offline greedy collapse's on this scene (the rule packs the many bottom nodes).
    #[test]
    fn bounded_below_by_the_optimal_collapses() {
        let prims = proc_scene("proc:soup?n=20000");
        let (m, bvh, _) = check("soup20k", &prims, &HlbvhBuilder::default());
        let fewest = collapse_optimal(&bvh, &SahParams::THESIS, CollapseGoal::FewestNodes).unwrap();
        let best = collapse_sah_optimal(&bvh, &SahParams::THESIS).unwrap();
        let off = collapse(&bvh).unwrap();
        assert!(m.nodes.len() >= fewest.nodes.len());
        assert!(m.normalized_sah() >= best.normalized_sah() * (1.0 - 1e-9));
        assert!(
            m.nodes.len() <= off.nodes.len(),
            "{} vs {}",
            m.nodes.len(),
            off.nodes.len()
        );
        println!(
            "nodes: stream {} offline {} fewest {}; SAH: stream {:.3} offline {:.3} optimal {:.3}",
            m.nodes.len(),
            off.nodes.len(),
            fewest.nodes.len(),
            m.normalized_sah(),
            off.normalized_sah(),
            best.normalized_sah()
        );
    }

    /// The shared scenes with MergeTree's `p2` tree options (30-bit codes on the cube grid,
    /// equal codes in one leaf of any size): node counts and 4-wide SAH of the streaming,
    /// offline greedy and SAH-optimal collapses of one HLBVH tree (`docs/beyond-thesis.md`;
    /// `cargo test -p bvh@0.1.0 --lib stream_collapse -- --ignored --nocapture`).
    #[test]
    #[ignore = "reads the shared scenes; prints a table"]
    fn shared_scenes_table() {
        let Some(scenes) = crate::testutil::real_scenes() else {
            return;
        };
        let b = HlbvhBuilder {
            max_leaf_size: u32::MAX,
            grid: crate::MortonGrid::Cube,
            ..Default::default()
        };
        println!("| scene | binary nodes | stream nodes | offline nodes | optimal nodes | stream SAH | offline SAH | optimal SAH | max open |");
        for (name, prims) in scenes {
            let (m, bvh, open) = check(&name, &prims, &b);
            let off = collapse(&bvh).unwrap();
            let best = collapse_sah_optimal(&bvh, &SahParams::THESIS).unwrap();
            assert!(m.normalized_sah() >= best.normalized_sah() * (1.0 - 1e-9));
            println!(
                "| {name} | {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {open} |",
                bvh.nodes.len(),
                m.nodes.len(),
                off.nodes.len(),
                best.nodes.len(),
                m.normalized_sah(),
                off.normalized_sah(),
                best.normalized_sah()
            );
        }
    }
}
