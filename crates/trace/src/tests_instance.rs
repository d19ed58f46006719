//! Two-level instancing (`instance::InstanceAccel`): closest and any hits equal brute force
//! over every instance's triangles in its object space (bit for bit) and, up to the
//! rounding of the ray transform, brute force over the triangles moved into world space;
//! animated transforms and deformed bottom levels refit the top level and trace like a
//! fresh build; bad transforms are errors.

use crate::instance::{
    BottomLevel, Instance, InstanceAccel, InstanceHit, InstanceStack, Transform,
};
use crate::testutil::*;
use crate::{brute_force, Accel, Bvh2Accel, KernelOptions, Mbvh4Accel, RayStats};
use geom::{Aabb, Mat4, Quat, Ray, Triangle, Vec3};

/// Two bottom levels: a closed bumpy sphere (Bvh2 kernel) and a triangle soup (Mbvh4).
fn meshes() -> Vec<Vec<Triangle>> {
    let (pos, ix) = bumpy_sphere(2, 0.3, 4);
    vec![resolve(&pos, &ix), soup(60, 0.8, 2)]
}

fn bottom(i: usize, tris: &[Triangle]) -> BottomLevel {
    let tree = bvh::SweepSahBuilder::default()
        .build(&bvh::triangle_aabbs(tris))
        .unwrap();
    let o = KernelOptions::default();
    let accel = if i.is_multiple_of(2) {
        Accel::Bvh2(Bvh2Accel::new(tree, tris, o).unwrap())
    } else {
        Accel::Mbvh4(Mbvh4Accel::new(bvh::collapse(&tree).unwrap(), tris, o).unwrap())
    };
    BottomLevel::new(accel, tris).unwrap()
}

/// `n` transforms with rotation, non-uniform scale (0.3 to 2.3) and translation; `phase`
/// animates them.
fn transforms(n: usize, seed: u64, phase: f32) -> Vec<Transform> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| {
            let axis = r.dir().normalize();
            let angle = 6.0 * r.f32() + phase;
            let scale = Vec3::new(r.f32(), r.f32(), r.f32()) * 2.0 + Vec3::splat(0.3);
            let at = r.vec() * 12.0 + Vec3::new(phase, 0.5 * phase, 0.0);
            let m = Mat4::from_scale_rotation_translation(
                scale,
                Quat::from_axis_angle(axis, angle),
                at,
            );
            Transform::from_mat4(m).unwrap()
        })
        .collect()
}

fn scene(meshes: &[Vec<Triangle>], ts: &[Transform]) -> InstanceAccel {
    let bottoms = meshes
        .iter()
        .enumerate()
        .map(|(i, m)| bottom(i, m))
        .collect();
    let instances = ts
        .iter()
        .enumerate()
        .map(|(i, &transform)| Instance {
            bottom: (i % 3 % 2) as u32,
            transform,
        })
        .collect();
    InstanceAccel::new(bottoms, instances).unwrap()
}

/// The reference: brute force over every instance's triangles in its object space; the
/// smallest `t`, ties to the smaller instance (brute force breaks ties on prim inside).
fn brute(ray: &Ray, accel: &InstanceAccel, meshes: &[Vec<Triangle>]) -> Option<InstanceHit> {
    let mut best: Option<InstanceHit> = None;
    for (i, inst) in accel.instances().iter().enumerate() {
        let r = inst.transform.ray_to_object(ray);
        if let Some(h) = brute_force(&r, &meshes[inst.bottom as usize]) {
            if best.is_none_or(|b| h.t < b.t) {
                best = Some(InstanceHit {
                    t: h.t,
                    instance: i as u32,
                    prim: h.prim,
                    bary: h.bary,
                });
            }
        }
    }
    best
}

fn world_bounds(accel: &InstanceAccel) -> Aabb {
    accel.top().bounds()
}

