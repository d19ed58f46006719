//! Tests of the compressed 4-wide format and its encoders.

use super::*;
use crate::bottomup::tests::soup;
use crate::tree::interval_encloses;
use crate::Coords;
use bvh::{validate_mbvh4, HlbvhBuilder, Mbvh4TopDownBuilder};
use geom::Vec3;
use proptest::prelude::*;

fn params(coords: Coords, bits: u32) -> Params {
    Params {
        bits,
        coords,
        ..Params::default()
    }
}

fn cfg(coords: Coords, bits: u32, m: u32) -> StreamConfig {
    StreamConfig {
        params: params(coords, bits),
        treelet_depth: m,
        ..StreamConfig::default()
    }
}

const ALL_COORDS: [Coords; 3] = [Coords::Relative, Coords::Modulo, Coords::PlaneSharing];

/// Child boxes of `a` (decoded) that do not enclose the same child of `b` (two 4-wide
/// trees of the same topology, in the same node order); panics on a topology mismatch.
fn not_enclosing(a: &Mbvh4, b: &Mbvh4) -> usize {
    assert_eq!(a.nodes.len(), b.nodes.len());
    assert_eq!(a.prim_indices, b.prim_indices);
    let mut bad = 0;
    for (x, y) in a.nodes.iter().zip(&b.nodes) {
        assert_eq!(x.children, y.children);
        for c in 0..WIDTH {
            if !y.children[c].is_empty() && !x.child_aabb(c).contains(&y.child_aabb(c)) {
                bad += 1;
            }
        }
    }
    bad
}

/// The checks every compressed tree of the exact tree `m` passes: it decodes to `m`'s
/// topology and leaf table, every decoded child box encloses the exact one (so the decoded
/// tree is a valid 4-wide BVH over `prims`), and the packed bytes round-trip.
fn check_decodes(c: &Cbvh4, m: &Mbvh4, prims: &[Aabb]) -> Mbvh4 {
    let d = c.decode_to_mbvh4().unwrap();
    assert_eq!(
        not_enclosing(&d, m),
        0,
        "a decoded box misses its exact box"
    );
    let max_leaf = m.stats().max_leaf_size.max(1);
    assert_eq!(validate_mbvh4(&d, prims, max_leaf), Ok(()));
    let bytes = c.to_bytes().unwrap();
    let nb = quad_bytes(c.params.bits);
    assert_eq!(bytes.len() as u64, c.node_bytes());
    for (i, n) in c.nodes.iter().enumerate() {
        assert_eq!(
            &QuadNode::unpack(c.params.bits, &bytes[i * nb..]).unwrap(),
            n
        );
    }
    d
}

/// Compresses `m` top-down and bottom-up (every coordinate kind, treelets 1..=3) and
/// checks both; the bottom-up boxes enclose the top-down ones (not with plane sharing,
/// see `bottomup`'s tests). Returns the top-down decoded tree and the number of boxes in
/// which the bottom-up trees differ from it.
fn check_tree(m: &Mbvh4, prims: &[Aabb], bits: u32) -> usize {
    let mut differ = 0;
    for coords in ALL_COORDS {
        let (td, st) = compress4_topdown(m, &params(coords, bits)).unwrap();
        assert_eq!(st.nodes_written as usize, m.nodes.len());
        let dtd = check_decodes(&td, m, prims);
        for t in 1..=3 {
            let (bu, st) = compress4_bottomup(m, &cfg(coords, bits, t)).unwrap();
            assert_eq!(st.nodes_written as usize, m.nodes.len());
            let dbu = check_decodes(&bu, m, prims);
            if !coords.shares_planes() {
                assert_eq!(not_enclosing(&dbu, &dtd), 0, "{coords:?} treelet {t}");
            }
            differ += not_enclosing(&dtd, &dbu);
        }
    }
    differ
}

