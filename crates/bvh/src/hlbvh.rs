//! HLBVH by streaming hierarchy emission: \[P2\] Algorithm 1 (§5.4), the MergeTree emitter.
//!
//! 1. The Morton code of every primitive's box centroid is computed over the centroid bounds
//!    ([`geom::MortonQuantizer`], 30 or 63 bits) and (code, primitive index) pairs are
//!    sorted, so the order is total and deterministic. With
//!    [`HlbvhBuilder::large_prims`] (off by default), primitives wider than a given
//!    fraction of the centroid bounds get a bit above the code and sort after all others.
//! 2. The sorted primitives stream through an [`Emitter`], a step machine that performs ONE
//!    stack operation per [`Emitter::step`] (or enlarges the current leaf by one primitive),
//!    exactly as the hardware unit does one per cycle. A cycle-level model drives the very
//!    same code; the software builder drives it in a loop.
//! 3. The emitted nodes come out bottom-up (every node after both of its children), depth
//!    first; [`Highlevel::to_bvh2`] renumbers them into the depth-first preorder of
//!    [`Bvh2`] (root = node 0).
//!
//! The emitter compares sort keys, not bare codes: a key is the Morton code followed by a
//! 32-bit tie field. Keys that are equal are combined into one leaf (\[P2\] lines 4..8);
//! otherwise the highest differing key bit is the hierarchy level of the inner node that
//! separates two neighbours (\[P2\] Fig. 5). The tie field gives both variants of the issue:
//! - `combine_identical = true` (\[P2\] §5.4): the tie is the index of a chunk of
//!   `max_leaf_size` primitives inside a run of identical codes, so identical codes make one
//!   leaf, and a run larger than `max_leaf_size` becomes a balanced subtree of full leaves
//!   (a scene whose codes all collide still gives a usable tree);
//! - `combine_identical = false` (\[P1\]): the tie is the sorted position, so identical codes
//!   are separated by "differing bits from their indices", one primitive per leaf.
//!
//! `highlevel_threshold` (\[P2\] lines 15..19): a subtree whose next separating level lies
//! above the threshold is complete for its grid cell (all its primitives share the code bits
//! above the threshold) and goes to the high-level output instead of the stack. Those cell
//! roots are the input of the toplevel builds in [`crate::toplevel`].
//!
//! Threads: coding, sorting and the gather of boxes in sorted order are parallel. Emission
//! is serial per stream, as in the hardware, but cells are independent (the stack is empty
//! at every cell boundary), so runs of whole cells are emitted by separate emitters in
//! parallel and concatenated; the output equals one emitter's, for any thread count.
//!
//! Frame loops: [`HlbvhBuilder::build_into`] rebuilds into the tree and the
//! [`HlbvhArena`] of the previous build, reusing their memory, with the same tree.

use crate::bvh2::Bvh2;
use crate::error::{check_input, in_pool, BuildError};
use crate::lbvh::MortonBits;
use crate::node::{ChildRef, Node};
use crate::PARALLEL_MIN_PRIMS;
use geom::{Aabb, MortonGrid, Vec3};
use rayon::prelude::*;

/// Configuration of the streaming HLBVH builder.
#[derive(Clone, Debug, PartialEq)]
pub struct HlbvhBuilder {
    /// Morton code length.
    pub bits: MortonBits,
    /// Identical codes share leaves (\[P2\]) rather than being split by index bits (\[P1\]).
    pub combine_identical: bool,
    /// Largest leaf when combining identical codes (>= 1); larger runs are split.
    pub max_leaf_size: u32,
    /// Cell level for the high-level output: subtrees are cut where neighbours first differ
    /// in a code bit above this one (1-based: bit `b` of the code is level `b + 1`), so each
    /// subtree is one cell of the top `bits - threshold` code bits. `None` never cuts.
    /// Only [`HlbvhBuilder::build_highlevel`] cuts; [`HlbvhBuilder::build`] gives the same
    /// tree for any threshold.
    pub highlevel_threshold: Option<u32>,
    /// Worker threads for coding, sorting and the emission of separate cells: 0 uses the
    /// current rayon pool, `n` a private pool of `n` threads. One stream (one cell) is
    /// emitted serially, as in the hardware.
    pub threads: usize,
    /// The grid of the Morton codes over the centroid bounds (default: stretched to the
    /// box on each axis; [`MortonGrid::Cube`] for cubic cells).
    pub grid: MortonGrid,
    /// `Some(f)` (`f` finite and > 0): large primitives apart. A primitive whose box is
    /// wider than `f` times the centroid bounds on some axis (an axis on which all
    /// centroids agree is not tested) gets a code bit above every Morton code bit, so the
    /// large primitives sort after all others, in their code order, and form their own
    /// subtree under the root, instead of widening every box on the path of their
    /// centroid's cell. The one-size-class case of extended Morton codes (Vinkler, Bittner
    /// and Havran 2017, which interleave several size bits with the position bits).
    /// `None` (the default) is \[P2\]'s tree, which the MergeTree model reproduces.
    /// Issue 34: `Some(0.5)` takes Crytek Sponza from 1.417x to 1.209x the sweep SAH and
    /// Conference from 1.707x to 1.483x; meshes without such primitives (Dragon) keep
    /// their tree (docs/builders.md).
    pub large_prims: Option<f32>,
}

impl Default for HlbvhBuilder {
    fn default() -> Self {
        Self {
            bits: MortonBits::Bits30,
            combine_identical: true,
            max_leaf_size: 8,
            highlevel_threshold: None,
            threads: 0,
            grid: MortonGrid::Box,
            large_prims: None,
        }
    }
}

/// The [`HlbvhBuilder::large_prims`] fraction of the `hlbvh-large` builder: the best of the
/// four issue 34 measured (0.5, 0.25, 0.125, 0.0625; docs/builders.md, "HLBVH's SAH on
/// Crytek Sponza").
pub const LARGE_PRIMS_FRACTION: f32 = 0.5;

/// Code bits of the cells that [`HlbvhBuilder::build`] emits in parallel (512 cells).
pub(crate) const PARALLEL_CELL_BITS: u32 = 9;

/// Level given to the end of the stream: above every key level and every threshold, so it
/// pops all stack entries and sends the last subtree to the high-level output.
const END_LEVEL: u32 = u32::MAX;

/// Number of tie bits below the code in a sort key.
const TIE_BITS: u32 = 32;

/// One sorted primitive as the emitter reads it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prim {
    /// Morton code of the centroid.
    pub code: u64,
    /// Tie field below the code (see the module doc): equal (code, tie) keys share a leaf.
    pub tie: u32,
    /// The primitive's box.
    pub aabb: Aabb,
}

/// Hierarchy level of the node separating keys `a` and `b` (`a != b`): the 1-based index of
/// their highest differing bit in the 96-bit key `code << 32 | tie`.
#[inline]
fn level(a: (u64, u32), b: (u64, u32)) -> u32 {
    if a.0 != b.0 {
        TIE_BITS + 64 - (a.0 ^ b.0).leading_zeros()
    } else {
        32 - (a.1 ^ b.1).leading_zeros()
    }
}

/// A reference to an emitted subtree: a leaf (a range of the sorted stream) or a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmitRef {
    /// A leaf of `count` primitives at sorted positions `first..first + count`.
    Leaf {
        /// First sorted position.
        first: u32,
        /// Number of primitives.
        count: u32,
    },
    /// The inner node emitted `n`-th (0-based emission order).
    Node(u32),
}

/// An inner node as the emitter outputs it: its two children and their boxes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmittedNode {
    /// Boxes of child 0 (left, lower codes) and child 1.
    pub aabbs: [Aabb; 2],
    /// Child 0 and child 1.
    pub children: [EmitRef; 2],
}

/// A complete subtree sent to the high-level output: the root of one grid cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HighlevelRoot {
    /// Box of the subtree.
    pub aabb: Aabb,
    /// Root of the subtree.
    pub root: EmitRef,
    /// Sort key (code, tie) of the subtree's last primitive; all its primitives share the
    /// code bits above the threshold.
    pub key: (u64, u32),
}

/// What one [`Emitter::step`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// The first primitive was loaded into the input register (no stack operation).
    Loaded,
    /// The input primitive had the current leaf's key and was combined into it.
    Combined,
    /// The current subtree was pushed with its level; the next primitive became the input.
    Pushed,
    /// The stack top was popped and joined with the current subtree into this node.
    Emitted(EmittedNode),
    /// The current subtree was complete for its cell and went to the high-level output.
    Highlevel(HighlevelRoot),
    /// The stream has ended and everything has been emitted.
    Done,
}

/// The subtree in the input register or in a stack entry.
#[derive(Clone, Copy, Debug)]
struct Sub {
    aabb: Aabb,
    root: EmitRef,
}

