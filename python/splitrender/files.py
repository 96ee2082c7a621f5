"""Result files, written atomically.

Every file a command writes as its result (PNGs, ``play.json``, ``summary.json``,
``results.json``, the Markdown tables, the bench's JSON) goes through :func:`write_atomic`: the
bytes go to a temporary file in the same folder, which is closed and then renamed over ``path``,
so an exception, Ctrl-C or a full disk leaves the previous file intact and never a half-written
one. (No ``fsync``: this guards against interrupted processes, not power loss, and a session
writes hundreds of frame PNGs.)

Every small file the package parses (head traces, scene descriptions, a recording's
``manifest.json`` and frame files, a dataset's ``cam.json``) is read through
:func:`read_regular` and, for JSON, :func:`read_json` (:func:`read_json_object` where the
document must be an object): only regular files, at most a given
number of bytes, and every parse failure (including nesting too deep for the parser and
integers no float can hold) as the caller's own exception class. Stream files, read in parts,
are opened by :func:`open_regular`.
:func:`temporary_beside` names such a temporary file for writers that stream (the stream file,
the videos), which derive from :class:`AtomicWriter`. :class:`OutputFolder` does the same for
the several files and folders one command writes into a folder (``play``'s frames and
``play.json``, ``demo``'s video, stills and summaries).
:func:`check_name` and :func:`joined` keep names that come from data or arguments from
escaping the folder they are joined under, and :func:`check_apart` refuses an output that is an
input or lies inside one (writing it would destroy what is being read).
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO

from splitrender.errors import InvalidInputError

if TYPE_CHECKING:
    from typing_extensions import Self  # annotations only (Python 3.10)

__all__ = [
    "AtomicWriter",
    "JSON_KINDS",
    "OutputFolder",
    "check_apart",
    "check_name",
    "joined",
    "open_regular",
    "open_temporary",
    "read_json",
    "read_regular",
    "temporary_beside",
    "write_atomic",
]

# The most digits a JSON integer may have: every integer of 308 digits is below 1.8e308, the
# largest float, and a longer one that the package converted with float() or math.isfinite()
# could raise OverflowError (and above 4300 digits int() itself refuses it).
_MAX_INT_DIGITS = sys.float_info.max_10_exp


#: JSON's names for the Python types that :func:`read_json` gives, for messages in JSON's terms
#: ("expected an integer, got a string", not ``<class 'int'>``).
JSON_KINDS: dict[type, str] = {
    bool: "true or false", int: "an integer", float: "a number", str: "a string",
    list: "an array", dict: "an object", type(None): "null",
}


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
    ``st_size`` says, so a file growing while read cannot exhaust memory; and no more than one
    byte past ``st_size`` is asked for at first (a read allocates what it asks for: a 1 KB
    manifest read under a 64 MB limit held 64 MB)."""
    with open_regular(path, what, error) as f:
        size = os.fstat(f.fileno()).st_size
        data = f.read(min(limit, size) + 1)
        if size < len(data) <= limit:  # it grew while read: the rest, still within the limit
            data += f.read(limit + 1 - len(data))
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


def read_json_object(
    path: str | os.PathLike[str],
    limit: int,
    what: str,
    error: type[Exception],
    *,
    missing: str = "missing file",
) -> dict[str, Any]:
    """:func:`read_json` of a document that must be a JSON object, with every failure as
    ``error`` naming the path: ``missing`` when there is no such file, ``cannot read: …`` for
    another system error, ``expected a JSON object`` for any other JSON value."""
    try:
        doc = read_json(path, limit, what, error)
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror or e}") from None
    if not isinstance(doc, dict):
        raise error(f"{path}: expected a JSON object")
    return doc


# Two writers of the same path in one process (threads, nested writers) must not share a
# temporary file, so the name carries a per-process serial number besides the pid.
_serial = itertools.count()


