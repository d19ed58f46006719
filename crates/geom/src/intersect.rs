//! Ray/box and ray/triangle tests.
//!
//! The triangle test is the watertight algorithm of Woop, Benthin and Wald, "Watertight
//! Ray/Triangle Intersection", JCGT 2(1), 2013: the ray is transformed so that it runs
//! along +z from the origin, and the three 2D edge functions of the sheared triangle decide
//! the hit. Edge functions of a shared edge are computed from the same operands in both
//! triangles, so a ray through an edge or vertex of a closed mesh cannot slip through.
//! Where an edge function is exactly zero it is recomputed in double precision, as the
//! paper recommends, so the sign is decided correctly.
//!
//! The box test is the slab test. A zero direction component gets the largest finite
//! reciprocal instead of infinity, so an origin exactly on a slab plane gives `0 * MAX = 0`
//! (the plane touches the box) rather than `0 * inf = NaN`, and an origin outside the slab
//! gives a distance beyond any real hit. The far distance is scaled by `1 + 2 gamma(3)` (Ize,
//! "Robust BVH Ray Traversal", JCGT 2013) so that rounding never culls a box the
//! triangle test would hit.

use crate::{Aabb, Ray, Triangle};
use glam::Vec3;

/// Per-ray values shared by every box and triangle test of a traversal.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    /// Ray origin.
    pub origin: Vec3,
    /// Ray direction.
    pub dir: Vec3,
    /// Component-wise reciprocal of the direction (`±f32::MAX` for zero components).
    pub inv_dir: Vec3,
    /// Axis of largest |dir| (the ray's "z" after permutation), and the other two.
    k: [usize; 3],
    /// Shear constants `Sx, Sy, Sz` of the watertight test.
    shear: Vec3,
}

/// A ray/triangle hit: distance and barycentric weights of the three vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Hit distance along the ray (in units of the ray direction).
    pub t: f32,
    /// Barycentric weights of vertices 0, 1, 2 (non-negative, summing to 1).
    pub bary: [f32; 3],
}

/// Relative widening of the division-free range pre-test of the triangle test: the divided
/// distance `t_scaled * (1 / det)` differs from `t_scaled / |det|` by at most two roundings,
/// and `t_max * |det|` adds one, so 4 ulps (`4 eps`) covers them with margin (plus the
/// smallest normal float, for products that underflow).
const RANGE_SLACK: f32 = 4.0 * f32::EPSILON;

/// `1 + 2 gamma(3)` with `gamma(n) = n eps / (1 - n eps)`, `eps = 2^-24` (Ize 2013): the
/// factor by which a slab test scales its far distance so that rounding never culls a box
/// that the exact test would hit.
pub const SLAB_FAR_SCALE: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

impl RayPrecomp {
    /// Precomputes the values for `ray`, without a branch on the direction (incoherent
    /// rays would mispredict the choice of axes) and with the six divisions in two
    /// 4-lane ones (each lane rounds exactly as a scalar division does, so the values are
    /// those of the scalar formulas).
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        let d = ray.dir;
        let a = d.abs();
        // kz: the axis of the largest |component| (the first on ties: x, then y).
        let x_max = (a.x >= a.y) & (a.x >= a.z);
        let y_ge_z = a.y >= a.z;
        let kz = (!x_max) as usize * (1 + (!y_ge_z) as usize);
        let c = d.to_array();
        // kx, ky follow kz cyclically, swapped for a negative kz component (keeps the
        // winding of the triangle after the permutation).
        const NEXT: [usize; 5] = [0, 1, 2, 0, 1];
        let neg = (c[kz] < 0.0) as usize;
        let (kx, ky) = (NEXT[kz + 1 + neg], NEXT[kz + 2 - neg]);
        let q = div4([1.0, 1.0, 1.0, c[kx]], [d.x, d.y, d.z, c[kz]]);
        let s = div4([c[ky], 1.0, 0.0, 0.0], [c[kz], c[kz], 1.0, 1.0]);
        // The largest finite value with the sign of x where 1 / x is infinite (zero or
        // denormal x), so that the slab test never computes 0 * inf.
        let inv: [f32; 3] = std::array::from_fn(|i| {
            if q[i].is_finite() {
                q[i]
            } else {
                f32::MAX.copysign(c[i])
            }
        });
        RayPrecomp {
            origin: ray.origin,
            dir: d,
            inv_dir: Vec3::from_array(inv),
            k: [kx, ky, kz],
            shear: Vec3::new(q[3], s[0], s[1]),
        }
    }
}

/// `n / d` lane by lane (one 4-lane division where the compiler has one).
#[inline(always)]
fn div4(n: [f32; 4], d: [f32; 4]) -> [f32; 4] {
    [n[0] / d[0], n[1] / d[1], n[2] / d[2], n[3] / d[3]]
}

