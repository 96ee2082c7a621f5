//! Client motion and the camera rig (DESIGN.md "Prediction error", "Vertical field of view").
//!
//! The head box follows a smooth key-framed path; the anchor (the actual head) deviates from it in
//! translation and rotation by a deterministic sum of sines. The client sees the anchor at `t`;
//! the server renders frame `k` at the head box's pose at `t_k` with the anchor's deviation taken
//! [`PREDICTION_DELAY`] earlier, an imperfect prediction.

use reproj_core::{Camera, Mat4};

use crate::error::{Result, SceneError};
use crate::math::{add, cross, hash, normalize, scale, sub, Rigid, V3};

/// How much older the deviation the server predicts with is than the true one (seconds).
pub const PREDICTION_DELAY: f64 = 0.1;
/// Main camera's vertical field of view (degrees).
pub const MAIN_FOV: f64 = 60.0;
/// Auxiliary cameras' vertical field of view (degrees).
pub const AUX_FOV: f64 = 80.0;
/// Auxiliary cameras' offset left and right of the main camera (metres).
pub const AUX_OFFSET: f64 = 0.2;
/// Auxiliary cameras' outward yaw (degrees).
pub const AUX_YAW: f64 = 10.0;
/// Interpupillary distance of the stereo client (metres).
pub const IPD: f64 = 0.07;
/// Main camera size at scale 1 (the paper's).
pub const FULL_SIZE: (usize, usize) = (2560, 1440);

/// A head (camera) pose: camera-to-world rigid transform; the camera looks along its −z.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadPose(pub Rigid);

impl HeadPose {
    /// A pose at `eye` looking at `target`, +y up.
    pub fn look_at(eye: V3, target: V3) -> HeadPose {
        let f = normalize(sub(target, eye));
        let x = normalize(cross(f, [0.0, 1.0, 0.0]));
        let y = cross(x, f);
        HeadPose(Rigid {
            rot: [
                [x[0], y[0], -f[0]],
                [x[1], y[1], -f[1]],
                [x[2], y[2], -f[2]],
            ],
            trans: eye,
        })
    }

    /// Eye position.
    pub fn position(&self) -> V3 {
        self.0.trans
    }

    /// World→camera matrix.
    pub fn view(&self) -> Mat4 {
        rigid_to_mat4(&self.0.inverse())
    }

    /// The pose moved by `offset` (in its own frame) and turned by `turn` (in its own frame).
    pub fn then(&self, local: &Rigid) -> HeadPose {
        HeadPose(self.0.then(local))
    }
}

fn rigid_to_mat4(r: &Rigid) -> Mat4 {
    let m = &r.rot;
    Mat4([
        [m[0][0], m[0][1], m[0][2], r.trans[0]],
        [m[1][0], m[1][1], m[1][2], r.trans[1]],
        [m[2][0], m[2][1], m[2][2], r.trans[2]],
        [0.0, 0.0, 0.0, 1.0],
    ])
}

/// The head box path (Catmull–Rom through `(time, eye, target)` keys, clamped at the ends) plus
/// the anchor's deterministic deviation from it.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPath {
    /// Keys `(time, eye, target)`, sorted by time; at least one.
    pub keys: Vec<(f64, V3, V3)>,
    /// Deviation amplitude in translation (metres, per axis).
    pub translation_amplitude: f64,
    /// Deviation amplitude in rotation (radians, per axis: yaw, pitch, roll).
    pub rotation_amplitude: f64,
    /// Seed of the deviation's sines.
    pub seed: u64,
}

impl CameraPath {
    /// Checks what [`CameraPath::head_box`] needs: at least one key, every key's time, eye and
    /// target finite, and times that never decrease ([`crate::Scene::new`] calls it).
    ///
    /// # Errors
    /// [`SceneError::BadPath`] naming the first key at fault.
    pub fn check(&self) -> Result<()> {
        let bad = |why: String| Err(SceneError::BadPath { why });
        if self.keys.is_empty() {
            return bad("no keys, expected at least one (time, eye, target)".to_string());
        }
        for (i, (t, eye, target)) in self.keys.iter().enumerate() {
            if !(t.is_finite() && eye.iter().chain(target).all(|c| c.is_finite())) {
                return bad(format!(
                    "key {i} is ({t:?}, {eye:?}, {target:?}), expected finite numbers"
                ));
            }
            if i > 0 && *t < self.keys[i - 1].0 {
                return bad(format!(
                    "key {i} at time {t} comes before key {} at {}, expected times in \
                     increasing order",
                    i - 1,
                    self.keys[i - 1].0
                ));
            }
        }
        Ok(())
    }