/// The streaming hierarchy emitter of \[P2\] Algorithm 1 as a step machine.
///
/// Call [`Emitter::needs_input`] before each step: when it is true, pass the next sorted
/// primitive (or `None` at the end of the stream) to [`Emitter::step`]; otherwise pass
/// `None`. Each step performs one stack push, one pop with a node emission, one high-level
/// output, or one leaf enlargement, so a cycle model can call it once per cycle.
///
/// ```
/// use bvh::{Emitter, Prim, Step};
/// use geom::{Aabb, Vec3};
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
/// let mut input = [1u64, 2, 4].into_iter().map(|code| Prim { code, tie: 0, aabb: unit });
/// let mut em = Emitter::new(None);
/// let (mut nodes, mut cycles) = (Vec::new(), 0);
/// loop {
///     // A cycle model would stall here while its input FIFO is empty.
///     let inp = if em.needs_input() { input.next() } else { None };
///     match em.step(inp) {
///         Step::Emitted(n) => nodes.push(n),
///         Step::Done => break,
///         _ => {}
///     }
///     cycles += 1;
/// }
/// assert_eq!(nodes.len(), 2); // 3 leaves, 2 inner nodes, bottom-up
/// assert_eq!(cycles, 6); // load, 2 pushes, 2 pops, the root to the high-level output
/// ```
#[derive(Clone, Debug)]
pub struct Emitter {
    /// Internal threshold on key levels (code level + [`TIE_BITS`]).
    threshold: u32,
    /// Stack of (left subtree waiting for its right sibling, its level).
    stack: Vec<(Sub, u32)>,
    /// The input register: the current subtree.
    cur: Option<Sub>,
    /// Key of the last primitive read (the current subtree's last primitive).
    last: (u64, u32),
    /// The primitive read ahead that starts the next leaf once the stack work is done.
    pending: Option<Prim>,
    /// Level between the current subtree and the next input, while reducing.
    level: u32,
    /// True while stack work is due before more input is read.
    reducing: bool,
    /// True after the final high-level output.
    done: bool,
    /// Primitives read so far (the next sorted position).
    read: u32,
    /// Nodes emitted so far (the next node's emission index).
    emitted: u32,
    /// Deepest stack seen.
    max_depth: usize,
}

impl Emitter {
    /// An emitter that cuts subtrees above `highlevel_threshold` (a 1-based code-bit level,
    /// `None` for a single tree).
    pub fn new(highlevel_threshold: Option<u32>) -> Self {
        Self {
            threshold: highlevel_threshold.map_or(END_LEVEL - 1, |t| t.saturating_add(TIE_BITS)),
            stack: Vec::new(),
            cur: None,
            last: (0, 0),
            pending: None,
            level: 0,
            reducing: false,
            done: false,
            read: 0,
            emitted: 0,
            max_depth: 0,
        }
    }

    /// True when the next [`Emitter::step`] reads an input (a primitive or end of stream).
    #[inline]
    pub fn needs_input(&self) -> bool {
        !self.reducing && !self.done
    }

    /// Deepest stack seen so far (at most the key length, 64 + 32 levels).
    pub fn max_stack_depth(&self) -> usize {
        self.max_depth
    }

    /// A leaf subtree for `p` at the next sorted position.
    #[inline]
    fn load(&mut self, p: &Prim) -> Sub {
        let first = self.read;
        self.read += 1;
        self.last = (p.code, p.tie);
        Sub {
            aabb: p.aabb,
            root: EmitRef::Leaf { first, count: 1 },
        }
    }

    /// Performs one step; `input` must be `None` unless [`Emitter::needs_input`] is true.
    // Inlined into its loops: returned through memory, the 80-byte `Step` costs a stalled
    // store-to-load forward per step (seen in the profile of the HLBVH build).
    #[inline(always)]
    pub fn step(&mut self, input: Option<Prim>) -> Step {
        if self.done {
            return Step::Done;
        }
        if !self.reducing {
            let Some(cur) = self.cur else {
                // Empty input register: only at the very start.
                return match input {
                    Some(p) => {
                        self.cur = Some(self.load(&p));
                        Step::Loaded
                    }
                    None => {
                        self.done = true;
                        Step::Done
                    }
                };
            };
            match input {
                Some(p) if (p.code, p.tie) == self.last => {
                    // [P2] lines 4..8: same key, enlarge the leaf.
                    let EmitRef::Leaf { first, count } = cur.root else {
                        unreachable!("equal keys only follow a leaf")
                    };
                    self.read += 1;
                    self.cur = Some(Sub {
                        aabb: cur.aabb.union(p.aabb),
                        root: EmitRef::Leaf {
                            first,
                            count: count + 1,
                        },
                    });
                    return Step::Combined;
                }
                Some(p) => {
                    self.level = level(self.last, (p.code, p.tie));
                    self.pending = Some(p);
                }
                None => {
                    self.level = END_LEVEL;
                    self.pending = None;
                }
            }
            self.reducing = true;
        }
        let cur = self
            .cur
            .expect("a subtree is in the input register while reducing");
        // [P2] lines 10..14: complete the nodes whose right child ends here.
        if let Some(&(top, top_level)) = self.stack.last() {
            if top_level < self.level {
                self.stack.pop();
                let node = EmittedNode {
                    aabbs: [top.aabb, cur.aabb],
                    children: [top.root, cur.root],
                };
                self.cur = Some(Sub {
                    aabb: top.aabb.union(cur.aabb),
                    root: EmitRef::Node(self.emitted),
                });
                self.emitted += 1;
                return Step::Emitted(node);
            }
        }
        // [P2] lines 15..19: the subtree is complete for its cell, or waits on the stack.
        let step = if self.level > self.threshold {
            Step::Highlevel(HighlevelRoot {
                aabb: cur.aabb,
                root: cur.root,
                key: self.last,
            })
        } else {
            self.stack.push((cur, self.level));
            self.max_depth = self.max_depth.max(self.stack.len());
            Step::Pushed
        };
        self.reducing = false;
        match self.pending.take() {
            Some(p) => self.cur = Some(self.load(&p)),
            None => {
                self.cur = None;
                self.done = true;
            }
        }
        step
    }
}

/// The emitter's complete output for one scene: nodes, cell roots and the leaf table.
#[derive(Clone, Debug, PartialEq)]
pub struct Highlevel {
    /// Emitted inner nodes, in emission order ([`EmitRef::Node`] indexes this).
    pub nodes: Vec<EmittedNode>,
    /// Cell roots in Morton order (one root when there is no threshold; none when empty).
    pub roots: Vec<HighlevelRoot>,
    /// Leaf table: the primitive index at each sorted position.
    pub order: Vec<u32>,
}

impl Highlevel {
    /// The first emitted node of the subtree rooted at emitted node `root`: its nodes are
    /// the emission range `first..=root` (emission is postorder).
    pub(crate) fn subtree_first(&self, root: u32) -> u32 {
        // Descend to the first inner child until there is none.
        let mut lo = root;
        while let [EmitRef::Node(c), _] | [EmitRef::Leaf { .. }, EmitRef::Node(c)] =
            self.nodes[lo as usize].children
        {
            lo = c;
        }
        lo
    }

    /// Appends the subtree `r` to `out` in depth-first preorder and returns its reference.
    pub(crate) fn append_subtree(&self, r: EmitRef, out: &mut Vec<Node>) -> ChildRef {
        let EmitRef::Node(root) = r else {
            return child_ref(r);
        };
        let base = out.len();
        let first = self.subtree_first(root);
        out.resize(base + (root - first) as usize + 1, Node::EMPTY);
        self.write_subtree(first, root, base as u32, &mut out[base..]);
        ChildRef::inner(base as u32)
    }

    /// Writes the subtree of emitted nodes `first..=root` in depth-first preorder to `out`
    /// (exactly that many nodes), whose first node will be node `base` of the tree.
    pub(crate) fn write_subtree(&self, first: u32, root: u32, base: u32, out: &mut [Node]) {
        let range = &self.nodes[first as usize..=root as usize];
        layout_preorder(range, first, base, out, &mut Vec::new());
    }

    /// The tree of a single-root output (no threshold) as a [`Bvh2`]; the cell roots of a
    /// cut output are joined by [`crate::toplevel::stitch`] instead.
    pub fn to_bvh2(&self) -> Bvh2 {
        match self.roots.as_slice() {
            [] => Bvh2::empty(),
            [root] => {
                let mut nodes = Vec::with_capacity(self.nodes.len());
                let r = self.append_subtree(root.root, &mut nodes);
                Bvh2::from_root(r, root.aabb, nodes, self.order.clone())
            }
            _ => crate::toplevel::stitch(&crate::toplevel::morton_top(self), self)
                .expect("the Morton top tree is a valid tree over the cell roots"),
        }
    }
}

/// Writes emitted nodes `range` — a whole subtree in emission (post)order, `range[k]` being
/// emitted node `first + k` and its last node the root — in depth-first preorder to `out`
/// (exactly `range.len()` nodes), whose first node will be node `base` of the tree.
///
/// One forward pass over the range counts subtree sizes ([`subtree_sizes`]); one backward
/// pass (parents before children) places every node at its preorder index (child 0 right
/// after its parent, child 1 after child 0's subtree). Both read the nodes sequentially.
/// `scratch` is reused between calls (two `u32` per node).
pub(crate) fn layout_preorder(
    range: &[EmittedNode],
    first: u32,
    base: u32,
    out: &mut [Node],
    scratch: &mut Vec<u32>,
) {
    scratch.clear();
    scratch.extend(subtree_sizes(range, first));
    place_preorder(range, first, base, out, scratch);
}