#[test]
fn sizes_and_layout() {
    assert_eq!(quad_bytes(6), 32);
    assert_eq!(
        (3..=8).map(quad_bytes).collect::<Vec<_>>(),
        vec![23, 26, 29, 32, 35, 38]
    );
    // At 6 bits slot c is little-endian u64 word c, laid out as a pair's slot.
    let mut q = QuadNode::default();
    q.slots[2].lo = [5, 0, 0];
    q.slots[2].leaf = true;
    q.slots[2].ptr = 77;
    q.slots[3] = Slot::EMPTY;
    let mut b = Vec::new();
    q.pack_into(6, &mut b).unwrap();
    let w = |k: usize| u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().unwrap());
    assert_eq!((w(0), w(1)), (0, 0));
    assert_eq!(w(2) & 0x3f, 5);
    assert_eq!((w(2) >> 36) & 1, 1);
    assert_eq!(w(2) >> 37, 77);
    assert_eq!(w(3) >> 37, u64::from(crate::format::EMPTY_PTR));
    // A node pair's bytes are the first two slots of the same layout.
    let pair = crate::format::NodePair {
        slots: [q.slots[2], q.slots[3]],
    };
    let mut pb = Vec::new();
    pair.pack_into(6, &mut pb).unwrap();
    assert_eq!(pb, b[16..32]);
    assert!(QuadNode::unpack(6, &b[..31]).is_err());
}

proptest! {
    #[test]
    fn quad_nodes_round_trip(bits in 3u32..=8, f in proptest::collection::vec(0u32..=255, 24), leaf in any::<[bool; 4]>(), ptr in proptest::array::uniform4(0..=crate::format::EMPTY_PTR)) {
        let m = (1u32 << bits) - 1;
        let mut q = QuadNode::default();
        for c in 0..WIDTH {
            for i in 0..3 {
                q.slots[c].lo[i] = (f[6 * c + i] & m) as u8;
                q.slots[c].hi[i] = (f[6 * c + 3 + i] & m) as u8;
            }
            q.slots[c].leaf = leaf[c];
            q.slots[c].ptr = ptr[c];
        }
        let mut b = Vec::new();
        q.pack_into(bits, &mut b).unwrap();
        prop_assert_eq!(b.len(), quad_bytes(bits));
        prop_assert_eq!(QuadNode::unpack(bits, &b).unwrap(), q);
    }
}

/// Four unit cubes at x = 0, 2, 4, 6: one root node, its fields derived by hand. The root
/// box 0..7 x 0..1 x 0..1 gets the estimated context (Eq. 2 on the zero-aligned grid of
/// Eq. 1's extra cell): x at scale 2^-3 (0..7.125 spans 57 of 64 cells; at 2^-4, 0..7.0625
/// spans 113 > 64), y and z at 2^-5 (0..1.03125, 33 cells). Child 1 (x 2..3) covers x cells
/// 16..25 and y, z cells 0..33, clipped to the node's 33: relative fields (16, 24) and
/// (0, 32) (`r`, `s - 1`); modulo fields (16, 25) and (0, 33) (`k`, `l` mod 64, the node's
/// lower bound being 0).
#[test]
fn one_node_by_hand() {
    let prims: Vec<Aabb> = [0.0f32, 2.0, 4.0, 6.0]
        .iter()
        .map(|&x| Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0)))
        .collect();
    let m = Mbvh4 {
        nodes: vec![Node4::from_children(
            &(0..4)
                .map(|i| (prims[i], ChildRef::leaf(i as u32, 1)))
                .collect::<Vec<_>>(),
        )],
        prim_indices: vec![0, 1, 2, 3],
        bounds: Aabb::new(Vec3::ZERO, Vec3::new(7.0, 1.0, 1.0)),
    };
    for coords in [Coords::Relative, Coords::Modulo] {
        let (c, _) = compress4_topdown(&m, &params(coords, 6)).unwrap();
        assert_eq!(c.root_ctx.scales(), [-3, -5, -5]);
        assert_eq!(c.root_ctx.aabb().max, Vec3::new(7.125, 1.03125, 1.03125));
        let s = c.nodes[0].slots[1];
        let hi = if coords == Coords::Relative {
            [24, 32, 32] // s - 1
        } else {
            [25, 33, 33] // l mod 64
        };
        assert_eq!((s.lo, s.hi, s.leaf, s.ptr), ([16, 0, 0], hi, true, 1));
        assert_eq!(
            c.prim_ids,
            vec![LEAF_END, 1 | LEAF_END, 2 | LEAF_END, 3 | LEAF_END]
        );
        let d = c.decode_to_mbvh4().unwrap();
        assert_eq!(
            d.nodes[0].child_aabb(1),
            Aabb::new(Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.125, 1.03125, 1.03125))
        );
        // The streaming encoder of one node writes the same bits.
        let (b, st) = compress4_bottomup(&m, &cfg(coords, 6, 1)).unwrap();
        assert_eq!(b, c);
        assert_eq!(st.backtrack_steps, 0);
    }
}

