"""What a real-time display showed at each refresh, scored against the ground truth.

:class:`~splitrender.client.realtime.RealtimeClient` renders display frame ``n`` at the pose of
refresh slot ``n`` (content time ``t_n = start + n / f_c``) for its deadline: the refresh
``divisor`` periods after the one it started on. Slot ``s`` is shown from the refresh at
``s + 1`` periods (a full-rate frame on time shows its own slot). A frame is visible from the
first refresh at or after both its deadline and the moment it was done, so

    first slot of frame n = n + max(divisor, ceil((done - refresh) / period)) - 1

and slot ``s`` shows the newest frame whose first slot is at most ``s``. A frame that misses
its deadline leaves the previous image up for the refreshes it overran, and a frame at half
rate shows its pose one refresh later and for two refreshes: scoring the slots (the image up at
each refresh against the ground truth of that refresh's time) charges a missed deadline and a
halved rate what the viewer sees of them, as it charges an extrapolated frame its
reprojection error. Scoring the frames made instead (``connect --score``) scores a late frame
as if it were on time.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Sequence, Sized
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from splitrender.client.realtime import DisplayFrame

__all__ = [
    "METRIC_WORDS", "MIN_RUN", "SCORED", "SCORED_RUN", "Shown", "ShownRecorder", "first_slot",
    "format_scores", "group", "runs", "score_images", "score_shown", "scorable", "spread",
]

_Image = npt.NDArray[np.uint8]

#: Most refresh slots ``bench --realtime --score`` scores by default, and display frames
#: ``connect --score`` scores (the ground truth costs a render each).
SCORED = 120

#: Most frames scored in a row. VMAF's motion feature compares each reference frame with the
#: one before it and the one after it, so frames scored apart (every tenth refresh of a run)
#: get the motion of frames 80 ms apart and a VMAF about 5 points higher than the same frames
#: in the video a viewer sees (docs/realtime.md, "VMAF on consecutive refreshes"). The scored
#: frames therefore come in runs of consecutive ones, each with one more at each end that only
#: VMAF sees. 12: a server period at 120/10 FPS, so that a run goes through every phase of a
#: pair.
SCORED_RUN = 12

#: The fewest frames of a run that score any: one between VMAF's two context frames.
MIN_RUN = 3

_R = TypeVar("_R", bound=Sized)


def scorable(runs_of: Iterable[_R]) -> list[_R]:
    """The runs of ``runs_of`` that score a frame (at least :data:`MIN_RUN` long); the others
    score nothing."""
    return [run for run in runs_of if len(run) >= MIN_RUN]


#: The metrics as the text reports write them: their labels and digits.
METRIC_WORDS = {"ssim": ("SSIM", 4), "flip": ("FLIP", 4), "psnr": ("PSNR", 2),
                "vmaf": ("VMAF", 2)}


def format_scores(scores: dict[str, Any]) -> str:
    """The metrics in ``scores`` (:func:`score_images`' means), as ``SSIM 0.8527, ...``."""
    return ", ".join(f"{label} {scores[m]:.{digits}f}" for m, (label, digits)
                     in METRIC_WORDS.items() if m in scores)


def first_slot(frame: DisplayFrame, period: float) -> int:
    """The first refresh slot ``frame`` is shown for (module docs); ``period`` is ``1 / f_c``.
    A frame without its refresh's clock time counts as on time."""
    late = 0
    if frame.refresh is not None:
        # 1e-9: a frame done exactly on a refresh is visible at that refresh.
        late = math.ceil((frame.done - frame.refresh) / period - 1e-9)
    return frame.index + max(frame.divisor, late) - 1


@dataclass(frozen=True)
class Shown:
    """Refresh slot ``slot`` (content time ``time``) showed ``image`` (a stereo frame's eyes,
    left first), made by ``frame``."""

    slot: int
    time: float
    frame: DisplayFrame
    image: tuple[_Image, ...]

    @property
    def stale(self) -> int:
        """Refreshes between the frame's pose and this slot: 0 for a full-rate frame on time,
        more where its successor missed its deadline or the rate was divided."""
        return self.slot - self.frame.index


class ShownRecorder:
    """An ``on_frame`` of :meth:`RealtimeClient.run <splitrender.client.realtime.
    RealtimeClient.run>` that keeps what the display showed at each of ``slots`` (ascending
    refresh slots; ``start_time`` and ``fps`` as the run's), and nothing else: a reference to
    each image shown, which :meth:`Client.render <splitrender.client.client.Client.render>`
    returns read-only and never writes again (it is the eye's previous output until the next
    frame replaces it), so keeping it costs the display no copy."""

    def __init__(self, slots: Sequence[int], start_time: float, fps: float) -> None:
        self._slots = sorted(set(slots))
        self._start, self._period = start_time, 1.0 / fps
        self._next = 0  # the first slot not yet resolved
        self._current: tuple[DisplayFrame, tuple[_Image, ...]] | None = None
        self.shown: list[Shown] = []

    def _resolve(self, below: int | None) -> None:
        """Resolves every pending slot under ``below`` (``None``: all) to the current frame."""
        while self._next < len(self._slots) and (below is None
                                                 or self._slots[self._next] < below):
            s = self._slots[self._next]
            self._next += 1
            if self._current is not None:  # before the first frame nothing was shown
                frame, image = self._current
                self.shown.append(Shown(s, self._start + s * self._period, frame, image))

    def __call__(self, image: Any, frame: DisplayFrame) -> None:
        # The slots before this frame's first showed the frame before it.
        self._resolve(first_slot(frame, self._period))
        self._current = (frame, tuple(image) if isinstance(image, tuple) else (image,))

    def finish(self, slots_in_run: int) -> list[Shown]:
        """What was shown at the slots, once the run is over (``slots_in_run``: its refreshes;
        slots past them were not shown)."""
        self._slots = [s for s in self._slots if s < slots_in_run]
        self._resolve(None)
        return self.shown


def spread(first: int, stop: int, count: int) -> list[int]:
    """At most ``count`` integers evenly spread over ``first .. stop - 1``, both ends kept."""
    n = stop - first
    k = min(count, n)
    if k <= 0:
        return []
    if k == 1:
        return [first]
    return [first + round(j * (n - 1) / (k - 1)) for j in range(k)]


def runs(candidates: Sequence[int], count: int, length: int = SCORED_RUN) -> list[list[int]]:
    """Runs of consecutive integers taken from the ascending ``candidates`` (refresh slots or
    frame indices that may be scored), for scoring ``count`` of them: each run's first and
    last are VMAF's context only (:data:`SCORED_RUN`), the ones between are scored. The runs
    score ``count`` in ``ceil(count / length)`` runs whose lengths differ by at most one (the
    longer first), spread evenly over the candidates from their start to their end, never
    overlapping. Where the candidates hold no more than ``count``, every one is taken:
    each stretch of consecutive candidates is one run. Stretches too short for a run (under
    three) are left out, and where the runs do not all fit, fewer are returned."""
    stretches: list[list[int]] = []
    for c in candidates:
        if stretches and c == stretches[-1][-1] + 1:
            stretches[-1].append(c)
        else:
            stretches.append([c])
    stretches = scorable(stretches)
    if count <= 0 or not stretches:
        return []
    if count >= sum(len(s) - 2 for s in stretches):
        return stretches
    k = -(-count // length)
    lengths = [count // k + (i < count % k) for i in range(k)]  # longest first
    window = lengths[0] + 2
    # Where a window of the longest run fits inside one stretch: (stretch, offset).
    starts = [(i, o) for i, s in enumerate(stretches) for o in range(len(s) - window + 1)]
    out: list[list[int]] = []
    taken_to = (-1, 0)  # the first (stretch, offset) not inside a window already taken
    for j, n in zip(spread(0, len(starts), k), lengths):
        at = next((p for p in starts[j:] if p >= taken_to), None)
        if at is None:
            break
        i, o = at
        out.append(stretches[i][o : o + n + 2])
        taken_to = (i, o + n + 2)
    return out


def _across_runs(
    progress: Callable[[str, int, int], None], before: int, total: int, run: int, runs: int,
    metric: str, done: int, _: int,
) -> None:
    """One run's ``progress(metric, done, n)`` as of all the runs: VMAF (reported once a run)
    by runs, the other metrics by the ``total`` frames, ``before`` of them in earlier runs."""
    progress(metric, *((run, runs) if metric == "vmaf" else (before + done, total)))


def score_images(
    images: Sequence[Sequence[Sequence[_Image]]],
    truths: Sequence[Sequence[Sequence[_Image]]],
    no_vmaf: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
) -> tuple[dict[str, Any], list[dict[str, float]]]:
    """``images[r][i][e]`` (run ``r``, its frame ``i``, eye ``e``) against ``truths[r][i][e]``,
    each run consecutive frames of which the first and the last are VMAF's context, scored by
    no metric (:data:`SCORED_RUN`; runs of fewer than three frames score nothing): each
    metric's mean over the scored frames and the eyes (a stereo sequence's as eval's Table 3;
    PSNR's of the mean squared error), with ``per_eye`` for two eyes and ``scored_frames``,
    and each scored frame's metrics (the eyes' mean), run after run. VMAF is left out with
    ``no_vmaf`` and for a side under ``VMAF_MIN_SIDE`` pixels. ``progress(metric, done,
    total)`` counts over all the runs."""
    from splitrender.evaluation.metrics import (
        METRICS,
        VMAF_MIN_SIDE,
        evaluate_sequence,
        psnr_of_mse,
    )

    kept = [(r, t) for r, t in zip(images, truths) if len(r) >= MIN_RUN]
    if not kept:
        return {"scored_frames": 0}, []
    eyes = len(kept[0][0][0])
    h, w = kept[0][0][0][0].shape[:2]
    metrics = [m for m in METRICS if not (m == "vmaf" and (no_vmaf or min(h, w) < VMAF_MIN_SIDE))]
    total = sum(len(r) - 2 for r, _ in kept)
    frames = [dict.fromkeys(metrics, 0.0) for _ in range(total)]
    per_eye = []
    for e in range(eyes):
        rows: list[dict[str, float]] = []
        squared = 0.0  # the sum of the frames' mean squared errors
        for run, (r, t) in enumerate(kept, 1):
            counted = None if progress is None else functools.partial(
                _across_runs, progress, len(rows), total, run, len(kept))
            result = evaluate_sequence(
                [f[e] for f in r], [g[e] for g in t], skip=1, metrics=metrics, progress=counted,
            )
            rows.extend(result.per_frame)
            if result.mse is not None:
                squared += result.mse * len(result.per_frame)
        mean = {m: float(np.mean([row[m] for row in rows])) for m in metrics}
        if "psnr" in metrics:
            mean["psnr"] = psnr_of_mse(squared / total)
        per_eye.append(mean)
        for row, values in zip(frames, rows):
            for m in metrics:
                row[m] += values[m] / eyes
    out: dict[str, Any] = {m: sum(p[m] for p in per_eye) / eyes for m in metrics}
    out["scored_frames"] = total
    if eyes > 1:
        out["per_eye"] = per_eye
    return out, frames


def _kind(s: Shown) -> str:
    return "deferred" if s.frame.deferred else s.frame.mode


def score_shown(
    shown: Sequence[Sequence[Shown]],
    truth: Callable[[float], Sequence[_Image]],
    no_vmaf: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """The runs of consecutive slots ``shown`` (:class:`ShownRecorder`'s, grouped by
    :func:`group`) against ``truth(time)`` (the ground truth at the slot's content time, one
    image per eye; each run's first and last slot are VMAF's context, :func:`score_images`):
    the means of :func:`score_images`, and the same split by what was up: ``by_mode`` (the
    mode of the frame shown; ``deferred``: an extrapolated frame that could have interpolated,
    :class:`~splitrender.client.realtime.ModeGovernor`) and ``by_staleness`` (``"0"``: the
    frame of the slot's own pose, ``"1"``, ``"2+"``: refreshes older, where a deadline was
    missed or the rate divided), each with its ``refreshes`` count. PSNR's means here are of
    the frames' PSNR values (the overall one is the PSNR of the mean squared error, as
    :func:`evaluate_sequence`'s)."""
    shown = scorable(shown)
    truths = [[tuple(truth(s.time)) for s in run] for run in shown]
    out, frames = score_images([[s.image for s in run] for run in shown], truths, no_vmaf,
                               progress)
    if not frames:
        return out
    scored = [s for run in shown for s in run[1:-1]]

    def split(key: Callable[[Shown], str]) -> dict[str, dict[str, float]]:
        groups: dict[str, list[dict[str, float]]] = {}
        for s, row in zip(scored, frames):
            groups.setdefault(key(s), []).append(row)
        return {
            k: {"refreshes": len(rows), **{m: float(np.mean([r[m] for r in rows]))
                                           for m in rows[0]}}
            for k, rows in sorted(groups.items())
        }

    out["by_mode"] = split(_kind)
    out["by_staleness"] = split(lambda s: str(s.stale) if s.stale < 2 else "2+")
    return out


def group(shown: Sequence[Shown], slot_runs: Sequence[Sequence[int]]) -> list[list[Shown]]:
    """``shown`` (:meth:`ShownRecorder.finish`) as the runs of ``slot_runs`` (:func:`runs`),
    each without the slots that showed nothing (before the first frame): still consecutive,
    as only a run's first slots can be missing."""
    at = {s.slot: s for s in shown}
    return [[at[k] for k in run if k in at] for run in slot_runs]
