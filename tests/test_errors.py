"""Errors: every invalid input raises InvalidInputError (a ValueError and a SplitRenderError) with a
message naming what was expected and what came; invalid pixels never reach the output; no panic
and no foreign exception type ever crosses into Python."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import splitrender as sr
from conftest import FPS, SMALL_H, SMALL_W, Pair, make_pair
from hypothesis import given
from hypothesis import strategies as st
from splitrender import _native


def _native_args(pair: Pair) -> tuple[Any, Any, Any]:
    return (
        pair.older.to_native("fwd"),
        pair.newer.to_native("bwd"),
        pair.request.camera.to_native(),
    )


def _replace_cam(frame: Any, which: str, index: int, value: Any) -> Any:
    """A native frame tuple with slot ``index`` of camera ``which`` ("main" or aux number)."""
    main, aux = frame
    aux = list(aux)
    if which == "main":
        cam = list(main)
        cam[index] = value
        return (tuple(cam), aux)
    k = int(which)
    cam = list(aux[k])
    cam[index] = value
    aux[k] = tuple(cam)
    return (main, aux)


def _raises_invalid(fn: Callable[[], object], *fragments: str) -> str:
    with pytest.raises(sr.InvalidInputError) as e:
        fn()
    assert isinstance(e.value, ValueError)
    assert isinstance(e.value, sr.SplitRenderError)
    msg = str(e.value)
    for f in fragments:
        assert f in msg, (f, msg)
    return msg


# Camera tuple slots: (view, proj, color, depth, motion, shadow).
VIEW, PROJ, COLOR, DEPTH, MOTION, SHADOW = range(6)


def test_wrong_dtype(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    aux_depth = newer[1][1][DEPTH]
    bad = _replace_cam(newer, "1", DEPTH, aux_depth.astype(np.float64))
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.aux[1].depth: expected float32 array of shape (16, 24), got float64 (16, 24)",
    )
    bad = _replace_cam(older, "main", COLOR, older[0][COLOR].astype(np.int16))
    _raises_invalid(
        lambda: _native.reproject("ours", bad, newer, client, 0.5),
        "older.main.color: expected uint8 array of shape (32, 48, 3), got int16 (32, 48, 3)",
    )
    bad = _replace_cam(newer, "main", VIEW, newer[0][VIEW].astype(np.float32))
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.view: expected float64 array of shape (4, 4), got float32 (4, 4)",
    )
    bits, s_min, s_max = older[0][SHADOW]
    bad = _replace_cam(older, "main", SHADOW, (bits.astype(np.int32), s_min, s_max))
    _raises_invalid(
        lambda: _native.reproject("ours", bad, newer, client, 0.5),
        "older.main.shadow.bits: expected uint32 array of shape (32, 48), got int32 (32, 48)",
    )


def test_wrong_shape(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    bad = _replace_cam(newer, "main", MOTION, np.zeros((32, 48, 2), np.float32))
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.motion: expected float32 array of shape (32, 48, 3), got float32 (32, 48, 2)",
    )
    bad = _replace_cam(newer, "0", COLOR, np.zeros((16, 24), np.uint8))
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.aux[0].color: expected uint8 array of shape (16, 24, 3), got uint8 (16, 24)",
    )
    prev = np.zeros((31, 48, 3), np.uint8)
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, client, 0.5, None, prev),
        "previous: expected uint8 array of shape (32, 48, 3), got uint8 (31, 48, 3)",
    )
    _raises_invalid(
        lambda: _native.reproject("ours", older, (newer[0],), client, 0.5),
        "newer: expected a tuple (main, aux)",
    )


def test_non_contiguous(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    wide = np.zeros((32, 96, 3), np.uint8)[:, ::2]
    bad = _replace_cam(newer, "main", COLOR, wide)
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.color: expected a C-contiguous array",
        "non-contiguous uint8 (32, 48, 3)",
    )
    fortran = np.asfortranarray(newer[0][DEPTH])
    bad = _replace_cam(newer, "main", DEPTH, fortran)
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.depth: expected a C-contiguous array",
    )
    # The Python data model rejects it earlier, naming the field.
    cf = pair.older.main
    with pytest.raises(sr.InvalidInputError, match="CameraFrame.color: expected a C-contiguous"):
        sr.CameraFrame(cf.camera, np.zeros((32, 96, 3), np.uint8)[:, ::2], cf.depth)


def test_unaligned(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    depth = newer[0][DEPTH]
    buf = np.zeros(depth.nbytes + 1, np.uint8)
    unaligned = np.frombuffer(buf.data, np.float32, depth.size, offset=1).reshape(depth.shape)
    assert not unaligned.flags.aligned
    bad = _replace_cam(newer, "main", DEPTH, unaligned)
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.depth: expected an aligned array",
    )


def test_mismatched_camera_sizes(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    # Older frame with one auxiliary camera, newer with two.
    _raises_invalid(
        lambda: _native.reproject("ours", (older[0], older[1][:1]), newer, client, 0.5),
        "older frame has 1 auxiliary cameras, newer has 2",
    )
    # Depth sets the size: a colour of another size is named with the expected shape.
    bad = _replace_cam(newer, "main", DEPTH, np.zeros((16, 24), np.float32))
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "newer.main.color: expected uint8 array of shape (16, 24, 3), got uint8 (32, 48, 3)",
    )
    # scene_flow and apply_shadows check their buffers against each other too.
    cf = pair.older.main
    _raises_invalid(
        lambda: _native.scene_flow(
            cf.camera.view,
            cf.camera.proj,
            cf.depth,
            np.zeros((3, 3, 3), np.float32),
            (cf.camera.view, cf.camera.proj, 48, 32),
            0.5,
        ),
        "motion: expected float32 array of shape (32, 48, 3), got float32 (3, 3, 3)",
    )
    assert cf.shadow_fwd is not None
    _raises_invalid(
        lambda: _native.apply_shadows(
            cf.color,
            np.zeros((32, 47), np.uint32),
            cf.shadow_fwd.s_min,
            cf.shadow_fwd.s_max,
            0.5,
            4,
            "older",
        ),
        "bits: expected uint32 array of shape (32, 48), got uint32 (32, 47)",
    )


def test_sizes_checked_before_allocating(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    huge = (client[0], client[1], 2**40, 32)
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, huge, 0.5),
        "client.width: expected an image side in 1..=16384, got 1099511627776",
    )
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, (client[0], client[1], 48, -1), 0.5),
        "client.height",
    )
    _raises_invalid(
        lambda: _native.synthetic_ground_truth(True, (client[0], client[1], 10**6, 10), 0.0),
        "camera.width: expected an image side in 1..=16384",
    )
    empty = _replace_cam(newer, "main", DEPTH, np.zeros((0, 48), np.float32))
    _raises_invalid(
        lambda: _native.reproject("ours", older, empty, client, 0.5),
        "newer.main.depth: expected each side in 1..=16384, got shape (0, 48)",
    )


def test_non_invertible_matrix(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    singular = np.zeros((4, 4))
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, (singular, client[1], 48, 32), 0.5),
        "client camera: matrix is not invertible or not finite",
    )
    bad = _replace_cam(newer, "0", PROJ, singular)
    _raises_invalid(
        lambda: _native.reproject("ours", older, bad, client, 0.5),
        "not invertible",
    )
    nan = np.full((4, 4), np.nan)
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, (client[0], nan, 48, 32), 0.5),
        "not invertible or not finite",
    )


@pytest.mark.parametrize("alpha", [-0.1, 3.5, float("nan"), float("inf"), -1e300])
@pytest.mark.parametrize("method", sr.METHODS)
def test_alpha_out_of_range(pair: Pair, alpha: float, method: str) -> None:
    older, newer, client = _native_args(pair)
    _raises_invalid(
        lambda: _native.reproject(method, older, newer, client, alpha),
        "alpha = ",
        "outside the supported range",
        f"method '{method}'",
    )
    _raises_invalid(
        lambda: sr.reproject_alpha(pair.older, pair.newer, pair.request.camera, alpha, method),
        "alpha = ",
    )


def test_alpha_out_of_range_for_method(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    _raises_invalid(
        lambda: _native.reproject("ours_extrapolate", older, newer, client, 0.5),
        "alpha = 0.5 is outside the supported range [1, 3]",
    )
    _raises_invalid(
        lambda: _native.reproject("backward_bidir", older, newer, client, 1.5),
        "[0, 1]",
    )
    _raises_invalid(
        lambda: _native.reproject("ours", None, newer, client, 0.5),
        "needs the older frame",
    )


def test_unknown_method(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    expected = "expected one of: ours, ours_extrapolate, forward_splat, timewarp, backward_bidir"
    _raises_invalid(
        lambda: _native.reproject("Ours", older, newer, client, 0.5),
        "unknown method 'Ours'",
        expected,
    )
    _raises_invalid(
        lambda: sr.reproject(pair.older, pair.newer, pair.request, "warp"),
        "unknown method 'warp'",
        expected,
    )


def test_unknown_option(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, client, 0.5, {"eps": 0.1}),
        "unknown option 'eps'; valid options: eps_e, eps_z, eps_o, aux_threshold_scale, window",
    )
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, client, 0.5, {"window": "3"}),
        "option window: expected an int, got str",
    )
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, client, 0.5, {"eps_e": -1.0}),
        "option eps_e = -1: expected a finite value > 0",
    )
    for key, value in (("eps_e", "1e300"), ("eps_z", "1e-50")):  # named as given, not as f32
        _raises_invalid(
            lambda: _native.reproject("ours", older, newer, client, 0.5, {key: float(value)}),
            f"option {key} = {value}: expected a value within float32's range",
        )
    _raises_invalid(
        lambda: _native.reproject("ours", older, newer, client, 0.5, [("window", 1)]),
        "options: expected a dict, got list",
    )
    with pytest.raises(TypeError):
        sr.ReprojectOptions(eps=0.1)  # type: ignore[call-arg]


def test_bad_history(pair: Pair) -> None:
    older, newer, client = _native_args(pair)
    _raises_invalid(
        lambda: _native.reproject(
            "backward_bidir", older, newer, client, 0.5, None, None, False, {}
        ),
        "history: expected a BidirHistory or None, got dict",
    )


# ------------------------------------------------------------------------------------------
# Invalid pixels


def _frame_with(frame: sr.ServerFrame, **fields: Callable[[sr.CameraFrame], Any]) -> sr.ServerFrame:
    cams = [
        dataclasses.replace(cf, **{k: f(cf) for k, f in fields.items()})
        for cf in (frame.main, *frame.aux)
    ]
    return sr.ServerFrame(frame.index, frame.time, cams[0], tuple(cams[1:]))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("method", sr.METHODS)
def test_invalid_depth_never_matches(pair: Pair, method: str, bad: float) -> None:
    fill = {"depth": lambda cf: np.full_like(cf.depth, bad)}
    older, newer = _frame_with(pair.older, **fill), _frame_with(pair.newer, **fill)
    h, w = pair.request.camera.shape
    prev = np.random.default_rng(3).integers(0, 256, (h, w, 3), dtype=np.uint8)
    r = sr.reproject(older, newer, pair.request, method, previous=prev, diagnostics=True)
    assert r.image.dtype == np.uint8
    assert (r.source == sr.Reprojection.SOURCE_NONE).all()
    assert np.isnan(r.error).all()
    np.testing.assert_array_equal(r.image, prev)


# Every method, timewarp included (it reads no motion, but a pixel with invalid motion is
# invalid for every method, DESIGN.md).
@pytest.mark.parametrize("method", sr.METHODS)
def test_invalid_motion_never_matches(pair: Pair, method: str) -> None:
    fill = {
        "motion_fwd": lambda cf: np.full_like(cf.motion_fwd, np.nan),
        "motion_bwd": lambda cf: np.full_like(cf.motion_bwd, np.inf),
    }
    older, newer = _frame_with(pair.older, **fill), _frame_with(pair.newer, **fill)
    h, w = pair.request.camera.shape
    prev = np.random.default_rng(4).integers(0, 256, (h, w, 3), dtype=np.uint8)
    r = sr.reproject(older, newer, pair.request, method, previous=prev, diagnostics=True)
    assert (r.source == sr.Reprojection.SOURCE_NONE).all()
    np.testing.assert_array_equal(r.image, prev)


def _spoilt(frame: sr.ServerFrame, seed: int, fill: int | None) -> sr.ServerFrame:
    """``frame`` with about a fifth of each camera's pixels invalid (NaN or infinite depth, or
    NaN or infinite motion in both directions), and, where ``fill`` is given, those pixels'
    colour, shadow colours and shadow bits set to ``fill``. A few other pixels get finite but
    odd depths and motions (1e30, -5), which no method may fail on. The same ``seed`` spoils
    the same pixels in the same way."""
    rng = np.random.default_rng(seed)
    cams = []
    for cf in (frame.main, *frame.aux):
        shape = cf.depth.shape
        mask = rng.random(shape) < 0.2
        by_depth = mask & (rng.random(shape) < 0.5)
        bad = rng.choice(np.array([np.nan, np.inf, -np.inf], np.float32), shape)
        odd = ~mask & (rng.random(shape) < 0.05)
        odd_value = rng.choice(np.array([1e30, -5.0], np.float32), shape)
        depth = cf.depth.copy()
        depth[by_depth] = bad[by_depth]
        depth[odd] = odd_value[odd]
        fields: dict[str, Any] = {"depth": depth}
        for name in ("motion_fwd", "motion_bwd"):
            m = getattr(cf, name)
            assert m is not None
            m = m.copy()
            m[mask & ~by_depth] = bad[mask & ~by_depth][:, None]
            m[odd] = odd_value[odd][:, None]
            fields[name] = m
        if fill is not None:
            color = cf.color.copy()
            color[mask] = fill
            fields["color"] = color
            for name in ("shadow_fwd", "shadow_bwd"):
                s = getattr(cf, name)
                assert s is not None
                bits, s_min, s_max = s.bits.copy(), s.s_min.copy(), s.s_max.copy()
                bits[mask] = 0 if fill == 0 else 0xFFFF_FFFF
                s_min[mask] = fill
                s_max[mask] = fill
                fields[name] = sr.ShadowBuffers(bits, s_min, s_max)
        cams.append(dataclasses.replace(cf, **fields))
    return sr.ServerFrame(frame.index, frame.time, cams[0], tuple(cams[1:]))


@pytest.mark.parametrize("method", sr.METHODS)
def test_partly_invalid_pixels_give_valid_output(pair: Pair, method: str) -> None:
    """An invalid pixel (NaN or infinite depth or motion) never reaches the output (DESIGN.md):
    what the invalid pixels hold (colour, shadow colours and bits) changes no output pixel, no
    source and no error, while the same change on valid pixels does change the output. Pixels
    no source coloured keep the previous frame, and every matched pixel has a finite error."""
    h, w = pair.request.camera.shape
    prev = np.random.default_rng(6).integers(0, 256, (h, w, 3), dtype=np.uint8)
    results = []
    for fill in (0, 255):
        older, newer = _spoilt(pair.older, 5, fill), _spoilt(pair.newer, 7, fill)
        results.append(
            sr.reproject(older, newer, pair.request, method, previous=prev, diagnostics=True)
        )
    dark, bright = results
    assert dark.image.dtype == np.uint8 and dark.image.shape == (h, w, 3)
    matched = dark.source != sr.Reprojection.SOURCE_NONE
    assert matched.mean() > 0.3, "too few matched pixels for the test to mean anything"
    np.testing.assert_array_equal(dark.source, bright.source)
    np.testing.assert_array_equal(dark.error, bright.error)
    np.testing.assert_array_equal(dark.image, bright.image)
    np.testing.assert_array_equal(dark.image[~matched], prev[~matched])
    if method != "timewarp":  # timewarp reports no error (always NaN)
        assert np.isfinite(dark.error[matched]).all()
    # The power of the check: with valid depth and motion, the same pixels' colours show.
    valid = []
    for fill in (0, 255):
        older, newer = _recolored(pair.older, 5, fill), _recolored(pair.newer, 7, fill)
        valid.append(sr.reproject(older, newer, pair.request, method, previous=prev))
    assert (valid[0] != valid[1]).any(axis=2).mean() > 0.1


def _recolored(frame: sr.ServerFrame, seed: int, fill: int) -> sr.ServerFrame:
    """``frame`` with the colours :func:`_spoilt` would set, and its depth and motion intact."""
    spoilt = _spoilt(frame, seed, fill)
    cams = [
        dataclasses.replace(s, depth=cf.depth, motion_fwd=cf.motion_fwd, motion_bwd=cf.motion_bwd)
        for s, cf in zip((spoilt.main, *spoilt.aux), (frame.main, *frame.aux), strict=True)
    ]
    return sr.ServerFrame(frame.index, frame.time, cams[0], tuple(cams[1:]))


# ------------------------------------------------------------------------------------------
# Panics and fuzzing


def test_panic_becomes_split_render_error() -> None:
    with pytest.raises(sr.SplitRenderError) as e:
        _native._panic_for_test()
    assert type(e.value) is sr.SplitRenderError
    assert "internal error in _panic_for_test" in str(e.value)
    assert "please report" in str(e.value)


DTYPES = [
    np.uint8,
    np.int8,
    np.uint16,
    np.int32,
    np.uint32,
    np.int64,
    np.float16,
    np.float32,
    np.float64,
    np.complex64,
    np.bool_,
    object,
]

arrays = st.builds(
    lambda dtype, shape: np.zeros(shape, dtype=dtype),
    st.sampled_from(DTYPES),
    st.lists(st.integers(0, 5), min_size=0, max_size=4).map(tuple),
)
junk = st.one_of(
    arrays,
    st.none(),
    st.integers(-3, 3),
    st.floats(allow_nan=True),
    st.text(max_size=3),
    st.lists(st.integers(0, 3), max_size=3),
    st.tuples(),
)


@given(
    target=st.sampled_from(["older", "newer", "client", "previous"]),
    cam=st.sampled_from(["main", "0", "1"]),
    slot=st.integers(0, 5),
    value=junk,
    # A shadow tuple whose entries are junk, and the natural-size arrays of the wrong dtype.
    shadow_part=st.integers(0, 2),
    natural=st.booleans(),
    natural_dtype=st.sampled_from(DTYPES),
)
def test_fuzz_only_split_render_errors(
    pair: Pair,
    target: str,
    cam: str,
    slot: int,
    value: Any,
    shadow_part: int,
    natural: bool,
    natural_dtype: Any,
) -> None:
    older, newer, client = _native_args(pair)
    previous: Any = None
    if target in ("older", "newer"):
        frame = older if target == "older" else newer
        original = (frame[0] if cam == "main" else frame[1][int(cam)])[slot]
        if natural and isinstance(original, np.ndarray):
            value = original.astype(natural_dtype)
        if slot == SHADOW and not isinstance(value, np.ndarray) and value is not None:
            parts = list(original)
            parts[shadow_part] = value
            value = tuple(parts)
        frame = _replace_cam(frame, cam, slot, value)
        if target == "older":
            older = frame
        else:
            newer = frame
    elif target == "client":
        c = list(client)
        c[slot % 4] = value
        client = tuple(c)
    else:
        previous = value
    try:
        out = _native.reproject("ours", older, newer, client, 0.5, None, previous)
    except sr.SplitRenderError:
        return
    except BaseException as e:  # noqa: BLE001 - the point of the test
        pytest.fail(f"{type(e).__name__} escaped: {e}")
    assert isinstance(out, np.ndarray) and out.dtype == np.uint8


# ------------------------------------------------------------------------------------------
# The public API names a bad buffer by the path the caller passed it under (issue 12)
#
# numpy arrays stay mutable after a frame is made (``a.dtype = ...``, ``a.shape = ...``) and
# ``object.__setattr__`` gets past a frozen dataclass, so a frame that was valid when made can
# reach the kernels with a bad buffer. The message then names the argument, the camera and the
# field: ``newer.aux[1].motion_bwd``, not the native layer's ``newer.aux[1].motion``.


def _fresh() -> Pair:
    """A pair of its own, for tests that spoil a frame's arrays in place."""
    return make_pair()


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