impl RayPrecomp {
    /// The axis permutation of the watertight test: `[kx, ky, kz]`, with `kz` the axis of
    /// the largest direction component.
    #[inline]
    pub fn axes(&self) -> [usize; 3] {
        self.k
    }

    /// The shear constants `Sx, Sy, Sz` of the watertight test.
    #[inline]
    pub fn shear(&self) -> Vec3 {
        self.shear
    }
}

/// Slab test: the entry distance of the ray into `b` when the ray overlaps it within
/// `[t_min, t_max]`, else `None`.
///
/// Per axis, the near plane is chosen by the sign of the reciprocal direction (the box
/// minimum for a positive direction, the maximum for a negative one) instead of taking the
/// minimum and maximum of both plane distances. For real boxes the two are the same; for
/// the empty box (`min = +inf`, `max = -inf`) the chosen near plane is at `+inf`, so an
/// empty child slot is never hit, which tree formats rely on.
#[inline]
pub fn ray_aabb(r: &RayPrecomp, b: &Aabb, t_min: f32, t_max: f32) -> Option<f32> {
    let d = r.inv_dir;
    let sel = |pos: bool, lo: f32, hi: f32| if pos { (lo, hi) } else { (hi, lo) };
    let (nx, fx) = sel(d.x >= 0.0, b.min.x, b.max.x);
    let (ny, fy) = sel(d.y >= 0.0, b.min.y, b.max.y);
    let (nz, fz) = sel(d.z >= 0.0, b.min.z, b.max.z);
    let o = r.origin;
    let near = ((nx - o.x) * d.x)
        .max((ny - o.y) * d.y)
        .max((nz - o.z) * d.z)
        .max(t_min);
    let far = ((fx - o.x) * d.x)
        .min((fy - o.y) * d.y)
        .min((fz - o.z) * d.z)
        * SLAB_FAR_SCALE;
    let far = far.min(t_max);
    (near <= far).then_some(near)
}

/// Watertight ray/triangle test (Woop, Benthin and Wald 2013), without backface culling.
/// Returns the hit when its distance lies in `[t_min, t_max]`. Degenerate triangles never
/// hit.
#[inline]
pub fn intersect_triangle_watertight(
    r: &RayPrecomp,
    tri: &Triangle,
    t_min: f32,
    t_max: f32,
) -> Option<TriangleHit> {
    // The axis permutation is chosen per ray. Indexing a `Vec3` by a run-time axis
    // compiles to a chain of branches per access; indexing a 4-element array by an index
    // masked to 0..4 is one load with no bounds check. Same values, same arithmetic.
    let [kx, ky, kz] = r.k.map(|k| k & 3);
    let a = (tri.v[0] - r.origin).extend(0.0).to_array();
    let b = (tri.v[1] - r.origin).extend(0.0).to_array();
    let c = (tri.v[2] - r.origin).extend(0.0).to_array();
    let s = r.shear;
    let ax = a[kx] - s.x * a[kz];
    let ay = a[ky] - s.y * a[kz];
    let bx = b[kx] - s.x * b[kz];
    let by = b[ky] - s.y * b[kz];
    let cx = c[kx] - s.x * c[kz];
    let cy = c[ky] - s.y * c[kz];
    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    if u == 0.0 || v == 0.0 || w == 0.0 {
        let (ax, ay, bx, by, cx, cy) = (
            ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64,
        );
        u = (cx * by - cy * bx) as f32;
        v = (ax * cy - ay * cx) as f32;
        w = (bx * ay - by * ax) as f32;
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 || det.is_nan() {
        return None;
    }
    let az = s.z * a[kz];
    let bz = s.z * b[kz];
    let cz = s.z * c[kz];
    let t_scaled = u * az + v * bz + w * cz;
    // Reject most out-of-range hits before dividing: compare t_scaled (sign-flipped by
    // det's) against the range scaled by |det|, widened by RANGE_SLACK so that rounding
    // never rejects a hit whose divided distance is in range. The final test is on the
    // divided `t` itself, so a hit is reported exactly when the returned `t` lies in
    // `[t_min, t_max]` (traversal relies on this: a hit at exactly the current closest
    // distance is still found, so ties can be broken by primitive id).
    let sign = det.to_bits() & 0x8000_0000;
    let ts = f32::from_bits(t_scaled.to_bits() ^ sign);
    let det_abs = det.abs();
    let lo = t_min * det_abs;
    let hi = t_max * det_abs;
    if ts < lo - lo.abs() * RANGE_SLACK - f32::MIN_POSITIVE
        || ts > hi + hi.abs() * RANGE_SLACK + f32::MIN_POSITIVE
        || ts.is_nan()
    {
        return None;
    }
    let inv = 1.0 / det;
    let t = t_scaled * inv;
    if !(t >= t_min && t <= t_max) {
        return None;
    }
    Some(TriangleHit {
        t,
        bary: [u * inv, v * inv, w * inv],
    })
}

/// Four triangles in structure-of-arrays form, for [`intersect_triangles4_watertight`]:
/// `v[vertex][axis][lane]`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub struct Triangles4 {
    /// Vertex coordinates: `v[k][a][i]` is axis `a` of vertex `k` of triangle (lane) `i`.
    pub v: [[[f32; 4]; 3]; 3],
}

