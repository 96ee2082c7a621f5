"""Encoding a recording into a stream file (``splitrender encode``).

The server side of the wire: every server frame of a recording (:mod:`splitrender.scene.recording`) goes
through one :class:`~splitrender.codec.coder.StreamEncoder` and into a container file
(:mod:`splitrender.codec.stream`), whose writer writes under a temporary name and renames when
complete, so an interrupted encode never leaves a stream that looks finished.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path

from splitrender.codec.coder import CodecConfig, StreamEncoder
from splitrender.errors import InvalidInputError
from splitrender.files import check_apart
from splitrender.scene.recording import load_recording
from splitrender.codec.stream import StreamStats, StreamWriter

__all__ = ["encode_recording"]


def encode_recording(
    recording: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    bitrate_mbps: float | None = None,
    config: CodecConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> StreamStats:
    """Encodes every server frame of the recording at ``recording`` into the stream file ``out``.

    ``bitrate_mbps`` sets the total target (all cameras and buffers); without it the paper's
    40 Mb/s at 2560x1440 is scaled to the recording's main camera by pixel count
    (:meth:`CodecConfig.scaled`). ``config`` gives every other codec setting (its bitrate is
    replaced when ``bitrate_mbps`` is given). ``progress(done, total)`` is called after each frame.

    Returns the per-buffer byte accounting of the stream.

    Raises:
        InvalidInputError: for a bad bitrate, an output path that already exists as a folder or
            one that is the recording or lies inside it.
        RecordingError: for a recording that is missing, incomplete or corrupted.
    """
    # The stream must not land inside the recording (--out REC/manifest.json replaced it).
    check_apart(out, {"recording": recording})
    rec = load_recording(recording)
    frames = rec.server_frames
    if len(frames) == 0:
        raise InvalidInputError(f"{recording}: the recording has no server frames")
    out_path = Path(out)
    if out_path.is_dir():
        raise InvalidInputError(f"{out_path}: expected a file name for the stream, got a folder")
    first = frames[0]
    w, h = first.main.camera.width, first.main.camera.height
    base = config or CodecConfig.scaled(w, h, fps=rec.fs)
    if bitrate_mbps is not None:
        base = dataclasses.replace(base, bitrate_mbps=bitrate_mbps)
    stats = StreamStats(fps=rec.fs)
    # StreamWriter writes beside out_path and renames when complete: an interrupted encode
    # leaves the previous file, never a stream that looks finished. The encoder's worker
    # threads end with the call (they outlived it, until the encoder was collected).
    with StreamEncoder(base) as encoder, StreamWriter(out_path, fps=rec.fs) as writer:
        for k, frame in enumerate(frames):
            packet = encoder.encode(frame)
            writer.write(packet)
            stats.add(packet)
            if progress is not None:
                progress(k + 1, len(frames))
    return stats