def _unaligned(a: np.ndarray) -> np.ndarray:
    buf = np.zeros(a.nbytes + 1, np.uint8)
    out = np.frombuffer(buf.data, a.dtype, a.size, offset=1).reshape(a.shape)
    assert not out.flags.aligned
    return out


def _spoil_aux_depth_dtype(p: Pair) -> None:
    p.newer.aux[1].depth.dtype = np.int32  # type: ignore[misc]


def _spoil_main_depth_shape(p: Pair) -> None:
    p.older.main.depth.shape = (16, 96)


def _spoil_motion_bwd_shape(p: Pair) -> None:
    assert p.newer.aux[1].motion_bwd is not None
    p.newer.aux[1].motion_bwd.shape = (16, 72, 1)


def _spoil_motion_fwd_dtype(p: Pair) -> None:
    cf = p.older.aux[0]
    assert cf.motion_fwd is not None
    _set(cf, "motion_fwd", cf.motion_fwd.astype(np.float64))


def _spoil_shadow_bits(p: Pair) -> None:
    assert p.newer.aux[1].shadow_bwd is not None
    p.newer.aux[1].shadow_bwd.bits.dtype = np.int32  # type: ignore[misc]


def _spoil_shadow_s_min(p: Pair) -> None:
    s = p.older.main.shadow_fwd
    assert s is not None
    _set(s, "s_min", np.zeros((32, 96, 3), np.uint8)[:, ::2])