/// The node count of each emitted node's subtree, for a range in emission order whose
/// node `k` is emitted node `first + k` (children come before their parent).
fn subtree_sizes(range: &[EmittedNode], first: u32) -> impl Iterator<Item = u32> + '_ {
    let mut size: Vec<u32> = Vec::with_capacity(range.len());
    range.iter().map(move |e| {
        let s = 1 + node_size(&size, first, e.children[0]) + node_size(&size, first, e.children[1]);
        size.push(s);
        s
    })
}

/// The node count of the subtree of `c` given the sizes of emitted nodes `first..`.
#[inline]
fn node_size(size: &[u32], first: u32, c: EmitRef) -> u32 {
    match c {
        EmitRef::Node(id) => size[(id - first) as usize],
        EmitRef::Leaf { .. } => 0,
    }
}

/// The backward pass of [`layout_preorder`]; `scratch` holds the subtree sizes of `range`
/// and is extended by the preorder positions.
fn place_preorder(
    range: &[EmittedNode],
    first: u32,
    base: u32,
    out: &mut [Node],
    scratch: &mut Vec<u32>,
) {
    debug_assert_eq!(out.len(), range.len());
    let m = range.len();
    debug_assert_eq!(scratch.len(), m);
    scratch.resize(2 * m, 0);
    let (size, pre) = scratch.split_at_mut(m);
    for (k, e) in range.iter().enumerate().rev() {
        let at = pre[k];
        let mut refs = [child_ref(e.children[0]), child_ref(e.children[1])];
        if let EmitRef::Node(c) = e.children[0] {
            pre[(c - first) as usize] = at + 1;
            refs[0] = ChildRef::inner(base + at + 1);
        }
        if let EmitRef::Node(c) = e.children[1] {
            let p = at + 1 + node_size(size, first, e.children[0]);
            pre[(c - first) as usize] = p;
            refs[1] = ChildRef::inner(base + p);
        }
        out[at as usize] = Node::new(&e.aabbs[0], refs[0], &e.aabbs[1], refs[1]);
    }
}

/// The [`ChildRef`] of an emitted leaf; inner references are patched by the caller.
#[inline]
fn child_ref(r: EmitRef) -> ChildRef {
    match r {
        EmitRef::Leaf { first, count } => ChildRef::leaf(first, count),
        EmitRef::Node(_) => ChildRef::inner(0),
    }
}

/// The tie field of each sorted position in turn (see the module doc): the chunk index
/// inside a run of identical codes when combining, the sorted position otherwise.
struct Ties {
    combine: bool,
    max_leaf: u32,
    /// Chunk index inside the current run of identical codes.
    chunk: u32,
    /// Position inside the current chunk.
    in_chunk: u32,
}

impl Ties {
    fn new(combine: bool, max_leaf: u32) -> Self {
        Self {
            combine,
            max_leaf,
            chunk: 0,
            in_chunk: 0,
        }
    }

    /// The tie of sorted position `k`, whose code equals the previous position's when
    /// `same`, and whether `k` starts a new leaf (its key differs from the previous one).
    #[inline]
    fn next(&mut self, k: usize, same: bool) -> (u32, bool) {
        if !self.combine {
            return (k as u32, true);
        }
        // `run / max_leaf` and `run % max_leaf == 0` for the position `run` in the run of
        // identical codes, without a division per primitive.
        if !same {
            (self.chunk, self.in_chunk) = (0, 0);
        } else {
            self.in_chunk += 1;
            if self.in_chunk == self.max_leaf {
                (self.chunk, self.in_chunk) = (self.chunk + 1, 0);
            }
        }
        (self.chunk, self.in_chunk == 0)
    }
}

/// Tie fields of sorted `codes` (see [`Ties`]).
pub(crate) fn ties(codes: &[u64], combine: bool, max_leaf: u32) -> Vec<u32> {
    let mut t = Ties::new(combine, max_leaf);
    (0..codes.len())
        .map(|k| t.next(k, k > 0 && codes[k - 1] == codes[k]).0)
        .collect()
}

/// The test of a large primitive for `large_prims = Some(f)` (see the field) over the
/// centroid box `cbounds`: `wider(d)` for a box of extent `d`. An axis on which all
/// centroids agree gets an infinite limit.
fn large_test(f: f32, cbounds: &Aabb) -> impl Fn(Vec3) -> bool + Sync {
    let e = cbounds.max - cbounds.min;
    let lim = |e: f32| if e > 0.0 { f * e } else { f32::INFINITY };
    let (x, y, z) = (lim(e.x), lim(e.y), lim(e.z));
    move |d: Vec3| (d.x > x) | (d.y > y) | (d.z > z)
}

/// Boxes a cell emitter gathers at a time (96 KiB).
const GATHER_BLOCK: usize = 4096;

/// Per-thread buffers of [`HlbvhBuilder::build`]'s cell emitters, reused across cells.
#[derive(Default)]
struct CellScratch {
    /// The next block of the cell's boxes in sorted order (at most [`GATHER_BLOCK`]).
    boxes: Vec<Aabb>,
    /// The cell's emitted nodes.
    nodes: Vec<EmittedNode>,
    /// Subtree sizes, then preorder positions, of the cell's nodes ([`place_preorder`]).
    layout: Vec<u32>,
}

/// The buffers of [`HlbvhBuilder::build_into`], kept from one build to the next as a
/// renderer keeps them from frame to frame: the sort keys and their second buffer, the
/// sorted codes, and the cells' ranges and plan. With the output tree they are all the
/// memory a build needs but each thread's buffers for one cell, so a build into buffers of
/// an earlier build of as many primitives or more allocates nothing large and touches no
/// fresh page (fresh pages and the frees of the previous build's buffers were a quarter of
/// a 2-thread Dragon build).
/// Any arena suits any build: its contents never change the tree.
#[derive(Debug, Default)]
pub struct HlbvhArena {
    /// Key arrays of the Morton sort.
    sort: crate::morton_sort::SortBuffers,
    /// Sorted Morton codes.
    codes: Vec<u64>,
    /// Cells: ranges of sorted positions.
    cells: Vec<std::ops::Range<usize>>,
    /// Per cell: inner nodes, tie of its last primitive, box (see `build_cells`).
    plan: Vec<(u32, u32, Aabb)>,
}

impl HlbvhArena {
    /// Bytes held by the arena's buffers (their capacity).
    pub fn capacity_bytes(&self) -> usize {
        self.sort.capacity_bytes()
            + self.codes.capacity() * std::mem::size_of::<u64>()
            + self.cells.capacity() * std::mem::size_of::<std::ops::Range<usize>>()
            + self.plan.capacity() * std::mem::size_of::<(u32, u32, Aabb)>()
    }
}

/// A node of the top tree over the cells, or a cell, while laying out the final tree.
#[derive(Clone, Copy)]
enum Slot {
    Top(usize),
    Cell(usize),
}

impl HlbvhBuilder {
    /// Checks the configuration.
    pub(crate) fn check(&self) -> Result<(), BuildError> {
        if self.max_leaf_size == 0 {
            return Err(BuildError::InvalidConfig(
                "HLBVH max_leaf_size must be at least 1".into(),
            ));
        }
        if let Some(f) = self.large_prims.filter(|f| !(f.is_finite() && *f > 0.0)) {
            return Err(BuildError::InvalidConfig(format!(
                "HLBVH large_prims must be finite and greater than 0, not {f}"
            )));
        }
        Ok(())
    }

    /// The sorted stream of `aabbs` into `codes` and `order`: Morton codes, with the
    /// large-primitive bit when [`HlbvhBuilder::large_prims`] is set.
    fn sorted_codes_into(
        &self,
        aabbs: &[Aabb],
        sort: &mut crate::morton_sort::SortBuffers,
        codes: &mut Vec<u64>,
        order: &mut Vec<u32>,
    ) {
        let centroid = |i: usize| crate::centroid(&aabbs[i]);
        let Some(f) = self.large_prims else {
            crate::morton_sort::sorted_codes_into(
                aabbs.len(),
                centroid,
                self.bits,
                self.grid,
                sort,
                codes,
                order,
            );
            return;
        };
        crate::morton_sort::sorted_tagged_codes_into(
            aabbs.len(),
            centroid,
            |cb| {
                let wider = large_test(f, cb);
                move |i: usize| wider(aabbs[i].max - aabbs[i].min)
            },
            self.bits,
            self.grid,
            sort,
            codes,
            order,
        );
    }

    /// Largest leaf this configuration produces (for the validator).
    pub fn leaf_limit(&self) -> u32 {
        if self.combine_identical {
            self.max_leaf_size
        } else {
            1
        }
    }

    /// Builds a single tree over the primitive boxes `aabbs` (the threshold is not used:
    /// joining the cells by their Morton prefixes gives the uncut tree).
    ///
    /// Large inputs are emitted as cells of the top `PARALLEL_CELL_BITS` (9) code bits in
    /// parallel, joined by [`crate::toplevel::morton_top`]: the result is node for node the
    /// single-stream tree (the tests check this), for any thread count. The nodes go
    /// straight into the final [`Bvh2`] (see `HlbvhBuilder::build_cells`). A caller that
    /// builds again and again (every frame) uses [`HlbvhBuilder::build_into`].
    pub fn build(&self, aabbs: &[Aabb]) -> Result<Bvh2, BuildError> {
        let mut out = Bvh2::empty();
        self.build_into(aabbs, &mut HlbvhArena::default(), &mut out)?;
        Ok(out)
    }

