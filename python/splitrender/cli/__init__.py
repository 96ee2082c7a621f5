"""The ``splitrender`` command line, one module per subcommand family (:mod:`.main` dispatches)."""

from splitrender.cli.main import main

__all__ = ["main"]