def _spoil_shadow_size(p: Pair) -> None:
    small = p.newer.aux[0].shadow_bwd
    _set(p.newer.main, "shadow_bwd", small)


def _spoil_consistent_size(p: Pair) -> None:
    # Buffers that agree with each other but not with the camera: the native layer, which takes
    # the size from the depth, cannot see it.
    cf = p.newer.main
    _set(cf, "color", np.zeros((16, 24, 3), np.uint8))
    _set(cf, "depth", np.zeros((16, 24), np.float32))
    _set(cf, "motion_bwd", None)
    _set(cf, "shadow_bwd", None)


def _spoil_unaligned(p: Pair) -> None:
    _set(p.newer.main, "depth", _unaligned(p.newer.main.depth))


def _spoil_view(p: Pair) -> None:
    cam = p.newer.aux[0].camera
    _set(cam, "view", cam.view.astype(np.float32))


def _spoil_list(p: Pair) -> None:
    _set(p.older.aux[1], "color", p.older.aux[1].color.tolist())


SPOILS: list[tuple[Callable[[Pair], None], str]] = [
    (
        _spoil_aux_depth_dtype,
        "newer.aux[1].depth: expected float32 array of shape (16, 24), got int32 (16, 24)",
    ),
    (
        _spoil_main_depth_shape,
        "older.main.depth: expected float32 array of shape (32, 48), got float32 (16, 96)",
    ),
    (
        _spoil_motion_bwd_shape,
        (
            "newer.aux[1].motion_bwd: expected float32 array of shape (16, 24, 3), "
            "got float32 (16, 72, 1)"
        ),
    ),
    (
        _spoil_motion_fwd_dtype,
        (
            "older.aux[0].motion_fwd: expected float32 array of shape (16, 24, 3), "
            "got float64 (16, 24, 3)"
        ),
    ),
    (
        _spoil_shadow_bits,
        (
            "newer.aux[1].shadow_bwd.bits: expected uint32 array of shape (16, 24), "
            "got int32 (16, 24)"
        ),
    ),
    (_spoil_shadow_s_min, "older.main.shadow_fwd.s_min: expected a C-contiguous array"),
    (_spoil_shadow_size, "newer.main.shadow_bwd: expected buffers of shape (32, 48), got (16, 24)"),
    (
        _spoil_consistent_size,
        "newer.main.color: expected uint8 array of shape (32, 48, 3), got uint8 (16, 24, 3)",
    ),
    (_spoil_unaligned, "newer.main.depth: expected an aligned array, got an unaligned float32"),
    (
        _spoil_view,
        "newer.aux[0].camera.view: expected float64 array of shape (4, 4), got float32 (4, 4)",
    ),
    (_spoil_list, "older.aux[1].color: expected uint8 array of shape (16, 24, 3), got list"),
]


