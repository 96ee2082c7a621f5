"""The task functions of ``eval``'s sweep (:mod:`splitrender.evaluation.sweep`): each runs in a
worker as ``fn(task, cache)``, reads its inputs from the cache (or ``task.paths``) and writes its
one output atomically under ``task.key``.

- :func:`render_chunk`: a run of a recording's server or client frames of a built-in scene;
  :func:`render_recording`: the recording assembled from them.
- :func:`render_timewarp`: the main camera's colour and depth at another server rate or
  prediction delay (Figure 6's timewarp lines), as one ``.npz``.
- :func:`encode_stream`: a recording's server frames encoded at one bit-rate: a stream file and
  its packet sizes and achieved rate.
- :func:`score_play`, :func:`score_interp`, :func:`score_video_streaming`,
  :func:`score_timewarp`: one row part (one eye of one method × delay × bit-rate), a JSON object
  with ``ssim``, ``flip``, ``psnr``, ``vmaf``, ``mse``, ``frames`` and ``mbps``.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.evaluation.sweep import Cache, DamagedCacheError, Task, make_task
from splitrender.files import write_atomic

__all__ = [
    "CLIENT_CHUNK",
    "SERVER_CHUNK",
    "chunk_params",
    "chunks",
    "encode_stream",
    "render_chunk",
    "render_recording",
    "render_timewarp",
    "score_interp",
    "score_play",
    "score_timewarp",
    "score_video_streaming",
]


def _trace(task: Task) -> Any:
    """The task's head trace, which must be the one planned: it is outside the cache, and the
    task's key holds its SHA-256, not its path. A changed trace is the caller's input (a
    TraceError: the failure says to run again once that is fixed, which plans anew)."""
    from splitrender.scene.builtin import TraceError, load_trace

    path = task.paths.get("trace")
    if path is None:
        return None
    trace = load_trace(path)
    if trace.sha256 != task.params["trace_sha256"]:
        raise TraceError(
            f"{path}: the trace changed since the sweep was planned (SHA-256 {trace.sha256}, "
            f"planned {task.params['trace_sha256']})"
        )
    return trace


#: Frames per render task at most: a 1280x720 server frame takes ~10 s to render and a ground
#: truth (client) frame ~2.6 s (issue 16), so a chunk is about a minute of work there: small
#: enough to spread a recording over many workers, large enough that a task's start-up
#: (loading the scene, a Ray task's scheduling) stays a small part of it.
SERVER_CHUNK = 4
CLIENT_CHUNK = 24


def _renderer(task: Task) -> Any:
    from splitrender.scene.recording import RecordingRender, RecordingSettings

    p = task.params
    return RecordingRender(p["scene"], RecordingSettings(
        variant=p["variant"], seconds=p["seconds"], scale=p["scale"], stereo=p["stereo"],
        trace=_trace(task), translation_scale=p["trace_scale"], samples=p["samples"],
    ))


def render_chunk(task: Task, cache: Cache) -> None:
    """Frames ``start..stop`` of the ``part`` (``"server"`` or ``"client"``) of a recording:
    their npz files as the recording holds them, and ``entries.json`` (times, and the auxiliary
    cameras' sizes) written last; the folder is renamed into place once complete."""
    import os
    import shutil

    from splitrender.files import temporary_beside

    p = task.params
    r = _renderer(task)
    recording = _recording_of(task, r)
    # Another run sharing the cache may have assembled the recording (and removed its chunks)
    # since this one planned the chunk: it is not needed any more.
    if recording is not None and cache.has(recording):
        return
    dest = cache.chunk(task.key)
    tmp = temporary_beside(dest)
    tmp.mkdir(parents=True)
    try:
        times: list[float] = []
        digests: list[str] = []
        aux: list[list[int]] = []
        for i in range(p["start"], p["stop"]):
            if p["part"] == "server":
                t, data, aux = r.server_entry(i)
            else:
                t, data = r.client_entry(i)
            (tmp / f"{i:06d}.npz").write_bytes(data)
            times.append(t)
            digests.append(hashlib.sha256(data).hexdigest())
        entries = {"part": p["part"], "times": times, "sha256": digests, "aux": aux}
        write_atomic(tmp / "entries.json", json.dumps(entries) + "\n")
        try:
            # An earlier partial attempt cannot be at dest (renamed whole): a twin, whose bytes
            # are these, can, and stays: never empty, it fails the rename (ENOTEMPTY), with no
            # window between a look and the move. (An empty folder there is replaced.)
            os.rename(tmp, dest)
        except OSError:
            if not dest.is_dir():
                raise
            shutil.rmtree(tmp)
        else:
            # Checked again after the rename: an assembly writes the recording's manifest
            # before it removes the chunks, so a chunk renamed into place after that removal
            # sees the recording here. Left, it would stay for good (~280 MB at 1280x720): this
            # run's recording task, finding the recording made, does not run to remove it.
            if recording is not None and cache.has(recording):
                shutil.rmtree(dest, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def chunk_params(params: dict[str, Any], n_server: int, n_client: int) -> list[dict[str, Any]]:
    """The parameters of the chunk tasks of the recording task of ``params`` (``n_server`` and
    ``n_client`` frames): its server chunks, then its client chunks, of :data:`SERVER_CHUNK`
    and :data:`CLIENT_CHUNK` frames."""
    return [{**params, "part": part, "start": a, "stop": b}
            for part, n, size in (("server", n_server, SERVER_CHUNK),
                                  ("client", n_client, CLIENT_CHUNK))
            for a, b in chunks(n, size)]


def _recording_of(task: Task, r: Any) -> Task | None:
    """The recording task that chunk ``task`` is planned for (``experiments.py``, by
    :func:`chunk_params`); ``None`` where that does not give ``task`` (a chunk planned
    otherwise)."""
    params = {k: v for k, v in task.params.items() if k not in ("part", "start", "stop")}
    parts = [make_task("render", task.fn, c) for c in chunk_params(params, r.n_server, r.n_client)]
    if task.key not in {t.key for t in parts}:
        return None
    module = task.fn.rpartition(":")[0]
    return make_task("render", f"{module}:render_recording", params, parts)


def chunks(n: int, size: int) -> list[tuple[int, int]]:
    """``0..n`` in consecutive ``(start, stop)`` runs of at most ``size``."""
    return [(a, min(n, a + size)) for a in range(0, n, size)]


def render_recording(task: Task, cache: Cache) -> None:
    """The recording assembled from its chunks (``deps``: the server chunks, then the client
    chunks, in frame order); the chunks are removed once it is in place."""
    import shutil

    from splitrender.scene.recording import LazyFrames, frame_bytes_limit, write_entries

    r = _renderer(task)
    server: list[tuple[float, Path, str]] = []
    client: list[tuple[float, Path, str]] = []
    aux: list[list[int]] | None = None  # the first server chunk's (aux_key's)
    aux_key = ""
    for key in task.deps:
        folder = cache.chunk(key)
        part, times, digests, chunk_aux = cache.read_chunk_info(key)
        files = sorted(folder.glob("*.npz"))
        if len(files) != len(times):
            raise cache.damaged(folder, f"{len(files)} frames, expected {len(times)}")
        if part == "server":
            # One rig renders every server frame: chunks that disagree on its auxiliary
            # cameras cannot be one recording, and the manifest would take the first's.
            if aux is None:
                aux, aux_key = chunk_aux, key
            elif chunk_aux != aux:
                # Which one is wrong cannot be told from the two: all go, as below.
                raise cache.damaged(
                    cache.root / "chunks",
                    f"server chunks {aux_key} and {key} disagree on the auxiliary cameras' "
                    f"sizes ({aux} and {chunk_aux}); expected one rig's")
            server += zip(times, files, digests)
        else:
            client += zip(times, files, digests)
    if aux is None or (len(server), len(client)) != (r.n_server, r.n_client):
        # Which chunk is wrong cannot be told (each agrees with its entries.json): all go.
        raise cache.damaged(cache.root / "chunks",
                            f"the chunks hold {len(server)} server and {len(client)} client "
                            f"frames, expected {r.n_server} and {r.n_client}")

    fields = r.fields(aux)
    limits = {part: frame_bytes_limit(fields, part) for part in ("server", "client")}

    def checked(part: str, t: float, f: Path, digest: str) -> tuple[float, bytes]:
        # Read with the most bytes such a frame takes (a damaged file is not read whole), then
        # checked against the SHA-256 the chunk's task wrote: the recording's manifest gets the
        # SHA-256 of these bytes, so a frame damaged in the chunk would pass every later check.
        data = cache.read_file(f, limits[part], "chunk frame")
        if hashlib.sha256(data).hexdigest() != digest:
            raise cache.damaged(f, "SHA-256 does not match the chunk's entries.json")
        return t, data

    # Read as they are written: held in lists, the frame files of a 3 s stereo recording at
    # 1280x720 would take about 4 GB (31 server frames of 70 MB, 720 images of 2.7 MB).
    write_entries(cache.recording(task.key), fields,
                  LazyFrames(len(server), lambda k: checked("server", *server[k])),
                  LazyFrames(len(client), lambda n: checked("client", *client[n])),
                  overwrite=True)
    for key in task.deps:
        shutil.rmtree(cache.chunk(key), ignore_errors=True)


def render_timewarp(task: Task, cache: Cache) -> None:
    from splitrender.evaluation.demo import FC
    from splitrender.scene.builtin import ClientMotion, PathMotion, Scene, TraceMotion
    from splitrender.scene.recording import plan

    p = task.params
    sc = Scene(p["scene"], "dynamic")
    trace = _trace(task)
    fps = float(p["fps"])
    motion: ClientMotion = (
        PathMotion(sc, p["delay"]) if trace is None
        else TraceMotion(sc, trace, p["trace_scale"], p["delay"])
    )
    n_server, _ = plan(p["seconds"], fps, FC)
    frames = [sc.server_frame(k, p["scale"], fps, 1, pose=motion.server_pose(k, fps),
                              samples=p["samples"]) for k in range(n_server)]
    buf = io.BytesIO()
    np.savez(
        buf, index=np.array([f.index for f in frames], np.int64),
        time=np.array([f.time for f in frames], np.float64),
        view=np.stack([f.main.camera.view for f in frames]),
        proj=np.stack([f.main.camera.proj for f in frames]),
        color=np.stack([f.main.color for f in frames]),
        depth=np.stack([f.main.depth for f in frames]),
    )
    write_atomic(cache.timewarp(task.key), buf.getvalue())


def _timewarp_frames(path: Path) -> list[Any]:
    """The frames :func:`render_timewarp` wrote. Each array is read from the archive once: an
    ``NpzFile`` decompresses the whole stack at every ``z[name]``, and a frame's slice keeps
    that copy alive, so indexing it per frame held N copies of each stack (N² memory: 13 GB
    for the 60 FPS line at 320×180, beyond any machine at 1280×720).

    Raises:
        RecordingError: naming ``path`` (:func:`run_task` makes it a damaged cache entry)."""
    from splitrender.scene.recording import NPZ_ERRORS, RecordingError
    from splitrender.types import Camera, CameraFrame, ServerFrame

    _, h, w = _timewarp_shape(path)
    try:
        # _timewarp_shape checked the headers, not the data: a byte changed in an array fails
        # its member's CRC-32 only when read (BadZipFile), which named no file.
        with np.load(path) as z:
            index, time, view, proj, color, depth = (
                z[k] for k in ("index", "time", "view", "proj", "color", "depth"))
    except NPZ_ERRORS as e:
        raise RecordingError(f"{path}: not a valid npz: {type(e).__name__}: {e}") from None
    return [
        ServerFrame(int(index[k]), float(time[k]), CameraFrame(
            Camera(view[k], proj[k], int(w), int(h)), color[k], depth[k]))
        for k in range(len(index))
    ]


def _timewarp_shape(path: Path) -> tuple[int, int, int]:
    """The frames, height and width of :func:`render_timewarp`'s file ``path``, from its
    members' npy headers, checked before any array is read: the members and dtypes it writes,
    shapes that agree (``index``, ``time``: (n,); ``view``, ``proj``: (n, 4, 4); ``color``:
    (n, h, w, 3); ``depth``: (n, h, w)), each array within its stored member's bytes.

    Raises:
        RecordingError: naming ``path`` (:func:`run_task` makes it a damaged cache entry)."""
    import zipfile

    from splitrender.files import open_regular
    from splitrender.scene.recording import NPZ_ERRORS, RecordingError, npy_header

    dtypes = {"index": np.int64, "time": np.float64, "view": np.float64, "proj": np.float64,
              "color": np.uint8, "depth": np.float32}
    shapes: dict[str, tuple[int, ...]] = {}
    try:
        with open_regular(path, "cached timewarp frames", RecordingError) as f, \
                zipfile.ZipFile(f) as zf:
            if sorted(zf.namelist()) != sorted(f"{k}.npy" for k in dtypes):
                raise RecordingError(f"{path}: members {sorted(zf.namelist())}, expected "
                                     f"{sorted(f'{k}.npy' for k in dtypes)}")
            for key, dtype in dtypes.items():
                info = zf.getinfo(f"{key}.npy")
                with zf.open(info) as fh:
                    shape, fortran, dt = npy_header(fh, path, key)
                    size = math.prod(shape) * dt.itemsize
                    if dt != dtype or fortran or info.compress_type != zipfile.ZIP_STORED \
                            or size > info.file_size:
                        raise RecordingError(f"{path}: {key}: {dt} {shape}")
                    shapes[key] = shape
    except NPZ_ERRORS as e:
        raise RecordingError(f"{path}: not a valid npz: {type(e).__name__}: {e}") from None
    n = shapes["index"][0] if len(shapes["index"]) == 1 else -1
    hw = shapes["depth"][1:]
    want = {"index": (n,), "time": (n,), "view": (n, 4, 4), "proj": (n, 4, 4),
            "color": (n, *hw, 3), "depth": (n, *hw)}
    if n < 1 or len(hw) != 2 or shapes != want:
        raise RecordingError(f"{path}: shapes {shapes} do not agree")
    return n, hw[0], hw[1]


def _recording(task: Task, cache: Cache) -> Any:
    from splitrender.scene.recording import load_recording

    return load_recording(task.paths.get("recording") or cache.recording(task.deps[0]))


def encode_stream(task: Task, cache: Cache) -> None:
    from splitrender.codec.coder import CodecConfig, StreamEncoder
    from splitrender.codec.stream import StreamWriter, stream_stats

    rec = _recording(task, cache)
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                              for k, v in task.params["codec"].items()}
    cfg = CodecConfig(**fields)
    packets: list[bytes] = []
    with StreamWriter(cache.stream(task.key), rec.fs) as out, StreamEncoder(cfg) as enc:
        for f in rec.server_frames:
            packets.append(enc.encode(f))
            out.write(packets[-1])
    info = {"sizes": [len(p) for p in packets], "mbps": stream_stats(packets, rec.fs).mbps_total()}
    write_atomic(cache.stream_info(task.key), json.dumps(info) + "\n")


def _write_part(task: Task, cache: Cache, metrics: Any, mbps: float) -> None:
    part = {**{m: metrics.mean.get(m) for m in ("ssim", "flip", "psnr", "vmaf")},
            "mse": metrics.mse, "frames": len(metrics.frames), "mbps": float(mbps)}
    write_atomic(cache.row(task.key), json.dumps(part, sort_keys=True, allow_nan=False) + "\n")


class _CachedStream:
    """The server frames of the cache's stream ``key``, decoded as the client needs each
    (``DecodedStream``): held whole, a 1280x720 run would take about 50 MB per server frame in
    every task running at once.

    A ``StreamError`` from reading the file or from decoding a packet (during the playback) is
    a damaged entry, named here: the encode task wrote the file from its encoder's packets, and
    those errors name the file by its base name or not at all (``frame 0: packet CRC
    mismatch``), which :func:`run_task` cannot tell from a caller's error."""

    def __init__(self, cache: Cache, key: str, sizes: list[int]) -> None:
        from splitrender.codec.coder import DecodedStream
        from splitrender.codec.stream import read_stream
        from splitrender.errors import StreamError

        self._cache, self._path = cache, cache.stream(key)
        try:
            packets = list(read_stream(self._path))
        except StreamError as e:
            raise self._damaged(e) from None
        if [len(q) for q in packets] != sizes:
            raise cache.damaged(cache.stream_info(key), "the sizes of another stream than "
                                f"{self._path.name}")
        self._frames = DecodedStream(packets)

    def __iter__(self) -> Iterator[Any]:
        from splitrender.errors import StreamError

        try:
            yield from self._frames
        except StreamError as e:
            raise self._damaged(e) from None

    def _damaged(self, e: Exception) -> DamagedCacheError:
        from splitrender.codec.stream import without_file_name

        problem = without_file_name(str(e), self._path)
        return self._cache.damaged(self._path, problem)


def score_play(task: Task, cache: Cache) -> None:
    from splitrender.evaluation.pipeline import play_and_score_eyes, raw_mbps
    from splitrender.gpu import backend_for
    from splitrender.net.model import NetworkModel
    from splitrender.types import ReprojectOptions, ServerFrame

    p = task.params
    rec = _recording(task, cache)
    sizes: list[int] | None = None
    server: Iterable[ServerFrame]
    if p["stream"]:
        key = task.deps[1]
        sizes, mbps = cache.read_stream_info(key)
        server = _CachedStream(cache, key, sizes)
    else:
        server = rec.server_frames  # read when the client needs each
        mbps = raw_mbps(rec)
    options = (ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes)
               if p["own_rates"] else None)
    cams, truth = rec.eye(p["eye"])
    net = NetworkModel(**p["network"], client_fps=rec.fc)
    [scored] = play_and_score_eyes(server, [cams], [truth], p["method"], net, rec.fc,
                                   p["metrics"], frame_sizes=sizes, options=options,
                                   backend=backend_for(p["method"], p["backend"]),
                                   flip_every=p["flip_every"], keep_images=False)
    _write_part(task, cache, scored.metrics, mbps)


