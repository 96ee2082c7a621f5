"""splitrender.progress: live bars on a terminal, one plain line per stage elsewhere."""

from __future__ import annotations

import io
import re

import pytest

from splitrender.progress import Progress


def _run(progress: Progress) -> None:
    with progress:
        progress.stage("rendering")
        for k in range(5):
            progress.bar(k + 1, 5, "frames")
        progress.stage("encoding")
        for k in range(3):
            progress.bar(k + 1, 3, "server frames")
        progress.stage("scoring")


def test_not_a_terminal_gives_one_plain_line_per_stage() -> None:
    out = io.StringIO()  # isatty() is False, as for CI logs and `> log`
    progress = Progress(3, stream=out)
    progress.start -= 90.0  # made 90 s ago: each line says so (it checked only for " s)")
    _run(progress)
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert [line.split("  (")[0] for line in lines] == [
        "[1/3] rendering",
        "[2/3] encoding",
        "[3/3] scoring",
    ]
    assert all(line.endswith("  (90.0 s)") for line in lines), lines  # elapsed time


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_terminal_gets_live_bars_with_rate_and_eta() -> None:
    out = _Terminal()
    _run(Progress(3, stream=out))
    text = out.getvalue()
    assert "[1/3] rendering" in text and "[3/3] scoring" in text
    assert "\r" in text  # redrawn in place
    assert "5/5 frames" in text and "3/3 server frames" in text
    assert "frames/s" in text and "ETA" in text


@pytest.mark.parametrize("live", [True, False])
def test_disabled_prints_nothing(live: bool) -> None:
    out = io.StringIO()
    _run(Progress(3, enabled=False, stream=out, live=live))
    assert out.getvalue() == ""


def test_a_new_loop_in_the_same_stage_starts_a_new_bar() -> None:
    out = _Terminal()
    with Progress(1, stream=out) as p:
        p.stage("two loops")
        p.bar(2, 4, "a")
        p.bar(1, 6, "b")  # another total: the first bar is closed, not overrun
        p.bar(6, 6, "b")
    text = out.getvalue()
    assert "6/6 b" in text
    # The first bar stays where it stopped (2 of 4) and the second starts from 0 of its own
    # total on a new line: neither is drawn with the other's total.
    a, b = text.index("2/4 a"), text.index("0/6 b")
    assert a < b and "\n" in text[a:b]
    of_4 = re.findall(r"(\d+)/4 (\w)", text)
    of_6 = re.findall(r"(\d+)/6 (\w)", text)
    assert {u for _, u in of_4} == {"a"} and max(int(n) for n, _ in of_4) == 2
    assert {u for _, u in of_6} == {"b"}


def test_a_finished_loop_closes_its_bar_at_once() -> None:
    # A bar is closed (its line ended) when done == total, not when the next stage starts: what
    # else is printed before that does not land on the bar's line.
    out = _Terminal()
    with Progress(1, stream=out) as p:
        p.stage("one loop")
        for k in range(3):
            p.bar(k + 1, 3, "frames")
        text = out.getvalue()
        assert text.endswith("\n") and "3/3 frames" in text.rsplit("\r", 1)[-1], repr(text)
