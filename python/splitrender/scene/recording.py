"""Recordings: every server buffer of every camera and the ground-truth client frames of a scene,
on disk (format ``splitrender-recording``, version 2; docs/recording-format.md).

Layout of a recording directory::

    DIR/
      manifest.json              # written last: its presence marks a complete recording
      server/000000.npz ...      # one per server frame k = 0..K
      client/000000.npz ...      # one per client frame n = 0..N-1

``manifest.json`` holds ``format`` (``"splitrender-recording"``), ``version`` (2), ``generator``,
``scene``, ``variant``, ``scale``, ``fs``, ``fc``, ``subframes`` (S), ``seconds``, ``stereo``,
``samples`` (colour sub-samples per pixel side, ``{"main", "aux", "client"}``),
``near``/``far``, ``cameras`` (``main``/``aux``/``client`` as ``[width, height]``, ``eyes``),
``client_motion`` (``{"source": "path"}`` or ``{"source": "trace", "file", "sha256",
"translation_scale"}``, both with ``prediction_delay``), and ``server_frames``/``client_frames``:
lists of ``{"index", "time", "file", "bytes", "sha256"}``.

Each ``.npz`` is an uncompressed zip of ``.npy`` members (numpy format 1.0, no pickles), written
in a fixed order with fixed dates, so rendering the same inputs twice gives identical bytes; it
loads with ``numpy.load``. A server frame holds ``pose`` (camera-to-world ``float64[4,4]`` of the
predicted head) and, per camera ``c`` in ``main``, ``aux0``, ``aux1``: ``c.view``, ``c.proj``
(``float64[4,4]``), ``c.color`` (``uint8[H,W,3]``), ``c.depth`` (``float32[H,W]``),
``c.motion_fwd``, ``c.motion_bwd`` (``float32[H,W,3]``), ``c.shadow_{fwd,bwd}_bits``
(``uint32[H,W]``), ``c.shadow_{fwd,bwd}_{min,max}`` (``uint8[H,W,3]``). A client frame holds
``pose`` (the client's actual head) and per eye ``e`` in ``eye0`` (mono, or left) and ``eye1``
(right, stereo): ``e.view``, ``e.proj`` and ``e.color`` (the ground truth).

:func:`write_frames` (which :func:`write_recording` and the dataset import use) writes into
``DIR.partial-<pid>`` next to ``DIR`` and renames it at the end; on an exception (Ctrl-C included)
the partial directory is removed, and one left by a killed process is refused by
:func:`load_recording`. Loading checks everything it reads against the
manifest (format and version, sizes, file sizes before reading, SHA-256, member names, dtypes and
shapes before allocating) and raises :class:`RecordingError` naming the file and the problem.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import shutil
import tokenize
import zipfile
import zlib
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, BinaryIO, Generic, TypeVar, overload

import numpy as np
import numpy.typing as npt

from splitrender._native import __version__
from splitrender.errors import InvalidInputError, SplitRenderError
from splitrender.files import (
    JSON_KINDS,
    open_regular,
    read_json_object,
    read_regular,
    rename_new_folder,
)
from splitrender.scene.builtin import (
    MAX_SAMPLES,
    ClientMotion,
    PathMotion,
    Scene,
    Trace,
    TraceMotion,
    default_samples,
)
from splitrender.types import (
    MAX_SIDE,
    Camera,
    CameraFrame,
    ClientRequest,
    ServerFrame,
    ShadowBuffers,
)
from splitrender.types import (  # argument checks
    BOOL,
    CALLABLE,
    PATH,
    checked,
    floats,
    instances,
    ints,
    optional,
    strs,
)

__all__ = [
    "FORMAT",
    "MAX_FRAMES",
    "VERSION",
    "ClientFrame",
    "Recording",
    "RecordingError",
    "RecordingRender",
    "RecordingSettings",
    "check_destination",
    "load_recording",
    "plan",
    "write_entries",
    "write_frames",
    "write_recording",
]

FORMAT = "splitrender-recording"
#: 2: colour and ground truth are supersampled (``samples``); version 1 recordings were point
#: sampled, so their colours differ and they are refused rather than mixed with new ones.
VERSION = 2
_MANIFEST = "manifest.json"
_MAX_MANIFEST_BYTES = 64 * 1024 * 1024
#: Most server or client frames one recording plans (seven minutes at 120 Hz): fs=1e6 planned
#: 300,000 frames to render, and a product such as seconds·fc of 1e400 overflowed in plan().
MAX_FRAMES = 50_000
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
# Per-member allowance over the array data: zip local header + central directory + npy header.
_MEMBER_OVERHEAD = 512
_PARTIAL = re.compile(r"\.partial-\d+$")
_CAMERAS = ("main", "aux0", "aux1")
_SERVER_ARRAYS: tuple[tuple[str, type[np.generic], int], ...] = (
    # (name, dtype, channels: 0 = [H, W], 3 = [H, W, 3], -1 = [4, 4])
    ("view", np.float64, -1),
    ("proj", np.float64, -1),
    ("color", np.uint8, 3),
    ("depth", np.float32, 0),
    ("motion_fwd", np.float32, 3),
    ("motion_bwd", np.float32, 3),
    ("shadow_fwd_bits", np.uint32, 0),
    ("shadow_fwd_min", np.uint8, 3),
    ("shadow_fwd_max", np.uint8, 3),
    ("shadow_bwd_bits", np.uint32, 0),
    ("shadow_bwd_min", np.uint8, 3),
    ("shadow_bwd_max", np.uint8, 3),
)

Progress = Callable[[int, int], None]
Spec = dict[str, tuple[np.dtype[Any], tuple[int, ...]]]


class RecordingError(SplitRenderError):
    """A recording that cannot be written or read: missing, unfinished, corrupted or of another
    format version. The message names the file and the problem."""


# --------------------------------------------------------------------------- writing


def _npz_bytes(arrays: Sequence[tuple[str, npt.NDArray[Any]]]) -> bytes:
    """An uncompressed ``.npz`` with members in the given order and fixed metadata."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for name, a in arrays:
            member = io.BytesIO()
            np.lib.format.write_array(
                member, np.ascontiguousarray(a), version=(1, 0), allow_pickle=False
            )
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            info.create_system = 3
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


