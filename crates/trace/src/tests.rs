//! Kernel correctness: every kernel over every tree agrees with brute force, bit for bit,
//! and closed meshes are watertight under traversal.

use crate::testutil::*;
use crate::{brute_force, Hit, Query, RayStats, TraversalStack, Traverse};
use geom::{Ray, Triangle, Vec3};

/// Traces `rays` through `accel` and compares each closest hit with `expected` exactly
/// (same primitive, same `t` bit for bit); returns the summed counters.
fn check_against<T: Traverse>(
    name: &str,
    accel: &T,
    rays: &[Ray],
    expected: &[Option<Hit>],
) -> RayStats {
    let mut stack = TraversalStack::new();
    let mut stats = RayStats::default();
    for (i, (ray, want)) in rays.iter().zip(expected).enumerate() {
        let got = accel.closest_hit(ray, &mut stack, &mut stats);
        let key = |h: &Option<Hit>| h.map(|h| (h.prim, h.t.to_bits()));
        assert_eq!(key(&got), key(want), "{name}: ray {i} {ray:?}");
        // Occlusion agrees with the closest hit's existence.
        let mut s = RayStats::default();
        let occ = accel.trace_observed(ray, Query::Any, &mut stack, &mut s, &mut ());
        assert_eq!(occ.is_some(), want.is_some(), "{name}: any-hit of ray {i}");
        if let Some(o) = occ {
            // The any-hit is a real hit within the range.
            assert!(o.t >= ray.t_min && o.t <= ray.t_max);
        }
    }
    assert_eq!(stats.rays, rays.len() as u64);
    stats
}