    /// [`HlbvhBuilder::build`] into `out`, whose tree it replaces, with the buffers of
    /// `arena`: a renderer keeps both from frame to frame and rebuilds into them, so that
    /// a build after the first reuses the previous one's memory (output nodes, leaf table,
    /// sort keys, codes) instead of allocating, faulting in and freeing it again. The tree
    /// is node for node the one [`HlbvhBuilder::build`] gives, whatever `out` and `arena`
    /// held before (tests check it). On an error `out` is left the empty tree.
    pub fn build_into(
        &self,
        aabbs: &[Aabb],
        arena: &mut HlbvhArena,
        out: &mut Bvh2,
    ) -> Result<(), BuildError> {
        let checked = check_input(aabbs).and_then(|()| self.check());
        if let Err(e) = checked {
            out.clear();
            return Err(e);
        }
        let shift = if aabbs.len() >= 2 * PARALLEL_MIN_PRIMS {
            self.bits.total_bits() - PARALLEL_CELL_BITS
        } else {
            u32::MAX
        };
        in_pool(self.threads, || {
            self.build_cells(aabbs, shift, false, arena, out, |hl| {
                Ok(crate::toplevel::morton_top(hl))
            })
        })?
    }

    /// Emits the cells of equal `code >> shift` (one cell when `shift >= 64`) and joins
    /// them under the tree `top` builds over them: a valid tree over the cell roots' boxes
    /// whose leaves hold one root each, like [`crate::toplevel::stitch`] takes. `top` gets
    /// the cells as a [`Highlevel`] with `roots` only (each root's key and, when `boxes`,
    /// its box; `root` is a placeholder) and no `nodes` or `order`. Input and configuration
    /// are checked by the caller; runs in the current pool.
    ///
    /// The emitted nodes go straight into the final [`Bvh2`]: each cell's node count (its
    /// leaves, the distinct sort keys, less one) and box follow from the sorted codes, so
    /// the top tree over the cells and every cell's place in the preorder layout are known
    /// before emission, and each cell's emitter lays its subtree out into its own range of
    /// the output from a small buffer that stays in cache. No emission-order array of the
    /// whole tree is made (the [`HlbvhBuilder::build_highlevel`] output keeps one). The
    /// result is node for node `stitch(top, build_highlevel(..))` (tests check it); a top
    /// tree with a leaf of several roots is stitched that way.
    ///
    /// The tree is written into `out` (replacing it, reusing its buffers), with the
    /// buffers of `arena`; on an error `out` is left the empty tree.
    pub(crate) fn build_cells(
        &self,
        aabbs: &[Aabb],
        shift: u32,
        boxes: bool,
        arena: &mut HlbvhArena,
        out: &mut Bvh2,
        top: impl FnOnce(&Highlevel) -> Result<Bvh2, BuildError>,
    ) -> Result<(), BuildError> {
        let done = self.build_cells_into(aabbs, shift, boxes, arena, out, top);
        if done.is_err() {
            out.clear();
        }
        done
    }

    /// [`HlbvhBuilder::build_cells`] without the clean-up on an error.
    fn build_cells_into(
        &self,
        aabbs: &[Aabb],
        shift: u32,
        boxes: bool,
        arena: &mut HlbvhArena,
        out: &mut Bvh2,
        top: impl FnOnce(&Highlevel) -> Result<Bvh2, BuildError>,
    ) -> Result<(), BuildError> {
        let HlbvhArena {
            sort,
            codes,
            cells,
            plan,
        } = arena;
        let mut order = std::mem::take(&mut out.prim_indices);
        self.sorted_codes_into(aabbs, sort, codes, &mut order);
        let (codes, order) = (&codes[..], order);
        let n = codes.len();
        if n == 0 {
            out.prim_indices = order;
            out.clear();
            return Ok(());
        }
        // Cells: runs of equal `code >> shift`.
        let prefix = |c: u64| c.checked_shr(shift).unwrap_or(0);
        cells.clear();
        if shift < 64 {
            // Room for the most cells there can be (twice as many with large primitives
            // apart), so that a later build of no more primitives keeps these buffers.
            let most = 1usize << (PARALLEL_CELL_BITS + self.large_prims.is_some() as u32);
            plan.clear();
            cells.reserve(most);
            plan.reserve(most);
        }
        let mut start = 0;
        while start < n {
            let p = prefix(codes[start]);
            let end = start + codes[start..].partition_point(|&c| prefix(c) == p);
            cells.push(start..end);
            start = end;
        }
        // Per cell: inner nodes (its leaves, the distinct keys, less one), the key of its
        // last primitive, and its box when the top tree needs it.
        cells
            .par_iter()
            .map(|r| {
                let mut t = Ties::new(self.combine_identical, self.max_leaf_size);
                let (mut leaves, mut tie) = (0u32, 0u32);
                for k in r.clone() {
                    let (tk, starts) = t.next(k, k > r.start && codes[k - 1] == codes[k]);
                    leaves += starts as u32;
                    tie = tk;
                }
                let b = if boxes {
                    order[r.clone()]
                        .iter()
                        .fold(Aabb::EMPTY, |b, &i| b.union(aabbs[i as usize]))
                } else {
                    Aabb::EMPTY
                };
                (leaves - 1, tie, b)
            })
            .collect_into_vec(plan);
        let (cells, plan) = (&cells[..], &plan[..]);
        if cells.len() == 1 {
            // Every node is written by the emitter's layout: no fill pass.
            crate::size_for_overwrite(&mut out.nodes, plan[0].0 as usize);
            let mut sc = CellScratch::default();
            let (root, bounds) =
                self.emit_cell(0..n, codes, &order, aabbs, 0, &mut out.nodes, &mut sc);
            out.prim_indices = order;
            out.set_root(root, bounds);
            return Ok(());
        }
        let skeleton = Highlevel {
            nodes: Vec::new(),
            roots: cells
                .iter()
                .zip(plan)
                .map(|(r, p)| HighlevelRoot {
                    aabb: p.2,
                    root: EmitRef::Leaf { first: 0, count: 0 },
                    key: (codes[r.end - 1], p.1),
                })
                .collect(),
            order: Vec::new(),
        };
        let top = top(&skeleton)?;
        if boxes {
            let b = crate::toplevel::root_boxes(&skeleton);
            crate::validate::validate(&top, &b, u32::MAX).map_err(|e| {
                BuildError::InvalidConfig(format!("top tree over the cell roots: {e}"))
            })?;
        }
        let root = top.nodes[0];
        let grouped = top
            .nodes
            .iter()
            .any(|t| t.children.iter().any(|c| c.count > 1));
        if grouped || root.children[1].is_empty() {
            // A leaf of several roots: the general stitch over the whole emission.
            let hl = HlbvhBuilder {
                highlevel_threshold: Some(shift),
                ..self.clone()
            }
            .emit_all(aabbs);
            *out = crate::toplevel::stitch(&top, &hl)?;
            return Ok(());
        }
        // Preorder places: each top node, then each cell's range, child 0 first.
        let cell_of = |c: ChildRef| top.prim_indices[c.index as usize] as usize;
        let mut top_at = vec![0u32; top.nodes.len()];
        let mut cell_at = vec![0u32; cells.len()];
        let mut by_place = Vec::with_capacity(cells.len());
        let mut at = 0u32;
        let mut stack = vec![Slot::Top(0)];
        while let Some(slot) = stack.pop() {
            match slot {
                Slot::Top(t) => {
                    top_at[t] = at;
                    at += 1;
                    for c in top.nodes[t].children.iter().rev() {
                        if c.is_inner() {
                            stack.push(Slot::Top(c.index as usize));
                        } else if c.is_leaf() {
                            stack.push(Slot::Cell(cell_of(*c)));
                        }
                    }
                }
                Slot::Cell(c) => {
                    cell_at[c] = at;
                    at += plan[c].0;
                    by_place.push(c);
                }
            }
        }
        // No fill pass: every node is written below.
        crate::size_for_overwrite(&mut out.nodes, at as usize);
        let nodes = &mut out.nodes;
        // Each cell's range of the output, in the order of their places.
        let mut tasks: Vec<(usize, &mut [Node])> = Vec::with_capacity(cells.len());
        let mut rest = nodes.as_mut_slice();
        let mut taken = 0usize;
        for &c in &by_place {
            let from = cell_at[c] as usize;
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(from - taken);
            let (mine, tail) = tail.split_at_mut(plan[c].0 as usize);
            taken = from + mine.len();
            rest = tail;
            tasks.push((c, mine));
        }
        let mut roots = vec![(ChildRef::EMPTY, Aabb::EMPTY); cells.len()];
        let emitted: Vec<(usize, (ChildRef, Aabb))> = tasks
            .into_par_iter()
            .map_init(CellScratch::default, |sc, (c, out)| {
                let r = cells[c].clone();
                (
                    c,
                    self.emit_cell(r, codes, &order, aabbs, cell_at[c], out, sc),
                )
            })
            .collect();
        for (c, r) in emitted {
            roots[c] = r;
        }
        // The top nodes, children (later in preorder) before parents.
        let mut top_box = vec![Aabb::EMPTY; top.nodes.len()];
        for t in (0..top.nodes.len()).rev() {
            let kid = |c: ChildRef| {
                if c.is_inner() {
                    let i = c.index as usize;
                    (ChildRef::inner(top_at[i]), top_box[i])
                } else {
                    roots[cell_of(c)]
                }
            };
            let [k0, k1] = top.nodes[t].children.map(kid);
            nodes[top_at[t] as usize] = Node::new(&k0.1, k0.0, &k1.1, k1.0);
            top_box[t] = k0.1.union(k1.1);
        }
        out.prim_indices = order;
        out.bounds = top_box[0];
        Ok(())
    }

