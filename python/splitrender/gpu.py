"""The GPU path: the client reprojection as WGSL compute shaders run by wgpu (crates/reproj-wgpu).

``backend="wgpu"`` (in :func:`splitrender.reproject`, :class:`splitrender.Client`, the command
line) runs ``ours``, ``ours_extrapolate`` and ``forward_splat`` on the GPU with the CPU path's
semantics (the parity tests compare them pixel for pixel). :class:`GpuReprojector` is the
device-resident form: :meth:`~GpuReprojector.load` uploads a pair of server frames once, then each
:meth:`~GpuReprojector.render` uploads only the client pose and ``α`` and downloads the image (or
leaves it on the device). A real-time client uploads the next pair on its receiving thread
(:meth:`~GpuReprojector.upload`, which does not wait for a frame being rendered) and makes it
current between two display frames (:meth:`~GpuReprojector.install`, no copy), so that no
display frame pays the upload.

Without a GPU, Mesa's software Vulkan driver lavapipe works (Debian/Ubuntu:
``apt-get install mesa-vulkan-drivers``); without any adapter, asking for the wgpu backend raises
:class:`~splitrender.errors.GpuUnavailableError`. wgpu's ``WGPU_BACKEND`` (e.g. ``vulkan``)
restricts the search; a value naming no backend raises the same error, naming the variable.

On a machine without a desktop session (a server, a CI runner, a cluster node) Mesa's Vulkan
device-selection layer is turned off before the first device is made (``_headless_vulkan``):
it looks for the desktop's GPU through Wayland, whose library then wrote "error:
XDG_RUNTIME_DIR is invalid or not set in the environment." to stderr twice per process.
"""

from __future__ import annotations

import os
import threading
from collections.abc import MutableMapping
from typing import Literal, overload

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.errors import GpuDeviceLostError, GpuUnavailableError, InvalidInputError
from splitrender.types import (
    Camera,
    FrameArgument,
    Reprojection,
    ReprojectOptions,
    ServerFrame,
    check_server_frame,
    interpolates,
    native_error,
    precheck_frames,
)
from splitrender.types import (  # argument checks
    BOOL,
    checked,
    floats,
    instances,
    ints,
    optional,
    strs,
)

__all__ = [
    "BACKENDS",
    "GPU_METHODS",
    "GpuPair",
    "GpuReprojector",
    "GpuDeviceLostError",
    "GpuUnavailableError",
    "OUTPUT_SLOTS",
    "adapter",
    "available",
    "backend_for",
    "check_backend",
    "require",
]

#: The backends every method entry point accepts.
BACKENDS: tuple[str, ...] = ("cpu", "wgpu")
#: The methods the wgpu backend runs (``timewarp`` and ``backward_bidir`` are CPU only).
GPU_METHODS: tuple[str, ...] = ("ours", "ours_extrapolate", "forward_splat")

#: Output slots a :class:`GpuReprojector` holds on the device (``reproj_wgpu::MAX_OUTPUTS``).
OUTPUT_SLOTS: int = _native.GPU_OUTPUT_SLOTS

_Image = npt.NDArray[np.uint8]

#: A pair of server frames on the device (:meth:`GpuReprojector.upload`): ``has_older`` says
#: whether it can interpolate, ``device_bytes`` what it holds; freed when the last reference goes.
GpuPair = _native.WgpuPair


def check_backend(backend: object, method: str | None = None) -> str:
    """``backend`` if it is one of :data:`BACKENDS` (and, for ``"wgpu"``, ``method`` has a GPU
    kernel).

    Raises:
        InvalidInputError: for an unknown backend or a method the backend cannot run.
    """
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise InvalidInputError(
            f"unknown backend {backend!r}; expected one of: {', '.join(BACKENDS)}"
        )
    if backend == "wgpu" and method is not None and method not in GPU_METHODS:
        raise InvalidInputError(
            f"method {method!r} has no wgpu kernel (the wgpu backend runs "
            f"{', '.join(GPU_METHODS)}); use backend='cpu' for it"
        )
    return backend


def require(backend: str, method: str) -> str | None:
    """Checks that ``method`` can run on ``backend`` before any work starts: ``None`` for the CPU,
    the adapter in words for ``"wgpu"``.

    Raises:
        InvalidInputError: for an unknown backend or a method the backend cannot run.
        GpuUnavailableError: for ``"wgpu"`` without an adapter.
    """
    return adapter() if check_backend(backend, method) == "wgpu" else None


def backend_for(method: str, backend: str) -> str:
    """The backend ``method`` runs on when ``backend`` is chosen for a whole run (``demo``,
    ``eval``, ``play``): ``"wgpu"`` for the methods with a GPU kernel (:data:`GPU_METHODS`), the
    CPU for the baselines that have none (``timewarp``, ``backward_bidir``)."""
    return "wgpu" if check_backend(backend) == "wgpu" and method in GPU_METHODS else "cpu"