    /// The head box's pose at `t`.
    ///
    /// # Panics
    /// When the path has no keys ([`CameraPath::check`] refuses it).
    pub fn head_box(&self, t: f64) -> HeadPose {
        let k = &self.keys;
        if k.len() == 1 || t <= k[0].0 {
            return HeadPose::look_at(k[0].1, k[0].2);
        }
        let last = k.len() - 1;
        if t >= k[last].0 {
            return HeadPose::look_at(k[last].1, k[last].2);
        }
        let i = k
            .iter()
            .rposition(|key| key.0 <= t)
            .unwrap_or(0)
            .min(last - 1);
        let s = (t - k[i].0) / (k[i + 1].0 - k[i].0);
        let at = |j: isize| k[j.clamp(0, last as isize) as usize];
        let (p0, p1, p2, p3) = (
            at(i as isize - 1),
            at(i as isize),
            at(i as isize + 1),
            at(i as isize + 2),
        );
        let eye = catmull_rom(p0.1, p1.1, p2.1, p3.1, s);
        let target = catmull_rom(p0.2, p1.2, p2.2, p3.2, s);
        HeadPose::look_at(eye, target)
    }

    /// The anchor's deviation from the head box at `t`, in the head box's frame: each of the six
    /// degrees of freedom is a sum of three sines whose amplitudes, frequencies (0.15–1.2 Hz) and
    /// phases are hashed from the seed.
    pub fn deviation(&self, t: f64) -> Rigid {
        let dof = |d: i64| -> f64 {
            (0..3)
                .map(|k| {
                    let h = |salt: u64| hash(d, k, self.seed.wrapping_mul(31).wrapping_add(salt));
                    let amp = (0.4 + 0.6 * h(1)) / (1 + k) as f64;
                    let freq = 0.15 + 1.05 * h(2);
                    let phase = 2.0 * std::f64::consts::PI * h(3);
                    amp * (2.0 * std::f64::consts::PI * freq * t + phase).sin()
                })
                .sum::<f64>()
                / 1.5
        };
        let ta = self.translation_amplitude;
        let ra = self.rotation_amplitude;
        Rigid::translation([ta * dof(0), ta * dof(1), ta * dof(2)])
            .then(&Rigid::rotation([0.0, 1.0, 0.0], ra * dof(3)))
            .then(&Rigid::rotation([1.0, 0.0, 0.0], ra * dof(4)))
            .then(&Rigid::rotation([0.0, 0.0, 1.0], 0.5 * ra * dof(5)))
    }

    /// The anchor's (the client's actual head) pose at `t`.
    pub fn client_pose(&self, t: f64) -> HeadPose {
        self.head_box(t).then(&self.deviation(t))
    }

    /// The pose the server renders frame `k` at (time `k / f_s`): the head box at `t_k` with the
    /// deviation of `t_k − `[`PREDICTION_DELAY`].
    pub fn server_pose(&self, k: usize, fs: f64) -> HeadPose {
        let t = k as f64 / fs;
        self.head_box(t).then(&self.deviation(t - PREDICTION_DELAY))
    }
}

fn catmull_rom(p0: V3, p1: V3, p2: V3, p3: V3, s: f64) -> V3 {
    let (s2, s3) = (s * s, s * s * s);
    let a = scale(p1, 2.0);
    let b = scale(sub(p2, p0), s);
    let c = scale(
        add(sub(scale(p0, 2.0), scale(p1, 5.0)), sub(scale(p2, 4.0), p3)),
        s2,
    );
    let d = scale(add(sub(scale(p1, 3.0), p0), sub(p3, scale(p2, 3.0))), s3);
    scale(add(add(a, b), add(c, d)), 0.5)
}

/// Main camera size at `scale`: `round(2560·scale) × round(1440·scale)`.
///
/// # Errors
/// [`SceneError::BadScale`] when a side would be below 2 or above `reproj_core::MAX_SIDE`.
pub fn main_size(scale: f64) -> Result<(usize, usize)> {
    let side = |full: usize| (full as f64 * scale).round();
    let (w, h) = (side(FULL_SIZE.0), side(FULL_SIZE.1));
    let max = reproj_core::MAX_SIDE;
    let ok = |v: f64| v.is_finite() && v >= 2.0 && v <= max as f64;
    if !ok(w) || !ok(h) {
        return Err(SceneError::BadScale {
            scale,
            width: w,
            height: h,
            max,
        });
    }
    Ok((w as usize, h as usize))
}