impl Triangles4 {
    /// Packs up to four triangles; unused lanes repeat the last given triangle (callers
    /// mask them out).
    pub fn pack(tris: &[Triangle]) -> Self {
        let mut v = [[[0f32; 4]; 3]; 3];
        for i in 0..4 {
            if let Some(t) = tris.get(i.min(tris.len().saturating_sub(1))) {
                for (k, vk) in v.iter_mut().enumerate() {
                    for (a, row) in vk.iter_mut().enumerate() {
                        row[i] = t.v[k][a];
                    }
                }
            }
        }
        Self { v }
    }

    /// Triangle `i` (0..4).
    pub fn get(&self, i: usize) -> Triangle {
        let p = |k: usize| Vec3::new(self.v[k][0][i], self.v[k][1][i], self.v[k][2][i]);
        Triangle::new(p(0), p(1), p(2))
    }
}

/// The hits of [`intersect_triangles4_watertight`]: lane `i` hit when bit `i` of `mask` is
/// set, at `t[i]` with barycentrics `bary[0..3][i]`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hits4 {
    /// Lanes that hit.
    pub mask: u8,
    /// Hit distances.
    pub t: [f32; 4],
    /// Barycentric weights of vertices 0, 1, 2 per lane.
    pub bary: [[f32; 4]; 3],
}

/// [`intersect_triangle_watertight`] on the lanes of `tris` selected by `lanes` (bit `i` for
/// lane `i`) at once. Every lane performs exactly the scalar test's operations in the same
/// order (no fused or reassociated arithmetic), so each lane's result equals the scalar
/// test's bit for bit, the double-precision fallback included (done per lane where an
/// edge function is zero). On x86-64 it runs in SSE; elsewhere lane by lane.
#[inline(always)]
pub fn intersect_triangles4_watertight(
    r: &RayPrecomp,
    tris: &Triangles4,
    lanes: u8,
    t_min: f32,
    t_max: f32,
) -> Hits4 {
    #[cfg(target_arch = "x86_64")]
    {
        intersect4_sse(r, tris, lanes, t_min, t_max)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        intersect4_portable(r, tris, lanes, t_min, t_max)
    }
}

/// The lane-by-lane form of [`intersect_triangles4_watertight`] (the reference of the SSE
/// form, and the form used off x86-64).
#[inline]
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn intersect4_portable(
    r: &RayPrecomp,
    tris: &Triangles4,
    lanes: u8,
    t_min: f32,
    t_max: f32,
) -> Hits4 {
    let [kx, ky, kz] = r.k.map(|k| k & 3);
    let o = r.origin.extend(0.0).to_array();
    let s = r.shear;
    // Rows of one vertex, permuted into the ray's axes and translated to its origin.
    let rows = |k: usize| {
        let v = &tris.v[k];
        let pad = [0f32; 4];
        let axis = |a: usize| if a < 3 { &v[a] } else { &pad };
        let sub = |a: usize| -> [f32; 4] {
            let row = axis(a);
            std::array::from_fn(|i| row[i] - o[a])
        };
        (sub(kx), sub(ky), sub(kz))
    };
    let (a_x, a_y, a_z) = rows(0);
    let (b_x, b_y, b_z) = rows(1);
    let (c_x, c_y, c_z) = rows(2);
    let ax: [f32; 4] = std::array::from_fn(|i| a_x[i] - s.x * a_z[i]);
    let ay: [f32; 4] = std::array::from_fn(|i| a_y[i] - s.y * a_z[i]);
    let bx: [f32; 4] = std::array::from_fn(|i| b_x[i] - s.x * b_z[i]);
    let by: [f32; 4] = std::array::from_fn(|i| b_y[i] - s.y * b_z[i]);
    let cx: [f32; 4] = std::array::from_fn(|i| c_x[i] - s.x * c_z[i]);
    let cy: [f32; 4] = std::array::from_fn(|i| c_y[i] - s.y * c_z[i]);
    let mut u: [f32; 4] = std::array::from_fn(|i| cx[i] * by[i] - cy[i] * bx[i]);
    let mut v: [f32; 4] = std::array::from_fn(|i| ax[i] * cy[i] - ay[i] * cx[i]);
    let mut w: [f32; 4] = std::array::from_fn(|i| bx[i] * ay[i] - by[i] * ax[i]);
    for i in 0..4 {
        if u[i] == 0.0 || v[i] == 0.0 || w[i] == 0.0 {
            let (ax, ay, bx, by, cx, cy) = (
                ax[i] as f64,
                ay[i] as f64,
                bx[i] as f64,
                by[i] as f64,
                cx[i] as f64,
                cy[i] as f64,
            );
            u[i] = (cx * by - cy * bx) as f32;
            v[i] = (ax * cy - ay * cx) as f32;
            w[i] = (bx * ay - by * ax) as f32;
        }
    }
    let det: [f32; 4] = std::array::from_fn(|i| u[i] + v[i] + w[i]);
    let az: [f32; 4] = std::array::from_fn(|i| s.z * a_z[i]);
    let bz: [f32; 4] = std::array::from_fn(|i| s.z * b_z[i]);
    let cz: [f32; 4] = std::array::from_fn(|i| s.z * c_z[i]);
    let t_scaled: [f32; 4] = std::array::from_fn(|i| u[i] * az[i] + v[i] * bz[i] + w[i] * cz[i]);
    let inv: [f32; 4] = std::array::from_fn(|i| 1.0 / det[i]);
    let mut out = Hits4::default();
    for i in 0..4 {
        let (u, v, w, det) = (u[i], v[i], w[i], det[i]);
        let outside = (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0);
        let sign = det.to_bits() & 0x8000_0000;
        let ts = f32::from_bits(t_scaled[i].to_bits() ^ sign);
        let det_abs = det.abs();
        let lo = t_min * det_abs;
        let hi = t_max * det_abs;
        let pre_reject = ts < lo - lo.abs() * RANGE_SLACK - f32::MIN_POSITIVE
            || ts > hi + hi.abs() * RANGE_SLACK + f32::MIN_POSITIVE
            || ts.is_nan();
        let t = t_scaled[i] * inv[i];
        let rejected = lanes >> i & 1 == 0 || outside || det == 0.0 || det.is_nan() || pre_reject;
        let hit = !rejected && t >= t_min && t <= t_max;
        out.mask |= (hit as u8) << i;
        out.t[i] = t;
        out.bary[0][i] = u * inv[i];
        out.bary[1][i] = v * inv[i];
        out.bary[2][i] = w * inv[i];
    }
    out
}

