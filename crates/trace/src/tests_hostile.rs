//! Hostile trees: trees built in memory (not read through the validating file reader) with
//! broken links, cycles, shared subtrees, NaN or inverted boxes, leaf ranges outside the
//! leaf table, primitive ids beyond the triangles, empty and degenerate shapes. Preparing a
//! kernel over such a tree must either fail with a `TraceError` or give a kernel that
//! traces every ray to an end without a panic, visiting each node at most once per ray
//! (the bound that rules out hangs and exponential walks), and reporting only hits on real
//! triangles within the ray's range. A mutated tree that still passes its validator
//! (`bvh::validate`, `bvh::validate_mbvh4`, `bvh::validate_wide` for the 8-wide trees) must
//! trace exactly like brute force.

use crate::custom::CustomAccel;
use crate::testutil::{random_rays, soup};
use crate::{
    brute_force, Bvh2Accel, CbvhAccel, Hit, KernelOptions, Mbvh4Accel, Mbvh8Accel, Query, RayStats,
    TraceError, TraversalStack, Traverse,
};
use bvh::{Bvh2, ChildRef, Mbvh4, Node, Node4, WideBvh, WideNode};
use geom::{Aabb, Ray, Triangle, Vec3};
use proptest::prelude::*;

/// A tree format whose nodes the mutations below can edit: `W` child slots per node, each
/// with a reference and six box planes `[min x, y, z, max x, y, z]`.
trait Editable: Clone + std::fmt::Debug {
    const W: usize;
    fn nodes(&self) -> usize;
    fn child(&mut self, node: usize, slot: usize) -> &mut ChildRef;
    fn plane(&mut self, node: usize, slot: usize, plane: usize) -> &mut f32;
    fn prims(&mut self) -> &mut Vec<u32>;
    fn truncate(&mut self, nodes: usize);
}

impl Editable for Bvh2 {
    const W: usize = 2;
    fn nodes(&self) -> usize {
        self.nodes.len()
    }
    fn child(&mut self, node: usize, slot: usize) -> &mut ChildRef {
        &mut self.nodes[node].children[slot]
    }
    fn plane(&mut self, node: usize, slot: usize, plane: usize) -> &mut f32 {
        &mut self.nodes[node].bounds[slot][plane]
    }
    fn prims(&mut self) -> &mut Vec<u32> {
        &mut self.prim_indices
    }
    fn truncate(&mut self, nodes: usize) {
        self.nodes.truncate(nodes);
    }
}

impl Editable for Mbvh4 {
    const W: usize = 4;
    fn nodes(&self) -> usize {
        self.nodes.len()
    }
    fn child(&mut self, node: usize, slot: usize) -> &mut ChildRef {
        &mut self.nodes[node].children[slot]
    }
    fn plane(&mut self, node: usize, slot: usize, plane: usize) -> &mut f32 {
        let n = &mut self.nodes[node];
        let row = match plane {
            0 => &mut n.min_x,
            1 => &mut n.min_y,
            2 => &mut n.min_z,
            3 => &mut n.max_x,
            4 => &mut n.max_y,
            _ => &mut n.max_z,
        };
        &mut row[slot]
    }
    fn prims(&mut self) -> &mut Vec<u32> {
        &mut self.prim_indices
    }
    fn truncate(&mut self, nodes: usize) {
        self.nodes.truncate(nodes);
    }
}

impl Editable for WideBvh<8> {
    const W: usize = 8;
    fn nodes(&self) -> usize {
        self.nodes.len()
    }
    fn child(&mut self, node: usize, slot: usize) -> &mut ChildRef {
        &mut self.nodes[node].children[slot]
    }
    fn plane(&mut self, node: usize, slot: usize, plane: usize) -> &mut f32 {
        let b = &mut self.nodes[node].boxes[slot];
        match plane {
            0 => &mut b.min.x,
            1 => &mut b.min.y,
            2 => &mut b.min.z,
            3 => &mut b.max.x,
            4 => &mut b.max.y,
            _ => &mut b.max.z,
        }
    }
    fn prims(&mut self) -> &mut Vec<u32> {
        &mut self.prim_indices
    }
    fn truncate(&mut self, nodes: usize) {
        self.nodes.truncate(nodes);
    }
}

