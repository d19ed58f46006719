//! Deterministic sampling for the path tracer: a small PCG generator seeded per pixel
//! (so images do not depend on the thread count or tile order), cosine-weighted hemisphere
//! directions, an orthonormal basis around a normal, and the offset of a secondary ray's
//! origin off the surface it leaves.

use geom::Vec3;

/// PCG32 (O'Neill 2014, "PCG: a family of simple fast space-efficient statistically good
/// algorithms for random number generation"): 64-bit LCG state, xorshift-rotate output.
#[derive(Clone, Debug)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

impl Pcg32 {
    /// A generator for `stream` (e.g. a pixel index) of image seed `seed`.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut g = Pcg32 {
            state: 0,
            inc: (mix64(stream ^ 0x5851_F42D_4C95_7F2D) << 1) | 1,
        };
        g.next_u32();
        g.state = g.state.wrapping_add(mix64(seed));
        g.next_u32();
        g
    }

    /// The next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in `[0, 1)` (24 random bits, so never exactly 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

/// A 64-bit finalizer (the splitmix64 output function) to spread seeds.
#[inline]
pub fn mix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Two unit vectors that complete `n` (unit) to a right-handed orthonormal basis, without
/// branching on the major axis (the construction of Duff et al. 2017, "Building an
/// Orthonormal Basis, Revisited").
#[inline]
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// A direction on the hemisphere around unit `n` with density `cos(theta) / pi`, from two
/// uniform numbers in `[0, 1)` (Malley's method: a uniform disk point projected up).
#[inline]
pub fn cosine_hemisphere(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (s, c) = phi.sin_cos();
    let (x, y) = (r * c, r * s);
    let z = (1.0 - u1).max(0.0).sqrt();
    let (t, b) = basis(n);
    (t * x + b * y + n * z).normalize()
}

/// Moves a point `p` on a surface off it along the normal `n` (unit, facing the side the
/// new ray leaves to), so that the new ray does not hit the surface it starts on.
///
/// The idea is Wächter and Binder's ("A Fast and Robust Method for Avoiding
/// Self-Intersection", Ray Tracing Gems ch. 6, 2019): offset by a number of float ulps, so
/// that the offset stays correct at any distance from the world origin. They offset each
/// component by ulps of that component; here the distance is 256 ulps of the *largest*
/// component (`2^-15` relative), along the normal, because the watertight triangle test
/// mixes the components in its shear, so its error near the origin of a ray scales with
/// the largest coordinate (a floor at y = -1.5 in a room 2,700 units wide needs an offset
/// for the x and z of its points, not for its y). Near the world origin a small absolute
/// offset (`2^-16`) takes over.
pub fn offset_origin(p: Vec3, n: Vec3) -> Vec3 {
    const RELATIVE: f32 = 1.0 / 32768.0;
    const ABSOLUTE: f32 = 1.0 / 65536.0;
    let scale = p.abs().max_element() * RELATIVE + ABSOLUTE;
    p + n * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pcg_is_deterministic_per_stream_and_uniform() {
        let a: Vec<u32> = {
            let mut g = Pcg32::new(1, 7);
            (0..8).map(|_| g.next_u32()).collect()
        };
        let b: Vec<u32> = {
            let mut g = Pcg32::new(1, 7);
            (0..8).map(|_| g.next_u32()).collect()
        };
        let c: Vec<u32> = {
            let mut g = Pcg32::new(1, 8);
            (0..8).map(|_| g.next_u32()).collect()
        };
        assert_eq!(a, b);
        assert_ne!(a, c);
        let mut g = Pcg32::new(3, 0);
        let n = 100_000;
        let mean: f64 = (0..n).map(|_| g.next_f32() as f64).sum::<f64>() / n as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
    }

    #[test]
    fn basis_is_orthonormal_and_cosine_samples_have_the_right_mean() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.5, 0.81).normalize(),
        ] {
            let (t, b) = basis(n);
            for (x, y) in [(t, b), (t, n), (b, n)] {
                assert!(x.dot(y).abs() < 1e-5);
            }
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
            let mut g = Pcg32::new(9, 1);
            let k = 50_000;
            let mut mean_cos = 0.0f64;
            for _ in 0..k {
                let d = cosine_hemisphere(n, g.next_f32(), g.next_f32());
                let c = d.dot(n);
                assert!(c >= -1e-6);
                mean_cos += c as f64;
            }
            // E[cos] under the cos/pi density is 2/3.
            assert!((mean_cos / k as f64 - 2.0 / 3.0).abs() < 0.01);
        }
    }

    #[test]
    fn offset_moves_off_the_surface_in_the_normal_direction() {
        let n = Vec3::new(0.0, 0.0, 1.0);
        for p in [
            Vec3::ZERO,
            Vec3::new(1e4, -3e3, 5e3),
            Vec3::new(-1e4, 2.0, -7e3),
        ] {
            let q = offset_origin(p, n);
            assert!(q.z > p.z, "{p} -> {q}");
            assert_eq!((q.x, q.y), (p.x, p.y));
            let q = offset_origin(p, -n);
            assert!(q.z < p.z, "{p} -> {q}");
        }
    }
}
