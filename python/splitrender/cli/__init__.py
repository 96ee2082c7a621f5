"""The ``splitrender`` command line, one module per subcommand family (:mod:`.dispatch` builds
the parser and dispatches), and the codec benchmark's (:mod:`.bench_codec`: ``python -m
splitrender.cli.bench_codec``).

This module imports nothing of the package: the console script imports it before any of our
code runs, and the rest (numpy, the native module, the codec: a few tenths of a second) is
imported inside :func:`main`, where Ctrl-C is an interrupt like any other instead of a
traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``splitrender`` console script (``argv``: the arguments after the
    program name; ``None``: ``sys.argv[1:]``); returns the exit status.

    See :func:`splitrender.cli.dispatch.main` for the statuses; 130 also for Ctrl-C while the
    command's modules are still being imported."""
    try:
        from splitrender.cli.dispatch import main as dispatch
    except KeyboardInterrupt:
        # The program name is spelled out: importing `args` for it could be what was interrupted.
        print("splitrender: interrupted", file=sys.stderr)
        return 130
    return dispatch(argv)