/// One edit of a tree. Node, slot and entry positions are taken modulo the tree's sizes
/// when applied.
#[derive(Clone, Debug)]
enum Mutation {
    /// A child's index (an inner node, a leaf's first entry, or `EMPTY_INDEX`).
    Index(usize, usize, u32),
    /// A child's leaf size (0 turns a leaf into an inner reference).
    Count(usize, usize, u32),
    /// A child removed (its box kept).
    Empty(usize, usize),
    /// A child made a reference to an existing node (self-loops, back edges, subtrees
    /// reached twice).
    Link(usize, usize, usize),
    /// One box plane set to a value (NaN, infinities, anything).
    Plane(usize, usize, usize, f32),
    /// A child box turned inside out.
    Invert(usize, usize),
    /// A leaf-table entry set to a primitive id.
    Prim(usize, u32),
    /// The leaf table cut to a length.
    CutPrims(usize),
    /// The node array cut to a length.
    CutNodes(usize),
}

fn index_value() -> impl Strategy<Value = u32> {
    prop_oneof![
        Just(0u32),
        Just(u32::MAX),
        Just(u32::MAX - 1),
        Just(1u32 << 31),
        0u32..200,
        any::<u32>(),
    ]
}

fn float_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(f32::MAX),
        Just(-f32::MAX),
        Just(0.0f32),
        -20.0f32..20.0,
        any::<f32>(),
    ]
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let (n, s) = (any::<usize>(), any::<usize>());
    prop_oneof![
        (n, s, index_value()).prop_map(|(n, s, v)| Mutation::Index(n, s, v)),
        (n, s, index_value()).prop_map(|(n, s, v)| Mutation::Count(n, s, v)),
        (n, s, 0u32..6).prop_map(|(n, s, v)| Mutation::Count(n, s, v)),
        (n, s).prop_map(|(n, s)| Mutation::Empty(n, s)),
        (n, s, any::<usize>()).prop_map(|(n, s, t)| Mutation::Link(n, s, t)),
        (n, s, 0usize..6, float_value()).prop_map(|(n, s, p, v)| Mutation::Plane(n, s, p, v)),
        (n, s).prop_map(|(n, s)| Mutation::Invert(n, s)),
        (n, index_value()).prop_map(|(e, p)| Mutation::Prim(e, p)),
        (n, 0u32..6).prop_map(|(e, p)| Mutation::Prim(e, p)),
        n.prop_map(Mutation::CutPrims),
        n.prop_map(Mutation::CutNodes),
    ]
}

impl Mutation {
    fn apply<T: Editable>(&self, t: &mut T) {
        let nodes = t.nodes();
        if nodes == 0 {
            return;
        }
        let at = |n: &usize, s: &usize| (n % nodes, s % T::W);
        match self {
            Mutation::Index(n, s, v) => {
                let (n, s) = at(n, s);
                t.child(n, s).index = *v;
            }
            Mutation::Count(n, s, v) => {
                let (n, s) = at(n, s);
                t.child(n, s).count = *v;
            }
            Mutation::Empty(n, s) => {
                let (n, s) = at(n, s);
                *t.child(n, s) = ChildRef::EMPTY;
            }
            Mutation::Link(n, s, target) => {
                let (n, s) = at(n, s);
                *t.child(n, s) = ChildRef::inner((target % nodes) as u32);
            }
            Mutation::Plane(n, s, p, v) => {
                let (n, s) = at(n, s);
                *t.plane(n, s, *p) = *v;
            }
            Mutation::Invert(n, s) => {
                let (n, s) = at(n, s);
                for a in 0..3 {
                    let lo = *t.plane(n, s, a);
                    let hi = *t.plane(n, s, a + 3);
                    *t.plane(n, s, a) = hi;
                    *t.plane(n, s, a + 3) = lo;
                }
            }
            Mutation::Prim(e, p) => {
                let prims = t.prims();
                if !prims.is_empty() {
                    let len = prims.len();
                    prims[e % len] = *p;
                }
            }
            Mutation::CutPrims(len) => {
                let prims = t.prims();
                let keep = len % (prims.len() + 1);
                prims.truncate(keep);
            }
            Mutation::CutNodes(len) => t.truncate(len % (nodes + 1)),
        }
    }
}

/// The scene every property test mutates: a triangle soup, rays around it, and their
/// brute-force hits.
struct Scene {
    tris: Vec<Triangle>,
    rays: Vec<Ray>,
    expected: Vec<Option<Hit>>,
}