    /// Emits the cell of sorted positions `r` with one emitter and lays its subtree out in
    /// preorder into `out` (exactly its inner nodes), whose first node is node `base` of
    /// the tree. Returns the cell root's reference and box.
    #[allow(clippy::too_many_arguments)]
    fn emit_cell(
        &self,
        r: std::ops::Range<usize>,
        codes: &[u64],
        order: &[u32],
        aabbs: &[Aabb],
        base: u32,
        out: &mut [Node],
        sc: &mut CellScratch,
    ) -> (ChildRef, Aabb) {
        // Gather the cell's boxes in a tight loop, a block at a time: its cache misses
        // overlap, where the emission loop would take them one at a time ([P2] §4.2 sorts
        // the AABBs themselves for the same reason). Blocks, not the whole cell: a cell can
        // hold most of the scene (62% of Conference), and its boxes would be the peak.
        sc.boxes.clear();
        sc.nodes.clear();
        sc.nodes.reserve(out.len());
        sc.layout.clear();
        sc.layout.reserve(2 * out.len());
        let mut em = Emitter::new(None);
        em.read = r.start as u32;
        let mut ties = Ties::new(self.combine_identical, self.max_leaf_size);
        let boxes = &mut sc.boxes;
        let mut next_box = 0usize;
        let mut input = r.clone().map(|k| {
            if next_box == boxes.len() {
                boxes.clear();
                let end = r.end.min(k + GATHER_BLOCK);
                boxes.extend(order[k..end].iter().map(|&i| aabbs[i as usize]));
                next_box = 0;
            }
            let aabb = boxes[next_box];
            next_box += 1;
            let same = k > r.start && codes[k - 1] == codes[k];
            Prim {
                code: codes[k],
                tie: ties.next(k, same).0,
                aabb,
            }
        });
        let mut root = None;
        loop {
            let inp = if em.needs_input() { input.next() } else { None };
            match em.step(inp) {
                Step::Emitted(e) => {
                    // Subtree sizes as the nodes come (the forward pass of the layout).
                    let s = 1
                        + node_size(&sc.layout, 0, e.children[0])
                        + node_size(&sc.layout, 0, e.children[1]);
                    sc.layout.push(s);
                    sc.nodes.push(e);
                }
                Step::Highlevel(h) => root = Some(h),
                Step::Done => break,
                Step::Loaded | Step::Combined | Step::Pushed => {}
            }
        }
        let root = root.expect("a non-empty stream ends with its root");
        match root.root {
            EmitRef::Leaf { first, count } => (ChildRef::leaf(first, count), root.aabb),
            EmitRef::Node(_) => {
                place_preorder(&sc.nodes, 0, base, out, &mut sc.layout);
                (ChildRef::inner(base), root.aabb)
            }
        }
    }

    /// Runs the emitter with the configured threshold and returns its raw output: the
    /// emitted nodes, the cell roots for a toplevel build, and the leaf table.
    ///
    /// With a threshold, runs of whole cells are emitted in parallel by separate emitters
    /// and concatenated; cells are independent (the stack is empty at every cell boundary),
    /// so the output equals that of one emitter over the whole stream.
    pub fn build_highlevel(&self, aabbs: &[Aabb]) -> Result<Highlevel, BuildError> {
        check_input(aabbs)?;
        self.check()?;
        in_pool(self.threads, || self.emit_all(aabbs))
    }

    fn emit_all(&self, aabbs: &[Aabb]) -> Highlevel {
        let (mut codes, mut order) = (Vec::new(), Vec::new());
        self.sorted_codes_into(aabbs, &mut Default::default(), &mut codes, &mut order);
        // Gather the boxes in sorted order up front: a tight parallel loop overlaps the cache
        // misses of this random gather, which dominated the serial emission loop ([P2] §4.2
        // sorts the AABBs themselves for the same reason).
        let boxes: Vec<Aabb> = order.par_iter().map(|&i| aabbs[i as usize]).collect();
        let ties = ties(&codes, self.combine_identical, self.max_leaf_size);
        let n = codes.len();
        if n == 0 {
            return Highlevel {
                nodes: Vec::new(),
                roots: Vec::new(),
                order,
            };
        }
        // Chunk boundaries (every chunk non-empty): the first cell boundary at or after each
        // equal share of the stream (cells are runs of equal `code >> shift`).
        let mut bounds = vec![0usize];
        if let Some(shift) = self.highlevel_threshold.filter(|&t| t < 64) {
            let chunks = (n / PARALLEL_MIN_PRIMS).clamp(1, 4 * rayon::current_num_threads());
            for c in 1..chunks {
                let mut k = (c * n / chunks).max(*bounds.last().expect("non-empty"));
                if k > 0 && k < n {
                    let cell = codes[k - 1] >> shift;
                    k += codes[k..].partition_point(|&c| c >> shift == cell);
                }
                if k > *bounds.last().expect("non-empty") && k < n {
                    bounds.push(k);
                }
            }
        }
        bounds.push(n);
        // Chunk `i` over positions `a..b` emits at most `b - a - 1` nodes; it writes them
        // to its own slice of one shared buffer, at `a - i`, so no per-chunk vectors are
        // allocated and copied (fresh pages were a third of the build time).
        let capacity = n - (bounds.len() - 1);
        let mut nodes: Vec<EmittedNode> =
            (0..capacity).into_par_iter().map(|_| PLACEHOLDER).collect();
        let mut slices = Vec::with_capacity(bounds.len() - 1);
        let mut rest = nodes.as_mut_slice();
        for w in bounds.windows(2) {
            let (head, tail) = rest.split_at_mut(w[1] - w[0] - 1);
            slices.push(head);
            rest = tail;
        }
        let parts: Vec<(u32, Vec<HighlevelRoot>)> = bounds
            .par_windows(2)
            .zip(slices.into_par_iter())
            .map(|(w, out)| {
                let r = w[0]..w[1];
                self.emit_range(w[0], &codes[r.clone()], &ties[r.clone()], &boxes[r], out)
            })
            .collect();
        // Renumber each chunk's nodes after those of the chunks before it, then close the
        // gaps between the chunks' slices (moves to the left, in place).
        let mut offsets = Vec::with_capacity(parts.len());
        let mut total = 0u32;
        for p in &parts {
            offsets.push(total);
            total += p.0;
        }
        let shift = |r: EmitRef, off: u32| match r {
            EmitRef::Node(id) => EmitRef::Node(id + off),
            leaf => leaf,
        };
        if parts.len() > 1 {
            let mut slices = Vec::with_capacity(parts.len());
            let mut rest = nodes.as_mut_slice();
            for (w, p) in bounds.windows(2).zip(&parts) {
                let (head, tail) = rest.split_at_mut(w[1] - w[0] - 1);
                slices.push(&mut head[..p.0 as usize]);
                rest = tail;
            }
            slices
                .into_par_iter()
                .zip(offsets.par_iter())
                .for_each(|(sl, &off)| {
                    for e in sl {
                        e.children = e.children.map(|c| shift(c, off));
                    }
                });
            for (i, (w, p)) in bounds.windows(2).zip(&parts).enumerate() {
                let src = w[0] - i;
                nodes.copy_within(src..src + p.0 as usize, offsets[i] as usize);
            }
        }
        nodes.truncate(total as usize);
        let mut roots = Vec::new();
        for (p, &off) in parts.iter().zip(&offsets) {
            roots.extend(p.1.iter().map(|r| HighlevelRoot {
                root: shift(r.root, off),
                ..*r
            }));
        }
        Highlevel {
            nodes,
            roots,
            order,
        }
    }

    /// One emitter over sorted positions `first..first + codes.len()`; writes its nodes to
    /// `out` (room for `codes.len() - 1`) and returns their count and the cell roots.
    fn emit_range(
        &self,
        first: usize,
        codes: &[u64],
        ties: &[u32],
        boxes: &[Aabb],
        out: &mut [EmittedNode],
    ) -> (u32, Vec<HighlevelRoot>) {
        let mut em = Emitter::new(self.highlevel_threshold);
        em.read = first as u32;
        let mut count = 0usize;
        let mut roots = Vec::new();
        let mut input = codes
            .iter()
            .zip(ties)
            .zip(boxes)
            .map(|((&code, &tie), &aabb)| Prim { code, tie, aabb });
        loop {
            let inp = if em.needs_input() { input.next() } else { None };
            match em.step(inp) {
                Step::Emitted(n) => {
                    out[count] = n;
                    count += 1;
                }
                Step::Highlevel(r) => roots.push(r),
                Step::Done => break,
                Step::Loaded | Step::Combined | Step::Pushed => {}
            }
        }
        (count as u32, roots)
    }
}

