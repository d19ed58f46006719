//! Keyframe sampling for glTF animation channels: STEP, LINEAR (spherical for rotations)
//! and CUBICSPLINE (Hermite with per-key in/out tangents), per glTF 2.0 section 3.11 and
//! appendix C. Times outside the keys hold the first or last value.

use geom::Quat;

/// How values between two keys are found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Interp {
    /// The earlier key's value.
    Step,
    /// Linear (slerp for rotations).
    Linear,
    /// Cubic Hermite spline; the output holds (in-tangent, value, out-tangent) per key.
    Cubic,
}

/// What a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Target {
    /// Node translation (3 floats).
    Translation,
    /// Node rotation quaternion x, y, z, w (4 floats).
    Rotation,
    /// Node scale (3 floats).
    Scale,
    /// Morph target weights of the node's mesh (one float per target).
    Weights,
}

/// One decoded channel: key times and values, checked at load (finite, non-decreasing
/// times; value count matching the keys).
#[derive(Clone, Debug)]
pub(crate) struct Channel {
    /// Target node index.
    pub node: usize,
    /// Animated property.
    pub target: Target,
    /// Interpolation.
    pub interp: Interp,
    /// Key times in seconds.
    pub times: Vec<f32>,
    /// Values, `width` floats per key (three groups per key for [`Interp::Cubic`]).
    pub values: Vec<f32>,
    /// Floats per value.
    pub width: usize,
}

impl Channel {
    /// Value `k` (the middle group for cubic splines).
    fn value(&self, k: usize) -> &[f32] {
        let w = self.width;
        let g = if self.interp == Interp::Cubic {
            3 * k + 1
        } else {
            k
        };
        &self.values[g * w..(g + 1) * w]
    }

    /// Samples the channel at `t` into `out` (`width` floats).
    pub fn sample(&self, t: f32, out: &mut [f32]) {
        let n = self.times.len();
        let w = self.width;
        // Keys are validated non-empty at load.
        if n == 1 || t.partial_cmp(&self.times[0]) != Some(std::cmp::Ordering::Greater) {
            out.copy_from_slice(self.value(0));
            return self.fix_rotation(out);
        }
        if t >= self.times[n - 1] {
            out.copy_from_slice(self.value(n - 1));
            return self.fix_rotation(out);
        }
        // times[k] <= t < times[k + 1], with k + 1 < n.
        let k = self.times.partition_point(|&x| x <= t) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let s = if dt > 0.0 {
            ((t - t0) / dt).clamp(0.0, 1.0)
        } else {
            0.0
        };
        match self.interp {
            Interp::Step => out.copy_from_slice(self.value(k)),
            Interp::Linear if self.target == Target::Rotation => {
                let q = slerp(quat(self.value(k)), quat(self.value(k + 1)), s);
                out.copy_from_slice(&q.to_array());
            }
            Interp::Linear => {
                let (a, b) = (self.value(k), self.value(k + 1));
                for i in 0..w {
                    out[i] = a[i] + (b[i] - a[i]) * s;
                }
            }
            Interp::Cubic => {
                let v = &self.values;
                let (s2, s3) = (s * s, s * s * s);
                let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
                let h10 = s3 - 2.0 * s2 + s;
                let h01 = -2.0 * s3 + 3.0 * s2;
                let h11 = s3 - s2;
                for i in 0..w {
                    let p0 = v[(3 * k + 1) * w + i];
                    let b0 = v[(3 * k + 2) * w + i]; // out-tangent of key k
                    let a1 = v[(3 * k + 3) * w + i]; // in-tangent of key k + 1
                    let p1 = v[(3 * k + 4) * w + i];
                    out[i] = h00 * p0 + h10 * dt * b0 + h01 * p1 + h11 * dt * a1;
                }
            }
        }
        self.fix_rotation(out);
    }

    /// Rotations are renormalized after STEP/CUBIC too (the spec requires it for cubic).
    fn fix_rotation(&self, out: &mut [f32]) {
        if self.target == Target::Rotation {
            out.copy_from_slice(&quat(out).normalize().to_array());
        }
    }
}

