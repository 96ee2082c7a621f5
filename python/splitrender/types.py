"""The typed values that flow through splitrender: cameras, server frames, requests, options, results.

Conventions (shared/DESIGN.md): world right-handed, +y up, metres; a camera looks along its -z;
images row-major ``H x W``, row 0 at the top, colour RGB8; reversed depth in ``[0, 1]`` (1 at the
near plane, 0 at the far plane); matrices 4x4 ``float64`` acting on column vectors,
``clip = proj @ view @ [x, y, z, 1]``.

Every dataclass checks its fields in ``__post_init__`` and raises
:class:`~splitrender.errors.InvalidInputError` naming the field, what was expected and what came.
Arrays are taken as they are (no silent dtype conversion, no copy) and must be C-contiguous;
only the small camera matrices are converted to read-only ``float64`` copies.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import numbers
import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.errors import InvalidInputError

__all__ = [
    "IPD",
    "MAX_INDEX",
    "MAX_SIDE",
    "MAX_SPAN",
    "Camera",
    "CameraFrame",
    "ClientRequest",
    "ReprojectOptions",
    "Reprojection",
    "ServerFrame",
    "ShadowBuffers",
]

#: Largest server-frame index (:attr:`ServerFrame.index`): an i64 for the kernels.
MAX_INDEX = 2**63 - 1
#: Largest image side the kernels accept (``reproj_core::MAX_SIDE``).
MAX_SIDE = 16384
#: Most server-frame periods a frame's motion may span (:attr:`ServerFrame.span`): a server
#: that keeps less than 1/16 of its f_s has nothing left to interpolate.
MAX_SPAN = 16
#: Most encoder or decoder threads (``CodecConfig.threads``, ``serve --encoder-threads``;
#: ``threads=10**400`` reached the thread pool).
MAX_THREADS = 1024
#: The stereo client's interpupillary distance, metres: the eyes of :meth:`Camera.stereo` and of
#: the reference renderer's stereo client frames (reproj-scene's ``rig::IPD``) are this far apart.
IPD = 0.07
#: The range of a float32 (the kernels' thresholds): its largest value, and its smallest
#: above 0 (a subnormal).
_F32_MAX = float(np.finfo(np.float32).max)
_F32_TRUE_MIN = float(np.finfo(np.float32).smallest_subnormal)

Shape = tuple[int, ...]


def describe(value: object) -> str:
    if isinstance(value, np.ndarray):
        return f"{value.dtype} {tuple(value.shape)}"
    return type(value).__name__


def check_array(
    where: str, value: object, dtype: type[np.generic], shape: Shape
) -> None:
    """Raises unless ``value`` is a C-contiguous ``dtype`` array of exactly ``shape``."""
    want = np.dtype(dtype)
    if (
        not isinstance(value, np.ndarray)
        or value.dtype != want
        or tuple(value.shape) != tuple(shape)
    ):
        raise InvalidInputError(
            f"{where}: expected {want} array of shape {tuple(shape)}, got {describe(value)}"
        )
    if not value.flags.c_contiguous:
        raise InvalidInputError(
            f"{where}: expected a C-contiguous array, got a non-contiguous {describe(value)} "
            "view (pass numpy.ascontiguousarray(...))"
        )
    if not value.flags.aligned:
        raise InvalidInputError(
            f"{where}: expected an aligned array, got an unaligned {describe(value)} buffer "
            "(pass numpy.array(..., copy=True))"
        )


def check_image(
    where: str, value: object, dtype: type[np.generic], channels: int | None = None
) -> tuple[int, int]:
    """Raises unless ``value`` is a :func:`check_array` ``dtype`` array of shape ``(H, W)``
    (``(H, W, channels)`` with ``channels``) for some ``H, W``; returns ``(H, W)``."""
    ndim, shape = (2, "(H, W)") if channels is None else (3, f"(H, W, {channels})")
    if not isinstance(value, np.ndarray) or value.ndim != ndim:
        raise InvalidInputError(
            f"{where}: expected {np.dtype(dtype)} array of shape {shape}, got {describe(value)}"
        )
    h, w = value.shape[:2]
    check_array(where, value, dtype, (h, w) if channels is None else (h, w, channels))
    return h, w


# ------------------------------------------------------------------------------------------------
# Checks of single arguments, shared by every public entry point: each raises InvalidInputError
# naming ``where`` (the parameter or field), what was expected and what came, and returns the
# value as the code below it may take it, before it reaches float(), int(), struct or the kernels.


def check_int(where: str, value: object, lo: int, hi: int) -> int:
    """``value`` as an int in ``lo..hi`` (a bool, float or string is refused)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidInputError(f"{where}: expected an int, got {describe(value)}")
    v = int(value)
    if not lo <= v <= hi:
        raise InvalidInputError(f"{where}: expected an int in [{lo}, {hi}], got {v}")
    return v


