//! Test geometry and rays: a deterministic RNG, closed meshes, soups, and every tree the
//! builders make over them.

use crate::{Bvh2Accel, CbvhAccel, KernelOptions, Mbvh4Accel};
use cbvh::bottomup::{compress_bottomup, compress_hlbvh, StreamConfig};
use cbvh::{compress_topdown, Coords, Params};
use geom::{Ray, Triangle, Vec3};

/// xorshift64* (tests need no RNG crate).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (x >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in [-1, 1)^3.
    pub fn vec(&mut self) -> Vec3 {
        Vec3::new(self.f32(), self.f32(), self.f32()) * 2.0 - Vec3::ONE
    }
    /// A direction (not normalized, never zero).
    pub fn dir(&mut self) -> Vec3 {
        loop {
            let v = self.vec();
            if v.length_squared() > 1e-4 {
                return v;
            }
        }
    }
}

/// An indexed closed mesh: a subdivided icosahedron with vertices displaced radially by up
/// to `bump` (relative) and rotated, so that edges are not axis-aligned.
pub fn bumpy_sphere(levels: u32, bump: f32, seed: u64) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut pos: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        let mut midpoint = |a: u32, b: u32, pos: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                pos.push(((pos[a as usize] + pos[b as usize]) * 0.5).normalize());
                pos.len() as u32 - 1
            })
        };
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut pos);
            let bc = midpoint(b, c, &mut pos);
            let ca = midpoint(c, a, &mut pos);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    let mut r = Rng::new(seed);
    let rot = geom::Quat::from_axis_angle(Vec3::new(0.3, 0.8, -0.5).normalize(), 1.1);
    for p in pos.iter_mut() {
        *p = rot * (*p * (1.0 + bump * r.f32())) * 3.0 + Vec3::new(0.5, -0.25, 0.125);
    }
    (pos, tris)
}

/// Resolves an indexed mesh into triangles.
pub fn resolve(pos: &[Vec3], tris: &[[u32; 3]]) -> Vec<Triangle> {
    tris.iter()
        .map(|t| Triangle::new(pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]))
        .collect()
}

/// `n` random triangles in a cube of side 10 (overlapping, of edge up to `size`).
pub fn soup(n: usize, size: f32, seed: u64) -> Vec<Triangle> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| {
            let a = r.vec() * 5.0;
            Triangle::new(a, a + r.vec() * size, a + r.vec() * size)
        })
        .collect()
}

/// A grid of `n x n` unit squares at z = 0 (axis-aligned and coplanar: many ties and flat
/// boxes), two triangles each.
pub fn flat_grid(n: u32) -> Vec<Triangle> {
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = |a: u32, b: u32| Vec3::new(a as f32, b as f32, 0.0);
            out.push(Triangle::new(p(i, j), p(i + 1, j), p(i + 1, j + 1)));
            out.push(Triangle::new(p(i, j), p(i + 1, j + 1), p(i, j + 1)));
        }
    }
    out
}

/// Random rays from a box around the scene towards random points in it (some miss).
pub fn random_rays(n: usize, center: Vec3, radius: f32, seed: u64) -> Vec<Ray> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = center + r.vec() * radius * 2.0;
            let target = center + r.vec() * radius;
            let d = if i % 7 == 0 { r.dir() } else { target - o };
            // Some rays start inside, some have a finite range.
            if i % 5 == 0 {
                Ray::with_range(o, d, 0.0, r.f32() * 2.0)
            } else {
                Ray::new(o, d)
            }
        })
        .collect()
}

/// Every Bvh2 builder of the bvh crate over `tris`, by name (the spatial-split one too).
pub fn all_bvh2(tris: &[Triangle]) -> Vec<(&'static str, bvh::Bvh2)> {
    let prims = bvh::triangle_aabbs(tris);
    vec![
        (
            "sweep",
            bvh::SweepSahBuilder::default().build(&prims).unwrap(),
        ),
        (
            "binned",
            bvh::BinnedSahBuilder::default().build(&prims).unwrap(),
        ),
        ("lbvh", bvh::LbvhBuilder::default().build(&prims).unwrap()),
        ("hlbvh", bvh::HlbvhBuilder::default().build(&prims).unwrap()),
        (
            "hlbvh+sah",
            bvh::HlbvhSahBuilder::default().build(&prims).unwrap(),
        ),
        (
            "hlbvh+atrbvh",
            bvh::HlbvhAtrbvhBuilder::default().build(&prims).unwrap(),
        ),
        (
            "atrbvh",
            bvh::AtrbvhBuilder::default().build(&prims).unwrap(),
        ),
        // Spatial splits everywhere they lower the SAH (alpha 0): leaves name parts of
        // triangles, and the kernels must still find every hit.
        (
            "sbvh",
            bvh::SbvhBuilder {
                alpha: 0.0,
                ..Default::default()
            }
            .build(tris)
            .unwrap(),
        ),
    ]
}

/// Every traversal configuration over every tree: both widths (collapse of each binary
/// tree, and the native top-down MBVH4), with and without the distance stack.
pub type Named<T> = Vec<(String, T)>;