/// Random rays around `tris` with their brute-force closest hits and the hit count.
fn brute_force_case(
    tris: &[Triangle],
    rays: usize,
    seed: u64,
) -> (Vec<Ray>, Vec<Option<Hit>>, usize) {
    let b = tris
        .iter()
        .fold(geom::Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = random_rays(rays, b.center(), b.extent().max_element() * 0.6, seed);
    let expected: Vec<Option<Hit>> = rays.iter().map(|r| brute_force(r, tris)).collect();
    let hits = expected.iter().filter(|h| h.is_some()).count();
    // The ray set exercises both outcomes.
    assert!(
        hits > rays.len() / 10 && hits < rays.len(),
        "{hits} of {}",
        rays.len()
    );
    (rays, expected, hits)
}

fn agree_with_brute_force(tris: &[Triangle], rays: usize, seed: u64) {
    let (rays, expected, hits) = brute_force_case(tris, rays, seed);
    let (b2, b4) = all_accels(tris);
    for (name, a) in &b2 {
        let s = check_against(name, a, &rays, &expected);
        assert_eq!(s.hits, hits as u64);
    }
    for (name, a) in &b4 {
        let s = check_against(name, a, &rays, &expected);
        assert_eq!(s.hits, hits as u64);
    }
    for (name, a) in &all_mbvh8(tris) {
        let s = check_against(name, a, &rays, &expected);
        assert_eq!(s.hits, hits as u64);
    }
}

/// 100K random rays on a random soup: every builder, both widths, both kernels, the
/// same closest hit as brute force.
#[test]
fn soup_matches_brute_force() {
    agree_with_brute_force(&soup(1500, 1.5, 11), 100_000, 1);
}

/// A closed bumpy sphere and a flat axis-aligned grid (ties on shared edges, flat boxes).
#[test]
fn closed_and_flat_meshes_match_brute_force() {
    let (p, t) = bumpy_sphere(3, 0.2, 5);
    agree_with_brute_force(&resolve(&p, &t), 30_000, 2);
    agree_with_brute_force(&flat_grid(24), 30_000, 3);
}

/// Every CBVH encoder variant of [`all_cbvh`] (top-down, bottom-up and the emitter stream,
/// relative and modulo coordinates, treelet depths 1-4, 3 to 8 bits, three minimum scales,
/// two source trees): the same closest hit as brute force, bit for bit, on a soup, a closed
/// mesh and a flat axis-aligned grid (whose boxes are flat on one axis).
#[test]
fn cbvh_matches_brute_force() {
    let (p, t) = bumpy_sphere(3, 0.2, 5);
    for (tris, rays, seed) in [
        (soup(1500, 1.5, 11), 20_000, 1),
        (resolve(&p, &t), 10_000, 2),
        (flat_grid(24), 10_000, 3),
    ] {
        let (rays, expected, hits) = brute_force_case(&tris, rays, seed);
        for (name, a) in &all_cbvh(&tris) {
            let s = check_against(name, a, &rays, &expected);
            assert_eq!(s.hits, hits as u64);
        }
    }
}

/// Compressed 4-wide trees (`cbvh::wide`, issue 18 part 2): every encoder (top-down and
/// streaming, behind the greedy and windowed streaming collapses and over the offline
/// collapse), relative, modulo and plane-sharing coordinates, 3 and 6 bits, treelets of 1
/// and 3: the tree the compressed nodes decode to, traced by the 4-wide kernel, gives the
/// brute-force closest hit, bit for bit, on a soup, a closed mesh and a flat grid.
#[test]
fn cbvh4_matches_brute_force() {
    use cbvh::bottomup::StreamConfig;
    use cbvh::{Coords, Params};
    let (p, t) = bumpy_sphere(3, 0.2, 5);
    for (tris, rays, seed) in [
        (soup(1500, 1.5, 11), 8_000, 1),
        (resolve(&p, &t), 4_000, 2),
        (flat_grid(24), 4_000, 3),
    ] {
        let (rays, expected, hits) = brute_force_case(&tris, rays, seed);
        let prims = bvh::triangle_aabbs(&tris);
        let hl = cbvh::study::paper_lbvh().build_highlevel(&prims).unwrap();
        let offline =
            bvh::collapse(&bvh::BinnedSahBuilder::default().build(&prims).unwrap()).unwrap();
        let mut trees = Vec::new();
        for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
            for (bits, treelet) in [(6, 1), (3, 3)] {
                let cfg = StreamConfig {
                    params: Params {
                        bits,
                        coords,
                        ..Params::default()
                    },
                    treelet_depth: treelet,
                    ..StreamConfig::default()
                };
                let name = format!("{coords:?}/{bits} bits/treelet {treelet}");
                for (rule, sc) in [
                    ("greedy", bvh::StreamCollapse::new()),
                    ("window 2", bvh::StreamCollapse::with_window(2)),
                ] {
                    let (c, _, _) = cbvh::compress_stream_collapse(&hl, sc, &cfg).unwrap();
                    trees.push((format!("stream {rule}/{name}"), c));
                }
                let td = cbvh::compress4_topdown(&offline, &cfg.params).unwrap().0;
                trees.push((format!("topdown offline/{name}"), td));
                let bu = cbvh::compress4_bottomup(&offline, &cfg).unwrap().0;
                trees.push((format!("bottomup offline/{name}"), bu));
            }
        }
        for (name, c) in &trees {
            let m = c.decode_to_mbvh4().unwrap();
            let a = crate::Mbvh4Accel::new(m, &tris, Default::default()).unwrap();
            let s = check_against(name, &a, &rays, &expected);
            assert_eq!(s.hits, hits as u64);
        }
    }
}