def check_float(
    where: str, value: object, *, positive: bool = False, lo: float | None = None,
    hi: float | None = None, finite: bool = True,
) -> float:
    """``value`` as a finite float (> 0 with ``positive``; within ``lo..hi`` when given); an int
    too large for a float is refused like a non-number. ``finite=False`` lets NaN and the
    infinities through (when the callee words their refusal better, e.g. with the range a
    method supports)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidInputError(f"{where}: expected a float, got {describe(value)}")
    try:
        v = float(value)
    except OverflowError:
        raise InvalidInputError(
            f"{where}: expected a finite float, got an int too large for a float"
        ) from None
    low = "" if lo is None else f" >= {lo:g}"
    if positive:
        low = " > 0"
    top = "" if hi is None else f"{' and' if low else ''} <= {hi:g}"
    if (
        (finite and not math.isfinite(v))
        or (positive and v <= 0.0)
        or (lo is not None and v < lo)
        or (hi is not None and v > hi)
    ):
        raise InvalidInputError(f"{where}: expected a finite float{low}{top}, got {v}")
    return v


def check_bool(where: str, value: object) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidInputError(f"{where}: expected a bool, got {describe(value)}")
    return bool(value)


def check_str(where: str, value: object, choices: Sequence[str] = ()) -> str:
    """``value`` as a str, one of ``choices`` when given."""
    if not isinstance(value, str):
        raise InvalidInputError(f"{where}: expected a str, got {describe(value)}")
    if choices and value not in choices:
        names = [repr(c) for c in choices]
        want = " or ".join(names) if len(names) == 2 else "one of " + ", ".join(names)
        raise InvalidInputError(f"{where}: expected {want}, got {value!r}")
    return value


def check_path(where: str, value: object) -> str | os.PathLike[str]:
    """``value`` as a file system path: a non-empty str or an ``os.PathLike`` of one."""
    if isinstance(value, os.PathLike):
        text = os.fspath(value)
    else:
        text = value
    if not isinstance(text, str) or not text or "\0" in text:
        raise InvalidInputError(
            f"{where}: expected a path (a non-empty str or os.PathLike), got {describe(value)}"
        )
    return value  # type: ignore[return-value]


def check_items(where: str, value: object, item: Check | None = None) -> list[Any]:
    """``value`` as a list: a sequence or other iterable (not a str, bytes or mapping), each
    item checked by ``item`` (named ``where[i]``) when given."""
    if isinstance(value, (str, bytes, bytearray, dict)) or not isinstance(value, Iterable):
        raise InvalidInputError(f"{where}: expected a sequence, got {describe(value)}")
    items = list(value)
    if item is not None:
        items = [item(f"{where}[{i}]", v) for i, v in enumerate(items)]
    return items


def check_iterable(where: str, value: object) -> object:
    """``value`` unchanged if it can be iterated (it is not consumed: it may be a generator)
    and is not a str, bytes or mapping."""
    if isinstance(value, (str, bytes, bytearray, dict)) or not isinstance(value, Iterable):
        raise InvalidInputError(f"{where}: expected an iterable, got {describe(value)}")
    return value


def check_buffer(where: str, value: object, also: tuple[type, ...] = ()) -> Any:
    """``value`` as the bytes of a packet: ``bytes``, a ``bytearray`` or a C-contiguous
    ``memoryview`` (then as a flat view of its bytes, so that ``len`` counts bytes), or as it
    is when it is an instance of one of ``also``."""
    if isinstance(value, (bytes, bytearray)) or (also and isinstance(value, also)):
        return value
    if isinstance(value, memoryview):
        try:
            contiguous = value.c_contiguous
        except ValueError:  # released
            raise InvalidInputError(f"{where}: the memoryview was released") from None
        if not contiguous:
            raise InvalidInputError(
                f"{where}: expected a C-contiguous buffer, got a non-contiguous memoryview "
                "(copy it with bytes(...))"
            )
        return value if value.format == "B" and value.ndim == 1 else value.cast("B")
    names = ", ".join(["bytes", "bytearray", "memoryview", *(c.__name__ for c in also)])
    raise InvalidInputError(f"{where}: expected one of {names}, got {describe(value)}")


def check_callable(where: str, value: object) -> object:
    if not callable(value):
        raise InvalidInputError(f"{where}: expected a callable, got {describe(value)}")
    return value


def check_instance(where: str, value: object, cls: type | tuple[type, ...]) -> Any:
    """``value`` if it is an instance of ``cls``."""
    if not isinstance(value, cls):
        names = " or ".join(c.__name__ for c in (cls if isinstance(cls, tuple) else (cls,)))
        raise InvalidInputError(f"{where}: expected {names}, got {describe(value)}")
    return value


#: Largest frame rate (FPS) an entry point takes: the codec's ``MAX_FPS``.
MAX_RATE = 1000.0

#: A check of one argument: ``(where, value) -> value as the callee takes it``.
Check = Callable[[str, Any], Any]


def ints(lo: int, hi: int) -> Check:
    return lambda where, v: check_int(where, v, lo, hi)


def floats(
    *, positive: bool = False, lo: float | None = None, hi: float | None = None,
    finite: bool = True,
) -> Check:
    return lambda where, v: check_float(where, v, positive=positive, lo=lo, hi=hi,
                                        finite=finite)


def strs(*choices: str) -> Check:
    return lambda where, v: check_str(where, v, choices)


def instances(cls: type | tuple[type, ...]) -> Check:
    return lambda where, v: check_instance(where, v, cls)


def buffers(*also: type) -> Check:
    """:func:`check_buffer`, with instances of ``also`` allowed as they are."""
    return lambda where, v: check_buffer(where, v, also)


def items(item: Check | None = None) -> Check:
    return lambda where, v: check_items(where, v, item)


def optional(check: Check) -> Check:
    """``check``, with ``None`` allowed."""
    return lambda where, v: None if v is None else check(where, v)


BOOL: Check = check_bool
PATH: Check = check_path
CALLABLE: Check = check_callable
ITERABLE: Check = check_iterable

_F = TypeVar("_F", bound=Callable[..., Any])


def checked(**checks: Check) -> Callable[[_F], _F]:
    """A public entry point whose arguments named in ``checks`` are checked (and converted:
    ``check(name, value)`` returns what the body gets) before its body runs; a parameter the
    caller left at its default is not checked. Missing or unexpected arguments raise
    InvalidInputError too, not TypeError. The table of every public name and its bad arguments
    is tests/test_api_types.py."""

    def wrap(fn: _F) -> _F:
        sig = inspect.signature(fn)
        unknown = set(checks) - set(sig.parameters)
        if unknown:  # a typo here would silently check nothing
            raise AssertionError(f"{fn.__qualname__}: no parameters {sorted(unknown)}")
        name = fn.__qualname__

        @functools.wraps(fn)
        def call(*args: Any, **kwargs: Any) -> Any:
            try:
                bound = sig.bind(*args, **kwargs)
            except TypeError as e:
                raise InvalidInputError(f"{name}: {e}") from None
            given = bound.arguments
            for param, check in checks.items():
                if param in given:
                    given[param] = check(param, given[param])
            return fn(*bound.args, **bound.kwargs)

        call.__checked__ = checks  # type: ignore[attr-defined]
        return call  # type: ignore[return-value]

    return wrap


def _matrix(where: str, value: object) -> npt.NDArray[np.float64]:
    try:
        # Complex values are refused, not cast (numpy drops the imaginary part with a warning).
        if np.asarray(value).dtype.kind == "c":
            raise TypeError
        m = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError, OverflowError):
        raise InvalidInputError(
            f"{where}: expected a 4x4 matrix of floats, got {describe(value)}"
        ) from None
    if m.shape != (4, 4):
        raise InvalidInputError(
            f"{where}: expected float64 array of shape (4, 4), got {describe(value)}"
        )
    if not np.isfinite(m).all():
        raise InvalidInputError(f"{where}: expected finite values, got {m.tolist()}")
    m.setflags(write=False)
    return m


@dataclass(frozen=True, slots=True, eq=False)
class Camera:
    """A pinhole camera: world-to-camera ``view``, camera-to-clip ``proj`` (reversed depth) and the
    image size in pixels. The matrices are stored as read-only ``float64[4, 4]`` copies."""

    view: npt.NDArray[np.float64]
    proj: npt.NDArray[np.float64]
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "view", _matrix("Camera.view", self.view))
        object.__setattr__(self, "proj", _matrix("Camera.proj", self.proj))
        object.__setattr__(self, "width", check_int("Camera.width", self.width, 1, MAX_SIDE))
        object.__setattr__(
            self, "height", check_int("Camera.height", self.height, 1, MAX_SIDE)
        )

    @classmethod
    @checked(
        fov_y_deg=floats(positive=True), near=floats(positive=True), far=floats(positive=True),
    )
    def look_at(
        cls,
        eye: Sequence[float],
        target: Sequence[float],
        *,
        fov_y_deg: float = 60.0,
        width: int,
        height: int,
        near: float = 0.1,
        far: float = 100.0,
        up: Sequence[float] = (0.0, 1.0, 0.0),
    ) -> Camera:
        """A camera at ``eye`` looking at ``target`` with vertical field of view ``fov_y_deg`` and
        the reversed-depth projection of DESIGN.md (aspect ``width / height``)."""
        width = check_int("width", width, 1, MAX_SIDE)
        height = check_int("height", height, 1, MAX_SIDE)
        view = _native.look_at(_vec3("eye", eye), _vec3("target", target), _vec3("up", up))
        proj = _native.perspective(fov_y_deg, width / height, near, far)
        return cls(view, proj, width, height)

    @checked(ipd=floats(positive=True))
    def stereo(self, ipd: float = IPD) -> tuple[Camera, Camera]:
        """The two eyes ``(left, right)`` of a head whose camera is this one: ``∓ipd / 2`` along
        its own x axis, the same orientation, projection and size (as the reference renderer's
        stereo client frames, whose IPD is :data:`IPD`). An eye at offset ``o`` from the head
        sees world points at ``view_eye = T(−o) · view``.

        Raises:
            InvalidInputError: for an ``ipd`` that is not a positive finite number."""
        out = []
        for side in (-1.0, 1.0):
            shift = np.eye(4)
            shift[0, 3] = -0.5 * ipd * side
            out.append(Camera(shift @ self.view, self.proj, self.width, self.height))
        return (out[0], out[1])

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    def to_native(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int, int]:
        """``(view, proj, width, height)`` as ``splitrender._native`` takes it."""
        return (self.view, self.proj, self.width, self.height)


def _vec3(where: str, v: Sequence[float]) -> tuple[float, float, float]:
    try:
        x, y, z = (float(c) for c in v)
    except (TypeError, ValueError, OverflowError):
        raise InvalidInputError(f"{where}: expected 3 floats, got {v!r}") from None
    return (x, y, z)


@dataclass(frozen=True, slots=True, eq=False)
class ShadowBuffers:
    """Dynamic-shadow buffers of one source image and direction (seeds/000 §3.3): per pixel a
    bitfield with 2 bits per subframe (subframe ``j`` in bits ``2j, 2j+1``, subframe 0 the key
    frame) and the RGB8 colours at the minimum/maximum level (0 where that level is the key
    frame's own)."""

    bits: npt.NDArray[np.uint32]
    s_min: npt.NDArray[np.uint8]
    s_max: npt.NDArray[np.uint8]

    def __post_init__(self) -> None:
        h, w = check_image("ShadowBuffers.bits", self.bits, np.uint32)
        check_array("ShadowBuffers.s_min", self.s_min, np.uint8, (h, w, 3))
        check_array("ShadowBuffers.s_max", self.s_max, np.uint8, (h, w, 3))

    def to_native(
        self,
    ) -> tuple[npt.NDArray[np.uint32], npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
        """``(bits, s_min, s_max)`` as ``splitrender._native`` takes it."""
        return (self.bits, self.s_min, self.s_max)


@dataclass(frozen=True, slots=True, eq=False)
class CameraFrame:
    """Everything the client holds of one camera of one server frame.

    ``motion_fwd`` is ``O_{t->t+1}`` and ``motion_bwd`` ``O_{t->t-1}``, both ``float32[H, W, 3]``
    in this camera's NDC with the camera held fixed (``None``: static, all zero);
    ``shadow_fwd``/``shadow_bwd`` the dynamic-shadow buffers toward the next/previous frame
    (``None``: no shadow application). A frame used as the older of a pair contributes its
    forward buffers, as the newer its backward ones."""

    camera: Camera
    color: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32]
    motion_fwd: npt.NDArray[np.float32] | None = None
    motion_bwd: npt.NDArray[np.float32] | None = None
    shadow_fwd: ShadowBuffers | None = None
    shadow_bwd: ShadowBuffers | None = None

    def __post_init__(self) -> None:
        check_camera_frame("CameraFrame", self)

    def to_native(self, direction: str) -> tuple[Any, ...]:
        """``(view, proj, color, depth, motion, shadow)`` with the ``"fwd"`` or ``"bwd"``
        buffers, as ``splitrender._native.reproject`` takes a camera."""
        if direction == "fwd":
            motion, shadow = self.motion_fwd, self.shadow_fwd
        elif direction == "bwd":
            motion, shadow = self.motion_bwd, self.shadow_bwd
        else:
            raise InvalidInputError(f"direction: expected 'fwd' or 'bwd', got {direction!r}")
        c = self.camera
        sh = None if shadow is None else shadow.to_native()
        return (c.view, c.proj, self.color, self.depth, motion, sh)


@dataclass(frozen=True, slots=True, eq=False)
class ServerFrame:
    """Server frame ``index`` at ``time`` seconds: the main camera and the auxiliary cameras (in
    rig order; the synthetic scene and the renderer produce two).

    ``span``: how many server-frame periods (``1 / f_s``) its motion and shadow buffers span,
    so that it pairs with frame ``index ± span``. 1 everywhere but in a live session whose
    server, unable to keep ``f_s``, renders every ``span``-th frame (docs/live.md); the stream
    format does not store it (the live protocol's frame header carries it)."""

    index: int
    time: float
    main: CameraFrame
    aux: tuple[CameraFrame, ...] = ()
    span: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "index", check_int("ServerFrame.index", self.index, 0, MAX_INDEX)
        )
        object.__setattr__(self, "span", check_int("ServerFrame.span", self.span, 1, MAX_SPAN))
        object.__setattr__(self, "time", check_float("ServerFrame.time", self.time))
        if isinstance(self.aux, (str, bytes)) or not isinstance(self.aux, Sequence):
            raise InvalidInputError(
                f"ServerFrame.aux: expected a sequence of CameraFrame, got {describe(self.aux)}"
            )
        aux = tuple(self.aux)
        object.__setattr__(self, "aux", aux)
        # The cameras checked themselves when they were made, but numpy arrays stay mutable
        # (``a.dtype = ...``, ``a.shape = ...``): check again, naming the path in this frame
        # (and that main and each aux is a CameraFrame).
        check_server_frame("ServerFrame", self)

    def to_native(self, direction: str) -> tuple[Any, list[Any]]:
        """``(main, [aux...])`` with the ``"fwd"`` or ``"bwd"`` buffers."""
        return (
            self.main.to_native(direction),
            [a.to_native(direction) for a in self.aux],
        )