/// Size of each auxiliary camera beside a `width×height` main camera: half of each side,
/// rounded down, at least 1 (the rig's rule, [`rig`]).
pub fn aux_size(width: usize, height: usize) -> (usize, usize) {
    ((width / 2).max(1), (height / 2).max(1))
}

/// The rig's camera sizes at `scale`, `[main, left, right]`, without rendering a frame: the
/// main camera of [`main_size`] and the auxiliary cameras of [`aux_size`].
///
/// # Errors
/// [`SceneError::BadScale`], as [`main_size`].
pub fn camera_sizes(scale: f64) -> Result<[(usize, usize); 3]> {
    let (w, h) = main_size(scale)?;
    let aux = aux_size(w, h);
    Ok([(w, h), aux, aux])
}

/// The three server cameras of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rig {
    /// Main camera.
    pub main: Camera,
    /// Left and right auxiliary cameras.
    pub aux: [Camera; 2],
}

/// The DESIGN.md rig at `pose`: main camera (60°, `width×height`) and two auxiliary cameras
/// (80°, half width and height, rounded down, at least 1) 20 cm left and right along the main
/// camera's x axis, yawed 10° outward.
pub fn rig(pose: &HeadPose, width: usize, height: usize, near: f64, far: f64) -> Rig {
    let aspect = |w: usize, h: usize| w.max(1) as f64 / h.max(1) as f64;
    let main = Camera {
        view: pose.view(),
        proj: Mat4::perspective(MAIN_FOV, aspect(width, height), near, far),
        width,
        height,
    };
    let (aw, ah) = aux_size(width, height);
    let aux_proj = Mat4::perspective(AUX_FOV, aspect(aw, ah), near, far);
    // side −1 = left: moved along −x and yawed left (a positive rotation about +y turns −z to −x).
    let aux = |side: f64| {
        let local = Rigid::translation([AUX_OFFSET * side, 0.0, 0.0]).then(&Rigid::rotation(
            [0.0, 1.0, 0.0],
            -side * AUX_YAW.to_radians(),
        ));
        Camera {
            view: pose.then(&local).view(),
            proj: aux_proj,
            width: aw,
            height: ah,
        }
    };
    Rig {
        main,
        aux: [aux(-1.0), aux(1.0)],
    }
}

/// The stereo client's two eyes at `pose`, `±IPD/2` along its x axis, same orientation and field
/// of view as the main camera. Returns `[left, right]`.
pub fn stereo(pose: &HeadPose, width: usize, height: usize, near: f64, far: f64) -> [Camera; 2] {
    let proj = Mat4::perspective(
        MAIN_FOV,
        width.max(1) as f64 / height.max(1) as f64,
        near,
        far,
    );
    [-1.0, 1.0].map(|side| Camera {
        view: pose
            .then(&Rigid::translation([0.5 * IPD * side, 0.0, 0.0]))
            .view(),
        proj,
        width,
        height,
    })
}

/// The single client camera (mono) at `pose`: the main camera's intrinsics.
pub fn mono(pose: &HeadPose, width: usize, height: usize, near: f64, far: f64) -> Camera {
    rig(pose, width, height, near, far).main
}

#[cfg(test)]
mod tests {
    use super::*;

    fn centre_and_forward(c: &Camera) -> (V3, V3) {
        let iv = c.view.inverse().unwrap();
        let o = iv.mul_vec([0.0, 0.0, 0.0, 1.0]);
        let f = iv.mul_vec([0.0, 0.0, -1.0, 0.0]);
        ([o[0], o[1], o[2]], [f[0], f[1], f[2]])
    }