@pytest.mark.parametrize(("spoil", "message"), SPOILS, ids=[s.__name__[7:] for s, _ in SPOILS])
def test_reproject_names_the_buffer_as_passed(
    spoil: Callable[[Pair], None], message: str
) -> None:
    p = _fresh()
    spoil(p)
    _raises_invalid(lambda: sr.reproject(p.older, p.newer, p.request), message)
    _raises_invalid(
        lambda: sr.reproject_alpha(p.older, p.newer, p.request.camera, p.alpha), message
    )


def test_unidirectional_names_the_frame_used() -> None:
    # ours_extrapolate at a time before `newer` extrapolates from `older`, with its backward
    # buffers: the message names `older` (the native layer sees it as its `newer`).
    p = _fresh()
    cf = p.older.aux[1]
    assert cf.motion_bwd is not None and p.request.time < p.newer.time
    cf.motion_bwd.shape = (8, 48, 3)
    _raises_invalid(
        lambda: sr.reproject(p.older, p.newer, p.request, "ours_extrapolate"),
        "older.aux[1].motion_bwd: expected float32 array of shape (16, 24, 3), "
        "got float32 (8, 48, 3)",
    )
    # Interpolating, `older` gives its forward buffers: the spoilt backward one is not read.
    sr.reproject(p.older, p.newer, p.request, "ours")