/// [`intersect4_portable`] in SSE: the same IEEE operations lane for lane, so the same bits
/// (checked by a property test), without the per-lane round trips through memory.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn intersect4_sse(r: &RayPrecomp, tris: &Triangles4, lanes: u8, t_min: f32, t_max: f32) -> Hits4 {
    use std::arch::x86_64::*;
    let [kx, ky, kz] = r.k.map(|k| k % 3);
    let o = r.origin.to_array();
    let s = r.shear;
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline; every load reads a [f32; 4]
    // row of `tris` (axis indices are reduced modulo 3).
    unsafe {
        let row = |k: usize, a: usize| _mm_loadu_ps(tris.v[k][a].as_ptr());
        let sub = |k: usize, a: usize| _mm_sub_ps(row(k, a), _mm_set1_ps(o[a]));
        let (sx, sy, sz) = (_mm_set1_ps(s.x), _mm_set1_ps(s.y), _mm_set1_ps(s.z));
        let (a_x, a_y, a_z) = (sub(0, kx), sub(0, ky), sub(0, kz));
        let (b_x, b_y, b_z) = (sub(1, kx), sub(1, ky), sub(1, kz));
        let (c_x, c_y, c_z) = (sub(2, kx), sub(2, ky), sub(2, kz));
        let ax = _mm_sub_ps(a_x, _mm_mul_ps(sx, a_z));
        let ay = _mm_sub_ps(a_y, _mm_mul_ps(sy, a_z));
        let bx = _mm_sub_ps(b_x, _mm_mul_ps(sx, b_z));
        let by = _mm_sub_ps(b_y, _mm_mul_ps(sy, b_z));
        let cx = _mm_sub_ps(c_x, _mm_mul_ps(sx, c_z));
        let cy = _mm_sub_ps(c_y, _mm_mul_ps(sy, c_z));
        let mut u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
        let mut v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
        let mut w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
        let zero = _mm_setzero_ps();
        let zeros = _mm_movemask_ps(_mm_or_ps(
            _mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)),
            _mm_cmpeq_ps(w, zero),
        ));
        if zeros != 0 {
            // A zero edge function: recompute that lane in double precision (rare).
            let mut ua = [0f32; 4];
            let mut va = [0f32; 4];
            let mut wa = [0f32; 4];
            _mm_storeu_ps(ua.as_mut_ptr(), u);
            _mm_storeu_ps(va.as_mut_ptr(), v);
            _mm_storeu_ps(wa.as_mut_ptr(), w);
            let lane = |x: __m128, i: usize| {
                let mut t = [0f32; 4];
                _mm_storeu_ps(t.as_mut_ptr(), x);
                t[i] as f64
            };
            for i in 0..4 {
                if zeros >> i & 1 != 0 {
                    let (ax, ay, bx, by, cx, cy) = (
                        lane(ax, i),
                        lane(ay, i),
                        lane(bx, i),
                        lane(by, i),
                        lane(cx, i),
                        lane(cy, i),
                    );
                    ua[i] = (cx * by - cy * bx) as f32;
                    va[i] = (ax * cy - ay * cx) as f32;
                    wa[i] = (bx * ay - by * ax) as f32;
                }
            }
            u = _mm_loadu_ps(ua.as_ptr());
            v = _mm_loadu_ps(va.as_ptr());
            w = _mm_loadu_ps(wa.as_ptr());
        }
        // Outside: some edge function negative and some positive.
        let any_neg = _mm_or_ps(
            _mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)),
            _mm_cmplt_ps(w, zero),
        );
        let any_pos = _mm_or_ps(
            _mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)),
            _mm_cmpgt_ps(w, zero),
        );
        let outside = _mm_and_ps(any_neg, any_pos);
        let det = _mm_add_ps(_mm_add_ps(u, v), w);
        // det == 0 or NaN: "not (det != 0 and det == det)".
        let det_bad = _mm_or_ps(_mm_cmpeq_ps(det, zero), _mm_cmpunord_ps(det, det));
        let az = _mm_mul_ps(sz, a_z);
        let bz = _mm_mul_ps(sz, b_z);
        let cz = _mm_mul_ps(sz, c_z);
        let t_scaled = _mm_add_ps(
            _mm_add_ps(_mm_mul_ps(u, az), _mm_mul_ps(v, bz)),
            _mm_mul_ps(w, cz),
        );
        let sign_bit = _mm_set1_ps(-0.0);
        let ts = _mm_xor_ps(t_scaled, _mm_and_ps(det, sign_bit));
        let det_abs = _mm_andnot_ps(sign_bit, det);
        let lo = _mm_mul_ps(_mm_set1_ps(t_min), det_abs);
        let hi = _mm_mul_ps(_mm_set1_ps(t_max), det_abs);
        let slack = _mm_set1_ps(RANGE_SLACK);
        let tiny = _mm_set1_ps(f32::MIN_POSITIVE);
        let lo_w = _mm_sub_ps(
            _mm_sub_ps(lo, _mm_mul_ps(_mm_andnot_ps(sign_bit, lo), slack)),
            tiny,
        );
        let hi_w = _mm_add_ps(
            _mm_add_ps(hi, _mm_mul_ps(_mm_andnot_ps(sign_bit, hi), slack)),
            tiny,
        );
        let pre_reject = _mm_or_ps(
            _mm_or_ps(_mm_cmplt_ps(ts, lo_w), _mm_cmpgt_ps(ts, hi_w)),
            _mm_cmpunord_ps(ts, ts),
        );
        let inv = _mm_div_ps(_mm_set1_ps(1.0), det);
        let t = _mm_mul_ps(t_scaled, inv);
        let in_range = _mm_and_ps(
            _mm_cmpge_ps(t, _mm_set1_ps(t_min)),
            _mm_cmple_ps(t, _mm_set1_ps(t_max)),
        );
        let rejected = _mm_or_ps(_mm_or_ps(outside, det_bad), pre_reject);
        let hit = _mm_andnot_ps(rejected, in_range);
        let mut out = Hits4 {
            mask: (_mm_movemask_ps(hit) as u8) & lanes,
            ..Hits4::default()
        };
        _mm_storeu_ps(out.t.as_mut_ptr(), t);
        _mm_storeu_ps(out.bary[0].as_mut_ptr(), _mm_mul_ps(u, inv));
        _mm_storeu_ps(out.bary[1].as_mut_ptr(), _mm_mul_ps(v, inv));
        _mm_storeu_ps(out.bary[2].as_mut_ptr(), _mm_mul_ps(w, inv));
        out
    }
}