fn scene(seed: u64) -> Scene {
    let tris = soup(48, 1.5, seed);
    let b = tris.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let mut rays = random_rays(24, b.center(), b.extent().max_element() * 0.6, seed + 1);
    // Axis-parallel rays (zero direction components: infinite reciprocals).
    rays.push(Ray::new(b.center() - Vec3::X * 20.0, Vec3::X));
    rays.push(Ray::new(b.center() + Vec3::Z * 20.0, -Vec3::Z));
    let expected = rays.iter().map(|r| brute_force(r, &tris)).collect();
    Scene {
        tris,
        rays,
        expected,
    }
}

/// Traces every ray of `s` through `a` (both queries) and checks the guarantees of a
/// prepared kernel: each node visited at most once per ray, every hit a real hit of an
/// existing triangle in the ray's range, and (when `exact`) the brute-force hits.
fn trace_all<T: Traverse>(name: &str, a: &T, s: &Scene, exact: bool) {
    let mut stack = TraversalStack::new();
    for (i, ray) in s.rays.iter().enumerate() {
        for query in [Query::Closest, Query::Any] {
            let mut st = RayStats::default();
            let hit = a.trace_observed(ray, query, &mut stack, &mut st, &mut ());
            assert!(
                st.node_visits <= a.node_count() as u64,
                "{name}: ray {i} visited {} nodes of {}",
                st.node_visits,
                a.node_count()
            );
            if let Some(h) = hit {
                assert!((h.prim as usize) < s.tris.len(), "{name}: ray {i} {h:?}");
                assert!(
                    h.t >= ray.t_min && h.t <= ray.t_max,
                    "{name}: ray {i} {h:?}"
                );
                let own = geom::intersect_triangle_watertight(
                    &geom::RayPrecomp::new(ray),
                    &s.tris[h.prim as usize],
                    ray.t_min,
                    ray.t_max,
                );
                assert!(own.is_some(), "{name}: ray {i} reports a miss as {h:?}");
            }
            if exact {
                let key = |h: &Option<Hit>| h.map(|h| (h.prim, h.t.to_bits()));
                match query {
                    Query::Closest => {
                        assert_eq!(key(&hit), key(&s.expected[i]), "{name}: ray {i}")
                    }
                    Query::Any => assert_eq!(hit.is_some(), s.expected[i].is_some()),
                }
            }
        }
    }
}

/// Prepares a kernel with `make`; on success traces everything (also after an in-place
/// refit over the same triangles, and over too few). A valid tree must be accepted.
fn check_kernel<T: Traverse>(
    name: &str,
    made: Result<T, TraceError>,
    s: &Scene,
    valid: bool,
    refit: impl Fn(&mut T, &[Triangle]) -> Result<(), TraceError>,
) {
    let mut a = match made {
        Ok(a) => a,
        Err(e) => {
            assert!(!valid, "{name}: a valid tree was refused: {e}");
            // The error says what is wrong.
            assert!(!e.to_string().is_empty());
            return;
        }
    };
    trace_all(name, &a, s, valid);
    if refit(&mut a, &s.tris).is_ok() {
        trace_all(&format!("{name} refitted"), &a, s, valid);
    }
    assert!(refit(&mut a, &s.tris[..s.tris.len() / 2]).is_err());
}

fn opts() -> [KernelOptions; 2] {
    [false, true].map(|d| KernelOptions { distance_stack: d })
}

fn bvh2_of(s: &Scene) -> Bvh2 {
    bvh::SweepSahBuilder {
        max_leaf_size: 4,
        ..Default::default()
    }
    .build(&bvh::triangle_aabbs(&s.tris))
    .unwrap()
}

/// Every kernel over the binary tree `t` (mutated): `Bvh2Accel`, and the custom-primitive
/// tree with a triangle callback that tolerates any id.
fn check_bvh2(t: &Bvh2, s: &Scene) {
    let prims = bvh::triangle_aabbs(&s.tris);
    let valid = bvh::validate(t, &prims, u32::MAX).is_ok();
    for o in opts() {
        let made = Bvh2Accel::new(t.clone(), &s.tris, o);
        check_kernel("bvh2", made, s, valid, |a, t| a.refit(t));
    }
    let Ok(c) = CustomAccel::new(t.clone()) else {
        assert!(!valid, "custom: a valid tree was refused");
        return;
    };
    let mut stack = TraversalStack::new();
    for (i, ray) in s.rays.iter().enumerate() {
        let mut st = RayStats::default();
        let tri = |p: u32, r: &Ray, t_max: f32| {
            let t = s.tris.get(p as usize)?;
            let pre = geom::RayPrecomp::new(r);
            geom::intersect_triangle_watertight(&pre, t, r.t_min, t_max).map(|h| (h.t, ()))
        };
        let hit = c.closest_hit(ray, &mut stack, &mut st, tri);
        assert!(st.node_visits <= t.nodes.len() as u64, "custom: ray {i}");
        if valid {
            assert_eq!(hit.map(|h| h.prim), s.expected[i].map(|h| h.prim));
        }
        c.any_hit(ray, &mut stack, &mut st, tri);
    }
}