def test_pair_and_argument_errors() -> None:
    p = _fresh()
    _raises_invalid(
        lambda: sr.reproject(p.older, p.newer.main, p.request),  # type: ignore[arg-type]
        "newer: expected a ServerFrame, got CameraFrame",
    )
    _raises_invalid(
        lambda: sr.reproject_alpha(p.older, p.newer, p.request, 0.5),  # type: ignore[arg-type]
        "camera: expected a Camera, got ClientRequest",
    )
    _raises_invalid(
        lambda: sr.reproject(
            p.older, p.newer, p.request, previous=np.zeros((32, 48, 3), np.float32)
        ),
        "previous: expected uint8 array of shape (32, 48, 3), got float32 (32, 48, 3)",
    )
    cam = p.request.camera
    _set(cam, "proj", cam.proj.T)  # a transposed view: the native layer takes any strides
    sr.reproject(p.older, p.newer, p.request)
    _set(cam, "proj", cam.proj.astype(np.float32))
    _raises_invalid(
        lambda: sr.reproject(p.older, p.newer, p.request),
        "request.camera.proj: expected float64 array of shape (4, 4), got float32 (4, 4)",
    )
    _raises_invalid(
        lambda: sr.reproject_alpha(p.older, p.newer, cam, p.alpha),
        "camera.proj: expected float64 array of shape (4, 4)",
    )
    # Auxiliary cameras that differ between the frames of a pair.
    q = _fresh()
    _set(q.older, "aux", q.older.aux[:1])
    _raises_invalid(
        lambda: sr.reproject(q.older, q.newer, q.request),
        "older.aux has 1 cameras but newer.aux has 2; both frames of a pair need the same "
        "auxiliary cameras",
    )


