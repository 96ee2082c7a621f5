"""The client runtime: :class:`Client`, the object a headset integration drives (feed it server
frames as they arrive and ask for a frame per display refresh), and :func:`play`, the batch path
the experiments use (a whole session through a :class:`~splitrender.network.NetworkModel`).

Which frames, ``α`` and mode each client frame uses is decided by
:func:`splitrender.network.choose_frames` (see :mod:`splitrender.network` for the timing rules,
REFERENCE.md §2.1), so :func:`play` and :meth:`splitrender.network.Schedule.build` agree frame
for frame.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from splitrender import _native
from splitrender.errors import InvalidInputError
from splitrender.gpu import GpuReprojector, check_backend
from splitrender.network import (
    TIME_EPS,
    ClientFrameInfo,
    FrameBuffer,
    NetworkModel,
    Schedule,
    choose_frames,
)
from splitrender.reproject import METHODS, reproject_alpha
from splitrender.types import Camera, ReprojectOptions, ServerFrame

__all__ = ["Client", "PlaybackResult", "frame_nbytes", "play"]

_Image = npt.NDArray[np.uint8]


class Client:
    """A split-rendering client for one reprojection ``method``.

    ``receive`` server frames as they arrive, then ``render`` a frame for each display refresh
    at the client's actual camera and display time. The client holds at most ``capacity``
    server frames (see :class:`~splitrender.network.FrameBuffer`: duplicates, stale frames and
    frames beyond capacity are refused), keeps its previous output per ``eye`` for hole filling
    (DESIGN.md: no-match pixels keep the previous client frame's colour) and, for
    ``backward_bidir``, a :class:`~splitrender.BidirHistory` per eye that is reset whenever the
    pair changes. ``server_fps`` (default ``options.server_fps``, else 10) sets ``α`` when
    extrapolating.

    ``backend="wgpu"`` reprojects on the GPU (:mod:`splitrender.gpu`): the pair is uploaded once
    when it changes, each client frame uploads only its pose, and the previous output of each eye
    stays on the device for hole filling.

    Raises:
        InvalidInputError: for an unknown method, invalid options, a ``server_fps`` that
            contradicts ``options.server_fps``, or a method the backend cannot run.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """

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
        self._previous: dict[int, _Image] = {}
        self._history: dict[int, tuple[tuple[int, int] | None, _native.BidirHistory]] = {}
        self.last_info: ClientFrameInfo | None = None
        """How the last rendered frame was made (frames used, ``α``, mode)."""
        self._gpu = GpuReprojector() if self.backend == "wgpu" else None
        self._gpu_pair: tuple[int | None, int] | None = None

    def __repr__(self) -> str:
        return f"Client(method={self.method!r}, backend={self.backend!r}, held={self.held})"

    @property
    def server_fps(self) -> float:
        return self.options.server_fps

    @property
    def held(self) -> tuple[int, ...]:
        """Indices of the server frames held, oldest first."""
        return tuple(sorted(self._frames))

    def receive(self, frame: ServerFrame, arrival_time: float | None = None) -> bool:
        """Takes a server frame that has arrived; returns whether it was kept (``False`` for a
        duplicate, a stale frame or a full buffer). ``arrival_time`` is informational only: a
        frame is usable from its receipt on.

        Raises:
            InvalidInputError: if ``frame`` is not a :class:`ServerFrame` or its time contradicts
                the order of the frames held.
        """
        if not isinstance(frame, ServerFrame):
            raise InvalidInputError(f"frame: expected a ServerFrame, got {type(frame).__name__}")
        if not self._buffer.receive(frame.index, frame.time):
            return False
        self._frames[frame.index] = frame
        return True

    def choose(self, time: float) -> ClientFrameInfo:
        """The frames, ``α`` and mode :meth:`render` would use at ``time`` (no state change)."""
        return choose_frames(
            self._buffer.times,
            time,
            self.server_fps,
            self.method,
            splat_bidirectional=self.options.splat_bidirectional,
        )

    def render(self, camera: Camera, time: float, *, eye: int = 0) -> _Image:
        """The client frame (``uint8[H, W, 3]``) at ``camera`` and display ``time`` seconds;
        ``eye`` keys the previous-output and history state (0 mono/left, 1 right).
        :attr:`last_info` then says how it was made. Holding (no usable frame) returns the
        previous output of that eye, or black.

        Raises:
            InvalidInputError: for an invalid camera or time.
        """
        if not isinstance(camera, Camera):
            raise InvalidInputError(f"camera: expected a Camera, got {type(camera).__name__}")
        if isinstance(time, bool) or not isinstance(time, numbers.Real) or not math.isfinite(time):
            raise InvalidInputError(f"time: expected a finite float, got {time!r}")
        info = self.choose(time)
        prev = self._previous.get(eye)
        if prev is not None and prev.shape[:2] != camera.shape:
            prev = None
        if info.mode == "hold" or info.newer is None:
            image = prev.copy() if prev is not None else np.zeros((*camera.shape, 3), np.uint8)
        else:
            older = None if info.older is None else self._frames[info.older]
            # One history per eye and server-frame pair: backward_bidir's previous B-frame, and the
            # pair-level work of ours (done once per pair instead of once per client frame).
            pair = (info.older, info.newer) if info.older is not None else None
            last_pair, history = self._history.get(eye, (None, _native.BidirHistory()))
            if pair != last_pair:
                history.reset()
            self._history[eye] = (pair, history)
            assert info.alpha is not None
            if self._gpu is not None:
                image = self._render_gpu(older, info.older, info.newer, camera, info.alpha, prev, eye)
            else:
                image = reproject_alpha(
                    older,
                    self._frames[info.newer],
                    camera,
                    info.alpha,
                    self.method,
                    options=self.options,
                    previous=prev,
                    history=history,
                )
        self._previous[eye] = image
        self._buffer.prune(float(time))
        for j in [j for j in self._frames if j not in self._buffer.times]:
            del self._frames[j]
        self.last_info = info
        return image

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
            self._gpu.load(older, self._frames[newer_index])
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

    def reset(self) -> None:
        """Forgets every frame, previous output and history (a new session)."""
        self._buffer.clear()
        self._frames.clear()
        self._previous.clear()
        self._history.clear()
        self.last_info = None
        self._gpu_pair = None


def frame_nbytes(frame: ServerFrame) -> int:
    """Bytes of every buffer of ``frame`` uncompressed: the packet size :func:`play` assumes
    when no sizes are given."""
    total = 0
    for cam in (frame.main, *frame.aux):
        for name in ("color", "depth", "motion_fwd", "motion_bwd"):
            a = getattr(cam, name)
            if a is not None:
                total += int(a.nbytes)
        for sh in (cam.shadow_fwd, cam.shadow_bwd):
            if sh is not None:
                total += int(sh.bits.nbytes + sh.s_min.nbytes + sh.s_max.nbytes)
    return total


@dataclass
class PlaybackResult:
    """The output of :func:`play`: ``images[n]`` and ``info[n]`` per client frame,
    ``arrivals[k]`` (``None``: lost) and ``sends[k]`` per server frame read (in the order given;
    :func:`play` stops reading frames once the last client frame is rendered)."""

    images: list[_Image]
    info: list[ClientFrameInfo]
    arrivals: list[float | None] = field(default_factory=list)
    sends: list[float] = field(default_factory=list)

    def modes(self) -> list[str]:
        return [i.mode for i in self.info]

    def summary(self) -> dict[str, int]:
        """How many client frames each mode made."""
        return {
            m: sum(i.mode == m for i in self.info) for m in ("interpolate", "extrapolate", "hold")
        }

    def schedule(self) -> Schedule:
        """The session as a :class:`~splitrender.network.Schedule` (without the images)."""
        return Schedule(list(self.info), list(self.arrivals), sends=list(self.sends))


def play(
    frames: Iterable[ServerFrame],
    cameras: Sequence[Camera],
    network: NetworkModel | None = None,
    fps: float = 120.0,
    method: str = "ours",
    *,
    options: ReprojectOptions | None = None,
    frame_sizes: Sequence[int] | None = None,
    lead: float | None = None,
    keep_images: bool = True,
    on_frame: Callable[[int, _Image, ClientFrameInfo], None] | None = None,
    backend: str = "cpu",
) -> PlaybackResult:
    """Plays a session: server ``frames`` (in index order; consumed lazily, so a recording can be
    streamed) are sent ``lead`` seconds (default ``1 / options.server_fps``) before their time
    through ``network`` (default: ideal) with ``frame_sizes`` bytes (default: uncompressed,
    :func:`frame_nbytes`; pass the encoded packet sizes for a compressed stream), and a
    :class:`Client` renders client frame ``n`` at ``cameras[n]`` and time ``n / fps``.

    ``on_frame(n, image, info)`` is called for every client frame (e.g. to write it out); with
    ``keep_images=False`` the result holds no images. ``backend`` is ``"cpu"`` or ``"wgpu"``
    (see :class:`Client`).

    Raises:
        InvalidInputError: for invalid arguments, a network whose ``client_fps`` is not ``fps``,
            or frames out of order.
    """
    client = Client(method, options, backend=backend)
    fs = client.server_fps
    net = network if network is not None else NetworkModel(client_fps=fps)
    if not isinstance(net, NetworkModel):
        raise InvalidInputError(f"network: expected a NetworkModel, got {type(net).__name__}")
    if not np.isclose(net.client_fps, fps):
        raise InvalidInputError(
            f"network.client_fps: expected the client's fps = {fps}, got {net.client_fps}"
        )
    lead_s = 1.0 / fs if lead is None else float(lead)
    cams = list(cameras)
    for n, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise InvalidInputError(f"cameras[{n}]: expected a Camera, got {type(c).__name__}")
    link = net.link()
    it = iter(frames)
    sizes = None if frame_sizes is None else list(frame_sizes)
    arrivals: list[float | None] = []
    sends: list[float] = []
    pending: tuple[ServerFrame, float | None] | None = None
    exhausted = False

    def next_frame() -> tuple[ServerFrame, float | None] | None:
        k = len(sends)
        try:
            f = next(it)
        except StopIteration:
            return None
        if not isinstance(f, ServerFrame):
            raise InvalidInputError(f"frames[{k}]: expected a ServerFrame, got {type(f).__name__}")
        if sizes is not None:
            if k >= len(sizes):
                raise InvalidInputError(
                    f"frame_sizes: expected a size for frame {k}, got {len(sizes)} sizes"
                )
            size = sizes[k]
        else:
            size = frame_nbytes(f)
        send = f.time - lead_s
        sends.append(send)
        a = link.send(send, size)
        arrivals.append(a)
        return (f, a)

    result = PlaybackResult([], [], arrivals, sends)
    for n, cam in enumerate(cams):
        t = n / fps
        while not exhausted:
            if pending is None:
                pending = next_frame()
                if pending is None:
                    exhausted = True
                    break
            f, a = pending
            if a is not None and a > t + TIME_EPS:
                break
            if a is not None:
                client.receive(f, a)
            pending = None
        image = client.render(cam, t)
        assert client.last_info is not None
        if keep_images:
            result.images.append(image)
        result.info.append(client.last_info)
        if on_frame is not None:
            on_frame(n, image, client.last_info)
    return result
