"""Progress of long-running work, the one facility every command uses (on ``tqdm``).

A long command is a few *stages* (render, encode, play, score, ...), some of which loop over
frames. :class:`Progress` shows them on a stream (stderr by default):

- on a terminal: ``[k/N] text (elapsed)`` per stage, and a live ``tqdm`` bar with the count, the
  rate and the ETA for each loop of a stage;
- elsewhere (CI, ``> log``, a pipe): exactly one plain line per stage, ``[k/N] text (elapsed)``,
  and nothing for the loops, so that a log has no carriage returns and no bar clutter.

Work functions do not take a :class:`Progress`: they take a plain callback
``progress(done, total)`` (see :meth:`Progress.bar`), so that the library stays usable without it.
"""

from __future__ import annotations

import time
from typing import Any, TextIO

from tqdm import tqdm

__all__ = ["Progress"]


def _is_terminal(stream: Any) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if isatty is not None else False
    except (OSError, ValueError):  # a closed or detached stream
        return False


class Progress:
    """Stages and per-stage loop bars of one command on ``stream`` (stderr by default).

    ``total`` is the number of stages announced (``[k/total]``); ``enabled=False`` prints
    nothing. ``live`` forces the terminal (``True``) or plain-line (``False``) style; by default
    it follows ``stream.isatty()``. Use as a context manager, or call :meth:`close` at the end.
    """

    def __init__(
        self,
        total: int,
        enabled: bool = True,
        stream: TextIO | None = None,
        *,
        live: bool | None = None,
    ) -> None:
        import sys

        self.total = total
        self.step = 0
        self.enabled = enabled
        self.stream: TextIO = stream if stream is not None else sys.stderr
        self.live = _is_terminal(self.stream) if live is None else live
        self.start = time.perf_counter()
        self._bar: tqdm[Any] | None = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def elapsed(self) -> float:
        """Seconds since this object was made."""
        return time.perf_counter() - self.start

    def stage(self, text: str) -> None:
        """Start the next stage: one line ``[k/N] text (elapsed)``; closes the previous bar."""
        self._close_bar()
        self.step += 1
        if self.enabled:
            print(f"[{self.step}/{self.total}] {text}  ({self.elapsed():.1f} s)", file=self.stream)
            self.stream.flush()

    def bar(self, done: int, total: int, unit: str = "") -> None:
        """``done`` of ``total`` items of the current stage are finished (a callback for loops).

        On a terminal this moves a live bar (count, rate, ETA), closed when ``done == total``;
        otherwise it prints nothing (the stage's line said what runs)."""
        if not (self.enabled and self.live) or total <= 0:
            return
        if self._bar is None or self._bar.total != total or done < self._bar.n:
            self._close_bar()
            self._bar = tqdm(
                total=total,
                unit=f" {unit}" if unit else "it",
                file=self.stream,
                leave=True,
                dynamic_ncols=True,
                bar_format="      {bar:30} {n_fmt}/{total_fmt}{unit} {rate_fmt} "
                "{elapsed} ETA {remaining}",
            )
        self._bar.update(done - self._bar.n)
        if done >= total:
            self._close_bar()

    def close(self) -> None:
        """Close a bar still open (an interrupted loop)."""
        self._close_bar()

    def _close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
