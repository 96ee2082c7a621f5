//! Small `f64` vector and rigid-transform helpers.
//!
//! Everything geometric is computed in `f64` so that the buffers agree with each other to far
//! better than their `f32` storage; only the BVH culling runs in `f32` (with padded boxes).

/// A 3-vector in `f64`.
pub type V3 = [f64; 3];

#[inline(always)]
pub(crate) fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline(always)]
pub(crate) fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
pub(crate) fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline(always)]
pub(crate) fn mul(a: V3, b: V3) -> V3 {
    [a[0] * b[0], a[1] * b[1], a[2] * b[2]]
}
#[inline(always)]
pub(crate) fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
pub(crate) fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline(always)]
pub(crate) fn length(a: V3) -> f64 {
    dot(a, a).sqrt()
}
#[inline(always)]
pub(crate) fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / length(a))
}
#[inline(always)]
pub(crate) fn lerp(a: V3, b: V3, s: f64) -> V3 {
    add(a, scale(sub(b, a), s))
}

/// `x.floor()`, bit for bit for every `f64` (infinities, NaN and `-0.0` included), without the
/// library call that `f64::floor` becomes on the x86-64 baseline (no SSE4.1 `roundsd`), which the
/// procedural textures make several times per sample.
///
/// Exact: every `|x| ≥ 2⁵²` is an integer, infinite or NaN (the comparison fails for NaN) and is
/// its own floor; below that, the truncation toward zero `x as i64` and its conversion back are
/// exact, an integral `x` (`-0.0` too) is returned as it is, and a negative non-integer, whose
/// truncation lies above it, is one less (an exact subtraction of two small integers).
#[inline(always)]
pub(crate) fn floor(x: f64) -> f64 {
    if !(x.abs() < 4_503_599_627_370_496.0) {
        return x;
    }
    let i = x as i64 as f64;
    if i == x {
        x
    } else if i > x {
        i - 1.0
    } else {
        i
    }
}

/// `x.floor() as i64`, the same integer for every `f64` (saturating as `as` does, NaN to 0),
/// without the floating-point floor: the truncation `x as i64` is exact (and saturates and maps
/// NaN as the cast of the floor does), and is one above the floor exactly when it lies above a
/// negative non-integer `x` (the comparison is exact: the truncation of an `x` beyond `2⁵³` is
/// `x` itself); the saturating step keeps `i64::MIN` for every `x` below it.
#[inline(always)]
pub(crate) fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if i as f64 > x {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// A rigid transform `x ↦ R·x + t` (rotation `R` row-major, no scale), so ray parameters are the
/// same in object and world space and the inverse is exact up to rounding (`Rᵀ`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    /// Rotation, row-major.
    pub rot: [[f64; 3]; 3],
    /// Translation.
    pub trans: V3,
}

impl Rigid {
    /// The identity.
    pub const IDENTITY: Rigid = Rigid {
        rot: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        trans: [0.0; 3],
    };

    /// A pure translation.
    pub fn translation(t: V3) -> Rigid {
        Rigid {
            trans: t,
            ..Rigid::IDENTITY
        }
    }

    /// A rotation by `angle` radians about the (not necessarily unit) `axis` (Rodrigues).
    pub fn rotation(axis: V3, angle: f64) -> Rigid {
        let k = normalize(axis);
        let (s, c) = angle.sin_cos();
        let v = 1.0 - c;
        let [x, y, z] = k;
        Rigid {
            rot: [
                [c + x * x * v, x * y * v - z * s, x * z * v + y * s],
                [y * x * v + z * s, c + y * y * v, y * z * v - x * s],
                [z * x * v - y * s, z * y * v + x * s, c + z * z * v],
            ],
            trans: [0.0; 3],
        }
    }