def test_construction_names_the_field() -> None:
    p = _fresh()
    cf = p.newer.aux[1]
    with pytest.raises(
        sr.InvalidInputError,
        match=r"^CameraFrame.depth: expected float32 array of shape \(16, 24\), got float64",
    ):
        dataclasses.replace(cf, depth=cf.depth.astype(np.float64))
    # A ServerFrame checks its cameras again, naming them in the frame.
    cf.depth.dtype = np.int32  # type: ignore[misc]
    _raises_invalid(
        lambda: sr.ServerFrame(5, 0.5, p.newer.main, p.newer.aux),
        "ServerFrame.aux[1].depth: expected float32 array of shape (16, 24), got int32 (16, 24)",
    )
    _set(p.older.main, "shadow_fwd", "shadow")
    _raises_invalid(
        lambda: sr.ServerFrame(5, 0.5, p.older.main),
        "ServerFrame.main.shadow_fwd: expected ShadowBuffers or None, got str",
    )


def test_client_names_the_frame_by_its_index() -> None:
    p = _fresh()
    client = sr.Client()
    bad = _fresh().newer
    bad.aux[1].depth.dtype = np.int32  # type: ignore[misc]
    _raises_invalid(
        lambda: client.receive(bad),
        "frame.aux[1].depth: expected float32 array of shape (16, 24), got int32 (16, 24)",
    )
    assert client.held == ()
    assert client.receive(p.older) and client.receive(p.newer)
    client.render(p.request.camera, p.request.time)
    # Spoilt after it was received: the render names it by its index.
    assert p.newer.aux[1].motion_bwd is not None
    p.newer.aux[1].motion_bwd.shape = (16, 72, 1)
    _raises_invalid(
        lambda: client.render(p.request.camera, p.request.time),
        "frame(index=1).aux[1].motion_bwd: expected float32 array of shape (16, 24, 3), "
        "got float32 (16, 72, 1)",
    )


def _session(n: int) -> tuple[list[sr.ServerFrame], list[sr.Camera]]:
    scene = sr.SyntheticScene(dynamic=True)
    frames = [scene.server_frame(k, k / FPS, SMALL_W, SMALL_H, fps=FPS) for k in range(n)]
    cams = [scene.rig(i / 120, SMALL_W, SMALL_H)[0] for i in range(int((n - 1) * 120 / FPS))]
    return frames, cams


