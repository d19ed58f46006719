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
//! # Windowed rule
//! [`StreamCollapse::with_window`] decides by cost instead, with a bounded delay. Every
//! open subtree keeps its top binary levels unresolved (a treelet of at most `levels + 1`
//! levels, as \[P3\] §4.3 keeps the top of every subtree unwritten) over *items* already
//! decided: leaves, closed wide nodes, and committed open frontiers (which may still be
//! closed). For the treelet it runs the program of [`crate::collapse_sah_optimal`]: per
//! node and budget `j` = 1..4 slots in its parent, the least summed area of the wide nodes
//! it needs (a node of its own costs its area; an open frontier of `s` slots costs
//! nothing with `j >= s` and its area as a closed node otherwise). When a node arrives,
//! the levels that fall out of the window are committed as the optimum of the new treelet
//! has them with its root a wide node of its own; at the end the root's treelet is
//! resolved exactly. A window deeper than the tree therefore gives the SAH-optimal
//! collapse (tested); the buffer is at most `2^(levels + 1)` unresolved nodes per open
//! subtree ([`StreamCollapse::max_treelet_nodes`] reports the peak).
//!
//! Its storage is the treelets: a row of [`TREELET_NODE_BYTES`] per unresolved node (its
//! box, 24 B; the four least costs, 16 B; the four choices, 4 B; two child references and
//! the depth, 5 B: 49 B, rounded up to 64) and the items below them, a fixed slot of
//! [`COLLAPSE_SLOT_BYTES`] (a leaf or a closed wide node) or a committed open frontier of
//! [`COLLAPSE_SLOT_BYTES`] (its box and slot count) plus its slots. [`StreamCollapse::max_window_bytes`]
//! reports the peak of their sum over all open subtrees.
//!
//! # Output order
//! Wide nodes are written in closing order, every node after the nodes it references
//! (emission order, like the binary nodes of the plain output); [`StreamCollapse::tree`]
//! renumbers them into the depth-first preorder of [`Mbvh4`] with the crate's shared stack
//! layout (`layout::try_preorder`), as [`crate::Highlevel::to_bvh2`] does for the binary
//! tree. Leaves are the emitter's leaves,
//! ranges of the sorted order, so the leaf table is the emitter's.

use crate::collapse::CollapseError;
use crate::hlbvh::{EmitRef, EmittedNode, Highlevel, HighlevelRoot};
use crate::mbvh4::{Mbvh4, Node4, MBVH_WIDTH};
use crate::node::ChildRef;
use geom::Aabb;

/// Bytes of one slot: a 24-byte box and an 8-byte reference (a wide node's child).
pub const COLLAPSE_SLOT_BYTES: usize = 32;

/// Bytes of one unresolved treelet node of the windowed rule: box (24 B), four least
/// costs (16 B), four choices (4 B), two child references and the depth (5 B), rounded up
/// to a 64-byte row.
pub const TREELET_NODE_BYTES: usize = 64;

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
    /// The windowed variant's state ([`StreamCollapse::with_window`]).
    win: Option<Window>,
}

/// The state of the windowed variant: the open subtrees' unresolved treelets.
#[derive(Clone, Debug, Default)]
struct Window {
    /// Binary levels kept unresolved below the newest node.
    levels: u32,
    /// Open subtrees, the last opened on top.
    stack: Vec<Treelet>,
    /// Peak treelet nodes held over all open subtrees.
    max_nodes: usize,
    /// Bytes the open subtrees' treelets hold now (see [`Treelet::bytes`]).
    bytes: usize,
    /// Peak of `bytes`.
    max_bytes: usize,
}

impl StreamCollapse {
    /// A collapse before its first node, with the greedy rule of the module doc.
    pub fn new() -> Self {
        Self::default()
    }

    /// A collapse with the windowed rule: every open subtree keeps its top `levels + 1`
    /// binary levels unresolved and is resolved by the optimal collapse program over
    /// them (see [`StreamCollapse::max_treelet_nodes`] and the module doc).
    pub fn with_window(levels: u32) -> Self {
        Self {
            win: Some(Window {
                levels,
                ..Window::default()
            }),
            ..Self::default()
        }
    }