#[test]
fn top_down_and_streaming_trees_decode_conservatively() {
    for (seed, flat) in [(1u64, false), (2, true)] {
        let prims = soup(3000, seed, flat);
        let bin = bvh::BinnedSahBuilder::default().build(&prims).unwrap();
        let topdown = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
        let hl = crate::study::paper_lbvh().build_highlevel(&prims).unwrap();
        let (streamed, _) = bvh::stream_collapse(&hl).unwrap();
        for (name, m) in [
            ("collapse", bvh::collapse(&bin).unwrap()),
            ("topdown", topdown),
            ("stream", streamed),
        ] {
            for bits in [3, 6, 8] {
                let differ = check_tree(&m, &prims, bits);
                println!("{name} flat {flat} bits {bits}: {differ} boxes differ");
            }
        }
    }
}

/// The exact tree each encoder compressed: the decoded boxes' parametric intervals
/// enclose the exact boxes' ([P3] §5.5's criterion) on rays through every child.
#[test]
fn decoded_intervals_enclose_the_exact_ones() {
    let prims = soup(1500, 4, false);
    let m = bvh::collapse(&bvh::LbvhBuilder::default().build(&prims).unwrap()).unwrap();
    let (c, _) = compress4_bottomup(&m, &cfg(Coords::Modulo, 6, 2)).unwrap();
    let d = c.decode_to_mbvh4().unwrap();
    let o = Vec3::new(-70.0, 20.0, 150.0);
    for (x, y) in m.nodes.iter().zip(&d.nodes) {
        for s in 0..WIDTH {
            if x.children[s].is_empty() {
                continue;
            }
            let dir = x.child_aabb(s).center() - o;
            assert!(interval_encloses(
                o,
                dir,
                0.0,
                f32::INFINITY,
                &x.child_aabb(s),
                &y.child_aabb(s)
            ));
        }
    }
}

