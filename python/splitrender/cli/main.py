"""The ``splitrender`` command: the parser of every subcommand and the dispatch.

Each subcommand family lives in its own module (``example``, ``recording``, ``play``,
``evaluation``, ``dataset``), which adds its parser and sets ``run`` as the parser's default, so that this
module only dispatches.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from splitrender._native import __version__
from splitrender.cli import dataset, evaluation, example, live, play, recording
from splitrender.cli.args import PROG, Parser
from splitrender.errors import SplitRenderError
from splitrender.reproject import METHODS

__all__ = ["main"]


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
    """Entry point of the ``splitrender`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        status: int = args.run(args)
        return status
    except (SplitRenderError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
