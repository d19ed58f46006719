//! In-place refit of the prepared kernels (`Accel::refit`): after the vertices move, a
//! refitted kernel traces exactly like one prepared afresh from the tree refitted by the
//! `bvh` crate (same hits, bit for bit, and the same counters), and like brute force.

use crate::testutil::*;
use crate::{
    brute_force, Accel, Bvh2Accel, Hit, KernelOptions, Mbvh4Accel, Mbvh8Accel, Query, RayStats,
    TraversalStack, Traverse,
};
use geom::{Ray, Triangle, Vec3};

/// The sphere's vertices moved by a smooth, non-rigid warp (the topology is unchanged).
fn warp(pos: &[Vec3]) -> Vec<Vec3> {
    pos.iter()
        .map(|p| {
            Vec3::new(
                p.x * 1.3 + 0.4 * (p.y * 1.7).sin(),
                p.y * 0.8 + 0.3 * (p.z * 2.1).cos(),
                p.z + 0.5 * (p.x * 0.9).sin(),
            )
        })
        .collect()
}

/// Every ray through both kernels, closest and any hit: identical hits and counters.
fn same_traces<A: Traverse, B: Traverse>(name: &str, a: &A, b: &B, rays: &[Ray]) {
    let mut stack = TraversalStack::new();
    for (i, r) in rays.iter().enumerate() {
        for q in [Query::Closest, Query::Any] {
            let (mut sa, mut sb) = (RayStats::default(), RayStats::default());
            let ha = a.trace_observed(r, q, &mut stack, &mut sa, &mut ());
            let hb = b.trace_observed(r, q, &mut stack, &mut sb, &mut ());
            let key = |h: Option<Hit>| h.map(|h| (h.prim, h.leaf_entry, h.t.to_bits()));
            assert_eq!(key(ha), key(hb), "{name}: ray {i} {q:?}");
            assert_eq!(sa, sb, "{name}: counters of ray {i} {q:?}");
        }
    }
}

/// Closest hits equal brute force over `tris` (same primitive and `t`, bit for bit).
fn matches_brute_force<A: Traverse>(name: &str, a: &A, rays: &[Ray], tris: &[Triangle]) {
    let mut stack = TraversalStack::new();
    let mut stats = RayStats::default();
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let got = a.closest_hit(r, &mut stack, &mut stats);
        let want = brute_force(r, tris);
        let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits()));
        assert_eq!(key(got), key(want), "{name}: ray {i}");
        hits += got.is_some() as usize;
    }
    assert!(hits > rays.len() / 10, "{name}: only {hits} hits");
}

#[test]
fn refit_in_place_traces_like_a_fresh_kernel() {
    let (pos, ix) = bumpy_sphere(3, 0.3, 7);
    let before = resolve(&pos, &ix);
    let moved_pos = warp(&pos);
    let after = resolve(&moved_pos, &ix);
    let prims = bvh::triangle_aabbs(&after);
    let b = after
        .iter()
        .fold(geom::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = random_rays(400, b.center(), b.extent().max_element() * 0.6, 11);
    for (name, tree) in all_bvh2(&before) {
        let mut refitted = tree.clone();
        bvh::refit_bvh2(&mut refitted, &prims).unwrap();
        let wide = bvh::collapse(&tree).unwrap();
        let mut wide_refitted = wide.clone();
        bvh::refit_mbvh4(&mut wide_refitted, &prims).unwrap();
        for d in [false, true] {
            let o = KernelOptions { distance_stack: d };
            let mut a = Bvh2Accel::new(tree.clone(), &before, o).unwrap();
            a.refit(&after).unwrap();
            let fresh = Bvh2Accel::new(refitted.clone(), &after, o).unwrap();
            same_traces(&format!("{name}/bvh2/{d}"), &a, &fresh, &rays);
            matches_brute_force(&format!("{name}/bvh2/{d}"), &a, &rays, &after);

            let mut a = Mbvh4Accel::new(wide.clone(), &before, o).unwrap();
            a.refit(&after).unwrap();
            let fresh = Mbvh4Accel::new(wide_refitted.clone(), &after, o).unwrap();
            same_traces(&format!("{name}/mbvh4/{d}"), &a, &fresh, &rays);

            // The 8-wide collapse has no refit in `bvh`; brute force is its reference.
            let mut a = Mbvh8Accel::from_bvh2(&tree, &before, o).unwrap();
            a.refit(&after).unwrap();
            matches_brute_force(&format!("{name}/mbvh8/{d}"), &a, &rays, &after);
        }
    }
}

#[test]
fn refit_through_accel_and_its_errors() {
    let (pos, ix) = bumpy_sphere(2, 0.2, 3);
    let before = resolve(&pos, &ix);
    let after = resolve(&warp(&pos), &ix);
    let tree = bvh::BinnedSahBuilder::default()
        .build(&bvh::triangle_aabbs(&before))
        .unwrap();
    let o = KernelOptions::default();
    let mut a = Accel::Bvh2(Bvh2Accel::new(tree.clone(), &before, o).unwrap());
    // A list of another length is refused and changes nothing.
    assert!(a.refit(&after[1..]).is_err());
    assert!(a.refit(&after).unwrap());
    let b = after
        .iter()
        .fold(geom::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = random_rays(200, b.center(), b.extent().max_element() * 0.6, 5);
    matches_brute_force("accel", &a, &rays, &after);
    // Refitting back to the first positions gives the first kernel again.
    assert!(a.refit(&before).unwrap());
    let first = Bvh2Accel::new(tree, &before, o).unwrap();
    same_traces("back", &a, &first, &rays);
    // A CBVH is not refitted in place.
    let mut c = Accel::Cbvh(all_cbvh(&before).swap_remove(0).1);
    assert!(!c.refit(&after).unwrap());
}