@dataclass(frozen=True, slots=True, eq=False)
class ClientRequest:
    """The client's actual camera at display time ``time`` (seconds)."""

    camera: Camera
    time: float

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera):
            raise InvalidInputError(
                f"ClientRequest.camera: expected a Camera, got {describe(self.camera)}"
            )
        object.__setattr__(self, "time", check_float("ClientRequest.time", self.time))


#: Methods that interpolate a pair when they have one (``forward_splat`` only with
#: ``ReprojectOptions.splat_bidirectional``: :func:`interpolates`).
BIDIRECTIONAL_METHODS: tuple[str, ...] = ("ours", "backward_bidir")


def interpolates(method: str, splat_bidirectional: bool) -> bool:
    """Whether ``method`` interpolates between a pair of server frames when it has both, and so
    reads the older one; the others extrapolate from the newest frame alone."""
    return method in BIDIRECTIONAL_METHODS or (method == "forward_splat" and splat_bidirectional)


@dataclass(frozen=True, slots=True)
class ReprojectOptions:
    """Options of the reprojection methods, with the defaults of shared/DESIGN.md. Each option
    names the methods that read it."""

    eps_e: float = 0.002
    """``ε_e``: reprojection-error threshold of the main camera, in NDC units scaled so that 2.0
    is the image's short side (REFERENCE.md §2.5), given at the paper's 2560×1440: the core
    multiplies it by ``1440 / min(client width, height)``, so that it stays the same number of
    pixels at every resolution (``Reprojection.error`` is compared against that scaled value).
    (ours, forward_splat)"""

    eps_z: float = 0.001
    """``ε_z``: depth-similarity threshold of the main camera in NDC z units. (ours,
    forward_splat, backward_bidir)"""

    eps_o: float = 0.01
    """``ε_O``: motion-cancel threshold of Algorithm 2, 3-D NDC norm. (ours)"""

    aux_threshold_scale: float = 4.0
    """Factor applied to ``eps_e`` and ``eps_z`` for the auxiliary cameras. (ours,
    forward_splat)"""

    window: int = 1
    """Half-width ``W`` of the ``(2W+1)^2`` window search around the splat (1: 3x3), 0..8."""

    fpi_iterations: int = 3
    """Fixed-point iterations after the splat initialisation (ours), 0..32."""

    bidir_iterations: int = 3
    """Fixed-point iterations of ``backward_bidir`` (seeds/001 uses 3), 0..32."""

    shadow_subframes: int = 4
    """``S = f_d / f_s``: dynamic-shadow subframes per server interval, 1..16."""

    use_shadows: bool = True
    """Apply dynamic shadows (seeds/000 eqs. 9-11). (ours, ours_extrapolate)"""

    use_aux: bool = True
    """Use the auxiliary cameras of the frames. (ours, ours_extrapolate, forward_splat,
    timewarp)"""

    blend: bool = True
    """Blend the two frames by Algorithm 2 (second chance). (ours)"""

    splat_bidirectional: bool = False
    """``forward_splat`` only: splat both frames instead of the newest one alone (the paper's
    baseline is unidirectional)."""

    server_fps: float = 10.0
    """``f_s``: server frame rate. Sets ``α = 1 + (t − t_k)·f_s`` when a method extrapolates from
    the newest frame ``k`` alone (Python side only)."""

    _FLOATS: ClassVar[tuple[str, ...]] = ("eps_e", "eps_z", "eps_o", "aux_threshold_scale")
    _INTS: ClassVar[dict[str, tuple[int, int]]] = {
        "window": (0, 8),
        "fpi_iterations": (0, 32),
        "bidir_iterations": (0, 32),
        "shadow_subframes": (1, 16),
    }
    _BOOLS: ClassVar[tuple[str, ...]] = (
        "use_shadows",
        "use_aux",
        "blend",
        "splat_bidirectional",
    )

    def __post_init__(self) -> None:
        for name in self._FLOATS:
            # The kernels take them as float32: beyond its range they became inf or 0 there,
            # and every call was refused naming a value the caller never gave.
            v = check_float(f"ReprojectOptions.{name}", getattr(self, name), lo=_F32_TRUE_MIN,
                            hi=_F32_MAX)
            object.__setattr__(self, name, v)
        v = check_float("ReprojectOptions.server_fps", self.server_fps, positive=True)
        object.__setattr__(self, "server_fps", v)
        for name, (lo, hi) in self._INTS.items():
            v = check_int(f"ReprojectOptions.{name}", getattr(self, name), lo, hi)
            object.__setattr__(self, name, v)
        for name in self._BOOLS:
            object.__setattr__(
                self, name, check_bool(f"ReprojectOptions.{name}", getattr(self, name))
            )

    def to_native(self) -> dict[str, float | int | bool]:
        """The options ``splitrender._native.reproject`` takes (all but ``server_fps``)."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name != "server_fps"
        }

    def replace(self, **changes: Any) -> ReprojectOptions:
        """A copy with ``changes`` applied (validated again)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise InvalidInputError(
                f"ReprojectOptions.replace: unknown options {sorted(unknown)}; expected some of "
                f"{', '.join(f.name for f in dataclasses.fields(self))}"
            )
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, slots=True, eq=False)
class Reprojection:
    """One synthesised client frame with per-pixel diagnostics.

    ``image``: ``uint8[H, W, 3]``. ``error``: ``float32[H, W]``, the reprojection error of the
    chosen match (aspect-scaled NDC), NaN where none. ``source``: ``uint8[H, W]``, which source
    coloured the pixel:

    - ``SOURCE_NONE`` (0): no match, the previous client frame's colour was kept;
    - ``SOURCE_MAIN_OLDER`` (1) / ``SOURCE_MAIN_NEWER`` (2): the main camera of the older/newer
      frame;
    - ``SOURCE_AUX_BASE + 2*i`` (+1 for the newer frame): auxiliary camera ``i``;
    - ``SOURCE_BLENDED`` (0x80) is or-ed in when Algorithm 2 blended the other frame in.
    """

    SOURCE_NONE: ClassVar[int] = 0
    SOURCE_MAIN_OLDER: ClassVar[int] = 1
    SOURCE_MAIN_NEWER: ClassVar[int] = 2
    SOURCE_AUX_BASE: ClassVar[int] = 3
    SOURCE_BLENDED: ClassVar[int] = 0x80

    image: npt.NDArray[np.uint8]
    source: npt.NDArray[np.uint8]
    error: npt.NDArray[np.float32]

    def __post_init__(self) -> None:
        h, w = check_image("Reprojection.image", self.image, np.uint8, 3)
        check_array("Reprojection.source", self.source, np.uint8, (h, w))
        check_array("Reprojection.error", self.error, np.float32, (h, w))

    @property
    def matched(self) -> npt.NDArray[np.bool_]:
        """``bool[H, W]``: pixels that some source coloured."""
        return np.asarray(self.source != self.SOURCE_NONE)



