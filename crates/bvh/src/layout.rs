//! The depth-first preorder layout that every tree writer of the crate shares.
//!
//! All node arrays of the crate ([`Bvh2`](crate::Bvh2), [`Mbvh4`](crate::Mbvh4),
//! [`WideBvh`](crate::WideBvh)) are stored in depth-first preorder, slot 0 first. Writers
//! whose source is another tree (parallel build fragments, the HLBVH top tree over its
//! cells, the ATRBVH and reinsertion working trees, the collapses to wide nodes) all lay it
//! out with [`try_preorder`]: an explicit stack of sources still to place, each with the
//! (parent, slot) whose child reference becomes its position once it is written. The
//! writers differ only in how one source becomes one node, which they pass in.
//!
//! Writers that know the size of every subtree before writing it (a binary tree whose
//! subtree of `k` leaves has `k - 1` nodes: PLOC's clustered tree, the ATRBVH working tree)
//! use [`preorder_sized`] instead: each subtree owns a known range of the output (and of
//! a leaf table laid out in the same order), so child 1's position is known without
//! writing child 0's subtree first and large subtrees are written in parallel, into
//! disjoint slices, with no stack of pending patches.

use crate::collapse::WideNode;
use crate::mbvh4::Node4;
use crate::node::{ChildRef, Node};
use crate::PARALLEL_MIN_PRIMS;
use std::convert::Infallible;

/// A node type with child references that the layout patches.
pub(crate) trait Slots {
    /// The node's child references, by slot.
    fn slots_mut(&mut self) -> &mut [ChildRef];
}

impl Slots for Node {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

impl Slots for Node4 {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

impl<const W: usize> Slots for WideNode<W> {
    #[inline(always)]
    fn slots_mut(&mut self) -> &mut [ChildRef] {
        &mut self.children
    }
}

/// Appends the tree below source `root` to `out` in depth-first preorder (slot 0 first).
///
/// `visit(s, out, kids)` appends the node of source `s` at position `out.len()` (it may
/// append more after it: a block it lays out itself) and pushes onto `kids`, in increasing
/// slot order, `(slot, source)` for each child still to lay out below that node; leaf and
/// empty children are final in the node it wrote. Each such child is laid out right after
/// the subtree of the slot before it, and the node's reference in that slot is set to the
/// child's position. The first error of `visit` stops the layout and is returned.
pub(crate) fn try_preorder<N: Slots, S, E>(
    root: S,
    out: &mut Vec<N>,
    mut visit: impl FnMut(S, &mut Vec<N>, &mut Vec<(usize, S)>) -> Result<(), E>,
) -> Result<(), E> {
    let mut stack: Vec<(S, Option<(usize, usize)>)> = vec![(root, None)];
    let mut kids: Vec<(usize, S)> = Vec::new();
    while let Some((s, patch)) = stack.pop() {
        let at = out.len();
        if let Some((p, slot)) = patch {
            out[p].slots_mut()[slot] = ChildRef::inner(at as u32);
        }
        visit(s, out, &mut kids)?;
        debug_assert!(out.len() > at, "visit must write the node");
        stack.extend(kids.drain(..).rev().map(|(slot, c)| (c, Some((at, slot)))));
    }
    Ok(())
}

/// [`try_preorder`] for a `visit` that cannot fail.
pub(crate) fn preorder<N: Slots, S>(
    root: S,
    out: &mut Vec<N>,
    mut visit: impl FnMut(S, &mut Vec<N>, &mut Vec<(usize, S)>),
) {
    let r: Result<(), Infallible> = try_preorder(root, out, |s, o, k| {
        visit(s, o, k);
        Ok(())
    });
    let Ok(()) = r;
}

/// Recursion depth after which [`preorder_sized`] stops forking and continues with an
/// explicit stack (an adversarial tree may be as deep as it has leaves).
const MAX_FORK_DEPTH: u32 = 48;

/// An inner child that [`Kids::inner`] placed: its source, node position and leaf offset
/// (absolute), and its size in nodes and leaf-table entries.
#[derive(Clone, Copy)]
struct Placed<S> {
    source: S,
    at: u32,
    leaf: u32,
    nodes: u32,
    leaves: u32,
}

/// The children of the node that [`preorder_sized`]'s `visit` is writing, placed in slot
/// order: each call hands out the next free position (inner children) or the next leaf
/// table entries (leaf children), right after the previous slot's subtree.
pub(crate) struct Kids<'a, S, A> {
    /// Position of the next inner child (absolute).
    next: u32,
    /// Next free leaf-table entry (absolute).
    leaf: u32,
    /// The leaf table of the subtree being written, whose first entry is entry `aux_base`.
    aux: &'a mut [A],
    aux_base: u32,
    /// The inner children placed so far (binary trees: two at most).
    inner: [Option<Placed<S>>; 2],
}

impl<S: Copy, A> Kids<'_, S, A> {
    /// Places the next child as an inner node: source `source` whose subtree has `nodes`
    /// nodes and `leaves` leaf-table entries. Returns the child's node position, the
    /// reference to write into the parent's slot.
    #[inline(always)]
    pub(crate) fn inner(&mut self, source: S, nodes: u32, leaves: u32) -> u32 {
        debug_assert!(nodes > 0, "an inner child is at least its own node");
        let placed = Placed {
            source,
            at: self.next,
            leaf: self.leaf,
            nodes,
            leaves,
        };
        let free = self.inner.iter_mut().find(|k| k.is_none());
        *free.expect("binary trees: at most two inner children") = Some(placed);
        self.next += nodes;
        self.leaf += leaves;
        placed.at
    }

