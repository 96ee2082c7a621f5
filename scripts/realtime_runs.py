"""Late frames against the time the virtual machine's host took, over many real-time runs.

Reads the files that ``splitrender bench --realtime --json FILE`` wrote and prints one line per
run (frames, late frames, the host's share of the machine's CPU time, the rate achieved), the
runs grouped by that share with what made their frames late (``deadline_misses_by_cause``:
started late, more CPU, threads waited; docs/realtime.md, "What makes the rare misses late"),
and Spearman's rank correlation between the share and the late frames; ``--plot FILE`` also
draws each run's late frames per thousand against the share.

    for i in $(seq 1 24); do
        splitrender bench --realtime --scale 0.25 --seconds 10 --json runs/r$i.json
    done
    python scripts/realtime_runs.py runs/*.json --plot runs/late-vs-steal.png

A run made before the benches recorded the share (``host_steal_pct`` absent) or on a platform
that does not count it (``null``) is listed and left out of the groups and the correlation.
(docs/realtime.md, "Time the host took", was made this way.)
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

#: The groups of the host's share (per cent): [lower, upper).
GROUPS = ((0.0, 5.0), (5.0, 15.0), (15.0, math.inf))

#: ``deadline_misses_by_cause``'s keys, in the order printed, and how they are printed.
CAUSES = (("late_start", "started late"), ("more_cpu", "more CPU"), ("waited", "threads waited"))


@dataclass(frozen=True)
class Run:
    name: str
    frames: int
    late: int
    steal_pct: float | None
    achieved_fps: float
    #: Late frames by cause, in the order of :data:`CAUSES` (``None`` for a run made before the
    #: benches recorded them).
    causes: tuple[int, ...] | None = None


def load(path: Path) -> Run:
    """One run's figures, or ``ValueError`` naming the file and what it lacks."""
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a readable JSON file ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected the object `bench --realtime --json` writes")
    want = {"frames": int, "deadline_misses": int, "achieved_fps": (int, float)}
    for key, kind in want.items():
        if not isinstance(d.get(key), kind) or isinstance(d.get(key), bool):
            raise ValueError(f"{path}: expected a number `{key}`, as `bench --realtime "
                             "--json` writes")
    if not 0 <= d["deadline_misses"] <= d["frames"]:
        raise ValueError(f"{path}: {d['deadline_misses']} deadline misses of {d['frames']} "
                         "frames; expected 0 to that many")
    if not math.isfinite(d["achieved_fps"]) or d["achieved_fps"] < 0:
        raise ValueError(f"{path}: `achieved_fps` {d['achieved_fps']!r} is not a rate >= 0")
    steal = d.get("host_steal_pct")
    if steal is not None and (not isinstance(steal, (int, float)) or isinstance(steal, bool)
                              or not 0.0 <= steal <= 100.0):
        raise ValueError(f"{path}: `host_steal_pct` {steal!r} is not a share in 0-100")
    return Run(path.name, d["frames"], d["deadline_misses"], steal, float(d["achieved_fps"]),
               _causes(path, d))


def _causes(path: Path, d: dict[str, object]) -> tuple[int, ...] | None:
    """The run's late frames by cause (:data:`CAUSES`), checked to count each late frame once."""
    by = d.get("deadline_misses_by_cause")
    if by is None:
        return None
    keys = [k for k, _ in CAUSES]
    if not isinstance(by, dict) or sorted(by) != sorted(keys) or not all(
        isinstance(by[k], int) and not isinstance(by[k], bool) and by[k] >= 0 for k in keys
    ):
        raise ValueError(f"{path}: `deadline_misses_by_cause` {by!r} is not counts >= 0 of "
                         f"{', '.join(keys)}")
    counts = tuple(by[k] for k in keys)
    if sum(counts) != d["deadline_misses"]:
        raise ValueError(f"{path}: `deadline_misses_by_cause` counts {sum(counts)} late frames, "
                         f"`deadline_misses` {d['deadline_misses']}")
    return counts


def report(runs: list[Run]) -> str:
    """The per-run lines, the groups and the correlation as text."""
    lines = [f"{'run':<24} {'frames':>7} {'late':>6} {'host %':>7} {'FPS':>7}"]
    for r in runs:
        steal = "n/a" if r.steal_pct is None else f"{r.steal_pct:.1f}"
        lines.append(f"{r.name:<24} {r.frames:7d} {r.late:6d} {steal:>7} {r.achieved_fps:7.1f}")
    counted = [r for r in runs if r.steal_pct is not None]
    lines.append("")
    for lo, hi in GROUPS:
        g = [r for r in counted if r.steal_pct is not None and lo <= r.steal_pct < hi]
        span = f"{lo:g} % or more" if math.isinf(hi) else f"{lo:g}-{hi:g} %"
        if not g:
            lines.append(f"host took {span}: no run")
            continue
        late = sorted(r.late for r in g)
        causes = [r.causes for r in g]
        why = ""
        if all(c is not None for c in causes):  # else the groups' counts would not add up
            totals = [sum(c[i] for c in causes if c is not None) for i in range(len(CAUSES))]
            why = " (" + ", ".join(f"{n} {say}" for n, (_, say) in zip(totals, CAUSES)) + ")"
        lines.append(
            f"host took {span}: {len(g)} run{'s' * (len(g) != 1)}, late frames "
            f"{late[0]}-{late[-1]} a run, {sum(late)} in {sum(r.frames for r in g)} frames{why}, "
            f"{(clean := sum(r.late == 0 for r in g))} run{'s' * (clean != 1)} without one"
        )
    if len(counted) >= 3:
        from scipy.stats import spearmanr

        rho = spearmanr([r.steal_pct for r in counted], [r.late for r in counted]).statistic
        lines.append(f"Spearman's rho, late frames against the host's share: {rho:.2f} "
                     f"over {len(counted)} runs")
    return "\n".join(lines)


def plot(runs: list[Run]) -> bytes:
    """A PNG: each counted run's late frames per thousand against the host's share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counted = [r for r in runs if r.steal_pct is not None]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    ax.scatter([r.steal_pct for r in counted],
               [1e3 * r.late / max(r.frames, 1) for r in counted], s=18)
    ax.set_xlabel("the host's share of the machine's CPU time during the run (steal, %)")
    ax.set_ylabel("late frames per 1000")
    ax.set_title(f"{len(counted)} real-time runs")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+", type=Path, help="`bench --realtime --json` files")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG")
    args = p.parse_args(argv)
    try:
        runs = [load(f) for f in args.files]
    except ValueError as e:
        print(f"realtime_runs: error: {e}", file=sys.stderr)
        return 2
    print(report(runs))
    if args.plot is not None:
        from splitrender.files import write_atomic

        try:
            write_atomic(args.plot, plot(runs))  # nothing half-written on failure
        except OSError as e:
            print(f"realtime_runs: error: --plot: {e.strerror}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
