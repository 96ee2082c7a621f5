"""What a real-time display showed at each refresh slot (splitrender.evaluation.shown), and
`bench --realtime --score`, which scores it against the ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from splitrender.client.realtime import DisplayFrame
from splitrender.errors import InvalidInputError
from splitrender.evaluation.shown import ShownRecorder, first_slot, score_shown, spread

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


def test_connect_score_spreads_a_short_session_over_all_of_it():
    # 60 display frames (connect --fps 10 --seconds 6), 36 after the skipped ends: all are
    # scored; the steps of 120 took 11, all from the session's first third.
    from splitrender.cli.live import _pick
    from splitrender.evaluation.metrics import SKIP_FRAMES

    frames = [(k / 10, np.zeros((2, 2, 3), np.uint8)) for k in range(60)]
    assert [t for t, _ in _pick(frames)] == [k / 10 for k in range(SKIP_FRAMES, 60 - SKIP_FRAMES)]
    long = [(k / 120, frames[0][1]) for k in range(1200)]
    picked = [t for t, _ in _pick(long)]
    assert len(picked) == 120 and picked[0] == SKIP_FRAMES / 120
    assert picked[-1] == (1199 - SKIP_FRAMES) / 120


def test_score_splits_by_the_mode_shown_and_its_age():
    # Ground truth grey 128; each shown frame off by a known amount: its PSNR is known.
    made = [frame(0, 0.5, mode="interpolate"), frame(1, 0.5, mode="extrapolate", deferred=True),
            frame(2, 1.5, mode="extrapolate"), frame(4, 0.5, mode="hold")]
    offset = {0: 4, 1: 8, 2: 16, 4: 32}
    rec = ShownRecorder(range(5), 0.0, FC)
    for f in made:
        rec(np.full((48, 48, 3), 128 + offset[f.index], np.uint8), f)
    shown = rec.finish(5)
    assert [s.frame.index for s in shown] == [0, 1, 1, 2, 4]
    truth = np.full((48, 48, 3), 128, np.uint8)
    score = score_shown(shown, lambda t: [truth], no_vmaf=True)

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
    # Slot 2 kept frame 1 up; frame 2 missed and was up from slot 3.
    assert {k: g["refreshes"] for k, g in by_age.items()} == {"0": 3, "1": 2}
    assert by_age["1"]["psnr"] == pytest.approx((psnr(8) + psnr(16)) / 2, abs=1e-6)
    # The overall PSNR is that of the mean squared error (as the evaluation's everywhere).
    mse = np.mean([4**2, 8**2, 8**2, 16**2, 32**2])
    assert score["psnr"] == pytest.approx(10 * math.log10(255**2 / mse), abs=1e-6)


def test_score_of_nothing_shown_scores_nothing():
    assert score_shown([], lambda t: [], no_vmaf=True) == {"scored_frames": 0}


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
         r"each end, so at least 0.208 s is needed"),
        ({"score": 5, "display_fps": 240.0}, r"0.1 s is 24 refreshes at 240 FPS.*0.104 s"),
    ],
)
def test_bench_realtime_score_refuses_what_cannot_be_scored(kwargs, message):
    from splitrender.evaluation.bench_realtime import run_realtime_bench

    with pytest.raises(InvalidInputError, match=message):
        run_realtime_bench(seconds=0.1, progress=False, **kwargs)
