"""The fork server: each case runs in a child forked from this (single-threaded) process.

The parent imports splitrender and numpy once; ``os.fork()`` then costs milliseconds where a
fresh interpreter would cost a second. The child sets ``RLIMIT_AS`` (and ``RLIMIT_FSIZE`` for
the writer cases that simulate a full disk), sends stdout and stderr to a file (Rust panic text
and the CLI's messages are read from it), runs the case and reports its verdict as one JSON line
through a pipe; the parent waits with a time limit and kills the child's process group on a
hang.

Forking is safe only while the parent has no other thread (a child would inherit locks held by
threads that do not exist in it): :func:`check_single_threaded` is called before every fork,
and everything that starts threads (the HEVC encoder, rayon's pool of the renderer) runs in
children only.
"""

from __future__ import annotations

import enum
import json
import os
import re
import resource
import select
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from splitrender import errors


class Outcome(str, enum.Enum):
    """How one case ended. Only SPECIFIC and ACCEPTED are good."""

    SPECIFIC = "specific error"
    ACCEPTED = "accepted"
    WRONG_ACCEPT = "wrongly accepted"
    GENERIC = "generic exception"
    PANIC = "panic"
    CRASH = "crash"
    HANG = "hang"
    OOM = "out of memory"
    CORRUPTED = "corrupted output"
    #: A hand-picked case (pinned.py) refused by another error than the one it pins: the check
    #: it pins let the input through (a later one caught it). Random cases never get it.
    UNEXPECTED = "not the expected error"

    @property
    def good(self) -> bool:
        return self in (Outcome.SPECIFIC, Outcome.ACCEPTED)


class WrongAccept(Exception):
    """Raised by a case's check: the input was accepted, but accepting it was wrong (the
    mutation made it invalid, or what was read back is not well-formed)."""


class Corrupted(Exception):
    """Raised by a writer case's check: the previous good file changed, or a half-written
    file reads as valid."""


class DiskFull(Exception):
    """Raised by a writer case's check: the write failed on the simulated full disk (EFBIG),
    which is the right error to pass on (an ``OSError`` with its errno, not a data error), and
    the previous output was left intact."""


@dataclass(frozen=True)
class Verdict:
    outcome: Outcome
    detail: str


#: Rust's panic message on stderr (``thread '...' panicked at src/..``) and the text PyO3 and the
#: bindings give a panic that reaches Python.
_PANIC = re.compile(r"panicked at|PanicException|internal error in .*please report")
#: A Rust allocation failure aborts with this line before SIGABRT.
_RUST_OOM = re.compile(r"memory allocation of \d+ bytes failed")
#: The CLI's specific error: exit status 2 and exactly one such line (argparse names the
#: subcommand: ``splitrender render: error: ...``).
CLI_ERROR = re.compile(r"^splitrender(?: [a-z-]+)*: error: ", re.MULTILINE)


def check_single_threaded() -> None:
    """Raises RuntimeError unless this process has one thread: forking is only safe then."""
    n = len(os.listdir("/proc/self/task"))
    if n != 1:
        tasks = Path("/proc/self/task")
        names = sorted((t / "comm").read_text().strip() for t in tasks.iterdir())
        raise RuntimeError(f"the fork server must be single-threaded, it has {n} threads: {names}")


