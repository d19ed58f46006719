//! Custom primitives (`custom::CustomAccel`): closest and any hits over random spheres
//! equal brute force over the same callback, for every binary builder's tree, before and
//! after a refit; malformed trees are refused and bad rays hit nothing.

use crate::custom::CustomAccel;
use crate::testutil::*;
use crate::{Query, RayStats, TraversalStack};
use geom::{Aabb, Ray, Vec3};

/// A sphere: center and radius.
#[derive(Clone, Copy, Debug)]
struct Sphere {
    center: Vec3,
    radius: f32,
}

impl Sphere {
    fn aabb(&self) -> Aabb {
        Aabb::new(
            self.center - Vec3::splat(self.radius),
            self.center + Vec3::splat(self.radius),
        )
    }

    /// The nearer crossing of the ray in `[t_min, t_max]` (the far one from inside).
    fn hit(&self, ray: &Ray, t_max: f32) -> Option<f32> {
        let oc = ray.origin - self.center;
        let a = ray.dir.dot(ray.dir);
        let b = oc.dot(ray.dir);
        let c = oc.dot(oc) - self.radius * self.radius;
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        [(-b - s) / a, (-b + s) / a]
            .into_iter()
            .find(|&t| t >= ray.t_min && t <= t_max)
    }
}

fn spheres(n: usize, seed: u64) -> Vec<Sphere> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| Sphere {
            center: r.vec() * 5.0,
            radius: 0.05 + 0.4 * r.f32(),
        })
        .collect()
}

/// Brute force: every sphere, the smallest `t`, ties to the smaller index.
fn brute(ray: &Ray, s: &[Sphere]) -> Option<(u32, f32)> {
    let mut best: Option<(u32, f32)> = None;
    for (i, sp) in s.iter().enumerate() {
        if let Some(t) = sp.hit(ray, ray.t_max) {
            if best.is_none_or(|(_, bt)| t < bt) {
                best = Some((i as u32, t));
            }
        }
    }
    best
}

/// Closest hits equal brute force; any hits are real hits and found exactly when brute
/// force finds one. Returns the closest-hit count.
fn check(name: &str, accel: &CustomAccel, s: &[Sphere], rays: &[Ray]) -> usize {
    let mut stack = TraversalStack::new();
    let mut stats = RayStats::default();
    let mut calls = 0u64;
    let mut f = |prim: u32, ray: &Ray, t_max: f32| {
        calls += 1;
        s[prim as usize].hit(ray, t_max).map(|t| (t, prim * 10))
    };
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let want = brute(r, s);
        let got = accel.closest_hit(r, &mut stack, &mut stats, &mut f);
        assert_eq!(
            got.map(|h| (h.prim, h.t.to_bits())),
            want.map(|(p, t)| (p, t.to_bits())),
            "{name}: closest, ray {i}"
        );
        if let Some(h) = got {
            assert_eq!(h.data, h.prim * 10, "{name}: the callback's data");
            hits += 1;
        }
        let any = accel.any_hit(r, &mut stack, &mut stats, &mut f);
        assert_eq!(any.is_some(), want.is_some(), "{name}: any, ray {i}");
        if let Some(h) = any {
            let t = s[h.prim as usize].hit(r, r.t_max);
            assert_eq!(t, Some(h.t), "{name}: any-hit is a real hit, ray {i}");
        }
    }
    assert_eq!(stats.rays, 2 * rays.len() as u64);
    assert_eq!(
        stats.tri_tests, calls,
        "{name}: every callback call counted"
    );
    // The tree saves work: far fewer calls than brute force's.
    assert!(
        calls < (2 * rays.len() * s.len() / 4) as u64,
        "{name}: {calls} calls"
    );
    hits
}

#[test]
fn custom_spheres_match_brute_force_on_every_tree() {
    let s = spheres(300, 5);
    let boxes: Vec<Aabb> = s.iter().map(Sphere::aabb).collect();
    let rays = random_rays(2000, Vec3::ZERO, 5.0, 9);
    let trees = [
        ("sweep-sah", bvh::SweepSahBuilder::default().build(&boxes)),
        ("binned-sah", bvh::BinnedSahBuilder::default().build(&boxes)),
        ("lbvh", bvh::LbvhBuilder::default().build(&boxes)),
    ];
    for (name, tree) in trees {
        let accel = CustomAccel::new(tree.unwrap()).unwrap();
        let hits = check(name, &accel, &s, &rays);
        assert!(hits > rays.len() / 5, "{name}: only {hits} hits");
    }
}

