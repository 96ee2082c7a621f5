"""The client runtime: :class:`Client`, the object a headset integration drives (feed it server
frames as they arrive and ask for a frame per display refresh). The batch path the experiments
use, a whole session through a :class:`~splitrender.net.model.NetworkModel`, is
:func:`splitrender.client.playback.play`, which drives a :class:`Client`.

Which frames, ``α`` and mode each client frame uses is decided by
:func:`splitrender.net.model.choose_frames` (see :mod:`splitrender.net.model` for the timing rules,
REFERENCE.md §2.1), so :func:`~splitrender.client.playback.play` and
:meth:`splitrender.net.model.Schedule.build` agree frame for frame.
"""

from __future__ import annotations

import threading
from typing import cast

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.errors import InvalidInputError
from splitrender.gpu import GpuDeviceLostError, GpuPair, GpuReprojector, check_backend
from splitrender.net.model import (
    ClientFrameInfo,
    FrameBuffer,
    choose_frames,
)
from splitrender.reproject import METHODS, _reproject_alpha
from splitrender.types import Camera, ReprojectOptions, ServerFrame, check_server_frame
from splitrender.types import (  # argument checks
    BOOL,
    MAX_RATE,
    checked,
    floats,
    instances,
    ints,
    optional,
    strs,
)

__all__ = ["Client"]

_Image = npt.NDArray[np.uint8]
#: A server-frame pair by index: ``(older, newer)``; ``older`` is ``None`` when extrapolating.
_Pair = tuple[int | None, int]
#: Most device pairs a client keeps for :meth:`Client.retired_uploads` (a real-time client takes
#: them once per server frame, after two or three; a caller that never does holds no more device
#: memory than this many pairs).
_MAX_RETIRED = 4