def virtual_size() -> int:
    """This process's address-space size in bytes (what RLIMIT_AS counts)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmSize in /proc/self/status")


def _classify_exception(e: BaseException) -> Verdict:
    name = f"{type(e).__module__}.{type(e).__qualname__}"
    text = f"{name}: {str(e)[:300]}"
    if isinstance(e, WrongAccept):
        return Verdict(Outcome.WRONG_ACCEPT, str(e)[:300])
    if isinstance(e, DiskFull):
        return Verdict(Outcome.SPECIFIC, str(e)[:300])
    if isinstance(e, Corrupted):
        return Verdict(Outcome.CORRUPTED, str(e)[:300])
    # Before MemoryError: OutOfMemoryError is one too, the bindings' refusal of legal sizes
    # this process cannot hold (the case's memory cap), named before anything is allocated.
    if isinstance(e, errors.OutOfMemoryError):
        return Verdict(Outcome.SPECIFIC, text)
    if isinstance(e, MemoryError):
        return Verdict(Outcome.OOM, text)
    if type(e).__name__ == "PanicException" or _PANIC.search(str(e)):
        return Verdict(Outcome.PANIC, text)
    if isinstance(e, errors.SplitRenderError):
        return Verdict(Outcome.SPECIFIC, text)
    tb = traceback.extract_tb(e.__traceback__)
    where = f" at {tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno}" if tb else ""
    return Verdict(Outcome.GENERIC, text + where)


def _child(
    work: Callable[[], Verdict], out: int, log: int, mem_limit: int, fsize_limit: int | None
) -> None:
    """Runs in the forked child; never returns."""
    code = 0
    try:
        os.setpgid(0, 0)  # the parent kills the whole group on a hang (ffmpeg helpers included)
        os.dup2(log, 1)
        os.dup2(log, 2)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        resource.setrlimit(resource.RLIMIT_AS, (mem_limit, mem_limit))
        if fsize_limit is not None:
            # A full disk: writes past the limit fail with EFBIG instead of killing the process.
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_limit, fsize_limit))
        try:
            verdict = work()
        except BaseException as e:  # noqa: BLE001 - classifying every exception is the point
            verdict = _classify_exception(e)
        sys.stdout.flush()
        sys.stderr.flush()
        os.write(out, json.dumps([verdict.outcome.value, verdict.detail]).encode() + b"\n")
    except BaseException:  # noqa: BLE001 - even reporting failed (e.g. MemoryError)
        code = 3
    finally:
        os._exit(code)


def run_case(
    work: Callable[[], Verdict],
    *,
    time_limit: float,
    mem_budget: int,
    fsize_limit: int | None = None,
    log_check: Callable[[Verdict, str], Verdict] | None = None,
    running: re.Pattern[str] | None = None,
    long_by_design: bool = False,
) -> Verdict:
    """Runs ``work`` in a forked child with ``mem_budget`` bytes of address space over this
    process's own, and classifies how it ended. ``log_check(verdict, output)`` may reclassify
    from the child's stdout/stderr (the CLI cases). A child whose output matches ``running``
    (a server that says it is listening) is stopped there and counted as accepted: it runs
    until interrupted by design. With ``long_by_design`` (a command line that asks for minutes
    of work), a child still running at ``time_limit`` without a panic or a traceback
    is stopped and counted as accepted too."""
    check_single_threaded()
    mem_limit = virtual_size() + mem_budget
    r, w = os.pipe()
    with tempfile.TemporaryFile() as log:
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child
            os.close(r)
            _child(work, w, log.fileno(), mem_limit, fsize_limit)
        os.close(w)
        data = b""
        deadline = time.monotonic() + time_limit
        hung = serving = False
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                hung = True
                break
            if running is not None:
                log.seek(0)
                if running.search(log.read().decode("utf-8", "replace")):
                    hung = serving = True
                    break
            ready, _, _ = select.select([r], [], [], min(left, 0.2) if running else left)
            if ready:
                chunk = os.read(r, 65536)
                if not chunk:
                    break
                data += chunk
        os.close(r)
        if hung:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _, status = os.waitpid(pid, 0)
        try:  # grandchildren (an ffmpeg run by the CLI) share the group
            os.killpg(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        log.seek(0)
        output = log.read().decode("utf-8", "replace")
    if serving:
        return Verdict(Outcome.ACCEPTED, "serving (runs until interrupted)")
    if hung and long_by_design:
        if _PANIC.search(output):
            return Verdict(Outcome.PANIC, _first_panic_line(output))
        if "Traceback" in output:
            return Verdict(Outcome.GENERIC, f"a traceback within {time_limit:g} s: "
                           f"{output.strip().splitlines()[-1][:200]}")
        return Verdict(Outcome.ACCEPTED, f"still running after {time_limit:g} s, as its "
                       "command line asks")
    if hung:
        return Verdict(Outcome.HANG, f"no result after {time_limit:g} s")
    verdict: Verdict
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        if _RUST_OOM.search(output):
            verdict = Verdict(Outcome.OOM, _RUST_OOM.search(output).group(0))  # type: ignore[union-attr]
        elif _PANIC.search(output):
            verdict = Verdict(Outcome.PANIC, _first_panic_line(output))
        else:
            verdict = Verdict(Outcome.CRASH, f"killed by {signal.Signals(sig).name}")
    elif not data:
        verdict = Verdict(Outcome.CRASH, f"exit status {os.WEXITSTATUS(status)} without a verdict")
    else:
        outcome, detail = json.loads(data.decode().splitlines()[0])
        verdict = Verdict(Outcome(outcome), detail)
    if _PANIC.search(output) and verdict.outcome.good:
        verdict = Verdict(Outcome.PANIC, _first_panic_line(output))
    if log_check is not None:
        verdict = log_check(verdict, output)
    return verdict


def _first_panic_line(output: str) -> str:
    for line in output.splitlines():
        if _PANIC.search(line):
            return line.strip()[:300]
    return output.strip()[:300]