    /// Places the next child as a leaf of `count` leaf-table entries. Returns the index of
    /// its first entry and the entries themselves, for the caller to fill.
    #[inline(always)]
    pub(crate) fn leaf(&mut self, count: u32) -> (u32, &mut [A]) {
        let first = self.leaf;
        self.leaf += count;
        let k = (first - self.aux_base) as usize;
        (first, &mut self.aux[k..k + count as usize])
    }
}

/// How [`preorder_sized`] writes one node: source `s`'s node, its children placed through
/// `kids`. Every closure `|s, kids| node` is one. A writer whose node is too large for the
/// compiler to inline a closure into the layout loop implements it itself with
/// `#[inline(always)]` (PLOC's: the closure's call per node made its write-out 1.6x slower
/// than its former own loop, issue 34).
pub(crate) trait SizedVisit<S, A, N>: Sync {
    /// The node of source `s`.
    fn node(&self, s: S, kids: &mut Kids<'_, S, A>) -> N;
}

impl<S, A, N, F: Fn(S, &mut Kids<'_, S, A>) -> N + Sync> SizedVisit<S, A, N> for F {
    #[inline(always)]
    fn node(&self, s: S, kids: &mut Kids<'_, S, A>) -> N {
        self(s, kids)
    }
}

/// Writes the binary tree below source `root` in depth-first preorder (slot 0 first) into
/// `out`, its nodes, and `aux`, its leaf table, when the size of every subtree is known.
///
/// `out` holds exactly the tree's nodes and `aux` exactly its leaf-table entries (empty for
/// a writer without one). `visit` (a closure `|s, kids|`, or a [`SizedVisit`]) returns the node of source `s`, placing its
/// children in slot order through `kids`: [`Kids::inner`] for a child whose subtree is
/// written below it (given its node and entry counts; returns its position),
/// [`Kids::leaf`] for a leaf (returns its first entry, to fill). Child 0's subtree follows
/// its parent; each later child follows the subtree of the slot before it; leaf entries
/// follow the same order. Subtrees of [`PARALLEL_MIN_PRIMS`] nodes or more are written in
/// parallel (`rayon::join` on disjoint slices) when the pool has more than one thread;
/// the result does not depend on the thread count.
pub(crate) fn preorder_sized<N, A, S, V>(root: S, out: &mut [N], aux: &mut [A], visit: &V)
where
    N: Send,
    A: Send,
    S: Copy + Send,
    V: SizedVisit<S, A, N>,
{
    if out.is_empty() {
        return;
    }
    let root = Placed {
        source: root,
        at: 0,
        leaf: 0,
        nodes: out.len() as u32,
        leaves: aux.len() as u32,
    };
    let fork = rayon::current_num_threads() > 1;
    sized_subtree(root, out, aux, visit, if fork { 0 } else { MAX_FORK_DEPTH });
}

/// [`preorder_sized`] of the subtree `p`, which is exactly `out` and `aux`; forks while
/// the subtree is large and `depth` is below [`MAX_FORK_DEPTH`].
fn sized_subtree<N, A, S, V>(p: Placed<S>, out: &mut [N], aux: &mut [A], visit: &V, depth: u32)
where
    N: Send,
    A: Send,
    S: Copy + Send,
    V: SizedVisit<S, A, N>,
{
    debug_assert_eq!(
        (out.len(), aux.len()),
        (p.nodes as usize, p.leaves as usize)
    );
    if depth >= MAX_FORK_DEPTH || (p.nodes as usize) < PARALLEL_MIN_PRIMS {
        return sized_stack(p, out, aux, visit);
    }
    let mut kids = Kids {
        next: p.at + 1,
        leaf: p.leaf,
        aux: &mut *aux,
        aux_base: p.leaf,
        inner: [None, None],
    };
    out[0] = visit.node(p.source, &mut kids);
    debug_assert_eq!(
        kids.next,
        p.at + p.nodes,
        "the children must fill the subtree"
    );
    let inner = kids.inner;
    // The children's nodes follow the parent's back to back; leaf entries that `visit`
    // filled may lie between their leaf-table ranges.
    let rest = &mut out[1..];
    let go = |c: Placed<S>, o: &mut [N], a: &mut [A]| {
        let o = &mut o[..c.nodes as usize];
        let a = &mut a[..c.leaves as usize];
        sized_subtree(c, o, a, visit, depth + 1);
    };
    let offsets = |c: &Placed<S>| ((c.at - p.at - 1) as usize, (c.leaf - p.leaf) as usize);
    match inner {
        [Some(a), Some(b)] => {
            let (oa, la) = offsets(&a);
            let (ob, lb) = offsets(&b);
            let (ra, rb) = rest.split_at_mut(ob);
            let (aa, ab) = aux.split_at_mut(lb);
            rayon::join(
                move || go(a, &mut ra[oa..], &mut aa[la..]),
                move || go(b, rb, ab),
            );
        }
        [Some(c), None] | [None, Some(c)] => {
            let (o, l) = offsets(&c);
            go(c, &mut rest[o..], &mut aux[l..]);
        }
        [None, None] => {}
    }
}

/// [`preorder_sized`] of the subtree `p` (exactly `out` and `aux`) on one thread, with an
/// explicit stack of children still to write.
fn sized_stack<N, A, S, V>(p: Placed<S>, out: &mut [N], aux: &mut [A], visit: &V)
where
    S: Copy,
    V: SizedVisit<S, A, N>,
{
    let (node_base, leaf_base) = (p.at, p.leaf);
    let mut stack: Vec<Placed<S>> = vec![p];
    while let Some(p) = stack.pop() {
        let mut kids = Kids {
            next: p.at + 1,
            leaf: p.leaf,
            aux: &mut *aux,
            aux_base: leaf_base,
            inner: [None, None],
        };
        let node = visit.node(p.source, &mut kids);
        debug_assert_eq!(
            kids.next,
            p.at + p.nodes,
            "the children must fill the subtree"
        );
        out[(p.at - node_base) as usize] = node;
        // Slot 0 on top: its subtree is written first (the order does not change the
        // result, every position being known; it keeps writes sequential).
        let [a, b] = kids.inner;
        stack.extend(b);
        stack.extend(a);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{Aabb, Vec3};

    /// A source tree given as child lists (`None`: a leaf of that id) is laid out in
    /// preorder: positions, patched references and the order of visits.
    #[test]
    fn lays_out_in_preorder_and_patches_children() {
        // 0 -> (1, leaf 7), 1 -> (2, 3), 2 -> (leaf 8, leaf 9), 3 -> (leaf 5, 4), 4 -> leaves.
        let kids: [[Option<u32>; 2]; 5] = [
            [Some(1), None],
            [Some(2), Some(3)],
            [None, None],
            [None, Some(4)],
            [None, None],
        ];
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let mut visited = Vec::new();
        let mut out: Vec<Node> = Vec::new();
        preorder(0u32, &mut out, |s, out, k| {
            visited.push(s);
            let mut refs = [ChildRef::leaf(s, 1); 2];
            for (slot, c) in kids[s as usize].iter().enumerate() {
                if let Some(c) = *c {
                    refs[slot] = ChildRef::EMPTY;
                    k.push((slot, c));
                }
            }
            out.push(Node::new(&b, refs[0], &b, refs[1]));
        });
        assert_eq!(visited, [0, 1, 2, 3, 4]);
        assert_eq!(out[0].children[0], ChildRef::inner(1));
        assert_eq!(out[1].children, [ChildRef::inner(2), ChildRef::inner(3)]);
        assert_eq!(out[3].children[1], ChildRef::inner(4));
        assert_eq!(out[3].children[0], ChildRef::leaf(3, 1));
        assert_eq!(out.len(), 5);
        assert_eq!(out[4].children, [ChildRef::leaf(4, 1); 2]);
    }

    /// The first error stops the layout.
    #[test]
    fn an_error_stops_the_layout() {
        let mut out: Vec<Node> = Vec::new();
        let mut n = 0;
        let r = try_preorder(0u32, &mut out, |s, out, k| {
            n += 1;
            if s == 2 {
                return Err(s);
            }
            out.push(Node::EMPTY);
            k.push((0, s + 1));
            Ok(())
        });
        assert_eq!((r, n, out.len()), (Err(2), 3, 2));
    }

    /// A random binary tree over `n` leaves, as PLOC writes one: leaf ids `0..n`, inner
    /// node `k` has id `n + k` and children made before it; the last inner node is the
    /// root. `chain` makes it a degenerate chain (deeper than the fork depth).
    fn random_tree(n: usize, seed: u64, chain: bool) -> (Vec<[u32; 2]>, Vec<u32>) {
        let mut state = seed | 1;
        let mut rnd = move |m: usize| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % m as u64) as usize
        };
        let mut open: Vec<u32> = (0..n as u32).collect();
        let mut children = Vec::new();
        while open.len() > 1 {
            let (i, j) = if chain {
                (open.len() - 2, open.len() - 1)
            } else {
                let i = rnd(open.len());
                let j = (i + 1 + rnd(open.len() - 1)) % open.len();
                (i, j)
            };
            let pair = [open[i], open[j]];
            let id = (n + children.len()) as u32;
            children.push(if rnd(2) == 0 {
                pair
            } else {
                [pair[1], pair[0]]
            });
            open.swap_remove(i.max(j));
            open.swap_remove(i.min(j));
            open.push(id);
        }
        let leaves = crate::ploc::leaf_counts(&children, n);
        (children, leaves)
    }