def test_play_names_the_frame_by_its_position() -> None:
    frames, cams = _session(5)
    frames[3].aux[0].color.shape = (24, 16, 3)
    _raises_invalid(
        lambda: sr.play(frames, cams),
        "frames[3].aux[0].color: expected uint8 array of shape (16, 24, 3), got uint8 (24, 16, 3)",
    )
    frames, cams = _session(3)

    def spoil(n: int, image: object, info: object) -> None:
        if n == 0:
            frames[1].main.depth.dtype = np.int32  # type: ignore[misc]

    # Received (checked) before client frame 0, spoilt after it: the render names it.
    _raises_invalid(
        lambda: sr.play(frames, cams, on_frame=spoil),
        "frames[1].main.depth: expected float32 array of shape (32, 48), got int32 (32, 48)",
    )


def test_play_refuses_a_camera_that_is_not_one_and_frames_out_of_order() -> None:
    frames, cams = _session(3)
    _raises_invalid(
        lambda: sr.play(frames, [cams[0], "left eye", *cams[2:]]),
        "cameras[1]: expected Camera, got str",
    )
    frames[1], frames[2] = frames[2], frames[1]
    _raises_invalid(
        lambda: sr.play(frames, cams),
        f"frames[2]: time {frames[2].time:g} s is before frames[1]'s {frames[1].time:g} s; "
        "expected the frames in time order",
    )
    frames, cams = _session(3)
    _raises_invalid(
        lambda: sr.play(frames, cams, frame_sizes=[1000, 1000]),
        "frame_sizes: expected a size for frame 2, got 2 sizes",
    )


def test_bindings_check_their_arguments_themselves() -> None:
    # The Python layer checks these first; the extension module checks them again for a caller
    # of _native itself, and must never panic or return NaN matrices.
    for args, problem in [
        ((0.0, 1.0, 0.1, 10.0), "fov_y_deg: expected a value in (0, 180), got 0"),
        ((180.0, 1.0, 0.1, 10.0), "fov_y_deg: expected a value in (0, 180), got 180"),
        ((60.0, math.nan, 0.1, 10.0), "aspect: expected a finite value > 0, got NaN"),
        ((60.0, 0.0, 0.1, 10.0), "aspect: expected a finite value > 0, got 0"),
        ((60.0, 1.0, 10.0, 10.0), "near, far: expected 0 < near < far (finite), got near = 10"),
        ((60.0, 1.0, 0.1, math.inf), "near, far: expected 0 < near < far (finite), got near"),
    ]:
        _raises_invalid(lambda: _native.perspective(*args), problem)
    for eye, target, up in [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None),
                            ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0)),
                            ((math.nan, 0.0, 0.0), (0.0, 0.0, -1.0), None)]:
        _raises_invalid(lambda: _native.look_at(eye, target, up),
                        "must be finite, eye != target, and up not parallel")
    # The synthetic scene's interval and rig.
    cam = _native.synthetic_rig((0.0, 1.0, 0.0), (0.0, 1.0, -1.0), 8, 4)[0]
    for interval, shown in [(0.0, "0"), (-0.1, "-0.1"), (math.inf, "inf"), (math.nan, "NaN")]:
        _raises_invalid(lambda: _native.synthetic_render_server(True, cam, 0.0, interval, 1),
                        f"interval: expected a finite value > 0, got {shown}")
    for eye, target in [((0.0, 1.0, 0.0), (0.0, 1.0, 0.0)),
                        ((0.0, math.inf, 0.0), (0.0, 1.0, 1.0))]:
        _raises_invalid(lambda: _native.synthetic_rig(eye, target, 8, 4),
                        "must be finite and distinct")
    _raises_invalid(lambda: _native.ssim(np.zeros((4, 4, 3)), np.zeros((4, 5, 3))),
                    "x and y: expected the same shape, got [4, 4, 3] and [4, 5, 3]")
    # A placed model's scale and speed, before its file is looked for.
    for scale, speed, problem in [(0.0, 1.0, "models[0]: scale must be a finite value > 0, got 0"),
                                  (math.inf, 1.0, "models[0]: scale must be a finite value > 0"),
                                  (1.0, 0.0, "models[0]: speed must be > 0, got 0")]:
        model = ("missing.glb", (0.0, 0.0, 0.0), 0.0, scale, None, 0.0, speed)
        _raises_invalid(lambda: _native.Scene("courtyard", "static", [model]), problem)
    # A matrix is a 4x4 float64 array (any strides), nothing else.
    for bad in (np.eye(3), np.eye(4, dtype=np.float32), np.eye(4)[None]):
        _raises_invalid(lambda: _native.singular_camera(bad, np.eye(4)),
                        "view: expected float64 array of shape (4, 4), got")
    assert _native.singular_camera(np.eye(8)[::2, ::2], np.eye(4)) is None
    # The shadow tile's chroma planes must agree with each other.
    luma = np.zeros((4, 8), np.uint8)
    _raises_invalid(
        lambda: _native.shadow_colour(luma, np.zeros((4, 8), np.uint8), np.zeros((2, 8), np.uint8),
                                      0, 0, np.ones((4, 8), np.uint32)),
        "cr: expected the shape of cb [4, 8], got [2, 8]",
    )
    frames, _ = _session(1)
    cf = frames[0].main
    _raises_invalid(
        lambda: _native.scene_flow(
            cf.camera.view, cf.camera.proj, cf.depth, None, cf.camera.to_native(), math.inf
        ),
        "w: expected a finite float, got inf",
    )


