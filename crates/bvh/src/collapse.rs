//! SAH-guided collapse of a binary [`Bvh2`] into a 4-wide [`Mbvh4`] (Wald, Benthin and
//! Boulos 2008; thesis §4.2), or into a tree of any width `W` ([`Collapse::collapse_wide`]).
//!
//! Each wide node starts from the two children of a binary node and greedily pulls up the
//! inner child with the largest surface area, replacing it by its own two children, until
//! the node has `W` children or only leaves are left. Pulling up the largest child removes
//! the node that rays reach most often (the SAH weighs a node by its area), so this is the
//! greedy step of minimising the SAH's inner-node term. The remaining inner children become
//! 4-wide nodes in turn. Leaves stay the binary tree's leaves, in the same order.
//!
//! Optional leaf merging ([`Collapse::merge_leaves_up_to`]): a whole binary subtree of at
//! most that many primitives becomes one leaf when its SAH cost as a leaf is not higher
//! than its cost as a subtree (wide leaves suit SIMD primitive tests, \[WBB08\]).
//!
//! The input tree is not trusted: links are bounds-checked and each binary node may be
//! reached only once, so a corrupt tree gives a [`CollapseError`], never a panic.

use crate::bvh2::Bvh2;
use crate::layout::try_preorder;
use crate::mbvh4::{Mbvh4, Node4, MBVH_WIDTH};
use crate::node::{ChildRef, TreeNode};
use crate::sah::SahParams;
use geom::Aabb;
use thiserror::Error;

/// Why a binary tree could not be collapsed.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum CollapseError {
    /// The node array is empty.
    #[error("the binary tree has no root node")]
    NoRoot,
    /// An inner child index is out of range or not after its parent (nodes must be
    /// depth-first).
    #[error("node {node} child {slot} points to node {target}: out of range or not depth-first")]
    BadLink {
        /// Parent node.
        node: usize,
        /// Child slot.
        slot: usize,
        /// Bad target.
        target: u32,
    },
    /// A node is reached twice (shared subtree).
    #[error("node {node} is reached twice")]
    SharedNode {
        /// The node reached again.
        node: usize,
    },
    /// A leaf range runs past the leaf table.
    #[error("node {node} child {slot} leaf range runs past the leaf table")]
    BadLeaf {
        /// Node index.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// Streaming collapse ([`crate::StreamCollapse`]): an emitted node's inner child is not
    /// the last open subtree (the stream is not in emission order), or a node follows the
    /// end of the stream.
    #[error("emitted node {node} child {slot} is not the last open subtree: the stream is not in emission order")]
    StreamOrder {
        /// Emission index of the node.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// Streaming collapse: an emitted leaf of no primitives.
    #[error("emitted node {node} child {slot} is a leaf of no primitives")]
    EmptyLeaf {
        /// Emission index of the node.
        node: usize,
        /// Child slot.
        slot: usize,
    },
    /// Streaming collapse: the stream ended elsewhere than at its one open subtree (or has
    /// not ended).
    #[error("the stream ended (or was read) with {open} open subtrees besides its root")]
    StreamEnd {
        /// Open subtrees held.
        open: usize,
    },
    /// Streaming collapse: the emitter cut the tree into several roots (a high-level
    /// threshold); the collapse needs one tree.
    #[error(
        "{roots} high-level roots: the streaming collapse needs one tree (no high-level threshold)"
    )]
    ManyRoots {
        /// Number of roots.
        roots: usize,
    },
}

/// Configuration of the collapse.
#[derive(Clone, Debug, PartialEq)]
pub struct Collapse {
    /// Binary subtrees of at most this many primitives may become one leaf (0 = keep the
    /// binary tree's leaves unchanged).
    pub merge_leaves_up_to: u32,
    /// SAH weights used by the merge decision.
    pub sah: SahParams,
}

impl Default for Collapse {
    fn default() -> Self {
        Self {
            merge_leaves_up_to: 0,
            sah: SahParams::THESIS,
        }
    }
}

/// A child of a wide node under construction: its box and the binary child reference.
type Kid = (Aabb, ChildRef);

/// A node of a `W`-wide tree made by [`Collapse::collapse_wide`]: its children's boxes and
/// references (unused slots hold [`Aabb::EMPTY`] and [`ChildRef::EMPTY`], after the used
/// ones). Leaves are ranges of the tree's leaf table, as in [`Mbvh4`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WideNode<const W: usize> {
    /// Child boxes.
    pub boxes: [Aabb; W],
    /// Child references.
    pub children: [ChildRef; W],
}