def _headless_vulkan(env: MutableMapping[str, str] | None = None) -> bool:
    """Turns Mesa's Vulkan device-selection layer off (``NODEVICE_SELECT=1`` in ``env``, the
    process's environment by default) where there is no desktop session, and says whether it
    did.

    Why: the Vulkan loader runs that layer (``VK_LAYER_MESA_device_select``, installed with
    Mesa's drivers) in every process that makes a Vulkan instance; it puts the GPU the desktop
    shows on first, and to find that GPU it connects to the Wayland compositor, whose library
    writes "error: XDG_RUNTIME_DIR is invalid or not set in the environment." to stderr where
    there is no session. Without a session (``XDG_RUNTIME_DIR`` unset or not a directory, and no
    ``DISPLAY`` or ``WAYLAND_DISPLAY``) there is no such GPU to find, and wgpu picks its
    adapter by kind itself. Left alone: a process with a session, and one whose user set
    ``NODEVICE_SELECT`` or chose a device with ``MESA_VK_DEVICE_SELECT`` (the layer's own
    variables)."""
    env = os.environ if env is None else env
    if any(k in env for k in ("NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT")):
        return False
    if env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"):
        return False
    runtime = env.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isdir(runtime):
        return False
    env["NODEVICE_SELECT"] = "1"
    return True


def adapter() -> str:
    """The wgpu adapter in words, e.g. ``llvmpipe (...) (Vulkan, Cpu, Mesa 22.3.6 ...)``.

    Raises:
        GpuUnavailableError: when there is no adapter (the message says how to install one).
    """
    _headless_vulkan()
    return _native.wgpu_adapter()


def available() -> bool:
    """Whether the wgpu backend can run here (an adapter and a device exist)."""
    try:
        adapter()
    except GpuUnavailableError:
        return False
    return True