/// Closest hits equal the object-space brute force bit for bit; any hits exist exactly
/// when it finds one, and are real hits. Returns the closest hits.
fn check(
    name: &str,
    accel: &InstanceAccel,
    meshes: &[Vec<Triangle>],
    rays: &[Ray],
) -> Vec<Option<InstanceHit>> {
    let mut stack = InstanceStack::new();
    let mut stats = RayStats::default();
    let mut out = Vec::new();
    for (i, r) in rays.iter().enumerate() {
        let want = brute(r, accel, meshes);
        let got = accel.closest_hit(r, &mut stack, &mut stats);
        assert_eq!(got, want, "{name}: closest, ray {i}");
        let any = accel.any_hit(r, &mut stack, &mut stats);
        assert_eq!(any.is_some(), want.is_some(), "{name}: any, ray {i}");
        if let Some(h) = any {
            let inst = accel.instances()[h.instance as usize];
            let tri = &meshes[inst.bottom as usize][h.prim as usize];
            let obj = inst.transform.ray_to_object(r);
            let pre = geom::RayPrecomp::new(&obj);
            let again = geom::intersect_triangle_watertight(&pre, tri, obj.t_min, obj.t_max);
            assert_eq!(
                again.map(|x| x.t),
                Some(h.t),
                "{name}: any-hit is a real hit, ray {i}"
            );
        }
        out.push(got);
    }
    assert_eq!(stats.rays, 2 * rays.len() as u64);
    let hits = out.iter().flatten().count();
    assert!(hits > rays.len() / 5, "{name}: only {hits} hits");
    out
}

/// Against brute force over the triangles moved into world space: the same instance and
/// triangle, at the same distance up to rounding, for all but a few rays grazing an edge.
fn check_world_space(
    accel: &InstanceAccel,
    meshes: &[Vec<Triangle>],
    rays: &[Ray],
    got: &[Option<InstanceHit>],
) {
    let mut world = Vec::new();
    let mut owner = Vec::new();
    for (i, inst) in accel.instances().iter().enumerate() {
        for (p, tri) in meshes[inst.bottom as usize].iter().enumerate() {
            world.push(inst.transform.triangle_to_world(tri));
            owner.push((i as u32, p as u32));
        }
    }
    let mut differ = 0;
    for (r, g) in rays.iter().zip(got) {
        let w = brute_force(r, &world);
        let same = match (w, g) {
            (None, None) => true,
            (Some(w), Some(g)) => {
                owner[w.prim as usize] == (g.instance, g.prim)
                    && (w.t - g.t).abs() <= 1e-4 * w.t.abs().max(1.0)
            }
            _ => false,
        };
        differ += !same as usize;
    }
    assert!(
        differ * 200 <= rays.len(),
        "{differ} of {} rays differ from world-space brute force",
        rays.len()
    );
}

#[test]
fn instances_match_brute_force_in_object_and_world_space() {
    let meshes = meshes();
    let ts = transforms(40, 3, 0.0);
    let accel = scene(&meshes, &ts);
    let b = world_bounds(&accel);
    let rays = random_rays(3000, b.center(), b.extent().max_element() * 0.5, 17);
    let got = check("static", &accel, &meshes, &rays);
    check_world_space(&accel, &meshes, &rays, &got);
}

#[test]
fn animated_instances_refit_like_a_fresh_build() {
    let meshes = meshes();
    let mut accel = scene(&meshes, &transforms(30, 5, 0.0));
    for (frame, phase) in [0.4f32, 1.3, 2.0].into_iter().enumerate() {
        let ts = transforms(30, 5, phase);
        accel.set_transforms(&ts).unwrap();
        let fresh = scene(&meshes, &ts);
        let b = world_bounds(&fresh);
        let rays = random_rays(
            1500,
            b.center(),
            b.extent().max_element() * 0.5,
            frame as u64,
        );
        let got = check(&format!("frame {frame}"), &accel, &meshes, &rays);
        let want = check(&format!("fresh {frame}"), &fresh, &meshes, &rays);
        assert_eq!(
            got, want,
            "frame {frame}: refitted and fresh top levels differ"
        );
        check_world_space(&accel, &meshes, &rays, &got);
    }
    // A deformed bottom level: refit it, and the top level follows its new box.
    let mut moved = meshes.clone();
    for t in moved[0].iter_mut() {
        for v in t.v.iter_mut() {
            *v = Vec3::new(v.x * 1.8, v.y + 0.4 * (v.x * 3.0).sin(), v.z);
        }
    }
    assert!(accel.refit_bottom(0, &moved[0]).unwrap());
    let b = world_bounds(&accel);
    let rays = random_rays(1500, b.center(), b.extent().max_element() * 0.5, 99);
    check("deformed", &accel, &moved, &rays);
    accel.rebuild().unwrap();
    check("rebuilt", &accel, &moved, &rays);
}

