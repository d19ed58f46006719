//! Streaming CBVH refit (\[P3\] §5.2, after Wald et al. 2007): the tree's topology is kept,
//! its boxes are recomputed bottom-up from new primitive boxes, and every node pair is
//! re-encoded in place by the streaming encoder of [`crate::bottomup`], with the same
//! context estimation, backtracking and treelets as construction.
//!
//! The refitter walks the existing CBVH depth first (children before their parent, child 0's
//! subtree first), reading each node pair for its pointers and leaf bits, and each leaf's
//! primitive ids and primitives; the full-precision box of every subtree travels up with the
//! walk (in hardware, beside the context on the stack). The old quantized boxes are not used.

use crate::bottomup::{InChild, InputNode, StreamConfig, StreamEncoder};
use crate::codec::{slot_ptr, ChildPtr};
use crate::error::CbvhError;
use crate::format::LEAF_END;
use crate::tree::Cbvh;
use crate::EncodeStats;
use geom::Aabb;

/// Refits `old` to the primitive boxes `prims` (indexed by primitive id) and re-encodes it
/// in a stream. The result has the same topology and node addresses.
pub fn refit_streaming(
    old: &Cbvh,
    prims: &[Aabb],
    cfg: &StreamConfig,
) -> Result<(Cbvh, EncodeStats), CbvhError> {
    let mut enc = StreamEncoder::in_place(*cfg, old.pairs.len())?;
    // Postorder walk with an explicit stack; subtree boxes on a value stack.
    let mut stack = vec![(old.root, false)];
    let mut boxes: Vec<Aabb> = Vec::new();
    let mut steps = 0usize;
    while let Some((idx, expanded)) = stack.pop() {
        steps += 1;
        if steps > 2 * old.pairs.len() {
            return Err(CbvhError::Corrupt("pointer cycle".into()));
        }
        let pair = *old
            .pairs
            .get(idx as usize)
            .ok_or_else(|| CbvhError::Corrupt(format!("pointer {idx} outside the tree")))?;
        let ptrs = [0, 1].map(|c| slot_ptr(&pair.slots[c]));
        if !expanded {
            stack.push((idx, true));
            for c in (0..2).rev() {
                if let ChildPtr::Inner(k) = ptrs[c] {
                    stack.push((k, false));
                }
            }
            continue;
        }
        let mut nb = [Aabb::EMPTY; 2];
        let mut children = [InChild::Empty; 2];
        for c in (0..2).rev() {
            match ptrs[c] {
                ChildPtr::Inner(_) => {
                    nb[c] = boxes
                        .pop()
                        .ok_or_else(|| CbvhError::Corrupt("walk".into()))?;
                    children[c] = InChild::Node;
                }
                ChildPtr::Leaf(first) => {
                    let mut b = Aabb::EMPTY;
                    let mut i = first as usize;
                    loop {
                        let id = *old.prim_ids.get(i).ok_or_else(|| {
                            CbvhError::Corrupt(format!("leaf at {first} has no end"))
                        })?;
                        b = b.union(*prims.get((id & !LEAF_END) as usize).ok_or_else(|| {
                            CbvhError::Corrupt(format!(
                                "primitive {} missing: the tree has more primitives than the frame",
                                id & !LEAF_END
                            ))
                        })?);
                        if id & LEAF_END != 0 {
                            break;
                        }
                        i += 1;
                    }
                    nb[c] = b;
                    children[c] = InChild::Leaf { first };
                }
                ChildPtr::Empty => {}
            }
        }
        enc.push(InputNode {
            boxes: nb,
            children,
            addr: Some(idx),
        })?;
        boxes.push(nb[0].union(nb[1]));
    }
    let (t, st) = enc.finish(old.prim_ids.clone())?;
    if t.root != old.root {
        return Err(CbvhError::Corrupt("refit moved the root".into()));
    }
    Ok((t, st))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bottomup::{compress_hlbvh, tests::soup};
    use crate::topdown::compress_topdown;
    use crate::tree::{boxes_not_enclosing, enclosure_violations};
    use crate::Coords;
    use bvh::{refit_bvh2, HlbvhBuilder};
    use geom::Vec3;
    use proptest::prelude::*;

    /// Refit to moved geometry: encloses the new primitives, keeps the topology, and
    /// encloses the top-down compression of the refitted full-precision tree.
    fn check(prims0: &[Aabb], prims1: &[Aabb], coords: Coords, m: u32, bits: u32) -> EncodeStats {
        let cfg = StreamConfig {
            params: crate::Params {
                bits,
                coords,
                ..Default::default()
            },
            treelet_depth: m,
            ..StreamConfig::default()
        };
        let hl = HlbvhBuilder::default().build_highlevel(prims0).unwrap();
        let (c0, _) = compress_hlbvh(&hl, &cfg).unwrap();
        let (c1, st) = refit_streaming(&c0, prims1, &cfg).unwrap();
        let d1 = c1.decode_to_bvh2().unwrap();
        assert_eq!(enclosure_violations(&d1, prims1).unwrap(), 0);
        // Same topology as the built tree; compare with top-down on the refitted BVH.
        let mut full = c0.decode_to_bvh2().unwrap();
        refit_bvh2(&mut full, prims1).unwrap();
        let (td, _) = compress_topdown(&full, &cfg.params).unwrap();
        let dtd = td.decode_to_bvh2().unwrap();
        // With plane sharing the sharing child can differ (see `bottomup`'s tests).
        if !coords.shares_planes() {
            assert_eq!(boxes_not_enclosing(&d1, &dtd).unwrap(), 0);
        }
        assert_eq!(st.nodes_written as usize, c0.pairs.len());
        st
    }

    #[test]
    fn refit_to_moved_geometry() {
        let p0 = soup(3000, 11, false);
        let p1: Vec<Aabb> = p0
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let d = Vec3::new((i % 7) as f32 * 0.3, (i % 5) as f32 * -0.2, 1.5);
                Aabb::new(b.min + d, b.max + d + d.abs() * 0.01)
            })
            .collect();
        for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
            for m in 1..=4 {
                check(&p0, &p1, coords, m, 6);
            }
        }
        // Refit to the same geometry backtracks like construction does.
        check(&p0, &p0, Coords::Modulo, 1, 6);
    }

    #[test]
    fn refit_with_too_few_primitives_is_an_error() {
        let p0 = soup(100, 1, false);
        let hl = HlbvhBuilder::default().build_highlevel(&p0).unwrap();
        let (c0, _) = compress_hlbvh(&hl, &StreamConfig::default()).unwrap();
        assert!(matches!(
            refit_streaming(&c0, &p0[..50], &StreamConfig::default()),
            Err(CbvhError::Corrupt(_))
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn refit_encloses_random_motion(seed in any::<u64>(), scale in 0.1f32..10.0, bits in 3u32..=8, m in 1u32..=4, modulo in any::<bool>()) {
            let p0 = soup(300, seed, seed % 3 == 0);
            let p1: Vec<Aabb> = p0.iter().map(|b| Aabb::new(b.min * scale, b.max * scale + Vec3::splat(scale))).collect();
            check(&p0, &p1, if modulo { Coords::Modulo } else { Coords::Relative }, m, bits);
        }
    }
}