    /// `self ∘ other`: apply `other` first.
    pub fn then(&self, other: &Rigid) -> Rigid {
        let mut rot = [[0.0; 3]; 3];
        for (r, row) in rot.iter_mut().enumerate() {
            for (c, out) in row.iter_mut().enumerate() {
                *out = (0..3).map(|k| self.rot[r][k] * other.rot[k][c]).sum();
            }
        }
        Rigid {
            rot,
            trans: self.point(other.trans),
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Rigid {
        let r = &self.rot;
        let rt = [
            [r[0][0], r[1][0], r[2][0]],
            [r[0][1], r[1][1], r[2][1]],
            [r[0][2], r[1][2], r[2][2]],
        ];
        let t = self.trans;
        let trans = [
            -(rt[0][0] * t[0] + rt[0][1] * t[1] + rt[0][2] * t[2]),
            -(rt[1][0] * t[0] + rt[1][1] * t[1] + rt[1][2] * t[2]),
            -(rt[2][0] * t[0] + rt[2][1] * t[1] + rt[2][2] * t[2]),
        ];
        Rigid { rot: rt, trans }
    }

    /// `R·v` (a direction).
    #[inline(always)]
    pub fn vector(&self, v: V3) -> V3 {
        let r = &self.rot;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }

    /// `R·p + t` (a point).
    #[inline(always)]
    pub fn point(&self, p: V3) -> V3 {
        add(self.vector(p), self.trans)
    }
}

/// Deterministic hash of two integers and a salt to `[0, 1)` (splitmix64 finaliser): the
/// synthetic scene's, so that the two crates draw the same values.
pub(crate) use reproj_core::synthetic::hash;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_inverse_round_trips() {
        let m = Rigid::translation([1.0, -2.0, 0.5]).then(&Rigid::rotation([0.3, 1.0, -0.2], 1.1));
        let p = [0.7, 0.2, -3.0];
        let q = m.inverse().point(m.point(p));
        assert!((0..3).all(|k| (q[k] - p[k]).abs() < 1e-14));
    }

    /// `a.then(&b)` applies `b` first: for two general transforms (each with a rotation and a
    /// translation, so that neither order nor a dropped term can pass), the same point as
    /// applying `b` and then `a`.
    #[test]
    fn then_applies_its_argument_first() {
        let p = [0.7, 0.2, -3.0];
        let a = Rigid {
            trans: [0.4, -1.5, 2.0],
            ..Rigid::rotation([1.0, 0.2, 0.3], -0.8)
        };
        let b = Rigid {
            trans: [-0.6, 0.9, 0.1],
            ..Rigid::rotation([-0.1, 0.5, 1.0], 2.1)
        };
        let (got, want) = (a.then(&b).point(p), a.point(b.point(p)));
        assert!(
            (0..3).all(|k| (got[k] - want[k]).abs() < 1e-14),
            "{got:?} vs {want:?}"
        );
    }

    /// [`floor`] is `f64::floor` bit for bit, and [`floor_i64`] its cast: special values, values
    /// at and near integers and the `2⁵²` threshold, and pseudo-random bit patterns over the
    /// whole range.
    #[test]
    fn floors_are_the_library_floor_bit_for_bit() {
        let mut xs = vec![
            0.0,
            -0.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::MIN,
            f64::EPSILON,
        ];
        for k in -70..=70 {
            let b = 2f64.powi(k.clamp(-60, 63));
            for x in [
                b,
                b + 0.5,
                b - 0.5,
                b * 1.5,
                4_503_599_627_370_496.0 + k as f64,
            ] {
                for y in [
                    x,
                    -x,
                    f64::from_bits(x.to_bits().wrapping_add(1)),
                    f64::from_bits(x.to_bits().wrapping_sub(1)),
                ] {
                    xs.extend([y, -y]);
                }
            }
        }
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..200_000 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            xs.push(f64::from_bits(state));
            // Mostly ordinary magnitudes too, where textures live.
            xs.push((state >> 11) as f64 / (1u64 << 40) as f64 - 4096.0);
        }
        for x in xs {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "floor({x:e})");
            assert_eq!(floor_i64(x), x.floor() as i64, "floor_i64({x:e})");
        }
    }

    #[test]
    fn rotation_turns_by_the_right_hand_rule_about_any_axis() {
        let r = Rigid::rotation([0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2);
        let v = r.vector([1.0, 0.0, 0.0]);
        assert!(v[0].abs() < 1e-15 && (v[1] - 1.0).abs() < 1e-15);
        // The right-hand rule about the other axes too: y toward z about x, z toward x about y.
        let quarter = std::f64::consts::FRAC_PI_2;
        for (axis, from, to) in [
            ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        ] {
            let v = Rigid::rotation(axis, quarter).vector(from);
            assert!(
                (0..3).all(|k| (v[k] - to[k]).abs() < 1e-15),
                "{axis:?}: {v:?}"
            );
        }
        // Any axis (not unit) and angle: Rodrigues' formula in vector form,
        // v·cos θ + (k × v)·sin θ + k·(k·v)·(1 − cos θ).
        let (axis, angle, v) = ([0.3, -1.2, 0.7], 2.3f64, [0.4, 1.1, -0.9]);
        let k = normalize(axis);
        let (s, c) = angle.sin_cos();
        let want = add(
            add(scale(v, c), scale(cross(k, v), s)),
            scale(k, dot(k, v) * (1.0 - c)),
        );
        let got = Rigid::rotation(axis, angle).vector(v);
        assert!(
            (0..3).all(|i| (got[i] - want[i]).abs() < 1e-14),
            "{got:?} vs {want:?}"
        );
    }
}