def test_encode_names_the_buffer() -> None:
    frames, _ = _session(1)
    frames[0].aux[0].color.dtype = np.int8  # type: ignore[misc]
    with sr.StreamEncoder(sr.CodecConfig(uncompressed=True, fps=FPS)) as enc:
        _raises_invalid(
            lambda: enc.encode(frames[0]),
            "frame.aux[0].color: expected uint8 array of shape (16, 24, 3), got int8 (16, 24, 3)",
        )


def test_building_blocks_name_the_buffer() -> None:
    p = _fresh()
    cf = p.newer.main
    assert cf.motion_bwd is not None and cf.shadow_bwd is not None
    cf.motion_bwd.dtype = np.int32  # type: ignore[misc]
    _raises_invalid(
        lambda: sr.scene_flow(cf, p.request.camera, 0.5, direction="backward"),
        "source.motion_bwd: expected float32 array of shape (32, 48, 3), got int32 (32, 48, 3)",
    )
    sr.scene_flow(cf, p.request.camera, 0.5, direction="forward")
    shadow = cf.shadow_bwd
    shadow.bits.shape = (16, 96)
    _raises_invalid(
        lambda: sr.apply_shadows(cf.color, shadow, 0.5, role="newer"),
        "shadow.bits: expected uint32 array of shape (32, 48), got uint32 (16, 96)",
    )
    _raises_invalid(
        lambda: sr.apply_shadows(cf.depth, p.older.main.shadow_fwd, 0.5),  # type: ignore[arg-type]
        "frame_color: expected uint8 array of shape (H, W, 3), got float32 (32, 48)",
    )


@pytest.mark.skipif(not sr.gpu.available(), reason="no wgpu adapter")
def test_gpu_names_the_buffer_as_passed() -> None:
    p = _fresh()
    _spoil_motion_bwd_shape(p)
    message = (
        "newer.aux[1].motion_bwd: expected float32 array of shape (16, 24, 3), "
        "got float32 (16, 72, 1)"
    )
    _raises_invalid(lambda: sr.reproject(p.older, p.newer, p.request, backend="wgpu"), message)
    _raises_invalid(lambda: sr.gpu.GpuReprojector().load(p.older, p.newer), message)
    q = _fresh()
    client = sr.Client(backend="wgpu")
    assert client.receive(q.older) and client.receive(q.newer)
    _spoil_aux_depth_dtype(q)
    _raises_invalid(
        lambda: client.render(q.request.camera, q.request.time),
        "frame(index=1).aux[1].depth: expected float32 array of shape (16, 24), got int32",
    )


def test_entry_check_runs_the_full_check_only_on_a_size_mismatch(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """What the hot path adds before the native call reads shapes only (the native layer checks
    the rest, and the full Python check, which reads every buffer, runs only on its errors):
    frames that agree with their cameras never reach that check; a depth of another size than
    its camera, the one mismatch the native layer cannot see, does. (It was a timed test.)"""
    import splitrender.types as types
    from splitrender.types import FrameArgument, precheck_frames

    p = _fresh()
    checked: list[str] = []
    monkeypatch.setattr(types, "check_server_frame", lambda path, *_: checked.append(path))
    args = (
        FrameArgument("older", "older", p.older, "fwd"),
        FrameArgument("newer", "newer", p.newer, "bwd"),
    )
    precheck_frames(args)
    assert checked == []
    camera = p.newer.aux[1].camera
    _set(camera, "width", camera.width + 1)
    precheck_frames(args)
    assert checked == ["newer"]


def test_native_message_gets_the_path_and_the_direction() -> None:
    """A native error about a buffer that the Python checks pass (one they cannot see, e.g. an
    array another thread holds mutably borrowed) keeps the native message, its frame named by the
    caller's path and ``motion``/``shadow`` by the direction that frame gave (the messages above
    all come from the Python checks, which run first)."""
    from splitrender.types import FrameArgument, native_error

    p = _fresh()
    args = (
        FrameArgument("older", "older", p.older, "fwd"),
        FrameArgument("newer", "frames[3]", p.newer, "bwd"),
    )
    for native, want in (
        ("newer.aux[1].motion: busy", "frames[3].aux[1].motion_bwd: busy"),
        ("older.main.shadow.s_min: busy", "older.main.shadow_fwd.s_min: busy"),
        ("newer.main.depth: busy", "frames[3].main.depth: busy"),
    ):
        got = native_error(sr.InvalidInputError(native), args)
        assert type(got) is sr.InvalidInputError and str(got) == want
    # An error about no frame comes back as it was.
    other = sr.InvalidInputError("alpha = 5 is outside the supported range")
    assert native_error(other, args) is other