def temporary_beside(path: str | os.PathLike[str]) -> Path:
    """A fresh name for the temporary file of ``path``: hidden, in the same folder (so that the
    final ``os.replace`` is a rename within one file system, hence atomic) and unique to this
    process and call.

    Raises :class:`~splitrender.errors.InvalidInputError` when ``path`` is a device, FIFO or
    socket: the rename would replace the node itself (run as root, an output of ``/dev/zero``
    replaced the device with a regular file; found by the fuzz suite). A link is replaced as a
    link, so it is allowed whatever it points to."""
    dest = Path(path)
    _check_not_special(dest)
    return dest.with_name(f".{dest.name}.partial-{os.getpid()}-{next(_serial)}")


def open_temporary(path: str | os.PathLike[str]) -> tuple[Path, BinaryIO]:
    """A :func:`temporary_beside` file of ``path``, opened for binary writing, and its name.

    Why not ``open`` alone: where the folder is missing or not writable, the error would name
    the hidden temporary file, which the caller never gave; it names ``path`` instead, with
    the folder as the reason (the same ``OSError`` class and ``errno``)."""
    dest = Path(path)
    tmp = temporary_beside(dest)
    try:
        return tmp, open(tmp, "wb")  # noqa: SIM115 - the caller closes it
    except OSError as e:
        if e.filename != str(tmp):
            raise
        why = unwritable_folder(e, dest.parent)
        raise type(e)(e.errno, f"cannot write the file: {why}", str(path)) from None


def unwritable_folder(e: OSError, folder: Path) -> str:
    """Why nothing could be created in ``folder`` (``e``, raised creating something there), in
    words about ``folder``: the caller names its destination, not a hidden temporary beside it."""
    where = repr(str(folder))
    return {
        errno.ENOENT: f"its folder {where} does not exist",
        errno.ENOTDIR: f"{where} is not a folder",
        errno.EEXIST: f"{where} is not a folder",
        errno.EACCES: f"no permission to write in its folder {where}",
        errno.EPERM: f"no permission to write in its folder {where}",
        errno.EROFS: f"its folder {where} is on a read-only file system",
    }.get(e.errno or 0, e.strerror or str(e))


def _check_not_special(dest: Path) -> None:
    """Raises :class:`~splitrender.errors.InvalidInputError` when ``dest`` is a device, FIFO or
    socket (see :func:`temporary_beside`)."""
    try:
        mode = dest.lstat().st_mode
    except OSError:
        return  # missing (or unreadable: the write itself will say why)
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode) or stat.S_ISLNK(mode)):
        raise InvalidInputError(
            f"{dest}: the output is {_kind(mode)}; expected a regular file or a new name"
        )


def check_output_file(path: str | os.PathLike[str]) -> None:
    """Raises :class:`~splitrender.errors.InvalidInputError` when a file cannot be renamed into
    place at ``path`` (:func:`write_atomic`): an existing directory, or a device, FIFO or
    socket. For a command to check its output before its work, not after."""
    dest = Path(path)
    if dest.is_dir():
        raise InvalidInputError(f"{path} is a directory; expected a file name")
    _check_not_special(dest)


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


