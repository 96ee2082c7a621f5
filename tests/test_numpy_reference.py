"""Property (5) of issue #2: the native kernels agree with the pure-numpy reference.

- ``_native.scene_flow`` (eqs. 1, 12, 13) against :func:`numpy_ref.scene_flow` on random cameras,
  depths (NaN, ±inf and out-of-range values included), motions and ``w``: within 1e-5 NDC
  (relative to the flow's magnitude where that exceeds 1; the kernels run in float32), and NaN
  exactly where the reference says the pixel is invalid or behind the client camera.
- ``apply_shadows`` (eqs. 9–11) against :func:`numpy_ref.apply_shadows` on random bitfields,
  colours, ``α``, subframe counts and roles: equal after rounding, except by one where the exact
  value is a rounding tie within float32 noise.
"""

from __future__ import annotations

import math

import numpy as np
import numpy_ref
import pytest
import scenes
import splitrender as sr
from hypothesis import given, settings
from hypothesis import strategies as st
from splitrender import _native as native

# --------------------------------------------------------------------------------------------
# Strategies
# --------------------------------------------------------------------------------------------

coord = st.floats(-3.0, 3.0, allow_nan=False)


@st.composite
def cameras(draw, width=None, height=None):
    """A random perspective camera: position, yaw/pitch, field of view, near/far planes, size."""
    eye = [draw(coord), draw(coord), draw(coord)]
    yaw = draw(st.floats(-180.0, 180.0))
    pitch = draw(st.floats(-70.0, 70.0))
    fov = draw(st.floats(20.0, 110.0))
    near = draw(st.floats(0.05, 0.5))
    far = near * draw(st.floats(20.0, 2000.0))
    w = width if width is not None else draw(st.integers(1, 13))
    h = height if height is not None else draw(st.integers(1, 11))
    return scenes.Cam.make(
        eye,
        scenes.yawed_target(eye, yaw, pitch),
        fov_y_deg=fov,
        width=w,
        height=h,
        near=near,
        far=far,
    )


@st.composite
def nearby_camera(draw, cam: scenes.Cam):
    """A camera a few centimetres / degrees away from ``cam`` (the client's usual situation)."""
    eye = cam.eye + np.array([draw(st.floats(-0.3, 0.3)) for _ in range(3)])
    fwd = -np.linalg.inv(cam.view)[:3, 2]
    yaw = math.degrees(math.atan2(-fwd[0], -fwd[2])) + draw(st.floats(-10.0, 10.0))
    pitch = math.degrees(math.asin(np.clip(fwd[1], -1, 1))) + draw(st.floats(-10.0, 10.0))
    pitch = float(np.clip(pitch, -75.0, 75.0))
    fov = draw(st.floats(30.0, 100.0))
    w, h = draw(st.integers(1, 64)), draw(st.integers(1, 64))
    return scenes.Cam.make(
        eye, scenes.yawed_target(eye, yaw, pitch), fov_y_deg=fov, width=w, height=h
    )


SPECIAL_DEPTHS = np.array(
    [np.nan, np.inf, -np.inf, -0.25, -1e-7, 1.0000001, 2.0, 0.0, 1.0], dtype=np.float32
)


@st.composite
def depth_and_motion(draw, h: int, w: int):
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.0, 1.0, size=(h, w)) ** draw(st.sampled_from([1.0, 3.0, 6.0]))
    depth = depth.astype(np.float32)
    if draw(st.booleans()):
        bad = rng.random((h, w)) < 0.15
        depth[bad] = rng.choice(SPECIAL_DEPTHS, size=int(bad.sum()))
    kind = draw(st.sampled_from(["none", "zero", "random", "partly_moving"]))
    if kind == "none":
        motion = None
    elif kind == "zero":
        motion = np.zeros((h, w, 3), dtype=np.float32)
    else:
        scale = draw(st.sampled_from([1e-3, 0.02, 0.2]))
        motion = rng.normal(0.0, scale, size=(h, w, 3))
        # Keep Z + O_z inside [0, 1]: a moved point beyond the far plane's "infinity" (clip w of the
        # unprojection crossing 0) is ill-conditioned in any precision and not a real motion.
        zf = np.nan_to_num(depth.astype(np.float64), nan=0.5, posinf=0.5, neginf=0.5).clip(0, 1)
        motion[..., 2] = np.clip(motion[..., 2], -0.9 * zf, 0.9 * (1.0 - zf))
        if kind == "partly_moving":
            motion[rng.random((h, w)) < 0.5] = 0.0
        motion = motion.astype(np.float32)
        if draw(st.booleans()):
            bad = rng.random((h, w)) < 0.1
            motion[bad, rng.integers(0, 3)] = rng.choice(
                np.array([np.nan, np.inf, -np.inf], dtype=np.float32)
            )
    return depth, motion