def score_interp(task: Task, cache: Cache) -> None:
    """``video_interp``: minterpolate of the main colour (HEVC-coded at ``bitrate`` first when
    one is given)."""
    from splitrender.evaluation.references import minterpolate, video_streaming
    from splitrender.evaluation.metrics import SKIP_FRAMES, evaluate_sequence

    p = task.params
    rec = _recording(task, cache)
    colours = [f.main.color for f in rec.server_frames]
    if p["bitrate"] is None:
        mbps = colours[0].nbytes * 8 * rec.fs / 1e6
    else:
        colours, mbps = video_streaming(colours, p["bitrate"], rec.fs)
    _, truth = rec.eye(0)
    frames = minterpolate(colours, rec.fs, rec.fc, len(truth))
    _write_part(task, cache, evaluate_sequence(frames, truth, SKIP_FRAMES, p["metrics"],
                                               fps=rec.fc, flip_every=p["flip_every"]), mbps)


def score_video_streaming(task: Task, cache: Cache) -> None:
    """The ground truth itself as one HEVC video at ``bitrate``."""
    from splitrender.evaluation.references import video_streaming
    from splitrender.evaluation.metrics import SKIP_FRAMES, evaluate_sequence

    p = task.params
    rec = _recording(task, cache)
    _, truth = rec.eye(0)
    frames, mbps = video_streaming(truth, p["bitrate"], rec.fc)
    _write_part(task, cache, evaluate_sequence(frames, truth, SKIP_FRAMES, p["metrics"],
                                               fps=rec.fc, flip_every=p["flip_every"]), mbps)