/// The distance stack never changes a hit, and saves work: it culls entries, and tests
/// no more triangles than the plain kernel.
#[test]
fn distance_stack_culls_without_changing_hits() {
    let tris = soup(3000, 1.0, 4);
    let rays = random_rays(20_000, Vec3::ZERO, 4.0, 9);
    let (_, b4) = all_accels(&tris);
    let find = |n: &str| &b4.iter().find(|(k, _)| k == n).unwrap().1;
    let plain = find("binned+collapse/KernelOptions { distance_stack: false }");
    let dist = find("binned+collapse/KernelOptions { distance_stack: true }");
    let (mut s0, mut s1) = (RayStats::default(), RayStats::default());
    let mut st = TraversalStack::new();
    for r in &rays {
        let a = plain.closest_hit(r, &mut st, &mut s0);
        let b = dist.closest_hit(r, &mut st, &mut s1);
        assert_eq!(
            a.map(|h| (h.prim, h.t.to_bits())),
            b.map(|h| (h.prim, h.t.to_bits()))
        );
    }
    assert_eq!(s0.culled_pops, 0);
    assert!(s1.culled_pops > 0);
    assert!(s1.tri_tests <= s0.tri_tests && s1.node_visits < s0.node_visits);
    // Every push is popped or culled, or left on the stack when the ray ends.
    assert!(s1.pops + s1.culled_pops <= s1.pushes);
}

/// Rays aimed exactly at shared edges and vertices of closed meshes never pass through:
/// over 1.5M rays through Bvh2, Mbvh4 and CBVH traversal, zero misses.
///
/// Two kinds of rays, each of which must hit in exact arithmetic whatever rounding does to
/// the aimed point: rays from inside the mesh (a closed surface must be crossed to leave
/// it), and rays from outside that cross the surface transversally at the aimed edge or
/// vertex: every face around the aimed point faces the origin (or every one faces away),
/// none at a grazing angle (|cos| > 0.05), and edge points keep 1% of the edge's length
/// from its ends. Outside rays that graze a silhouette are left out: an aimed point that
/// rounding moves just outside such an edge is a true miss. The CBVH kernel (modulo
/// coordinates, bottom-up with depth-2 treelets) is held to the same standard.
#[test]
fn closed_meshes_are_watertight_under_traversal() {
    let mut misses = 0usize;
    let mut total = 0usize;
    for (seed, levels) in [(1u64, 2u32), (2, 4)] {
        let (pos, idx) = bumpy_sphere(levels, 0.3, seed);
        let tris = resolve(&pos, &idx);
        let mut faces_of_vertex = vec![Vec::new(); pos.len()];
        for (f, t) in idx.iter().enumerate() {
            for &v in t {
                faces_of_vertex[v as usize].push(f);
            }
        }
        let prims = bvh::triangle_aabbs(&tris);
        let binned = bvh::BinnedSahBuilder::default().build(&prims).unwrap();
        let cfg = cbvh::StreamConfig {
            params: cbvh::Params {
                coords: cbvh::Coords::Modulo,
                ..Default::default()
            },
            treelet_depth: 2,
            ..Default::default()
        };
        let cb = crate::CbvhAccel::new(
            &cbvh::compress_bottomup(&binned, &cfg).unwrap().0,
            &tris,
            Default::default(),
        )
        .unwrap();
        let b2 = crate::Bvh2Accel::new(binned, &tris, Default::default()).unwrap();
        let b4 = crate::Mbvh4Accel::new(
            bvh::Mbvh4TopDownBuilder::default().build(&prims).unwrap(),
            &tris,
            Default::default(),
        )
        .unwrap();
        let b8 = crate::Mbvh8Accel::from_bvh2(
            &bvh::BinnedSahBuilder::default().build(&prims).unwrap(),
            &tris,
            Default::default(),
        )
        .unwrap();
        let mut r = Rng::new(seed * 77);
        let mut stack = TraversalStack::new();
        let mut stats = RayStats::default();
        let centre = Vec3::new(0.5, -0.25, 0.125);
        let mut k = 0usize;
        let mut made = 0;
        while made < 250_000 {
            k += 1;
            let t = idx[k % idx.len()];
            let (ia, ib) = (t[k % 3] as usize, t[(k + 1) % 3] as usize);
            let (a, b) = (pos[ia], pos[ib]);
            // A vertex, or a point on an edge shared with a neighbour.
            let vertex = k.is_multiple_of(4);
            let target = if vertex {
                a
            } else {
                a.lerp(b, 0.01 + 0.98 * r.f32())
            };
            let o = if k.is_multiple_of(2) {
                let o = target + r.dir().normalize() * 10.0;
                // The faces around the aimed point: all of a's for a vertex, the two
                // that share the edge otherwise.
                let around = faces_of_vertex[ia]
                    .iter()
                    .filter(|&&f| vertex || idx[f].contains(&(ib as u32)));
                let cosines =
                    around.map(|&f| tris[f].normal().normalize().dot((o - target).normalize()));
                let (lo, hi) = cosines.fold((1f32, -1f32), |(l, h), c| (l.min(c), h.max(c)));
                if !(lo > 0.05 || hi < -0.05) {
                    continue;
                }
                o
            } else {
                centre + r.vec() * 0.5
            };
            made += 1;
            let ray = Ray::new(o, target - o);
            total += 3;
            let m2 = b2.closest_hit(&ray, &mut stack, &mut stats).is_none();
            let m4 = b4.closest_hit(&ray, &mut stack, &mut stats).is_none();
            let m8 = b8.closest_hit(&ray, &mut stack, &mut stats).is_none();
            let mc = cb.closest_hit(&ray, &mut stack, &mut stats).is_none();
            misses += m2 as usize + m4 as usize + m8 as usize + mc as usize;
        }
    }
    assert!(total >= 1_500_000);
    assert_eq!(misses, 0, "{misses} of {total} rays slipped through");
}