    #[test]
    fn rig_matches_the_synthetic_rig() {
        let (eye, target) = ([0.3, 0.2, 2.0], [0.3, 0.2, -4.0]);
        let ours = rig(&HeadPose::look_at(eye, target), 1280, 720, 0.1, 100.0);
        let (m, [l, r]) = reproj_core::synthetic::rig(eye, target, 1280, 720);
        for (a, b) in [(ours.main, m), (ours.aux[0], l), (ours.aux[1], r)] {
            assert_eq!((a.width, a.height), (b.width, b.height));
            for row in 0..4 {
                for col in 0..4 {
                    assert!((a.view.0[row][col] - b.view.0[row][col]).abs() < 1e-12);
                    assert!((a.proj.0[row][col] - b.proj.0[row][col]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn stereo_eyes_are_an_ipd_apart() {
        let pose = HeadPose::look_at([1.0, 1.6, 0.0], [3.0, 1.2, -5.0]);
        let [l, r] = stereo(&pose, 64, 36, 0.1, 100.0);
        let (lo, lf) = centre_and_forward(&l);
        let (ro, rf) = centre_and_forward(&r);
        let d = sub(ro, lo);
        assert!((crate::math::length(d) - IPD).abs() < 1e-12);
        assert!((0..3).all(|k| (lf[k] - rf[k]).abs() < 1e-12));
        // Left and right of the head, half the IPD each way along its own x axis (the head's
        // right, computed here from the look-at), looking where the head looks.
        let f = crate::math::normalize(sub([3.0, 1.2, -5.0], [1.0, 1.6, 0.0]));
        let right = crate::math::normalize([-f[2], 0.0, f[0]]);
        for (o, side) in [(lo, -1.0), (ro, 1.0)] {
            let want = add(pose.position(), scale(right, 0.5 * IPD * side));
            assert!(
                (0..3).all(|k| (o[k] - want[k]).abs() < 1e-12),
                "{o:?} vs {want:?}"
            );
        }
        assert!(
            (0..3).all(|k| (lf[k] - f[k]).abs() < 1e-12),
            "{lf:?} vs {f:?}"
        );
    }

    #[test]
    fn server_pose_uses_the_deviation_100_ms_earlier() {
        let path = CameraPath {
            keys: vec![
                (0.0, [0.0, 1.6, 5.0], [0.0, 1.0, 0.0]),
                (2.0, [2.0, 1.6, 4.0], [0.0, 1.0, 0.0]),
                (4.0, [3.0, 1.7, 2.0], [0.0, 1.0, -1.0]),
            ],
            translation_amplitude: 0.03,
            rotation_amplitude: 0.03,
            seed: 5,
        };
        let k = 13;
        let t = k as f64 / 10.0;
        let s = path.server_pose(k, 10.0);
        let expect = path.head_box(t).then(&path.deviation(t - 0.1));
        assert_eq!(s, expect);
        let c = path.client_pose(t);
        let err = crate::math::length(sub(s.position(), c.position()));
        assert!(err > 1e-4 && err < 0.1, "prediction error {err}");
        // The head box passes through its keys.
        assert!(crate::math::length(sub(path.head_box(2.0).position(), [2.0, 1.6, 4.0])) < 1e-12);
    }

    #[test]
    fn camera_sizes_are_the_rigs() {
        let pose = HeadPose::look_at([0.0, 1.6, 5.0], [0.0, 1.6, 0.0]);
        for scale in [0.5, 0.0011, 0.0013, 0.3] {
            let sizes = camera_sizes(scale).unwrap();
            let (w, h) = sizes[0];
            let r = rig(&pose, w, h, 0.1, 100.0);
            let got = [r.main, r.aux[0], r.aux[1]].map(|c| (c.width, c.height));
            assert_eq!(got, sizes, "scale {scale}");
        }
        assert_eq!(aux_size(3, 2), (1, 1));
        assert_eq!(aux_size(1281, 721), (640, 360));
        assert!(camera_sizes(0.0).is_err());
    }

    #[test]
    fn main_size_rounds_and_rejects() {
        assert_eq!(main_size(1.0).unwrap(), (2560, 1440));
        assert_eq!(main_size(0.05).unwrap(), (128, 72));
        assert_eq!(main_size(0.5).unwrap(), (1280, 720));
        assert!(main_size(0.0).is_err());
        assert!(main_size(f64::NAN).is_err());
        assert!(main_size(100.0).is_err());
        // At the edges: a side of 2 is the least allowed, MAX_SIDE the most.
        assert_eq!(main_size(0.0014).unwrap(), (4, 2));
        assert!(main_size(0.001).is_err(), "a height of 1");
        assert_eq!(main_size(6.4).unwrap(), (reproj_core::MAX_SIDE, 9216));
        assert!(main_size(6.4004).is_err(), "a width of MAX_SIDE + 1");
    }
}
