//! SAH-optimal collapse of a binary [`Bvh2`] into a 4-wide [`Mbvh4`] with the same leaves
//! (issue 31 part 4), or into a tree of any width `W` ([`collapse_wide_optimal`], the
//! 8-wide tree of the `mbvh8` kernel): the dynamic program of Ylitie, Karras and Laine
//! (2017, "Efficient incoherent ray traversal on GPUs through compressed wide BVHs", §3),
//! restricted to keeping the binary tree's leaves.
//!
//! Among all `W`-wide trees whose nodes are cuts of the binary tree (every wide node's
//! children are a frontier of the binary subtree below it, as in any collapse), it picks
//! the one of least SAH with wide nodes costing `(W / 2) C_i` ([`SahParams::for_width`];
//! for 4-wide nodes `2 C_i`, the cost that [`Mbvh4::normalized_sah`] reports). With the
//! leaves fixed, every candidate pays the same for its leaves, so the optimum is the tree
//! of least total wide-node area whatever `C_i`. Every wide node is paid in full whether it
//! has two children or four, so the optimum opens small subtrees into their parent rather
//! than giving them nodes of their own: it fills nodes where the greedy collapse
//! ([`crate::Collapse`], which pulls up only the largest inner child and leaves subtrees of
//! two or three leaves as nodes of two or three children) cannot.
//!
//! The program, bottom-up over binary inner nodes `i` with children `l`, `r` and box area
//! `A_i`: `S(i, j)`, the least cost of `i`'s subtree when it may take up to `j` (1..=4)
//! slots of its parent, is `S(i, 1) = 2 C_i A_i + O(i, 4)` (a wide node of its own) and
//! `S(i, j) = min(S(i, j - 1), O(i, j))`, where `O(i, j) = min_a S(l, a) + S(r, j - a)` opens
//! `i` into its parent; a leaf child costs `A (C_l + C_t n)` in one slot.

use crate::bvh2::Bvh2;
use crate::collapse::{check_links, gather, CollapseError, WideBvh, WideNode};
use crate::layout::try_preorder;
use crate::mbvh4::{Mbvh4, MBVH_WIDTH};
use crate::node::ChildRef;
use crate::sah::SahParams;
use geom::Aabb;

/// Per binary inner node: least cost for up to `j + 1` slots, and how it is reached
/// (`0`: a wide node of its own; `a` in 1..W: `a` slots to the left child, the rest right).
#[derive(Clone, Copy)]
struct Entry<const W: usize> {
    cost: [Cost; W],
    how: [u8; W],
    /// Split of the 4 slots of this node's own wide node (`a` slots to the left child).
    own: u8,
    /// Kept whole, the subtree is one merged leaf rather than a wide node
    /// ([`collapse_wide_blocks`]).
    leaf: bool,
}

/// (wide nodes, unnormalized SAH) of a subtree.
type Cost = (f64, f64);

/// What the collapse minimizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CollapseGoal {
    /// The 4-wide SAH.
    Sah,
    /// The number of wide nodes, then the 4-wide SAH among the trees with the fewest: the
    /// fullest nodes the binary tree's leaves and topology allow.
    FewestNodes,
}

/// The SAH-optimal 4-wide collapse of `bvh` keeping its leaves, with SAH weights `sah`
/// (binary units; a 4-wide node costs `2 · sah.c_inner`).
pub fn collapse_sah_optimal(bvh: &Bvh2, sah: &SahParams) -> Result<Mbvh4, CollapseError> {
    collapse_optimal(bvh, sah, CollapseGoal::Sah)
}

/// The 4-wide collapse of `bvh` keeping its leaves that is optimal for `goal`.
pub fn collapse_optimal(
    bvh: &Bvh2,
    sah: &SahParams,
    goal: CollapseGoal,
) -> Result<Mbvh4, CollapseError> {
    Ok(collapse_wide_optimal::<MBVH_WIDTH>(bvh, sah, goal)?.into())
}