/// Degenerate input: the empty tree, a single triangle, NaN and zero-direction rays.
#[test]
fn tiny_trees_and_bad_rays() {
    let none: Vec<Triangle> = Vec::new();
    let e = crate::Bvh2Accel::new(bvh::Bvh2::empty(), &none, Default::default()).unwrap();
    let mut st = TraversalStack::new();
    let mut s = RayStats::default();
    assert!(e
        .closest_hit(&Ray::new(Vec3::ZERO, Vec3::X), &mut st, &mut s)
        .is_none());
    assert_eq!(s.box_tests, 0);
    let one = vec![Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)];
    let t = bvh::SweepSahBuilder::default()
        .build(&bvh::triangle_aabbs(&one))
        .unwrap();
    let a = crate::Bvh2Accel::new(t.clone(), &one, Default::default()).unwrap();
    let m = crate::Mbvh4Accel::new(bvh::collapse(&t).unwrap(), &one, Default::default()).unwrap();
    let hit = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
    assert_eq!(a.closest_hit(&hit, &mut st, &mut s).unwrap().prim, 0);
    assert_eq!(m.closest_hit(&hit, &mut st, &mut s).unwrap().prim, 0);
    for bad in [
        Ray::new(Vec3::splat(f32::NAN), -Vec3::Z),
        Ray::new(Vec3::new(0.2, 0.2, 1.0), Vec3::splat(f32::NAN)),
        Ray::new(Vec3::new(0.2, 0.2, 1.0), Vec3::ZERO),
    ] {
        assert!(a.closest_hit(&bad, &mut st, &mut s).is_none());
        assert!(m.closest_hit(&bad, &mut st, &mut s).is_none());
    }
    // A tree over triangles that are not there is refused.
    assert!(crate::Bvh2Accel::new(t, &none, Default::default()).is_err());
}