fn check_mbvh4(t: &Mbvh4, s: &Scene) {
    let prims = bvh::triangle_aabbs(&s.tris);
    let valid = bvh::validate_mbvh4(t, &prims, u32::MAX).is_ok();
    for o in opts() {
        let made = Mbvh4Accel::new(t.clone(), &s.tris, o);
        check_kernel("mbvh4", made, s, valid, |a, t| a.refit(t));
    }
}

fn check_mbvh8(t: &WideBvh<8>, s: &Scene) {
    let prims = bvh::triangle_aabbs(&s.tris);
    let valid = bvh::validate_wide(t, &prims, u32::MAX).is_ok();
    for o in opts() {
        let made = Mbvh8Accel::new(t.clone(), &s.tris, o);
        let sse = made.as_ref().ok().map(|a| a.clone().without_avx());
        let avx2 = made.as_ref().ok().map(|a| a.clone().without_avx512());
        check_kernel("mbvh8", made, s, valid, |a, t| a.refit(t));
        if let Some(sse) = sse {
            check_kernel("mbvh8/sse", Ok(sse), s, valid, |a, t| a.refit(t));
        }
        if let Some(avx2) = avx2 {
            check_kernel("mbvh8/avx2", Ok(avx2), s, valid, |a, t| a.refit(t));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(192))]

    /// Random edits of valid binary trees.
    #[test]
    fn mutated_bvh2_trees_never_panic(seed in 0u64..4, edits in proptest::collection::vec(mutation(), 1..4)) {
        let s = scene(seed);
        let mut t = bvh2_of(&s);
        for m in &edits {
            m.apply(&mut t);
        }
        check_bvh2(&t, &s);
    }

    /// Random edits of valid 4-wide trees.
    #[test]
    fn mutated_mbvh4_trees_never_panic(seed in 0u64..4, edits in proptest::collection::vec(mutation(), 1..4)) {
        let s = scene(seed);
        let mut t = bvh::collapse(&bvh2_of(&s)).unwrap();
        for m in &edits {
            m.apply(&mut t);
        }
        check_mbvh4(&t, &s);
    }

    /// Random edits of valid 8-wide trees.
    #[test]
    fn mutated_mbvh8_trees_never_panic(seed in 0u64..4, edits in proptest::collection::vec(mutation(), 1..4)) {
        let s = scene(seed);
        let mut t = bvh::Collapse::default().collapse_wide::<8>(&bvh2_of(&s)).unwrap();
        for m in &edits {
            m.apply(&mut t);
        }
        check_mbvh8(&t, &s);
    }
}

#[test]
fn unmutated_trees_trace_like_brute_force() {
    let s = scene(9);
    let t = bvh2_of(&s);
    check_bvh2(&t, &s);
    check_mbvh4(&bvh::collapse(&t).unwrap(), &s);
    let w = bvh::Collapse::default().collapse_wide::<8>(&t).unwrap();
    bvh::validate_wide(&w, &bvh::triangle_aabbs(&s.tris), u32::MAX).unwrap();
    check_mbvh8(&w, &s);
}

/// A box around every triangle of `s`.
fn all_box(s: &Scene) -> Aabb {
    s.tris.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb()))
}

/// Node `i` of a chain of `n` nodes whose both children are node `i + 1` (the last one
/// holds a leaf of every triangle): 2^n root-to-leaf paths over n nodes.
fn doubling_chain(s: &Scene, n: usize) -> Bvh2 {
    let b = all_box(s);
    let mut nodes: Vec<Node> = (0..n - 1)
        .map(|i| {
            let c = ChildRef::inner(i as u32 + 1);
            Node::new(&b, c, &b, c)
        })
        .collect();
    let leaf = ChildRef::leaf(0, s.tris.len() as u32);
    nodes.push(Node::new(&b, leaf, &Aabb::EMPTY, ChildRef::EMPTY));
    Bvh2 {
        nodes,
        prim_indices: (0..s.tris.len() as u32).collect(),
        bounds: b,
    }
}

