//! Rigid animation: elementary motions composed into an object's transform relative to its
//! parent, `local(t) = place ∘ anim₁(t) ∘ anim₂(t) ∘ …`.

use std::sync::Arc;

use crate::gltf_model::NodeTrack;
use crate::math::{cross, normalize, scale, Rigid, V3};

/// One elementary rigid motion as a function of time (seconds). Each one is the identity at
/// `t = 0` except where its phase or offset says otherwise.
#[derive(Debug, Clone, PartialEq)]
pub enum Anim {
    /// Translation `v·t + ½·a·t²` (linear when `acceleration` is zero, accelerating otherwise).
    Translate {
        /// Initial velocity (m/s).
        velocity: V3,
        /// Constant acceleration (m/s²).
        acceleration: V3,
    },
    /// Translation `amplitude · sin(rate·t + phase)` (bobbing, shaking).
    Oscillate {
        /// Direction and size of the excursion (m).
        amplitude: V3,
        /// Angular rate (rad/s).
        rate: f64,
        /// Phase (rad).
        phase: f64,
    },
    /// Rotation about `axis` through the local origin by `rate·t + ½·acceleration·t²`.
    Spin {
        /// Rotation axis (need not be unit).
        axis: V3,
        /// Angular rate (rad/s).
        rate: f64,
        /// Angular acceleration (rad/s²).
        acceleration: f64,
    },
    /// Rotation about `axis` by `offset + amplitude·sin(rate·t + phase)`: a joint of an
    /// articulated figure.
    Swing {
        /// Joint axis.
        axis: V3,
        /// Rest angle (rad).
        offset: f64,
        /// Swing amplitude (rad).
        amplitude: f64,
        /// Angular rate (rad/s).
        rate: f64,
        /// Phase (rad).
        phase: f64,
    },
    /// A ball of `radius` rolling without slipping on a plane with normal +y along the horizontal
    /// `direction`: distance `s = speed·t + ½·acceleration·t²`, translation `s·direction` and
    /// rotation `s / radius` about `+y × direction`, so the contact point is at rest.
    Roll {
        /// Direction of travel (horizontal; normalised).
        direction: V3,
        /// Ball radius (m).
        radius: f64,
        /// Initial speed (m/s).
        speed: f64,
        /// Acceleration along the direction (m/s²).
        acceleration: f64,
    },
    /// Travel around a horizontal circle of `radius` about the local origin at `rate`, turning to
    /// keep facing along the path (a carousel, a figure running in a loop).
    Circle {
        /// Circle radius (m).
        radius: f64,
        /// Angular rate (rad/s).
        rate: f64,
        /// Starting angle (rad).
        phase: f64,
    },
    /// The keyframed rigid motion of a glTF node (see [`crate::gltf`]).
    Keyframes(Arc<NodeTrack>),
}

impl Anim {
    /// The transform at time `t`.
    pub fn at(&self, t: f64) -> Rigid {
        match *self {
            Anim::Keyframes(ref track) => track.at(t),
            Anim::Translate {
                velocity,
                acceleration,
            } => Rigid::translation(std::array::from_fn(|k| {
                velocity[k] * t + 0.5 * acceleration[k] * t * t
            })),
            Anim::Oscillate {
                amplitude,
                rate,
                phase,
            } => Rigid::translation(scale(amplitude, (rate * t + phase).sin())),
            Anim::Spin {
                axis,
                rate,
                acceleration,
            } => Rigid::rotation(axis, rate * t + 0.5 * acceleration * t * t),
            Anim::Swing {
                axis,
                offset,
                amplitude,
                rate,
                phase,
            } => Rigid::rotation(axis, offset + amplitude * (rate * t + phase).sin()),
            Anim::Roll {
                direction,
                radius,
                speed,
                acceleration,
            } => {
                let d = normalize([direction[0], 0.0, direction[2]]);
                let s = speed * t + 0.5 * acceleration * t * t;
                Rigid::translation(scale(d, s))
                    .then(&Rigid::rotation(cross([0.0, 1.0, 0.0], d), s / radius))
            }
            Anim::Circle {
                radius,
                rate,
                phase,
            } => {
                let a = rate * t + phase;
                // Position (r cos a, 0, −r sin a); the local −z axis turned to the tangent.
                let pos = [radius * a.cos(), 0.0, -radius * a.sin()];
                let heading = if rate >= 0.0 {
                    a
                } else {
                    a + std::f64::consts::PI
                };
                Rigid::translation(pos).then(&Rigid::rotation([0.0, 1.0, 0.0], heading))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{add, sub};

    #[test]
    fn rolling_keeps_the_contact_point_at_rest() {
        let r = 0.4;
        let roll = Anim::Roll {
            direction: [1.0, 0.0, 0.5],
            radius: r,
            speed: 3.0,
            acceleration: 1.5,
        };
        let t = 0.7;
        let h = 1e-6;
        // The material point at the bottom of the ball at t (ball centre at local origin).
        let m0 = roll.at(t);
        let body = m0.inverse().point([m0.trans[0], -r, m0.trans[2]]);
        let before = roll.at(t - h).point(body);
        let after = roll.at(t + h).point(body);
        let v = scale(sub(after, before), 0.5 / h);
        assert!(v.iter().all(|c| c.abs() < 1e-6), "{v:?}");
        // While the top moves at twice the centre's speed.
        let top = m0.inverse().point(add(m0.trans, [0.0, r, 0.0]));
        let vt = scale(
            sub(roll.at(t + h).point(top), roll.at(t - h).point(top)),
            0.5 / h,
        );
        let speed = 3.0 + 1.5 * t;
        let vt_len = (vt[0] * vt[0] + vt[2] * vt[2]).sqrt();
        assert!((vt_len - 2.0 * speed).abs() < 1e-5, "{vt_len}");
    }

    #[test]
    fn circle_faces_along_the_path() {
        let c = Anim::Circle {
            radius: 2.0,
            rate: 1.0,
            phase: 0.0,
        };
        let m = c.at(0.0);
        let fwd = m.vector([0.0, 0.0, -1.0]);
        // At a = 0 the position is (2, 0, 0) moving toward −z.
        assert!((m.trans[0] - 2.0).abs() < 1e-12);
        assert!((fwd[2] + 1.0).abs() < 1e-12, "{fwd:?}");
        // Everywhere on the circle, either way round: the local −z axis is the direction of
        // travel (the path's velocity by central differences), the speed is radius·|rate|, and
        // the local origin stays on the horizontal circle of the radius.
        let h = 1e-6;
        for (radius, rate, phase) in [(2.0, 1.0, 0.0), (0.5, -1.7, 0.4), (3.0, 0.6, -2.0)] {
            let c = Anim::Circle {
                radius,
                rate,
                phase,
            };
            for t in [0.3, 1.1, 2.9, 4.4] {
                let m = c.at(t);
                let v = scale(sub(c.at(t + h).trans, c.at(t - h).trans), 0.5 / h);
                let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!((speed - radius * rate.abs()).abs() < 1e-6, "{speed}");
                let fwd = m.vector([0.0, 0.0, -1.0]);
                let err = (0..3)
                    .map(|k| (fwd[k] - v[k] / speed).abs())
                    .fold(0.0, f64::max);
                assert!(err < 1e-8, "rate {rate} t {t}: faces {fwd:?}, moves {v:?}");
                let r = (m.trans[0] * m.trans[0] + m.trans[2] * m.trans[2]).sqrt();
                assert!(
                    (r - radius).abs() < 1e-12 && m.trans[1] == 0.0,
                    "{:?}",
                    m.trans
                );
            }
        }
    }
}
