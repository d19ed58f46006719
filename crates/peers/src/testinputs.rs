//! Test inputs for the adapters: random triangle soups and adversarial box sets (the same
//! kinds as Arbor's builder tests, whose generators are private to the `bvh` crate).

use geom::{Aabb, Vec3};

/// A small deterministic xorshift64* generator.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn f32(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)) >> 40) as f32 / (1u64 << 24) as f32
    }
    fn point(&mut self, s: f32) -> Vec3 {
        Vec3::new(self.f32() * s, self.f32() * s, self.f32() * s)
    }
}

/// Boxes of `n` random triangles of edge up to `size` in a cube of side 100.
pub fn soup(n: usize, size: f32, seed: u64) -> Vec<Aabb> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| {
            let a = r.point(100.0);
            Aabb::from_points([a, a + r.point(size), a + r.point(size)])
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
            Aabb::from_points([a, a + r.point(0.5) * Vec3::new(1.0, 1.0, 0.0)])
        })
        .collect();
    let mut huge = soup(2000, 0.01, 3);
    huge[1234] = Aabb::new(Vec3::splat(-1e4), Vec3::splat(1e4));
    vec![
        ("one", vec![unit]),
        (
            "two",
            vec![unit, Aabb::new(Vec3::splat(2.0), Vec3::splat(3.0))],
        ),
        ("two identical", vec![unit, unit]),
        ("all centroids equal (5000)", vec![unit; 5000]),
        (
            "nested boxes, one centroid",
            (1..2000)
                .map(|i| Aabb::new(Vec3::splat(-(i as f32)), Vec3::splat(i as f32)))
                .collect(),
        ),
        ("coplanar axis-aligned (flat z)", flat),
        ("one huge among tiny", huge),
        (
            "points on a line",
            (0..1000)
                .map(|i| Aabb::from_point(Vec3::new(i as f32, 0.0, 0.0)))
                .collect(),
        ),
        (
            "exponentially spaced points",
            (0..300)
                .map(|i| Aabb::from_point(Vec3::splat(1.1f32.powi(i))))
                .collect(),
        ),
    ]
}

/// Boxes near `f32::MAX`, whose centroid arithmetic overflows in naive builders.
pub fn huge_coordinates() -> Vec<Aabb> {
    vec![
        Aabb::new(Vec3::splat(-3e38), Vec3::splat(3e38)),
        Aabb::from_point(Vec3::splat(3e38)),
        Aabb::from_point(Vec3::splat(-3e38)),
    ]
}