#[test]
fn shared_subtrees_are_refused() {
    // Tracing this would take 2^64 node visits per ray: it must be refused up front.
    let s = scene(3);
    let t = doubling_chain(&s, 64);
    for o in opts() {
        assert!(matches!(
            Bvh2Accel::new(t.clone(), &s.tris, o),
            Err(TraceError::BadTree(_))
        ));
    }
    assert!(matches!(
        CustomAccel::new(t.clone()),
        Err(TraceError::BadTree(_))
    ));
    let b = all_box(&s);
    let w = WideBvh::<8> {
        nodes: (0..64u32)
            .map(|i| WideNode {
                boxes: [b; 8],
                children: [if i == 63 {
                    ChildRef::leaf(0, 1)
                } else {
                    ChildRef::inner(i + 1)
                }; 8],
            })
            .collect(),
        prim_indices: (0..s.tris.len() as u32).collect(),
        bounds: b,
    };
    assert!(Mbvh8Accel::new(w, &s.tris, KernelOptions::default()).is_err());
    let m = Mbvh4 {
        nodes: (0..64u32)
            .map(|i| {
                let c = if i == 63 {
                    ChildRef::leaf(0, 1)
                } else {
                    ChildRef::inner(i + 1)
                };
                Node4 {
                    min_x: [b.min.x; 4],
                    min_y: [b.min.y; 4],
                    min_z: [b.min.z; 4],
                    max_x: [b.max.x; 4],
                    max_y: [b.max.y; 4],
                    max_z: [b.max.z; 4],
                    children: [c; 4],
                }
            })
            .collect(),
        prim_indices: (0..s.tris.len() as u32).collect(),
        bounds: b,
    };
    assert!(Mbvh4Accel::new(m, &s.tris, KernelOptions::default()).is_err());
}

#[test]
fn leaves_sharing_entries_cannot_inflate_the_packing() {
    // Every child of a wide chain is a leaf of the whole leaf table: packing them would
    // copy the table once per leaf (here 8 x 4096 leaves of 48 triangles).
    let s = scene(4);
    let b = all_box(&s);
    let n = 4096u32;
    let all = ChildRef::leaf(0, s.tris.len() as u32);
    let w = WideBvh::<8> {
        nodes: (0..n)
            .map(|i| {
                let mut children = [all; 8];
                if i + 1 < n {
                    children[0] = ChildRef::inner(i + 1);
                }
                WideNode {
                    boxes: [b; 8],
                    children,
                }
            })
            .collect(),
        prim_indices: (0..s.tris.len() as u32).collect(),
        bounds: b,
    };
    assert!(Mbvh8Accel::new(w, &s.tris, KernelOptions::default()).is_err());
}

#[test]
fn an_empty_slot_with_a_box_is_never_entered() {
    // An absent child whose box is a real box (not the empty box): the wide kernels read
    // which slots are in use off the boxes, so without care they would enter the absent
    // child, node `EMPTY_INDEX`.
    let s = scene(5);
    let t = bvh2_of(&s);
    let mut m = bvh::collapse(&t).unwrap();
    let mut w = bvh::Collapse::default().collapse_wide::<8>(&t).unwrap();
    let b = all_box(&s);
    for n in &mut m.nodes {
        for k in 0..4 {
            if n.children[k].is_empty() || k == 3 {
                n.children[k] = ChildRef::EMPTY;
                (n.min_x[k], n.min_y[k], n.min_z[k]) = (b.min.x, b.min.y, b.min.z);
                (n.max_x[k], n.max_y[k], n.max_z[k]) = (b.max.x, b.max.y, b.max.z);
            }
        }
    }
    for n in &mut w.nodes {
        for k in 0..8 {
            if n.children[k].is_empty() || k == 7 {
                n.children[k] = ChildRef::EMPTY;
                n.boxes[k] = b;
            }
        }
    }
    check_mbvh4(&m, &s);
    check_mbvh8(&w, &s);
    // Same for the binary tree: its kernel masks empty slots by their references.
    let mut t2 = t.clone();
    t2.nodes[0].children[1] = ChildRef::EMPTY;
    check_bvh2(&t2, &s);
}