/// The `W`-wide collapse (`W >= 2`) of `bvh` keeping its leaves that is optimal for
/// `goal`, with wide nodes costing `sah.for_width(W).c_inner`.
pub fn collapse_wide_optimal<const W: usize>(
    bvh: &Bvh2,
    sah: &SahParams,
    goal: CollapseGoal,
) -> Result<WideBvh<W>, CollapseError> {
    collapse_wide(bvh, sah, goal, 0)
}

/// The SAH-optimal `W`-wide collapse of `bvh` for a kernel that tests triangles in SIMD
/// blocks of `block` (`>= 1`): a leaf costs its area times `C_leaf + C_tri * block *
/// ceil(n / block)` (a partly filled block costs a whole test), and a binary subtree of at
/// most `block` primitives may become one leaf (its primitives gathered) where that costs
/// less than keeping it as a wide node or opening it into its parent. Small leaves of a
/// fine mesh then share one block instead of a node and a block each (the `mbvh8` kernel
/// traces the tree with `block = 4`).
pub fn collapse_wide_blocks<const W: usize>(
    bvh: &Bvh2,
    sah: &SahParams,
    block: u32,
) -> Result<WideBvh<W>, CollapseError> {
    collapse_wide(bvh, sah, CollapseGoal::Sah, block.max(1))
}