#[test]
fn custom_refit_follows_moved_primitives() {
    let s = spheres(200, 3);
    let boxes: Vec<Aabb> = s.iter().map(Sphere::aabb).collect();
    let mut accel =
        CustomAccel::new(bvh::SweepSahBuilder::default().build(&boxes).unwrap()).unwrap();
    let moved: Vec<Sphere> = s
        .iter()
        .map(|sp| Sphere {
            center: sp.center * 0.7 + Vec3::new((sp.center.y * 2.0).sin(), 0.5, 0.0),
            radius: sp.radius * 1.2,
        })
        .collect();
    let moved_boxes: Vec<Aabb> = moved.iter().map(Sphere::aabb).collect();
    accel.refit(&moved_boxes).unwrap();
    check(
        "refit",
        &accel,
        &moved,
        &random_rays(1500, Vec3::ZERO, 4.0, 1),
    );
    // A box list of another length is refused.
    assert!(accel.refit(&moved_boxes[1..]).is_err());
}

#[test]
fn custom_edge_cases() {
    let s = spheres(50, 8);
    let boxes: Vec<Aabb> = s.iter().map(Sphere::aabb).collect();
    let tree = bvh::SweepSahBuilder::default().build(&boxes).unwrap();
    let accel = CustomAccel::new(tree.clone()).unwrap();
    let mut stack = TraversalStack::new();
    let mut stats = RayStats::default();
    let always = |_: u32, _: &Ray, t_max: f32| Some((t_max.min(1.0), ()));
    // Non-finite rays hit nothing, and the callback is never asked.
    let never = |_: u32, _: &Ray, _: f32| -> Option<(f32, ())> { unreachable!() };
    for r in [
        Ray::new(Vec3::splat(f32::NAN), Vec3::X),
        Ray::new(Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0)),
    ] {
        assert!(accel
            .trace(&r, Query::Closest, &mut stack, &mut stats, &mut { never })
            .is_none());
    }
    // A callback answering outside the range, or NaN, is ignored.
    let r = Ray::with_range(Vec3::splat(-9.0), Vec3::ONE, 0.5, 30.0);
    for bad in [f32::NAN, 0.25, 31.0, f32::INFINITY] {
        let f = |_: u32, _: &Ray, _: f32| Some((bad, ()));
        assert!(accel.closest_hit(&r, &mut stack, &mut stats, f).is_none());
    }
    // Ties go to the smaller primitive index, whatever the visiting order: eight copies
    // of one sphere.
    let copies = [s[0]; 8];
    let copy_boxes: Vec<Aabb> = copies.iter().map(Sphere::aabb).collect();
    let dup = CustomAccel::new(bvh::LbvhBuilder::default().build(&copy_boxes).unwrap()).unwrap();
    let toward = Ray::new(s[0].center + Vec3::new(3.0, 0.0, 0.0), -Vec3::X);
    let f = |p: u32, r: &Ray, t_max: f32| copies[p as usize].hit(r, t_max).map(|t| (t, ()));
    let tie = dup.closest_hit(&toward, &mut stack, &mut stats, f).unwrap();
    assert_eq!(tie.prim, 0);
    // An empty tree answers nothing.
    let empty = CustomAccel::new(bvh::Bvh2::empty()).unwrap();
    assert!(empty
        .closest_hit(&r, &mut stack, &mut stats, always)
        .is_none());
    assert!(empty.bounds().is_empty());
    // Malformed trees are refused.
    let mut bad = tree.clone();
    bad.nodes[0].children[0] = bvh::ChildRef::inner(0);
    assert!(CustomAccel::new(bad).is_err());
    let mut bad = tree;
    bad.prim_indices.truncate(1);
    assert!(CustomAccel::new(bad).is_err());
}