#[test]
fn deep_trees_trace_without_overflow() {
    // A valid chain of 20,000 nodes, each with one triangle as a leaf and the rest of
    // the chain as its inner child: the stack grows as deep as the tree.
    let tris = soup(20_000, 0.5, 11);
    let n = tris.len();
    let boxes = bvh::triangle_aabbs(&tris);
    // Suffix unions: node i holds triangle i and the chain below.
    let mut below = vec![Aabb::EMPTY; n + 1];
    for i in (0..n).rev() {
        below[i] = below[i + 1].union(boxes[i]);
    }
    let nodes: Vec<Node> = (0..n - 1)
        .map(|i| {
            let rest = if i + 1 == n - 1 {
                ChildRef::leaf(n as u32 - 1, 1)
            } else {
                ChildRef::inner(i as u32 + 1)
            };
            Node::new(&boxes[i], ChildRef::leaf(i as u32, 1), &below[i + 1], rest)
        })
        .collect();
    let t = Bvh2 {
        nodes,
        prim_indices: (0..n as u32).collect(),
        bounds: below[0],
    };
    bvh::validate(&t, &boxes, 1).unwrap();
    let s = Scene {
        rays: random_rays(8, below[0].center(), 6.0, 2),
        expected: Vec::new(),
        tris,
    };
    let s = Scene {
        expected: s.rays.iter().map(|r| brute_force(r, &s.tris)).collect(),
        ..s
    };
    let a = Bvh2Accel::new(t.clone(), &s.tris, KernelOptions::default()).unwrap();
    trace_all("deep bvh2", &a, &s, true);
    let c = cbvh::compress_topdown(&t, &cbvh::Params::default())
        .unwrap()
        .0;
    let a = CbvhAccel::new(&c, &s.tris, KernelOptions::default()).unwrap();
    trace_all("deep cbvh", &a, &s, true);
}

#[test]
fn empty_trees_and_missing_triangles() {
    let s = scene(6);
    let none: Vec<Triangle> = Vec::new();
    let empty = Bvh2::empty();
    // An empty tree traces (to no hit) over no triangles and over some.
    for tris in [&none, &s.tris] {
        let a = Bvh2Accel::new(empty.clone(), tris, KernelOptions::default()).unwrap();
        let sc = Scene {
            tris: tris.clone(),
            rays: s.rays.clone(),
            expected: vec![None; s.rays.len()],
        };
        trace_all("empty", &a, &sc, true);
        let m = bvh::collapse(&empty).unwrap();
        let a = Mbvh4Accel::new(m, tris, KernelOptions::default()).unwrap();
        trace_all("empty4", &a, &sc, true);
        let a = Mbvh8Accel::from_bvh2(&empty, tris, KernelOptions::default()).unwrap();
        trace_all("empty8", &a, &sc, true);
    }
    // No nodes at all.
    let mut rootless = empty.clone();
    rootless.nodes.clear();
    assert!(Bvh2Accel::new(rootless.clone(), &none, KernelOptions::default()).is_err());
    assert!(CustomAccel::new(rootless).is_err());
    // A tree over triangles given none of them.
    let t = bvh2_of(&s);
    assert!(matches!(
        Bvh2Accel::new(t, &none, KernelOptions::default()),
        Err(TraceError::PrimitiveOutOfRange { .. })
    ));
}

#[test]
fn self_loops_and_back_edges_are_refused() {
    let s = scene(7);
    let t = bvh2_of(&s);
    let inner = t.nodes[0]
        .children
        .iter()
        .position(ChildRef::is_inner)
        .unwrap();
    for target in [0u32, t.nodes[0].children[inner].index] {
        let mut b = t.clone();
        let k = t.nodes[0].children[inner].index as usize;
        b.nodes[k].children[0] = ChildRef::inner(target.min(k as u32));
        assert!(Bvh2Accel::new(b.clone(), &s.tris, KernelOptions::default()).is_err());
        assert!(CustomAccel::new(b).is_err());
    }
}

/// A random edit of a compressed tree.
#[derive(Clone, Debug)]
enum CbvhEdit {
    Ptr(usize, usize, u32),
    Leaf(usize, usize, bool),
    Coord(usize, usize, usize, u8),
    PrimId(usize, u32),
    CutPrims(usize),
    CutPairs(usize),
    Root(u32),
    RootCtx(usize, bool, f32),
    RootScale(usize, i32),
}