# --------------------------------------------------------------------------------------------
# Scene flow
# --------------------------------------------------------------------------------------------


def _native_flow(src: scenes.Cam, depth, motion, client: scenes.Cam, w: float) -> np.ndarray:
    return np.asarray(
        native.scene_flow(
            src.view,
            src.proj,
            depth,
            motion,
            (client.view, client.proj, client.width, client.height),
            w,
        )
    )


def numpy_ref_points(src: scenes.Cam, depth) -> np.ndarray:
    """World points ``P⁻¹(p̄)`` of the source pixels (float64; garbage where the depth is invalid)."""
    x, y = scenes.pixel_ndc(src.width, src.height)
    z = np.where(np.isfinite(depth), depth, 0.5).astype(np.float64)
    with np.errstate(all="ignore"):
        return scenes.unproject(src.vp, np.stack([x, y, z], axis=-1))


def check_flow(src: scenes.Cam, depth, motion, client: scenes.Cam, w: float) -> None:
    got = _native_flow(src, depth, motion, client, w)
    assert got.shape == depth.shape + (3,)
    assert got.dtype == np.float32
    ref, cw = numpy_ref.scene_flow(
        src.view, src.proj, depth, motion, client.view, client.proj, float(np.float32(w))
    )
    ref_nan = np.isnan(ref).any(axis=-1)
    got_nan = np.isnan(got).any(axis=-1)
    # The kernel returns whole NaN triples, never a partly valid one.
    assert (np.isnan(got).all(axis=-1) == got_nan).all(), "partly-NaN flow vector"
    # M: the size of the coordinates that meet in the client's clip w (eyes and world points).
    mag = (
        1.0
        + np.abs(src.eye).max()
        + np.abs(client.eye).max()
        + np.nan_to_num(np.abs(numpy_ref_points(src, depth)), nan=0.0).max(axis=-1)
    )
    # Points within float32 noise of the client camera's w = 0 plane may fall either way.
    scale = 1.0 + np.abs(np.nan_to_num(ref, nan=0.0)).max(axis=-1)
    ambiguous = np.isfinite(cw) & (np.abs(cw) < 1e-4 * mag)
    mismatch = (ref_nan != got_nan) & ~ambiguous
    assert not mismatch.any(), (
        f"NaN disagreement at {np.argwhere(mismatch)[:5].tolist()}: "
        f"depth={depth[mismatch][:5]}, ref={ref[mismatch][:5]}, native={got[mismatch][:5]}"
    )
    both = ~ref_nan & ~got_nan & ~ambiguous
    # 1e-5 NDC, relative to the flow where that exceeds 1 (float32 holds ~7 digits; a few dozen
    # operations and the conditioning of the unprojection, far/near up to 2000, stay inside).
    # One more term for points within centimetres of the client's camera plane (|clip w| small,
    # in front of its near plane): there w is a difference of terms of size M (the scene's
    # coordinates), so float32 leaves it a relative error of ~1e-6·M/|w|, and NDC = xyz/w inherits it.
    # Measured over 1000 random cases: at worst 0.29 of this tolerance. (At 1e-4 it was 25 times
    # what was measured; the nearby-client test passed with w off by 2e-4 of itself.)
    cond = np.where(np.isfinite(cw), 0.5 * mag / np.maximum(np.abs(cw), 1e-12), 1.0)
    tol = 1e-5 * scale * np.maximum(1.0, cond)
    err = np.abs(got.astype(np.float64) - ref)
    bad = both[..., None] & (err > tol[..., None])
    assert not bad.any(), (
        f"scene flow differs from the numpy reference at {np.argwhere(bad.any(axis=-1))[:5].tolist()}: "
        f"ref={ref[bad.any(axis=-1)][:3].tolist()}, native={got[bad.any(axis=-1)][:3].tolist()}, "
        f"max err={err[both].max() if both.any() else 0}"
    )


