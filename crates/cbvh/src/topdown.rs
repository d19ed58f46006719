//! Top-down compression of a finished [`Bvh2`]: the postprocessing baseline of \[P3\]
//! Fig. 2a. The root's context is estimated from the scene box (as the bottom-up encoders
//! do for their root, so both agree on it); every node is then encoded in the context its
//! parent's encoding produced (Eq. 1). The node pairs keep the [`Bvh2`]'s node numbering.

use crate::codec::{check_box, encode_pair, ChildPtr, Ctx};
use crate::error::CbvhError;
use crate::format::MAX_PTR;
use crate::grid::Params;
use crate::tree::{prim_ids_of, Cbvh};
use crate::EncodeStats;
use bvh::{Bvh2, ChildRef};
use geom::Aabb;

/// The [`ChildPtr`] of a [`Bvh2`] child.
pub(crate) fn child_ptr(c: &ChildRef) -> Result<ChildPtr, CbvhError> {
    if c.is_empty() {
        return Ok(ChildPtr::Empty);
    }
    if c.index > MAX_PTR {
        return Err(CbvhError::TooLarge {
            what: "pointer",
            count: c.index as usize,
        });
    }
    Ok(if c.is_leaf() {
        ChildPtr::Leaf(c.index)
    } else {
        ChildPtr::Inner(c.index)
    })
}

/// The top-down walk of both top-down encoders (binary pairs and 4-wide nodes): from node
/// 0 in `root_ctx`, for each node reached (`node(i)`: its `K` child boxes and references,
/// `None` outside the tree) checks the boxes and pointers, calls `encode(i, boxes,
/// pointers, ctx)`, which stores node `i`'s encoding and returns the context each child
/// gets, and goes on to the inner children in slot order. A tree of `count` nodes that
/// revisits one (a cycle in `what`) is an error. Returns the nodes visited.
pub(crate) fn walk_topdown<const K: usize>(
    count: usize,
    what: &str,
    root_ctx: Ctx,
    node: impl Fn(usize) -> Option<([Aabb; K], [ChildRef; K])>,
    mut encode: impl FnMut(usize, &[Aabb; K], [ChildPtr; K], &Ctx) -> [Ctx; K],
) -> Result<usize, CbvhError> {
    let mut stack = vec![(0u32, root_ctx)];
    let mut visited = 0usize;
    while let Some((i, ctx)) = stack.pop() {
        visited += 1;
        if visited > count {
            return Err(CbvhError::Corrupt(format!("cycle in {what}")));
        }
        let (boxes, refs) = node(i as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("node {i} outside the tree")))?;
        for (c, b) in boxes.iter().enumerate() {
            check_box(b, K * i as usize + c)?;
        }
        let mut ptrs = [ChildPtr::Empty; K];
        for (p, c) in ptrs.iter_mut().zip(&refs) {
            *p = child_ptr(c)?;
        }
        let kids = encode(i as usize, &boxes, ptrs, &ctx);
        for c in (0..K).rev() {
            if let ChildPtr::Inner(k) = ptrs[c] {
                stack.push((k, kids[c]));
            }
        }
    }
    Ok(visited)
}

/// Compresses `bvh` top-down. Statistics: one write per node pair, no backtracking.
pub fn compress_topdown(bvh: &Bvh2, params: &Params) -> Result<(Cbvh, EncodeStats), CbvhError> {
    params.check()?;
    if bvh.nodes.len() > MAX_PTR as usize {
        return Err(CbvhError::TooLarge {
            what: "node pair",
            count: bvh.nodes.len(),
        });
    }
    let prim_ids = prim_ids_of(bvh)?;
    let root_box = bvh.nodes[0].aabb();
    check_box(&root_box, 0)?;
    let root_ctx = Ctx::estimate(&root_box, params);
    let mut pairs = vec![crate::format::NodePair::default(); bvh.nodes.len()];
    let visited = walk_topdown(
        bvh.nodes.len(),
        "the BVH",
        root_ctx,
        |i| {
            bvh.nodes
                .get(i)
                .map(|n| ([n.child_aabb(0), n.child_aabb(1)], n.children))
        },
        |i, boxes, ptrs, ctx| {
            let (pair, kids) = encode_pair(boxes, ptrs, ctx, params);
            pairs[i] = pair;
            kids
        },
    )?;
    let stats = EncodeStats {
        nodes_written: visited as u64,
        ..EncodeStats::default()
    };
    Ok((
        Cbvh {
            params: *params,
            pairs,
            root: 0,
            root_ctx,
            prim_ids,
        },
        stats,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::{enclosure_violations, interval_encloses, node_intervals_enclose};
    use geom::Vec3;

    #[test]
    fn decoded_tree_keeps_the_topology_and_encloses() {
        let prims = crate::bottomup::tests::soup(2000, 8, false);
        let bvh = bvh::BinnedSahBuilder::default().build(&prims).unwrap();
        let (c, st) = compress_topdown(&bvh, &Params::default()).unwrap();
        assert_eq!(st.nodes_written as usize, bvh.nodes.len());
        let d = c.decode_to_bvh2().unwrap();
        assert_eq!(d.nodes.len(), bvh.nodes.len());
        assert_eq!(d.prim_indices, bvh.prim_indices);
        for (a, b) in d.nodes.iter().zip(&bvh.nodes) {
            assert_eq!(a.children, b.children);
            for k in 0..2 {
                assert!(a.child_aabb(k).contains(&b.child_aabb(k)));
            }
        }
        assert_eq!(enclosure_violations(&d, &prims).unwrap(), 0);
        assert_eq!(bvh::validate(&d, &prims, 8), Ok(()));
        // The watertightness criterion of [P3] §5.5 on rays through every node.
        for (a, b) in d.nodes.iter().zip(&bvh.nodes).take(200) {
            let o = Vec3::new(-60.0, 13.0, 200.0);
            let target = b.child_aabb(0).center();
            assert!(interval_encloses(
                o,
                target - o,
                0.0,
                f32::INFINITY,
                &b.child_aabb(0),
                &a.child_aabb(0)
            ));
            let t1 = b.child_aabb(1).center();
            assert_eq!(
                node_intervals_enclose(o, t1 - o, 0.0, f32::INFINITY, b, a),
                [true; 2]
            );
        }
        // A box strictly inside the original does not enclose its interval.
        let bx = geom::Aabb::new(Vec3::ZERO, Vec3::ONE);
        let small = geom::Aabb::new(Vec3::splat(0.25), Vec3::splat(0.75));
        assert!(!interval_encloses(
            Vec3::new(0.5, 0.5, -1.0),
            Vec3::Z,
            0.0,
            10.0,
            &bx,
            &small
        ));
        assert!(interval_encloses(
            Vec3::new(0.5, 0.5, -1.0),
            Vec3::Z,
            0.0,
            10.0,
            &small,
            &bx
        ));
    }

    #[test]
    fn packed_bytes_round_trip() {
        let prims = crate::bottomup::tests::soup(500, 2, false);
        let bvh = bvh::LbvhBuilder::default().build(&prims).unwrap();
        for bits in 3..=8 {
            let p = Params {
                bits,
                ..Params::default()
            };
            let (c, _) = compress_topdown(&bvh, &p).unwrap();
            let bytes = c.to_bytes().unwrap();
            assert_eq!(bytes.len() as u64, c.node_bytes());
            let n = crate::format::pair_bytes(bits);
            for (i, pair) in c.pairs.iter().enumerate() {
                assert_eq!(
                    &crate::format::NodePair::unpack(bits, &bytes[i * n..]).unwrap(),
                    pair
                );
            }
        }
    }
}