fn cbvh_edit() -> impl Strategy<Value = CbvhEdit> {
    let (n, s) = (any::<usize>(), any::<usize>());
    let ptr = prop_oneof![
        Just(0u32),
        Just(cbvh::format::EMPTY_PTR),
        Just(cbvh::format::MAX_PTR),
        0u32..200,
        0u32..(1 << 27)
    ];
    prop_oneof![
        (n, s, ptr.clone()).prop_map(|(n, s, p)| CbvhEdit::Ptr(n, s, p)),
        (n, s, any::<bool>()).prop_map(|(n, s, l)| CbvhEdit::Leaf(n, s, l)),
        (n, s, 0usize..6, any::<u8>()).prop_map(|(n, s, c, v)| CbvhEdit::Coord(n, s, c, v)),
        (n, index_value()).prop_map(|(e, p)| CbvhEdit::PrimId(e, p)),
        (n, 0u32..4).prop_map(|(e, p)| CbvhEdit::PrimId(e, p | cbvh::format::LEAF_END)),
        n.prop_map(CbvhEdit::CutPrims),
        n.prop_map(CbvhEdit::CutPairs),
        ptr.prop_map(CbvhEdit::Root),
        (0usize..3, any::<bool>(), float_value()).prop_map(|(a, h, v)| CbvhEdit::RootCtx(a, h, v)),
        (0usize..3, prop_oneof![any::<i32>(), -140i32..140])
            .prop_map(|(a, e)| CbvhEdit::RootScale(a, e)),
    ]
}

impl CbvhEdit {
    fn apply(&self, c: &mut cbvh::Cbvh) {
        fn slot<'a>(c: &'a mut cbvh::Cbvh, n: &usize, s: &usize) -> Option<&'a mut cbvh::Slot> {
            let len = c.pairs.len();
            (len > 0).then(|| &mut c.pairs[n % len].slots[s % 2])
        }
        let bits = c.params.bits;
        match self {
            CbvhEdit::Ptr(n, s, p) => {
                if let Some(sl) = slot(c, n, s) {
                    sl.ptr = *p;
                }
            }
            CbvhEdit::Leaf(n, s, l) => {
                if let Some(sl) = slot(c, n, s) {
                    sl.leaf = *l;
                }
            }
            CbvhEdit::Coord(n, s, k, v) => {
                if let Some(sl) = slot(c, n, s) {
                    let v = (*v as u32 & ((1u32 << bits) - 1)) as u8;
                    if *k < 3 {
                        sl.lo[*k] = v;
                    } else {
                        sl.hi[*k - 3] = v;
                    }
                }
            }
            CbvhEdit::PrimId(e, p) => {
                if !c.prim_ids.is_empty() {
                    let len = c.prim_ids.len();
                    c.prim_ids[e % len] = *p;
                }
            }
            CbvhEdit::CutPrims(len) => {
                let keep = len % (c.prim_ids.len() + 1);
                c.prim_ids.truncate(keep);
            }
            CbvhEdit::CutPairs(len) => {
                let keep = len % (c.pairs.len() + 1);
                c.pairs.truncate(keep);
            }
            CbvhEdit::Root(r) => c.root = *r,
            CbvhEdit::RootScale(a, e) => c.root_ctx.axes[*a].e = *e,
            CbvhEdit::RootCtx(a, hi, v) => {
                let ax = &mut c.root_ctx.axes[*a];
                if *hi {
                    ax.hi = *v
                } else {
                    ax.lo = *v
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(192))]

    /// Random edits of valid compressed trees (top-down encoder, relative and modulo
    /// coordinates).
    #[test]
    fn mutated_cbvhs_never_panic(
        seed in 0u64..4,
        modulo in any::<bool>(),
        edits in proptest::collection::vec(cbvh_edit(), 1..4),
    ) {
        let s = scene(seed);
        let params = cbvh::Params {
            coords: if modulo { cbvh::Coords::Modulo } else { cbvh::Coords::Relative },
            ..Default::default()
        };
        let mut c = cbvh::compress_topdown(&bvh2_of(&s), &params).unwrap().0;
        for e in &edits {
            e.apply(&mut c);
        }
        for o in opts() {
            if let Ok(a) = CbvhAccel::new(&c, &s.tris, o) {
                trace_all("cbvh", &a, &s, false);
            }
        }
    }
}
