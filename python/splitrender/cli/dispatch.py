"""The ``splitrender`` command: the parser of every subcommand and the dispatch.

Each subcommand family lives in its own module (``example``, ``recording``, ``play``,
``evaluation``, ``dataset``), which adds its parser and sets ``run`` as the parser's default, so that this
module only dispatches.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import threading
import traceback
from collections.abc import Sequence
from typing import Any

from splitrender._native import __version__
from splitrender.cli import dataset, evaluation, example, live, play, recording
from splitrender.cli.args import PROG, Parser
from splitrender.errors import SplitRenderError, is_user_error
from splitrender.reproject import METHODS

__all__ = ["main"]

#: ``errno`` values of an :class:`OSError` that is the machine's, not a bug: the disk or the
#: quota is full, the device failed, the process or the system ran out of files or memory.
_MACHINE_ERRNOS = frozenset({
    errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EMFILE, errno.ENFILE, errno.ENOMEM,
})

#: Set (to anything but empty or 0) to print the traceback of an internal error.
DEBUG_ENV = "SPLITRENDER_DEBUG"


def build_parser() -> argparse.ArgumentParser:
    """The ``splitrender`` parser with every subcommand."""
    parser = Parser(
        prog=PROG,
        description=(
            "Image-based split rendering: synthesise display-rate client frames from sparse "
            "server frames by bidirectional reprojection (Steiner et al. 2025)."
        ),
        epilog=f"Methods: {', '.join(METHODS)}. Example: {PROG} example --out splitrender-out",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    example.add(sub)
    recording.add_render(sub)
    recording.add_encode(sub)
    evaluation.add_demo(sub)
    play.add(sub)
    evaluation.add_eval(sub)
    evaluation.add_bench(sub)
    dataset.add(sub)
    live.add_serve(sub)
    live.add_connect(sub)
    live.add_relay(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the ``splitrender`` command (what the console script's :func:`splitrender.cli.main`
    calls once this module is imported); returns the exit status.

    0: done. 2: the caller's error (:func:`~splitrender.errors.is_user_error`: a bad argument,
    an unreadable or malformed input, a refused destination ...), one ``splitrender: error:``
    line naming it, as argparse does for a bad option. 1: a failure that is not the caller's
    (``SplitRenderError`` itself: an external tool or the device; an ``OSError`` of the machine,
    such as a full disk, or a ``MemoryError``, one line too; any other exception: a bug,
    said as such, with its traceback when :data:`DEBUG_ENV` is set). 130: interrupted (143: by
    SIGTERM, unwound the same way). 141: the
    reader of the output went away (a broken pipe), said nothing."""
    try:
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt:  # Ctrl-C while the parsers are built (a few tenths of a second)
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    # SIGTERM (what `timeout` and service managers send) ends the command as Ctrl-C does, so
    # that its temporary files go (an encode left its `.partial` file, a render its folder).
    previous = _on_sigterm()
    try:
        status: int = args.run(args)
        return status
    except _Terminated:
        print(f"{PROG}: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader of our output went away (`splitrender ... | head`): not an error of ours
        # or theirs. Python would report the pipe again when it flushes stdout at exit, so
        # stdout is pointed at /dev/null first (the Python documentation's recipe, signal
        # module, "Note on SIGPIPE"). 141 is what a shell reports for a process that SIGPIPE
        # ended.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except Exception as e:
        if is_user_error(e):
            print(f"{PROG}: error: {_describe(e)}", file=sys.stderr)
            return 2
        if isinstance(e, SplitRenderError) or (
            isinstance(e, OSError) and e.errno in _MACHINE_ERRNOS
        ):
            print(f"{PROG}: error: {_describe(e)}", file=sys.stderr)
            return 1
        if isinstance(e, MemoryError):
            # numpy or Python ran out (the bindings raise OutOfMemoryError, a user error, for
            # sizes they cannot reserve): the machine's limit, not a bug.
            print(f"{PROG}: error: out of memory ({_describe(e) or 'MemoryError'}): this "
                  "machine could not allocate what the command needs; try a smaller --scale "
                  "or fewer frames", file=sys.stderr)
            return 1
        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            traceback.print_exc()
        print(f"{PROG}: internal error: {type(e).__name__}: {_describe(e)} (this is a bug; "
              f"please report it with the traceback that {DEBUG_ENV}=1 prints)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is, and unwound as an interrupt is."""


def _on_sigterm() -> Any:
    """Installs the SIGTERM handler of :func:`main` (main thread only: elsewhere Python takes
    no handler) and returns what it replaced (``None``: nothing installed)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def terminate(signum: int, frame: object) -> None:
        raise _Terminated()

    return signal.signal(signal.SIGTERM, terminate)


def _describe(error: BaseException) -> str:
    """``error``'s message on one line; an ``OSError`` as ``path: reason``."""
    if isinstance(error, OSError) and error.strerror and error.filename is not None:
        text = f"{error.filename}: {error.strerror}"
        if error.filename2 is not None:
            text += f" (and {error.filename2})"
    else:
        text = str(error) or type(error).__name__
    return " ".join(text.split())
