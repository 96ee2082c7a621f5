"""Client-side reprojection: one display frame from the server frames the client holds.

:func:`reproject` works in times (it picks the frames, their directional buffers and ``α``);
:func:`reproject_alpha` is the core's entry point with an explicit ``α``; :func:`prepare_pair`
does a pair's client-independent work ahead of its first client frame.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, TypeVar, overload

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
import splitrender.gpu as gpu
from splitrender.errors import InvalidInputError
from splitrender.types import (
    Camera,
    CameraFrame,
    ClientRequest,
    FrameArgument,
    Reprojection,
    ReprojectOptions,
    ServerFrame,
    ShadowBuffers,
    check_camera_frame,
    check_image,
    check_shadow,
    interpolates,
    native_error,
    precheck_frames,
)
from splitrender.types import (  # argument checks
    BOOL,
    checked,
    floats,
    ints,
    optional,
    strs,
)

__all__ = [
    "MAX_PREPARE_THREADS",
    "METHODS",
    "apply_shadows",
    "prepare_pair",
    "reproject",
    "reproject_alpha",
    "scene_flow",
]

#: Every method, by name, in the order of the paper's tables.
METHODS: tuple[str, ...] = tuple(_native.METHODS)

#: The most threads :func:`prepare_pair` runs its pool on (the native module's bound).
MAX_PREPARE_THREADS: int = _native.MAX_PREPARE_THREADS

_Image = npt.NDArray[np.uint8]
_T = TypeVar("_T")


def _check_method(method: object) -> str:
    if not isinstance(method, str) or method not in METHODS:
        raise InvalidInputError(
            f"unknown method {method!r}; expected one of: {', '.join(METHODS)}"
        )
    return method


def _check_frame(where: str, frame: object, *, optional: bool = False) -> None:
    if frame is None and optional:
        return
    if not isinstance(frame, ServerFrame):
        want = "a ServerFrame or None" if optional else "a ServerFrame"
        raise InvalidInputError(f"{where}: expected {want}, got {type(frame).__name__}")


def _options(options: ReprojectOptions | None) -> ReprojectOptions:
    if options is None:
        return ReprojectOptions()
    if not isinstance(options, ReprojectOptions):
        raise InvalidInputError(
            f"options: expected ReprojectOptions or None, got {type(options).__name__}"
        )
    return options


def _result(
    out: _Image | tuple[_Image, npt.NDArray[np.uint8], npt.NDArray[np.float32]],
) -> _Image | Reprojection:
    if isinstance(out, tuple):
        return Reprojection(*out)
    return out


@overload
def reproject_alpha(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    alpha: float,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: Literal[False] = ...,
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> _Image: ...
@overload
def reproject_alpha(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    alpha: float,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: Literal[True],
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> Reprojection: ...
@overload
def reproject_alpha(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    alpha: float,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: bool = ...,
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> _Image | Reprojection: ...
# NaN and infinities reach the core, which names the range the method supports.
@checked(alpha=floats(finite=False), diagnostics=BOOL)
def reproject_alpha(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    alpha: float,
    method: str = "ours",
    *,
    options: ReprojectOptions | None = None,
    previous: _Image | None = None,
    diagnostics: bool = False,
    history: _native.BidirHistory | None = None,
    backend: str = "cpu",
) -> _Image | Reprojection:
    """One client frame at ``camera`` and an explicit ``alpha``, with the core's pair semantics.

    ``older`` is ``F_t`` and contributes its forward buffers (``motion_fwd``, ``shadow_fwd``);
    ``newer`` is ``F_{t+1}`` and contributes its backward buffers. ``alpha ∈ [0, 1)``
    interpolates, ``alpha ∈ [1, 3]`` extrapolates from ``newer`` (seeds/000 §3.5). The
    unidirectional methods (``ours_extrapolate``, ``forward_splat`` unless
    ``options.splat_bidirectional``) need ``alpha >= 1`` and use ``newer`` alone; ``timewarp``
    uses ``older`` when ``alpha < 1`` and ``newer`` otherwise; ``backward_bidir`` needs both and
    ``alpha <= 1``.

    ``previous`` (``uint8[H, W, 3]`` at the camera's size) is the previous client frame: pixels
    without a match keep its colour (black when ``None``). It is copied, never modified.
    ``history`` (a :class:`BidirHistory`, one per server-frame pair, ``reset()`` when the pair
    changes) carries state between the client frames of one pair: ``backward_bidir``'s previous
    B-frame and its full flows of the pair, and for ``ours``, ``ours_extrapolate`` and
    ``forward_splat`` the work that does not depend on the client pose (Algorithm 2's
    correspondences, the auxiliary cameras' visibility in main), which is then done once per pair
    instead of once per call. For those three the images are the same with or without it
    (without it each call does that work again); for ``backward_bidir`` the previous B-frame
    seeds the search (seeds/001's latest-frame initialisation). Do not modify a frame's arrays
    in place while a history holds its pair. The history keeps the arrays of the pair of its
    last call alive until the next call or ``reset()`` (a pair given new arrays is a new pair,
    even where the old ones were); a call that fails forgets the pair's state.
    ``backend`` is ``"cpu"`` (reproj-core) or ``"wgpu"`` (the GPU path, :mod:`splitrender.gpu`:
    ``ours``, ``ours_extrapolate`` and ``forward_splat``, the same images; this per-call form
    uploads the frames every time, :class:`splitrender.gpu.GpuReprojector` keeps them on the
    device).

    Returns the image (``uint8[H, W, 3]``), or a :class:`Reprojection` with per-pixel
    diagnostics when ``diagnostics`` is true.

    Raises:
        InvalidInputError: for any invalid argument (it names the argument or buffer), or a
            method the backend cannot run.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """
    return _reproject_alpha(
        older,
        newer,
        camera,
        alpha,
        method,
        options=options,
        previous=previous,
        diagnostics=diagnostics,
        history=history,
        backend=backend,
    )


def _reproject_alpha(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    alpha: float,
    method: str,
    *,
    options: ReprojectOptions | None,
    previous: _Image | None,
    diagnostics: bool,
    history: _native.BidirHistory | None,
    backend: str,
    paths: tuple[str, str] = ("older", "newer"),
    camera_path: str = "camera",
) -> _Image | Reprojection:
    """:func:`reproject_alpha` for callers that know the frames by other names: ``paths`` (for
    ``older`` and ``newer``) and ``camera_path`` start the messages about their buffers."""
    method = _check_method(method)
    backend = gpu.check_backend(backend, method)
    _check_call(older, newer, camera, paths, camera_path)
    opts = _options(options)
    if backend == "wgpu":
        return gpu.shared().reproject(
            older,
            newer,
            camera,
            float(alpha),
            method,
            options=opts,
            previous=previous,
            diagnostics=bool(diagnostics),
            _paths=paths,
        )
    out = _call_native(
        lambda o, n: _native.reproject(
            method,
            o,
            n,
            camera.to_native(),
            float(alpha),
            opts.to_native(),
            previous,
            bool(diagnostics),
            history,
        ),
        older,
        newer,
        paths,
        camera_path,
    )
    return _result(out)


def _check_call(
    older: object, newer: object, camera: object, paths: tuple[str, str], camera_path: str
) -> None:
    """The type checks of the frames and the camera of a native call (``paths`` and
    ``camera_path`` name them in the messages)."""
    _check_frame(paths[0], older, optional=True)
    _check_frame(paths[1], newer)
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"{camera_path}: expected a Camera, got {type(camera).__name__}")


def _call_native(
    call: Callable[[tuple[Any, list[Any]] | None, tuple[Any, list[Any]]], _T],
    older: ServerFrame | None,
    newer: ServerFrame,
    paths: tuple[str, str],
    camera_path: str,
) -> _T:
    """``call(older, newer)`` with the frames in their native form (the older frame's forward
    buffers, the newer frame's backward ones), its errors about a frame or the camera named by
    the caller's paths."""
    frames = (
        FrameArgument("older", paths[0], older, "fwd"),
        FrameArgument("newer", paths[1], newer, "bwd"),
    )
    precheck_frames(frames)
    try:
        return call(None if older is None else older.to_native("fwd"), newer.to_native("bwd"))
    except InvalidInputError as e:
        raise native_error(e, frames, client=camera_path) from None


@checked(threads=optional(ints(1, MAX_PREPARE_THREADS)))
def prepare_pair(
    older: ServerFrame | None,
    newer: ServerFrame,
    camera: Camera,
    method: str = "ours",
    *,
    options: ReprojectOptions | None = None,
    history: _native.BidirHistory,
    threads: int | None = None,
) -> None:
    """Does the work of a server-frame pair that does not depend on the client pose, into
    ``history``, ahead of the pair's first client frame.

    ``ours``, ``ours_extrapolate`` and ``forward_splat`` keep that work (Algorithm 2's
    correspondences, the auxiliary cameras' visibility in main) in the :class:`BidirHistory` and
    otherwise do it in the first :func:`reproject_alpha` call of the pair, which then costs about
    twice the others. A real-time client calls this when the pair's newer frame arrives (from a
    background thread: the GIL is released), then displays the pair's frames with the same
    ``history``, frames and ``options``; they reuse the work (``history.pair_builds`` does not
    grow) and their images are the same as without it. Work the history already holds for this
    pair is kept.

    The arguments are those of :func:`reproject_alpha`, checked the same way. With ``older``
    given, it prepares interpolation (every ``alpha < 1``) for the methods that interpolate
    (``ours``, ``forward_splat`` with ``options.splat_bidirectional``); with ``older=None`` and
    for ``ours_extrapolate`` and unidirectional ``forward_splat``, extrapolation from ``newer``
    (``alpha >= 1``: pass ``older=None`` to prepare a late frame). The work does not depend on
    ``camera`` (it is only checked). ``timewarp`` and ``backward_bidir`` have no pair work: the
    call only checks its arguments.

    ``threads`` (1 to :data:`MAX_PREPARE_THREADS`) runs the work on a dedicated pool of that
    many threads (kept for later calls), so that it neither waits behind nor delays the display
    frames on the default pool; ``None`` uses the default pool. The CPU backend only.

    Raises:
        InvalidInputError: for any invalid argument (it names the argument or buffer), or a
            history in use by another call.
    """
    method = _check_method(method)
    _check_call(older, newer, camera, ("older", "newer"), "camera")
    if not isinstance(history, _native.BidirHistory):
        raise InvalidInputError(
            f"history: expected a BidirHistory, got {type(history).__name__}"
        )
    opts = _options(options)
    _call_native(
        lambda o, n: history.prepare(
            method, o, n, camera.to_native(), opts.to_native(), threads
        ),
        older,
        newer,
        ("older", "newer"),
        "camera",
    )


def _unidirectional(method: str, opts: ReprojectOptions, older: ServerFrame | None) -> bool:
    if not interpolates(method, opts.splat_bidirectional):
        return True
    # `ours` (and bidirectional splatting) without the older frame extrapolate from the newest.
    return older is None and method in ("ours", "forward_splat")


@overload
def reproject(
    older: ServerFrame | None,
    newer: ServerFrame,
    request: ClientRequest,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: Literal[False] = ...,
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> _Image: ...
@overload
def reproject(
    older: ServerFrame | None,
    newer: ServerFrame,
    request: ClientRequest,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: Literal[True],
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> Reprojection: ...
@overload
def reproject(
    older: ServerFrame | None,
    newer: ServerFrame,
    request: ClientRequest,
    method: str = ...,
    *,
    options: ReprojectOptions | None = ...,
    previous: _Image | None = ...,
    diagnostics: bool = ...,
    history: _native.BidirHistory | None = ...,
    backend: str = ...,
) -> _Image | Reprojection: ...
@checked(diagnostics=BOOL)
def reproject(
    older: ServerFrame | None,
    newer: ServerFrame,
    request: ClientRequest,
    method: str = "ours",
    *,
    options: ReprojectOptions | None = None,
    previous: _Image | None = None,
    diagnostics: bool = False,
    history: _native.BidirHistory | None = None,
    backend: str = "cpu",
) -> _Image | Reprojection:
    """One client frame for ``request`` (its camera and display time) from the frames held.

    Bidirectional methods (``ours`` with both frames, ``backward_bidir``, ``forward_splat`` with
    ``options.splat_bidirectional``) use the pair with
    ``α = (request.time − older.time) / (newer.time − older.time)``; ``α ≥ 1`` means ``newer``
    is late and the core extrapolates from it. Unidirectional methods (``ours_extrapolate``,
    ``forward_splat``, ``timewarp``, and ``ours`` when ``older`` is ``None``) use the newest
    frame whose time is ``<= request.time``, with its backward buffers, and
    ``α = 1 + (request.time − frame.time) · options.server_fps``.

    See :func:`reproject_alpha` for ``previous``, ``diagnostics``, ``history`` and ``backend``.

    Raises:
        InvalidInputError: for any invalid argument, a request before every usable frame, or
            frames out of order.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """
    method = _check_method(method)
    backend = gpu.check_backend(backend, method)
    _check_frame("older", older, optional=True)
    _check_frame("newer", newer)
    if not isinstance(request, ClientRequest):
        raise InvalidInputError(
            f"request: expected a ClientRequest, got {type(request).__name__}"
        )
    opts = _options(options)
    t = request.time
    if older is not None and not newer.time > older.time:
        raise InvalidInputError(
            f"frames out of order: newer.time = {newer.time} must be > older.time = {older.time}"
        )
    pair: tuple[ServerFrame | None, ServerFrame]
    if _unidirectional(method, opts, older):
        held = [f for f in (newer, older) if f is not None and f.time <= t]
        if not held:
            times = ", ".join(f"{f.time}" for f in (older, newer) if f is not None)
            raise InvalidInputError(
                f"request.time = {t} is before every frame held (times {times}); "
                f"method '{method}' extrapolates from a frame at or before the request"
            )
        frame = held[0]
        pair = (None, frame)
        alpha = 1.0 + (t - frame.time) * opts.server_fps
        # The frame goes to the core as the newer one; messages name it as the caller passed it.
        paths = ("older", "newer" if frame is newer else "older")
    else:
        if older is None:
            raise InvalidInputError(f"method '{method}' needs both frames; older is None")
        pair = (older, newer)
        alpha = (t - older.time) / (newer.time - older.time)
        paths = ("older", "newer")
    return _reproject_alpha(
        pair[0],
        pair[1],
        request.camera,
        alpha,
        method,
        options=opts,
        previous=previous,
        diagnostics=diagnostics,
        history=history,
        backend=backend,
        paths=paths,
        camera_path="request.camera",
    )


@checked(w=floats(), direction=strs("forward", "backward"))
def scene_flow(
    source: CameraFrame,
    client: Camera,
    w: float,
    *,
    direction: Literal["forward", "backward"] = "forward",
) -> npt.NDArray[np.float32]:
    """The scene flow of every pixel of ``source`` to the ``client`` camera with a fraction ``w``
    of its object motion applied (seeds/000 eq. 1): eq. 12 is ``direction="forward"`` (the older
    frame's ``motion_fwd``) with ``w = α``, eq. 13 ``direction="backward"`` (the newer frame's
    ``motion_bwd``) with ``w = 1 − α``.

    Returns ``float32[H, W, 3]`` of ``[Δx, Δy, ΔZ]`` in NDC; NaN where the pixel is invalid or
    the moved point is behind the client camera.
    """
    d = "fwd" if direction == "forward" else "bwd"
    check_camera_frame("source", source, (d,))
    if not isinstance(client, Camera):
        raise InvalidInputError(f"client: expected a Camera, got {type(client).__name__}")
    motion = source.motion_fwd if d == "fwd" else source.motion_bwd
    c = source.camera
    return _native.scene_flow(
        c.view,
        c.proj,
        source.depth,
        motion,
        client.to_native(),
        float(w),
    )


@checked(alpha=floats(), subframes=ints(1, 16), role=strs("older", "newer"))
def apply_shadows(
    frame_color: _Image,
    shadow: ShadowBuffers,
    alpha: float,
    *,
    subframes: int = 4,
    role: Literal["older", "newer"] = "older",
) -> _Image:
    """``frame_color`` (``uint8[H, W, 3]``) with its dynamic shadows at ``alpha`` applied
    (seeds/000 eqs. 9–11). ``role="older"`` for forward buffers (subframe ``j`` at
    ``t + j/S``), ``"newer"`` for backward buffers (at ``t+1 − j/S``)."""
    h, w = check_image("frame_color", frame_color, np.uint8, 3)
    check_shadow("shadow", shadow, h, w)
    return _native.apply_shadows(
        frame_color,
        shadow.bits,
        shadow.s_min,
        shadow.s_max,
        float(alpha),
        subframes,
        role,
    )