def _shape(channels: int, w: int, h: int) -> tuple[int, ...]:
    """The shape of a server array with ``channels`` (see ``_SERVER_ARRAYS``) at ``w`` x ``h``."""
    return (4, 4) if channels < 0 else (h, w) if channels == 0 else (h, w, 3)


def _server_arrays(pose: npt.NDArray[np.float64], f: ServerFrame) -> list[tuple[str, Any]]:
    """The members of server frame ``f``'s file; a buffer it lacks (``None``) is zero: no
    motion, no shadow change."""
    out: list[tuple[str, Any]] = [("pose", pose)]
    for cam, cf in zip(_CAMERAS, (f.main, *f.aux)):
        sf, sb = cf.shadow_fwd, cf.shadow_bwd
        values: dict[str, npt.NDArray[Any] | None] = {
            "view": cf.camera.view,
            "proj": cf.camera.proj,
            "color": cf.color,
            "depth": cf.depth,
            "motion_fwd": cf.motion_fwd,
            "motion_bwd": cf.motion_bwd,
            "shadow_fwd_bits": None if sf is None else sf.bits,
            "shadow_fwd_min": None if sf is None else sf.s_min,
            "shadow_fwd_max": None if sf is None else sf.s_max,
            "shadow_bwd_bits": None if sb is None else sb.bits,
            "shadow_bwd_min": None if sb is None else sb.s_min,
            "shadow_bwd_max": None if sb is None else sb.s_max,
        }
        w, h = cf.camera.width, cf.camera.height
        for name, dt, ch in _SERVER_ARRAYS:
            v = values[name]
            out.append((f"{cam}.{name}", np.zeros(_shape(ch, w, h), dt) if v is None else v))
    return out


def _client_arrays(c: ClientFrame) -> list[tuple[str, Any]]:
    """The members of client frame ``c``'s file."""
    out: list[tuple[str, Any]] = [("pose", c.pose)]
    for e, (cam, img) in enumerate(zip(c.cameras, c.ground_truths)):
        out += [(f"eye{e}.view", cam.view), (f"eye{e}.proj", cam.proj), (f"eye{e}.color", img)]
    return out


def plan(seconds: float, fs: float, fc: float) -> tuple[int, int]:
    """``(server frames, client frames)`` of a recording: client frames ``n = 0..N-1`` with
    ``N = round(seconds·fc)``, server frames ``k = 0..K`` with ``K = ceil(t_{N-1}·fs)`` so that
    every client time lies between two recorded server frames."""
    n = max(1, round(seconds * fc))
    k = math.ceil(round((n - 1) / fc * fs, 9))
    return k + 1, n