impl Triangle {
    /// Convenience wrapper of [`intersect_triangle_watertight`] for a single ray.
    pub fn intersect(&self, ray: &Ray) -> Option<TriangleHit> {
        intersect_triangle_watertight(&RayPrecomp::new(ray), self, ray.t_min, ray.t_max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn v3(r: f32) -> impl Strategy<Value = Vec3> {
        (-r..r, -r..r, -r..r).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    /// The per-ray values as the scalar formulas give them (the watertight paper's
    /// choice of axes with branches, one division each): what `RayPrecomp::new` must equal
    /// bit for bit.
    fn precomp_reference(d: Vec3) -> ([usize; 3], [u32; 3], [u32; 3]) {
        let a = d.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let (mut kx, mut ky) = ((kz + 1) % 3, (kz + 2) % 3);
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let recip = |x: f32| {
            let r = 1.0 / x;
            if r.is_finite() {
                r
            } else {
                f32::MAX.copysign(x)
            }
        };
        let inv = [recip(d.x), recip(d.y), recip(d.z)].map(f32::to_bits);
        let shear = [d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]].map(f32::to_bits);
        ([kx, ky, kz], inv, shear)
    }

    fn precomp_bits(d: Vec3) -> ([usize; 3], [u32; 3], [u32; 3]) {
        let p = RayPrecomp::new(&Ray::new(Vec3::ZERO, d));
        (
            p.axes(),
            p.inv_dir.to_array().map(f32::to_bits),
            p.shear().to_array().map(f32::to_bits),
        )
    }

    #[test]
    fn precomputation_equals_the_scalar_formulas_on_edge_cases() {
        let vals = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            -3.0,
            1e-40,
            -1e-40,
            1e30,
            f32::MAX,
        ];
        for &x in &vals {
            for &y in &vals {
                for &z in &vals {
                    let d = Vec3::new(x, y, z);
                    if d == Vec3::ZERO {
                        continue;
                    }
                    assert_eq!(precomp_bits(d), precomp_reference(d), "{d}");
                }
            }
        }
    }

    proptest! {
        #[test]
        fn precomputation_equals_the_scalar_formulas(d in v3(100.0)) {
            prop_assume!(d != Vec3::ZERO);
            prop_assert_eq!(precomp_bits(d), precomp_reference(d));
        }
    }

    #[test]
    fn hits_the_centre_of_a_triangle() {
        let t = Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y);
        let ray = Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::new(0.0, 0.0, -2.0));
        let h = t.intersect(&ray).unwrap();
        assert!((h.t - 0.5).abs() < 1e-6);
        assert!((h.bary[0] - 0.5).abs() < 1e-6 && (h.bary[1] - 0.25).abs() < 1e-6);
        // Back side hits too (no culling); misses outside; range is respected.
        let back = Ray::new(Vec3::new(0.25, 0.25, -1.0), Vec3::Z);
        assert!(t.intersect(&back).is_some());
        assert!(t
            .intersect(&Ray::new(Vec3::new(0.8, 0.8, 1.0), -Vec3::Z))
            .is_none());
        let short = Ray::with_range(ray.origin, ray.dir, 0.0, 0.49);
        assert!(t.intersect(&short).is_none());
        let behind = Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::Z);
        assert!(t.intersect(&behind).is_none());
    }

    /// A ray exactly through a shared edge and a shared vertex (zero edge functions): both
    /// triangles' tests agree, scalar and 4-wide, and at least one reports the hit.
    #[test]
    fn exact_edge_and_vertex_hits_agree_between_scalar_and_four_wide() {
        let t0 = Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y);
        let t1 = Triangle::new(Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let pack = Triangles4::pack(&[t0, t1]);
        for target in [Vec3::new(0.5, 0.5, 0.0), Vec3::X, Vec3::new(0.5, 0.0, 0.0)] {
            let ray = Ray::new(target + Vec3::Z, -Vec3::Z);
            let pre = RayPrecomp::new(&ray);
            let h = intersect_triangles4_watertight(&pre, &pack, 0b11, 0.0, f32::INFINITY);
            let s0 = intersect_triangle_watertight(&pre, &t0, 0.0, f32::INFINITY);
            let s1 = intersect_triangle_watertight(&pre, &t1, 0.0, f32::INFINITY);
            assert!(s0.is_some() || s1.is_some(), "{target}");
            assert_eq!(h.mask & 1 != 0, s0.is_some());
            assert_eq!(h.mask & 2 != 0, s1.is_some());
            if let Some(s) = s0 {
                assert_eq!(h.t[0], s.t);
            }
        }
    }

    #[test]
    fn degenerate_triangles_never_hit() {
        let t = Triangle::new(Vec3::ZERO, Vec3::X, Vec3::X * 2.0);
        let ray = Ray::new(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z);
        assert!(t.intersect(&ray).is_none());
        let p = Triangle::new(Vec3::ONE, Vec3::ONE, Vec3::ONE);
        assert!(p
            .intersect(&Ray::new(Vec3::new(1.0, 1.0, 3.0), -Vec3::Z))
            .is_none());
    }

    #[test]
    fn shared_edges_and_vertices_of_a_fan_are_watertight() {
        // A fan of 8 triangles around the origin, tilted so edges are not axis aligned.
        let rot = glam::Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 0.2);
        let ring: Vec<Vec3> = (0..8)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 8.0;
                rot * Vec3::new(a.cos() * 1.7, a.sin() * 0.9, 0.1 * i as f32)
            })
            .collect();
        let centre = rot * Vec3::new(0.0, 0.0, 0.35);
        let tris: Vec<Triangle> = (0..8)
            .map(|i| Triangle::new(centre, ring[i], ring[(i + 1) % 8]))
            .collect();
        let mut misses = 0;
        let mut rng = 0x1234_5678_u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for k in 0..20000 {
            // Aim at the shared vertex or a point on a shared (interior) edge.
            let i = k % 8;
            let target = if k % 3 == 0 {
                centre
            } else {
                centre.lerp(ring[i], next())
            };
            let origin = target + Vec3::new(next() - 0.5, next() - 0.5, 2.0 + next()) * 3.0;
            let r = RayPrecomp::new(&Ray::new(origin, target - origin));
            if !tris
                .iter()
                .any(|t| intersect_triangle_watertight(&r, t, 0.0, f32::INFINITY).is_some())
            {
                misses += 1;
            }
        }
        assert_eq!(misses, 0);
    }

    #[test]
    fn slab_test_handles_zero_direction_components() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let pre = |o: Vec3, d: Vec3| RayPrecomp::new(&Ray::new(o, d));
        // Axis-aligned ray through the box.
        assert_eq!(
            ray_aabb(
                &pre(Vec3::new(0.5, 0.5, -1.0), Vec3::Z),
                &b,
                0.0,
                f32::INFINITY
            ),
            Some(1.0)
        );
        // Parallel to x = 0 slab and outside it: miss.
        assert_eq!(
            ray_aabb(
                &pre(Vec3::new(-0.1, 0.5, -1.0), Vec3::Z),
                &b,
                0.0,
                f32::INFINITY
            ),
            None
        );
        // Origin exactly on the slab plane, zero component (0 * inf = NaN): touches.
        assert!(ray_aabb(
            &pre(Vec3::new(0.0, 0.5, -1.0), Vec3::Z),
            &b,
            0.0,
            f32::INFINITY
        )
        .is_some());
        assert!(ray_aabb(
            &pre(Vec3::new(1.0, 1.0, -1.0), -Vec3::NEG_Z),
            &b,
            0.0,
            f32::INFINITY
        )
        .is_some());
        // Negative zero components behave like positive ones.
        assert!(ray_aabb(
            &pre(Vec3::new(0.5, 0.5, 2.0), Vec3::new(-0.0, -0.0, -1.0)),
            &b,
            0.0,
            f32::INFINITY
        )
        .is_some());
        // Range limits: box beyond t_max, box behind the origin.
        assert_eq!(
            ray_aabb(&pre(Vec3::new(0.5, 0.5, -5.0), Vec3::Z), &b, 0.0, 4.0),
            None
        );
        assert_eq!(
            ray_aabb(
                &pre(Vec3::new(0.5, 0.5, 5.0), Vec3::Z),
                &b,
                0.0,
                f32::INFINITY
            ),
            None
        );
        // Origin inside: entry distance is t_min.
        assert_eq!(
            ray_aabb(&pre(Vec3::splat(0.5), Vec3::X), &b, 0.0, f32::INFINITY),
            Some(0.0)
        );
        // A flat box (zero thickness) is still hit.
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0));
        assert!(ray_aabb(
            &pre(Vec3::new(0.5, 0.5, 1.0), -Vec3::Z),
            &flat,
            0.0,
            f32::INFINITY
        )
        .is_some());
        // The empty box is never hit, from any direction (zero components included) and
        // from any origin, even one at infinity-adjacent coordinates.
        for d in [
            Vec3::X,
            -Vec3::Y,
            Vec3::new(0.3, -0.2, 0.9),
            Vec3::new(-1.0, 0.0, -0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ] {
            for o in [Vec3::ZERO, Vec3::splat(-1e30), Vec3::new(5.0, -3.0, 1e-30)] {
                assert_eq!(
                    ray_aabb(&pre(o, d), &Aabb::EMPTY, 0.0, f32::INFINITY),
                    None,
                    "{o} {d}"
                );
            }
        }
    }

    proptest! {
        #[test]
        fn aimed_rays_hit_at_the_expected_point(
            a in v3(10.0), b in v3(10.0), c in v3(10.0), o in v3(50.0),
            u in 0.02f32..0.96, v in 0.02f32..0.96,
        ) {
            let tri = Triangle::new(a, b, c);
            prop_assume!(tri.area() > 1e-2);
            // Keep the aimed point strictly inside: scale (u, v) so that w = 1 - u - v >= 0.04.
            let (u, v) = if u + v > 0.96 { (u * 0.96 / (u + v), v * 0.96 / (u + v)) } else { (u, v) };
            let p = a * (1.0 - u - v) + b * u + c * v;
            let d = p - o;
            prop_assume!(d.length() > 1e-2);
            // Skip grazing rays, where the aimed point is ill-conditioned.
            prop_assume!(tri.normal().normalize().dot(d.normalize()).abs() > 0.05);
            let h = tri.intersect(&Ray::new(o, d));
            prop_assert!(h.is_some());
            let h = h.unwrap();
            prop_assert!((h.t - 1.0).abs() < 1e-3, "t = {}", h.t);
            let q = a * h.bary[0] + b * h.bary[1] + c * h.bary[2];
            prop_assert!((q - p).length() < 1e-2 * (1.0 + p.length()));
        }

        /// The 4-wide test equals the scalar test lane by lane, bit for bit: random
        /// triangles, triangles on a unit grid hit through their edges and vertices by
        /// axis-aligned rays (exactly zero edge functions: the double-precision fallback),
        /// degenerate ones, and masked lanes.
        #[test]
        fn four_wide_test_equals_the_scalar_test(
            tris in proptest::collection::vec((v3(10.0), v3(10.0), v3(10.0)), 4),
            grid in proptest::collection::vec((0i32..3, 0i32..3, 0i32..3), 12),
            o in v3(20.0), d in v3(1.0), lanes in 0u8..16, kind in 0u8..3,
            range in (0.0f32..2.0, 0.5f32..100.0),
        ) {
            let tris: Vec<Triangle> = match kind {
                0 => tris.iter().map(|&(a, b, c)| Triangle::new(a, b, c)).collect(),
                1 => grid
                    .chunks(3)
                    .map(|g| {
                        let p = |i: usize| Vec3::new(g[i].0 as f32, g[i].1 as f32, g[i].2 as f32);
                        Triangle::new(p(0), p(1), p(2))
                    })
                    .collect(),
                _ => tris.iter().map(|&(a, b, _)| Triangle::new(a, b, a.lerp(b, 0.5))).collect(),
            };
            let ray = if kind == 1 {
                // Through a grid point or a grid edge midpoint, along an axis.
                let g = grid[0];
                let target = Vec3::new(g.0 as f32, g.1 as f32 + 0.5 * (g.2 % 2) as f32, 0.0);
                Ray::new(target + Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.0, 0.0, -1.0))
            } else {
                prop_assume!(d.length() > 1e-3);
                Ray::new(o, d)
            };
            let pre = RayPrecomp::new(&ray);
            let pack = Triangles4::pack(&tris);
            for (t_min, t_max) in [(0.0, f32::INFINITY), range] {
                let h4 = intersect_triangles4_watertight(&pre, &pack, lanes, t_min, t_max);
                // The SSE form and the lane-by-lane form agree on the hits.
                let hp = intersect4_portable(&pre, &pack, lanes, t_min, t_max);
                prop_assert_eq!(hp.mask, h4.mask);
                for (i, tri) in tris.iter().enumerate() {
                    let h1 = intersect_triangle_watertight(&pre, tri, t_min, t_max);
                    let on = lanes >> i & 1 != 0;
                    prop_assert_eq!(h4.mask >> i & 1 != 0, on && h1.is_some(), "lane {}", i);
                    if let (true, Some(h)) = (on, h1) {
                        prop_assert_eq!(h4.t[i].to_bits(), h.t.to_bits());
                        for k in 0..3 {
                            prop_assert_eq!(h4.bary[k][i].to_bits(), h.bary[k].to_bits());
                        }
                    }
                }
            }
        }

        /// A hit is reported exactly when its returned distance lies in the range: the
        /// same ray limited to `[t, t]` still hits at `t`, and limited to just below `t`
        /// (or just above) it misses.
        #[test]
        fn range_test_is_exact_on_the_returned_distance(
            a in v3(10.0), b in v3(10.0), c in v3(10.0), o in v3(50.0), d in v3(1.0),
        ) {
            prop_assume!(d.length() > 1e-3);
            let tri = Triangle::new(a, b, c);
            let pre = RayPrecomp::new(&Ray::new(o, d));
            if let Some(h) = intersect_triangle_watertight(&pre, &tri, 0.0, f32::INFINITY) {
                prop_assume!(h.t > 0.0);
                let same = intersect_triangle_watertight(&pre, &tri, h.t, h.t);
                prop_assert_eq!(same.map(|s| s.t), Some(h.t));
                let below = f32::from_bits(h.t.to_bits() - 1);
                let above = f32::from_bits(h.t.to_bits() + 1);
                prop_assert!(intersect_triangle_watertight(&pre, &tri, 0.0, below).is_none());
                prop_assert!(intersect_triangle_watertight(&pre, &tri, above, f32::INFINITY).is_none());
            }
        }

        #[test]
        fn hit_implies_box_hit(a in v3(10.0), b in v3(10.0), c in v3(10.0), o in v3(50.0), d in v3(1.0)) {
            prop_assume!(d.length() > 1e-3);
            let tri = Triangle::new(a, b, c);
            let pre = RayPrecomp::new(&Ray::new(o, d));
            if let Some(h) = intersect_triangle_watertight(&pre, &tri, 0.0, f32::INFINITY) {
                let e = ray_aabb(&pre, &tri.aabb(), 0.0, f32::INFINITY);
                prop_assert!(e.is_some());
                prop_assert!(e.unwrap() <= h.t * SLAB_FAR_SCALE);
            }
        }
    }
}
