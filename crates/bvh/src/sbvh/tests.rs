use super::*;
use crate::testutil::Rng;
use crate::{sah_cost, validate, validate_spatial, BinnedSahBuilder, ValidationError};

/// `n` small random triangles in a cube of side 100, plus `long` long thin ones that
/// cross it diagonally: the case spatial splits are for.
fn slivers(n: usize, long: usize, seed: u64) -> Vec<Triangle> {
    let mut r = Rng::new(seed);
    let mut t: Vec<Triangle> = (0..n)
        .map(|_| {
            let a = r.point(100.0);
            Triangle::new(a, a + r.point(2.0), a + r.point(2.0))
        })
        .collect();
    for _ in 0..long {
        let a = r.point(100.0) * Vec3::new(0.1, 1.0, 1.0);
        let b = Vec3::new(90.0 + 10.0 * r.f32(), 100.0 * r.f32(), 100.0 * r.f32());
        t.push(Triangle::new(a, b, a + r.point(1.0) + Vec3::splat(0.5)));
    }
    t
}

/// Every leaf's box and the triangles it names.
fn leaves(t: &Bvh2) -> Vec<(Aabb, Vec<u32>)> {
    let mut out = Vec::new();
    for n in &t.nodes {
        for s in 0..2 {
            let c = n.children[s];
            if c.is_leaf() {
                let r = c.index as usize..(c.index + c.count) as usize;
                out.push((n.child_aabb(s), t.prim_indices[r].to_vec()));
            }
        }
    }
    out
}

/// Points on each triangle (vertices, edge crossings of the leaves' planes and random
/// barycentric points, in f64) each lie in the box of some leaf that names the triangle.
fn assert_covered(t: &Bvh2, tris: &[Triangle], samples: usize, seed: u64) {
    let mut boxes: Vec<Vec<Aabb>> = vec![Vec::new(); tris.len()];
    for (b, prims) in leaves(t) {
        for p in prims {
            boxes[p as usize].push(b);
        }
    }
    let mut r = Rng::new(seed);
    let inside =
        |b: &Aabb, p: [f64; 3]| (0..3).all(|a| b.min[a] as f64 <= p[a] && p[a] <= b.max[a] as f64);
    for (i, tri) in tris.iter().enumerate() {
        let v = tri.v.map(|v| [v.x as f64, v.y as f64, v.z as f64]);
        let mut points: Vec<[f64; 3]> = v.to_vec();
        for _ in 0..samples {
            let (mut u, mut w) = (r.f32() as f64, r.f32() as f64);
            if u + w > 1.0 {
                (u, w) = (1.0 - u, 1.0 - w);
            }
            points.push(std::array::from_fn(|a| {
                v[0][a] + (v[1][a] - v[0][a]) * u + (v[2][a] - v[0][a]) * w
            }));
        }
        // The points where the edges cross the planes of the leaf boxes naming it.
        for b in &boxes[i] {
            for e in 0..3 {
                let (p, q) = (v[e], v[(e + 1) % 3]);
                for a in 0..3 {
                    for plane in [b.min[a] as f64, b.max[a] as f64] {
                        let (lo, hi) = (p[a].min(q[a]), p[a].max(q[a]));
                        if lo < plane && plane < hi {
                            let s = (plane - p[a]) / (q[a] - p[a]);
                            let mut x: [f64; 3] = std::array::from_fn(|c| p[c] + (q[c] - p[c]) * s);
                            x[a] = plane;
                            points.push(x);
                        }
                    }
                }
            }
        }
        for p in points {
            assert!(
                boxes[i].iter().any(|b| inside(b, p)),
                "triangle {i}: point {p:?} is in no leaf box that names it ({} boxes)",
                boxes[i].len()
            );
        }
    }
}

fn build(tris: &[Triangle], alpha: f32, growth: f32) -> Bvh2 {
    SbvhBuilder {
        alpha,
        max_growth: growth,
        ..Default::default()
    }
    .build(tris)
    .unwrap()
}

#[test]
fn splits_references_and_covers_every_triangle() {
    let tris = slivers(2000, 150, 3);
    let prims = crate::triangle_aabbs(&tris);
    for alpha in [0.0, 1e-5] {
        let t = build(&tris, alpha, 1.0);
        validate_spatial(&t, &prims, 8).unwrap();
        assert!(
            t.prim_indices.len() > tris.len(),
            "alpha {alpha}: no reference was split ({} entries)",
            t.prim_indices.len()
        );
        assert!(t.prim_indices.len() <= 2 * tris.len() + 64);
        // A tree with split references is not a tree of each primitive once.
        assert!(matches!(
            validate(&t, &prims, 8),
            Err(ValidationError::LeafTableLength { .. })
        ));
        assert_covered(&t, &tris, 8, 11);
    }
}

#[test]
fn beats_binned_sah_where_long_triangles_cross_the_scene() {
    let tris = slivers(4000, 300, 5);
    let prims = crate::triangle_aabbs(&tris);
    let binned = BinnedSahBuilder::default().build(&prims).unwrap();
    let s = build(&tris, 1e-5, 1.0);
    let (cb, cs) = (sah_cost(&binned), sah_cost(&s));
    assert!(cs < 0.9 * cb, "SBVH SAH {cs} not 10% below binned {cb}");
}