fn quat(v: &[f32]) -> Quat {
    Quat::from_xyzw(v[0], v[1], v[2], v[3])
}

/// Spherical interpolation along the shorter arc between normalized `a` and `b`.
pub(crate) fn slerp(a: Quat, b: Quat, s: f32) -> Quat {
    let a = a.normalize();
    let mut b = b.normalize();
    let mut d = a.dot(b);
    if d < 0.0 {
        // q and -q are the same rotation; flipping takes the short way round.
        b = -b;
        d = -d;
    }
    if d > 0.9995 {
        // Nearly parallel: sin(theta) ~ 0, normalized lerp is accurate and stable.
        return (a * (1.0 - s) + b * s).normalize();
    }
    let th = d.min(1.0).acos();
    let sn = th.sin();
    (a * (((1.0 - s) * th).sin() / sn) + b * ((s * th).sin() / sn)).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(target: Target, interp: Interp, times: &[f32], values: &[f32], width: usize) -> Channel {
        Channel {
            node: 0,
            target,
            interp,
            times: times.to_vec(),
            values: values.to_vec(),
            width,
        }
    }

    fn sample(c: &Channel, t: f32) -> Vec<f32> {
        let mut o = vec![0.0; c.width];
        c.sample(t, &mut o);
        o
    }

    #[test]
    fn linear_step_and_holds() {
        let c = ch(
            Target::Translation,
            Interp::Linear,
            &[1.0, 3.0],
            &[0., 0., 0., 4., -2., 8.],
            3,
        );
        assert_eq!(sample(&c, 0.0), vec![0., 0., 0.]); // before first key: first value
        assert_eq!(sample(&c, 2.0), vec![2., -1., 4.]);
        assert_eq!(sample(&c, 2.5), vec![3., -1.5, 6.]);
        assert_eq!(sample(&c, 9.0), vec![4., -2., 8.]); // after last key: last value
        let s = Channel {
            interp: Interp::Step,
            ..c
        };
        assert_eq!(sample(&s, 2.9), vec![0., 0., 0.]);
        assert_eq!(sample(&s, 3.0), vec![4., -2., 8.]);
    }

    #[test]
    fn slerp_quarter_turn_and_shortest_path() {
        let a = Quat::IDENTITY;
        let b = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let h = slerp(a, b, 0.5);
        assert!(h.abs_diff_eq(Quat::from_rotation_z(std::f32::consts::FRAC_PI_4), 1e-6));
        // -b is the same rotation; the result must still be the 45 degree one (up to sign).
        let h2 = slerp(a, -b, 0.5);
        assert!(h2.dot(h).abs() > 1.0 - 1e-6);
        // Channel with rotation keys.
        let c = ch(
            Target::Rotation,
            Interp::Linear,
            &[0.0, 1.0],
            &[0., 0., 0., 1., b.x, b.y, b.z, b.w],
            4,
        );
        let q = quat(&sample(&c, 0.25));
        assert!(q.abs_diff_eq(Quat::from_rotation_z(std::f32::consts::PI / 8.0), 1e-6));
    }

    #[test]
    fn cubic_spline_hermite() {
        // Scalar-like weights channel: keys at 0 and 2, values 0 and 1, out-tangent of key 0
        // = 1, in-tangent of key 1 = 0. At s = 0.5: h00=0.5, h10=0.125, h01=0.5, h11=-0.125,
        // so p = 0.5*0 + 0.125*2*1 + 0.5*1 + (-0.125)*2*0 = 0.75.
        let c = ch(
            Target::Weights,
            Interp::Cubic,
            &[0.0, 2.0],
            &[9., 0., 1., 0., 1., 9.],
            1,
        );
        assert!((sample(&c, 1.0)[0] - 0.75).abs() < 1e-6);
        assert_eq!(sample(&c, -1.0), vec![0.0]);
        assert_eq!(sample(&c, 5.0), vec![1.0]);
    }
}
