"""Result files, written atomically.

Every file a command writes as its result (PNGs, ``play.json``, ``summary.json``,
``results.json``, the Markdown tables, the bench's JSON) goes through :func:`write_atomic`: the
bytes go to a temporary file in the same folder, which is closed and then renamed over ``path``,
so an exception, Ctrl-C or a full disk leaves the previous file intact and never a half-written
one. (No ``fsync``: this guards against interrupted processes, not power loss, and a session
writes hundreds of frame PNGs.)

:func:`temporary_beside` names such a temporary file for writers that stream (the stream file).
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

__all__ = ["temporary_beside", "write_atomic"]

# Two writers of the same path in one process (threads, nested writers) must not share a
# temporary file, so the name carries a per-process serial number besides the pid.
_serial = itertools.count()


def temporary_beside(path: str | os.PathLike[str]) -> Path:
    """A fresh name for the temporary file of ``path``: hidden, in the same folder (so that the
    final ``os.replace`` is a rename within one file system, hence atomic) and unique to this
    process and call."""
    dest = Path(path)
    return dest.with_name(f".{dest.name}.partial-{os.getpid()}-{next(_serial)}")


def write_atomic(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Writes ``data`` (``str``: as UTF-8) to ``path`` through a temporary file beside it and a
    rename; on any failure the temporary file is removed and ``path`` is as it was."""
    dest = Path(path)
    tmp = temporary_beside(dest)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        with open(tmp, "wb") as f:
            f.write(raw)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