/// Rays that start on surfaces far from the world origin (the bounce rays of a path
/// tracer): coplanar, overlapping and axis-aligned triangles at coordinates near 1000,
/// origins on the triangles themselves (offset and not offset), every kernel equals brute
/// force. Near the origin the triangle test's distance has an absolute error of about an
/// ulp of the coordinates; without the own-box condition of a hit, the kernels and brute
/// force disagree on such rays (as they did on Conference).
#[test]
fn rays_leaving_surfaces_far_from_the_origin_match_brute_force() {
    let mut r = Rng::new(31);
    let base = Vec3::new(1350.0, -1.5, -340.0);
    let mut tris = Vec::new();
    for i in 0..400 {
        let p = base + r.vec() * Vec3::new(40.0, 2.0, 40.0);
        let (a, b) = (r.vec() * 3.0, r.vec() * 3.0);
        let t = match i % 4 {
            // Flat in y (floors), often overlapping each other.
            0 | 1 => Triangle::new(
                p,
                p + Vec3::new(a.x, 0.0, a.z),
                p + Vec3::new(b.x, 0.0, b.z),
            ),
            // A coplanar duplicate, shifted within its plane.
            2 => {
                let q = tris
                    .last()
                    .copied()
                    .unwrap_or(Triangle::new(p, p + a, p + b));
                let s = Vec3::new(0.3, 0.0, -0.2);
                Triangle::new(q.v[0] + s, q.v[1] + s, q.v[2] + s)
            }
            _ => Triangle::new(p, p + a, p + b),
        };
        tris.push(t);
    }
    let mut rays = Vec::new();
    for k in 0..20_000 {
        let t = &tris[k % tris.len()];
        let (u, v) = (r.f32(), r.f32());
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        let p = t.v[0] * (1.0 - u - v) + t.v[1] * u + t.v[2] * v;
        let n = t.normal().normalize_or_zero();
        if n == Vec3::ZERO {
            continue;
        }
        let n = if r.f32() < 0.5 { n } else { -n };
        let d = crate::sampling::cosine_hemisphere(n, r.f32(), r.f32());
        let o = if k % 2 == 0 {
            p
        } else {
            crate::sampling::offset_origin(p, n)
        };
        rays.push(Ray::new(o, d));
    }
    let expected: Vec<Option<Hit>> = rays.iter().map(|ray| brute_force(ray, &tris)).collect();
    assert!(expected.iter().filter(|h| h.is_some()).count() > rays.len() / 20);
    let (b2, b4) = all_accels(&tris);
    for (name, a) in &b2 {
        check_against(name, a, &rays, &expected);
    }
    for (name, a) in &b4 {
        check_against(name, a, &rays, &expected);
    }
    for (name, a) in &all_mbvh8(&tris) {
        check_against(name, a, &rays, &expected);
    }
    for (name, a) in all_cbvh(&tris).iter().step_by(5) {
        check_against(name, a, &rays, &expected);
    }
}

/// A batch (`Traverse::trace_batch`, which the binary and 4-wide kernels trace one ray
/// after the other with the traversal inlined in the loop) answers every ray once, with
/// the hit and counters of the one-ray trace, for both queries, on every tree and setting.
#[test]
fn batches_of_the_binary_and_4_wide_kernels_trace_each_ray_as_alone() {
    fn check<T: Traverse>(name: &str, accel: &T, rays: &[Ray]) {
        let mut stack = TraversalStack::new();
        for q in [Query::Closest, Query::Any] {
            let mut got: Vec<Option<(Option<Hit>, RayStats)>> = vec![None; rays.len()];
            accel.trace_batch(rays, q, &mut stack, |i, h, s| {
                assert!(got[i].is_none(), "{name}: ray {i} answered twice");
                got[i] = Some((h, *s));
            });
            for (i, r) in rays.iter().enumerate() {
                let mut s = RayStats::default();
                let alone = accel.trace_observed(r, q, &mut stack, &mut s, &mut ());
                assert_eq!(got[i], Some((alone, s)), "{name} {q:?}: ray {i}");
            }
        }
    }
    let tris = soup(800, 1.5, 21);
    let mut rays = random_rays(300, Vec3::ZERO, 2.0, 8);
    rays[4].origin.y = f32::NAN;
    rays[7].t_max = 0.25;
    let (b2, b4) = all_accels(&tris);
    for (name, a) in &b2 {
        check(name, a, &rays);
    }
    for (name, a) in &b4 {
        check(name, a, &rays);
    }
}