class Client:
    """A split-rendering client for one reprojection ``method``.

    ``receive`` server frames as they arrive, then ``render`` a frame for each display refresh
    at the client's actual camera and display time. The client holds at most ``capacity``
    server frames (see :class:`~splitrender.net.model.FrameBuffer`: duplicates, stale frames and
    frames beyond capacity are refused), keeps its previous output per ``eye`` for hole filling
    (DESIGN.md: no-match pixels keep the previous client frame's colour) and, for
    ``backward_bidir``, a :class:`~splitrender.BidirHistory` per eye that is reset whenever the
    pair changes. ``server_fps`` (default ``options.server_fps``, else 10) sets ``α`` when
    extrapolating.

    ``backend="wgpu"`` reprojects on the GPU (:mod:`splitrender.gpu`): the pair is uploaded once
    when it changes (or was uploaded beforehand, off the display path: :meth:`adopt_uploaded`),
    each client frame uploads only its pose, and the previous output of each eye stays on the
    device for hole filling.

    A client renders one frame at a time: :meth:`render` from a second thread while one runs
    raises :class:`~splitrender.errors.InvalidInputError` (use a client per thread, or a lock).

    Raises:
        InvalidInputError: for an unknown method, invalid options, a ``server_fps`` that
            contradicts ``options.server_fps``, or a method the backend cannot run.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """

    @checked(server_fps=optional(floats(positive=True, hi=MAX_RATE)), capacity=ints(2, 1 << 16))
    def __init__(
        self,
        method: str = "ours",
        options: ReprojectOptions | None = None,
        server_fps: float | None = None,
        *,
        capacity: int = 4,
        backend: str = "cpu",
    ) -> None:
        if not isinstance(method, str) or method not in METHODS:
            raise InvalidInputError(
                f"unknown method {method!r}; expected one of: {', '.join(METHODS)}"
            )
        self.backend = check_backend(backend, method)
        if options is None:
            options = (
                ReprojectOptions()
                if server_fps is None
                else ReprojectOptions(server_fps=server_fps)
            )
        elif not isinstance(options, ReprojectOptions):
            raise InvalidInputError(
                f"options: expected ReprojectOptions or None, got {type(options).__name__}"
            )
        elif server_fps is not None and float(server_fps) != options.server_fps:
            raise InvalidInputError(
                f"server_fps: expected options.server_fps = {options.server_fps} or None, "
                f"got {server_fps}"
            )
        self.method = method
        self.options = options
        self._buffer = FrameBuffer(capacity)
        self._frames: dict[int, ServerFrame] = {}
        # What the caller knows each held frame by, for messages: "frame(index=3)", "frames[3]".
        self._paths: dict[int, str] = {}
        self._previous: dict[int, _Image] = {}
        # Held while a frame renders: a render from another thread meanwhile is refused.
        self._rendering = threading.Lock()
        # Per eye: the pair last rendered, its history, and the eye's own history (reset and
        # reused when the pair changes; never one that was adopted, which the preparing side
        # may reuse once retired).
        self._history: dict[int, tuple[_Pair | None, _native.BidirHistory]] = {}
        self._own: dict[int, _native.BidirHistory] = {}
        # Pair state prepared off the display path (adopt_prepared), and the histories of pairs
        # that can no longer be used, for the preparing side to reuse (their buffers are warm).
        self._prepared: dict[_Pair, _native.BidirHistory] = {}
        self._retired: list[_native.BidirHistory] = []
        # The wgpu backend's counterpart: pairs uploaded off the display path (adopt_uploaded),
        # and those no longer used, for the uploading side to drop (retired_uploads).
        self._uploaded: dict[_Pair, GpuPair] = {}
        self._retired_pairs: list[GpuPair] = []
        self.last_info: ClientFrameInfo | None = None
        """How the last rendered frame was made (frames used, ``α``, mode)."""
        self._gpu = GpuReprojector() if self.backend == "wgpu" else None
        self._gpu_pair: tuple[int | None, int] | None = None
        self.gpu_lost: str | None = None
        """Why the GPU device was lost (wgpu's reason and message, e.g. ``"Destroyed"``;
        ``None`` while it was not, and on the CPU): from the frame that met the loss on, this
        client renders on the CPU (:attr:`backend` becomes ``"cpu"``), so that the display
        goes on."""

    def __repr__(self) -> str:
        return f"Client(method={self.method!r}, backend={self.backend!r}, held={self.held})"

    @property
    def server_fps(self) -> float:
        return self.options.server_fps

    @property
    def gpu(self) -> GpuReprojector | None:
        """The device-resident reprojector of ``backend="wgpu"`` (``None`` on the CPU): what
        uploads a pair off the display path (:meth:`GpuReprojector.upload`) for
        :meth:`adopt_uploaded`."""
        return self._gpu

    @property
    def held(self) -> tuple[int, ...]:
        """Indices of the server frames held, oldest first."""
        return tuple(sorted(self._frames))

    @checked(frame=instances(ServerFrame), arrival_time=optional(floats()))
    def receive(self, frame: ServerFrame, arrival_time: float | None = None) -> bool:
        """Takes a server frame that has arrived; returns whether it was kept (``False`` for a
        duplicate, a stale frame or a full buffer). ``arrival_time`` is informational only: a
        frame is usable from its receipt on.

        Raises:
            InvalidInputError: if ``frame`` is not a valid :class:`ServerFrame` (naming the buffer,
                e.g. ``frame.aux[1].depth``) or its time contradicts the order of the frames held.
        """
        return self._receive(frame, "frame")

    def _receive(self, frame: ServerFrame, path: str, *, checked: bool = False) -> bool:
        """:meth:`receive` of a frame the caller knows by ``path`` (``frames[3]`` for
        :func:`~splitrender.client.playback.play`). Checks every buffer once, here: the frames
        will be read many times, and the native layer checks them again at each render, where a
        frame's buffers are named by its index (``frame(index=3).aux[1].depth``). ``checked``:
        the caller has just checked the frame under ``path``."""
        if not checked:
            check_server_frame(path, frame)
        if not self._buffer.receive(frame.index, frame.time):
            return False
        self._frames[frame.index] = frame
        self._paths[frame.index] = (
            f"frame(index={frame.index})" if path == "frame" else path
        )
        return True

    @checked(time=floats(), interpolate=BOOL)
    def choose(self, time: float, *, interpolate: bool = True) -> ClientFrameInfo:
        """The frames, ``α`` and mode :meth:`render` would use at ``time`` (no state change);
        ``interpolate`` as :meth:`render`'s."""
        return choose_frames(
            self._buffer.times,
            time,
            self.server_fps,
            self.method,
            splat_bidirectional=self.options.splat_bidirectional,
            spans={i: f.span for i, f in self._frames.items()},
            interpolate=interpolate,
        )

    @checked(camera=instances(Camera), time=floats(), eye=ints(0, 1), interpolate=BOOL)
    def render(
        self, camera: Camera, time: float, *, eye: int = 0, interpolate: bool = True
    ) -> _Image:
        """The client frame (``uint8[H, W, 3]``) at ``camera`` and display ``time`` seconds;
        ``eye`` keys the previous-output and history state (0 mono/left, 1 right).
        :attr:`last_info` then says how it was made. Holding (no usable frame) returns the
        previous output of that eye, or black. ``interpolate=False`` extrapolates from the
        newest frame at or before ``time`` even where a pair would interpolate (cheaper: what
        the real-time loop does when an interpolated frame would miss its deadline,
        :class:`~splitrender.client.realtime.ModeGovernor`; ``backward_bidir``, which cannot
        extrapolate, then holds).

        The image is read-only, on both backends: it is also the eye's previous output, whose
        colour the next frame's unmatched pixels keep, so a caller that drew on it (an overlay
        in place) would have changed the next frame. Copy it (``image.copy()``) to modify it.

        Raises:
            InvalidInputError: for an invalid camera or time, or while another thread renders
                with this client.
        """
        if not self._rendering.acquire(blocking=False):
            raise InvalidInputError(
                "Client.render: this client is rendering a frame in another thread; a client "
                "renders one frame at a time (use one client per thread, or a lock)"
            )
        try:
            return self._render(camera, float(time), eye, interpolate)
        finally:
            self._rendering.release()

    def _render(self, camera: Camera, time: float, eye: int, interpolate: bool = True) -> _Image:
        """:meth:`render` with its arguments checked, one thread at a time."""
        info = self.choose(time, interpolate=interpolate)
        prev = self._previous.get(eye)
        if prev is not None and prev.shape[:2] != camera.shape:
            prev = None
        if info.mode == "hold" or info.newer is None:
            # Read-only, as every image returned: the previous output itself serves.
            image = prev if prev is not None else np.zeros((*camera.shape, 3), np.uint8)
        else:
            older = None if info.older is None else self._frames[info.older]
            history = self._history_for((info.older, info.newer), eye)
            assert info.alpha is not None
            rendered: _Image | None = None
            if self._gpu is not None:
                try:
                    rendered = self._render_gpu(
                        older, info.older, info.newer, camera, info.alpha, prev, eye
                    )
                except GpuDeviceLostError as e:
                    # The CPU renders this frame and the rest: a lost device never works again,
                    # and the frames the client holds are all the CPU path needs.
                    self.lose_gpu(self._gpu.lost or str(e))
            if rendered is None:
                rendered = cast(_Image, _reproject_alpha(  # diagnostics=False: the image
                    older,
                    self._frames[info.newer],
                    camera,
                    info.alpha,
                    self.method,
                    options=self.options,
                    previous=prev,
                    diagnostics=False,
                    history=history,
                    backend="cpu",
                    paths=self._paths_of(info.older, info.newer),
                ))
            image = rendered
        # The returned image is the eye's previous output for the next frame's hole filling
        # (on the CPU; the GPU keeps its own copy on the device): read-only, so that a caller
        # cannot change the next frame through it (and the backends behave alike).
        image.flags.writeable = False
        self._previous[eye] = image
        self._buffer.prune(float(time))
        for j in [j for j in self._frames if j not in self._buffer.times]:
            del self._frames[j]
            del self._paths[j]
        for pair in [p for p in self._prepared if p[1] not in self._frames]:
            retired = self._prepared.pop(pair)
            retired.reset()  # lets go of the pair's arrays (it holds them while it may be used)
            self._retired.append(retired)
        # A device pair whose frames are gone is retired: the uploading side drops it
        # (retired_uploads), so that freeing its device memory costs no display frame.
        for pair in [p for p in self._uploaded if not self._holds(p)]:
            self._retire(self._uploaded.pop(pair))
        self.last_info = info
        return image

    def _history_for(self, pair: _Pair, eye: int) -> _native.BidirHistory:
        """The history of ``eye`` for ``pair``: backward_bidir's previous B-frame, and the
        pair-level work of ours (done once per pair instead of once per client frame). A history
        prepared for the pair (:meth:`adopt_prepared`) is used as it is; otherwise the eye's own
        is reset when the pair changes (its buffers are kept)."""
        last_pair, last = self._history.get(eye, (None, None))
        prepared = self._prepared.get(pair)
        if prepared is not None and self.method != "backward_bidir":
            history = prepared
        else:
            history = self._own.setdefault(eye, _native.BidirHistory())
            if pair != last_pair or last is not history:
                history.reset()
        self._history[eye] = (pair, history)
        return history

    @checked(
        older=optional(ints(-(1 << 63), (1 << 63) - 1)), newer=ints(-(1 << 63), (1 << 63) - 1),
        history=instances(_native.BidirHistory),
    )
    def adopt_prepared(
        self, older: int | None, newer: int, history: _native.BidirHistory
    ) -> None:
        """Uses ``history``, whose pair-level state for the held frames ``(older, newer)`` was
        computed off the display path (:func:`splitrender.prepare_pair`), for every client frame
        that renders that pair, so that the first of them costs no more than the others.
        ``backward_bidir`` keeps its own per-eye history (its state depends on the pose)."""
        self._prepared[(older, newer)] = history

    @checked(
        older=optional(ints(-(1 << 63), (1 << 63) - 1)), newer=ints(-(1 << 63), (1 << 63) - 1),
        pair=instances(GpuPair),
    )
    def adopt_uploaded(self, older: int | None, newer: int, pair: GpuPair) -> None:
        """Uses ``pair``, the held frames ``(older, newer)`` uploaded off the display path
        (``client.gpu.upload(...)``, :meth:`GpuReprojector.upload`), when client frames first
        render that pair: it is made current with no copy, so that the first of them costs no
        more than the others. ``backend="wgpu"`` only.

        Raises:
            InvalidInputError: on the CPU backend, or when the frames are not held.
        """
        if self._gpu is None and self.gpu_lost is not None:
            return  # uploaded before the device was lost: nothing renders it now
        if self._gpu is None:
            raise InvalidInputError(
                "adopt_uploaded: this client renders on the CPU (backend='cpu'); a pair uploaded "
                "to the GPU is for backend='wgpu' (use adopt_prepared with prepare_pair)"
            )
        if not self._holds((older, newer)):
            raise InvalidInputError(
                f"adopt_uploaded: expected held frames, got ({older}, {newer}); held: {self.held}"
            )
        self._uploaded[(older, newer)] = pair

    @checked(reason=strs())
    def lose_gpu(self, reason: str) -> None:
        """Renders on the CPU from now on, the GPU device having been lost (``reason``,
        :attr:`gpu_lost`): what a device-lost error met elsewhere (an upload on another thread)
        tells the client. Pairs uploaded to the device are dropped; the next frame of each pair
        does the CPU's pair work itself."""
        if self._gpu is None:
            return
        self.gpu_lost = reason
        self.backend = "cpu"
        self._gpu = None
        self._gpu_pair = None
        self._uploaded.clear()
        self._retired_pairs.clear()

    def retired_uploads(self) -> list[GpuPair]:
        """Takes the device pairs this client no longer uses (those adopted with
        :meth:`adopt_uploaded` whose frames are gone, and each pair an adopted one replaced on the
        device); dropping them (on the uploading thread) frees their device memory."""
        out, self._retired_pairs = self._retired_pairs, []
        return out

    def _retire(self, pair: GpuPair | None) -> None:
        """Keeps ``pair`` for :meth:`retired_uploads`; at most :data:`_MAX_RETIRED` (beyond
        them, for a caller that never takes them, the oldest is dropped here)."""
        if pair is not None:
            self._retired_pairs.append(pair)
            del self._retired_pairs[:-_MAX_RETIRED]

    def _holds(self, pair: _Pair) -> bool:
        return pair[1] in self._frames and (pair[0] is None or pair[0] in self._frames)

    @checked(index=ints(-(1 << 63), (1 << 63) - 1))
    def held_frame(self, index: int) -> ServerFrame | None:
        """The held server frame ``index``, or ``None``."""
        return self._frames.get(index)

    @checked(
        older=optional(ints(-(1 << 63), (1 << 63) - 1)), newer=ints(-(1 << 63), (1 << 63) - 1)
    )
    def was_prepared(self, older: int | None, newer: int) -> bool:
        """Whether client frames of the pair ``(older, newer)`` use a history adopted with
        :meth:`adopt_prepared` (on the GPU: a pair adopted with :meth:`adopt_uploaded`)."""
        if self._gpu is not None:
            return (older, newer) in self._uploaded
        return self.method != "backward_bidir" and (older, newer) in self._prepared

    def retired_histories(self) -> list[_native.BidirHistory]:
        """Takes the adopted histories whose pair can no longer be rendered (reuse them for the
        next :func:`splitrender.prepare_pair`: their buffers are already allocated)."""
        out, self._retired = self._retired, []
        return out

    def _render_gpu(
        self,
        older: ServerFrame | None,
        older_index: int | None,
        newer_index: int,
        camera: Camera,
        alpha: float,
        prev: _Image | None,
        eye: int,
    ) -> _Image:
        assert self._gpu is not None
        pair = (older_index, newer_index)
        if pair != self._gpu_pair:
            self._gpu_pair = None
            uploaded = self._uploaded.get(pair)
            if uploaded is not None:
                self._retire(self._gpu.install(uploaded))
            else:
                paths = self._paths_of(older_index, newer_index)
                self._gpu._load(older, self._frames[newer_index], paths)
            self._gpu_pair = pair
        # The eye's output slot on the device holds exactly `prev` (the last frame returned for
        # this eye at this size), so nothing needs to go up but the pose.
        return self._gpu.render(
            camera,
            alpha,
            self.method,
            options=self.options,
            previous="keep" if prev is not None else None,
            slot=eye,
        )

    def _paths_of(self, older: int | None, newer: int) -> tuple[str, str]:
        return ("older" if older is None else self._paths[older], self._paths[newer])

    def reset(self) -> None:
        """Forgets every frame, previous output and history (a new session)."""
        self._buffer.clear()
        self._frames.clear()
        self._paths.clear()
        self._previous.clear()
        self._history.clear()
        self._own.clear()
        self._prepared.clear()
        self._retired.clear()
        self._uploaded.clear()
        self._retired_pairs.clear()
        self.last_info = None
        self._gpu_pair = None