    /// Peak unresolved binary nodes held over all open subtrees (windowed rule; 0 with
    /// the greedy rule).
    pub fn max_treelet_nodes(&self) -> usize {
        self.win.as_ref().map_or(0, |w| w.max_nodes)
    }

    /// Peak bytes of the windowed rule's storage over all open subtrees: a
    /// [`TREELET_NODE_BYTES`] row per unresolved node, and per item below them a
    /// [`COLLAPSE_SLOT_BYTES`] slot (a leaf or a closed node) or a committed open frontier of
    /// [`COLLAPSE_SLOT_BYTES`] plus [`COLLAPSE_SLOT_BYTES`] per slot (module doc); 0 with the greedy rule,
    /// whose storage is [`StreamCollapse::max_open`] x 128 bytes.
    pub fn max_window_bytes(&self) -> usize {
        self.win.as_ref().map_or(0, |w| w.max_bytes)
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
        if self.win.is_some() {
            return self.push_window(e);
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
        if let (Some(w), [r]) = (&mut self.win, roots) {
            if let EmitRef::Node(c) = r.root {
                let t = match w.stack.pop() {
                    Some(t) if t.id == c && w.stack.is_empty() => t,
                    _ => {
                        return Err(CollapseError::StreamEnd {
                            open: w.stack.len() + 1,
                        })
                    }
                };
                return Ok(self.end_window(t, r.aabb));
            }
        }
        let open = self.win.as_ref().map_or(self.open.len(), |w| w.stack.len());
        let root = match roots {
            [] => {
                if open > 0 || self.consumed > 0 {
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
            EmitRef::Leaf { first, count } if open == 0 && count > 0 => {
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
        // Written nodes come children first; the shared stack layout renumbers them into
        // preorder (slot 0 first), checking every leaf range on the way.
        let mut nodes = Vec::with_capacity(self.written.len());
        crate::layout::try_preorder(root, &mut nodes, |k, out, kids| {
            let m = self.written[k];
            for (slot, c) in m.children.iter().enumerate() {
                if c.is_inner() {
                    kids.push((slot, c.index as usize));
                } else if c.is_leaf() && c.index as u64 + c.count as u64 > order.len() as u64 {
                    return Err(CollapseError::BadLeaf { node: k, slot });
                }
            }
            out.push(m);
            Ok(())
        })?;
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

/// A reference inside a treelet: a fixed slot (leaf or closed node), a committed open
/// frontier (which may still be closed), or an unresolved treelet node.
#[derive(Clone, Copy, Debug)]
enum TRef {
    Slot(Aabb, ChildRef),
    Open(Aabb, Open),
    Node(usize),
}

/// An unresolved binary node: its box, children and depth below the treelet's root.
#[derive(Clone, Copy, Debug)]
struct TNode {
    b: Aabb,
    kids: [TRef; 2],
    depth: u32,
}

/// An open subtree of the windowed rule: its unresolved top levels.
#[derive(Clone, Debug)]
struct Treelet {
    id: u32,
    nodes: Vec<TNode>,
}

impl Treelet {
    /// Bytes of its storage: a row per node and the items below them (module doc).
    fn bytes(&self) -> usize {
        let item = |k: &TRef| match k {
            TRef::Slot(..) => COLLAPSE_SLOT_BYTES,
            TRef::Open(_, o) => COLLAPSE_SLOT_BYTES * (1 + o.len),
            TRef::Node(_) => 0,
        };
        self.nodes
            .iter()
            .map(|n| TREELET_NODE_BYTES + n.kids.iter().map(item).sum::<usize>())
            .sum()
    }
}

/// Per treelet node and budget `j` (index 1..=4): least cost, whether it is a wide node of
/// its own, the split `a` (slots to child 0) and the budget `jj <= j` the split uses.
#[derive(Clone, Copy, Debug, Default)]
struct Choice {
    cost: f64,
    own: bool,
    a: usize,
    jj: usize,
}

/// The windowed rule (`StreamCollapse::with_window`).
impl StreamCollapse {
    /// Consumes the next emitted node with the windowed rule.
    fn push_window(&mut self, e: &EmittedNode) -> Result<usize, CollapseError> {
        let id = self.consumed as usize;
        let before = self.written.len();
        let w = self.win.as_mut().expect("the windowed rule");
        let mut nodes: Vec<TNode> = Vec::new();
        let mut kids = [TRef::Slot(Aabb::EMPTY, ChildRef::EMPTY); 2];
        let mut parts: [Option<Treelet>; 2] = [None, None];
        for slot in (0..2).rev() {
            match e.children[slot] {
                EmitRef::Leaf { first, count } => {
                    if count == 0 {
                        return Err(CollapseError::EmptyLeaf { node: id, slot });
                    }
                    kids[slot] = TRef::Slot(e.aabbs[slot], ChildRef::leaf(first, count));
                }
                EmitRef::Node(c) => match w.stack.pop() {
                    Some(t) if t.id == c => {
                        w.bytes -= t.bytes();
                        parts[slot] = Some(t)
                    }
                    _ => return Err(CollapseError::StreamOrder { node: id, slot }),
                },
            }
        }
        for slot in 0..2 {
            if let Some(t) = parts[slot].take() {
                let base = nodes.len();
                for mut n in t.nodes {
                    n.depth += 1;
                    for k in n.kids.iter_mut() {
                        if let TRef::Node(i) = k {
                            *i += base;
                        }
                    }
                    nodes.push(n);
                }
                kids[slot] = TRef::Node(nodes.len() - 1);
            }
        }
        nodes.push(TNode {
            b: e.aabbs[0].union(e.aabbs[1]),
            kids,
            depth: 0,
        });
        // The levels leaving the window are committed as the optimum of the treelet has
        // them when its root becomes a wide node of its own.
        let limit = w.levels + 1;
        let budgets = resolve(&nodes, 1);
        let mut t = self.commit(nodes, &budgets, |n| n.depth >= limit);
        t.id = self.consumed;
        let w = self.win.as_mut().expect("the windowed rule");
        w.bytes += t.bytes();
        w.max_bytes = w.max_bytes.max(w.bytes);
        w.stack.push(t);
        let held: usize = w.stack.iter().map(|t| t.nodes.len()).sum();
        w.max_nodes = w.max_nodes.max(held);
        self.max_open = self.max_open.max(w.stack.len());
        self.consumed += 1;
        Ok(self.written.len() - before)
    }

    /// Ends the windowed stream at root treelet `t` (box `b`): resolves it exactly, the
    /// root a wide node; returns the wide nodes written.
    fn end_window(&mut self, t: Treelet, b: Aabb) -> usize {
        let before = self.written.len();
        let budgets = resolve(&t.nodes, 1);
        let rest = self.commit(t.nodes, &budgets, |_| true);
        debug_assert!(rest.nodes.is_empty());
        self.bounds = Some(b);
        self.written.len() - before
    }

    /// Commits the nodes `pick` selects (children before parents; a picked node's
    /// descendants must be picked too) with their budgets, writing what they close, and
    /// returns the treelet of the others.
    fn commit(
        &mut self,
        nodes: Vec<TNode>,
        budgets: &[usize],
        pick: impl Fn(&TNode) -> bool,
    ) -> Treelet {
        let mut done: Vec<Option<TRef>> = vec![None; nodes.len()];
        let mut keep: Vec<usize> = Vec::new();
        let mut at: Vec<usize> = vec![usize::MAX; nodes.len()];
        let cost = choices(&nodes);
        for (i, n) in nodes.iter().enumerate() {
            let kid = |k: TRef| match k {
                TRef::Node(c) => done[c].unwrap_or(TRef::Node(c)),
                other => other,
            };
            if pick(n) {
                let ch = cost[i][budgets[i]];
                let (jj, own) = if ch.own {
                    (MBVH_WIDTH, true)
                } else {
                    (ch.jj, false)
                };
                let a = if own { cost[i][1].a } else { ch.a };
                let mut o = Open {
                    id: 0,
                    len: 0,
                    slots: [(Aabb::EMPTY, ChildRef::EMPTY); MBVH_WIDTH],
                };
                for (k, want) in [(kid(n.kids[0]), a), (kid(n.kids[1]), jj - a)] {
                    self.place(&mut o, k, want);
                }
                done[i] = Some(if own {
                    let w = self.write(&o);
                    TRef::Slot(n.b, ChildRef::inner(w))
                } else {
                    TRef::Open(n.b, o)
                });
            } else {
                at[i] = keep.len();
                keep.push(i);
            }
        }
        let nodes_left = keep
            .iter()
            .map(|&i| {
                let mut n = nodes[i];
                for k in n.kids.iter_mut() {
                    if let TRef::Node(c) = *k {
                        *k = match done[c] {
                            Some(r) => r,
                            None => TRef::Node(at[c]),
                        };
                    }
                }
                n
            })
            .collect();
        Treelet {
            id: 0,
            nodes: nodes_left,
        }
    }

    /// Puts item `k` into `o` with `want` slots: opened if it fits, else closed (written).
    fn place(&mut self, o: &mut Open, k: TRef, want: usize) {
        match k {
            TRef::Slot(b, c) => o.put(b, c),
            TRef::Open(_, inner) if inner.len <= want => {
                for &(sb, sc) in &inner.slots[..inner.len] {
                    o.put(sb, sc);
                }
            }
            TRef::Open(b, inner) => {
                let w = self.write(&inner);
                o.put(b, ChildRef::inner(w));
            }
            TRef::Node(_) => unreachable!("children are committed before their parents"),
        }
    }
}

/// Cost of treelet reference `k` with `a` slots.
fn ref_cost(k: TRef, a: usize, cost: &[[Choice; MBVH_WIDTH + 1]]) -> f64 {
    match k {
        TRef::Slot(..) => 0.0,
        TRef::Open(b, o) if a < o.len => b.half_area() as f64,
        TRef::Open(..) => 0.0,
        TRef::Node(i) => cost[i][a].cost,
    }
}

/// The program over a treelet (children before parents): per node and budget 1..=4.
fn choices(nodes: &[TNode]) -> Vec<[Choice; MBVH_WIDTH + 1]> {
    let mut cost: Vec<[Choice; MBVH_WIDTH + 1]> = Vec::with_capacity(nodes.len());
    for n in nodes {
        // A split of one slot to child 0 until a finite cost is found: with boxes whose
        // areas overflow `f32` (coordinates near the format's limits) every cost is
        // infinite, and the split must still be a valid one (1..j slots to child 0).
        let mut open = [(f64::INFINITY, 1usize); MBVH_WIDTH + 1];
        for (j, o) in open.iter_mut().enumerate().skip(2) {
            for a in 1..j {
                let c = ref_cost(n.kids[0], a, &cost) + ref_cost(n.kids[1], j - a, &cost);
                if c < o.0 {
                    *o = (c, a);
                }
            }
        }
        let mut row = [Choice::default(); MBVH_WIDTH + 1];
        row[1] = Choice {
            cost: n.b.half_area() as f64 + open[MBVH_WIDTH].0,
            own: true,
            a: open[MBVH_WIDTH].1,
            jj: MBVH_WIDTH,
        };
        for j in 2..=MBVH_WIDTH {
            row[j] = if open[j].0 < row[j - 1].cost {
                Choice {
                    cost: open[j].0,
                    own: false,
                    a: open[j].1,
                    jj: j,
                }
            } else {
                row[j - 1]
            };
        }
        cost.push(row);
    }
    cost
}

/// The budget of every treelet node when its root (the last node) gets `root` slots.
fn resolve(nodes: &[TNode], root: usize) -> Vec<usize> {
    let cost = choices(nodes);
    let mut b = vec![0usize; nodes.len()];
    let Some(last) = nodes.len().checked_sub(1) else {
        return b;
    };
    b[last] = root;
    for i in (0..nodes.len()).rev() {
        let ch = cost[i][b[i].max(1)];
        let (a, jj) = if ch.own {
            (cost[i][1].a, MBVH_WIDTH)
        } else {
            (ch.a, ch.jj)
        };
        for (k, want) in [(nodes[i].kids[0], a), (nodes[i].kids[1], jj - a)] {
            if let TRef::Node(c) = k {
                b[c] = want;
            }
        }
    }
    b
}

/// The streaming collapse of an emitter's whole output (one root, no high-level
/// threshold): [`StreamCollapse`] fed `hl`'s nodes in emission order.
pub fn stream_collapse(hl: &Highlevel) -> Result<(Mbvh4, StreamCollapse), CollapseError> {
    stream_collapse_with(hl, StreamCollapse::new())
}

/// [`stream_collapse`] with the collapse `sc` (for example
/// [`StreamCollapse::with_window`]).
pub fn stream_collapse_with(
    hl: &Highlevel,
    mut sc: StreamCollapse,
) -> Result<(Mbvh4, StreamCollapse), CollapseError> {
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

    /// The windowed rule: valid on every input; with a window deeper than the tree it is
    /// the SAH-optimal collapse; a deeper window does not raise the SAH here.
    #[test]
    fn windowed_rule_reaches_the_optimum() {
        let b = HlbvhBuilder::default();
        for (name, prims) in adversarial() {
            let hl = b.build_highlevel(&prims).unwrap();
            for w in 0..4 {
                let (m, _) = stream_collapse_with(&hl, StreamCollapse::with_window(w)).unwrap();
                let max_leaf = m.stats().max_leaf_size.max(1);
                assert_eq!(validate_mbvh4(&m, &prims, max_leaf), Ok(()), "{name} {w}");
                assert_eq!(m.prim_indices, hl.order);
            }
        }
        let prims = soup(400, 2.0, 7);
        let hl = b.build_highlevel(&prims).unwrap();
        let bvh = hl.to_bvh2();
        let depth = bvh.stats().max_depth as u32;
        let (whole, sc) = stream_collapse_with(&hl, StreamCollapse::with_window(depth)).unwrap();
        assert_eq!(validate_mbvh4(&whole, &prims, 8), Ok(()));
        let best = collapse_sah_optimal(&bvh, &SahParams::THESIS).unwrap();
        let (a, o) = (whole.normalized_sah(), best.normalized_sah());
        assert!((a - o).abs() <= 1e-9 * o, "{a} vs optimum {o}");
        // Nothing was committed before the end: the whole tree was held.
        assert_eq!(sc.max_treelet_nodes(), bvh.nodes.len());
        let sah = |w: u32| {
            let (m, _) = stream_collapse_with(&hl, StreamCollapse::with_window(w)).unwrap();
            m.normalized_sah()
        };
        assert!(
            sah(4) <= sah(1) && sah(1) < sah(0) * 1.2,
            "{} {} {}",
            sah(4),
            sah(1),
            sah(0)
        );
        // Out of order is an error here too.
        let mut sc = StreamCollapse::with_window(2);
        let last = hl.nodes.len() - 1;
        assert!(matches!(
            sc.push(&hl.nodes[last]),
            Err(CollapseError::StreamOrder { .. })
        ));
    }

    /// The windowed rule's storage by hand, on a perfect tree of 4 leaves (emission order
    /// n0 = (l0, l1), n1 = (l2, l3), n2 = (n0, n1)). After n0: one row and two leaf slots,
    /// 64 + 2 x 32 = 128 B; after n1: two such treelets, 256 B. At n2 a window of 1 level or
    /// more keeps all three rows over four leaf slots, 3 x 64 + 4 x 32 = 320 B; a window of
    /// 0 commits n0 and n1 (depth 1) as open frontiers of two slots each (the root, a wide
    /// node of its own, gives each two slots) and keeps one row over two frontiers of
    /// 32 + 2 x 32 B: 64 + 2 x 96 = 256 B. The greedy rule holds no treelets.
    #[test]
    fn window_storage_by_hand() {
        let prims = cubes_at(&[0.0, 3.0, 6.0, 9.0]);
        let hl = HlbvhBuilder::default().build_highlevel(&prims).unwrap();
        assert_eq!(hl.nodes.len(), 3);
        let bytes = |sc: StreamCollapse| {
            let (m, sc) = stream_collapse_with(&hl, sc).unwrap();
            assert_eq!(m.nodes.len(), 1, "one root of four leaves");
            sc.max_window_bytes()
        };
        assert_eq!(TREELET_NODE_BYTES, 64);
        assert_eq!(COLLAPSE_SLOT_BYTES, 32);
        assert_eq!(bytes(StreamCollapse::new()), 0);
        assert_eq!(bytes(StreamCollapse::with_window(0)), 256);
        for w in 1..4 {
            assert_eq!(bytes(StreamCollapse::with_window(w)), 320, "window {w}");
        }
        // A larger scene: the storage grows with the window and covers the rows.
        let prims = soup(3000, 2.0, 3);
        let hl = HlbvhBuilder::default().build_highlevel(&prims).unwrap();
        let mut last = 0;
        for w in 0..5 {
            let (_, sc) = stream_collapse_with(&hl, StreamCollapse::with_window(w)).unwrap();
            let b = sc.max_window_bytes();
            assert!(
                b >= sc.max_treelet_nodes() * TREELET_NODE_BYTES,
                "window {w}"
            );
            assert!(b > last, "window {w}: {b} B after {last} B");
            last = b;
        }
    }

    /// Boxes whose areas overflow `f32` (found by `cbvh`'s property test): every cost of
    /// the windowed rule's program is infinite, and it must still choose valid splits.
    #[test]
    fn windowed_rule_survives_infinite_areas() {
        let b = |a: [f32; 3], c: [f32; 3]| Aabb::new(geom::Vec3::from(a), geom::Vec3::from(c));
        let prims = vec![
            b([0.0, 1.329228e36, 0.0], [0.0, 1.329228e36, 0.0]),
            b(
                [4.1951594e-7, 2.663469e-39, 1.329228e36],
                [4.1951594e-7, 2.66347e-39, 1.329228e36],
            ),
            b(
                [-3.1843913e-7, -1.329228e36, 5.344632e29],
                [-3.1843913e-7, -1.3292279e36, 5.344634e29],
            ),
            b(
                [1.035599e-39, 7.356348e-7, -2.238046e29],
                [1.035599e-39, 7.356348e-7, -2.2380458e29],
            ),
            b(
                [0.0, 1.329228e36, 1.329228e36],
                [4.867152e-7, 1.329228e36, 1.329228e36],
            ),
            b(
                [-1.329228e36, 1.329228e36, -4.9372773],
                [-1.3292267e36, 1.329228e36, -4.937277],
            ),
        ];
        let hl = HlbvhBuilder {
            max_leaf_size: u32::MAX,
            grid: crate::MortonGrid::Cube,
            ..Default::default()
        }
        .build_highlevel(&prims)
        .unwrap();
        assert!(hl
            .nodes
            .iter()
            .any(|n| n.aabbs.iter().any(|a| a.half_area().is_infinite())));
        for w in 0..4 {
            let (m, _) = stream_collapse_with(&hl, StreamCollapse::with_window(w)).unwrap();
            assert_eq!(validate_mbvh4(&m, &prims, 6), Ok(()), "window {w}");
        }
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
            let hl = b.build_highlevel(&prims).unwrap();
            for w in [0, 1, 2, 3, 4] {
                let (t, wc) = stream_collapse_with(&hl, StreamCollapse::with_window(w)).unwrap();
                let max_leaf = bvh.stats().max_leaf_size.max(1);
                assert_eq!(validate_mbvh4(&t, &prims, max_leaf), Ok(()), "{name} {w}");
                println!(
                    "  window {w}: nodes {} SAH {:.3} open {} treelet nodes {}",
                    t.nodes.len(),
                    t.normalized_sah(),
                    wc.max_open(),
                    wc.max_treelet_nodes()
                );
            }
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