impl<const W: usize> TreeNode for WideNode<W> {
    const WIDTH: usize = W;
    #[inline(always)]
    fn child_refs(&self) -> &[ChildRef] {
        &self.children
    }
    #[inline(always)]
    fn slot_aabb(&self, slot: usize) -> Aabb {
        self.boxes[slot]
    }
    #[inline(always)]
    fn set_slot_aabb(&mut self, slot: usize, b: &Aabb) {
        self.boxes[slot] = *b;
    }
    #[inline(always)]
    fn own_box(&self) -> Aabb {
        self.boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b))
    }
}

/// A `W`-wide tree: nodes in depth-first preorder (slot 0 first; every inner child after
/// its parent), a leaf table, and the scene bounds. [`crate::validate_wide`] checks all of
/// its invariants.
#[derive(Clone, Debug, PartialEq)]
pub struct WideBvh<const W: usize> {
    /// Nodes; `nodes[0]` is the root.
    pub nodes: Vec<WideNode<W>>,
    /// Leaf table: primitive indices.
    pub prim_indices: Vec<u32>,
    /// Scene bounds.
    pub bounds: Aabb,
}

impl From<WideBvh<MBVH_WIDTH>> for Mbvh4 {
    /// The same 4-wide tree in [P4]'s node layout ([`Node4`]).
    fn from(w: WideBvh<MBVH_WIDTH>) -> Self {
        let nodes = w
            .nodes
            .iter()
            .map(|n| {
                let mut node = Node4::EMPTY;
                for slot in 0..MBVH_WIDTH {
                    node.set_child_aabb(slot, &n.boxes[slot]);
                }
                node.children = n.children;
                node
            })
            .collect();
        Mbvh4 {
            nodes,
            prim_indices: w.prim_indices,
            bounds: w.bounds,
        }
    }
}

impl Collapse {
    /// Collapses `bvh` into a 4-wide tree with the same primitives and leaf boxes.
    pub fn collapse(&self, bvh: &Bvh2) -> Result<Mbvh4, CollapseError> {
        Ok(self.collapse_wide::<MBVH_WIDTH>(bvh)?.into())
    }

    /// Collapses `bvh` into a `W`-wide tree (`W >= 2`) with the same primitives and leaf
    /// boxes: the 4-wide collapse of [P4] generalized to any branching factor (8-wide
    /// nodes suit 8-lane SIMD).
    pub fn collapse_wide<const W: usize>(&self, bvh: &Bvh2) -> Result<WideBvh<W>, CollapseError> {
        self.collapse_wide_roots(bvh, &mut Vec::new())
    }

    /// The binary node (index into `bvh.nodes`) that roots each node of the 4-wide
    /// [`Collapse::collapse`] of `bvh`, in the wide tree's node order: the binary nodes a
    /// collapse pass writes a wide node for (the others are pulled into their parent's).
    pub fn wide_roots(&self, bvh: &Bvh2) -> Result<Vec<u32>, CollapseError> {
        let mut roots = Vec::new();
        self.collapse_wide_roots::<MBVH_WIDTH>(bvh, &mut roots)?;
        Ok(roots)
    }

    /// [`Collapse::collapse_wide`], also recording each wide node's binary root in `roots`.
    fn collapse_wide_roots<const W: usize>(
        &self,
        bvh: &Bvh2,
        roots: &mut Vec<u32>,
    ) -> Result<WideBvh<W>, CollapseError> {
        const { assert!(W >= 2) };
        let n = bvh.nodes.len();
        if n == 0 {
            return Err(CollapseError::NoRoot);
        }
        check_links(bvh)?;
        let mergeable = self.mergeable(bvh);
        let mut out: Vec<WideNode<W>> = Vec::with_capacity(n / (W / 2) + 1);
        let mut table: Vec<u32> = Vec::with_capacity(bvh.prim_indices.len());
        let mut seen = vec![false; n];
        let mut kids: Vec<Kid> = Vec::with_capacity(W);
        try_preorder(0usize, &mut out, |bi, out, next| {
            roots.push(bi as u32);
            visit(&mut seen, bi)?;
            kids.clear();
            push_children(&mut kids, bvh, bi);
            // Greedy pull-up of the largest inner child that is not merged into a leaf.
            while kids.len() < W {
                let best = kids
                    .iter()
                    .enumerate()
                    .filter(|(_, (_, c))| c.is_inner() && !mergeable[c.index as usize])
                    .max_by(|a, b| a.1 .0.half_area().total_cmp(&b.1 .0.half_area()))
                    .map(|(k, _)| k);
                let Some(k) = best else { break };
                let ci = kids[k].1.index as usize;
                if kids.len() - 1 + child_count(bvh, ci) > W {
                    break;
                }
                visit(&mut seen, ci)?;
                kids.remove(k);
                // Insert the grandchildren where the child was, keeping spatial order.
                let mut g = Vec::with_capacity(2);
                push_children(&mut g, bvh, ci);
                for (j, kid) in g.into_iter().enumerate() {
                    kids.insert(k + j, kid);
                }
            }
            let mut node = WideNode {
                boxes: [Aabb::EMPTY; W],
                children: [ChildRef::EMPTY; W],
            };
            for (slot, &(b, c)) in kids.iter().enumerate() {
                node.boxes[slot] = b;
                node.children[slot] = if c.is_leaf() {
                    let first = table.len() as u32;
                    let (s, e) = (c.index as usize, c.index as usize + c.count as usize);
                    table.extend_from_slice(&bvh.prim_indices[s..e]);
                    ChildRef::leaf(first, c.count)
                } else if mergeable[c.index as usize] {
                    let first = table.len();
                    gather(bvh, c.index as usize, &mut table, &mut seen)?;
                    ChildRef::leaf(first as u32, (table.len() - first) as u32)
                } else {
                    next.push((slot, c.index as usize));
                    ChildRef::EMPTY // patched when the child node is emitted
                };
            }
            out.push(node);
            Ok::<(), CollapseError>(())
        })?;
        Ok(WideBvh {
            nodes: out,
            prim_indices: table,
            bounds: bvh.bounds,
        })
    }