# ------------------------------------------------------------------------------------------------
# Checks of whole frames, naming each buffer by its path as the caller passed it

#: The buffer directions of a camera frame: ``"fwd"`` (``motion_fwd``, ``shadow_fwd``: what a
#: frame contributes as the older of a pair) and ``"bwd"`` (as the newer).
DIRECTIONS: tuple[str, ...] = ("fwd", "bwd")


def _check_camera(where: str, camera: object) -> Camera:
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"{where}: expected a Camera, got {describe(camera)}")
    for name in ("view", "proj"):
        m = getattr(camera, name)
        if not isinstance(m, np.ndarray) or m.dtype != np.float64 or m.shape != (4, 4):
            raise InvalidInputError(
                f"{where}.{name}: expected float64 array of shape (4, 4), got {describe(m)}"
            )
    check_int(f"{where}.width", camera.width, 1, MAX_SIDE)
    check_int(f"{where}.height", camera.height, 1, MAX_SIDE)
    return camera


def check_shadow(where: str, shadow: object, h: int, w: int) -> None:
    if not isinstance(shadow, ShadowBuffers):
        raise InvalidInputError(f"{where}: expected ShadowBuffers or None, got {describe(shadow)}")
    bits, s_min, s_max = shadow.bits, shadow.s_min, shadow.s_max
    sides = getattr(bits, "shape", None)
    if (
        isinstance(sides, tuple)
        and len(sides) == 2
        and sides != (h, w)
        and getattr(s_min, "shape", None) == (*sides, 3)
        and getattr(s_max, "shape", None) == (*sides, 3)
    ):
        # Buffers that agree with each other but not with the camera: say so once.
        raise InvalidInputError(f"{where}: expected buffers of shape ({h}, {w}), got {sides}")
    check_array(f"{where}.bits", bits, np.uint32, (h, w))
    check_array(f"{where}.s_min", s_min, np.uint8, (h, w, 3))
    check_array(f"{where}.s_max", s_max, np.uint8, (h, w, 3))