/// Filler of the node buffer before emission overwrites it.
const PLACEHOLDER: EmittedNode = EmittedNode {
    aabbs: [Aabb::EMPTY; 2],
    children: [EmitRef::Leaf { first: 0, count: 0 }; 2],
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::centroid;
    use crate::morton_sort::sorted_codes;
    use crate::testutil::*;
    use crate::{validate, SweepSahBuilder};
    use geom::MortonQuantizer;
    use geom::Vec3;
    use proptest::prelude::*;

    /// Straightforward recursive reference of the same Morton-prefix topology: sort, derive
    /// the 96-bit keys, split each range at its highest differing key bit, and make a range
    /// of one key a single leaf.
    fn reference(aabbs: &[Aabb], cfg: &HlbvhBuilder) -> Bvh2 {
        if aabbs.is_empty() {
            return Bvh2::empty();
        }
        let cb = aabbs.iter().fold(Aabb::EMPTY, |b, a| b.grow(centroid(a)));
        let q = MortonQuantizer::with_grid(&cb, cfg.grid);
        let mut pairs: Vec<(u64, u32)> = aabbs
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let c = match cfg.bits {
                    MortonBits::Bits30 => q.code30(centroid(a)) as u64,
                    MortonBits::Bits63 => q.code63(centroid(a)),
                };
                // Large primitives: the bit above the code (written out per axis here).
                let (d, e) = (a.max - a.min, cb.max - cb.min);
                let large = cfg.large_prims.is_some_and(|f| {
                    [(d.x, e.x), (d.y, e.y), (d.z, e.z)]
                        .iter()
                        .any(|&(d, e)| e > 0.0 && d > f * e)
                });
                (c | (large as u64) << cfg.bits.total_bits(), i as u32)
            })
            .collect();
        pairs.sort();
        let mut keys = Vec::new();
        for (k, &(c, _)) in pairs.iter().enumerate() {
            let tie = if cfg.combine_identical {
                let run = pairs[..k].iter().rev().take_while(|p| p.0 == c).count() as u32;
                run / cfg.max_leaf_size
            } else {
                k as u32
            };
            keys.push(((c as u128) << 32) | tie as u128);
        }
        let order: Vec<u32> = pairs.iter().map(|p| p.1).collect();
        let boxes: Vec<Aabb> = order.iter().map(|&i| aabbs[i as usize]).collect();
        fn rec(
            lo: usize,
            hi: usize,
            keys: &[u128],
            b: &[Aabb],
            out: &mut Vec<Node>,
        ) -> (ChildRef, Aabb) {
            if keys[lo] == keys[hi] {
                let bb = b[lo..=hi].iter().fold(Aabb::EMPTY, |x, y| x.union(*y));
                return (ChildRef::leaf(lo as u32, (hi - lo + 1) as u32), bb);
            }
            let bit = 127 - (keys[lo] ^ keys[hi]).leading_zeros();
            let m = (lo..=hi).find(|&k| (keys[k] >> bit) & 1 == 1).unwrap();
            let at = out.len();
            out.push(Node::EMPTY);
            let (lc, lb) = rec(lo, m - 1, keys, b, out);
            let (rc, rb) = rec(m, hi, keys, b, out);
            out[at] = Node::new(&lb, lc, &rb, rc);
            (ChildRef::inner(at as u32), lb.union(rb))
        }
        let mut nodes = Vec::new();
        let (root, bounds) = rec(0, aabbs.len() - 1, &keys, &boxes, &mut nodes);
        Bvh2::from_root(root, bounds, nodes, order)
    }

    fn configs() -> Vec<HlbvhBuilder> {
        let mut v = Vec::new();
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for (combine_identical, max_leaf_size) in [(true, 8), (true, 1), (true, 3), (false, 8)]
            {
                for grid in [MortonGrid::Box, MortonGrid::Cube] {
                    v.push(HlbvhBuilder {
                        bits,
                        combine_identical,
                        max_leaf_size,
                        grid,
                        ..Default::default()
                    });
                }
            }
            // Large primitives apart: 0.005 of the centroid box names about half of a
            // soup's triangles (edges up to 1 in a cube of 100), 0.5 none.
            for large_prims in [0.005, 0.5] {
                v.push(HlbvhBuilder {
                    bits,
                    large_prims: Some(large_prims),
                    ..Default::default()
                });
            }
        }
        v
    }

    #[test]
    fn a_cube_grid_shares_codes_on_the_short_axes() {
        // A long, thin row of boxes: on the box grid every box has its own code; on the
        // cube grid the short axes have a single cell, so the codes are those of x alone
        // and identical ones fall into shared leaves.
        let prims: Vec<Aabb> = (0..4096)
            .map(|i| {
                let c = Vec3::new(
                    i as f32 * 0.25,
                    (i % 7) as f32 * 0.01,
                    (i % 5) as f32 * 0.01,
                );
                Aabb::new(c, c + Vec3::splat(0.1))
            })
            .collect();
        let boxed = HlbvhBuilder::default().build(&prims).unwrap();
        let cube = HlbvhBuilder {
            grid: MortonGrid::Cube,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        assert_valid("row box", &boxed, &prims, 8);
        assert_valid("row cube", &cube, &prims, 8);
        assert!(
            cube.stats().leaves < boxed.stats().leaves,
            "{:?} {:?}",
            cube.stats(),
            boxed.stats()
        );
        assert_ne!(cube, boxed);
    }

    #[test]
    fn adversarial_inputs_give_valid_trees_equal_to_reference() {
        for cfg in configs() {
            for (name, prims) in adversarial() {
                let t = cfg.build(&prims).unwrap();
                assert_valid(name, &t, &prims, cfg.leaf_limit());
                assert_eq!(t, reference(&prims, &cfg), "{name} {cfg:?}");
                assert!(t.stats().max_depth <= 64 + 32, "{name}");
            }
        }
    }

    #[test]
    fn all_codes_colliding_give_a_balanced_tree_of_full_leaves() {
        let prims = cubes_at(&[0.0; 1000]);
        let cfg = HlbvhBuilder::default();
        let t = cfg.build(&prims).unwrap();
        assert_valid("dups", &t, &prims, 8);
        let s = t.stats();
        // 125 full chunks of 8, joined by the bits of the chunk index: depth ceil(log2 125).
        assert_eq!((s.leaves, s.max_leaf_size, s.max_depth), (125, 8, 7));
        // Small runs are one leaf, as in [P2] §5.4.
        let t = cfg.build(&prims[..5]).unwrap();
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 5));
        assert!(t.nodes[0].children[1].is_empty());
        // The [P1] variant splits them by index bits into single-primitive leaves.
        let p1 = HlbvhBuilder {
            combine_identical: false,
            ..cfg
        };
        let t = p1.build(&prims).unwrap();
        assert_valid("dups p1", &t, &prims, 1);
        assert_eq!(t.stats().leaves, 1000);
        assert_eq!(t.stats().max_depth, 10);
    }

    #[test]
    fn zero_one_two_primitives() {
        let b = HlbvhBuilder::default();
        assert_eq!(b.build(&[]).unwrap(), Bvh2::empty());
        let one = cubes_at(&[1.0]);
        let t = b.build(&one).unwrap();
        assert_valid("one", &t, &one, 1);
        assert_eq!(t.nodes[0].children[0], ChildRef::leaf(0, 1));
        let two = cubes_at(&[10.0, 0.0]);
        let t = b.build(&two).unwrap();
        assert_valid("two", &t, &two, 1);
        assert_eq!(t.prim_indices, vec![1, 0]);
        assert_eq!(t.nodes.len(), 1);
    }

    /// A frame loop: one arena and one output tree through meshes of every size class in
    /// turn (parallel cells and a single stream, empty, one primitive, the adversarial
    /// sets), larger after smaller and smaller after larger, give each time the tree of a
    /// fresh build, bit for bit; a build no larger than an earlier one keeps every buffer.
    #[test]
    fn build_into_reused_buffers_equals_a_fresh_build() {
        let mut meshes: Vec<(&str, Vec<Aabb>)> = vec![
            ("soup 60K", soup(60_000, 2.0, 5)),
            ("empty", Vec::new()),
            ("soup 20K", soup(20_000, 1.0, 11)),
            ("cloth", proc_scene("proc:cloth?n=5000")),
        ];
        meshes.extend(adversarial());
        meshes.push(("soup 40K", soup(40_000, 0.5, 2)));
        let small_first = (2..meshes.len()).chain([0, 1]);
        let order: Vec<usize> = (0..meshes.len()).chain(small_first).collect();
        let mut cfgs = vec![HlbvhBuilder::default()];
        cfgs.extend(configs().into_iter().step_by(3));
        for cfg in cfgs {
            let mut arena = HlbvhArena::default();
            let mut out = Bvh2::empty();
            let mut largest = None;
            for &m in &order {
                let (name, prims) = &meshes[m];
                cfg.build_into(prims, &mut arena, &mut out).unwrap();
                assert_eq!(out, cfg.build(prims).unwrap(), "{name} {cfg:?}");
                let held = (
                    out.nodes.as_ptr(),
                    out.prim_indices.as_ptr(),
                    arena.capacity_bytes(),
                );
                match largest {
                    None => largest = Some(held),
                    // The 60K soup came first: nothing after it needs more room.
                    Some(l) => assert_eq!(held, l, "{name}: a buffer was reallocated"),
                }
            }
            // A bad input leaves the empty tree; the next build is whole again.
            let bad = [Aabb::new(Vec3::ONE, Vec3::ZERO)];
            assert!(cfg.build_into(&bad, &mut arena, &mut out).is_err());
            assert_eq!(out, Bvh2::empty());
            cfg.build_into(&meshes[2].1, &mut arena, &mut out).unwrap();
            assert_eq!(out, cfg.build(&meshes[2].1).unwrap());
        }
    }

    /// The thesis's Fig. 5 pattern on hand-made codes: every step is one stack operation,
    /// nodes come out bottom-up, and equal codes combine into one leaf.
    #[test]
    fn step_machine_emits_bottom_up_one_stack_operation_per_step() {
        // Codes a..f of [P2] Fig. 5 (as 4-bit values): 0001 0010 0100 1001 1001 1100.
        let codes = [1u64, 2, 4, 9, 9, 12];
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let mut em = Emitter::new(None);
        let mut it = codes.iter().map(|&code| Prim {
            code,
            tie: 0,
            aabb: unit,
        });
        let mut steps = Vec::new();
        loop {
            let inp = if em.needs_input() { it.next() } else { None };
            let s = em.step(inp);
            if s == Step::Done {
                break;
            }
            steps.push(s);
        }
        let kinds: Vec<&str> = steps
            .iter()
            .map(|s| match s {
                Step::Loaded => "L",
                Step::Combined => "C",
                Step::Pushed => "P",
                Step::Emitted(_) => "E",
                Step::Highlevel(_) => "H",
                Step::Done => "D",
            })
            .collect();
        // Levels (1-based highest differing bit): a|b 2, b|c 3, c|d 4, e|f 3, end infinite.
        // Load a; b: push (a, 2); c: pop A = (a, b), push (A, 3); d: pop B = (A, c), push
        // (B, 4); e: combine with d; f: push (de, 3); end: pop C = (de, f), pop D = (B, C),
        // D to the high-level output.
        assert_eq!(kinds.concat(), "LPEPEPCPEEH");
        let nodes: Vec<EmittedNode> = steps
            .iter()
            .filter_map(|s| match s {
                Step::Emitted(n) => Some(*n),
                _ => None,
            })
            .collect();
        // A = (a, b); B = (A, c); C = (de, f); D = (B, C): children before parents.
        use EmitRef::*;
        assert_eq!(
            nodes[0].children,
            [Leaf { first: 0, count: 1 }, Leaf { first: 1, count: 1 }]
        );
        assert_eq!(nodes[1].children, [Node(0), Leaf { first: 2, count: 1 }]);
        assert_eq!(
            nodes[2].children,
            [Leaf { first: 3, count: 2 }, Leaf { first: 5, count: 1 }]
        );
        assert_eq!(nodes[3].children, [Node(1), Node(2)]);
        assert!(em.max_stack_depth() <= 2);
    }

    /// \[P2\] §5.4: one primitive per leaf costs exactly one push and one pop per node,
    /// `2m - 2` stack operations for `m` leaves, plus the first load and the final output.
    #[test]
    fn step_count_is_two_per_node() {
        let prims = soup(5000, 1.0, 8);
        let (codes, order) = sorted_codes(&prims, MortonBits::Bits30, MortonGrid::Box);
        let ties = ties(&codes, false, 1);
        let mut em = Emitter::new(None);
        let mut input = codes
            .iter()
            .zip(&ties)
            .zip(&order)
            .map(|((&code, &tie), &i)| Prim {
                code,
                tie,
                aabb: prims[i as usize],
            });
        let (mut steps, mut stack_ops) = (0usize, 0usize);
        loop {
            let inp = if em.needs_input() { input.next() } else { None };
            let s = em.step(inp);
            if s == Step::Done {
                break;
            }
            steps += 1;
            stack_ops += matches!(s, Step::Pushed | Step::Emitted(_)) as usize;
        }
        let m = prims.len();
        assert_eq!(stack_ops, 2 * m - 2);
        assert_eq!(steps, 2 * m);
        assert!(em.max_stack_depth() <= 30 + 32);
    }

    #[test]
    fn emitter_order_is_bottom_up_and_stack_is_bounded() {
        let prims = soup(20_000, 1.0, 5);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let hl = HlbvhBuilder {
                bits,
                ..Default::default()
            }
            .build_highlevel(&prims)
            .unwrap();
            for (i, n) in hl.nodes.iter().enumerate() {
                for c in n.children {
                    if let EmitRef::Node(c) = c {
                        assert!((c as usize) < i, "child {c} after parent {i}");
                    }
                }
            }
            assert_eq!(hl.roots.len(), 1);
        }
    }

    #[test]
    fn threshold_cuts_cells_and_changes_nothing_else() {
        let prims = proc_scene("proc:forest?n=20000");
        let plain = HlbvhBuilder::default().build(&prims).unwrap();
        for t in [0, 10, 18, 27, 29, 30, 40] {
            let cfg = HlbvhBuilder {
                highlevel_threshold: Some(t),
                ..Default::default()
            };
            let hl = cfg.build_highlevel(&prims).unwrap();
            // Every cell's primitives share the code bits above the threshold, and the
            // cells are in Morton order with distinct prefixes.
            let shift = t.min(63);
            for w in hl.roots.windows(2) {
                assert!(w[0].key.0 >> shift < w[1].key.0 >> shift, "threshold {t}");
            }
            if t >= 30 {
                assert_eq!(hl.roots.len(), 1);
            }
            assert_eq!(cfg.build(&prims).unwrap(), plain);
            // The cells joined by their Morton prefixes are the uncut tree.
            assert_eq!(hl.to_bvh2(), plain, "threshold {t}");
        }
    }

    /// Large inputs take the parallel-cells path of `build`; still the reference tree.
    #[test]
    fn large_inputs_equal_reference() {
        let mut forest = proc_scene("proc:forest?n=20000");
        forest.truncate(40_000);
        for prims in [soup(30_000, 1.0, 11), forest, cubes_at(&[3.0; 20_000])] {
            for cfg in configs() {
                let t = cfg.build(&prims).unwrap();
                assert_valid("large", &t, &prims, cfg.leaf_limit());
                assert_eq!(t, reference(&prims, &cfg), "{cfg:?}");
            }
        }
    }

    /// A cell of more primitives than one gather block (a dense cluster in a sparse
    /// scene, as Conference's chairs are: 62% of its triangles in one cell) is gathered in
    /// several blocks, the last one partial; still the reference tree, on 1 and 2 threads.
    #[test]
    fn a_cell_larger_than_a_gather_block_equals_reference() {
        let mut prims = soup(9_000, 1.0, 41);
        prims.extend(
            soup(2 * GATHER_BLOCK + 1_500, 1.0, 43)
                .iter()
                .map(|b| Aabb::new(b.min * 1e-3, b.max * 1e-3)),
        );
        for cfg in configs() {
            let (codes, _) = sorted_codes(&prims, cfg.bits, cfg.grid);
            let shift = cfg.bits.total_bits() - PARALLEL_CELL_BITS;
            let biggest = codes
                .chunk_by(|a, b| a >> shift == b >> shift)
                .map(<[u64]>::len)
                .max();
            assert!(biggest > Some(2 * GATHER_BLOCK), "{biggest:?} {cfg:?}");
            for threads in [1, 2] {
                let cfg = HlbvhBuilder {
                    threads,
                    ..cfg.clone()
                };
                let t = cfg.build(&prims).unwrap();
                assert_valid("cluster", &t, &prims, cfg.leaf_limit());
                assert_eq!(t, reference(&prims, &cfg), "{cfg:?}");
            }
        }
    }

    /// The direct layout with cells of every shape: single-leaf cells (isolated boxes, and
    /// a few identical ones combined into one leaf) among ordinary ones, 1 to 3 threads.
    #[test]
    fn direct_layout_handles_leaf_cells_and_equals_the_emitter_path() {
        let mut prims = soup(20_000, 1.0, 17);
        for k in 0..6 {
            let c = Vec3::splat(1.0e4 * (k as f32 + 1.0));
            prims.push(Aabb::new(c, c + 0.5));
        }
        let far = Vec3::new(-3.0e4, 2.0e4, -1.0e4);
        prims.extend(std::iter::repeat_n(Aabb::new(far, far + 0.5), 5));
        for cfg in configs() {
            let hl = HlbvhBuilder {
                highlevel_threshold: Some(cfg.bits.total_bits() - PARALLEL_CELL_BITS),
                ..cfg.clone()
            }
            .build_highlevel(&prims)
            .unwrap();
            assert!(hl
                .roots
                .iter()
                .any(|r| matches!(r.root, EmitRef::Leaf { .. })));
            let want = hl.to_bvh2();
            assert_eq!(want, reference(&prims, &cfg), "{cfg:?}");
            for threads in [1, 2, 3] {
                let t = HlbvhBuilder {
                    threads,
                    ..cfg.clone()
                }
                .build(&prims)
                .unwrap();
                assert_eq!(t, want, "{cfg:?} threads {threads}");
            }
        }
    }

    #[test]
    fn parallel_cells_equal_one_emitter() {
        let prims = soup(40_000, 1.0, 2);
        for t in [0, 12, 21, 29] {
            let cfg = HlbvhBuilder {
                highlevel_threshold: Some(t),
                ..Default::default()
            };
            let serial = HlbvhBuilder {
                threads: 1,
                ..cfg.clone()
            };
            let one = serial.emit_range(0, &[], &[], &[], &mut []);
            assert!(one.0 == 0 && one.1.is_empty());
            // One emitter over the whole stream, by hand.
            let (codes, order) = sorted_codes(&prims, cfg.bits, cfg.grid);
            let boxes: Vec<Aabb> = order.iter().map(|&i| prims[i as usize]).collect();
            let ties = ties(&codes, true, 8);
            let mut nodes = vec![PLACEHOLDER; prims.len() - 1];
            let (count, roots) = cfg.emit_range(0, &codes, &ties, &boxes, &mut nodes);
            nodes.truncate(count as usize);
            let whole = Highlevel {
                nodes,
                roots,
                order,
            };
            for threads in [1, 2, 3] {
                let hl = HlbvhBuilder {
                    threads,
                    ..cfg.clone()
                }
                .build_highlevel(&prims)
                .unwrap();
                assert_eq!(hl, whole, "threshold {t} threads {threads}");
            }
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let prims = soup(30_000, 1.0, 29);
        for cfg in configs() {
            let t1 = HlbvhBuilder {
                threads: 1,
                ..cfg.clone()
            }
            .build(&prims)
            .unwrap();
            assert_valid("soup", &t1, &prims, cfg.leaf_limit());
            assert_eq!(
                t1,
                HlbvhBuilder {
                    threads: 2,
                    ..cfg.clone()
                }
                .build(&prims)
                .unwrap()
            );
        }
    }

    #[test]
    fn quality_is_sane_against_sweep() {
        let prims = proc_scene("proc:cloth?n=5000");
        let t = HlbvhBuilder::default().build(&prims).unwrap();
        assert_valid("cloth", &t, &prims, 8);
        let sweep = SweepSahBuilder::default().build(&prims).unwrap();
        let r = t.sah_vs(&sweep);
        assert!(r > 1.0 && r < 2.5, "HLBVH SAH {r} x sweep");
    }

    #[test]
    fn bad_input_and_config_are_errors() {
        let prims = [Aabb::new(Vec3::ZERO, Vec3::splat(f32::NAN))];
        assert_eq!(
            HlbvhBuilder::default().build(&prims),
            Err(BuildError::NonFinite { index: 0 })
        );
        let cfg = HlbvhBuilder {
            max_leaf_size: 0,
            ..Default::default()
        };
        assert!(matches!(
            cfg.build(&cubes_at(&[0.0])),
            Err(BuildError::InvalidConfig(_))
        ));
        for f in [0.0, -0.5, f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let cfg = HlbvhBuilder {
                large_prims: Some(f),
                ..Default::default()
            };
            let prims = soup(100, 1.0, 1);
            let e = cfg.build(&prims);
            assert!(
                matches!(&e, Err(BuildError::InvalidConfig(m)) if m.contains("large_prims")),
                "{f}: {e:?}"
            );
            assert!(matches!(
                cfg.build_highlevel(&prims),
                Err(BuildError::InvalidConfig(_))
            ));
            let mut out = HlbvhBuilder::default().build(&prims).unwrap();
            assert!(cfg
                .build_into(&prims, &mut HlbvhArena::default(), &mut out)
                .is_err());
            assert_eq!(out, Bvh2::empty(), "{f}");
        }
    }

    /// A scene like Crytek Sponza's nave (issue 34): a field of small triangles and long
    /// strips along x whose centroids lie just either side of the middle of the centroid
    /// box. The Morton split at the middle sends strips into both halves, so both children
    /// of the root span the whole scene; with the strips apart they form one subtree
    /// under the root and the rest of the tree is tight.
    fn field_with_strips() -> (Vec<Aabb>, usize) {
        let mut prims = soup(20_000, 1.0, 5);
        let mut strips = 0;
        for k in 0..64 {
            let x = 50.0 + (k as f32 - 31.5) * 0.01; // centroids straddle x = 50
            let (y, z) = ((k % 8) as f32 * 12.0 + 4.0, (k / 8) as f32 * 12.0 + 4.0);
            prims.push(Aabb::new(
                Vec3::new(x - 45.0, y, z),
                Vec3::new(x + 45.0, y + 0.1, z),
            ));
            strips += 1;
        }
        (prims, strips)
    }

    #[test]
    fn large_prims_apart_form_one_subtree_under_the_root() {
        let (prims, strips) = field_with_strips();
        let plain = HlbvhBuilder::default().build(&prims).unwrap();
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for threads in [1, 2] {
                let cfg = HlbvhBuilder {
                    bits,
                    threads,
                    large_prims: Some(0.5),
                    ..Default::default()
                };
                let t = cfg.build(&prims).unwrap();
                assert_valid("strips", &t, &prims, 8);
                assert_eq!(t, reference(&prims, &cfg), "{cfg:?}");
                // The strips, and only they, are the last leaf-table entries, under the
                // root's second child.
                let n = prims.len();
                let mut tail: Vec<u32> = t.prim_indices[n - strips..].to_vec();
                tail.sort_unstable();
                let want: Vec<u32> = (n - strips..n).map(|i| i as u32).collect();
                assert_eq!(tail, want);
                // Measured: 1.229x -> 1.004x the sweep tree's SAH (30 and 63 bits).
                let sweep = SweepSahBuilder::default().build(&prims).unwrap();
                assert!(
                    t.sah_vs(&sweep) < 0.9 * plain.sah_vs(&sweep),
                    "{:?}: {} against {}",
                    bits,
                    t.sah_vs(&sweep),
                    plain.sah_vs(&sweep)
                );
                // The one-stream emission of build_highlevel gives the same tree.
                assert_eq!(cfg.build_highlevel(&prims).unwrap().to_bvh2(), t);
            }
        }
    }

    #[test]
    fn large_prims_apart_change_nothing_without_large_primitives() {
        // No triangle of these spans half of its scene's centroid box on any axis.
        for prims in [
            soup(30_000, 1.0, 3),
            proc_scene("proc:cloth?n=5000"),
            cubes_at(&[3.0; 100]),
        ] {
            let plain = HlbvhBuilder::default().build(&prims).unwrap();
            let apart = HlbvhBuilder {
                large_prims: Some(0.5),
                ..Default::default()
            }
            .build(&prims)
            .unwrap();
            assert_eq!(apart, plain);
        }
    }

    #[test]
    fn real_scenes_give_valid_trees() {
        let Some(scenes) = real_scenes() else {
            return;
        };
        // Through one arena and output tree, as a renderer's frame loop, in both orders:
        // the tree of a fresh build every time.
        let (mut arena, mut out) = (HlbvhArena::default(), Bvh2::empty());
        for (name, prims) in scenes.iter().chain(scenes.iter().rev()) {
            let t = HlbvhBuilder::default().build(prims).unwrap();
            assert_valid(name, &t, prims, 8);
            HlbvhBuilder::default()
                .build_into(prims, &mut arena, &mut out)
                .unwrap();
            assert!(out == t, "{name}: the reused buffers changed the tree");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// THE key test: the streaming tree equals the recursive reference, node for node.
        #[test]
        fn streaming_tree_equals_recursive_reference(
            n in 0usize..1500,
            size in 0.0f32..20.0,
            seed: u64,
            wide: bool,
            combine: bool,
            max_leaf in 1u32..6,
            grid in 0u32..4,
            large in 0u32..3,
        ) {
            let mut prims = soup(n, size, seed);
            if grid > 0 {
                // Snap boxes to a coarse lattice so that many codes collide.
                let s = grid as f32 * 10.0;
                for b in &mut prims {
                    let c = ((centroid(b) / s).floor()) * s;
                    *b = Aabb::new(c, c + Vec3::splat(grid as f32));
                }
            }
            let cfg = HlbvhBuilder {
                bits: if wide { MortonBits::Bits63 } else { MortonBits::Bits30 },
                combine_identical: combine,
                max_leaf_size: max_leaf,
                // Triangles of edge up to 20 in a cube of 100: 0.1 names some of them.
                large_prims: [None, Some(0.1), Some(0.5)][large as usize],
                ..Default::default()
            };
            let t = cfg.build(&prims).unwrap();
            prop_assert_eq!(validate(&t, &prims, cfg.leaf_limit()), Ok(()));
            prop_assert_eq!(&t, &reference(&prims, &cfg));
        }
    }
}