/// [`collapse_wide_optimal`] (`block == 0`: the binary leaves kept, costs per triangle) or
/// [`collapse_wide_blocks`].
fn collapse_wide<const W: usize>(
    bvh: &Bvh2,
    sah: &SahParams,
    goal: CollapseGoal,
    block: u32,
) -> Result<WideBvh<W>, CollapseError> {
    const { assert!(W >= 2 && W <= 255) };
    let lt = |a: Cost, b: Cost| match goal {
        CollapseGoal::Sah => a.1 < b.1,
        CollapseGoal::FewestNodes => a < b,
    };
    let add = |a: Cost, b: Cost| (a.0 + b.0, a.1 + b.1);
    const INF: Cost = (f64::INFINITY, f64::INFINITY);
    let n = bvh.nodes.len();
    if n == 0 {
        return Err(CollapseError::NoRoot);
    }
    check_links(bvh)?;
    let p = sah.for_width(W);
    let (ci, cl, ct) = (p.c_inner as f64, p.c_leaf as f64, p.c_tri as f64);
    let mut dp = vec![
        Entry {
            cost: [INF; W],
            how: [0; W],
            own: 0,
            leaf: false,
        };
        n
    ];
    // Triangles a leaf of `count` is tested as (whole blocks).
    let tested = |count: u64| -> f64 {
        if block == 0 {
            count as f64
        } else {
            (count.div_ceil(block as u64) * block as u64) as f64
        }
    };
    let mut prims = vec![0u64; n];
    // Cost of child `slot` of binary node `i` in up to `j + 1` slots (`None`: empty slot).
    let child_cost = |dp: &[Entry<W>], i: usize, slot: usize, j: usize| -> Option<Cost> {
        let node = &bvh.nodes[i];
        let c = node.children[slot];
        if c.is_leaf() {
            let a = node.child_aabb(slot).half_area() as f64;
            Some((0.0, a * (cl + ct * tested(c.count as u64))))
        } else if c.is_inner() {
            Some(dp[c.index as usize].cost[j])
        } else {
            None
        }
    };
    // Children are after their parents (checked), so a reverse sweep is bottom-up.
    for i in (0..n).rev() {
        // open[j]: least cost of opening i into up to j + 1 slots, and its split.
        let mut open = [(INF, 0u8); W];
        for (j, o) in open.iter_mut().enumerate() {
            let slots = j + 1;
            let l0 = child_cost(&dp, i, 0, 0);
            let r0 = child_cost(&dp, i, 1, 0);
            match (l0, r0) {
                (None, None) => *o = ((0.0, 0.0), 0),
                (Some(_), None) => *o = (child_cost(&dp, i, 0, j).unwrap(), slots as u8),
                (None, Some(_)) => *o = (child_cost(&dp, i, 1, j).unwrap(), 0),
                (Some(_), Some(_)) => {
                    for a in 1..slots {
                        let c = add(
                            child_cost(&dp, i, 0, a - 1).unwrap(),
                            child_cost(&dp, i, 1, slots - a - 1).unwrap(),
                        );
                        if lt(c, o.0) {
                            *o = (c, a as u8);
                        }
                    }
                }
            }
        }
        let area = bvh.nodes[i].aabb().half_area() as f64;
        let count: u64 = bvh.nodes[i]
            .children
            .iter()
            .map(|c| {
                if c.is_leaf() {
                    c.count as u64
                } else if c.is_inner() {
                    prims[c.index as usize]
                } else {
                    0
                }
            })
            .sum();
        prims[i] = count;
        let e = &mut dp[i];
        e.own = open[W - 1].1;
        e.cost[0] = add((1.0, ci * area), open[W - 1].0);
        e.how[0] = 0;
        if block > 0 && i != 0 && count <= block as u64 {
            let as_leaf = (0.0, area * (cl + ct * tested(count)));
            if lt(as_leaf, e.cost[0]) {
                e.cost[0] = as_leaf;
                e.leaf = true;
            }
        }
        for (j, &(oc, oa)) in open.iter().enumerate().skip(1) {
            (e.cost[j], e.how[j]) = (e.cost[j - 1], e.how[j - 1]);
            if lt(oc, e.cost[j]) {
                (e.cost[j], e.how[j]) = (oc, oa);
            }
        }
    }
    // Emission, depth-first preorder as in the greedy collapse.
    let mut out: Vec<WideNode<W>> = Vec::with_capacity(n / 2 + 1);
    let mut table: Vec<u32> = Vec::with_capacity(bvh.prim_indices.len());
    let mut seen = vec![false; n];
    let mut kids: Vec<(Aabb, ChildRef)> = Vec::with_capacity(W);
    try_preorder(0usize, &mut out, |bi, out, next| {
        if std::mem::replace(&mut seen[bi], true) {
            return Err(CollapseError::SharedNode { node: bi });
        }
        kids.clear();
        let a = dp[bi].own as usize;
        expand_open(bvh, &dp, bi, a, W, &mut kids, &mut seen)?;
        let mut node = WideNode {
            boxes: [Aabb::EMPTY; W],
            children: [ChildRef::EMPTY; W],
        };
        for (slot, &(b, c)) in kids.iter().enumerate() {
            node.boxes[slot] = b;
            node.children[slot] = if c.is_leaf() {
                let first = table.len() as u32;
                let s = c.index as usize;
                table.extend_from_slice(&bvh.prim_indices[s..s + c.count as usize]);
                ChildRef::leaf(first, c.count)
            } else if dp[c.index as usize].leaf {
                let first = table.len();
                gather(bvh, c.index as usize, &mut table, &mut seen)?;
                ChildRef::leaf(first as u32, (table.len() - first) as u32)
            } else {
                next.push((slot, c.index as usize));
                ChildRef::EMPTY
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

/// Appends the children of binary node `i` opened into `slots` slots, `a` of them for its
/// left child: leaves as they are, inner children as their own choices say (an inner child
/// kept whole is a new wide node, `ChildRef::inner` of its binary index). Iterative, so a
/// long chain of one-child nodes in a tree from a file cannot overflow the call stack.
fn expand_open<const W: usize>(
    bvh: &Bvh2,
    dp: &[Entry<W>],
    i: usize,
    a: usize,
    slots: usize,
    kids: &mut Vec<(Aabb, ChildRef)>,
    seen: &mut [bool],
) -> Result<(), CollapseError> {
    // (binary node, slots, slots of its left child); or a slot to emit.
    enum Step {
        Open(usize, usize, usize),
        Emit((Aabb, ChildRef)),
    }
    let mut todo = vec![Step::Open(i, slots, a)];
    while let Some(step) = todo.pop() {
        let (i, slots, a) = match step {
            Step::Emit(kid) => {
                kids.push(kid);
                continue;
            }
            Step::Open(i, slots, a) => (i, slots, a),
        };
        let node = &bvh.nodes[i];
        // Pushed right child first, so that the left child's slots come first.
        for (slot, j) in [(1usize, slots - a), (0, a)] {
            let c = node.children[slot];
            if c.is_leaf() {
                todo.push(Step::Emit((node.child_aabb(slot), c)));
            } else if c.is_inner() {
                let k = c.index as usize;
                let how = dp[k].how[j.max(1) - 1] as usize;
                if how == 0 {
                    todo.push(Step::Emit((node.child_aabb(slot), c)));
                } else {
                    if std::mem::replace(&mut seen[k], true) {
                        return Err(CollapseError::SharedNode { node: k });
                    }
                    todo.push(Step::Open(k, j, how));
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mbvh4::validate_mbvh4;
    use crate::testutil::{adversarial, proc_scene};
    use crate::{collapse, validate, BinnedSahBuilder};

    fn check(name: &str, bvh: &Bvh2, prims: &[Aabb], max_leaf: u32) -> Mbvh4 {
        validate(bvh, prims, max_leaf).unwrap_or_else(|e| panic!("{name}: input {e}"));
        let t = collapse_sah_optimal(bvh, &SahParams::THESIS).unwrap();
        validate_mbvh4(&t, prims, max_leaf).unwrap_or_else(|e| panic!("{name}: {e}"));
        t
    }

    #[test]
    fn adversarial_inputs_collapse_validly() {
        for (name, prims) in adversarial() {
            for max in [1, 4, 8] {
                let b = BinnedSahBuilder {
                    max_leaf_size: max,
                    ..Default::default()
                }
                .build(&prims)
                .unwrap();
                check(name, &b, &prims, max);
                let w = collapse_wide_blocks::<8>(&b, &SahParams::THESIS, 4).unwrap();
                crate::validate_wide(&w, &prims, max.max(4))
                    .unwrap_or_else(|e| panic!("{name}: blocks: {e}"));
            }
        }
    }

    /// The optimum keeps the binary tree's leaves, is never worse in the 4-wide SAH than
    /// the greedy collapse (the greedy tree is one of the candidates), and fills nodes:
    /// more children per node and fewer nodes than the greedy collapse. The fewest-nodes
    /// goal gives no more nodes and no lower SAH.
    #[test]
    fn sah_not_above_the_greedy_collapse_and_nodes_fuller() {
        for spec in [
            "proc:soup?n=20000",
            "proc:city?n=20000&seed=2",
            "proc:hairball?n=20000&seed=3",
        ] {
            let prims = proc_scene(spec);
            let b = BinnedSahBuilder::default().build(&prims).unwrap();
            let g = collapse(&b).unwrap();
            let o = check(spec, &b, &prims, 8);
            let (so, sg) = (o.normalized_sah(), g.normalized_sah());
            let (so_, sg_) = (o.stats(), g.stats());
            println!(
                "{spec}: optimal {so:.3} ({} nodes, {:.2} children), greedy {sg:.3} ({} nodes, {:.2}), binary {} nodes",
                o.nodes.len(),
                so_.mean_children,
                g.nodes.len(),
                sg_.mean_children,
                b.nodes.len()
            );
            assert!(
                so <= sg * (1.0 + 1e-9),
                "{spec}: optimal {so} above greedy {sg}"
            );
            assert_eq!(so_.leaves, sg_.leaves, "{spec}: the same leaves");
            assert!(o.nodes.len() < g.nodes.len(), "{spec}");
            assert!(so_.mean_children > sg_.mean_children, "{spec}");
            // The fewest nodes the leaves and topology allow: no more than the SAH optimum's,
            // never fewer than a third of the binary tree's inner nodes (every wide node
            // stands for at most three of them).
            let f = collapse_optimal(&b, &SahParams::THESIS, CollapseGoal::FewestNodes).unwrap();
            validate_mbvh4(&f, &prims, 8).unwrap();
            println!(
                "  fewest nodes: {} ({:.2} children), SAH {:.3}",
                f.nodes.len(),
                f.stats().mean_children,
                f.normalized_sah()
            );
            assert!(f.nodes.len() <= o.nodes.len(), "{spec}");
            assert!(3 * f.nodes.len() >= b.nodes.len(), "{spec}");
            assert!(f.normalized_sah() >= so * (1.0 - 1e-9), "{spec}");
        }
    }

    /// A perfect binary tree of 16 leaves collapses into 5 full nodes (a root and four
    /// nodes of four leaves), the least possible.
    #[test]
    fn a_perfect_tree_gives_full_nodes() {
        let xs: Vec<f32> = (0..16).map(|i| i as f32 * 10.0).collect();
        let prims = crate::testutil::cubes_at(&xs);
        let b = BinnedSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        }
        .build(&prims)
        .unwrap();
        let o = check("cubes", &b, &prims, 1);
        assert_eq!(o.nodes.len(), 5);
        assert!(o.nodes.iter().all(|n| n.child_count() == 4));
    }

    /// Any width: valid trees with the binary tree's leaves and never more wide-node area
    /// (the only term that differs between collapses keeping the leaves) than the greedy
    /// collapse of the same width; for 8-wide nodes, fewer nodes.
    #[test]
    fn wide_optimum_beats_the_greedy_wide_collapse() {
        fn node_area<const W: usize>(t: &WideBvh<W>) -> f64 {
            t.nodes
                .iter()
                .map(|n| {
                    n.boxes
                        .iter()
                        .fold(Aabb::EMPTY, |a, b| a.union(*b))
                        .half_area() as f64
                })
                .sum()
        }
        fn leaves<const W: usize>(t: &WideBvh<W>) -> usize {
            t.nodes
                .iter()
                .flat_map(|n| n.children.iter())
                .filter(|c| c.is_leaf())
                .count()
        }
        for spec in ["proc:soup?n=20000", "proc:city?n=20000&seed=2"] {
            let prims = proc_scene(spec);
            let b = BinnedSahBuilder::default().build(&prims).unwrap();
            let o8 = collapse_wide_optimal::<8>(&b, &SahParams::THESIS, CollapseGoal::Sah).unwrap();
            let g8 = crate::Collapse::default().collapse_wide::<8>(&b).unwrap();
            crate::validate_wide(&o8, &prims, 8).unwrap_or_else(|e| panic!("{spec}: {e}"));
            assert_eq!(leaves(&o8), leaves(&g8), "{spec}");
            assert!(node_area(&o8) <= node_area(&g8) * (1.0 + 1e-9), "{spec}");
            assert!(o8.nodes.len() < g8.nodes.len(), "{spec}");
            let o3 = collapse_wide_optimal::<3>(&b, &SahParams::THESIS, CollapseGoal::Sah).unwrap();
            let g3 = crate::Collapse::default().collapse_wide::<3>(&b).unwrap();
            crate::validate_wide(&o3, &prims, 8).unwrap_or_else(|e| panic!("{spec}: {e}"));
            assert!(node_area(&o3) <= node_area(&g3) * (1.0 + 1e-9), "{spec}");
            // The 4-wide form is the 4-wide optimum node for node.
            let o4 = collapse_wide_optimal::<4>(&b, &SahParams::THESIS, CollapseGoal::Sah).unwrap();
            let m4 = collapse_sah_optimal(&b, &SahParams::THESIS).unwrap();
            assert_eq!(o4.nodes.len(), m4.nodes.len());
            assert_eq!(o4.prim_indices, m4.prim_indices);
            for (w, m) in o4.nodes.iter().zip(&m4.nodes) {
                assert_eq!(w.children, m.children);
            }
        }
    }

    /// A chain of 200,000 one-child nodes (possible in a tree read from a file) collapses
    /// without overflowing the call stack: the whole chain opens into the root.
    #[test]
    fn a_long_chain_of_one_child_nodes_collapses() {
        let n = 200_000u32;
        let unit = Aabb::new(geom::Vec3::ZERO, geom::Vec3::ONE);
        let nodes: Vec<crate::node::Node> = (0..n)
            .map(|i| {
                let c = if i + 1 < n {
                    ChildRef::inner(i + 1)
                } else {
                    ChildRef::leaf(0, 1)
                };
                crate::node::Node::new(&unit, c, &Aabb::EMPTY, ChildRef::EMPTY)
            })
            .collect();
        let b = Bvh2 {
            nodes,
            prim_indices: vec![0],
            bounds: unit,
        };
        let w = collapse_wide_optimal::<8>(&b, &SahParams::THESIS, CollapseGoal::Sah).unwrap();
        assert_eq!(w.nodes.len(), 1);
        assert_eq!(w.nodes[0].children[0], ChildRef::leaf(0, 1));
        assert_eq!(
            collapse_sah_optimal(&b, &SahParams::THESIS)
                .unwrap()
                .nodes
                .len(),
            1
        );
    }

    /// Block costs: valid trees holding every primitive once, merged leaves of at most a
    /// block, and never a higher block-rounded SAH than the optimum keeping the binary
    /// leaves (one of its candidates); on a fine mesh of one-triangle leaves, fewer nodes
    /// and leaves.
    #[test]
    fn block_costs_merge_small_subtrees_where_cheaper() {
        fn cost<const W: usize>(t: &WideBvh<W>, block: u32) -> f64 {
            let p = SahParams::THESIS.for_width(W);
            let mut c = 0.0;
            for n in &t.nodes {
                let own = n.boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
                c += p.c_inner as f64 * own.half_area() as f64;
                for (b, k) in n.boxes.iter().zip(&n.children) {
                    if k.is_leaf() {
                        let tested = k.count.div_ceil(block) * block;
                        c += b.half_area() as f64 * (p.c_leaf + p.c_tri * tested as f32) as f64;
                    }
                }
            }
            c
        }
        for (spec, max) in [
            ("proc:soup?n=20000", 1),
            ("proc:city?n=20000&seed=2", 8),
            ("proc:hairball?n=20000&seed=3", 1),
        ] {
            let prims = proc_scene(spec);
            let b = BinnedSahBuilder {
                max_leaf_size: max,
                ..Default::default()
            }
            .build(&prims)
            .unwrap();
            let kept =
                collapse_wide_optimal::<8>(&b, &SahParams::THESIS, CollapseGoal::Sah).unwrap();
            let merged = collapse_wide_blocks::<8>(&b, &SahParams::THESIS, 4).unwrap();
            crate::validate_wide(&merged, &prims, max.max(4))
                .unwrap_or_else(|e| panic!("{spec}: {e}"));
            let mut sorted = merged.prim_indices.clone();
            sorted.sort_unstable();
            assert_eq!(
                sorted,
                (0..prims.len() as u32).collect::<Vec<_>>(),
                "{spec}"
            );
            assert!(
                cost(&merged, 4) <= cost(&kept, 4) * (1.0 + 1e-9),
                "{spec}: {} above {}",
                cost(&merged, 4),
                cost(&kept, 4)
            );
            if max == 1 {
                assert!(merged.nodes.len() < kept.nodes.len(), "{spec}");
                let leaves = |t: &WideBvh<8>| {
                    t.nodes
                        .iter()
                        .flat_map(|n| n.children.iter())
                        .filter(|c| c.is_leaf())
                        .count()
                };
                assert!(leaves(&merged) < leaves(&kept), "{spec}");
            }
        }
    }
}