#[test]
fn transforms_and_their_errors() {
    // Round trip through the inverse.
    let mut r = Rng::new(1);
    for t in transforms(20, 8, 0.0) {
        for _ in 0..20 {
            let p = r.vec() * 10.0;
            let back = t.point_to_object(t.point_to_world(p));
            assert!((back - p).length() < 1e-4, "{p} -> {back}");
        }
    }
    let id = Transform::new(Transform::IDENTITY.matrix()).unwrap();
    assert_eq!(id, Transform::IDENTITY);
    // Non-finite, singular, nearly singular, projective: errors naming the problem.
    let mut m = Transform::IDENTITY.matrix();
    m[1][3] = f32::NAN;
    assert!(Transform::new(m)
        .unwrap_err()
        .to_string()
        .contains("non-finite"));
    let mut m = Transform::IDENTITY.matrix();
    m[2] = [1.0, 0.0, 0.0, 5.0]; // row 2 equals row 0
    assert!(Transform::new(m)
        .unwrap_err()
        .to_string()
        .contains("singular"));
    let mut m = Transform::IDENTITY.matrix();
    m[2] = [1.0, 0.0, 1e-9, 0.0]; // nearly parallel to row 0
    assert!(Transform::new(m).is_err());
    let mut m = Transform::IDENTITY.matrix();
    m[2][2] = 1e-40; // invertible, but the inverse overflows f32
    assert!(Transform::new(m)
        .unwrap_err()
        .to_string()
        .contains("not finite"));
    let mut m = Transform::IDENTITY.matrix();
    m[0][0] = f32::INFINITY;
    assert!(Transform::new(m).is_err());
    // Tiny but well-conditioned scales are fine.
    assert!(Transform::from_mat4(Mat4::from_scale(Vec3::splat(1e-3))).is_ok());
    let mut p = Mat4::IDENTITY;
    p.w_axis.w = 2.0;
    p.x_axis.w = 1.0;
    assert!(Transform::from_mat4(p)
        .unwrap_err()
        .to_string()
        .contains("not affine"));

    // Instances naming a missing bottom level, transform lists of the wrong length and
    // bottom levels over another triangle list are refused.
    let meshes = meshes();
    let inst = Instance {
        bottom: 2,
        transform: Transform::IDENTITY,
    };
    let bottoms = vec![bottom(0, &meshes[0])];
    assert!(InstanceAccel::new(bottoms.clone(), vec![inst]).is_err());
    let mut accel = InstanceAccel::new(bottoms, vec![Instance { bottom: 0, ..inst }]).unwrap();
    assert!(accel.set_transforms(&[]).is_err());
    assert!(accel.refit_bottom(1, &meshes[0]).is_err());
    assert!(accel.refit_bottom(0, &meshes[0][1..]).is_err());
    let b = bottom(0, &meshes[0]);
    assert!(BottomLevel::new(b.accel().clone(), &meshes[1]).is_err());

    // No instances, and an instance of an empty bottom level: nothing is hit.
    let mut stack = InstanceStack::new();
    let mut stats = RayStats::default();
    let ray = Ray::new(Vec3::splat(-5.0), Vec3::ONE);
    let none = InstanceAccel::new(vec![], vec![]).unwrap();
    assert!(none.closest_hit(&ray, &mut stack, &mut stats).is_none());
    let empty = BottomLevel::new(
        Accel::Bvh2(Bvh2Accel::new(bvh::Bvh2::empty(), &[], KernelOptions::default()).unwrap()),
        &[],
    )
    .unwrap();
    let one = InstanceAccel::new(vec![empty], vec![Instance { bottom: 0, ..inst }]).unwrap();
    assert!(one.closest_hit(&ray, &mut stack, &mut stats).is_none());
    // A NaN ray hits nothing.
    let nan = Ray::new(Vec3::splat(f32::NAN), Vec3::ONE);
    assert!(accel.closest_hit(&nan, &mut stack, &mut stats).is_none());
}