/// Behind the streaming collapse: the encoder's tree has the collapse's topology, encloses
/// the top-down compression of the collapse's tree, equals [`compress4_bottomup`] of it
/// bit for bit after decoding, and holds at most four subtrees per open subtree of the
/// collapse (greedy rule); the backtracking counts fall with modulo coordinates and with
/// treelets as for pairs.
#[test]
fn behind_the_streaming_collapse() {
    let prims = soup(20000, 9, false);
    let hl = crate::study::paper_lbvh().build_highlevel(&prims).unwrap();
    let mut steps = Vec::new();
    for coords in [Coords::Relative, Coords::Modulo] {
        for m in 1..=3 {
            for window in [None, Some(3)] {
                let sc = match window {
                    None => StreamCollapse::new(),
                    Some(w) => StreamCollapse::with_window(w),
                };
                let c = cfg(coords, 6, m);
                let (t, st, exact) = compress_stream_collapse(&hl, sc.clone(), &c).unwrap();
                let (want, _) = bvh::stream_collapse_with(&hl, sc).unwrap();
                assert_eq!(exact, want);
                assert_eq!(st.nodes_written as usize, exact.nodes.len());
                let d = check_decodes(&t, &exact, &prims);
                let (td, _) = compress4_topdown(&exact, &c.params).unwrap();
                assert_eq!(not_enclosing(&d, &td.decode_to_mbvh4().unwrap()), 0);
                let (bu, bst) = compress4_bottomup(&exact, &c).unwrap();
                assert_eq!(d, bu.decode_to_mbvh4().unwrap());
                assert_eq!(bst.nodes_written, st.nodes_written);
                if window.is_none() {
                    let (_, sc) = bvh::stream_collapse(&hl).unwrap();
                    assert!(
                        st.max_stack <= 4 * sc.max_open(),
                        "{} held, {} open",
                        st.max_stack,
                        sc.max_open()
                    );
                    steps.push(st.backtrack_steps);
                }
            }
        }
    }
    // Relative 1..3, modulo 1..3.
    assert!(steps[0] > 0, "{steps:?}");
    assert!(steps[3] < steps[0], "{steps:?}");
    assert!(steps[1] <= steps[0] && steps[2] <= steps[1], "{steps:?}");
    assert!(steps[4] <= steps[3] && steps[5] <= steps[4], "{steps:?}");
}

#[test]
fn tiny_and_empty_trees() {
    for n in [0usize, 1, 2, 5] {
        let prims = soup(n, n as u64 + 3, false);
        let hl = HlbvhBuilder::default().build_highlevel(&prims).unwrap();
        let (t, _, exact) =
            compress_stream_collapse(&hl, StreamCollapse::new(), &StreamConfig::default()).unwrap();
        assert_eq!(t.nodes.len(), exact.nodes.len());
        let d = t.decode_to_mbvh4().unwrap();
        assert_eq!(d.nodes.len(), exact.nodes.len());
        if n == 0 {
            assert_eq!(t.nodes[0].slots, [Slot::EMPTY; WIDTH]);
            assert_eq!(d, Mbvh4::empty());
        } else {
            assert_eq!(validate_mbvh4(&d, &prims, n as u32), Ok(()));
        }
        let (td, _) = compress4_topdown(&exact, &Params::default()).unwrap();
        assert_eq!(td.decode_to_mbvh4().unwrap(), d);
    }
}

#[test]
fn bad_streams_are_errors() {
    let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let leaf = |i| WideChild::Leaf { first: i };
    let mut e = WideStreamEncoder::new(StreamConfig::default()).unwrap();
    // A reference to a node not pushed.
    let r = e.push(WideInput {
        boxes: [b; WIDTH],
        children: [WideChild::Node(0), leaf(0), leaf(1), leaf(2)],
    });
    assert!(matches!(r, Err(CbvhError::BadOrder(_))));
    let n = WideInput {
        boxes: [b, b, Aabb::EMPTY, Aabb::EMPTY],
        children: [leaf(0), leaf(1), WideChild::Empty, WideChild::Empty],
    };
    let mut e = WideStreamEncoder::new(StreamConfig::default()).unwrap();
    e.push(n).unwrap();
    e.push(n).unwrap();
    // Two subtrees at the end.
    assert!(matches!(e.finish(vec![]), Err(CbvhError::BadOrder(_))));
    // A node taken twice.
    let mut e = WideStreamEncoder::new(StreamConfig::default()).unwrap();
    e.push(n).unwrap();
    let mut p = n;
    p.children[2] = WideChild::Node(0);
    p.boxes[2] = b;
    e.push(p).unwrap();
    assert_eq!(e.held(), 1);
    assert!(e.push(p).is_err());
    let mut bad = n;
    bad.boxes[1].max.y = f32::NAN;
    let mut e = WideStreamEncoder::new(StreamConfig::default()).unwrap();
    assert!(matches!(e.push(bad), Err(CbvhError::BadBox { .. })));
    assert!(WideStreamEncoder::new(cfg(Coords::Relative, 9, 1)).is_err());
    assert!(WideStreamEncoder::new(cfg(Coords::Relative, 6, 0)).is_err());
}