    /// Per binary node: whether its whole subtree becomes one leaf. Computed bottom-up
    /// (children have larger indices, checked by [`check_links`]) from each subtree's
    /// primitive count and unnormalized SAH cost.
    fn mergeable(&self, bvh: &Bvh2) -> Vec<bool> {
        let n = bvh.nodes.len();
        let mut merge = vec![false; n];
        if self.merge_leaves_up_to < 2 {
            return merge;
        }
        let (ci, cl, ct) = (
            self.sah.c_inner as f64,
            self.sah.c_leaf as f64,
            self.sah.c_tri as f64,
        );
        // (primitive count, SAH cost of the node's contents excluding its own C_i term)
        let mut info = vec![(0u64, 0f64); n];
        for i in (0..n).rev() {
            let node = &bvh.nodes[i];
            let (mut cnt, mut cost) = (0u64, 0f64);
            for (slot, c) in node.children.iter().enumerate() {
                let a = node.child_aabb(slot).half_area() as f64;
                if c.is_leaf() {
                    cnt += c.count as u64;
                    cost += a * (cl + ct * c.count as f64);
                } else if c.is_inner() {
                    let (k, sub) = info[c.index as usize];
                    cnt += k;
                    cost += a * ci + sub;
                }
            }
            info[i] = (cnt, cost);
            if i != 0 && cnt <= self.merge_leaves_up_to as u64 {
                let a = node.aabb().half_area() as f64;
                merge[i] = a * (cl + ct * cnt as f64) <= a * ci + cost;
            }
        }
        merge
    }
}

/// Collapses `bvh` with the default configuration (no leaf merging).
pub fn collapse(bvh: &Bvh2) -> Result<Mbvh4, CollapseError> {
    Collapse::default().collapse(bvh)
}

/// Checks that every inner link points after its parent and inside the array, and that
/// every leaf range lies inside the leaf table.
pub(crate) fn check_links(bvh: &Bvh2) -> Result<(), CollapseError> {
    let n = bvh.nodes.len();
    for (i, node) in bvh.nodes.iter().enumerate() {
        for (slot, c) in node.children.iter().enumerate() {
            if c.is_inner() && (c.index as usize <= i || c.index as usize >= n) {
                return Err(CollapseError::BadLink {
                    node: i,
                    slot,
                    target: c.index,
                });
            }
            if c.is_leaf() && c.index as usize + c.count as usize > bvh.prim_indices.len() {
                return Err(CollapseError::BadLeaf { node: i, slot });
            }
        }
    }
    Ok(())
}

/// Marks binary node `i` as consumed; a second visit means a shared subtree.
fn visit(seen: &mut [bool], i: usize) -> Result<(), CollapseError> {
    if std::mem::replace(&mut seen[i], true) {
        return Err(CollapseError::SharedNode { node: i });
    }
    Ok(())
}

/// The non-empty children of binary node `i` with their boxes.
fn push_children(kids: &mut Vec<Kid>, bvh: &Bvh2, i: usize) {
    let node = &bvh.nodes[i];
    for slot in 0..2 {
        if !node.children[slot].is_empty() {
            kids.push((node.child_aabb(slot), node.children[slot]));
        }
    }
}