#[test]
fn no_growth_means_no_spatial_split() {
    let tris = slivers(1500, 100, 7);
    let prims = crate::triangle_aabbs(&tris);
    let t = build(&tris, 0.0, 0.0);
    validate(&t, &prims, 8).unwrap();
    // A small budget is kept (up to rounding of the children's shares).
    let t = build(&tris, 0.0, 0.1);
    validate_spatial(&t, &prims, 8).unwrap();
    assert!(t.prim_indices.len() > tris.len());
    assert!(t.prim_indices.len() <= tris.len() + tris.len() / 10 + 64);
}

#[test]
fn same_tree_for_any_thread_count() {
    let tris = slivers(12000, 600, 9);
    let b = |threads| {
        SbvhBuilder {
            threads,
            ..Default::default()
        }
        .build(&tris)
        .unwrap()
    };
    assert_eq!(b(1), b(2));
}

#[test]
fn cut_parts_are_conservative_and_on_their_side() {
    let mut r = Rng::new(21);
    for i in 0..3000 {
        let s = if i % 3 == 0 { 1e4 } else { 10.0 };
        let tri = Triangle::new(r.point(s), r.point(s), r.point(s));
        let within = tri.aabb();
        let axis = i % 3;
        let plane = within.min[axis] + (within.max[axis] - within.min[axis]) * r.f32();
        let (lo, hi) = cut(&tri, &within, axis, plane);
        assert!(lo.is_empty() || lo.max[axis] <= plane);
        assert!(hi.is_empty() || hi.min[axis] >= plane);
        assert!(within.contains(&lo) || lo.is_empty());
        assert!(within.contains(&hi) || hi.is_empty());
        // The exact edge crossings (in f64) lie in both parts.
        let v = tri.v.map(|v| [v.x as f64, v.y as f64, v.z as f64]);
        for e in 0..3 {
            let (p, q) = (v[e], v[(e + 1) % 3]);
            let pl = plane as f64;
            if (p[axis] < pl && q[axis] > pl) || (p[axis] > pl && q[axis] < pl) {
                let t = (pl - p[axis]) / (q[axis] - p[axis]);
                for part in [&lo, &hi] {
                    for c in 0..3 {
                        let x = if c == axis {
                            pl
                        } else {
                            p[c] + (q[c] - p[c]) * t
                        };
                        assert!(
                            part.min[c] as f64 <= x && x <= part.max[c] as f64,
                            "case {i}: crossing {x} outside part {part:?} on axis {c}"
                        );
                    }
                }
            }
        }
        // Each vertex is in the part of its side.
        for vtx in tri.v {
            if vtx[axis] <= plane {
                assert!(lo.contains_point(vtx), "case {i}");
            }
            if vtx[axis] >= plane {
                assert!(hi.contains_point(vtx), "case {i}");
            }
        }
    }
}

#[test]
fn small_and_degenerate_inputs() {
    assert_eq!(SbvhBuilder::default().build(&[]).unwrap(), Bvh2::empty());
    let one = [Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)];
    let t = SbvhBuilder::default().build(&one).unwrap();
    validate(&t, &crate::triangle_aabbs(&one), 8).unwrap();
    // Identical triangles (all centroids coincide), slivers of zero area and points.
    let same = vec![Triangle::new(Vec3::ZERO, Vec3::new(50.0, 1.0, 0.0), Vec3::Y); 40];
    let line: Vec<Triangle> = (0..40)
        .map(|i| {
            let a = Vec3::new(i as f32, 0.0, 0.0);
            Triangle::new(a, a + Vec3::X * 30.0, a + Vec3::X * 60.0)
        })
        .collect();
    let point = vec![Triangle::new(Vec3::ONE, Vec3::ONE, Vec3::ONE); 20];
    for (name, tris) in [("same", same), ("line", line), ("point", point)] {
        let t = build(&tris, 0.0, 1.0);
        validate_spatial(&t, &crate::triangle_aabbs(&tris), 8)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_covered(&t, &tris, 4, 1);
    }
}

#[test]
fn bad_configurations_and_inputs_are_errors() {
    let tris = slivers(10, 2, 1);
    let bad = [
        SbvhBuilder {
            max_leaf_size: 0,
            ..Default::default()
        },
        SbvhBuilder {
            bins: 1,
            ..Default::default()
        },
        SbvhBuilder {
            spatial_bins: 65,
            ..Default::default()
        },
        SbvhBuilder {
            alpha: f32::NAN,
            ..Default::default()
        },
        SbvhBuilder {
            max_growth: -1.0,
            ..Default::default()
        },
        SbvhBuilder {
            sah: SahParams {
                c_tri: f32::INFINITY,
                ..SahParams::THESIS
            },
            ..Default::default()
        },
    ];
    for b in bad {
        assert!(
            matches!(b.build(&tris), Err(BuildError::InvalidConfig(_))),
            "{b:?}"
        );
    }
    let mut nan = tris.clone();
    nan[3].v[1].y = f32::NAN;
    assert!(matches!(
        SbvhBuilder::default().build(&nan),
        Err(BuildError::NonFinite { index: 3 })
    ));
}
