"""The ``splitrender`` command line, one module per subcommand family (:mod:`.main` dispatches),
and the codec benchmark's (:mod:`.bench_codec`: ``python -m splitrender.cli.bench_codec``)."""

from splitrender.cli.main import main

__all__ = ["main"]
