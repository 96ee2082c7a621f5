"""Result files, written atomically.

Every file a command writes as its result (PNGs, ``play.json``, ``summary.json``,
``results.json``, the Markdown tables, the bench's JSON) goes through :func:`write_atomic`: the
bytes go to a temporary file in the same folder, which is closed and then renamed over ``path``,
so an exception, Ctrl-C or a full disk leaves the previous file intact and never a half-written
one. (No ``fsync``: this guards against interrupted processes, not power loss, and a session
writes hundreds of frame PNGs.)
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["write_atomic"]


def write_atomic(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Writes ``data`` (``str``: as UTF-8) to ``path`` through a temporary file beside it and a
    rename; on any failure the temporary file is removed and ``path`` is as it was."""
    dest = Path(path)
    tmp = dest.with_name(f".{dest.name}.partial-{os.getpid()}")
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        with open(tmp, "wb") as f:
            f.write(raw)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
