"""Playback of a whole session: :func:`play` drives a :class:`~splitrender.client.client.Client`
through a :class:`~splitrender.net.model.NetworkModel` (the batch path the experiments use), so
that :func:`play` and :meth:`splitrender.net.model.Schedule.build` agree frame for frame."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from splitrender.client.client import Client
from splitrender.errors import InvalidInputError
from splitrender.net.model import (
    TIME_EPS,
    ClientFrameInfo,
    NetworkModel,
    Schedule,
    network_for,
)
from splitrender.types import Camera, ReprojectOptions, ServerFrame, check_server_frame
from splitrender.types import (  # argument checks
    BOOL,
    CALLABLE,
    ITERABLE,
    MAX_RATE,
    checked,
    floats,
    instances,
    ints,
    items,
    optional,
    strs,
)

__all__ = ["PlaybackResult", "frame_nbytes", "play"]

_Image = npt.NDArray[np.uint8]

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
        """The session as a :class:`~splitrender.net.model.Schedule` (without the images)."""
        return Schedule(list(self.info), list(self.arrivals), sends=list(self.sends))


@checked(
    frames=ITERABLE, cameras=items(instances(Camera)), network=optional(instances(NetworkModel)),
    fps=floats(positive=True, hi=MAX_RATE), method=strs(),
    frame_sizes=optional(items(ints(0, 1 << 40))), lead=optional(floats(lo=0.0)),
    keep_images=BOOL, on_frame=optional(CALLABLE), backend=strs(),
)
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
    ``keep_images=False`` the result holds no images. The images are read-only (see
    :meth:`Client.render`; a frame that holds repeats the same array). ``backend`` is
    ``"cpu"`` or ``"wgpu"`` (see :class:`Client`).

    Raises:
        InvalidInputError: for invalid arguments, a network whose ``client_fps`` is not ``fps``,
            or frames out of order.
    """
    client = Client(method, options, backend=backend)
    fs = client.server_fps
    net = network_for(network, fps, "the client's fps")
    lead_s = 1.0 / fs if lead is None else float(lead)
    cams = list(cameras)
    link = net.link()
    it = iter(frames)
    sizes = None if frame_sizes is None else list(frame_sizes)
    arrivals: list[float | None] = []
    sends: list[float] = []
    pending: tuple[ServerFrame, float | None, int] | None = None
    exhausted = False

    last_time = [0.0]  # the time of the frame taken before

    def next_frame() -> tuple[ServerFrame, float | None, int] | None:
        k = len(sends)
        try:
            f = next(it)
        except StopIteration:
            return None
        check_server_frame(f"frames[{k}]", f)
        if k and f.time < last_time[0]:
            raise InvalidInputError(
                f"frames[{k}]: time {f.time:g} s is before frames[{k - 1}]'s "
                f"{last_time[0]:g} s; expected the frames in time order"
            )
        last_time[0] = f.time
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
        return (f, a, k)

    result = PlaybackResult([], [], arrivals, sends)
    for n, cam in enumerate(cams):
        t = n / fps
        while not exhausted:
            if pending is None:
                pending = next_frame()
                if pending is None:
                    exhausted = True
                    break
            f, a, k = pending
            if a is not None and a > t + TIME_EPS:
                break
            if a is not None:
                client._receive(f, f"frames[{k}]", checked=True)
            pending = None
        image = client.render(cam, t)
        assert client.last_info is not None
        if keep_images:
            result.images.append(image)
        result.info.append(client.last_info)
        if on_frame is not None:
            on_frame(n, image, client.last_info)
    return result
