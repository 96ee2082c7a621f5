"""Result files, written atomically.

Every file a command writes as its result (PNGs, ``play.json``, ``summary.json``,
``results.json``, the Markdown tables, the bench's JSON) goes through :func:`write_atomic`: the
bytes go to a temporary file in the same folder, which is closed and then renamed over ``path``,
so an exception, Ctrl-C or a full disk leaves the previous file intact and never a half-written
one. (No ``fsync``: this guards against interrupted processes, not power loss, and a session
writes hundreds of frame PNGs.)

:func:`temporary_beside` names such a temporary file for writers that stream (the stream file,
the videos), which derive from :class:`AtomicWriter`.
:func:`check_name` and :func:`joined` keep names that come from data or arguments from
escaping the folder they are joined under, and :func:`check_apart` refuses an output that is an
input or lies inside one (writing it would destroy what is being read).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

from splitrender.errors import InvalidInputError

if TYPE_CHECKING:
    from typing_extensions import Self  # annotations only (Python 3.10)

__all__ = [
    "AtomicWriter",
    "check_apart", "check_name", "joined", "temporary_beside",
    "write_atomic",
]

# Two writers of the same path in one process (threads, nested writers) must not share a
# temporary file, so the name carries a per-process serial number besides the pid.
_serial = itertools.count()


def temporary_beside(path: str | os.PathLike[str]) -> Path:
    """A fresh name for the temporary file of ``path``: hidden, in the same folder (so that the
    final ``os.replace`` is a rename within one file system, hence atomic) and unique to this
    process and call."""
    dest = Path(path)
    return dest.with_name(f".{dest.name}.partial-{os.getpid()}-{next(_serial)}")


class AtomicWriter:
    """A writer that writes into a :func:`temporary_beside` file and renames it into place.

    As a context manager, a clean exit calls :meth:`close` (finish, rename over the target)
    and an exception :meth:`abort` (remove the temporary file, leave the target as it was), so
    an error inside the ``with`` never leaves a shorter file that reads as complete."""

    def close(self) -> None:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


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


Error = Callable[[str], Exception]


def check_name(name: object, what: str, error: Error = InvalidInputError) -> str:
    """Returns ``name`` if it is a plain file or folder name (a non-empty ``str`` without ``/``,
    ``\\`` or NUL, not ``.`` or ``..``), else raises ``error(message)`` naming ``what``. Both
    separators are refused on every system: a name from a dataset or a command line written on
    one system must not mean a path on another."""
    if (
        not isinstance(name, str)
        or name in ("", ".", "..")
        or any(c in name for c in "/\\\0")
        or os.path.isabs(name)
    ):
        raise error(
            f"{what}: expected a plain name (not empty, no '/', '\\' or NUL, not '.' or '..'), "
            f"got {name!r}"
        )
    return name


def joined(folder: str | os.PathLike[str], name: object, what: str,
           error: Error = InvalidInputError) -> Path:
    """``folder / name`` for a :func:`check_name` name, checked to stay inside ``folder`` once
    symbolic links are resolved (a link already there must not lead a writer elsewhere)."""
    base = Path(folder)
    path = base / check_name(name, what, error)
    if not path.resolve().is_relative_to(base.resolve()):
        raise error(f"{what}: {path} leads outside {base}; expected a path inside it")
    return path


def check_apart(out: str | os.PathLike[str], inputs: Mapping[str, str | os.PathLike[str]],
                error: Error = InvalidInputError, *, replaced: bool = False) -> None:
    """Raises ``error(message)`` when the output ``out`` is one of ``inputs`` (``{what: path}``)
    or lies inside one: writing it would replace or mix into what is being read (``encode REC
    --out REC/manifest.json`` replaced the recording's manifest). With ``replaced`` (``out`` is a
    folder removed and written anew, as ``--force`` does) an ``out`` that holds an input is
    refused too; otherwise writing beside an input (``--out .``) is fine. Paths are compared once
    resolved, so ``..`` and symbolic links do not hide it; the message names both paths."""
    o = Path(out).resolve()
    for what, path in inputs.items():
        i = Path(path).resolve()
        if o == i:
            problem = f"is the {what} {path}"
        elif o.is_relative_to(i):
            problem = f"lies inside the {what} {path}"
        elif replaced and i.is_relative_to(o):
            problem = f"holds the {what} {path}"
        else:
            continue
        raise error(f"{out}: the output {problem}; expected a path outside it")