def check_camera_frame(
    where: str, frame: object, directions: Sequence[str] = DIRECTIONS
) -> None:
    """Raises :class:`InvalidInputError` unless ``frame`` is a :class:`CameraFrame` whose camera
    and buffers (those of ``directions``) have the dtype, shape and layout the kernels read; the
    message names the buffer as ``where.<field>`` (e.g. ``newer.aux[1].motion_bwd``,
    ``CameraFrame.depth``). Nothing is copied."""
    if not isinstance(frame, CameraFrame):
        raise InvalidInputError(f"{where}: expected a CameraFrame, got {describe(frame)}")
    camera = _check_camera(f"{where}.camera", frame.camera)
    h, w = camera.height, camera.width
    check_array(f"{where}.color", frame.color, np.uint8, (h, w, 3))
    check_array(f"{where}.depth", frame.depth, np.float32, (h, w))
    for d in directions:
        m = getattr(frame, f"motion_{d}")
        if m is not None:
            check_array(f"{where}.motion_{d}", m, np.float32, (h, w, 3))
    for d in directions:
        s = getattr(frame, f"shadow_{d}")
        if s is not None:
            check_shadow(f"{where}.shadow_{d}", s, h, w)


def check_server_frame(
    where: str, frame: object, directions: Sequence[str] = DIRECTIONS
) -> ServerFrame:
    """:func:`check_camera_frame` for every camera of a :class:`ServerFrame`, naming them
    ``where.main`` and ``where.aux[i]``; returns the frame."""
    if not isinstance(frame, ServerFrame):
        raise InvalidInputError(f"{where}: expected a ServerFrame, got {describe(frame)}")
    check_camera_frame(f"{where}.main", frame.main, directions)
    for i, a in enumerate(frame.aux):
        check_camera_frame(f"{where}.aux[{i}]", a, directions)
    return frame