class OutputFolder:
    """The outputs of one command in folder ``out``, replaced together when the command ends.

    ``with OutputFolder(out, owned) as stage:`` creates ``out`` if needed and a hidden staging
    folder inside it, into which the command writes everything. A clean exit moves the old
    entries named in ``owned`` (the names the command writes; those this run did not make are
    removed as well, e.g. ``frames/`` of a run before when this one wrote ``client.mp4``) aside,
    moves every staged entry into ``out`` (``owned``'s last name, the summary that says a run
    is complete, last of all), and removes the old ones. An exception (Ctrl-C, a full
    disk) removes the staging folder instead: ``out`` keeps the previous run's outputs as they
    were, never some of each, and a folder it created for this run is removed again if empty.
    Entries of ``out`` not in ``owned`` are left alone.

    Raises :class:`~splitrender.errors.InvalidInputError` on entry when ``out`` exists and is
    not a folder (``mkdir`` said only "File exists")."""

    def __init__(self, out: str | os.PathLike[str], owned: Collection[str]) -> None:
        self.out = Path(out)
        self.owned = [check_name(n, "owned output") for n in owned]
        self._created = False
        self._stage: Path | None = None

    def check(self) -> None:
        """Raises :class:`~splitrender.errors.InvalidInputError` when ``out`` exists and is not
        a folder (what entering checks), or when no entry can be made in it, or, when it is
        missing, in its nearest existing parent (no permission, a read-only file system, a
        folder such as ``/proc/self`` that takes none), naming the path and the system's
        reason: for a command to check before long work (found on entering, after it, the
        work was lost). The check makes a temporary folder there and removes it."""
        self._check_kind()
        probe = next((p for p in (self.out, *self.out.absolute().parents) if p.exists()), None)
        if probe is None:
            return  # nothing exists above it (no root): entering will say why
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".check-", dir=probe))
        except OSError as e:
            where = "" if probe == self.out else f" (in {probe}, to create it)"
            raise InvalidInputError(
                f"{self.out}: cannot write the outputs there{where}: {e.strerror or e}; "
                "expected a folder this user can write"
            ) from None

    def _check_kind(self) -> None:
        if self.out.exists() and not self.out.is_dir():
            raise InvalidInputError(f"{self.out}: exists and is not a folder; expected a folder "
                                    "for the outputs (new or existing)")

    def __enter__(self) -> Path:
        self._check_kind()
        self._created = not self.out.exists()
        self.out.mkdir(parents=True, exist_ok=True)
        self._stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=self.out))
        return self._stage

    def final(self, path: str | os.PathLike[str]) -> Path:
        """Where ``path`` (in the staging folder) will lie once the outputs are in place."""
        assert self._stage is not None, "final() inside the with block"
        return self.out / Path(path).relative_to(self._stage)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        stage, self._stage = self._stage, None
        assert stage is not None
        try:
            if exc_type is None:
                self._commit(stage)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
            if exc_type is not None and self._created:
                try:
                    self.out.rmdir()  # only if empty: a folder made for this run, nothing else
                except OSError:
                    pass

    def _commit(self, stage: Path) -> None:
        made = {p.name for p in stage.iterdir()}
        # The summary (owned's last name) goes last: until it is in place the folder does not
        # claim a complete run.
        last = self.owned[-1:]
        order = sorted(made, key=lambda n: (n in last, n))
        old = stage / ".old"
        old.mkdir()
        aside: list[str] = []
        placed: list[str] = []
        try:
            for name in sorted({*self.owned, *made}):
                if os.path.lexists(self.out / name):
                    os.rename(self.out / name, old / name)
                    aside.append(name)
            for name in order:
                os.rename(stage / name, self.out / name)
                placed.append(name)
        except BaseException:
            # Back as it was: this run's entries out again, the old ones in.
            for name in placed:
                os.rename(self.out / name, stage / name)
            for name in aside:
                os.rename(old / name, self.out / name)
            raise


def write_atomic(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Writes ``data`` (``str``: as UTF-8) to ``path`` through a temporary file beside it and a
    rename; on any failure the temporary file is removed and ``path`` is as it was."""
    dest = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    tmp, f = open_temporary(dest)
    try:
        with f:
            f.write(raw)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


Error = Callable[[str], Exception]


def rename_new_folder(tmp: Path, out: Path, error: Error, hint: str = "") -> None:
    """Renames the finished folder ``tmp`` to ``out``, which was missing or an empty folder when
    the write began; raises ``error`` when something is there now (another run that wrote
    there meanwhile), which is left as it is.

    A folder's rename fails onto a non-empty folder or a file, so the check is the rename
    itself, with no window between a look and the move. (An empty folder made meanwhile is
    replaced: nothing of anyone's is lost.) ``hint`` ends the message (``"; expected ..."``)."""
    try:
        tmp.rename(out)
    except OSError as e:
        if not (out.exists() or out.is_symlink()):
            raise
        raise error(
            f"{out}: appeared while this one was written (another run writing there?) and is "
            f"left as it is{hint}"
        ) from e


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