@settings(deadline=None)
@given(data=st.data(), w=st.one_of(st.sampled_from([0.0, 1.0, 0.5, -1.0]), st.floats(-2.0, 2.0)))
def test_scene_flow_matches_numpy_reference_random_cameras(data, w):
    src = data.draw(cameras())
    client = data.draw(cameras())
    depth, motion = data.draw(depth_and_motion(src.height, src.width))
    check_flow(src, depth, motion, client, w)


@settings(deadline=None)
@given(data=st.data(), w=st.floats(-1.0, 2.0))
def test_scene_flow_matches_numpy_reference_nearby_client(data, w):
    src = data.draw(
        cameras(width=data.draw(st.integers(1, 40)), height=data.draw(st.integers(1, 30)))
    )
    client = data.draw(nearby_camera(src))
    depth, motion = data.draw(depth_and_motion(src.height, src.width))
    check_flow(src, depth, motion, client, w)


def test_scene_flow_identity_is_zero_and_invalid_is_nan():
    """Same camera, no motion: zero flow (within float32 noise); every invalid depth gives NaN."""
    cam = scenes.Cam.make((0.3, -0.2, 1.0), (0.0, 0.0, -3.0), width=9, height=7)
    depth = np.linspace(0.0, 1.0, 63, dtype=np.float32).reshape(7, 9)
    depth[0, : len(SPECIAL_DEPTHS)] = SPECIAL_DEPTHS
    got = _native_flow(cam, depth, None, cam, 0.5)
    invalid = ~(np.isfinite(depth) & (depth >= 0) & (depth <= 1))
    assert invalid.sum() == 7
    assert np.isnan(got[invalid]).all()
    assert np.abs(got[~invalid]).max() < 1e-5
    motion = np.zeros((7, 9, 3), dtype=np.float32)
    motion[3, 4] = [0.1, np.nan, 0.0]
    got = _native_flow(cam, depth, motion, cam, 0.5)
    assert np.isnan(got[3, 4]).all()
    assert np.isfinite(got[~invalid & ~(np.arange(63).reshape(7, 9) == 31)]).all()


# --------------------------------------------------------------------------------------------
# Shadows
# --------------------------------------------------------------------------------------------


def _shadow_inputs(seed: int, h: int, w: int, subframes: int):
    rng = np.random.default_rng(seed)
    color = scenes.random_color(rng, h, w)
    bits, s_min, s_max = scenes.random_shadow(rng, h, w, density=0.7)
    # Mix in structured bitfields: all-equal levels (the reference's 0/0), only bits above 2S set,
    # and the key frame at the min / max level (stored colour unused).
    flat = rng.random((h, w)) < 0.1
    lvl = rng.integers(0, 4, size=(h, w)).astype(np.uint32)
    allsame = np.zeros((h, w), dtype=np.uint32)
    for j in range(subframes):
        allsame |= lvl << np.uint32(2 * j)
    bits = np.where(flat, allsame, bits).astype(np.uint32)
    if subframes < 16:
        high = rng.random((h, w)) < 0.05
        bits = np.where(high, bits & ~np.uint32((1 << (2 * subframes)) - 1), bits).astype(np.uint32)
    return color, bits, s_min, s_max


alphas = st.one_of(
    st.sampled_from([0.0, 1.0, 0.25, 0.5, 0.75, 0.125, 1 / 3, 0.999, 1.5, 3.0]),
    st.floats(0.0, 3.0, width=32),
)