/// A backtracking step of a 4-wide node reads and writes every line the node touches:
/// one 64-byte line at 6 bits (two 32-byte nodes per line), two for a node that
/// straddles a line at 7 bits (35 bytes).
#[test]
fn recorded_ops_cover_the_node() {
    let prims = soup(4000, 5, false);
    let hl = crate::study::paper_lbvh().build_highlevel(&prims).unwrap();
    for bits in [6, 7] {
        let mut c = cfg(Coords::Relative, bits, 1);
        c.record_ops = true;
        c.base_addr_bytes = 4096;
        let (t, st, _) = compress_stream_collapse(&hl, StreamCollapse::new(), &c).unwrap();
        // compress_stream_collapse drops the ops: replay with the encoder by hand.
        let (_, sc) = bvh::stream_collapse(&hl).unwrap();
        let mut e = WideStreamEncoder::new(c).unwrap();
        let (mut writes, mut reads, mut straddle) = (0u64, 0u64, 0u64);
        let nb = quad_bytes(bits) as u64;
        let mut count = |ops: Vec<MemOp>| {
            for op in ops {
                match op {
                    MemOp::WritePair {
                        pair,
                        addr_bytes,
                        bytes,
                    } => {
                        assert_eq!((addr_bytes, bytes as u64), (4096 + nb * pair as u64, nb));
                        writes += 1;
                    }
                    MemOp::BacktrackRead {
                        pair,
                        addr_bytes,
                        bytes,
                    } => {
                        let start = 4096 + nb * pair as u64;
                        assert_eq!(addr_bytes % 64, 0);
                        assert!(addr_bytes <= start && start + nb <= addr_bytes + bytes as u64);
                        assert!(bytes == 64 || bytes == 128);
                        straddle += u64::from(bytes == 128);
                        reads += 1;
                    }
                    MemOp::BacktrackWrite { .. } => {}
                }
            }
        };
        for n in sc.written() {
            e.push(input_of_node4(n)).unwrap();
            count(e.drain_ops());
        }
        e.end_stream().unwrap();
        count(e.drain_ops());
        assert_eq!(writes, t.nodes.len() as u64);
        assert_eq!(reads, st.backtrack_steps);
        assert!(reads > 0);
        assert_eq!(straddle > 0, bits == 7, "{straddle}");
    }
}

fn any_prims() -> impl Strategy<Value = Vec<Aabb>> {
    proptest::collection::vec(crate::codec::tests::any_box(), 1..150)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(40))]
    /// Random boxes of every magnitude, every coordinate kind and N: every encoder's
    /// decoded tree encloses the exact one, and the streaming ones enclose top-down's.
    #[test]
    fn every_encoder_encloses(prims in any_prims(), bits in 3u32..=8, min_e in prop_oneof![Just(-30i32), Just(-126), Just(-8)]) {
        let m = Mbvh4TopDownBuilder::default().build(&prims).unwrap();
        for coords in ALL_COORDS {
            let mut c = cfg(coords, bits, 2);
            c.params.min_scale_exp = min_e;
            let (td, _) = compress4_topdown(&m, &c.params).unwrap();
            let dtd = check_decodes(&td, &m, &prims);
            let (bu, _) = compress4_bottomup(&m, &c).unwrap();
            let dbu = check_decodes(&bu, &m, &prims);
            if !coords.shares_planes() {
                prop_assert_eq!(not_enclosing(&dbu, &dtd), 0);
            }
        }
        let hl = crate::study::paper_lbvh().build_highlevel(&prims).unwrap();
        for sc in [StreamCollapse::new(), StreamCollapse::with_window(1)] {
            let (t, _, exact) = compress_stream_collapse(&hl, sc, &cfg(Coords::Modulo, bits, 1)).unwrap();
            check_decodes(&t, &exact, &prims);
        }
    }
}