def _check_positive(what: str, v: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise RecordingError(f"{what}: expected a finite number > 0, got {v!r}")
    return float(v)


@dataclass(frozen=True, kw_only=True)
class RecordingSettings:
    """What a recording holds: :func:`write_recording`'s keyword arguments but ``overwrite`` and
    ``progress``, with the same defaults and meaning (checked by :class:`RecordingRender`)."""

    variant: str = "dynamic"
    seconds: float = 2.0
    scale: float = 0.125
    fs: float = 10.0
    fc: float = 120.0
    subframes: int = 4
    stereo: bool = False
    trace: Trace | None = None
    translation_scale: float = 1.0
    samples: int | None = None


class RecordingRender:
    """Renders the frames of one recording, each on its own (``write_recording`` renders them
    all in order; ``eval``'s sweep renders chunks of them in separate tasks and assembles the
    recording with :func:`write_entries`). Each frame depends only on its index, so the bytes
    are the same however the frames are split. The checks raise :class:`RecordingError`
    (``InvalidInputError`` for bad scene arguments)."""

    def __init__(self, scene: str | Scene, settings: RecordingSettings) -> None:
        trace, samples = settings.trace, settings.samples
        sc = scene if isinstance(scene, Scene) else Scene(scene, settings.variant)
        seconds = _check_positive("seconds", settings.seconds)
        fs = _check_positive("fs", settings.fs)
        fc = _check_positive("fc", settings.fc)
        if seconds > sc.duration + 1e-9:
            raise RecordingError(
                f"seconds: scene {sc.name!r} lasts {sc.duration:g} s, asked for {seconds:g} s"
            )
        if trace is not None and seconds > trace.duration + 1e-9:
            raise RecordingError(
                f"{trace.name}: trace lasts {trace.duration:.3f} s, asked for {seconds:g} s"
            )
        if samples is not None and (
            isinstance(samples, bool) or not isinstance(samples, int)
            or not 1 <= samples <= MAX_SAMPLES
        ):
            raise RecordingError(
                f"samples: expected an int in 1..{MAX_SAMPLES} or None, got {samples!r}")
        for what, rate in (("fs", fs), ("fc", fc)):
            # Checked as floats before plan() rounds them: a product too large for a float is inf.
            if seconds * rate > MAX_FRAMES:
                raise RecordingError(
                    f"{what}: {rate:g} frames/s for {seconds:g} s is more than {MAX_FRAMES} "
                    f"frames; expected seconds x {what} <= {MAX_FRAMES}"
                )
        self.scene = sc
        self.motion: ClientMotion = (
            PathMotion(sc) if trace is None
            else TraceMotion(sc, trace, settings.translation_scale)
        )
        self.seconds, self.scale, self.fs, self.fc = seconds, settings.scale, fs, fc
        self.subframes, self.stereo, self.samples = settings.subframes, settings.stereo, samples
        self.width, self.height = sc.main_size(self.scale)
        self.n_server, self.n_client = plan(seconds, fs, fc)

    def server_frame(self, k: int) -> tuple[npt.NDArray[np.float64], ServerFrame]:
        """Server frame ``k`` and the head pose it was rendered at."""
        pose = self.motion.server_pose(k, self.fs)
        f = self.scene.server_frame(k, self.scale, self.fs, self.subframes, pose=pose,
                                    samples=self.samples)
        return pose, f

    def client_frame(self, n: int) -> ClientFrame:
        t = n / self.fc
        pose = self.motion.client_pose(t)
        eyes = self.scene.client_frames(n, self.scale, self.fc, self.stereo, pose=pose,
                                        samples=self.samples)
        return ClientFrame(n, t, pose, tuple(c for c, _ in eyes), tuple(i for _, i in eyes))

    def server_entry(self, k: int) -> tuple[float, bytes, list[list[int]]]:
        """Server frame ``k`` as written: ``(time, npz bytes, auxiliary cameras' sizes)``."""
        pose, f = self.server_frame(k)
        return f.time, _npz_bytes(_server_arrays(pose, f)), [
            [a.camera.width, a.camera.height] for a in f.aux]

    def client_entry(self, n: int) -> tuple[float, bytes]:
        """Client frame ``n`` as written: ``(time, npz bytes)``."""
        c = self.client_frame(n)
        return c.time, _npz_bytes(_client_arrays(c))

    def fields(self, aux_size: list[list[int]]) -> dict[str, Any]:
        """The manifest's fields (between ``version`` and ``server_frames``)."""
        def used_samples(w: int, h: int) -> int:
            return self.samples if self.samples is not None else default_samples(w, h)

        sc, width, height = self.scene, self.width, self.height
        return {
            "generator": f"splitrender {__version__}",
            "scene": sc.name,
            "variant": sc.variant,
            "scale": float(self.scale),
            "fs": self.fs,
            "fc": self.fc,
            "subframes": self.subframes,
            "seconds": self.seconds,
            "stereo": bool(self.stereo),
            "samples": {
                "main": used_samples(width, height),
                "aux": used_samples(*aux_size[0]),
                "client": used_samples(width, height),
            },
            "near": sc.near,
            "far": sc.far,
            "cameras": {
                "main": [width, height],
                "aux": aux_size,
                "client": [width, height],
                "eyes": 2 if self.stereo else 1,
            },
            "client_motion": self.motion.describe(),
        }


@checked(
    out=PATH, scene=instances((str, Scene)), variant=strs(), seconds=floats(positive=True),
    scale=floats(positive=True), fs=floats(positive=True), fc=floats(positive=True),
    subframes=ints(1, 16), stereo=BOOL, trace=optional(instances(Trace)),
    translation_scale=floats(), overwrite=BOOL, progress=optional(CALLABLE),
)
def write_recording(
    out: str | os.PathLike[str],
    scene: str | Scene,
    *,
    variant: str = "dynamic",
    seconds: float = 2.0,
    scale: float = 0.125,
    fs: float = 10.0,
    fc: float = 120.0,
    subframes: int = 4,
    stereo: bool = False,
    trace: Trace | None = None,
    translation_scale: float = 1.0,
    samples: int | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> Path:
    """Renders a recording of ``scene`` into directory ``out`` and returns its path.

    Colour (server and ground truth) is the mean of ``samples x samples`` sub-samples per pixel;
    ``None`` takes :func:`~splitrender.scene.builtin.default_samples` of each camera's size. The counts
    used are written to the manifest.

    ``progress(done, total)`` is called after every rendered frame (server and client). Raises
    :class:`RecordingError` when ``out`` exists (unless ``overwrite``) or ``seconds`` exceeds
    the scene's or trace's duration, ``InvalidInputError`` for bad scene arguments."""
    out = Path(out)
    r = RecordingRender(scene, RecordingSettings(
        variant=variant, seconds=seconds, scale=scale, fs=fs, fc=fc, subframes=subframes,
        stereo=stereo, trace=trace, translation_scale=translation_scale, samples=samples,
    ))
    check_destination(out, overwrite)
    aux_size: list[list[int]] = []

    def server_entry(k: int) -> tuple[float, bytes]:
        nonlocal aux_size
        t, data, aux_size = r.server_entry(k)
        return t, data

    return write_entries(
        out,
        lambda: r.fields(aux_size),  # after the frames: the auxiliary cameras' size
        LazyFrames(r.n_server, server_entry),
        LazyFrames(r.n_client, r.client_entry),
        overwrite=overwrite,
        progress=progress,
    )


def check_destination(out: Path, overwrite: bool) -> None:
    """Raises :class:`RecordingError` when ``out`` exists and not ``overwrite``, or exists and
    is not a recording directory or an empty one (a file, a symbolic link, another folder),
    or is the current directory or above it, even with ``overwrite``: the check
    :func:`write_frames` makes, for callers to make before long work."""
    # The name of an interrupted write: load_recording refuses it as unfinished, so a render
    # into x.partial-1 finished and was then "an unfinished recording; render it again".
    if _PARTIAL.search(out.name):
        raise RecordingError(
            f"{out}: a name ending in .partial-N is an unfinished recording's, which no reader "
            "opens; expected another name"
        )
    # Only a directory is replaced: write_frames moves the old one aside and removes it with
    # rmtree, which a file or a link would only fail at after the rename, all frames written.
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise RecordingError(
            f"{out}: exists and is not a directory; expected a new path or a recording "
            "directory to replace"
        )
    if not out.exists():
        return
    if not overwrite:
        raise RecordingError(
            f"{out}: already exists (choose another path, or replace it: --force, "
            "overwrite=True)"
        )
    # The rename that moves the old one aside cannot move the working directory or a folder
    # above it ("." failed as an internal error, ".." after the whole render).
    here, target = Path.cwd().resolve(), out.resolve()
    if target == here or target in here.parents:
        raise RecordingError(
            f"{out}: is the current directory or holds it; expected a folder beside or below it"
        )
    # --force replaces a recording, not whatever folder is given: a folder of notes, or one of
    # a recording's own subfolders, was removed with everything in it.
    if not (out / _MANIFEST).is_file() and any(out.iterdir()):
        raise RecordingError(
            f"{out}: is not a recording (no {_MANIFEST}) and not empty; --force (overwrite=True) "
            "replaces only a recording or an empty folder"
        )


def write_frames(
    out: str | os.PathLike[str],
    fields: Mapping[str, Any] | Callable[[], Mapping[str, Any]],
    server_frames: Sequence[tuple[npt.NDArray[np.float64], ServerFrame]],
    client_frames: Sequence[ClientFrame],
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> Path:
    """Writes a recording into directory ``out`` and returns its path: ``server_frames`` as
    ``(pose, frame)`` (the head pose it was rendered at, camera-to-world) and ``client_frames``;
    item ``i`` of each becomes frame ``i`` at the item's ``time``. A buffer a server frame lacks
    (``None``) is written as zeros: no motion, no shadow change.

    ``fields`` are the manifest's fields between ``version`` and ``server_frames``, in order
    (``generator`` ... ``client_motion``; see the module docstring); a callable is called once the
    frames are written, for fields that depend on them. Each sequence is read once, in order, so
    it may render or load a frame on access. ``progress(done, total)`` is called after every
    written frame.

    The recording is written into ``out.partial-<pid>`` and renamed to ``out`` when complete
    (an existing ``out`` is replaced then, with ``overwrite``); on an exception (Ctrl-C included)
    the partial directory is removed. Raises :class:`RecordingError` when ``out`` exists and
    not ``overwrite``, also when it appears while the frames are written (another run's
    recording, which is kept)."""

    def server(k: int) -> tuple[float, bytes]:
        pose, f = server_frames[k]
        return f.time, _npz_bytes(_server_arrays(pose, f))

    def client(n: int) -> tuple[float, bytes]:
        c = client_frames[n]
        return c.time, _npz_bytes(_client_arrays(c))

    return write_entries(out, fields, LazyFrames(len(server_frames), server),
                         LazyFrames(len(client_frames), client), overwrite=overwrite,
                         progress=progress)


def write_entries(
    out: str | os.PathLike[str],
    fields: Mapping[str, Any] | Callable[[], Mapping[str, Any]],
    server_frames: Sequence[tuple[float, bytes]],
    client_frames: Sequence[tuple[float, bytes]],
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> Path:
    """:func:`write_frames` of frames already serialised: ``(time, npz bytes)`` per frame, as
    :meth:`RecordingRender.server_entry` and :meth:`RecordingRender.client_entry` make them."""
    out = Path(out)
    check_destination(out, overwrite)
    # What load_recording refuses is not written.
    _check_count(len(server_frames), "server_frames", out)
    _check_count(len(client_frames), "client_frames", out)
    total = len(server_frames) + len(client_frames)
    tmp = out.with_name(f"{out.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        (tmp / "server").mkdir(parents=True)
        (tmp / "client").mkdir()
        done = 0

        def entry(kind: str, index: int, time: float, data: bytes) -> dict[str, Any]:
            nonlocal done
            rel = f"{kind}/{index:06d}.npz"
            (tmp / rel).write_bytes(data)
            done += 1
            if progress is not None:
                progress(done, total)
            return {
                "index": index,
                "time": time,
                "file": rel,
                "bytes": len(data),
                "sha256": hashlib.sha256(data).hexdigest(),
            }

        server = [entry("server", k, t, data) for k, (t, data) in enumerate(server_frames)]
        client = [entry("client", n, t, data) for n, (t, data) in enumerate(client_frames)]
        manifest = {
            "format": FORMAT,
            "version": VERSION,
            **(fields() if callable(fields) else fields),
            "server_frames": server,
            "client_frames": client,
        }
        text = json.dumps(manifest, indent=1, sort_keys=False) + "\n"
        (tmp / _MANIFEST).write_text(text, encoding="utf-8")
        if overwrite and out.exists():  # move the old one aside first, remove it after
            old = out.with_name(f"{out.name}.old-{os.getpid()}")
            out.rename(old)
            try:
                tmp.rename(out)
            except BaseException:
                old.rename(out)  # the previous recording goes back where it was
                raise
            shutil.rmtree(old)
        else:
            rename_new_folder(tmp, out, RecordingError, "; expected a new path (or replace it: "
                              "--force, overwrite=True)")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


# --------------------------------------------------------------------------- reading


def _fail(where: Path | str, problem: str) -> RecordingError:
    return RecordingError(f"{where}: {problem}")


def _json_kind(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if set(kinds) == {int, float}:
        return "a number"
    return " or ".join(JSON_KINDS.get(k, k.__name__) for k in kinds)


def _get(m: dict[str, Any], key: str, kind: type | tuple[type, ...], where: Path,
         within: str = "") -> Any:
    """Field ``key`` of the object ``m`` (``within`` names ``m``, e.g. ``server_frames[3]``),
    checked to be of ``kind``; the message names both in JSON's terms ("expected an integer,
    got a string"), not Python's (``<class 'int'>``)."""
    name = f"{within}.{key}" if within else key
    if key not in m:
        raise _fail(where, f"missing field {name!r}")
    v = m[key]
    if isinstance(v, bool) and kind is not bool:
        raise _fail(where, f"field {name!r}: expected {_json_kind(kind)}, got {v!r}")
    if not isinstance(v, kind):
        got = JSON_KINDS.get(type(v), type(v).__name__)
        raise _fail(where, f"field {name!r}: expected {_json_kind(kind)}, got {got}")
    return v


def _size(v: Any, what: str, where: Path) -> tuple[int, int]:
    if (
        not isinstance(v, list)
        or len(v) != 2
        or not all(isinstance(x, int) and not isinstance(x, bool) for x in v)
        or not all(1 <= x <= MAX_SIDE for x in v)
    ):
        raise _fail(
            where,
            f"cameras.{what}: expected [width, height] in 1..{MAX_SIDE}, got {v!r}",
        )
    return (v[0], v[1])


def _read_npz(
    root: Path, entry: dict[str, Any], spec: Spec, only: Collection[str] | None = None
) -> dict[str, npt.NDArray[Any]]:
    """Reads one frame file, checking its size, members, dtypes and shapes (each array's header
    is checked before its data is read).

    Without ``only`` the file is read whole and checked against the manifest's SHA-256. With
    ``only``, every header is checked but only those members' data are read and returned, each
    checked by the zip's own CRC-32 of the member, and the SHA-256 is not computed: a frame's
    matrices are 128 bytes of a 70 MB file at 1280×720, and hashing it all to read them cost
    110 ms per server frame. Whatever is read whole (a frame's buffers, a ground truth) is
    checked against the SHA-256 when it is read."""
    path = root / entry["file"]
    limit = _bytes_limit(spec)
    if entry["bytes"] > limit:
        raise _fail(
            path,
            f"manifest says {entry['bytes']} bytes, more than {limit} for its arrays",
        )
    source: BinaryIO
    try:
        if only is None:
            data = read_regular(path, entry["bytes"], "frame file", RecordingError)
            size = len(data)
            source = io.BytesIO(data)
        else:
            source = open_regular(path, "frame file", RecordingError)
            size = os.fstat(source.fileno()).st_size
    except FileNotFoundError:
        raise _fail(path, "missing file") from None
    except OSError as e:
        raise _fail(path, f"cannot read: {e.strerror or e}") from None
    with source:
        if size != entry["bytes"]:
            raise _fail(path, f"file is {size} bytes, the manifest says {entry['bytes']}")
        if only is None and hashlib.sha256(data).hexdigest() != entry["sha256"]:
            raise _fail(path, "SHA-256 does not match the manifest (corrupted file)")
        return _npz_members(path, source, spec, only)


def _npz_members(
    path: Path, source: BinaryIO, spec: Spec, only: Collection[str] | None
) -> dict[str, npt.NDArray[Any]]:
    """:func:`_read_npz`'s reading of the zip in ``source`` (of the file ``path``)."""
    out: dict[str, npt.NDArray[Any]] = {}
    try:
        with zipfile.ZipFile(source) as zf:
            names = zf.namelist()
            want = [f"{k}.npy" for k in spec]
            if sorted(names) != sorted(want):
                raise _fail(path, f"members {sorted(names)}, expected {sorted(want)}")
            for key, (dtype, shape) in spec.items():
                with zf.open(f"{key}.npy") as fh:
                    shp, fortran, dt = npy_header(fh, path, key)
                    if dt != dtype or tuple(shp) != shape or fortran:
                        raise _fail(
                            path,
                            f"{key}: {dt} {tuple(shp)}{' (Fortran order)' if fortran else ''}, "
                            f"expected {dtype} {shape}",
                        )
                    if only is not None and key not in only:
                        continue
                    raw = fh.read(int(np.prod(shape)) * dtype.itemsize)
                    # Read to the member's end, where zipfile compares its CRC-32: a member
                    # with more bytes than its array is refused, and the data are checked.
                    if fh.read(1):
                        raise _fail(path, f"{key}: more bytes than its {dtype} {shape} array")
                    out[key] = np.frombuffer(raw, dtype=dtype).reshape(shape).copy()
    except NPZ_ERRORS as e:
        raise _fail(path, f"not a valid npz: {type(e).__name__}: {e}") from None
    return out


#: What reading a malformed npz raises: numpy parses the npy header with tokenize and
#: ast.literal_eval, which report a malformed one as TokenError or SyntaxError (found by the
#: fuzz suite, issue 15); zipfile reports an unknown compression method as
#: NotImplementedError, an encrypted member as RuntimeError and broken compressed data as
#: zlib.error, OSError (bzip2) or lzma.LZMAError (an OSError).
NPZ_ERRORS = (zipfile.BadZipFile, ValueError, EOFError, SyntaxError, tokenize.TokenError,
              RecursionError, NotImplementedError, RuntimeError, OSError, zlib.error)


def _server_spec(sizes: Sequence[Sequence[int]]) -> Spec:
    """The members of a server frame's file whose cameras (main, then auxiliary) have
    ``sizes`` (``[width, height]`` each)."""
    spec: Spec = {"pose": (np.dtype(np.float64), (4, 4))}
    for cam, (w, h) in zip(_CAMERAS, sizes):
        for name, dt, ch in _SERVER_ARRAYS:
            spec[f"{cam}.{name}"] = (np.dtype(dt), _shape(ch, w, h))
    return spec


def _client_spec(size: Sequence[int], eyes: int) -> Spec:
    """The members of a client frame's file with ``eyes`` images of ``size`` (width, height)."""
    w, h = size
    m44 = (np.dtype(np.float64), (4, 4))
    spec: Spec = {"pose": m44}
    for e in range(eyes):
        spec[f"eye{e}.view"] = m44
        spec[f"eye{e}.proj"] = m44
        spec[f"eye{e}.color"] = (np.dtype(np.uint8), (h, w, 3))
    return spec


def _bytes_limit(spec: Spec) -> int:
    """The most bytes a frame file with the members ``spec`` takes: its arrays' bytes and, per
    member, room for the npy header and the zip's own records."""
    return sum(int(np.prod(shape)) * dt.itemsize + _MEMBER_OVERHEAD for dt, shape in spec.values())


def frame_bytes_limit(fields: dict[str, Any], part: str) -> int:
    """The most bytes a ``part`` (``"server"`` or ``"client"``) frame file of a recording whose
    manifest has ``fields`` (:meth:`RecordingRender.fields`) takes: a bound to read such a file
    with before anything else about it is known."""
    cams = fields["cameras"]
    spec = (_server_spec([cams["main"], *cams["aux"]]) if part == "server"
            else _client_spec(cams["client"], cams["eyes"]))
    return _bytes_limit(spec)


def npy_header(fh: IO[bytes], path: Path, key: str) -> tuple[tuple[int, ...], bool, np.dtype[Any]]:
    """``(shape, fortran_order, dtype)`` from the npy header of member ``key`` of the npz file
    ``path``, open as ``fh``; only npy format 1.0 (what the package writes) is read."""
    version = np.lib.format.read_magic(fh)
    if version != (1, 0):
        raise _fail(path, f"{key}: npy format {version}, expected (1, 0)")
    shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
    return tuple(shape), bool(fortran), dtype


@dataclass(frozen=True, slots=True, eq=False)
class ClientFrame:
    """Client frame ``index`` at ``time``: the client's actual head ``pose`` (camera-to-world),
    one camera and ground-truth image per eye (mono: one)."""

    index: int
    time: float
    pose: npt.NDArray[np.float64]
    cameras: tuple[Camera, ...]
    ground_truths: tuple[npt.NDArray[np.uint8], ...]

    @property
    def camera(self) -> Camera:
        """The (first / left) eye's camera."""
        return self.cameras[0]

    @property
    def ground_truth(self) -> npt.NDArray[np.uint8]:
        """The (first / left) eye's ground truth."""
        return self.ground_truths[0]

    @property
    def request(self) -> ClientRequest:
        """The request the client makes for this frame (first / left eye)."""
        return ClientRequest(self.cameras[0], self.time)

    @property
    def requests(self) -> tuple[ClientRequest, ...]:
        return tuple(ClientRequest(c, self.time) for c in self.cameras)


T = TypeVar("T")


class LazyFrames(Sequence[T], Generic[T]):
    """Frames made on access by ``load(i)``, never held: a recording's frames read from disk
    (each access reads and checks the file again), or the entries :func:`write_entries` is
    given, rendered or read one at a time. A slice is another such view, of the frames it
    names: ``rec.server_frames[:n]`` reads nothing until a frame is asked for, so a play of the
    first ``n`` never holds them all."""

    __slots__ = ("_load", "_n")

    def __init__(self, n: int, load: Callable[[int], T]) -> None:
        self._n, self._load = n, load

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, i: int) -> T: ...
    @overload
    def __getitem__(self, i: slice) -> LazyFrames[T]: ...
    def __getitem__(self, i: int | slice) -> T | LazyFrames[T]:
        if isinstance(i, slice):
            picked = range(*i.indices(self._n))
            load = self._load
            return LazyFrames(len(picked), lambda j: load(picked[j]))
        if not -self._n <= i < self._n:
            raise IndexError(f"frame {i} out of range (0..{self._n - 1})")
        return self._load(i % self._n)

    def __iter__(self) -> Iterator[T]:
        return (self._load(j) for j in range(self._n))


class Recording:
    """A recording opened by :func:`load_recording`; frames load lazily."""

    __slots__ = (
        "_client_members",
        "_eyes",
        "_server_members",
        "_sizes",
        "client_frames",
        "manifest",
        "path",
        "server_frames",
    )

    def __init__(self, path: Path, manifest: dict[str, Any]) -> None:
        self.path = path
        self.manifest = manifest
        cams = manifest["cameras"]
        self._sizes = [tuple(cams["main"]), *(tuple(a) for a in cams["aux"])]
        self._eyes = int(cams["eyes"])
        # The members of every frame file, by name: dtype and shape.
        self._server_members = _server_spec(self._sizes)
        self._client_members = _client_spec(cams["client"], self._eyes)
        self.server_frames: Sequence[ServerFrame] = LazyFrames(
            len(manifest["server_frames"]), self._server
        )
        self.client_frames: Sequence[ClientFrame] = LazyFrames(
            len(manifest["client_frames"]), self._client
        )

    def __repr__(self) -> str:
        m = self.manifest
        return (
            f"Recording({str(self.path)!r}, scene={m['scene']!r}, variant={m['variant']!r}, "
            f"{len(self.server_frames)} server / {len(self.client_frames)} client frames)"
        )

    scene = property(lambda self: str(self.manifest["scene"]), doc="Scene name.")
    variant = property(lambda self: str(self.manifest["variant"]), doc="Scene variant.")
    fs = property(lambda self: float(self.manifest["fs"]), doc="Server frame rate.")
    fc = property(lambda self: float(self.manifest["fc"]), doc="Client frame rate.")
    subframes = property(lambda self: int(self.manifest["subframes"]), doc="Shadow subframes S.")
    stereo = property(lambda self: bool(self.manifest["stereo"]), doc="Two eyes per frame.")
    samples = property(
        lambda self: dict(self.manifest["samples"]),
        doc="Colour sub-samples per pixel side: ``{'main', 'aux', 'client'}``.",
    )

    @property
    def server_nbytes(self) -> int:
        """Bytes of the buffers of one server frame uncompressed (every camera's colour, depth,
        both motions and both shadows' bits and colours): what
        :func:`~splitrender.client.playback.frame_nbytes` gives for each of its frames, which all
        hold every buffer, from the manifest alone (without reading a frame)."""
        return sum(
            dt.itemsize * math.prod(shape)
            for name, (dt, shape) in self._server_members.items()
            if name.rsplit(".", 1)[-1] not in ("pose", "view", "proj")
        )

    @checked(eye=ints(0, 1), n=optional(ints(0, MAX_FRAMES)))
    def eye(
        self, eye: int, n: int | None = None
    ) -> tuple[list[Camera], Sequence[npt.NDArray[np.uint8]]]:
        """Eye ``eye``'s client cameras and ground truths for the first ``n`` client frames (all
        when ``None``). The cameras are read now; each ground truth is read from its file when
        asked for, so a scored sequence never holds them all (1 GB per eye at 1280×720, 3 s)."""
        if eye >= self._eyes:
            raise InvalidInputError(f"eye: {eye} out of range; {self.path} is a mono recording "
                                    "(one eye, 0)")
        frames = self.client_frames
        count = len(frames) if n is None else min(n, len(frames))
        truths: Sequence[npt.NDArray[np.uint8]] = LazyFrames(
            count, lambda k: frames[k].ground_truths[eye]
        )
        # The cameras alone: the images are read (again) when asked for.
        return [self._client_camera(k, eye) for k in range(count)], truths

    def server_pose(self, k: int) -> npt.NDArray[np.float64]:
        """The (predicted) head pose server frame ``k`` was rendered at."""
        entry = self.manifest["server_frames"][k]
        return _read_npz(self.path, entry, self._server_members, {"pose"})["pose"]

    def server_cameras(self, k: int) -> tuple[Camera, ...]:
        """Server frame ``k``'s cameras, main then auxiliary: the frame file's size, members
        and headers are checked, and only the matrices are read (checked by the zip's CRC-32;
        the file's SHA-256 is checked when the frame is read whole)."""
        entry = self.manifest["server_frames"][k]
        only = {f"{cam}.{m}" for cam in _CAMERAS for m in ("view", "proj")}
        a = _read_npz(self.path, entry, self._server_members, only)
        try:
            return tuple(Camera(a[f"{cam}.view"], a[f"{cam}.proj"], w, h)
                         for cam, (w, h) in zip(_CAMERAS, self._sizes))
        except SplitRenderError as e:
            raise _fail(self.path / entry["file"], str(e)) from None

    def _server(self, k: int) -> ServerFrame:
        entry = self.manifest["server_frames"][k]
        a = _read_npz(self.path, entry, self._server_members)
        frames = []
        try:
            for cam in _CAMERAS:
                g = {name: a[f"{cam}.{name}"] for name, _, _ in _SERVER_ARRAYS}
                h, w = g["depth"].shape
                frames.append(
                    CameraFrame(
                        Camera(g["view"], g["proj"], w, h),
                        g["color"],
                        g["depth"],
                        g["motion_fwd"],
                        g["motion_bwd"],
                        ShadowBuffers(
                            g["shadow_fwd_bits"],
                            g["shadow_fwd_min"],
                            g["shadow_fwd_max"],
                        ),
                        ShadowBuffers(
                            g["shadow_bwd_bits"],
                            g["shadow_bwd_min"],
                            g["shadow_bwd_max"],
                        ),
                    )
                )
        except SplitRenderError as e:
            raise _fail(self.path / entry["file"], str(e)) from None
        return ServerFrame(entry["index"], entry["time"], frames[0], tuple(frames[1:]))

    def _cameras(self, entry: dict[str, Any], a: dict[str, Any], eyes: range) -> list[Camera]:
        """The client cameras of ``eyes`` in frame file ``a`` (of manifest ``entry``)."""
        w, h = self.manifest["cameras"]["client"]
        try:
            return [Camera(a[f"eye{e}.view"], a[f"eye{e}.proj"], w, h) for e in eyes]
        except SplitRenderError as e:
            raise _fail(self.path / entry["file"], str(e)) from None

    def _client(self, n: int) -> ClientFrame:
        entry = self.manifest["client_frames"][n]
        a = _read_npz(self.path, entry, self._client_members)
        cams = tuple(self._cameras(entry, a, range(self._eyes)))
        imgs = tuple(a[f"eye{e}.color"] for e in range(self._eyes))
        return ClientFrame(entry["index"], entry["time"], a["pose"], cams, imgs)

    def _client_camera(self, n: int, eye: int) -> Camera:
        """Client frame ``n``'s camera of ``eye``: the file's size, members and headers
        checked as :meth:`_client` does, its images not read (:func:`_read_npz`)."""
        entry = self.manifest["client_frames"][n]
        only = {f"eye{eye}.view", f"eye{eye}.proj"}
        a = _read_npz(self.path, entry, self._client_members, only)
        return self._cameras(entry, a, range(eye, eye + 1))[0]

    def verify(self) -> None:
        """Reads and checks every frame file; raises :class:`RecordingError` on the first bad
        one."""
        for _ in self.server_frames:
            pass
        for _ in self.client_frames:
            pass


def _check_count(n: int, key: str, where: Path | str) -> None:
    """Refuses more than :data:`MAX_FRAMES` entries in the frame list ``key`` (the plan bounds
    the client frames, nothing the server frames of a dataset import but this)."""
    if n > MAX_FRAMES:
        raise _fail(where, f"{key}: {n} frames, a recording holds at most {MAX_FRAMES}")


def _check_frames(m: dict[str, Any], key: str, rate: float, where: Path) -> None:
    frames = _get(m, key, list, where)
    if not frames:
        raise _fail(where, f"{key}: empty")
    for i, e in enumerate(frames):
        w = f"{key}[{i}]"
        if not isinstance(e, dict):
            raise _fail(where, f"{w}: expected an object")
        for field, kind in (("index", int), ("time", (int, float)), ("file", str)):
            _get(e, field, kind, where, w)
        b = _get(e, "bytes", int, where, w)
        s = _get(e, "sha256", str, where, w)
        if e["index"] != i or not math.isclose(e["time"], i / rate, abs_tol=1e-9):
            raise _fail(where, f"{w}: index/time {e['index']}/{e['time']} out of sequence")
        if e["file"] != f"{key.split('_')[0]}/{i:06d}.npz":
            raise _fail(where, f"{w}: unexpected file name {e['file']!r}")
        if b < 0 or not re.fullmatch(r"[0-9a-f]{64}", s):
            raise _fail(where, f"{w}: bad bytes or sha256")


@checked(path=PATH)
def load_recording(path: str | os.PathLike[str]) -> Recording:
    """Opens the recording in directory ``path``, validating its manifest; frame files are read
    and checked on access (:meth:`Recording.verify` reads them all).

    Raises :class:`RecordingError` naming the file and the problem."""
    root = Path(path)
    if _PARTIAL.search(root.name):
        raise _fail(
            root,
            "an unfinished recording (its render was interrupted); render it again",
        )
    if not root.is_dir():
        raise _fail(root, "no such recording directory")
    mpath = root / _MANIFEST
    m = read_json_object(
        mpath,
        _MAX_MANIFEST_BYTES,
        "recording manifest",
        RecordingError,
        missing="missing: not a recording, or an unfinished one",
    )
    if m.get("format") != FORMAT:
        raise _fail(mpath, f"format {m.get('format')!r}, expected {FORMAT!r}")
    if m.get("version") != VERSION:
        raise _fail(
            mpath,
            f"format version {m.get('version')!r}, this splitrender reads version {VERSION}",
        )
    for key in ("scene", "variant"):
        _get(m, key, str, mpath)
    for key in ("scale", "fs", "fc", "seconds", "near", "far"):
        v = _get(m, key, (int, float), mpath)
        if not (math.isfinite(v) and v > 0):
            raise _fail(mpath, f"field {key!r}: expected a finite number > 0, got {v!r}")
    sub = _get(m, "subframes", int, mpath)
    if not 1 <= sub <= 16:
        raise _fail(mpath, f"field 'subframes': expected 1..16, got {sub}")
    stereo = _get(m, "stereo", bool, mpath)
    samples = _get(m, "samples", dict, mpath)
    for key in ("main", "aux", "client"):
        n = samples.get(key)
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_SAMPLES:
            raise _fail(mpath, f"samples.{key}: expected an int in 1..{MAX_SAMPLES}, got {n!r}")
    cams = _get(m, "cameras", dict, mpath)
    main = _size(cams.get("main"), "main", mpath)
    aux = cams.get("aux")
    if not isinstance(aux, list) or len(aux) != 2:
        raise _fail(mpath, f"cameras.aux: expected two [width, height], got {aux!r}")
    for i, a in enumerate(aux):
        _size(a, f"aux[{i}]", mpath)
    if _size(cams.get("client"), "client", mpath) != main:
        raise _fail(mpath, "cameras.client: expected the main camera's size")
    if cams.get("eyes") != (2 if stereo else 1):
        raise _fail(mpath, f"cameras.eyes: {cams.get('eyes')!r} does not match stereo={stereo}")
    _get(m, "client_motion", dict, mpath)
    for key in ("server_frames", "client_frames"):
        _check_count(len(_get(m, key, list, mpath)), key, mpath)
    _check_frames(m, "server_frames", float(m["fs"]), mpath)
    _check_frames(m, "client_frames", float(m["fc"]), mpath)
    _check_plan(m, mpath)
    return Recording(root, m)


def _check_plan(m: dict[str, Any], where: Path) -> None:
    """Checks that the manifest's frame lists are the ones its ``seconds``, ``fs`` and ``fc``
    plan (:func:`plan`): ``play`` and ``eval`` take a run's length from ``seconds`` and index the
    frames it plans, so a manifest whose lists are shorter failed later under the names of
    internal parameters, or (too few server frames) played held frames scored as if the
    recording were whole. A dataset import keeps every server frame of its folder, so the
    server list may be longer than planned, never shorter."""
    seconds, fs, fc = (float(m[k]) for k in ("seconds", "fs", "fc"))
    for key, rate in (("fs", fs), ("fc", fc)):
        # Before plan() rounds them: a product too large for a float is inf (a frame's slack
        # for a product such as n / fc · fc that rounds above n).
        if seconds * rate > MAX_FRAMES + 1:
            raise _fail(where, f"fields 'seconds' and {key!r}: {seconds:g} s at {rate:g} "
                        f"frames/s is more than {MAX_FRAMES} frames")
    n_server, n_client = plan(seconds, fs, fc)
    have_server, have_client = len(m["server_frames"]), len(m["client_frames"])
    if have_client != n_client or have_server < n_server:
        raise _fail(
            where,
            f"{have_server} server frames and {have_client} client frames listed; "
            f"{seconds:g} s at fs={fs:g} and fc={fc:g} plan {n_server} and {n_client}",
        )
