"""The reference renderer's bindings (splitrender.scene.builtin) and head traces."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import splitrender as sr
from splitrender.scene.builtin import (
    MAX_SAMPLES,
    SCENE_NAMES,
    PathMotion,
    Scene,
    TraceError,
    TraceMotion,
    default_samples,
    load_trace,
)

SCALE = 0.04  # 102 x 58
TRACES = Path(__file__).resolve().parents[2] / "shared" / "traces"


@pytest.fixture(scope="module")
def lab() -> Scene:
    return Scene("lab", "dynamic")


def test_names_and_metadata(lab: Scene) -> None:
    assert set(SCENE_NAMES) == {"courtyard", "colonnade", "lab"}
    assert lab.name == "lab" and lab.variant == "dynamic"
    assert lab.duration > 0 and 0 < lab.near < lab.far
    assert lab.main_size(SCALE) == (102, 58)
    assert repr(lab) == "Scene('lab', 'dynamic')"


def test_a_scale_out_of_range_is_named_in_short(lab: Scene) -> None:
    # 1e300 and 1e-300 were written out in full (300-odd digits), and the sides of 1e300 as
    # the saturated 18446744073709551615.
    for scale, words in (
        (1e-300, r"scale 1e-300 gives a 0×0 main camera"),
        (1e300, r"scale 1e300 gives a 2\.560e303×1\.440e303 main camera"),
        (10.0, r"scale 10\.0 gives a 25600×14400 main camera"),
    ):
        with pytest.raises(sr.InvalidInputError, match=words) as e:
            lab.main_size(scale)
        assert len(str(e.value)) < 120


def test_unknown_scene_lists_valid_names() -> None:
    with pytest.raises(sr.InvalidInputError, match="valid scenes: courtyard, colonnade, lab"):
        Scene("atrium")
    with pytest.raises(ValueError, match="static, dynamic"):
        Scene("lab", "moving")


def test_server_frame_is_the_client_dataclass(lab: Scene) -> None:
    f = lab.server_frame(1, SCALE)
    assert isinstance(f, sr.ServerFrame) and f.index == 1 and f.time == pytest.approx(0.1)
    assert f.main.color.shape == (58, 102, 3) and len(f.aux) == 2
    assert f.aux[0].camera.shape == (29, 51)
    assert f.main.shadow_fwd is not None and f.main.shadow_fwd.bits.dtype == np.uint32
    # The default pose is the scene's predicted pose.
    g = lab.server_frame(1, SCALE, pose=lab.server_pose(1, 10.0))
    assert np.array_equal(f.main.color, g.main.color)
    # The ground truth at a server camera and time equals that camera's colour.
    gt = lab.ground_truth(f.main.camera, f.time)
    assert np.array_equal(gt, f.main.color)


def test_colour_samples_filter_colour_only(lab: Scene) -> None:
    # The Rust tests check the identity and the geometry for every count on all scenes; this
    # checks that the option reaches the renderer through the bindings, for every entry point.
    assert (default_samples(640, 360), default_samples(1280, 720), MAX_SAMPLES) == (3, 2, 8)
    point = lab.server_frame(2, SCALE, samples=1)
    fine = lab.server_frame(2, SCALE, samples=2)
    assert np.array_equal(lab.server_frame(2, SCALE).main.color,
                          lab.server_frame(2, SCALE, samples=3).main.color)
    for a, b in zip((point.main, *point.aux), (fine.main, *fine.aux)):
        assert not np.array_equal(a.color, b.color)
        for name in ("depth", "motion_fwd", "motion_bwd"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.shadow_fwd is not None and b.shadow_fwd is not None
        assert np.array_equal(a.shadow_fwd.bits, b.shadow_fwd.bits)
    for n, f in ((1, point), (2, fine)):
        assert np.array_equal(lab.ground_truth(f.main.camera, f.time, samples=n), f.main.color)
        ((_, img),) = lab.client_frames(24, SCALE, samples=n, pose=lab.server_pose(2, 10.0))
        assert np.array_equal(img, f.main.color)
    for bad in (0, MAX_SAMPLES + 1, True, 2.0):
        with pytest.raises(sr.InvalidInputError, match="samples"):
            lab.server_frame(0, SCALE, samples=bad)  # type: ignore[arg-type]
    with pytest.raises(sr.InvalidInputError, match="samples"):
        lab.ground_truth(point.main.camera, 0.2, samples=0)


def test_client_frames_mono_and_stereo(lab: Scene) -> None:
    ((cam, img),) = lab.client_frames(3, SCALE)
    assert img.shape == (58, 102, 3) and isinstance(cam, sr.Camera)
    eyes = lab.client_frames(3, SCALE, stereo=True)
    assert len(eyes) == 2 and not np.array_equal(eyes[0][0].view, eyes[1][0].view)


def test_camera_stereo_gives_the_renderers_eyes(lab: Scene) -> None:
    """A live client derives its eyes from the head camera (Camera.stereo); they must be the
    cameras the renderer's stereo ground truth is rendered at, or --score and Table 3 would
    score each eye against another viewpoint."""
    for n in (0, 3, 50):
        ((head, _),) = lab.client_frames(n, SCALE)
        rendered = [cam for cam, _ in lab.client_frames(n, SCALE, stereo=True)]
        for ours, theirs in zip(head.stereo(), rendered, strict=True):
            np.testing.assert_allclose(ours.view, theirs.view, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(ours.proj, theirs.proj)
            assert (ours.width, ours.height) == (theirs.width, theirs.height)
    # Left is left: the left eye's camera sees the head's origin at +IPD/2 along its x axis.
    left, right = head.stereo()
    centre = np.linalg.inv(head.view)[:, 3]
    assert (left.view @ centre)[0] == pytest.approx(sr.types.IPD / 2, abs=1e-12)
    assert (right.view @ centre)[0] == pytest.approx(-sr.types.IPD / 2, abs=1e-12)
    wide = head.stereo(0.5)[0]
    assert (wide.view @ centre)[0] == pytest.approx(0.25, abs=1e-12)
    for bad in (0.0, -0.07, float("nan"), float("inf"), "7cm"):
        with pytest.raises(sr.InvalidInputError, match="ipd"):
            head.stereo(bad)  # type: ignore[arg-type]


def test_bad_arguments(lab: Scene) -> None:
    with pytest.raises(sr.InvalidInputError, match="subframes"):
        lab.server_frame(0, SCALE, subframes=0)
    with pytest.raises(sr.InvalidInputError, match="scale"):
        lab.server_frame(0, 1e-6)
    with pytest.raises(sr.InvalidInputError, match="k"):
        lab.server_frame(-1, SCALE)
    # A pose must be rigid: each refusal says why.
    nan, last, mirror = np.eye(4), np.eye(4), np.diag([-1.0, 1.0, 1.0, 1.0])
    nan[0, 3] = np.nan
    last[3, 0] = 0.5
    for pose, why in [
        (np.diag([2.0, 1.0, 1.0, 1.0]), "its 3×3 rotation is not orthonormal"),
        (nan, "got non-finite values"),
        (last, r"last row must be \[0, 0, 0, 1\], got \[0.5, 0.0, 0.0, 1.0\]"),
        (mirror, "its rotation is a reflection"),
    ]:
        with pytest.raises(sr.InvalidInputError, match=f"pose: expected a rigid camera-to-world "
                           f"matrix, {why}"):
            lab.server_frame(0, SCALE, pose=pose)


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "trace.txt"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "line", "problem"),
    [
        ("0 0 0 0 0 0 0\n0 0 0 0 0 0\n", 2, "expected 7 numbers"),
        ("0 0 0 0 0 0 0\n0 0 x 0 0 0 16\n", 2, "not a number: 'x'"),
        ("0 0 0 0 0 0 0\n\n0 0 0 0 0 0 0\n", 3, "not after"),
        ("0 0 nan 0 0 0 0\n", 1, "non-finite"),
    ],
)
def test_trace_errors_name_file_and_line(
    tmp_path: Path, text: str, line: int, problem: str
) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(TraceError, match=problem) as e:
        load_trace(p)
    assert f"{p}:{line}:" in str(e.value)
    assert isinstance(e.value, sr.InvalidInputError)


def test_trace_missing_and_empty(tmp_path: Path) -> None:
    with pytest.raises(TraceError, match="cannot read trace"):
        load_trace(tmp_path / "nope.txt")
    with pytest.raises(TraceError, match="empty trace"):
        load_trace(_write(tmp_path, "\n\n"))


def test_trace_motion_reanchors_and_delays(tmp_path: Path, lab: Scene) -> None:
    # 1 m/s along the trace camera's own -z (forward) after a 90° yaw: forward in world is -x.
    lines = [f"{-t:.6f} 0 0 0 90 0 {t * 1000:.4f}" for t in np.arange(0, 1.01, 1 / 60)]
    trace = load_trace(_write(tmp_path, "\n".join(lines)))
    assert trace.duration == pytest.approx(1.0, abs=1e-3)
    m = TraceMotion(lab, trace, translation_scale=0.5)
    a0 = lab.head_box(0.0)
    np.testing.assert_allclose(m.client_pose(0.0), a0, atol=1e-9)
    p = m.client_pose(0.5)
    # Moved 0.5 s * 1 m/s * 0.5 along the anchor's forward (-z) axis, orientation unchanged.
    np.testing.assert_allclose(p[:3, 3], a0[:3, 3] - 0.25 * a0[:3, 2], atol=1e-6)
    np.testing.assert_allclose(p[:3, :3], a0[:3, :3], atol=1e-9)
    np.testing.assert_allclose(m.server_pose(5, 10.0), m.client_pose(0.4), atol=1e-12)
    assert m.describe()["source"] == "trace"
    assert PathMotion(lab).describe()["source"] == "path"


@pytest.mark.parametrize("scale", [-0.5, float("nan"), float("inf"), "1", None, True])
def test_trace_motion_refuses_a_translation_scale_that_is_not_a_finite_float_from_0(
    tmp_path: Path, lab: Scene, scale: object
) -> None:
    trace = load_trace(_write(tmp_path, "0 0 0 0 0 0 0\n0 0 0 0 0 0 100\n"))
    with pytest.raises(sr.InvalidInputError, match="^translation_scale: expected a"):
        TraceMotion(lab, trace, translation_scale=scale)  # type: ignore[arg-type]
    assert TraceMotion(lab, trace, translation_scale=0).translation_scale == 0.0


def test_shared_traces_load() -> None:
    if not TRACES.is_dir():
        pytest.skip(f"{TRACES} not present")
    for name in ("robot_lab_path.txt", "no_moving.txt"):
        tr = load_trace(TRACES / name)
        assert len(tr.times) > 100
        assert np.allclose(np.linalg.norm(tr.rotations, axis=1), 1.0)


def test_path_motion_prediction_delay() -> None:
    """The server's prediction window: 100 ms reproduces the renderer's own server pose, 0 ms is
    the client's actual pose, and a shorter window predicts a pose closer to the client's."""
    scene = Scene("courtyard")
    fs = 30.0
    for k in (0, 5, 17):
        t = k / fs
        assert np.allclose(PathMotion(scene, 0.1).server_pose(k, fs), scene.server_pose(k, fs),
                           atol=1e-9)
        assert np.allclose(PathMotion(scene, 0.0).server_pose(k, fs), scene.client_pose(t),
                           atol=1e-9)
    client = np.array([scene.client_pose(k / fs) for k in range(3, 30)])
    errors = [
        float(np.abs(np.array([PathMotion(scene, d).server_pose(k, fs) for k in range(3, 30)])
                     - client).mean())
        for d in (0.1, 1 / 30, 1 / 60)
    ]
    assert errors[0] > errors[1] > errors[2] > 0
    assert PathMotion(scene, 1 / 60).describe()["prediction_delay"] == 1 / 60
    with pytest.raises(sr.InvalidInputError, match="prediction_delay"):
        PathMotion(scene, -0.1)


def _warp_error(frame: sr.CameraFrame, motion: np.ndarray, later: np.ndarray) -> float:
    """MAE between the moving pixels' colours and ``later``'s colours where ``motion`` (NDC)
    carries them (nearest pixel; those carried outside the image are left out)."""
    h, w = frame.color.shape[:2]
    moving = (motion != 0).any(axis=-1)
    jj, ii = np.nonzero(moving)
    x = (2 * ii + 1) / w - 1 + motion[jj, ii, 0]
    y = 1 - (2 * jj + 1) / h + motion[jj, ii, 1]
    col = np.floor((x + 1) / 2 * w).astype(int)
    row = np.floor((1 - y) / 2 * h).astype(int)
    ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    a = later[row[ok], col[ok]].astype(int)
    return float(np.abs(a - frame.color[jj[ok], ii[ok]].astype(int)).mean())


def test_motion_and_shadow_buffers_are_the_ones_named(lab: Scene) -> None:
    """``motion_fwd`` carries a moving pixel to where the same camera sees it one server frame
    later, ``motion_bwd`` one frame earlier; ``S_max`` (the most shadowed level) is no brighter
    than the key colour and ``S_min`` no darker. Measured at frame 2: warp MAE 25.9 (forward)
    and 23.0 (backward) against 29.6/26.6 without motion and 31.0/32.2 with the other buffer."""
    f = lab.server_frame(2, SCALE, samples=1).main
    assert f.motion_fwd is not None and f.motion_bwd is not None
    for motion, other, t in ((f.motion_fwd, f.motion_bwd, 0.3), (f.motion_bwd, f.motion_fwd, 0.1)):
        assert (motion != 0).any(axis=-1).sum() > 100
        later = lab.ground_truth(f.camera, t, samples=1)
        right = _warp_error(f, motion, later)
        assert right < _warp_error(f, np.where(motion != 0, other, 0.0), later), t
        assert right < _warp_error(f, np.where(motion != 0, 1e-12, 0.0), later), t
    for sh in (f.shadow_fwd, f.shadow_bwd):
        assert sh is not None
        key = f.color.astype(int).sum(axis=-1)
        lo, hi = sh.s_min.astype(int).sum(axis=-1), sh.s_max.astype(int).sum(axis=-1)
        stored_lo, stored_hi = (sh.bits != 0) & (lo > 0), (sh.bits != 0) & (hi > 0)
        assert stored_lo.sum() + stored_hi.sum() > 50
        assert (hi[stored_hi] <= key[stored_hi]).all() and (lo[stored_lo] >= key[stored_lo]).all()


def test_trace_pose_interpolates_between_samples(tmp_path: Path) -> None:
    """Between two lines a trace's pose is linear in position and, for a turn about one axis,
    halfway in angle (normalised quaternion interpolation of a symmetric pair)."""
    trace = load_trace(_write(tmp_path, "0 0 0 0 0 0 0\n1 2 -4 0 40 0 100\n3 2 -4 0 40 0 200\n"))
    p = trace.pose(0.025)  # a quarter of the way from line 1 to line 2
    np.testing.assert_allclose(p[:3, 3], [0.25, 0.5, -1.0], atol=1e-12)
    p = trace.pose(0.05)  # halfway: a 20° yaw about +y
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    np.testing.assert_allclose(p[:3, :3], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-12)
    np.testing.assert_allclose(trace.pose(0.15)[:3, 3], [2.0, 2.0, -4.0], atol=1e-12)
    np.testing.assert_allclose(trace.pose(9.0)[:3, 3], [3.0, 2.0, -4.0], atol=1e-12)  # clamped
    np.testing.assert_allclose(trace.pose(-1.0), np.eye(4), atol=1e-12)
    # Across ±180° the two quaternions lie in opposite hemispheres: the short way is through
    # 180°, not back through 0°.
    trace = load_trace(_write(tmp_path, "0 0 0 0 170 0 0\n0 0 0 0 -170 0 100\n"))
    np.testing.assert_allclose(trace.pose(0.05)[:3, :3], np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