@settings(deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    h=st.integers(1, 12),
    w=st.integers(1, 12),
    alpha=alphas,
    subframes=st.one_of(st.just(4), st.integers(1, 16)),
    role=st.sampled_from(["older", "newer"]),
)
def test_apply_shadows_matches_numpy_reference(seed, h, w, alpha, subframes, role):
    color, bits, s_min, s_max = _shadow_inputs(seed, h, w, subframes)
    shadow = sr.ShadowBuffers(bits, s_min, s_max)
    got = np.asarray(sr.apply_shadows(color, shadow, alpha, subframes=subframes, role=role))
    exact = numpy_ref.shadow_color(color, bits, s_min, s_max, alpha, subframes, role)
    ref = numpy_ref.round_rgb(exact)
    assert got.shape == (h, w, 3) and got.dtype == np.uint8
    diff = np.abs(got.astype(np.int16) - ref.astype(np.int16))
    assert diff.max() <= 1, (
        f"apply_shadows differs from eqs. 9–11 by {diff.max()} at {np.argwhere(diff > 1)[:3].tolist()} "
        f"(alpha={alpha}, S={subframes}, role={role}, bits={bits[diff.max(axis=-1) > 1][:3]})"
    )
    # Off by one only where the exact value is a rounding tie within float32 noise (the kernels
    # blend in float32): measured at most 6.4e-6 from x.5 over 3000 random cases (77 of 386,000
    # channels differ). A kernel that truncates instead of rounding differs by one elsewhere.
    off = diff > 0
    tie = np.abs(exact[off] - np.floor(exact[off]) - 0.5)
    assert (tie < 2e-5).all(), (
        f"apply_shadows rounds {exact[off][tie >= 2e-5][:3].tolist()} to "
        f"{got[off][tie >= 2e-5][:3].tolist()}, eqs. 9–11 rounded give "
        f"{ref[off][tie >= 2e-5][:3].tolist()} (alpha={alpha}, S={subframes}, role={role})"
    )
    # Pixels without a dynamic shadow keep the key colour exactly.
    assert (got[bits == 0] == color[bits == 0]).all()


def test_apply_shadows_paper_figure_5_pixel():
    """seeds/000 Fig. 5: ``11 11 11 00`` — lit at ``t``, shadowed for subframes 1..3 (forward buffer)."""
    color = np.full((1, 1, 3), 200, np.uint8)
    bits = np.array([[0b11_11_11_00]], np.uint32)
    s_min = np.zeros((1, 1, 3), np.uint8)
    s_max = np.full((1, 1, 3), 40, np.uint8)
    shadow = sr.ShadowBuffers(bits, s_min, s_max)
    for alpha, expected in [(0.0, 200), (0.125, 120), (0.25, 40), (0.5, 40), (0.9, 40), (1.2, 200)]:
        got = np.asarray(sr.apply_shadows(color, shadow, alpha, subframes=4, role="older"))
        assert got[0, 0].tolist() == [expected] * 3, (alpha, got[0, 0])
        ref = numpy_ref.apply_shadows(color, bits, s_min, s_max, alpha, 4, "older")
        assert ref[0, 0].tolist() == [expected] * 3, (alpha, ref[0, 0])


def test_apply_shadows_newer_counts_backwards():
    """Backward buffer: subframe ``j`` at ``t+1 − j/S``; dark only at ``j = 2`` (``t + 0.5``)."""
    color = np.full((1, 1, 3), 100, np.uint8)
    bits = np.array([[0b00_11_00_00]], np.uint32)
    zero = np.zeros((1, 1, 3), np.uint8)
    shadow = sr.ShadowBuffers(bits, zero, zero)
    for alpha, expected in [(0.5, 0), (0.75, 100), (0.625, 50), (0.1, 100)]:
        got = np.asarray(sr.apply_shadows(color, shadow, alpha, subframes=4, role="newer"))
        assert got[0, 0].tolist() == [expected] * 3, (alpha, got[0, 0])
        ref = numpy_ref.apply_shadows(color, bits, zero, zero, alpha, 4, "newer")
        assert ref[0, 0].tolist() == [expected] * 3, (alpha, ref[0, 0])


def test_camera_matrices_match_numpy_conventions():
    """``sr.Camera.look_at`` builds the same matrices as the DESIGN.md formulas in scenes.py."""
    eye, target = (0.4, 1.2, 2.5), (-0.3, 0.2, -3.0)
    cam = sr.Camera.look_at(eye, target, fov_y_deg=70.0, width=40, height=30, near=0.2, far=50.0)
    ref = scenes.Cam.make(eye, target, fov_y_deg=70.0, width=40, height=30, near=0.2, far=50.0)
    np.testing.assert_allclose(np.asarray(cam.view), ref.view, atol=1e-12)
    np.testing.assert_allclose(np.asarray(cam.proj), ref.proj, atol=1e-12)
    # Reversed depth: Z = n(f − d)/(d(f − n)) for view-space depth d.
    for d in (0.2, 1.0, 7.0, 50.0):
        clip = ref.proj @ np.array([0.0, 0.0, -d, 1.0])
        assert clip[2] / clip[3] == pytest.approx(0.2 * (50.0 - d) / (d * 49.8), abs=1e-12)