def score_timewarp(task: Task, cache: Cache) -> None:
    """A timewarp line: the main colour and depth at ``fps`` streamed at ``bitrate`` and
    timewarped at the client poses. ``deps``: the recording, then the timewarp frames (when
    ``source`` is ``"timewarp"``; else the recording's own server frames)."""
    from splitrender.codec.coder import CodecConfig, DecodedStream
    from splitrender.evaluation.references import main_colour_depth
    from splitrender.evaluation.pipeline import encode_packets, play_and_score_eyes
    from splitrender.net.model import NetworkModel
    from splitrender.types import ReprojectOptions

    p = task.params
    rec = _recording(task, cache)
    fps = float(p["fps"])
    server: Iterable[Any]
    if p["source"] == "timewarp":
        server = _timewarp_frames(cache.timewarp(task.deps[1]))
    else:
        server = (main_colour_depth(f) for f in rec.server_frames)  # one read at a time
    twc = CodecConfig(bitrate_mbps=p["bitrate"], camera_shares=(1.0,), fps=fps, gop=int(fps))
    packets, mbps = encode_packets(server, twc, fps)
    cams, truth = rec.eye(0)
    net = NetworkModel(**p["network"], client_fps=rec.fc)
    # The packets are decoded as the client needs each frame (DecodedStream), not held decoded.
    [scored] = play_and_score_eyes(DecodedStream(packets), [cams], [truth], "timewarp", net,
                                   rec.fc, p["metrics"], frame_sizes=[len(q) for q in packets],
                                   options=ReprojectOptions(server_fps=fps),
                                   flip_every=p["flip_every"], keep_images=False)
    _write_part(task, cache, scored.metrics, mbps)