    /// A box that names node or leaf id `id`.
    fn named(id: u32) -> Aabb {
        let v = Vec3::splat(id as f32);
        Aabb::new(v, v + Vec3::ONE)
    }

    /// Depth-first preorder by definition: inner node `k` of a [`random_tree`] over `n`
    /// leaves, then each slot in turn (its subtree, or its leaf's table entry).
    fn reference(ch: &[[u32; 2]], n: usize, k: usize, out: &mut Vec<Node>, prims: &mut Vec<u32>) {
        let at = out.len();
        out.push(Node::EMPTY);
        let mut refs = [ChildRef::EMPTY; 2];
        for (s, &c) in ch[k].iter().enumerate() {
            refs[s] = if (c as usize) < n {
                prims.push(c * 7);
                ChildRef::leaf(prims.len() as u32 - 1, 1)
            } else {
                ChildRef::inner(out.len() as u32)
            };
            if (c as usize) >= n {
                reference(ch, n, c as usize - n, out, prims);
            }
        }
        let [b0, b1] = ch[k].map(named);
        out[at] = Node::new(&b0, refs[0], &b1, refs[1]);
    }

    /// [`preorder_sized`] writes the depth-first preorder of nodes and leaf table (the
    /// plain recursion's), on one thread and on two, for trees large enough to fork, small
    /// ones and a chain deeper than the fork depth.
    #[test]
    fn sized_layout_equals_the_stack_layout() {
        for (n, seed, chain) in [
            (2, 1, false),
            (3, 2, false),
            (100, 3, false),
            (20_000, 4, false),
            (50_000, 5, false),
            (9_000, 6, true),
        ] {
            let (children, leaves) = random_tree(n, seed, chain);
            let root = children.len() - 1;
            // The reference: the plain recursion (node, then each slot's subtree or leaf in
            // turn), on a thread with room for the chain's depth.
            let (want, want_prims) = std::thread::scope(|sc| {
                std::thread::Builder::new()
                    .stack_size(256 << 20)
                    .spawn_scoped(sc, || {
                        let (mut nodes, mut prims) = (Vec::new(), Vec::new());
                        reference(&children, n, root, &mut nodes, &mut prims);
                        (nodes, prims)
                    })
                    .unwrap()
                    .join()
                    .unwrap()
            });
            let visit = |k: usize, kids: &mut Kids<'_, usize, u32>| {
                let mut refs = [ChildRef::EMPTY; 2];
                let mut boxes = [Aabb::EMPTY; 2];
                for (s, &c) in children[k].iter().enumerate() {
                    boxes[s] = named(c);
                    if (c as usize) < n {
                        let (first, e) = kids.leaf(1);
                        e[0] = c * 7;
                        refs[s] = ChildRef::leaf(first, 1);
                    } else {
                        let m = leaves[c as usize - n];
                        refs[s] = ChildRef::inner(kids.inner(c as usize - n, m - 1, m));
                    }
                }
                Node::new(&boxes[0], refs[0], &boxes[1], refs[1])
            };
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut got = vec![Node::EMPTY; n - 1];
                let mut prims = vec![u32::MAX; n];
                pool.install(|| preorder_sized(root, &mut got, &mut prims, &visit));
                assert!(got == want, "nodes differ: {n} leaves, {threads} threads");
                assert_eq!(prims, want_prims, "{n} leaves, {threads} threads");
            }
        }
    }
}
