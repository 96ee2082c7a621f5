"""Result files, written atomically.

Every file a command writes as its result (PNGs, ``play.json``, ``summary.json``,
``results.json``, the Markdown tables, the bench's JSON) goes through :func:`write_atomic`: the
bytes go to a temporary file in the same folder, which is closed and then renamed over ``path``,
so an exception, Ctrl-C or a full disk leaves the previous file intact and never a half-written
one. (No ``fsync``: this guards against interrupted processes, not power loss, and a session
writes hundreds of frame PNGs.)

Every small file the package parses (head traces, scene descriptions, a recording's
``manifest.json`` and frame files, a dataset's ``cam.json``) is read through
:func:`read_regular` and, for JSON, :func:`read_json`: only regular files, at most a given
number of bytes, and every parse failure (including nesting too deep for the parser and
integers no float can hold) as the caller's own exception class. Stream files, read in parts,
are opened by :func:`open_regular`.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from pathlib import Path
from typing import Any, BinaryIO

__all__ = ["open_regular", "read_json", "read_regular", "write_atomic"]

# The most digits a JSON integer may have: every integer of 308 digits is below 1.8e308, the
# largest float, and a longer one that the package converted with float() or math.isfinite()
# could raise OverflowError (and above 4300 digits int() itself refuses it).
_MAX_INT_DIGITS = sys.float_info.max_10_exp


def open_regular(path: str | os.PathLike[str], what: str, error: type[Exception]) -> BinaryIO:
    """``path`` (symbolic links followed) opened for binary reading, which must be a regular
    file; otherwise raises ``error`` naming the path, ``what`` it should be and what it is.

    The file is opened non-blocking and checked with ``fstat`` on the open descriptor, so a FIFO
    cannot block the open and the file checked is the file read (no race with a rename).
    :class:`OSError` from opening (a missing file, no permission) propagates for the caller to
    word."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise error(f"{path}: {what} is {_kind(mode)}, expected a regular file")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(
    path: str | os.PathLike[str], limit: int, what: str, error: type[Exception]
) -> bytes:
    """The bytes of ``path``, opened by :func:`open_regular`, which must be at most ``limit``
    bytes; otherwise raises ``error``. At most ``limit + 1`` bytes are read whatever
    ``st_size`` says, so a file growing while read cannot exhaust memory."""
    with open_regular(path, what, error) as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise error(f"{path}: {what} is more than {limit} bytes")
    return data


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _parse_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > _MAX_INT_DIGITS:
        # A ValueError, which read_json reports as the caller's error; checked before int() so
        # that a long run of digits costs no quadratic conversion either.
        raise ValueError(f"an integer of {digits} digits, expected at most {_MAX_INT_DIGITS}")
    return int(text)


def read_json(
    path: str | os.PathLike[str], limit: int, what: str, error: type[Exception]
) -> Any:
    """The JSON document in ``path``, read by :func:`read_regular`; raises ``error`` naming the
    path and the problem for bytes that are not UTF-8 JSON, nesting deeper than the parser's
    recursion limit (``RecursionError``) and integers too long for a float (``OverflowError``
    later), never those exceptions themselves."""
    data = read_regular(path, limit, what, error)
    try:
        return json.loads(data.decode("utf-8"), parse_int=_parse_int)
    except RecursionError:
        raise error(f"{path}: {what} is nested too deeply to parse") from None
    except UnicodeDecodeError as e:
        raise error(f"{path}: {what} is not UTF-8 ({e.reason} at byte {e.start})") from None
    except ValueError as e:  # json.JSONDecodeError, and _parse_int's refusal
        raise error(f"{path}: {what} is not valid JSON: {e}") from None


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
