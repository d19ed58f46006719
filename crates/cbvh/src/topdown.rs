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
    let mut stack = vec![(0u32, root_ctx)];
    let mut visited = 0usize;
    while let Some((i, ctx)) = stack.pop() {
        visited += 1;
        if visited > bvh.nodes.len() {
            return Err(CbvhError::Corrupt("cycle in the BVH".into()));
        }
        let n = bvh
            .nodes
            .get(i as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("node {i} outside the tree")))?;
        let boxes = [n.child_aabb(0), n.child_aabb(1)];
        for (c, b) in boxes.iter().enumerate() {
            check_box(b, 2 * i as usize + c)?;
        }
        let ptrs = [child_ptr(&n.children[0])?, child_ptr(&n.children[1])?];
        let (pair, kids) = encode_pair(&boxes, ptrs, &ctx, params);
        pairs[i as usize] = pair;
        for c in (0..2).rev() {
            if let ChildPtr::Inner(k) = ptrs[c] {
                stack.push((k, kids[c]));
            }
        }
    }
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
