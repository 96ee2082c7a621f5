"""The Python API: data model validation, options, result shapes, and the package surface."""

from __future__ import annotations

import ast
import copy
import dataclasses
import gc
import importlib
import io
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
import numpy_ref
from conftest import FPS, Pair

import splitrender as sr
from splitrender import _native
from splitrender.cli import main as cli_main
from splitrender.imageio import caption_height, encode_png, montage, write_png

EXPECTED_METHODS = ("ours", "ours_extrapolate", "forward_splat", "timewarp", "backward_bidir")


def _cam(w: int = 8, h: int = 6) -> sr.Camera:
    return sr.Camera.look_at((0, 0, 2), (0, 0, 0), width=w, height=h)


# ------------------------------------------------------------------------------------------
# Package surface


def test_methods_and_version() -> None:
    assert sr.METHODS == EXPECTED_METHODS
    assert tuple(_native.METHODS) == EXPECTED_METHODS
    assert isinstance(sr.__version__, str) and sr.__version__.count(".") >= 2


def test_all_exports_exist() -> None:
    for name in sr.__all__:
        assert hasattr(sr, name), name


def _fresh(code: str) -> str:
    """Runs ``code`` in a new interpreter (nothing of the package imported yet); its stdout."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_package_imports_its_names_on_first_use() -> None:
    # `import splitrender` (and the command's `splitrender.cli`) loads none of the package's
    # modules, numpy or the native module: Ctrl-C during those imports is then the command's to
    # catch (test_cli_errors), and a script that needs one name does not pay for all of them.
    loaded = _fresh(
        "import sys\n"
        "import splitrender, splitrender.cli\n"
        "print(sorted(m for m in sys.modules if m.startswith(('splitrender', 'numpy'))))\n"
    )
    assert loaded.strip() == "['splitrender', 'splitrender.cli']"
    # Each name is its module's object; the table of homes names exactly the public names.
    assert set(sr._HOME) == set(sr.__all__)
    for name in sr.__all__:
        assert getattr(sr, name) is getattr(importlib.import_module(sr._HOME[name]), name), name
    assert set(sr.__all__) <= set(dir(sr))
    with pytest.raises(AttributeError, match="no attribute 'reprojet'"):
        _ = sr.reprojet  # type: ignore[attr-defined]
    # A submodule is reached from a bare `import splitrender`, as when the package imported
    # everything (`sr.gpu.available()` in scripts and tests).
    assert _fresh("import splitrender\nprint(splitrender.gpu.__name__)\n").strip() == (
        "splitrender.gpu")


def test_the_reproject_function_keeps_its_name_when_its_module_loads() -> None:
    # `splitrender.reproject` is a module and the package's public function: importing the
    # module (which the package's own modules do first) must not put it in the function's place.
    kinds = _fresh(
        "import splitrender.reproject\n"
        "import splitrender as sr\n"
        "from splitrender import reproject\n"
        "import splitrender.client\n"
        "print(type(sr.reproject).__name__, type(reproject).__name__,\n"
        "      sr.reproject is splitrender.reproject, 'reproject' in dir(sr))\n"
        "from splitrender import *\n"
        "print(callable(reproject), sorted(sr.__all__) == sorted(k for k in sr.__all__\n"
        "      if k in globals()))\n"
    )
    assert kinds.split("\n")[:2] == ["function function True True", "True True"]


def test_exception_hierarchy() -> None:
    assert issubclass(sr.InvalidInputError, sr.SplitRenderError)
    assert issubclass(sr.InvalidInputError, ValueError)
    assert issubclass(sr.StreamError, sr.SplitRenderError)
    assert issubclass(sr.SplitRenderError, Exception)
    assert not issubclass(sr.StreamError, ValueError)
    for cls in (sr.SplitRenderError, sr.InvalidInputError, sr.StreamError):
        assert cls.__module__ == "splitrender.errors"
    from splitrender import errors

    assert errors.InvalidInputError is _native.InvalidInputError


def _stub_names() -> set[str]:
    stub = Path(sr.__file__).with_name("_native.pyi")
    names: set[str] = set()
    for node in ast.parse(stub.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return {
        n for n in names if not n.startswith("_") or n.startswith("__")
        or n in ("_panic_for_test", "_wgpu_lose_device_for_test")
    }


def test_stub_matches_module() -> None:
    """Every public name of ``_native`` is in the stub and vice versa (``mypy.stubtest`` in
    scripts/test.sh checks the signatures too)."""
    runtime = set(_native.__all__)
    assert _stub_names() == runtime
    assert Path(sr.__file__).with_name("py.typed").exists()


# ------------------------------------------------------------------------------------------
# Data model validation


def test_camera_look_at_and_immutability() -> None:
    c = _cam(8, 6)
    assert c.view.dtype == np.float64 and c.view.shape == (4, 4)
    np.testing.assert_array_equal(c.proj, _native.perspective(60.0, 8 / 6, 0.1, 100.0))
    np.testing.assert_array_equal(c.view, _native.look_at((0, 0, 2), (0, 0, 0)))
    assert c.shape == (6, 8)
    # Every argument reaches the matrices.
    c3 = sr.Camera.look_at((1, 2, 3), (0, 0, 0), fov_y_deg=45.0, width=8, height=6, near=0.5,
                           far=50.0, up=(1, 0, 0))
    np.testing.assert_array_equal(c3.proj, _native.perspective(45.0, 8 / 6, 0.5, 50.0))
    np.testing.assert_array_equal(c3.view, _native.look_at((1, 2, 3), (0, 0, 0), (1, 0, 0)))
    assert not np.array_equal(c3.view, _native.look_at((1, 2, 3), (0, 0, 0)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.width = 3  # type: ignore[misc]
    with pytest.raises(ValueError):
        c.view[0, 0] = 2.0  # read-only copy
    # Lists are accepted for matrices and copied.
    m = np.eye(4)
    c2 = sr.Camera(m.tolist(), m, 4, 4)
    m[0, 0] = 5.0
    assert c2.proj[0, 0] == 1.0


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"width": 0}, "Camera.width: expected an int in [1, 16384], got 0"),
        ({"height": 20000}, "Camera.height"),
        ({"width": 4.0}, "Camera.width: expected an int, got float"),
        ({"width": True}, "Camera.width: expected an int, got bool"),
        (
            {"view": np.eye(3)},
            "Camera.view: expected float64 array of shape (4, 4), got float64 (3, 3)",
        ),
        ({"proj": np.full((4, 4), np.nan)}, "Camera.proj: expected finite values"),
        ({"view": "abc"}, "Camera.view"),
        # Refused, not cast: numpy drops the imaginary part with only a warning.
        (
            {"view": np.eye(4) + 1j},
            "Camera.view: expected a 4x4 matrix of floats, got complex128 (4, 4)",
        ),
    ],
)
def test_camera_validation(kwargs: dict[str, object], fragment: str) -> None:
    args: dict[str, object] = {"view": np.eye(4), "proj": np.eye(4), "width": 4, "height": 4}
    args.update(kwargs)
    with pytest.raises(sr.InvalidInputError) as e:
        sr.Camera(**args)  # type: ignore[arg-type]
    assert fragment in str(e.value)


def test_camera_frame_validation() -> None:
    c = _cam(8, 6)
    color = np.zeros((6, 8, 3), np.uint8)
    depth = np.zeros((6, 8), np.float32)
    sr.CameraFrame(c, color, depth)
    with pytest.raises(
        sr.InvalidInputError,
        match=r"CameraFrame.color: expected uint8 array of shape \(6, 8, 3\), got float32 \(6, 8, 3\)",
    ):
        sr.CameraFrame(c, color.astype(np.float32), depth)  # type: ignore[arg-type]
    with pytest.raises(
        sr.InvalidInputError,
        match=r"CameraFrame.depth: expected float32 array of shape \(6, 8\), got float32 \(8, 6\)",
    ):
        sr.CameraFrame(c, color, depth.T.copy())
    with pytest.raises(
        sr.InvalidInputError, match="CameraFrame.depth: expected a C-contiguous array"
    ):
        sr.CameraFrame(c, color, np.zeros((6, 16), np.float32)[:, ::2])
    buf = np.zeros(depth.nbytes + 1, np.uint8)
    unaligned = np.frombuffer(buf.data, np.float32, depth.size, offset=1).reshape(depth.shape)
    with pytest.raises(sr.InvalidInputError, match="CameraFrame.depth: expected an aligned array"):
        sr.CameraFrame(c, color, unaligned)
    with pytest.raises(sr.InvalidInputError, match="CameraFrame.motion_bwd"):
        sr.CameraFrame(c, color, depth, motion_bwd=np.zeros((6, 8, 2), np.float32))
    with pytest.raises(
        sr.InvalidInputError, match="CameraFrame.color: expected uint8 array of shape .*, got list"
    ):
        sr.CameraFrame(c, [[0]], depth)  # type: ignore[arg-type]
    small = sr.ShadowBuffers(
        np.zeros((2, 2), np.uint32), np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2, 3), np.uint8)
    )
    with pytest.raises(
        sr.InvalidInputError, match=r"CameraFrame.shadow_fwd: expected buffers of shape \(6, 8\)"
    ):
        sr.CameraFrame(c, color, depth, shadow_fwd=small)
    with pytest.raises(sr.InvalidInputError, match="CameraFrame.camera: expected a Camera"):
        sr.CameraFrame(None, color, depth)  # type: ignore[arg-type]


def test_shadow_buffers_validation() -> None:
    bits = np.zeros((2, 3), np.uint32)
    rgb = np.zeros((2, 3, 3), np.uint8)
    sr.ShadowBuffers(bits, rgb, rgb)
    with pytest.raises(
        sr.InvalidInputError,
        match=r"ShadowBuffers.bits: expected uint32 array of shape \(2, 3\), got int64 \(2, 3\)",
    ):
        sr.ShadowBuffers(bits.astype(np.int64), rgb, rgb)  # type: ignore[arg-type]
    with pytest.raises(
        sr.InvalidInputError,
        match=r"ShadowBuffers.s_max: expected uint8 array of shape \(2, 3, 3\)",
    ):
        sr.ShadowBuffers(bits, rgb, np.zeros((3, 2, 3), np.uint8))


def test_server_frame_and_request_validation(pair: Pair) -> None:
    f = sr.ServerFrame(3, 0.3, pair.older.main, [pair.older.aux[0]])  # type: ignore[arg-type]
    assert isinstance(f.aux, tuple) and len(f.aux) == 1
    with pytest.raises(sr.InvalidInputError, match="ServerFrame.index"):
        sr.ServerFrame(-1, 0.0, pair.older.main)
    with pytest.raises(
        sr.InvalidInputError, match="ServerFrame.time: expected a finite float, got nan"
    ):
        sr.ServerFrame(0, float("nan"), pair.older.main)
    with pytest.raises(sr.InvalidInputError, match=r"ServerFrame.aux\[0\]: expected a CameraFrame"):
        sr.ServerFrame(0, 0.0, pair.older.main, (None,))  # type: ignore[arg-type]
    with pytest.raises(sr.InvalidInputError, match="ClientRequest.time"):
        sr.ClientRequest(pair.request.camera, float("inf"))
    with pytest.raises(sr.InvalidInputError, match="ClientRequest.camera"):
        sr.ClientRequest("cam", 0.0)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------
# Options


def test_options_defaults_match_design() -> None:
    o = sr.ReprojectOptions()
    assert (o.eps_e, o.eps_z, o.eps_o, o.aux_threshold_scale) == (0.002, 0.001, 0.01, 4.0)
    assert (o.window, o.fpi_iterations, o.bidir_iterations, o.shadow_subframes) == (1, 3, 3, 4)
    assert (o.use_shadows, o.use_aux, o.blend, o.splat_bidirectional) == (True, True, True, False)
    assert o.server_fps == 10.0


def test_options_integer_ranges_are_inclusive() -> None:
    # Both ends of each range are taken (one past them is refused: test_options_validation).
    for name, lo, hi in (("window", 0, 8), ("fpi_iterations", 0, 32),
                         ("bidir_iterations", 0, 32), ("shadow_subframes", 1, 16)):
        for v in (lo, hi):
            assert getattr(sr.ReprojectOptions().replace(**{name: v}), name) == v


def test_options_round_trip() -> None:
    o = sr.ReprojectOptions(eps_e=0.004, window=2, blend=False, server_fps=20)
    assert sr.ReprojectOptions(**dataclasses.asdict(o)) == o
    assert o.replace(window=0) == sr.ReprojectOptions(
        eps_e=0.004, window=0, blend=False, server_fps=20
    )
    assert isinstance(o.server_fps, float)
    with pytest.raises(sr.InvalidInputError, match=r"ReprojectOptions.replace: unknown options "
                       r"\['eps'\]; expected some of eps_e, "):
        o.replace(eps=0.1)
    native = o.to_native()
    assert "server_fps" not in native
    assert set(native) | {"server_fps"} == {f.name for f in dataclasses.fields(o)}
    # The native module accepts exactly these keys.
    with pytest.raises(sr.InvalidInputError) as e:
        _native.reproject("ours", None, None, None, 1.0, {"x": 1})  # type: ignore[arg-type]
    assert "valid options: " + ", ".join(native) in str(e.value)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("eps_e", 0.0),
        ("eps_z", -1.0),
        ("eps_o", float("nan")),
        ("aux_threshold_scale", "4"),
        ("window", 9),
        ("window", 1.5),
        ("fpi_iterations", 33),
        ("bidir_iterations", -1),
        ("shadow_subframes", 0),
        ("shadow_subframes", 17),
        ("use_shadows", 1),
        ("use_aux", 1),
        ("blend", None),
        ("splat_bidirectional", "yes"),
        ("server_fps", 0.0),
        ("server_fps", float("inf")),
        # One past an end of the integer ranges (ReprojectOptions documents 0..8, 0..32, 1..16).
        ("window", -1),
        ("fpi_iterations", -1),
        ("bidir_iterations", 33),
        # Beyond float32, which the kernels take them as: inf and 0 there, and every call
        # refused naming a value the caller never gave.
        ("eps_e", 1e300),
        ("eps_z", 1e-50),
        ("aux_threshold_scale", 3.5e38),
    ],
)
def test_options_validation(name: str, value: object) -> None:
    with pytest.raises(sr.InvalidInputError, match=f"ReprojectOptions.{name}: expected"):
        sr.ReprojectOptions(**{name: value})  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------
# Reprojection results


@pytest.mark.parametrize("method", EXPECTED_METHODS)
def test_reproject_shapes(pair: Pair, method: str) -> None:
    h, w = pair.request.camera.shape
    img = sr.reproject(pair.older, pair.newer, pair.request, method)
    assert isinstance(img, np.ndarray)
    assert img.dtype == np.uint8 and img.shape == (h, w, 3) and img.flags.c_contiguous
    r = sr.reproject(pair.older, pair.newer, pair.request, method, diagnostics=True)
    assert isinstance(r, sr.Reprojection)
    assert r.image.shape == (h, w, 3) and r.image.dtype == np.uint8
    assert r.source.shape == (h, w) and r.source.dtype == np.uint8
    assert r.error.shape == (h, w) and r.error.dtype == np.float32
    assert r.matched.dtype == np.bool_
    np.testing.assert_array_equal(r.image, img)
    # Unmatched pixels carry no error.
    assert np.isnan(r.error[r.source == sr.Reprojection.SOURCE_NONE]).all()


def test_reproject_covers_most_pixels(pair: Pair) -> None:
    r = sr.reproject(pair.older, pair.newer, pair.request, "ours", diagnostics=True)
    # Measured: every pixel (the client pose lies between the server poses); 0.9 let a tenth of
    # the image go unmatched.
    assert r.matched.mean() > 0.99


def _top_half_invalid(frame: sr.ServerFrame) -> sr.ServerFrame:
    """``frame`` with NaN depth in the top half of every camera: no source for those pixels."""
    def cam(c: sr.CameraFrame) -> sr.CameraFrame:
        depth = c.depth.copy()
        depth[: depth.shape[0] // 2] = np.nan
        return dataclasses.replace(c, depth=depth)
    return dataclasses.replace(frame, main=cam(frame.main), aux=tuple(map(cam, frame.aux)))


@pytest.mark.parametrize("method", EXPECTED_METHODS)
def test_previous_is_copied_not_mutated(pair: Pair, method: str) -> None:
    # Half of each server image invalid, so that the client frame has unmatched pixels (the
    # pair alone has none: checked on them, the property held for any `previous`).
    older, newer = _top_half_invalid(pair.older), _top_half_invalid(pair.newer)
    h, w = pair.request.camera.shape
    prev = np.random.default_rng(1).integers(0, 256, (h, w, 3), dtype=np.uint8)
    before = prev.copy()
    r = sr.reproject(older, newer, pair.request, method, previous=prev, diagnostics=True)
    np.testing.assert_array_equal(prev, before)
    assert r.image is not prev
    keep = r.source == sr.Reprojection.SOURCE_NONE
    assert 0.2 < keep.mean() < 0.8  # measured: 0.44 to 0.5
    np.testing.assert_array_equal(r.image[keep], prev[keep])
    # Without a previous frame, unmatched pixels are black.
    r0 = sr.reproject(older, newer, pair.request, method, diagnostics=True)
    np.testing.assert_array_equal(r0.source, r.source)
    assert (r0.image[keep] == 0).all()
    np.testing.assert_array_equal(r0.image[~keep], r.image[~keep])


def test_reproject_time_to_alpha(pair: Pair) -> None:
    cam = pair.request.camera
    a = sr.reproject(pair.older, pair.newer, pair.request, "ours")
    b = sr.reproject_alpha(pair.older, pair.newer, cam, pair.alpha, "ours")
    np.testing.assert_array_equal(a, b)
    # Unidirectional: the newest frame at or before t, alpha = 1 + (t - t_frame) * f_s.
    uni_alpha = 1.0 + (pair.request.time - pair.older.time) * FPS
    for method in ("ours_extrapolate", "forward_splat", "timewarp"):
        a = sr.reproject(pair.older, pair.newer, pair.request, method)
        b = sr.reproject_alpha(None, pair.older, cam, uni_alpha, method)
        np.testing.assert_array_equal(a, b, err_msg=method)
    # `ours` without the older frame extrapolates from the newest frame it has.
    late = sr.ClientRequest(cam, pair.newer.time + 0.02)
    a = sr.reproject(None, pair.newer, late, "ours")
    b = sr.reproject_alpha(None, pair.newer, cam, 1.0 + 0.02 * FPS, "ours")
    np.testing.assert_array_equal(a, b)
    # With both frames held and the request at or after `newer`, the newest is used (at its
    # own time too, alpha = 1), not the older one.
    for dt in (0.0, 0.02):
        req = sr.ClientRequest(cam, pair.newer.time + dt)
        a = sr.reproject(pair.older, pair.newer, req, "ours_extrapolate")
        b = sr.reproject_alpha(None, pair.newer, cam, 1.0 + dt * FPS, "ours_extrapolate")
        np.testing.assert_array_equal(a, b, err_msg=str(dt))
    # alpha scales with options.server_fps (the default is FPS; not with timewarp, which
    # reads no motion and gives the same image at every alpha), ...
    fast = sr.ReprojectOptions(server_fps=2 * FPS)
    a = sr.reproject(pair.older, pair.newer, pair.request, "ours_extrapolate", options=fast)
    alpha = 1.0 + (pair.request.time - pair.older.time) * 2 * FPS
    b = sr.reproject_alpha(None, pair.older, cam, alpha, "ours_extrapolate", options=fast)
    np.testing.assert_array_equal(a, b)
    # ... and a pair's alpha with its frames' times (here two periods apart), not f_s.
    far = dataclasses.replace(pair.newer, time=2 / FPS)
    a = sr.reproject(pair.older, far, pair.request, "ours")
    b = sr.reproject_alpha(pair.older, far, cam, pair.request.time * FPS / 2, "ours")
    np.testing.assert_array_equal(a, b)


def test_alpha_is_refused_as_given_not_as_rounded(pair: Pair) -> None:
    # Narrowed to float32 first, 1e308 was reported as "inf" and 3.0000001 passed as 3.
    cam = pair.request.camera
    for alpha, shown in ((1e308, "1e308"), (3.0000001, "3.0000001"), (-1e-300, "-1e-300")):
        with pytest.raises(sr.InvalidInputError, match=f"alpha = {shown} is outside"):
            sr.reproject_alpha(pair.older, pair.newer, cam, alpha, "ours")
    sr.reproject_alpha(pair.older, pair.newer, cam, 3.0, "ours")


def test_reproject_time_errors(pair: Pair) -> None:
    early = sr.ClientRequest(pair.request.camera, pair.older.time - 0.01)
    with pytest.raises(sr.InvalidInputError, match="before every frame"):
        sr.reproject(pair.older, pair.newer, early, "ours_extrapolate")
    with pytest.raises(sr.InvalidInputError, match="frames out of order"):
        sr.reproject(pair.newer, pair.older, pair.request, "ours")
    same = dataclasses.replace(pair.newer, time=pair.older.time)  # alpha would be 0/0
    with pytest.raises(sr.InvalidInputError, match="frames out of order"):
        sr.reproject(pair.older, same, pair.request, "ours")
    with pytest.raises(sr.InvalidInputError, match="needs both frames"):
        sr.reproject(None, pair.newer, pair.request, "backward_bidir")
    with pytest.raises(sr.InvalidInputError, match="unknown method 'nope'"):
        sr.reproject(pair.older, pair.newer, pair.request, "nope")


def test_bidir_history_reused_and_reset_gives_the_images_without_one(pair: Pair) -> None:
    # backward_bidir keeps its per-pair correspondences in the history: the first call fills it,
    # the second reuses it, reset() empties it; every image equals the call without a history.
    h = sr.BidirHistory()
    assert repr(h) == "BidirHistory()"
    older = _copied(pair.older)
    fresh = sr.reproject(older, pair.newer, pair.request, "backward_bidir")
    assert fresh.shape == (*pair.request.camera.shape, 3)
    filled = sr.reproject(older, pair.newer, pair.request, "backward_bidir", history=h)
    reused = sr.reproject(older, pair.newer, pair.request, "backward_bidir", history=h)
    # The history holds the pair it keeps state for (backward_bidir counts no pair_builds, so
    # that is what shows it was given the call at all) until reset() empties it.
    depth = weakref.ref(older.main.depth)
    del older
    gc.collect()
    assert depth() is not None
    h.reset()
    gc.collect()
    assert depth() is None
    after_reset = sr.reproject(pair.older, pair.newer, pair.request, "backward_bidir", history=h)
    for image in (filled, reused, after_reset):
        np.testing.assert_array_equal(image, fresh)


@pytest.mark.parametrize("method", ["ours", "ours_extrapolate", "forward_splat"])
def test_history_through_two_pairs_gives_the_images_without_one(pair: Pair, method: str) -> None:
    # One history through the client frames of a pair (as the Client keeps it), then through the
    # next pair without a reset: every image equals the call without a history, so whatever
    # pair state the history keeps is never served to another pair. The state is built once per
    # pair and reused within it (pair_builds; 0 if the history never reached the core).
    w, h = pair.request.camera.width, pair.request.camera.height
    frames = [pair.older, pair.newer, pair.scene.server_frame(2, 2 / FPS, w, h, fps=FPS)]
    history = sr.BidirHistory()
    for k in range(2):
        older, newer = frames[k], frames[k + 1]
        # `ours` interpolates between the pair; the others extrapolate from its newer frame.
        t0 = older.time if method == "ours" else newer.time
        for n in [1, 4, 7, 11]:
            t = t0 + n / 120
            camera, _ = pair.scene.rig(t, w, h)
            req = sr.ClientRequest(camera, t)
            kept = sr.reproject(older, newer, req, method, history=history)
            fresh = sr.reproject(older, newer, req, method)
            assert np.array_equal(kept, fresh), (method, k, n)
        assert history.pair_builds == k + 1, (method, k)


def _copied(frame: sr.ServerFrame, **fields: Any) -> sr.ServerFrame:
    """``frame`` with new arrays (copies of its own), and ``fields`` replaced."""
    def cam(c: sr.CameraFrame) -> sr.CameraFrame:
        return dataclasses.replace(c, **{
            f.name: copy.deepcopy(getattr(c, f.name)) for f in dataclasses.fields(c)
            if f.name != "camera"})
    return dataclasses.replace(frame, main=cam(frame.main), aux=tuple(map(cam, frame.aux)),
                               **fields)


@pytest.mark.parametrize("method", ["ours", "ours_extrapolate", "forward_splat"])
def test_history_is_not_served_to_new_arrays_at_freed_addresses(pair: Pair, method: str) -> None:
    """The core knows its pair by the cameras and the buffers' addresses: a pair freed after a
    call, and another pair of the same cameras and sizes made in its place (the allocator
    gives it the same addresses), gets its own images, not the first pair's state. The history
    holds the arrays of the pair it keeps state for, so no other array can take their
    place. (Without that, 1357 of 1536 pixels differed for ``ours_extrapolate``.)"""
    w, h = pair.request.camera.width, pair.request.camera.height
    later = [pair.scene.server_frame(k, k / FPS, w, h, fps=FPS) for k in (5, 6)]
    # The later pair's content at the first pair's cameras, times and indices.
    second = [dataclasses.replace(
        f, index=ref.index, time=ref.time,
        main=dataclasses.replace(f.main, camera=ref.main.camera),
        aux=tuple(dataclasses.replace(a, camera=r.camera) for a, r in zip(f.aux, ref.aux)))
        for f, ref in zip(later, (pair.older, pair.newer))]
    alpha = 0.5 if method == "ours" else 1.5
    history = sr.BidirHistory()
    first = [_copied(pair.older), _copied(pair.newer)]
    sr.reproject_alpha(*first, pair.request.camera, alpha, method, history=history)
    del first
    gc.collect()
    new = [_copied(f) for f in second]
    kept = sr.reproject_alpha(*new, pair.request.camera, alpha, method, history=history)
    fresh = sr.reproject_alpha(*new, pair.request.camera, alpha, method)
    assert np.array_equal(kept, fresh)
    assert history.pair_builds == 2
    history.reset()  # lets go of the pair's arrays as well


def test_scene_flow(pair: Pair) -> None:
    src = pair.older.main
    flow = sr.scene_flow(src, src.camera, 0.0)
    h, w = src.camera.shape
    assert flow.dtype == np.float32 and flow.shape == (h, w, 3)
    # To its own camera with no object motion, every valid pixel stays where it is.
    assert np.nanmax(np.abs(flow)) < 1e-4
    moved = sr.scene_flow(src, pair.request.camera, 0.5, direction="backward")
    assert moved.shape == (h, w, 3) and np.isfinite(moved).any()
    with pytest.raises(sr.InvalidInputError, match="direction"):
        sr.scene_flow(src, src.camera, 0.0, direction="sideways")  # type: ignore[arg-type]
    # Finite, but infinite in the kernel's float32: a flow of NaN everywhere was returned.
    with pytest.raises(sr.InvalidInputError, match="w = 1e308: expected a value within float32"):
        sr.scene_flow(src, src.camera, 1e308)


def test_scene_flow_direction_takes_that_directions_motion(pair: Pair) -> None:
    """``direction="forward"`` is eq. 12 (the frame's ``motion_fwd``), ``"backward"`` eq. 13
    (its ``motion_bwd``): each is the kernel's flow with that motion buffer. The shape-only check
    above passed with the direction ignored."""
    src = pair.older.main
    cam, c = pair.request.camera, src.camera
    assert src.motion_fwd is not None and src.motion_bwd is not None
    flows = {}
    for direction, motion in (("forward", src.motion_fwd), ("backward", src.motion_bwd)):
        flows[direction] = sr.scene_flow(src, cam, 0.5, direction=direction)
        want = _native.scene_flow(c.view, c.proj, src.depth, motion, cam.to_native(), 0.5)
        np.testing.assert_array_equal(flows[direction], want, err_msg=direction)
    # Not vacuous: the two motions move the scene's pixels differently.
    differ = np.abs(flows["forward"] - flows["backward"]) > 1e-4
    assert np.nanmean(differ.any(axis=-1)) > 0.01


def test_apply_shadows(pair: Pair) -> None:
    cf = pair.older.main
    assert cf.shadow_fwd is not None
    at0 = sr.apply_shadows(cf.color, cf.shadow_fwd, 0.0)
    np.testing.assert_array_equal(at0, cf.color)
    mid = sr.apply_shadows(cf.color, cf.shadow_fwd, 0.5, subframes=4, role="older")
    assert mid.dtype == np.uint8 and mid.shape == cf.color.shape
    # alpha, subframes and role reach the kernel: each call is eqs. 9-11 (the NumPy reference;
    # off by one only at float32 rounding ties, see test_numpy_reference.py), and not the
    # same image for the other role or subframe count.
    s = cf.shadow_fwd
    images = {}
    calls: list[tuple[float, int, Literal["older", "newer"]]] = [
        (0.5, 4, "older"), (0.25, 4, "older"), (0.25, 4, "newer"), (0.25, 3, "older")]
    for alpha, subframes, role in calls:
        got = sr.apply_shadows(cf.color, s, alpha, subframes=subframes, role=role)
        want = numpy_ref.apply_shadows(cf.color, s.bits, s.s_min, s.s_max, alpha, subframes, role)
        assert np.abs(got.astype(np.int16) - want).max() <= 1, (alpha, subframes, role)
        images[alpha, subframes, role] = got
    np.testing.assert_array_equal(images[0.5, 4, "older"], mid)
    # Not vacuous: alpha, the role (subframe 1 against 3) and S each change this frame's image.
    older = images[0.25, 4, "older"]
    for other in (mid, images[0.25, 4, "newer"], images[0.25, 3, "older"]):
        assert (older != other).any()
    with pytest.raises(sr.InvalidInputError, match="role: expected 'older' or 'newer'"):
        sr.apply_shadows(cf.color, cf.shadow_fwd, 0.5, role="middle")  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------
# Synthetic scene


def test_synthetic_scene(pair: Pair) -> None:
    scene = pair.scene
    main, (left, right) = scene.rig(0.0, 48, 32)
    assert (main.width, main.height) == (48, 32)
    assert (left.width, left.height) == (right.width, right.height) == (24, 16)
    f = pair.older
    assert f.index == 0 and f.time == 0.0 and len(f.aux) == 2
    for cf in (f.main, *f.aux):
        assert cf.motion_fwd is not None and cf.motion_bwd is not None
        assert cf.shadow_fwd is not None and cf.shadow_bwd is not None
    # Ground truth at a server camera and time is that camera's colour.
    np.testing.assert_array_equal(scene.ground_truth(f.main.camera, f.time), f.main.color)
    eye, target = sr.SyntheticScene.head_pose(0.25)
    assert len(eye) == len(target) == 3
    assert repr(sr.SyntheticScene(dynamic=False)) == "SyntheticScene(dynamic=False)"
    with pytest.raises(sr.InvalidInputError, match="dynamic"):
        sr.SyntheticScene(dynamic="yes")  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------
# PNG writer and command line


def test_png_encoding_round_trips_through_pillow(tmp_path: Path) -> None:
    from PIL import Image

    rng = np.random.default_rng(0)
    for img in (
        rng.integers(0, 256, (5, 7, 3), dtype=np.uint8),
        rng.integers(0, 256, (5, 7), dtype=np.uint8),
        rng.integers(0, 256, (5, 7, 4), dtype=np.uint8),
    ):
        data = encode_png(img)
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        with Image.open(io.BytesIO(data)) as im:
            assert im.size == (7, 5)
            np.testing.assert_array_equal(np.asarray(im), img)
    write_png(tmp_path / "x.png", img[..., 0].copy())
    with Image.open(tmp_path / "x.png") as im:
        assert im.mode == "L"  # greyscale
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]  # no temporary file left
    with pytest.raises(sr.InvalidInputError, match="expected uint8 array"):
        encode_png(img.astype(np.float32))  # type: ignore[arg-type]
    with pytest.raises(sr.InvalidInputError, match="non-empty"):
        encode_png(np.zeros((0, 3, 3), np.uint8))


def test_montage_places_tiles_unchanged_under_their_own_captions() -> None:
    rng = np.random.default_rng(1)
    tiles = [rng.integers(0, 256, (30, 40, 3), dtype=np.uint8) for _ in range(5)]
    # Without labels: the tiles row by row, 4 white pixels apart, a short last row white.
    plain = montage(tiles, columns=3)
    assert plain.shape == (2 * 30 + 4, 3 * 40 + 2 * 4, 3)
    for k, tile in enumerate(tiles):
        y, x = divmod(k, 3)
        assert np.array_equal(plain[y * 34:y * 34 + 30, x * 44:x * 44 + 40], tile), k
    assert (plain[34:, 88:] == 255).all() and (plain[30:34] == 255).all()
    # With labels: each tile moves down by its caption bar, which holds black text on white,
    # and differs with the label (the label drawn, not a fixed mark).
    labels = ["ground truth", "ours", "ours", "timewarp", ""]
    bar = caption_height(30)
    cap = montage(tiles, columns=3, labels=labels)
    assert cap.shape == (2 * (bar + 30) + 4, 3 * 40 + 2 * 4, 3)
    bars = []
    for k, tile in enumerate(tiles):
        y, x = divmod(k, 3)
        y, x = y * (bar + 34), x * 44
        assert np.array_equal(cap[y + bar:y + bar + 30, x:x + 40], tile), k
        bars.append(cap[y:y + bar, x:x + 40])
    assert all(b.min() < 64 for b in bars[:4]) and (bars[4] == 255).all()
    assert np.array_equal(bars[1], bars[2]) and not np.array_equal(bars[0], bars[1])
    assert not np.array_equal(bars[1], bars[3])
    # Captions scale with the tile (legible at 720 rows), never below 10-pixel text.
    assert caption_height(720) > 2 * caption_height(144) and caption_height(18) >= 14
    with pytest.raises(sr.InvalidInputError, match=r"tiles\[1\]: expected uint8 array of shape"):
        montage([tiles[0], tiles[1][:, :20]])
    with pytest.raises(sr.InvalidInputError, match="labels: expected one per tile"):
        montage(tiles, labels=["a"])


def test_cli_example(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert cli_main(["example", "--out", str(out), "--width", "32", "--height", "24"]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"ground_truth.png", "montage.png", *(f"{m}.png" for m in EXPECTED_METHODS)}
    text = capsys.readouterr().out
    for m in EXPECTED_METHODS:
        assert m in text
    assert "MAE" in text


def test_cli_errors_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["example", "--width", "0"], ["example", "--width", "x"], ["frobnicate"], []):
        with pytest.raises(SystemExit) as e:
            cli_main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("splitrender") and ": error: " in err, err


def test_cli_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli_main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "example" in text and "ours" in text
    with pytest.raises(SystemExit):
        cli_main(["example", "--help"])
    text = capsys.readouterr().out
    for opt in ("--out", "--width", "--height"):
        assert opt in text


def test_every_help_text_is_printed_as_written() -> None:
    # argparse %-formats help lines but not descriptions: `encode --help` showed "60 %%".
    import argparse

    from splitrender.cli.dispatch import build_parser

    def walk(p: argparse.ArgumentParser, name: str) -> Iterator[tuple[str, str]]:
        yield name, p.format_help()
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, q in action.choices.items():
                    yield from walk(q, f"{name} {sub}")

    texts = dict(walk(build_parser(), "splitrender"))
    assert len(texts) > 10 and "splitrender encode" in texts
    for name, text in texts.items():
        assert "%%" not in text and "%(" not in text, name
