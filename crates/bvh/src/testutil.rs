//! Test inputs shared by the builder tests: random soups and adversarial primitive sets.

use geom::{Aabb, Triangle, Vec3, Vec4};

/// A small deterministic RNG (xorshift64*), so tests need no extra crates.
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed (any value).
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
    /// A point in the cube [0, s)^3.
    pub fn point(&mut self, s: f32) -> Vec3 {
        Vec3::new(self.f32() * s, self.f32() * s, self.f32() * s)
    }
}

/// `n` random triangles of edge up to `size` in a cube of side 100.
pub fn soup(n: usize, size: f32, seed: u64) -> Vec<Aabb> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| {
            let a = r.point(100.0);
            Triangle::new(a, a + r.point(size), a + r.point(size)).aabb()
        })
        .collect()
}

/// Adversarial inputs, each named for failure messages.
pub fn adversarial() -> Vec<(&'static str, Vec<Aabb>)> {
    let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let mut r = Rng::new(7);
    let flat: Vec<Aabb> = (0..3000)
        .map(|_| {
            let a = r.point(10.0) * Vec3::new(1.0, 1.0, 0.0);
            let b = a + r.point(0.5) * Vec3::new(1.0, 1.0, 0.0);
            Aabb::from_points([a, b])
        })
        .collect();
    let mut huge = soup(2000, 0.01, 3);
    huge[1234] = Aabb::new(Vec3::splat(-1e4), Vec3::splat(1e4));
    let points: Vec<Aabb> = (0..1000)
        .map(|i| Aabb::from_point(Vec3::new(i as f32, 0.0, 0.0)))
        .collect();
    let exp: Vec<Aabb> = (0..300)
        .map(|i| Aabb::from_point(Vec3::splat(1.1f32.powi(i))))
        .collect();
    vec![
        ("one", vec![unit]),
        (
            "two",
            vec![unit, Aabb::new(Vec3::splat(2.0), Vec3::splat(3.0))],
        ),
        ("two identical", vec![unit, unit]),
        ("all centroids equal (9)", vec![unit; 9]),
        ("all centroids equal (5000)", vec![unit; 5000]),
        (
            "nested boxes, one centroid",
            (1..2000)
                .map(|i| Aabb::new(Vec3::splat(-(i as f32)), Vec3::splat(i as f32)))
                .collect(),
        ),
        ("coplanar axis-aligned (flat z)", flat),
        ("one huge among tiny", huge),
        ("points on a line", points),
        ("exponentially spaced points", exp),
        (
            "huge coordinates",
            vec![
                Aabb::new(Vec3::splat(-3e38), Vec3::splat(3e38)),
                Aabb::from_point(Vec3::splat(3e38)),
                Aabb::from_point(Vec3::splat(-3e38)),
            ],
        ),
    ]
}

/// Asserts that `bvh` passes the validator, naming the input on failure.
pub fn assert_valid(name: &str, bvh: &crate::Bvh2, prims: &[Aabb], max_leaf: u32) {
    if let Err(e) = crate::validate(bvh, prims, max_leaf) {
        panic!("{name}: invalid tree: {e}");
    }
}

/// Triangle boxes of a procedural scene of the `scene` crate at t = 0.
pub fn proc_scene(spec: &str) -> Vec<Aabb> {
    let s = scene::open(spec, &Default::default()).expect("procedural scene");
    let m = s.mesh_at(0.0).expect("mesh");
    crate::indexed_triangle_aabbs(&m.positions, &m.triangles).expect("valid mesh")
}

/// Unit-edge cubes whose minimum corners are at `x` along the x axis.
pub fn cubes_at(xs: &[f32]) -> Vec<Aabb> {
    xs.iter()
        .map(|&x| Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0)))
        .collect()
}

/// The shared real scenes (`../../../shared/scenes` from the crate), each as (name, boxes
/// of the frame at t = 0). `None` (after printing why) when the folder is absent, so tests
/// skip outside the workspace.
pub fn real_scenes() -> Option<Vec<(String, Vec<Aabb>)>> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if !dir.is_dir() {
        println!("skipping: {} not found", dir.display());
        return None;
    }
    let mut specs: Vec<std::path::PathBuf> = std::fs::read_dir(&dir)
        .expect("scene folder")
        .chain(std::fs::read_dir(dir.join("gltf")).expect("gltf folder"))
        .map(|e| e.expect("dir entry").path())
        .filter(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            matches!(ext, "ply" | "glb") || p.ends_with("horse-gallop")
        })
        .collect();
    specs.sort();
    let mut out = Vec::new();
    for p in specs {
        let spec = p.to_str().expect("utf-8 path");
        let s = scene::open(spec, &Default::default()).unwrap_or_else(|e| panic!("{e}"));
        let m = s.mesh_at(0.0).unwrap_or_else(|e| panic!("{e}"));
        let boxes = crate::indexed_triangle_aabbs(&m.positions, &m.triangles).expect("mesh");
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        out.push((name, boxes));
    }
    Some(out)
}

/// Issue 17: the first lane of the SIMD box arithmetic on `(min, max)` that holds a
/// subnormal, as a description, or `None`. The compiler computes all four lanes (the `w`
/// lane, where the builders keep a primitive index, included) of the box's lanes, its
/// extent `max - min`, every product of the extent with one of its own lanes (what the
/// vectorized half area multiplies) and the centroid `min * 0.5 + max * 0.5`; a subnormal
/// in any of them costs a microcode assist on Intel cores.
pub fn subnormal_simd_lane(min: Vec4, max: Vec4) -> Option<String> {
    let e = max - min;
    let mut named = vec![
        ("min".to_string(), min),
        ("max".to_string(), max),
        ("max - min".to_string(), e),
        ("centroid".to_string(), min * 0.5 + max * 0.5),
    ];
    for k in 0..4 {
        named.push((format!("extent * extent[{k}]"), e * Vec4::splat(e[k])));
    }
    named.into_iter().find_map(|(name, v)| {
        let lane = v.to_array().iter().position(|x| x.is_subnormal())?;
        Some(format!("{name} = {v:?}: lane {lane} subnormal"))
    })
}