class GpuReprojector:
    """The client reprojection on the GPU, with the server frames kept on the device.

    ``force_32bit_atomics`` selects the 32-bit splat even where the adapter has 64-bit atomic
    min/max (both give the same images; the option exists for tests and comparisons).

    When the device is lost (a driver reset, a removed GPU) every call raises
    :class:`~splitrender.errors.GpuDeviceLostError` from then on, and :attr:`lost` says why; a
    new ``GpuReprojector`` is made on a new device (where one can be had).

    Raises:
        GpuUnavailableError: when there is no wgpu adapter.
    """

    @checked(force_32bit_atomics=BOOL)
    def __init__(self, *, force_32bit_atomics: bool = False) -> None:
        _headless_vulkan()
        self._native = _native.WgpuReprojector(force_32bit_atomics)
        self._lock = threading.RLock()

    def __repr__(self) -> str:
        return f"GpuReprojector(adapter={self.adapter!r}, atomics={self.atomics!r})"

    @property
    def adapter(self) -> str:
        """The adapter in words."""
        return self._native.adapter

    @property
    def atomics(self) -> str:
        """``"int64"`` (one 64-bit atomic maximum per splatted point) or ``"int32"`` (two
        32-bit passes)."""
        return self._native.atomics

    @property
    def lost(self) -> str | None:
        """Why its device was lost (``None`` while it is not): it never renders again."""
        return self._native.lost

    def load(self, older: ServerFrame | None, newer: ServerFrame) -> None:
        """Uploads a pair: ``older`` (``F_t``, its forward buffers; ``None`` to extrapolate only)
        and ``newer`` (``F_{t+1}``, its backward buffers), as :func:`splitrender.reproject_alpha`
        uses them.

        Raises:
            InvalidInputError: for invalid frames (naming the buffer).
        """
        self._load(older, newer)

    def _load(
        self,
        older: ServerFrame | None,
        newer: ServerFrame,
        paths: tuple[str, str] = ("older", "newer"),
    ) -> None:
        """:meth:`load`, naming the frames ``paths`` in messages."""
        with self._lock:
            self._native.install(self.upload(older, newer, _paths=paths))

    def upload(
        self,
        older: ServerFrame | None,
        newer: ServerFrame,
        *,
        _paths: tuple[str, str] = ("older", "newer"),
    ) -> GpuPair:
        """Uploads a pair as :meth:`load` does, without making it current: from any thread,
        while another renders (it does not take the lock a frame holds). :meth:`install` makes
        it current.

        Raises:
            InvalidInputError: for invalid frames (naming the buffer).
        """
        if older is not None and not isinstance(older, ServerFrame):
            raise InvalidInputError(
                f"{_paths[0]}: expected a ServerFrame or None, got {type(older).__name__}"
            )
        if not isinstance(newer, ServerFrame):
            raise InvalidInputError(
                f"{_paths[1]}: expected a ServerFrame, got {type(newer).__name__}"
            )
        frames = (
            FrameArgument("older", _paths[0], older, "fwd"),
            FrameArgument("newer", _paths[1], newer, "bwd"),
        )
        precheck_frames(frames)
        try:
            return self._native.upload(
                None if older is None else older.to_native("fwd"), newer.to_native("bwd")
            )
        except InvalidInputError as e:
            raise native_error(e, frames) from None

    def install(self, pair: GpuPair) -> GpuPair | None:
        """Makes an uploaded pair current (:meth:`upload`): the following :meth:`render` calls
        read it. Nothing is copied. Returns the pair that was current (``None`` if none), so that
        the caller can let it go where freeing its device memory costs no frame.

        Raises:
            InvalidInputError: when ``pair`` is not a :data:`GpuPair`.
        """
        if not isinstance(pair, GpuPair):
            raise InvalidInputError(
                f"pair: expected a GpuPair from GpuReprojector.upload, got {type(pair).__name__}"
            )
        with self._lock:
            return self._native.install(pair)

    @overload
    def render(
        self,
        camera: Camera,
        alpha: float,
        method: str = ...,
        *,
        options: ReprojectOptions | None = ...,
        previous: _Image | Literal["keep"] | None = ...,
        slot: int = ...,
        diagnostics: Literal[False] = ...,
    ) -> _Image: ...
    @overload
    def render(
        self,
        camera: Camera,
        alpha: float,
        method: str = ...,
        *,
        options: ReprojectOptions | None = ...,
        previous: _Image | Literal["keep"] | None = ...,
        slot: int = ...,
        diagnostics: Literal[True],
    ) -> Reprojection: ...
    @checked(camera=instances(Camera), alpha=floats(finite=False), method=strs(),
             options=optional(instances(ReprojectOptions)), slot=ints(0, OUTPUT_SLOTS - 1),
             diagnostics=BOOL)
    def render(
        self,
        camera: Camera,
        alpha: float,
        method: str = "ours",
        *,
        options: ReprojectOptions | None = None,
        previous: _Image | Literal["keep"] | None = None,
        slot: int = 0,
        diagnostics: bool = False,
    ) -> _Image | Reprojection:
        """One client frame at ``camera`` and ``alpha`` from the loaded pair (the semantics of
        :func:`splitrender.reproject_alpha`) into output ``slot`` (0 to
        :data:`OUTPUT_SLOTS` − 1, e.g. one per eye).

        ``previous`` is what unmatched pixels keep: an image (uploaded), ``"keep"`` (the slot's
        last frame, already on the device; black for a new slot or a new size) or ``None``
        (black).

        Raises:
            InvalidInputError: for invalid arguments, a method without a GPU kernel, or when no
                pair is loaded.
            SplitRenderError: for a device error.
        """
        opts = ReprojectOptions() if options is None else options
        keep = isinstance(previous, str)
        if keep and previous != "keep":
            raise InvalidInputError(
                f"previous: expected an image, 'keep' or None, got {previous!r}"
            )
        image = None if isinstance(previous, str) else previous
        with self._lock:
            try:
                out = self._native.render(
                    method,
                    camera.to_native(),
                    float(alpha),
                    opts.to_native(),
                    image,
                    keep,
                    slot,
                    bool(diagnostics),
                    True,
                )
            except InvalidInputError as e:
                raise native_error(e, (), client="camera") from None
        assert out is not None
        if isinstance(out, tuple):
            return Reprojection(*out)
        return out

    @checked(diagnostics=BOOL)
    def reproject(
        self,
        older: ServerFrame | None,
        newer: ServerFrame,
        camera: Camera,
        alpha: float,
        method: str = "ours",
        *,
        options: ReprojectOptions | None = None,
        previous: _Image | None = None,
        diagnostics: bool = False,
        _paths: tuple[str, str] = ("older", "newer"),
    ) -> _Image | Reprojection:
        """:meth:`load` then :meth:`render` (slot 0) as one step, safe against other threads
        using this reprojector: what :func:`splitrender.reproject_alpha` runs for
        ``backend="wgpu"``. Uploads the pair every call; a caller that renders several client
        frames from one pair should :meth:`load` once instead."""
        opts = ReprojectOptions() if options is None else options
        bidirectional = isinstance(opts, ReprojectOptions) and opts.splat_bidirectional
        if method in GPU_METHODS and not interpolates(method, bidirectional):
            # These read the newer frame only, and the CPU path does not look into the older
            # one's matrices: neither is it uploaded here (a singular older camera was refused
            # on the GPU alone). Its buffers are still checked, as the CPU path checks them.
            if older is not None:
                check_server_frame(_paths[0], older, ("fwd",))
            older = None
        with self._lock:
            self._load(older, newer, _paths)
            if diagnostics:
                return self.render(
                    camera, alpha, method, options=options, previous=previous, diagnostics=True
                )
            return self.render(camera, alpha, method, options=options, previous=previous)

    def unload(self) -> None:
        """Frees the pair and the output slots on the device."""
        with self._lock:
            self._native.unload()


_shared: GpuReprojector | None = None
_shared_lock = threading.Lock()


def shared() -> GpuReprojector:
    """The process-wide :class:`GpuReprojector` that the per-call API
    (:func:`splitrender.reproject` with ``backend="wgpu"``) uses; created on first use, and
    again after its device was lost (the call that met the loss raised
    :class:`~splitrender.errors.GpuDeviceLostError`; the next one runs on a new device).

    Raises:
        GpuUnavailableError: when there is no wgpu adapter.
    """
    global _shared
    with _shared_lock:
        if _shared is None or _shared.lost is not None:
            _shared = GpuReprojector()
        return _shared