/// Number of non-empty children of binary node `i`.
fn child_count(bvh: &Bvh2, i: usize) -> usize {
    bvh.nodes[i]
        .children
        .iter()
        .filter(|c| !c.is_empty())
        .count()
}

/// Appends every primitive of binary subtree `i` to `table` (depth-first).
pub(crate) fn gather(
    bvh: &Bvh2,
    i: usize,
    table: &mut Vec<u32>,
    seen: &mut [bool],
) -> Result<(), CollapseError> {
    let mut stack = vec![i];
    while let Some(j) = stack.pop() {
        visit(seen, j)?;
        for c in bvh.nodes[j].children.iter().rev() {
            if c.is_leaf() {
                let s = c.index as usize;
                table.extend_from_slice(&bvh.prim_indices[s..s + c.count as usize]);
            } else if c.is_inner() {
                stack.push(c.index as usize);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mbvh4::validate_mbvh4;
    use crate::node::Node;
    use crate::testutil::{adversarial, proc_scene, soup};
    use crate::{validate, BinnedSahBuilder, LbvhBuilder, SweepSahBuilder};

    fn check(name: &str, bvh: &Bvh2, prims: &[Aabb], max_leaf: u32) -> Mbvh4 {
        validate(bvh, prims, max_leaf).unwrap_or_else(|e| panic!("{name}: input {e}"));
        let m = collapse(bvh).unwrap_or_else(|e| panic!("{name}: {e}"));
        if let Err(e) = validate_mbvh4(&m, prims, max_leaf) {
            panic!("{name}: collapsed tree invalid: {e}");
        }
        assert_eq!(m.bounds, bvh.bounds, "{name}");
        assert_eq!(m.stats().leaves, bvh.stats().leaves, "{name}: leaves kept");
        m
    }

    #[test]
    fn adversarial_inputs_collapse_validly() {
        for (name, prims) in adversarial() {
            let b = BinnedSahBuilder::default().build(&prims).unwrap();
            check(name, &b, &prims, 8);
            let l = LbvhBuilder::default().build(&prims).unwrap();
            check(name, &l, &prims, 1);
        }
        let e = collapse(&Bvh2::empty()).unwrap();
        assert_eq!(validate_mbvh4(&e, &[], 1), Ok(()));
        assert_eq!(e.nodes.len(), 1);
    }

    #[test]
    fn node_count_drops_to_a_half_or_third_and_sah_improves() {
        let prims = proc_scene("proc:soup?n=20000");
        for (name, bvh, max) in [
            (
                "binned",
                BinnedSahBuilder::default().build(&prims).unwrap(),
                8,
            ),
            ("lbvh", LbvhBuilder::default().build(&prims).unwrap(), 1),
        ] {
            let m = check(name, &bvh, &prims, max);
            let ratio = m.nodes.len() as f64 / bvh.nodes.len() as f64;
            assert!((0.3..=0.55).contains(&ratio), "{name}: node ratio {ratio}");
            assert!(m.stats().mean_children > 3.0, "{name}: {:?}", m.stats());
            // Same leaves, fewer inner nodes: the SAH can only go down, by a good margin.
            let (s2, s4) = (bvh.sah(), m.sah());
            assert!(s4 < s2 && s4 > 0.5 * s2, "{name}: SAH {s2} -> {s4}");
        }
    }

    #[test]
    fn leaf_merging_makes_wider_leaves_within_the_bound() {
        let prims = soup(5000, 2.0, 9);
        let bvh = LbvhBuilder::default().build(&prims).unwrap();
        let m = Collapse {
            merge_leaves_up_to: 4,
            ..Default::default()
        }
        .collapse(&bvh)
        .unwrap();
        assert_eq!(validate_mbvh4(&m, &prims, 4), Ok(()));
        assert!(m.stats().max_leaf_size > 1);
        assert!(m.stats().leaves < bvh.stats().leaves);
        let (merged, plain) = (m.sah(), collapse(&bvh).unwrap().sah());
        println!("SAH merged {merged:.3} plain {plain:.3}");
        assert!(merged < 1.1 * plain, "merged {merged} plain {plain}");
    }

    /// The 8-wide collapse keeps every primitive once, fills its nodes, and has fewer
    /// nodes than the 4-wide one; width 4 gives exactly the `Mbvh4` collapse.
    #[test]
    fn wide_collapse_of_any_width() {
        let prims = proc_scene("proc:soup?n=20000");
        let bvh = BinnedSahBuilder::default().build(&prims).unwrap();
        let w8 = Collapse::default().collapse_wide::<8>(&bvh).unwrap();
        assert_eq!(crate::validate_wide(&w8, &prims, u32::MAX), Ok(()));
        let m4 = collapse(&bvh).unwrap();
        let mut seen = vec![false; prims.len()];
        for &p in &w8.prim_indices {
            assert!(!std::mem::replace(&mut seen[p as usize], true));
        }
        assert!(seen.iter().all(|&s| s));
        let mut leaves = 0;
        for (i, n) in w8.nodes.iter().enumerate() {
            let used = n.children.iter().filter(|c| !c.is_empty()).count();
            assert!(used >= 2 || i == 0);
            // Empty slots come last and have empty boxes; inner children follow parents.
            for (slot, c) in n.children.iter().enumerate() {
                if c.is_empty() {
                    assert!(slot >= used && n.boxes[slot].is_empty());
                } else if c.is_inner() {
                    assert!(c.index as usize > i);
                    assert!(n.boxes[slot].contains(&{
                        let k = &w8.nodes[c.index as usize];
                        k.boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b))
                    }));
                } else {
                    leaves += 1;
                    for &p in &w8.prim_indices[c.index as usize..(c.index + c.count) as usize] {
                        assert!(n.boxes[slot].contains(&prims[p as usize]));
                    }
                }
            }
        }
        assert_eq!(leaves, bvh.stats().leaves);
        assert!(
            w8.nodes.len() * 3 < m4.nodes.len() * 2,
            "{} vs {}",
            w8.nodes.len(),
            m4.nodes.len()
        );
        let w4 = Collapse::default().collapse_wide::<4>(&bvh).unwrap();
        assert_eq!(w4.nodes.len(), m4.nodes.len());
        for (a, b) in w4.nodes.iter().zip(&m4.nodes) {
            assert_eq!(a.children, b.children);
            for s in 0..4 {
                assert_eq!(a.boxes[s], b.child_aabb(s));
            }
        }
    }

    #[test]
    fn collapse_is_exact_on_a_perfect_tree() {
        // 16 cubes in a balanced binary tree collapse into a root plus four full nodes.
        let prims = crate::testutil::cubes_at(&(0..16).map(|i| i as f32 * 3.0).collect::<Vec<_>>());
        let bvh = SweepSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        let m = check("cubes", &bvh, &prims, 1);
        assert_eq!(m.nodes.len(), 5);
        assert!(m.nodes.iter().all(|n| n.child_count() == 4));
    }

    /// Every wide node's recorded binary root has the wide node's box, and only wide
    /// roots are recorded, once each, the tree's root first.
    #[test]
    fn wide_roots_are_the_roots_of_the_wide_nodes() {
        let prims = soup(3000, 2.0, 5);
        let bvh = LbvhBuilder::default().build(&prims).unwrap();
        let m = collapse(&bvh).unwrap();
        let roots = Collapse::default().wide_roots(&bvh).unwrap();
        assert_eq!(roots.len(), m.nodes.len());
        assert_eq!(roots[0], 0);
        let mut seen = vec![false; bvh.nodes.len()];
        for (k, &r) in roots.iter().enumerate() {
            assert!(!std::mem::replace(&mut seen[r as usize], true));
            assert_eq!(
                bvh.nodes[r as usize].aabb(),
                m.nodes[k].aabb(),
                "wide node {k}"
            );
        }
    }

    #[test]
    fn corrupt_trees_are_errors() {
        let prims = soup(200, 2.0, 1);
        let bvh = BinnedSahBuilder::default().build(&prims).unwrap();
        let mut c = bvh.clone();
        c.nodes[1].children[0] = ChildRef::inner(0);
        assert!(matches!(collapse(&c), Err(CollapseError::BadLink { .. })));
        let mut c = bvh.clone();
        c.nodes[1].children[0] = ChildRef::inner(u32::MAX - 1);
        assert!(matches!(collapse(&c), Err(CollapseError::BadLink { .. })));
        let mut c = bvh.clone();
        c.nodes[0].children[1] = ChildRef::leaf(u32::MAX - 2, 5);
        assert!(matches!(collapse(&c), Err(CollapseError::BadLeaf { .. })));
        // Two parents share one subtree.
        let mut c = bvh.clone();
        let last = c.nodes.len() as u32 - 1;
        c.nodes[1].children = [ChildRef::inner(last); 2];
        assert!(matches!(
            collapse(&c),
            Err(CollapseError::SharedNode { .. })
        ));
        let empty = Bvh2 {
            nodes: Vec::<Node>::new(),
            ..Bvh2::empty()
        };
        assert_eq!(collapse(&empty), Err(CollapseError::NoRoot));
    }
}