@dataclass(frozen=True, slots=True)
class FrameArgument:
    """A server frame as one native call receives it: under the name the native layer gives it
    (``native``: ``"older"`` or ``"newer"``), with the buffers of ``direction``, and under the
    path the caller knows it by (``path``: ``"older"``, ``"frames[3]"``, ...)."""

    native: str
    path: str
    frame: ServerFrame | None
    direction: str


def _size_mismatch(frame: ServerFrame) -> bool:
    """Whether some camera's depth is not of its camera's size: the one inconsistency the native
    layer cannot see (it takes every size from the depth)."""
    for cf in (frame.main, *frame.aux):
        c = cf.camera
        if getattr(cf.depth, "shape", None) != (c.height, c.width):
            return True
    return False


def precheck_frames(args: Sequence[FrameArgument]) -> None:
    """The cheap part of :func:`native_error` that runs before a native call (a few µs): frames
    whose buffers agree with each other but not with their camera's size pass the native checks,
    so they are checked here, naming the buffer by its path."""
    for a in args:
        if a.frame is not None and _size_mismatch(a.frame):
            check_server_frame(a.path, a.frame, (a.direction,))


_NATIVE_SUFFIX = re.compile(r"^((?:\.main|\.aux\[\d+\])?)\.(motion|shadow)\b")


