"""What a real-time display showed at each refresh slot (splitrender.evaluation.shown), and
`bench --realtime --score`, which scores it against the ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from splitrender.client.realtime import DisplayFrame
from splitrender.errors import InvalidInputError
from splitrender.evaluation.shown import (
    SCORED_RUN,
    ShownRecorder,
    first_slot,
    group,
    runs,
    score_images,
    score_shown,
    spread,
)

FC = 120.0
P = 1.0 / FC


def frame(index: int, done_periods: float, divisor: int = 1, mode: str = "interpolate",
          deferred: bool = False) -> DisplayFrame:
    """Display frame ``index``, started on its refresh and done ``done_periods`` later."""
    refresh = 100.0 + index * P
    return DisplayFrame(
        index=index, time=index * P, start=refresh, done=refresh + done_periods * P,
        deadline=refresh + divisor * P, mode=mode, older=0, newer=1, alpha=0.5,
        server_age_ms=None, prepared=True, divisor=divisor, refresh=refresh, deferred=deferred,
    )


def test_first_slot_is_its_own_on_time_and_later_when_late_or_halved():
    assert first_slot(frame(7, 0.5), P) == 7
    assert first_slot(frame(7, 1.0), P) == 7  # done on the refresh: shown at it
    assert first_slot(frame(7, 1.2), P) == 8  # missed: up from the next refresh
    assert first_slot(frame(7, 2.5), P) == 9
    assert first_slot(frame(7, 1.5, divisor=2), P) == 8  # half rate: its deadline's refresh
    assert first_slot(frame(7, 3.5, divisor=2), P) == 10


def test_each_slot_shows_the_newest_frame_up_by_then():
    # Frame 0 on time; 1 misses (done 1.5 periods after its refresh: up from slot 2), so the
    # loop's next is 3, at half rate (up from slot 4 for slots 4 and 5), as is 5; 7 on time
    # at the full rate again.
    made = [frame(0, 0.5), frame(1, 1.5), frame(3, 1.2, divisor=2), frame(5, 1.2, divisor=2),
            frame(7, 0.4)]
    images = [np.full((4, 4, 3), k, np.uint8) for k in range(len(made))]
    rec = ShownRecorder(range(9), 0.0, FC)
    for f, img in zip(made, images):
        rec(img, f)
    shown = rec.finish(8)  # slot 8 is past the run
    assert [s.slot for s in shown] == list(range(8))
    assert [s.frame.index for s in shown] == [0, 0, 1, 1, 3, 3, 5, 7]
    assert [s.stale for s in shown] == [0, 1, 1, 2, 1, 2, 1, 0]
    assert all(s.image[0] is images[[f.index for f in made].index(s.frame.index)]
               for s in shown)  # the images themselves: no copy
    assert [s.time for s in shown] == pytest.approx([k * P for k in range(8)])


def test_slots_before_the_first_frame_showed_nothing_and_stereo_keeps_both_eyes():
    rec = ShownRecorder([0, 1, 2], 0.0, FC)
    left, right = np.zeros((2, 2, 3), np.uint8), np.ones((2, 2, 3), np.uint8)
    rec((left, right), frame(0, 2.5))  # up from slot 2
    shown = rec.finish(3)
    assert [s.slot for s in shown] == [2]
    assert shown[0].image[0] is left and shown[0].image[1] is right


def test_spread_keeps_both_ends_and_never_repeats():
    assert spread(12, 1188, 120)[0] == 12 and spread(12, 1188, 120)[-1] == 1187
    assert len(spread(12, 1188, 120)) == 120
    assert spread(0, 5, 120) == [0, 1, 2, 3, 4]
    assert spread(3, 3, 10) == [] and spread(0, 10, 1) == [0]


def test_runs_are_consecutive_spread_to_both_ends_with_context_and_never_overlap():
    slots = list(range(12, 1188))
    got = runs(slots, 120)
    assert len(got) == 10 and all(len(r) == SCORED_RUN + 2 for r in got)
    assert all(r == list(range(r[0], r[0] + len(r))) for r in got)  # consecutive
    assert got[0][0] == 12 and got[-1][-1] == 1187  # the first and the last slot
    assert all(a[-1] < b[0] for a, b in zip(got, got[1:]))
    # 125 in 11 runs of 11 or 12 scored; 5 in one run of 5.
    assert sorted(len(r) - 2 for r in runs(slots, 125)) == [11] * 7 + [12] * 4
    assert [len(r) - 2 for r in runs(slots, 5)] == [5]
    assert runs(slots, 0) == [] and runs([], 5) == [] and runs([3, 4], 5) == []


def test_runs_stay_inside_stretches_and_take_all_where_there_is_no_more_room():
    # Two stretches (a looped run's seam between them): no run straddles the gap.
    slots = list(range(0, 40)) + list(range(50, 90))
    got = runs(slots, 24, length=6)
    assert len(got) == 4 and all(len(r) == 8 for r in got)
    assert all(r[-1] < 40 or r[0] >= 50 for r in got)
    # Room for 38 + 38 scored: asking for as many or more takes each stretch whole.
    assert runs(slots, 76) == [list(range(0, 40)), list(range(50, 90))]
    assert runs(slots + [95, 96], 1000) == [list(range(0, 40)), list(range(50, 90))]
    # 36 candidates, 3 runs of 11 need windows of 13: two fit, the third is left out.
    assert [len(r) for r in runs(range(36), 33)] == [13, 13]


def test_group_drops_the_slots_that_showed_nothing():
    shown = ShownRecorder([5, 6, 7, 8, 20, 21, 22], 0.0, FC)
    shown(np.zeros((2, 2, 3), np.uint8), frame(7, 0.5))  # the first frame: up from slot 7
    got = group(shown.finish(30), [[5, 6, 7, 8], [20, 21, 22]])
    assert [[s.slot for s in run] for run in got] == [[7, 8], [20, 21, 22]]


def _vmaf_texture(n: int, h: int = 48, w: int = 64) -> list[np.ndarray]:
    """A texture translating 2 px per frame (VMAF's motion feature is not 0)."""
    rng = np.random.default_rng(5)
    coarse = rng.integers(0, 256, (h // 4, (w + 2 * n) // 4 + 1, 3), dtype=np.uint8)
    big = np.repeat(np.repeat(coarse, 4, axis=0), 4, axis=1)
    return [np.ascontiguousarray(big[:, 2 * i : 2 * i + w]) for i in range(n)]


def test_vmaf_of_runs_is_the_vmaf_the_frames_have_in_the_whole_sequence():
    # What a viewer sees is the whole sequence; the score takes runs of it. Each scored
    # frame's VMAF must be the one it has there, which libvmaf's motion feature (a frame
    # against its neighbours) makes depend on the frames around it.
    from splitrender.evaluation.metrics import evaluate_sequence

    truth = _vmaf_texture(20)
    # Brighter and off by a pixel: VMAF well under 100.
    shown = [np.roll(np.asarray(np.clip(t.astype(int) + 24, 0, 255), np.uint8), 1, axis=1)
             for t in truth]
    whole = evaluate_sequence(shown, truth, skip=0, metrics=["vmaf"]).per_frame
    picked = [[0, 1, 2], [6, 7, 8], [12, 13, 14, 15]]
    _, rows = score_images([[(shown[i],) for i in r] for r in picked],
                           [[(truth[i],) for i in r] for r in picked])
    scored = [i for r in picked for i in r[1:-1]]
    assert [row["vmaf"] for row in rows] == pytest.approx([whole[i]["vmaf"] for i in scored],
                                                          abs=1e-6)
    # The same frames as one sequence, as a spread of single refreshes was scored: frame 7
    # between 1 and 13, 12 px of motion from each, scores otherwise.
    alone = evaluate_sequence([shown[i] for i in scored], [truth[i] for i in scored], skip=0,
                              metrics=["vmaf"]).per_frame
    assert scored[1] == 7
    assert alone[1]["vmaf"] != pytest.approx(whole[7]["vmaf"], abs=0.5)


def test_connect_score_spreads_a_short_session_over_all_of_it():
    # 60 display frames (connect --fps 10 --seconds 6), 36 after the skipped ends: all are
    # taken, in one run, and the 34 between its ends scored; the steps of 120 took 11, all
    # from the session's first third.
    from splitrender.cli.live import _pick
    from splitrender.evaluation.metrics import SKIP_FRAMES

    frames = [(k / 10, np.zeros((2, 2, 3), np.uint8)) for k in range(60)]
    picked = _pick(frames)
    assert [[t for t, _ in run] for run in picked] == [
        [k / 10 for k in range(SKIP_FRAMES, 60 - SKIP_FRAMES)]]
    long = [(k / 120, frames[0][1]) for k in range(1200)]
    picked = _pick(long)
    assert sum(len(run) - 2 for run in picked) == 120
    assert picked[0][0][0] == SKIP_FRAMES / 120
    assert picked[-1][-1][0] == (1199 - SKIP_FRAMES) / 120


def test_score_splits_by_the_mode_shown_and_its_age():
    # Ground truth grey 128; each shown frame off by a known amount: its PSNR is known.
    # Slots 0..6 in one run: 0 and 6 are VMAF's context, 1..5 scored.
    made = [frame(0, 0.5, mode="hold"), frame(1, 0.5, mode="interpolate"),
            frame(2, 0.5, mode="extrapolate", deferred=True), frame(3, 1.5, mode="extrapolate"),
            frame(5, 0.5, mode="hold"), frame(6, 0.5)]
    offset = {0: 64, 1: 4, 2: 8, 3: 16, 5: 32, 6: 64}
    rec = ShownRecorder(range(7), 0.0, FC)
    for f in made:
        rec(np.full((48, 48, 3), 128 + offset[f.index], np.uint8), f)
    shown = rec.finish(7)
    assert [s.frame.index for s in shown] == [0, 1, 2, 2, 3, 5, 6]
    truth = np.full((48, 48, 3), 128, np.uint8)
    score = score_shown([shown], lambda t: [truth], no_vmaf=True)

    def psnr(d: int) -> float:
        return 10 * math.log10(255**2 / d**2)

    assert score["scored_frames"] == 5 and "vmaf" not in score
    by_mode = score["by_mode"]
    assert {k: g["refreshes"] for k, g in by_mode.items()} == {
        "deferred": 2, "extrapolate": 1, "hold": 1, "interpolate": 1}
    assert by_mode["interpolate"]["psnr"] == pytest.approx(psnr(4), abs=1e-6)
    assert by_mode["deferred"]["psnr"] == pytest.approx(psnr(8), abs=1e-6)
    assert by_mode["hold"]["psnr"] == pytest.approx(psnr(32), abs=1e-6)
    by_age = score["by_staleness"]
    # Slot 3 kept frame 2 up; frame 3 missed and was up from slot 4.
    assert {k: g["refreshes"] for k, g in by_age.items()} == {"0": 3, "1": 2}
    assert by_age["1"]["psnr"] == pytest.approx((psnr(8) + psnr(16)) / 2, abs=1e-6)
    # The overall PSNR is that of the mean squared error (as the evaluation's everywhere).
    mse = np.mean([4**2, 8**2, 8**2, 16**2, 32**2])
    assert score["psnr"] == pytest.approx(10 * math.log10(255**2 / mse), abs=1e-6)


def test_score_pools_the_squared_error_of_every_run_and_counts_only_their_insides():
    # Two runs of two eyes (off by 4 and by 12 inside, by 100 at their context ends): the
    # overall PSNR is that of the mean squared error over the four scored frames of both.
    truth = np.full((40, 40, 3), 100, np.uint8)

    def run(off: int, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        end, inside = truth + 100, truth + off
        return [(end, end), *[(inside, inside)] * n, (end, end)]

    images = [run(4, 1), run(12, 3)]
    truths = [[(truth, truth)] * len(r) for r in images]
    out, rows = score_images(images, truths, no_vmaf=True)
    mse = (4**2 + 3 * 12**2) / 4
    assert out["scored_frames"] == 4 and len(rows) == 4
    assert out["psnr"] == pytest.approx(10 * math.log10(255**2 / mse), abs=1e-9)
    assert [p["psnr"] for p in out["per_eye"]] == pytest.approx([out["psnr"]] * 2, abs=1e-9)
    assert [r["psnr"] for r in rows] == pytest.approx(
        [10 * math.log10(255**2 / d**2) for d in (4, 12, 12, 12)], abs=1e-9)


def test_score_of_nothing_shown_scores_nothing():
    assert score_shown([], lambda t: [], no_vmaf=True) == {"scored_frames": 0}
    # A run of two slots has no frame between its context ends.
    rec = ShownRecorder([0, 1], 0.0, FC)
    rec(np.zeros((48, 48, 3), np.uint8), frame(0, 0.5))
    truths: list[float] = []
    score = score_shown([rec.finish(2)], lambda t: truths.append(t) or [], no_vmaf=True)
    assert score == {"scored_frames": 0} and truths == []  # and no ground truth rendered


def test_bench_realtime_score_scores_the_refreshes_of_a_builtin_scene(tmp_path, monkeypatch):
    import tempfile

    from splitrender.evaluation.bench_realtime import format_realtime, run_realtime_bench

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the stream cache
    b = run_realtime_bench(scale=0.05, seconds=0.5, score=6, no_vmaf=True, progress=False)
    s = b.score
    assert s is not None and s["scored_frames"] == 6
    assert sum(g["refreshes"] for g in s["by_mode"].values()) == 6
    assert sum(g["refreshes"] for g in s["by_staleness"].values()) == 6
    assert 0.0 < s["ssim"] <= 1.0 and s["psnr"] > 10.0 and "vmaf" not in s
    assert b.to_json()["score"] == s
    text = format_realtime(b)
    assert "shown at 6 refreshes against the ground truth: SSIM" in text
    assert "by the mode of the frame shown:" in text and "by the age of its pose:" in text


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"score": -1}, "score: expected refreshes to score, 0 to 100000, got -1"),
        ({"score": True}, "score: expected refreshes to score"),
        ({"score": 5, "stream": "x.srs"}, "a stream file carries no ground truth"),
        # Too short to score any refresh (it ran, then said "nothing scored").
        ({"score": 5}, r"--score: 0.1 s is 12 refreshes at 120 FPS; the score leaves out 12 at "
         r"each end and scores a refresh between two others, so at least 0.225 s is needed"),
        ({"score": 5, "display_fps": 240.0}, r"0.1 s is 24 refreshes at 240 FPS.*0.113 s"),
    ],
)
def test_bench_realtime_score_refuses_what_cannot_be_scored(kwargs, message):
    from splitrender.evaluation.bench_realtime import run_realtime_bench

    with pytest.raises(InvalidInputError, match=message):
        run_realtime_bench(seconds=0.1, progress=False, **kwargs)