/// Every traversal configuration over every tree (see [`all_bvh2`]).
pub fn all_accels(tris: &[Triangle]) -> (Named<Bvh2Accel>, Named<Mbvh4Accel>) {
    let mut b2 = Vec::new();
    let mut b4 = Vec::new();
    let opts = [false, true].map(|d| KernelOptions { distance_stack: d });
    for (name, t) in all_bvh2(tris) {
        let m = bvh::collapse(&t).unwrap();
        for o in opts {
            b2.push((
                format!("{name}/{o:?}"),
                Bvh2Accel::new(t.clone(), tris, o).unwrap(),
            ));
            b4.push((
                format!("{name}+collapse/{o:?}"),
                Mbvh4Accel::new(m.clone(), tris, o).unwrap(),
            ));
        }
    }
    let prims = bvh::triangle_aabbs(tris);
    let td = bvh::Mbvh4TopDownBuilder::default().build(&prims).unwrap();
    for o in opts {
        b4.push((
            format!("mbvh4-topdown/{o:?}"),
            Mbvh4Accel::new(td.clone(), tris, o).unwrap(),
        ));
    }
    (b2, b4)
}

/// The 8-wide collapse of every binary tree, with and without the distance stack.
pub fn all_mbvh8(tris: &[Triangle]) -> Named<crate::Mbvh8Accel> {
    let mut out = Vec::new();
    // Leaves of up to 48 triangles: more than a 32-bit child reference holds, so the
    // kernel's table of large leaves is used.
    let big = bvh::BinnedSahBuilder {
        max_leaf_size: 48,
        min_leaf_size: 33,
        ..Default::default()
    }
    .build(&bvh::triangle_aabbs(tris))
    .unwrap();
    let mut trees = all_bvh2(tris);
    trees.push(("big-leaves", big));
    for (name, t) in trees {
        for d in [false, true] {
            let o = KernelOptions { distance_stack: d };
            let a = crate::Mbvh8Accel::from_bvh2(&t, tris, o).unwrap();
            out.push((
                format!("{name}+collapse8/{o:?}/sse"),
                a.clone().without_avx(),
            ));
            // The AVX2 path as well where the default is the AVX-512 one.
            if a.isa() == "avx512" {
                out.push((
                    format!("{name}+collapse8/{o:?}/avx2"),
                    a.clone().without_avx512(),
                ));
            }
            out.push((format!("{name}+collapse8/{o:?}/{}", a.isa()), a));
        }
    }
    out
}

/// Compressed trees over `tris` with every encoder: top-down, bottom-up (the tree streamed
/// in postorder, and the LBVH emitter's own stream) with relative and modulo coordinates
/// and plane sharing, and treelet depths 1 to 4, coordinate bits 3 to 8 and three minimum scales, compressed
/// from the paper's LBVH ([P3] §5.2) and from a binned SAH tree; with and without the
/// distance stack. Names say tree, encoder, coordinates, treelet depth, bits and scale.
pub fn all_cbvh(tris: &[Triangle]) -> Named<CbvhAccel> {
    let prims = bvh::triangle_aabbs(tris);
    let hl = cbvh::study::paper_lbvh().build_highlevel(&prims).unwrap();
    let lbvh = hl.to_bvh2();
    let binned = bvh::BinnedSahBuilder::default().build(&prims).unwrap();
    // (tree, encoder, coords, treelet depth, bits, min scale exponent)
    let mut cases: Vec<(&str, &str, Coords, u32, u32, i32)> = Vec::new();
    for coords in [Coords::Relative, Coords::Modulo, Coords::PlaneSharing] {
        cases.push(("lbvh", "topdown", coords, 1, 6, -30));
        for m in 1..=4 {
            cases.push(("lbvh", "bottomup", coords, m, 6, -30));
        }
        cases.push(("lbvh", "emitter", coords, 1, 6, -30));
        for bits in [3, 4, 5, 7, 8] {
            cases.push(("lbvh", "bottomup", coords, 2, bits, -30));
        }
        cases.push(("lbvh", "topdown", coords, 1, 3, -30));
        cases.push(("lbvh", "bottomup", coords, 1, 6, -126));
        cases.push(("lbvh", "emitter", coords, 4, 6, -10));
        cases.push(("binned", "topdown", coords, 1, 6, -30));
        cases.push(("binned", "bottomup", coords, 3, 4, -30));
    }
    let mut out = Vec::new();
    for (k, (tree, enc, coords, m, bits, min_e)) in cases.into_iter().enumerate() {
        let params = Params {
            bits,
            min_scale_exp: min_e,
            coords,
        };
        let cfg = StreamConfig {
            params,
            treelet_depth: m,
            ..StreamConfig::default()
        };
        let src = if tree == "lbvh" { &lbvh } else { &binned };
        let (c, _) = match enc {
            "topdown" => compress_topdown(src, &params),
            "bottomup" => compress_bottomup(src, &cfg),
            _ => compress_hlbvh(&hl, &cfg),
        }
        .unwrap();
        // Alternate the distance stack over the cases.
        let o = KernelOptions {
            distance_stack: k % 2 == 1,
        };
        out.push((
            format!(
                "cbvh {tree}/{enc}/{}/{m}/{bits} bits/2^{min_e}/{o:?}",
                coords.name()
            ),
            CbvhAccel::new(&c, tris, o).unwrap(),
        ));
    }
    out
}