def native_error(
    error: InvalidInputError, args: Sequence[FrameArgument], *, client: str | None = None
) -> InvalidInputError:
    """The error to raise for ``error``, raised by a native call that took the frames ``args``.

    The native layer names a buffer by its place in the call (``newer.aux[1].motion``); the
    caller knows it by the path it passed (``frames[3].aux[1].motion_bwd``). For an error about a
    frame this checks the frames in Python (only now: on the hot path the native checks are the
    only ones) and returns that error, whose message names the path; if they pass, the native
    message with the frame's name replaced by its path. ``client`` is the path of the client
    camera (the native ``client.view`` becomes ``request.camera.view``). Any other error is
    returned as it is.
    """
    msg = str(error)
    if client is not None and msg.startswith("client."):
        return InvalidInputError(client + msg[len("client") :])
    named = [a for a in args if msg.startswith(a.native)]
    if not named:
        return error
    try:
        for a in args:
            if a.frame is not None:
                check_server_frame(a.path, a.frame, (a.direction,))
        held = [(a.path, a.frame) for a in args if a.frame is not None]
        if len(held) == 2 and len(held[0][1].aux) != len(held[1][1].aux):
            (p0, f0), (p1, f1) = held
            raise InvalidInputError(
                f"{p0}.aux has {len(f0.aux)} cameras but {p1}.aux has {len(f1.aux)}; "
                "both frames of a pair need the same auxiliary cameras"
            )
    except InvalidInputError as found:
        return found
    a = named[0]
    rest = _NATIVE_SUFFIX.sub(
        lambda m: f"{m.group(1)}.{m.group(2)}_{a.direction}", msg[len(a.native) :]
    )
    return InvalidInputError(a.path + rest)
