"""The real-time client loop (splitrender.client.realtime) with a fake clock: deadlines,
extrapolation while a pair is prepared, recovery after a late frame or a bad packet. No timing
is asserted: the clock only moves when the loop sleeps or a test's client says a frame cost
time."""

from __future__ import annotations

import dataclasses
import gc
import math
import os
import sys
import threading
import time
import weakref
from concurrent.futures import Executor, Future
from typing import Any

import numpy as np
import pytest
import splitrender as sr
import splitrender.client.collector as collector
import splitrender.client.realtime as rt
from splitrender.client import Client
from splitrender.client.realtime import RealtimeClient
from splitrender.codec.coder import StreamDecoder
from splitrender.errors import InvalidInputError, StreamError
from splitrender.machine import this_machine

W, H = 64, 36
FS, FC = 10.0, 120.0
PERIOD = 1.0 / FC


class FakeClock:
    """Time moves only when the loop sleeps or :meth:`advance` is called."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)

    def advance(self, dt: float) -> None:
        self.t += dt


class CostClient(Client):
    """A client whose n-th render takes ``cost(n)`` seconds of the fake clock."""

    def __init__(self, clock: FakeClock, cost: Any, **kw: Any) -> None:
        super().__init__("ours", **kw)
        self.clock, self.cost, self.calls = clock, cost, 0
        self.rendered: list[Any] = []  # (eye, last_info) of each call

    def render(self, camera: sr.Camera, time: float, *, eye: int = 0,
               interpolate: bool = True) -> np.ndarray:
        image = super().render(camera, time, eye=eye, interpolate=interpolate)
        self.clock.advance(self.cost(self.calls))
        self.calls += 1
        self.rendered.append((eye, self.last_info))
        return image


class InlineExecutor(Executor):
    """Runs each job at once on the caller's thread: with the fake clock, receiving then takes
    no time and the order of events is fixed."""

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as e:
            fut.set_exception(e)
        return fut


@pytest.fixture(scope="module")
def scene() -> sr.SyntheticScene:
    return sr.SyntheticScene(dynamic=True)


@pytest.fixture(scope="module")
def frames(scene: sr.SyntheticScene) -> list[sr.ServerFrame]:
    return [scene.server_frame(k, k / FS, W, H, fps=FS) for k in range(4)]


def pose_of(scene: sr.SyntheticScene) -> Any:
    return lambda t: scene.rig(t, W, H)[0]


def eyes_of(scene: sr.SyntheticScene) -> Any:
    return lambda t: scene.rig(t, W, H)[0].stereo()


def loop(
    clock: FakeClock,
    cost: Any = lambda n: 0.002,
    executor: Executor | None = None,
    max_divisor: int = rt.MAX_DIVISOR,
) -> RealtimeClient:
    return RealtimeClient(
        client=CostClient(clock, cost), clock=clock, display_fps=FC, executor=executor,
        max_divisor=max_divisor,
    )


def run_after_receiving(scene: sr.SyntheticScene, frames: list[sr.ServerFrame],
                        seconds: float) -> rt.RealtimeReport:
    """A run of ``seconds`` on the fake clock after every one of ``frames`` was received."""
    clock = FakeClock()
    with loop(clock) as c:
        for f in frames:
            c.submit(f)
            c.wait()
        return c.run(pose_of(scene), seconds)


def test_every_frame_meets_its_deadline_when_rendering_fits_the_period(scene, frames):
    report = run_after_receiving(scene, frames[:3], 0.2)
    assert len(report.frames) == 24 and report.dropped == 0
    assert report.deadline_misses == 0
    # One frame per refresh, each started on its refresh and due at the next.
    assert [f.index for f in report.frames] == list(range(24))
    for f in report.frames:
        assert f.start == pytest.approx(report.frames[0].start + f.index * PERIOD)
        assert f.deadline == pytest.approx(f.start + PERIOD)
        assert f.render_ms == pytest.approx(2.0)
    assert {f.mode for f in report.frames} == {"interpolate"}
    assert all(f.prepared for f in report.frames)


def test_a_run_that_meets_every_deadline_achieves_the_display_rate_exactly(scene, frames):
    # The run's time ended at the last frame's completion, (n - 1) / f_c plus its render
    # time: 24 frames of 2 ms at 120 FPS were 24 / 0.1937 s = 123.9 FPS achieved.
    report = run_after_receiving(scene, frames[:3], 0.2)
    s = report.summary()
    assert s["frames"] == 24 and s["deadline_misses"] == 0
    assert s["wall_s"] == pytest.approx(0.2) and s["achieved_fps"] == pytest.approx(FC)


def test_a_late_frame_is_a_miss_and_the_loop_resumes_on_the_next_free_refresh(scene, frames):
    clock = FakeClock()
    # Frame 3 takes 2.4 periods: it misses its deadline and overruns refreshes 4 and 5.
    with loop(clock, lambda n: 2.4 * PERIOD if n == 3 else 0.001) as c:
        for f in frames[:2]:
            c.submit(f)
        c.wait()
        report = c.run(pose_of(scene), 0.1)
    assert [f.index for f in report.frames] == [0, 1, 2, 3, 6, 7, 8, 9, 10, 11]
    assert [f.met for f in report.frames].count(False) == 1
    assert not report.frames[3].met
    assert report.dropped == 2
    # Back in phase: frame 6 starts on refresh 6, as if nothing had happened.
    assert report.frames[4].start == pytest.approx(report.frames[0].start + 6 * PERIOD)
    s = report.summary()
    assert s["deadline_misses"] == 1 and s["frames"] == 10
    assert s["deadline_misses_pct"] == pytest.approx(10.0)
    # One late frame does not divide the rate.
    assert s["full_rate_pct"] == 100.0 and s["repeated"] == 0


def test_frames_that_do_not_fit_the_refresh_halve_the_rate_and_then_meet_their_deadlines(
    scene, frames
):
    clock = FakeClock()
    # Every frame takes 1.5 refreshes: late at 120 Hz, on time at 60.
    with loop(clock, lambda n: 1.5 * PERIOD) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 0.5)
    down = rt.RateGovernor.DOWN_MISSES
    # The first `down` frames miss (each then starts on the first refresh not yet passed) ...
    assert [f.met for f in list(report.frames)[:down]] == [False] * down
    assert all(f.divisor == 1 for f in list(report.frames)[:down])
    # ... then every frame is at half rate: two refreshes apart, due two refreshes after its
    # start, and on time.
    after = list(report.frames)[down:]
    assert len(after) > 20
    assert all(f.divisor == 2 and f.met for f in after)
    for a, b in zip(after, after[1:]):
        assert b.index == a.index + 2
        assert b.start == pytest.approx(a.start + 2 * PERIOD)
    assert all(f.deadline == pytest.approx(f.start + 2 * PERIOD) for f in after)
    s = report.summary()
    assert s["deadline_misses"] == down
    assert s["frames_by_divisor"] == {"1": down, "2": len(after)}
    # Each half-rate frame is shown twice, except where the run ends after its first refresh.
    assert s["repeated"] in (len(after), len(after) - 1)
    assert s["dropped"] == down  # each late full-rate frame overran one refresh


def test_the_rate_goes_back_up_after_a_second_of_frames_that_fit_the_refresh(scene, frames):
    clock = FakeClock()
    # Slow for the first 12 frames, then a quarter of a refresh.
    with loop(clock, lambda n: 1.5 * PERIOD if n < 12 else 0.25 * PERIOD) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 2.0)
    divisors = [f.divisor for f in report.frames]
    first_half = divisors.index(2)
    back = divisors.index(1, first_half)
    # Halved once, and back at full rate only after a second (60 frames at 60 Hz) of frames
    # that fit; it stays there.
    slow_until = 12 - first_half  # the half-rate frames that were still slow
    assert back - first_half == slow_until + int(FC / 2)
    assert set(divisors[back:]) == {1}
    assert all(f.met for f in list(report.frames)[back:])


def test_a_display_that_fits_no_rate_stays_at_its_lowest(scene, frames):
    clock = FakeClock()
    # 2.5 refreshes: late even at half rate.
    with loop(clock, lambda n: 2.5 * PERIOD) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 0.5)
    assert {f.divisor for f in list(report.frames)[rt.RateGovernor.DOWN_MISSES:]} == {2}
    assert report.deadline_misses == len(report.frames)


def test_max_divisor_one_keeps_the_full_rate(scene, frames):
    clock = FakeClock()
    with loop(clock, lambda n: 1.5 * PERIOD, max_divisor=1) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 0.25)
    assert {f.divisor for f in report.frames} == {1}
    assert report.deadline_misses == len(report.frames)
    assert report.summary()["repeated"] == 0


class ModeCostClient(Client):
    """A client whose interpolated frames take ``interpolate_s`` seconds of the fake clock and
    its other frames ``extrapolate_s``, each times ``slow(clock)`` (the machine's speed)."""

    def __init__(self, clock: FakeClock, interpolate_s: float, extrapolate_s: float,
                 slow: Any = lambda t: 1.0, method: str = "ours") -> None:
        super().__init__(method)
        self.clock, self.slow = clock, slow
        self.cost = {"interpolate": interpolate_s, "extrapolate": extrapolate_s, "hold": 0.0}
        self.rendered: list[Any] = []  # (eye, last_info, interpolate) of each call

    def render(self, camera: sr.Camera, time: float, *, eye: int = 0,
               interpolate: bool = True) -> np.ndarray:
        image = super().render(camera, time, eye=eye, interpolate=interpolate)
        assert self.last_info is not None
        self.clock.advance(self.cost[self.last_info.mode] * self.slow(self.clock.t))
        self.rendered.append((eye, self.last_info, interpolate))
        return image


def mode_cost_run(scene: sr.SyntheticScene, n_frames: int, seconds: float, *,
                  slow: Any = lambda t: 1.0, defer: bool = True, stereo: bool = False,
                  ahead: float = 1.0, method: str = "ours", extrapolation_pairs: bool = True,
                  on_frame: Any = None) -> tuple[rt.RealtimeReport, ModeCostClient]:
    """A run over ``n_frames`` server frames, each received ``ahead`` server periods before its
    time (one: every display frame can interpolate; half: the first half of each pair's
    interval extrapolates), interpolated frames 1.2 refreshes long and extrapolated ones 0.4
    (times ``slow`` of the clock). ``extrapolation_pairs=False``: the worker prepares only the
    interpolation pairs (as it does for a frame it receives behind). ``on_frame``: the run's."""
    clock = FakeClock()
    client = ModeCostClient(clock, 1.2 * PERIOD, 0.4 * PERIOD, slow, method)
    server = [scene.server_frame(k, k / FS, W, H, fps=FS) for k in range(n_frames)]
    before = [f for f in server if f.time - ahead / FS <= 0]
    with RealtimeClient(client=client, clock=clock, display_fps=FC, executor=InlineExecutor(),
                        defer_interpolation=defer) as c:
        if not extrapolation_pairs:
            prepare = c._prepare
            c._prepare = lambda olders, *a: prepare([o for o in olders if o is not None], *a)
        for f in before:
            c.submit(f)
        report = c.run(eyes_of(scene) if stereo else pose_of(scene), seconds, stereo=stereo,
                       feed=[(f.time - ahead / FS, f) for f in server[len(before):]],
                       on_frame=on_frame)
    return report, client


@pytest.mark.parametrize("stereo", [False, True])
def test_interpolation_that_would_miss_its_deadline_is_deferred_to_extrapolation(scene,
                                                                                 stereo):
    # Interpolated frames take 1.2 refreshes, extrapolated ones 0.4 (both eyes: twice that
    # when stereo, where the first misses and the deferral cover the whole frame).
    report, client = mode_cost_run(scene, 4, 0.3, stereo=stereo,
                                   slow=lambda t: 0.5 if stereo else 1.0)
    frames_ = list(report.frames)
    first = rt.ModeGovernor.MIN_FRAMES
    # The first frames interpolate and miss, until their cost is known; then every frame that
    # could interpolate extrapolates from the pair's older frame instead, on time, at the full
    # rate (fewer misses than would halve it).
    assert [(f.mode, f.met, f.deferred) for f in frames_[:first]] == [
        ("interpolate", False, False)] * first
    assert first < rt.RateGovernor.DOWN_MISSES
    rest = frames_[first:]
    assert len(rest) > 20
    assert all(f.mode == "extrapolate" and f.deferred and f.met and f.divisor == 1
               for f in rest)
    # Extrapolated from the frame at or before the display time, as a late pair would be.
    assert all(f.newer == math.floor(f.time * FS + 1e-9) and f.older is None for f in rest)
    s = report.summary()
    assert s["deadline_misses"] == first
    assert s["interpolation_deferred"] == len(rest)
    assert s["modes"] == {"interpolate": first, "extrapolate": len(rest), "hold": 0}
    # Each eye of a deferred stereo frame extrapolates: both were asked not to interpolate.
    eyes = 2 if stereo else 1
    assert len(client.rendered) == eyes * len(frames_)
    for k, f in enumerate(frames_):
        calls = client.rendered[eyes * k: eyes * (k + 1)]
        assert [eye for eye, _, _ in calls] == list(range(eyes))
        assert all(info.mode == f.mode and interpolate != f.deferred
                   for _, info, interpolate in calls)


@pytest.mark.parametrize(("method", "defer", "pairs"), [
    ("ours", False, True), ("backward_bidir", True, True), ("ours", True, False)])
def test_always_interpolating_misses_and_halves_the_rate_instead(scene, method, defer, pairs):
    # Asked to; for backward_bidir, which cannot extrapolate (deferring would hold); and where
    # the older frame's extrapolation pair was not prepared (the display would prepare it: more
    # than the interpolated frame costs).
    report, _ = mode_cost_run(scene, 4, 0.3, defer=defer, method=method,
                              extrapolation_pairs=pairs)
    frames_ = list(report.frames)
    down = rt.RateGovernor.DOWN_MISSES
    assert all(f.mode == "interpolate" and not f.deferred for f in frames_)
    assert [f.met for f in frames_[:down]] == [False] * down
    assert all(f.divisor == 2 and f.met for f in frames_[down:])
    assert report.summary()["interpolation_deferred"] == 0


def test_deferred_interpolation_resumes_once_the_machine_is_fast_enough(scene):
    # Slow (as above) for the first 0.1 s, then 2.5 times faster: an interpolated frame takes
    # 0.48 refreshes. The deferred frames' extrapolation cost, scaled by what interpolating
    # cost against it, says when interpolation fits again: once the slow extrapolated frames
    # are out of the governor's window.
    report, _ = mode_cost_run(scene, 16, 1.5, slow=lambda t: 1.0 if t < 100.1 else 0.4)
    frames_ = list(report.frames)
    deferred = [k for k, f in enumerate(frames_) if f.deferred]
    assert deferred and deferred == list(range(deferred[0], deferred[-1] + 1))
    back = deferred[-1] + 1
    # Deferred through the slow part and until the slow extrapolated frames are too few of
    # those kept to be their quantile (95 %), after which every frame interpolates again and
    # meets its deadline.
    fast_from = next(k for k, f in enumerate(frames_) if f.start >= 100.1)
    slow = fast_from - deferred[0]
    kept = next(n for n in range(slow, rt.ModeGovernor.WINDOW + 1)
                if slow <= n - math.ceil(rt.ModeGovernor.QUANTILE * n))
    assert back - fast_from == kept - slow
    assert all(f.mode == "interpolate" and f.met and not f.deferred for f in frames_[back:])
    assert len(frames_) - back > 30


@pytest.mark.parametrize("defer", [True, False])
def test_the_rate_goes_back_up_where_extrapolating_fits_the_refresh(scene, defer):
    # Each frame arrives half a period before its time: each pair's interval extrapolates for
    # its first half and can interpolate for the second. The first frames are three times
    # slower (misses that halve the rate); then an interpolated frame takes 1.2 refreshes
    # (on time at half rate, late at the full rate) and an extrapolated one 0.4.
    report, _ = mode_cost_run(scene, 32, 3.0, ahead=0.5, defer=defer,
                              slow=lambda t: 3.0 if t < 100.04 else 1.0)
    frames_ = list(report.frames)
    halved = next(k for k, f in enumerate(frames_) if f.divisor == 2)
    assert all(not f.met for f in frames_[:halved])
    if not defer:
        # Interpolated frames of 1.2 refreshes never fit the full rate's headroom: half rate
        # for the rest of the run, every frame on time.
        assert all(f.divisor == 2 and f.met for f in frames_[halved:])
        return
    # Back at the full rate once a second of frames would fit it, the interpolated ones
    # counted as extrapolated; there, interpolation that would miss is deferred and every frame
    # is on time.
    back = next(k for k, f in enumerate(frames_) if k > halved and f.divisor == 1)
    after = frames_[back:]
    assert len(after) > 120
    assert all(f.divisor == 1 and f.met for f in after)
    assert all(f.mode == "extrapolate" for f in after)
    assert sum(f.deferred for f in after) > len(after) / 3


def test_mode_governor_estimates_from_its_quantile_and_the_ratio_of_the_modes():
    g = rt.ModeGovernor()
    assert g.interpolation_s() is None and g.allows(0.0)  # unknown: interpolate
    for _ in range(g.MIN_FRAMES - 1):
        g.record("interpolate", 0.02)
    assert g.interpolation_s() is None and g.allows(0.001)
    g.record("interpolate", 0.02)
    g.record("hold", 1.0)  # not kept
    assert g.interpolation_s() == 0.02
    # The slowest 5 % are above the quantile: one slow frame of 120 does not defer.
    for _ in range(g.WINDOW - 1):
        g.record("interpolate", 0.004)
    g.record("interpolate", 0.02)
    assert g.interpolation_s() == 0.004
    assert g.allows(0.004 / g.HEADROOM) and not g.allows(0.0039 / g.HEADROOM)
    # Deferred: its interpolated frames were let go; with no extrapolated frame kept yet, the
    # estimate stays the one that deferred it until one divides it.
    assert g.interpolation_s() == 0.004 and not g.allows(0.004)
    for _ in range(g.MIN_FRAMES):
        g.record("extrapolate", 0.002)
    assert g.interpolation_s() == pytest.approx(0.004)  # 0.002 times the ratio 2
    for _ in range(g.WINDOW):
        g.record("extrapolate", 0.001)
    assert g.interpolation_s() == pytest.approx(0.002)
    assert g.allows(0.0023)


def test_render_extrapolates_when_told_not_to_interpolate(scene, frames):
    # The caller's own display loop decides: no governor, no condition on the pairs prepared.
    with loop(FakeClock()) as c:
        for f in frames[:2]:
            c.submit(f)
        c.wait()
        cam = scene.rig(0.05, W, H)[0]
        c.render(cam, 0.05)
        assert (c.client.last_info.mode, c.client.last_info.older) == ("interpolate", 0)
        c.render(cam, 0.05, interpolate=False)
        info = c.client.last_info
        assert (info.mode, info.older, info.newer, info.alpha) == ("extrapolate", None, 0, 1.5)
        with pytest.raises(InvalidInputError, match="interpolate: expected a bool"):
            c.render(cam, 0.05, interpolate=0)


def test_bad_defer_interpolation_is_refused():
    with pytest.raises(InvalidInputError, match="defer_interpolation: expected a bool"):
        RealtimeClient(defer_interpolation=1)
    with pytest.raises(InvalidInputError, match="interpolate: expected a bool"):
        Client("ours").render(sr.Camera.look_at((0, 0, 0), (0, 0, -1), width=W, height=H), 0.0,
                              interpolate="no")


def test_a_stereo_frame_is_both_eyes_from_one_pair(scene, frames):
    """A stereo run renders each display frame's left eye, then its right eye, from the same
    server frames at the same α, each with its own previous output (the images a plain client
    gives for eyes 0 and 1), and hands both to on_frame."""
    plain = Client("ours")
    clock = FakeClock()
    shown: list[Any] = []
    with loop(clock, lambda n: 0.003) as c:
        # Frames 0-1 before the run, frame 2 during it: frames before and after a handover.
        for f in frames[:2]:
            plain.receive(f)
            c.submit(f)
            c.wait()
        report = c.run(
            eyes_of(scene), 0.15, stereo=True, feed=[(0.05, frames[2])],
            on_frame=lambda images, record: shown.append((images, record)),
        )
        rendered = c.client.rendered
    assert len(shown) == 18 and len(rendered) == 36
    assert [eye for eye, _ in rendered] == [0, 1] * 18
    pairs = set()
    for (left_info, right_info), ((left, right), record) in zip(
        zip(rendered[::2], rendered[1::2]), shown, strict=True
    ):
        made = [(i.older, i.newer, i.alpha, i.mode) for i in (left_info[1], right_info[1])]
        assert made[0] == made[1]  # the same frames, α and mode
        pairs.add(made[0][:2])
        if 2 in made[0][:2] and 2 not in plain.held:  # handed over as the loop's client had it
            plain.receive(frames[2])
        assert record.eyes == 2
        cams = scene.rig(record.time, W, H)[0].stereo()
        np.testing.assert_array_equal(left, plain.render(cams[0], record.time, eye=0))
        np.testing.assert_array_equal(right, plain.render(cams[1], record.time, eye=1))
        assert not np.array_equal(left, right)
    assert len(pairs) >= 2  # the run went on over the handover of frame 2
    assert report.summary()["eyes"] == 2


@pytest.mark.parametrize(
    ("per_eye_ms", "stereo", "met"), [(5.0, False, True), (3.0, True, True), (5.0, True, False)]
)
def test_a_stereo_frames_time_and_deadline_cover_both_eyes(scene, frames, per_eye_ms, stereo,
                                                          met):
    # An 8.3 ms refresh: one eye of 5 ms fits, two of 3 ms fit, two of 5 ms do not.
    clock = FakeClock()
    with loop(clock, lambda n: per_eye_ms / 1e3, max_divisor=1) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(eyes_of(scene) if stereo else pose_of(scene), 0.1, stereo=stereo)
    eyes = 2 if stereo else 1
    # A late frame overruns one refresh, which is dropped.
    assert len(report.frames) == (12 if met else 6)
    for f in report.frames:
        assert f.eyes == eyes and f.met == met
        assert f.render_ms == pytest.approx(per_eye_ms * eyes)
    assert report.summary()["eyes"] == eyes


@pytest.mark.parametrize(
    ("views", "said"),
    [
        (lambda cam: cam, "got Camera"),
        (lambda cam: (cam,), r"got a tuple of 1: \(Camera\)"),
        (lambda cam: [cam, cam, cam], r"got a list of 3: \(Camera, Camera, Camera\)"),
        (lambda cam: (cam, "right"), r"got a tuple of 2: \(Camera, str\)"),
    ],
)
def test_a_stereo_pose_that_is_not_two_cameras_is_refused(scene, frames, views, said):
    with loop(FakeClock()) as c:
        c.submit(frames[0])
        c.wait()
        with pytest.raises(InvalidInputError, match=r"pose\(0\): with stereo=True expected a "
                                                    r"pair \(left, right\) of Camera, " + said):
            c.run(lambda t: views(scene.rig(t, W, H)[0]), 0.05, stereo=True)
        # A mono run of the same client still works.
        assert c.run(pose_of(scene), 0.05).deadline_misses == 0


@pytest.mark.parametrize("divisor", [0, -1, 17, 1.5, "2", None])
def test_bad_max_divisor_is_refused(divisor):
    with pytest.raises(InvalidInputError, match="max_divisor"):
        RealtimeClient(max_divisor=divisor)
    with pytest.raises(InvalidInputError, match="max_divisor"):
        rt.RateGovernor(FC, divisor)


@pytest.mark.parametrize("fps", [0, -1.0, float("nan"), float("inf"), "120", None])
def test_rate_governor_refuses_a_bad_display_rate(fps):
    with pytest.raises(InvalidInputError, match="display_fps"):
        rt.RateGovernor(fps)


def test_rate_governor_goes_back_up_only_with_headroom_below():
    # At half rate, frames that would just fit the full rate's refresh (80 % of it) keep the
    # half rate; frames within HEADROOM (70 %) of it bring the full rate back after a second
    # of them (f_c / 2 frames), and not before.
    assert rt.RateGovernor.HEADROOM == 0.75
    for share, back_after in [(0.8, None), (0.7, math.ceil(FC / 2))]:
        g = rt.RateGovernor(FC)
        for _ in range(rt.RateGovernor.DOWN_MISSES):
            g.update(2.0 / FC, met=False)
        assert g.divisor == 2
        divisors = [g.update(share / FC, met=True) for _ in range(3 * int(FC))]
        if back_after is None:
            assert set(divisors) == {2}
        else:
            assert divisors.index(1) == back_after - 1 and set(divisors[back_after:]) == {1}


def test_rate_governor_counts_the_misses_of_each_divisor_afresh():
    # The misses that halved the rate do not count at the new divisor: dividing it again
    # takes DOWN_MISSES misses there.
    down = rt.RateGovernor.DOWN_MISSES
    g = rt.RateGovernor(FC, max_divisor=4)
    for _ in range(down):
        g.update(2.0 / FC, met=False)
    assert g.divisor == 2
    assert [g.update(3.0 / FC, met=m) for m in [True] + [False] * (down - 1)] == [2] * down
    assert g.update(3.0 / FC, met=False) == 3


def _hold_preparation(monkeypatch, held):  # type: ignore[no-untyped-def]
    """Makes the worker's preparation of each pair ``(older index or None, newer index)`` for
    which ``held`` is true wait until ``release`` is set (``entered`` is set when it starts);
    ``order`` lists the pairs prepared. Returns ``(entered, release, order)``."""
    release = threading.Event()
    entered = threading.Event()
    real = rt.prepare_pair
    order = []

    def slow_prepare(older, newer, *a, **kw):  # type: ignore[no-untyped-def]
        pair = (None if older is None else older.index, newer.index)
        order.append(pair)
        if held(pair):
            entered.set()
            assert release.wait(10.0)
        return real(older, newer, *a, **kw)

    monkeypatch.setattr(rt, "prepare_pair", slow_prepare)
    return entered, release, order


def _submit_until_held(c: RealtimeClient, frames: list[Any], entered: threading.Event) -> None:
    """Frame 0 received, then frame 1 submitted until its held preparation has started."""
    c.submit(frames[0])
    c.wait()
    c.submit(frames[1])
    assert entered.wait(10.0)


def test_close_dropping_the_backlog_cancels_what_was_not_received(scene, frames, monkeypatch):
    """A live session ends with close(drop_pending=True): a server that sent faster than its
    rate had the command decode the whole backlog first (minutes past --seconds)."""
    entered, release, _ = _hold_preparation(monkeypatch, lambda pair: pair[1] == 1)
    c = loop(FakeClock())
    c.submit(frames[0]).result(30)
    busy = c.submit(frames[1])
    assert entered.wait(10.0)
    backlog = [c.submit(f) for f in frames[2:]]
    threading.Timer(0.2, release.set).start()
    c.close(drop_pending=True)
    assert busy.result(0) == 1  # the one being received finishes
    assert backlog and all(f.cancelled() for f in backlog)


def test_a_client_that_never_waits_keeps_only_the_first_error(scene, frames):
    """A live session submits for hours and never waits: every future was kept (a failed one
    holds its packet). Done ones are let go, but for the first error, which wait() raises."""
    with loop(FakeClock(), executor=InlineExecutor()) as c:
        bad = c.submit(b"not a packet")
        for _ in range(3 * rt._PRUNE_PENDING):
            c.submit(b"nor this")
        assert len(c._pending) <= rt._PRUNE_PENDING + 1 and c._pending[0] is bad
        with pytest.raises(StreamError):
            c.wait()


def test_wait_times_out_for_the_whole_wait_and_leaves_the_rest_to_the_next(scene, frames):
    """wait(timeout) dropped the packets it had not waited for when one timed out (a second
    wait returned at once, nothing received), and gave each packet the whole timeout; after an
    error, the packets behind it were dropped the same way."""
    from concurrent.futures import ThreadPoolExecutor

    gate = threading.Event()
    worker = ThreadPoolExecutor(1)
    worker.submit(gate.wait, 10.0)  # the receive jobs queue behind it
    with loop(FakeClock(), executor=worker) as c:
        futs = [c.submit(frames[0]), c.submit(b"not a packet"), c.submit(frames[1])]
        with pytest.raises(TimeoutError):
            c.wait(0.05)
        with pytest.raises(TimeoutError):
            c.wait(0.05)  # still waiting for the same three
        gate.set()
        with pytest.raises(StreamError):
            c.wait()
        assert futs[0].result() == 0
        c.wait()  # the frame behind the error
        assert futs[2].done() and futs[2].result() == 1 and c._pending == []


class SlowFuture(Future):  # type: ignore[type-arg]
    """A packet's future that is ready after ``takes`` seconds of waiting on ``clock`` (which
    stands in for the monotonic clock of :meth:`RealtimeClient.wait`); records each timeout it
    was given."""

    def __init__(self, clock: FakeClock, takes: float, value: Any) -> None:
        super().__init__()
        self.clock, self.takes, self.value, self.timeouts = clock, takes, value, []

    def result(self, timeout: float | None = None) -> Any:
        self.timeouts.append(timeout)
        if timeout is not None and self.takes > timeout:
            self.clock.advance(timeout)
            self.takes -= timeout
            raise TimeoutError
        self.clock.advance(self.takes)
        self.takes = 0.0
        if not self.done():
            self.set_result(self.value)
        return super().result(0)


class SlowExecutor(Executor):
    """Receives each packet at once and hands back a :class:`SlowFuture` taking ``takes``."""

    def __init__(self, clock: FakeClock, takes: float) -> None:
        self.clock, self.takes, self.futures = clock, takes, []

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        fut = SlowFuture(self.clock, self.takes, fn(*args, **kwargs))
        self.futures.append(fut)
        return fut


def test_wait_timeout_is_one_deadline_for_all_the_packets(scene, frames, monkeypatch):
    """wait(timeout) gives the whole wait one deadline on the monotonic clock: each packet gets
    what is left of it, and the packet that runs past it is waited for again by the next wait
    (with a timeout of its own per packet, three packets of 30 ms fitted a 50 ms wait)."""
    clock = FakeClock()
    fake_time = type("FakeTime", (), {
        "monotonic": staticmethod(clock.now),
        "__getattr__": lambda self, name: getattr(time, name)})()
    monkeypatch.setattr(rt, "time", fake_time)
    slow = SlowExecutor(clock, 0.03)
    with RealtimeClient(client=CostClient(clock, lambda n: 0.0), clock=clock,
                        executor=slow) as c:
        for f in frames[:3]:
            c.submit(f)
        first, second, third = slow.futures
        with pytest.raises(TimeoutError):
            c.wait(0.05)
        assert first.timeouts == [pytest.approx(0.05)]
        assert second.timeouts == [pytest.approx(0.02)] and third.timeouts == []
        assert clock.now() == pytest.approx(100.05)
        # The next wait starts with the packet that timed out: 10 ms left of it, then 30 ms of
        # the third within the 40 ms left of the new deadline.
        c.wait(0.05)
        assert first.timeouts == [pytest.approx(0.05)]
        assert second.timeouts == [pytest.approx(0.02), pytest.approx(0.05)]
        assert third.timeouts == [pytest.approx(0.04)]
        assert clock.now() == pytest.approx(100.09)
        assert c._pending == []


def test_display_extrapolates_while_the_new_pair_is_prepared(scene, frames, monkeypatch):
    entered, release, _ = _hold_preparation(monkeypatch, lambda pair: pair[1] == 1)
    clock = FakeClock()
    with loop(clock) as c:
        _submit_until_held(c, frames, entered)
        # Frame 1 is decoded but its pair is still being prepared: not usable yet.
        first = c.run(pose_of(scene), 0.05)
        assert {(f.mode, f.newer) for f in first.frames} == {("extrapolate", 0)}
        assert all(f.met for f in first.frames)
        release.set()
        c.wait()
        later = c.run(pose_of(scene), 0.04, start_time=0.05).frames
    assert {(f.mode, f.older, f.newer) for f in later} == {("interpolate", 0, 1)}
    assert all(f.prepared for f in later)


def test_a_frame_interpolates_once_its_pair_is_prepared_before_its_extrapolation_pair(
    scene, frames, monkeypatch
):
    # The pair (0, 1) is what frame 1 is first needed for; (None, 1) only if frame 2 is late.
    entered, release, order = _hold_preparation(monkeypatch, lambda pair: pair == (None, 1))
    clock = FakeClock()
    with loop(clock) as c:
        _submit_until_held(c, frames, entered)
        # Frame 1 is usable with its interpolation pair while (None, 1) is being prepared.
        during = c.run(pose_of(scene), 0.05).frames
        assert {(f.mode, f.older, f.newer) for f in during} == {("interpolate", 0, 1)}
        assert all(f.prepared for f in during)
        assert not c.client.was_prepared(None, 1)
        release.set()
        c.wait()
        assert c.client.was_prepared(None, 1)
        # Past frame 1's time with frame 2 not there: extrapolated from the prepared pair.
        after = c.run(pose_of(scene), 0.02, start_time=0.11).frames
    assert {(f.mode, f.newer) for f in after} == {("extrapolate", 1)}
    assert all(f.prepared for f in after)
    assert order == [(None, 0), (0, 1), (None, 1)]


def test_exclusive_run_waits_for_the_worker_off_the_clock(scene, frames, monkeypatch):
    # Each preparation "takes" 30 ms of the fake clock, on the worker's thread.
    clock = FakeClock()
    real = rt.prepare_pair

    def slow_prepare(*a, **kw):  # type: ignore[no-untyped-def]
        clock.advance(0.03)
        return real(*a, **kw)

    monkeypatch.setattr(rt, "prepare_pair", slow_prepare)
    feed = [(k / FS - 1 / FS, frames[k]) for k in range(3)]
    with loop(clock) as c:
        report = c.run(pose_of(scene), 0.2, feed=feed, exclusive=True)
    f = list(report.frames)
    assert len(f) == 24 and report.deadline_misses == 0 and report.dropped == 0
    # Frames 0 and 1 arrived before refresh 0, frame 2 at refresh 12 (display time 0.1).
    assert {(x.mode, x.older, x.newer) for x in f[:12]} == {("interpolate", 0, 1)}
    assert {(x.mode, x.older, x.newer) for x in f[12:]} == {("interpolate", 1, 2)}
    assert all(x.prepared for x in f)
    # The refreshes after frame 2's arrival moved on by its two preparations (60 ms).
    assert f[12].start - f[11].start == pytest.approx(PERIOD + 0.06)
    assert f[13].start - f[12].start == pytest.approx(PERIOD)
    assert report.server_frames_late == 0


def test_prepared_pairs_give_the_same_images_and_no_pair_work_on_the_display(scene, frames):
    plain = Client("ours")
    clock = FakeClock()
    with loop(clock) as c:
        for f in frames[:3]:
            plain.receive(f)
            c.submit(f)
            c.wait()
        histories = dict(c.client._prepared)
        for n in range(1, 24):
            t = n / FC
            cam = scene.rig(t, W, H)[0]
            np.testing.assert_array_equal(c.render(cam, t), plain.render(cam, t))
            assert c.client.was_prepared(c.client.last_info.older, c.client.last_info.newer)
    # Each prepared pair was computed once, on the worker, and never again by a client frame.
    assert histories and all(h.pair_builds == 1 for h in histories.values())
    assert (0, 1) in histories and (None, 2) in histories


@pytest.mark.parametrize("bad", ["refused", "singular"])
def test_a_display_camera_the_client_refused_or_could_not_use_loses_no_server_frame(
        scene, frames, bad):
    """The worker prepares each pair with the frame's own camera (the pair's work does not
    depend on the display's): a camera the display refused, or a singular one it accepted while
    nothing was held (black), does not make every later frame's preparation fail."""
    camera = scene.rig(0.0, W, H)[0]
    with loop(FakeClock()) as c:
        if bad == "refused":
            with pytest.raises(InvalidInputError, match="camera: expected Camera, got str"):
                c.render("not a camera", 0.0)  # type: ignore[arg-type]
        else:
            singular = sr.Camera(camera.view, np.zeros((4, 4)), W, H)
            assert not c.render(singular, 0.0).any()
        for f in frames[:2]:
            assert c.submit(f).result(30) == f.index
        assert c.client.held == (0, 1)
        assert c.render(camera, 0.05).any()


def test_a_closed_client_renders_no_more(scene, frames):
    c = loop(FakeClock())
    c.close()
    with pytest.raises(InvalidInputError, match="the client is closed"):
        c.render(scene.rig(0.0, W, H)[0], 0.0)


def test_frames_of_a_longer_span_pair_with_each_other_and_are_prepared(scene):
    # A live server that keeps only f_s / 2 renders every 2nd frame with motion spanning two
    # periods (ServerFrame.span 2): frames 0 and 2 form the pair, prepared on the worker.
    spanned = [
        dataclasses.replace(scene.server_frame(k, k / FS, W, H, fps=FS / 2), span=2)
        for k in (0, 2)
    ]
    plain = Client("ours")
    clock = FakeClock()
    with loop(clock) as c:
        for f in spanned:
            plain.receive(f)
            c.submit(f)
            c.wait()
        assert (0, 2) in c.client._prepared
        for n in range(1, 2 * round(FC / FS)):
            t = n / FC
            cam = scene.rig(t, W, H)[0]
            np.testing.assert_array_equal(c.render(cam, t), plain.render(cam, t))
            info = c.client.last_info
            assert (info.mode, info.older, info.newer) == ("interpolate", 0, 2)
            assert info.alpha == pytest.approx(t * FS / 2)
            assert c.client.was_prepared(0, 2)


def test_packets_are_decoded_on_the_worker_and_a_bad_one_is_skipped(scene, frames):
    from splitrender.codec.coder import CodecConfig, StreamEncoder

    with StreamEncoder(CodecConfig(bitrate_mbps=2.0)) as enc:
        packets = [enc.encode(f) for f in frames[:3]]
    clock = FakeClock()
    with loop(clock) as c:
        feed = [(0.0 - 1 / FS, packets[0]), (0.0, b"not a packet"), (0.0, packets[1])]
        c.submit(feed[0][1]).result(30)
        bad = c.submit(feed[1][1])
        good = c.submit(feed[2][1])
        with pytest.raises(StreamError):
            bad.result(30)
        assert good.result(30) == 1
        with pytest.raises(StreamError):
            c.wait()
        report = c.run(pose_of(scene), 0.05)
    s = report.summary()
    assert s["server_frames_received"] == 2 and len(report.decode_ms) == 2
    assert s["decode_ms_per_server_frame"] > 0
    assert {f.mode for f in report.frames} == {"interpolate"}


def test_a_server_frame_that_becomes_usable_after_it_was_needed_counts_as_late(scene, frames):
    clock = FakeClock()
    with loop(clock, executor=InlineExecutor()) as c:
        # Frame 0 before the run, frame 1 arriving mid-way through its pair's interval.
        feed = [(-0.1, frames[0]), (0.05, frames[1])]
        report = c.run(pose_of(scene), 0.1, feed=feed)
    s = report.summary()
    assert s["server_frames_received"] == 2
    assert s["server_frames_late"] == 1
    assert report.frames[0].mode == "extrapolate"
    # The age of the newest frame: display time minus its pose time (its time minus 1/f_s).
    assert report.frames[0].server_age_ms == pytest.approx(100.0)


def test_on_handover_tells_each_frame_handed_over_and_the_late_decision(scene, frames):
    clock = FakeClock()
    told: list[rt.Handover] = []
    with RealtimeClient(client=CostClient(clock, lambda n: 0.002), clock=clock,
                        display_fps=FC, executor=InlineExecutor(), on_handover=told.append) as c:
        # Frame 0 before the run, frame 1 at 0.05 s (after the display first needed it, at 0),
        # frame 2 at 0.07 s (before it is needed, at 0.1).
        feed = [(-0.1, frames[0]), (0.05, frames[1]), (0.07, frames[2])]
        report = c.run(pose_of(scene), 0.15, feed=feed)
        # Outside run() nothing is handed over through the callback.
        c.submit(frames[3]).result(30)
        c.render(pose_of(scene)(0.35), 0.35)
    assert [(h.index, h.time, h.late) for h in told] == [
        (0, 0.0, False), (1, 0.1, True), (2, 0.2, False)]
    assert sum(h.late for h in told) == report.server_frames_late == 1
    # Each at the display time it was handed over: frame 0 at the run's start, frames 1 and 2
    # at the first refresh after they arrived.
    assert told[0].display_time == pytest.approx(0.0)
    for h, arrived in zip(told[1:], (0.05, 0.07)):
        assert arrived - 1e-9 <= h.display_time < arrived + PERIOD + 1e-9


def test_an_exception_in_on_handover_is_the_packets_after_the_handover(scene, frames):
    clock = FakeClock()

    def fail(h: rt.Handover) -> None:
        raise RuntimeError(f"callback failed on frame {h.index}")

    with RealtimeClient(client=CostClient(clock, lambda n: 0.002), clock=clock,
                        display_fps=FC, executor=InlineExecutor(), on_handover=fail) as c:
        report = c.run(pose_of(scene), 0.05, feed=[(0.0, frames[0])])
        # Handed over on the worker: the packet's error, which wait() raises; the frame was
        # handed over all the same and the display used it.
        with pytest.raises(RuntimeError, match="frame 0"):
            c.wait()
        assert c.client.held == (0,)
    assert report.server_frames_received == 1
    assert {f.mode for f in list(report.frames)[1:]} == {"extrapolate"}


def text_report(summary: dict[str, Any]) -> str:
    """The bench's text report (``format_realtime``) of a run with ``summary``."""
    from splitrender.evaluation.bench_realtime import RealtimeBench, format_realtime

    return format_realtime(
        RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", summary)
    )


def test_the_text_report_names_the_preparation_threads_on_the_cpu_only() -> None:
    from splitrender.evaluation.bench_realtime import RealtimeBench, format_realtime

    report = rt.RealtimeReport(display_fps=120.0)
    report.add(rt.DisplayFrame(
        index=0, time=0.0, start=0.0, done=0.004, deadline=1 / 120, mode="extrapolate",
        older=None, newer=0, alpha=None, server_age_ms=None, prepared=True))
    s = report.summary()
    cpu = format_realtime(RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", s,
                                        prepare_threads=2))
    assert "pair preparation" in cpu and "preparing on 2 threads" in cpu
    # The GPU backend uploads each pair: no preparation pool, none recorded or named.
    gpu = format_realtime(RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", s,
                                        backend="wgpu", prepare_threads=None))
    assert "pair upload" in gpu and "preparing on" not in gpu
    # A run that lost its GPU device says so (test_wgpu: the loss itself), and one that did not
    # says nothing of it.
    assert s["gpu_lost"] is None and "device was lost" not in gpu
    report.gpu_lost = "Destroyed"
    lost = format_realtime(RealtimeBench("ours", "test", W, H, False, False, "idle", "normal",
                                         report.summary(), backend="wgpu"))
    assert lost.splitlines()[-1] == (
        "  the GPU device was lost (Destroyed): the display went on on the CPU from then on "
        "(the figures mix the two backends)")


def test_the_text_report_names_the_machine_second() -> None:
    from splitrender.evaluation.bench_realtime import RealtimeBench, format_realtime

    report = rt.RealtimeReport(display_fps=120.0)
    report.add(rt.DisplayFrame(
        index=0, time=0.0, start=0.0, done=0.004, deadline=1 / 120, mode="extrapolate",
        older=None, newer=0, alpha=None, server_age_ms=None, prepared=True))
    b = RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", report.summary(),
                      processor="AMD EPYC (family 25, model 17)", cpus=2, simd="avx512")
    assert format_realtime(b).splitlines()[1] == (
        "  machine: AMD EPYC (family 25, model 17), 2 CPUs, CPU row loops AVX-512")
    assert b.to_json()["processor"] == "AMD EPYC (family 25, model 17)"
    assert (b.to_json()["cpus"], b.to_json()["simd"]) == (2, "avx512")
    # One made without its machine has no such line.
    bare = dataclasses.replace(b, processor="", cpus=0, simd="")
    assert "machine:" not in format_realtime(bare)


def test_a_run_records_the_share_of_cpu_time_the_host_took(scene, frames, monkeypatch) -> None:
    """The machine's CPU times are read as the clock starts and after the last frame: the
    host's share of the interval is the summary's ``host_steal_pct`` and the text says it."""
    from splitrender.machine import CpuTimes

    readings = iter([CpuTimes(10_000, 500), CpuTimes(12_000, 1_000)])
    monkeypatch.setattr(rt, "cpu_times", lambda: next(readings))
    clock = FakeClock()
    with loop(clock) as c:
        c.submit(frames[0])
        c.wait()
        s = c.run(pose_of(scene), 0.02).summary()
    assert next(readings, None) is None  # both read, no more
    assert s["host_steal_pct"] == pytest.approx(25.0)
    text = text_report(s)
    assert "; the host took 25.0 % of the machine's CPU time (steal)" in text
    assert "  note: the virtual machine's host took 5 % or more of the CPU time while the " \
        "display ran (steal)" in text
    # Where the platform does not count it: None, and the text says nothing of it.
    monkeypatch.setattr(rt, "cpu_times", lambda: None)
    with loop(FakeClock()) as c:
        c.submit(frames[0])
        c.wait()
        s = c.run(pose_of(scene), 0.02).summary()
    assert s["host_steal_pct"] is None and "steal" not in text_report(s)


def test_the_api_refuses_preparation_threads_for_the_gpu_backend(monkeypatch) -> None:
    from splitrender.evaluation import bench_realtime

    # Refused before the backend is looked for or anything rendered: no GPU is needed to see it.
    def no_backend(*_: Any) -> None:
        raise AssertionError("the backend was looked for before the arguments were checked")

    monkeypatch.setattr(bench_realtime, "require_backend", no_backend)
    with pytest.raises(InvalidInputError, match="--prepare-threads goes with --backend cpu"):
        bench_realtime.run_realtime_bench(seconds=0.1, backend="wgpu", prepare_threads=2)


def _every_frame(scene: Any, n: int) -> list[Any]:
    """Server frames 0 … n − 1 of ``scene``, a server period apart."""
    return [scene.server_frame(k, k / FS, W, H, fps=FS) for k in range(n)]


def test_the_client_keeps_no_state_for_the_frames_it_has_dropped(scene):
    """A headset runs for hours: what the loop keeps per server frame goes with the frame."""
    many = _every_frame(scene, 11)
    clock = FakeClock()
    with loop(clock, executor=InlineExecutor()) as c:
        feed = [(f.time - 1 / FS, f) for f in many]
        report = c.run(pose_of(scene), 1.0, feed=feed)
        held = c.client.held
        kept = set(c._pose_time)
    assert report.server_frames_received == 11 and report.server_frames_late == 0
    assert 0 < len(held) < 11 and kept == set(held)


def test_a_worker_that_is_behind_hands_frames_over_without_preparing_them(scene, frames):
    from concurrent.futures import ThreadPoolExecutor

    gate = threading.Event()
    worker = ThreadPoolExecutor(1)
    worker.submit(gate.wait, 10.0)  # holds the worker until every frame is queued
    with RealtimeClient(client=CostClient(FakeClock(), lambda n: 0.0), executor=worker) as c:
        for f in frames[:3]:
            c.submit(f)
        gate.set()
        c.wait(30.0)
        assert c.client.held == (0, 1, 2)
        # Frames 0 and 1 had a newer frame waiting behind them; frame 2 did not.
        assert not c.client.was_prepared(0, 1) and not c.client.was_prepared(None, 1)
        assert c.client.was_prepared(1, 2) and c.client.was_prepared(None, 2)


def _clocked_preparation(  # type: ignore[no-untyped-def]
    monkeypatch, clock, pair_s, extrapolation_s
):
    """Makes each preparation take ``pair_s`` (an interpolation pair) or ``extrapolation_s``
    (``(None, k)``) seconds of the fake clock; returns the list of pairs prepared."""
    real = rt.prepare_pair
    order = []

    def slow_prepare(older, newer, *a, **kw):  # type: ignore[no-untyped-def]
        order.append((None if older is None else older.index, newer.index))
        clock.advance(extrapolation_s if older is None else pair_s)
        return real(older, newer, *a, **kw)

    monkeypatch.setattr(rt, "prepare_pair", slow_prepare)
    return order


def test_a_pair_that_would_be_ready_too_late_is_skipped_and_its_frame_used_from_its_time(
    scene, frames, monkeypatch
):
    # An interpolation pair takes 150 ms, longer than its 100 ms interval; frames arrive when
    # their pair's interval starts (as splitrender bench --realtime sends them).
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.15, 0.01)
    feed = [(k / FS - 1 / FS, frames[k]) for k in range(4)]
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.35, feed=feed)
        # The first pair was prepared (nothing to estimate from) and ready too late to be
        # shown; the next frames' pairs were not prepared, only their extrapolations.
        assert order[:3] == [(None, 0), (0, 1), (None, 1)]
        assert (1, 2) not in order and (2, 3) not in order
        assert c.client.held == (3,) and c.client.was_prepared(None, 3)
    f = [x for x in report.frames if x.mode != "hold"]
    assert report.pairs_skipped == 2 and report.summary()["pairs_skipped"] == 2
    # Frame 2 was usable from display time 0.2 on, not before (where the display would have
    # interpolated towards it and done the pair's work itself), and every frame rendered a
    # pair prepared on the worker.
    assert all(x.newer != 2 for x in f if x.time < 0.2 - 1e-9)
    assert all(x.newer == 2 and x.mode == "extrapolate" for x in f if 0.2 <= x.time < 0.3)
    assert all(x.prepared for x in f)


def test_a_skipped_pair_is_measured_again_and_interpolation_comes_back(scene, monkeypatch):
    # The first interpolation pair takes 150 ms (slow by itself: start-up, say), the later ones
    # 20 ms. The estimate from the first skips the next pairs; after PAIR_PROBE_AFTER skipped
    # in a row one is prepared to measure it, fits, and every later pair is prepared again.
    many = _every_frame(scene, 8)
    monkeypatch.setattr(rt, "PAIR_PROBE_AFTER", 2)
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.02, 0.01)
    real = rt.prepare_pair

    def first_slow(older, newer, *a, **kw):  # type: ignore[no-untyped-def]
        if (None if older is None else older.index, newer.index) == (0, 1):
            clock.advance(0.13)
        return real(older, newer, *a, **kw)

    monkeypatch.setattr(rt, "prepare_pair", first_slow)
    feed = [(k / FS - 1 / FS, many[k]) for k in range(8)]
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.75, feed=feed)
    assert [p for p in order if p[0] is not None] == [(0, 1), (3, 4), (4, 5), (5, 6), (6, 7)]
    assert report.pairs_skipped == 2 and report.pairs_probed == 1
    s = report.summary()
    assert (s["pairs_skipped"], s["pairs_probed"]) == (2, 1)
    text = text_report(s)
    assert "2 without their interpolation pair" in text
    assert "1 such pair prepared anyway to measure it again" in text
    modes = {(x.mode, x.older, x.newer) for x in report.frames}
    assert {("interpolate", 4, 5), ("interpolate", 5, 6)} <= modes


def test_a_pair_measured_again_and_still_too_late_waits_twice_as_long(scene, monkeypatch):
    # Every interpolation pair takes 150 ms: measured after 2 skipped, then after 4.
    many = _every_frame(scene, 10)
    monkeypatch.setattr(rt, "PAIR_PROBE_AFTER", 2)
    monkeypatch.setattr(rt, "PAIR_PROBE_MAX", 4)
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.15, 0.01)
    feed = [(k / FS - 1 / FS, many[k]) for k in range(10)]
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.95, feed=feed)
    assert [p for p in order if p[0] is not None] == [(0, 1), (3, 4), (8, 9)]
    assert report.pairs_skipped == 6 and report.pairs_probed == 2


def test_a_pair_that_is_ready_in_time_is_prepared(scene, frames, monkeypatch):
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.03, 0.01)
    feed = [(k / FS - 1 / FS, frames[k]) for k in range(4)]
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.35, feed=feed)
    assert report.pairs_skipped == 0
    assert [p for p in order if p[0] is not None] == [(0, 1), (1, 2), (2, 3)]
    modes = {(x.mode, x.older, x.newer) for x in report.frames if x.time < 0.3}
    assert modes >= {("interpolate", 1, 2), ("interpolate", 2, 3)}


def test_a_frame_due_later_whose_time_contradicts_the_held_frames_is_dropped(
    scene, frames, monkeypatch
):
    # Frame 2 claims a time just before frame 1's, and its pair would be late (80 ms from
    # display time 0.08), so it waits for its time, 0.099. The client refuses it there, on the
    # display thread: the run goes on without it.
    clock = FakeClock()
    _clocked_preparation(monkeypatch, clock, 0.08, 0.0)
    bad = dataclasses.replace(frames[2], time=0.099)
    feed = [(-0.1, frames[0]), (0.0, frames[1]), (0.0, bad)]
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.2, feed=feed)
        assert 2 not in c.client.held
    assert report.pairs_skipped == 1 and report.server_frames_received == 2
    assert all(f.newer != 2 for f in report.frames)


class ClockedDecoder(StreamDecoder):
    """Decodes packet ``b"k"`` into ``frames[k]`` in ``decode_s[k]`` seconds of the fake
    clock."""

    def __init__(self, clock: FakeClock, frames: list[Any], decode_s: list[float]) -> None:
        super().__init__()
        self.clock, self.frames, self.decode_s = clock, frames, decode_s

    def decode(self, data: bytes | memoryview) -> Any:
        k = int(bytes(data))
        self.clock.advance(self.decode_s[k])
        return self.frames[k]


def test_the_pair_estimate_follows_the_decode_time(scene, frames, monkeypatch):
    # A 20 ms pair after a 10 ms decode fits its interval; the same pair after a 40 ms decode
    # (the worker four times slower: the display took more of the cores) is estimated at
    # 80 ms, which would leave less than a quarter of the interval, and skipped. Taken as
    # measured (20 ms), it would have been prepared.
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.02, 0.0)
    decoder = ClockedDecoder(clock, frames, [0.01, 0.01, 0.01, 0.04])
    feed = [(k / FS - 1 / FS, str(k).encode()) for k in range(4)]
    with RealtimeClient(
        client=CostClient(clock, lambda n: 0.001), clock=clock, display_fps=FC,
        executor=InlineExecutor(), decoder=decoder,
    ) as c:
        report = c.run(pose_of(scene), 0.35, feed=feed)
    assert [p for p in order if p[0] is not None] == [(0, 1), (1, 2)]
    assert report.pairs_skipped == 1


def test_no_pair_is_skipped_outside_a_run(scene, frames, monkeypatch):
    # A caller with its own display loop (render) gives the worker no display clock: every
    # pair is prepared whatever it costs.
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.5, 0.01)
    with loop(clock, executor=InlineExecutor()) as c:
        for f in frames:
            c.submit(f)
        assert c.client.held == (0, 1, 2, 3)
    assert [p for p in order if p[0] is not None] == [(0, 1), (1, 2), (2, 3)]


def test_summary_has_the_keys_the_bench_reports(scene, frames):
    clock = FakeClock()
    with loop(clock) as c:
        c.submit(frames[0])
        c.wait()
        s = c.run(pose_of(scene), 0.02).summary()
    for key in (
        "frames",
        "deadline_misses",
        "frame_ms_p50",
        "frame_ms_p95",
        "frame_ms_p99",
        "frame_ms_max",
        "decode_ms_per_server_frame",
        "prepare_ms_per_server_frame",
        "usable_ms_per_server_frame",
        "cpu_utilisation",
        "host_steal_pct",
        "modes",
        "display_scheduling",
        "warm_up_ms",
        "warm_up_seed_ms",
        "full_rate_pct",
        "frames_by_divisor",
        "repeated",
        "pairs_skipped",
        "pairs_probed",
        "deadline_misses_by_cause",
        "frame_cpu_ms_p50",
        "frame_cpu_ms_max",
        "gc_between_frames",
        "gc_collections",
        "gc_forced",
        "gc_ms_max",
    ):
        assert key in s
    assert s["decode_ms_per_server_frame"] is None  # frames handed over decoded


def test_frames_record_their_refresh_and_the_display_threads_cpu(scene, frames):
    report = run_after_receiving(scene, frames[:2], 0.1)
    for f in report.frames:
        # The refresh each started on: the deadline is the next one.
        assert f.refresh == pytest.approx(f.deadline - PERIOD)
        assert f.start_delay_ms == pytest.approx(0.0, abs=1e-6)
    cpu = [f.cpu_ms for f in report.frames]
    if not sys.platform.startswith("linux"):
        assert cpu == [None] * len(cpu)
        return
    # Real CPU time (the fake clock moves only the wall time): every frame renders, on the
    # display thread or the render threads, so each used some, and none more than the whole
    # process did meanwhile.
    assert all(c is not None and c > 0.0 for c in cpu)
    assert sum(cpu) <= 1e3 * report.cpu_s + 1.0
    assert report.summary()["frame_cpu_ms_p50"] == pytest.approx(float(np.median(cpu)))


def test_misses_are_put_down_to_a_late_start_more_cpu_or_waiting():
    from splitrender.client.realtime import DisplayFrame, RealtimeReport

    report = RealtimeReport(display_fps=FC)
    # (mode, ms from the refresh to the start, render ms, CPU ms): medians of CPU 7 ms
    # (interpolate) and 4 ms (extrapolate).
    plan = [("interpolate", 0.2, 3.5, 7.0)] * 20 + [("extrapolate", 0.2, 2.0, 4.0)] * 20 + [
        ("interpolate", 2.0, 7.0, 7.0),  # late start
        ("interpolate", 3.0, 6.0, 20.0),  # late start, though it used more CPU too
        ("interpolate", 0.2, 9.0, 14.0),  # twice the median CPU
        ("extrapolate", 0.2, 9.0, 6.5),  # 1.6x its own mode's median (below interpolate's)
        ("interpolate", 0.2, 9.0, 9.0),  # 1.3x the median: the threads waited
        ("interpolate", 0.9, 8.0, 7.0),  # started within LATE_START_MS: waited
    ]
    for n, (mode, delay, render, cpu) in enumerate(plan):
        tick = 1.0 + n * PERIOD
        start = tick + delay / 1e3
        report.add(DisplayFrame(
            index=n, time=n * PERIOD, start=start, done=start + render / 1e3,
            deadline=tick + PERIOD, mode=mode, older=0, newer=1, alpha=0.5,
            server_age_ms=None, prepared=True, refresh=tick, cpu_ms=cpu))
    causes = {"late_start": 2, "more_cpu": 2, "waited": 2}
    assert report.deadline_misses == 6
    assert report.miss_causes() == causes
    s = report.summary()
    assert s["deadline_misses_by_cause"] == causes
    assert s["frame_cpu_ms_max"] == 20.0
    text = text_report(s)
    assert "deadline misses 6 (13.04 %; 2 started late, 2 more CPU than the median, " \
        "2 threads waited)" in text
    assert "display threads' CPU per frame p50 7.00 ms, max 20.00 ms" in text
    # Frames without a refresh or a CPU time (off Linux, or recorded before these existed):
    # only the tests they allow; a miss of them all is put down to waiting.
    bare = RealtimeReport(display_fps=FC)
    for f in report.frames:
        bare.add(dataclasses.replace(f, refresh=None, cpu_ms=None))
    assert bare.miss_causes() == {"late_start": 0, "more_cpu": 0, "waited": 6}
    assert bare.summary()["frame_cpu_ms_p50"] is None


class Node:
    """A tracked object in a reference cycle with itself: garbage only the collector frees."""

    def __init__(self) -> None:
        self.me = self


class CycleClient(CostClient):
    """A :class:`CostClient` whose every render leaves ``per_frame`` cycles of garbage, and
    that notes whether the collector ever runs inside a render (``gc.callbacks``)."""

    def __init__(self, clock: FakeClock, cost: Any, per_frame: int) -> None:
        super().__init__(clock, cost)
        self.per_frame, self.rendering = per_frame, False
        self.first: Any = None  # a weak reference to the first frame's garbage
        self.starts: list[bool] = []  # per collection: inside a render?

    def render(self, camera: sr.Camera, time: float, *, eye: int = 0,
               interpolate: bool = True) -> np.ndarray:
        self.rendering = True
        try:
            nodes = [Node() for _ in range(self.per_frame)]
            if self.first is None:
                self.first = weakref.ref(nodes[0])
            del nodes
            return super().render(camera, time, eye=eye, interpolate=interpolate)
        finally:
            self.rendering = False

    def on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self.starts.append(self.rendering)


def collecting_run(scene: sr.SyntheticScene, frames: list[sr.ServerFrame], cost: Any,
                   per_frame: int) -> tuple[rt.RealtimeReport, CycleClient]:
    """A run of 0.5 s on the fake clock by a :class:`CycleClient`, the process's collector
    enabled and nothing frozen before it (as they were restored after it)."""
    clock = FakeClock()
    client = CycleClient(clock, cost, per_frame)
    enabled, frozen = gc.isenabled(), gc.get_freeze_count()
    gc.enable()
    try:
        with RealtimeClient(client=client, clock=clock, display_fps=FC) as c:
            for f in frames[:3]:
                c.submit(f)
            c.wait()
            gc.callbacks.append(client.on_gc)
            try:
                report = c.run(pose_of(scene), 0.5)
            finally:
                gc.callbacks.remove(client.on_gc)
        # As the run left it: on again, nothing frozen.
        assert gc.isenabled() and gc.get_freeze_count() == frozen
    finally:
        gc.enable() if enabled else gc.disable()
    return report, client


def test_the_collector_runs_between_display_frames_not_inside_them(scene, frames):
    # 300 cycles a frame: Python's own schedule (700) would collect inside every third render.
    report, client = collecting_run(scene, frames, lambda n: 0.002, 300)
    assert report.deadline_misses == 0 and len(report.frames) == 60
    assert client.starts and not any(client.starts)
    # Over and over: the 18,000 cycles pass the youngest generation's 700 about 25 times.
    assert report.gc_between_frames and report.gc_collections >= 10
    assert len(client.starts) > report.gc_collections  # and the full one before the clock
    assert report.gc_forced == 0  # 6.3 ms to each next refresh: time enough every time
    assert client.first is not None and client.first() is None  # the garbage was collected
    s = report.summary()
    assert s["gc_collections"] == report.gc_collections and s["gc_ms_max"] >= 0


def test_garbage_of_frames_that_leave_no_time_is_collected_once_overdue(scene, frames):
    # Every frame takes 99 % of its refresh: no collection fits before the next, until the
    # youngest generation's count reaches OVERDUE times its threshold.
    per_frame = 1000
    report, client = collecting_run(scene, frames, lambda n: 0.99 * PERIOD, per_frame)
    assert report.deadline_misses == 0
    assert report.gc_forced >= 1 and report.gc_forced == report.gc_collections
    assert not any(client.starts)
    # Each once the garbage of about OVERDUE x 700 / 1000 = 7 frames had piled up, not one a
    # frame (8 or 9 in the 60 frames).
    assert report.gc_collections <= 60 * per_frame // (collector.OVERDUE * 700) + 3


def test_a_disabled_collector_is_left_to_the_application(scene, frames):
    clock = FakeClock()
    enabled = gc.isenabled()
    gc.disable()
    try:
        with loop(clock) as c:
            c.submit(frames[0])
            c.wait()
            report = c.run(pose_of(scene), 0.05)
        assert not gc.isenabled()
    finally:
        gc.enable() if enabled else gc.disable()
    assert not report.gc_between_frames and report.gc_collections == 0


@pytest.mark.parametrize("fps", [0, -1.0, float("nan"), "120"])
def test_bad_display_rate_is_refused(fps):
    with pytest.raises(InvalidInputError, match="display_fps"):
        RealtimeClient(display_fps=fps)


@pytest.mark.parametrize("priority", ["", "IDLE", "realtime", 10, None])
def test_unknown_worker_priority_is_refused(priority):
    with pytest.raises(InvalidInputError, match="worker_priority"):
        RealtimeClient(worker_priority=priority)


def _policy_and_nice() -> tuple[int, int]:
    tid = threading.get_native_id()
    return os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="needs Linux scheduling policies")
def test_the_worker_thread_runs_at_the_priority_asked():
    here = _policy_and_nice()
    got = {}
    for priority in rt.WORKER_PRIORITIES:
        with RealtimeClient(clock=FakeClock(), worker_priority=priority) as c:
            got[priority] = c._worker.submit(_policy_and_nice).result(timeout=30)
    assert here[0] == os.SCHED_OTHER  # the display thread keeps its own
    assert got["normal"] == here
    if here[1] <= 10:  # else lowering to 10 would be raising
        assert got["low"] == (os.SCHED_OTHER, 10)
    assert got["idle"][0] == os.SCHED_IDLE


@pytest.mark.parametrize("priority", ["", "REALTIME", "idle", 99, None])
def test_unknown_display_priority_is_refused(priority):
    with pytest.raises(InvalidInputError, match="display_priority"):
        RealtimeClient(display_priority=priority)


def _display_policies() -> list[int]:
    """The policies of the calling thread and of the threads ``reproject`` runs on."""
    return [os.sched_getscheduler(t)
            for t in (threading.get_native_id(), *sr._native.render_thread_ids())]


@pytest.mark.skipif(not hasattr(os, "SCHED_RR"), reason="needs Linux scheduling policies")
def test_display_threads_are_real_time_during_a_run_and_restored_after(scene, frames):
    before = _display_policies()
    assert len(before) >= 2  # the display thread and at least one render thread
    seen: dict[str, list[list[int]]] = {}
    reports = {}
    for priority in rt.DISPLAY_PRIORITIES:
        clock = FakeClock()
        c = RealtimeClient(
            client=CostClient(clock, lambda n: 0.002), clock=clock, display_fps=FC,
            display_priority=priority,
        )
        with c:
            c.submit(frames[0])
            c.wait()
            seen[priority] = []
            reports[priority] = c.run(
                pose_of(scene), 0.02, on_frame=lambda im, rec: seen[priority].append(
                    _display_policies()))
        # Whatever the run got, it gave it back.
        assert _display_policies() == before
    assert reports["normal"].display_scheduling == "normal"
    assert all(p == before for p in seen["normal"])
    got = reports["realtime"].display_scheduling
    if got == "realtime":
        assert seen["realtime"] and all(
            set(p) == {os.SCHED_RR} for p in seen["realtime"])
    else:  # refused (no CAP_SYS_NICE and no RLIMIT_RTPRIO): said so, and nothing changed
        assert got.startswith("normal (real-time scheduling refused")
        assert all(p == before for p in seen["realtime"])


@pytest.mark.skipif(not hasattr(os, "SCHED_RR"), reason="needs Linux scheduling policies")
def test_refused_real_time_scheduling_changes_nothing_and_says_so(scene, frames, monkeypatch):
    # As for a user without CAP_SYS_NICE or an RLIMIT_RTPRIO: the second thread is refused.
    real = os.sched_setscheduler
    calls: list[int] = []

    def refuse_after_one(tid: int, policy: int, param: os.sched_param) -> None:
        calls.append(policy)
        if policy == os.SCHED_RR and len(calls) > 1:
            raise PermissionError(1, "Operation not permitted")
        real(tid, policy, param)

    monkeypatch.setattr(os, "sched_setscheduler", refuse_after_one)
    before = _display_policies()
    seen: list[list[int]] = []
    clock = FakeClock()
    with loop(clock) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 0.02,
                       on_frame=lambda im, rec: seen.append(_display_policies()))
    assert report.display_scheduling == (
        "normal (real-time scheduling refused: Operation not permitted)")
    assert report.summary()["display_scheduling"] == report.display_scheduling
    # The one thread raised before the refusal was given its policy back at once.
    assert seen and all(p == before for p in seen)
    assert _display_policies() == before


def _policies_over_a_run(scene, frames, cost):  # type: ignore[no-untyped-def]
    """A second's run at the full rate only (at half rate slow frames would be on time) whose
    n-th render takes ``cost(n)``: its report, the display threads' scheduling policies at
    each frame, and theirs before (and, checked, after) the run. Skips where real-time
    scheduling is not permitted."""
    clock = FakeClock()
    before = _display_policies()
    policies: list[list[int]] = []
    with loop(clock, cost=cost, max_divisor=1) as c:
        c.submit(frames[0])
        c.wait()
        report = c.run(pose_of(scene), 1.0,
                       on_frame=lambda im, rec: policies.append(_display_policies()))
    assert _display_policies() == before
    if not report.display_scheduling.startswith("realtime"):
        pytest.skip(f"real-time scheduling not permitted here: {report.display_scheduling}")
    return report, policies, before


@pytest.mark.skipif(not hasattr(os, "SCHED_RR"), reason="needs Linux scheduling policies")
def test_a_display_that_cannot_keep_up_goes_back_to_normal_priority(scene, frames):
    # Every frame takes 1.5 refreshes: late, every time.
    report, policies, before = _policies_over_a_run(scene, frames, lambda n: 1.5 * PERIOD)
    n = rt._OVERRUN_FRAMES
    assert report.deadline_misses == len(report.frames) > n
    # Raised for the first late frames, normal from the n-th late frame in a row on.
    assert all(set(p) == {os.SCHED_RR} for p in policies[: n - 1])
    assert all(p == before for p in policies[n - 1:])
    assert report.display_scheduling == (
        f"realtime until frame {report.frames[n - 1].index}, then normal ({n} late frames in a "
        "row)")


@pytest.mark.skipif(not hasattr(os, "SCHED_RR"), reason="needs Linux scheduling policies")
def test_late_frames_not_in_a_row_keep_the_display_at_real_time_priority(scene, frames):
    # Every other frame takes 1.5 refreshes, the ones between a fifth of one: more late frames
    # in the run than the limit, but never two in a row.
    report, policies, _ = _policies_over_a_run(
        scene, frames, lambda n: (1.5 if n % 2 else 0.2) * PERIOD)
    late = [not f.met for f in report.frames]
    assert sum(late) > rt._OVERRUN_FRAMES and not any(a and b for a, b in zip(late, late[1:]))
    assert report.display_scheduling == "realtime"
    assert all(set(p) == {os.SCHED_RR} for p in policies)


def test_warm_up_receives_the_due_frames_and_renders_off_the_record(scene, frames):
    feed = [(k / FS - 1 / FS, frames[k]) for k in range(3)]
    clock = FakeClock()
    # Received inline: on a worker thread the display could run through the fake clock's
    # remaining refreshes before the worker took frame 2, which then came too late for its
    # pair and was never handed over (a CI run under load failed so).
    with loop(clock, executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.2, feed=feed, warm_up=True)
        calls = c.client.calls
        # Frame 2 was submitted on the clock (at refresh 12), as without a warm-up.
        c.wait()
        assert 2 in c.client.held
    f = list(report.frames)
    assert len(f) == 24 and report.deadline_misses == 0
    # Frames 0 and 1 (due at -0.1 and 0) were in before refresh 0: no frame held.
    assert {(x.mode, x.older, x.newer) for x in f[:12]} == {("interpolate", 0, 1)}
    # Before them, off the record: one render (the first touches), then the governor's seeds,
    # MIN_FRAMES of each mode, 2 ms of the clock each.
    warm = 1 + 2 * rt.ModeGovernor.MIN_FRAMES
    assert calls == len(f) + warm
    assert report.warm_up_ms == pytest.approx(2.0 * warm)
    assert f[0].start >= 100.0 + 0.002 * warm - 1e-9
    seeds = report.summary()["warm_up_seed_ms"]
    assert list(seeds) == ["extrapolate", "interpolate"]
    assert all(t == pytest.approx([2.0] * rt.ModeGovernor.MIN_FRAMES) for t in seeds.values())
    text = text_report(report.summary())
    assert "(timed for the governor: extrapolated 2.0/2.0/2.0 ms, interpolated 2.0/2.0/2.0 ms)" \
        in text
    without = loop(FakeClock(), executor=InlineExecutor())
    with without as c:
        plain = c.run(pose_of(scene), 0.2, feed=feed)
    assert plain.warm_up_ms is None and plain.summary()["warm_up_ms"] is None
    assert plain.summary()["warm_up_seed_ms"] is None
    assert "timed for the governor" not in text_report(plain.summary())


def test_warm_up_renders_after_the_collectors_full_collection(scene, frames):
    # The collection leaves the caches cold: the warm-up's frames, not refresh 0, pay for it.
    assert gc.isenabled()
    feed = [(k / FS - 1 / FS, frames[k]) for k in range(2)]
    with loop(FakeClock(), executor=InlineExecutor()) as c:
        seen = []
        real = c.client.render

        def render(*a: Any, **kw: Any) -> Any:
            seen.append(gc.isenabled())
            return real(*a, **kw)

        c.client.render = render  # type: ignore[method-assign]
        report = c.run(pose_of(scene), 0.05, feed=feed, warm_up=True)
    assert len(seen) == len(report.frames) + 1 + 2 * rt.ModeGovernor.MIN_FRAMES
    assert not any(seen) and gc.isenabled()


class BatchExecutor(Executor):
    """Holds the first ``size`` jobs submitted and runs them in order when the last comes (the
    worker finds a newer packet waiting behind each but the last: behind, as a worker thread
    is when packets arrive together), then runs each job at once (:class:`InlineExecutor`)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.held: list[tuple[Future[Any], Any, Any, Any]] = []

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        self.held.append((fut, fn, args, kwargs))
        if len(self.held) >= self.size:
            self.size = 0
            todo, self.held = self.held, []
            for f, job, a, kw in todo:
                try:
                    f.set_result(job(*a, **kw))
                except Exception as e:
                    f.set_exception(e)
        return fut


@pytest.mark.parametrize(("interpolate_periods", "defers"), [(1.2, True), (0.5, False)])
def test_warm_up_lets_the_governor_decide_the_first_pairs_frames(scene, monkeypatch,
                                                                 interpolate_periods, defers):
    # Server frames arrive a server period before their time (as splitrender bench --realtime
    # sends them): frames 0 and 1 are due by the start and submitted together, so the worker
    # is behind on frame 0 and leaves out its extrapolation pair. The warm-up prepares it and
    # seeds the governor: where an interpolated frame (1.2 refreshes) cannot be done by its
    # deadline, the first pair's frames extrapolate from frame 0 from refresh 0 on, on time;
    # where it can (0.5 refreshes), they interpolate.
    clock = FakeClock()
    order = _clocked_preparation(monkeypatch, clock, 0.0, 0.0)
    client = ModeCostClient(clock, interpolate_periods * PERIOD, 0.4 * PERIOD)
    server = [scene.server_frame(k, k / FS, W, H, fps=FS) for k in range(3)]
    feed = [(f.time - 1 / FS, f) for f in server]
    with RealtimeClient(client=client, clock=clock, display_fps=FC,
                        executor=BatchExecutor(2)) as c:
        report = c.run(pose_of(scene), 0.1, feed=feed, warm_up=True)
    # The worker prepared frame 1's pairs only; frame 0's extrapolation pair came after, from
    # the warm-up, before any render.
    assert order == [(0, 1), (None, 1), (None, 0)]
    seeds = rt.ModeGovernor.MIN_FRAMES
    warm = [(info.mode, interpolate) for _, info, interpolate in client.rendered[:1 + 2 * seeds]]
    assert warm == [("interpolate", True)] + [("extrapolate", False)] * seeds + [
        ("interpolate", True)] * seeds
    assert report.warm_up_seed_ms == {
        "extrapolate": pytest.approx([0.4 * PERIOD * 1e3] * seeds),
        "interpolate": pytest.approx([interpolate_periods * PERIOD * 1e3] * seeds)}
    frames_ = list(report.frames)
    assert len(frames_) == 12 and all(f.older in (0, None) for f in frames_)
    assert all(f.met and f.divisor == 1 and f.prepared for f in frames_)
    if defers:
        assert all(f.mode == "extrapolate" and f.deferred and f.newer == 0 for f in frames_)
    else:
        assert all(f.mode == "interpolate" and not f.deferred for f in frames_)


def test_warm_up_does_not_seed_a_governor_that_is_not_asked(scene):
    # Only one frame is in by the start (nothing to interpolate): the warm-up renders its one
    # frame and no seeds.
    clock = FakeClock()
    client = ModeCostClient(clock, 1.2 * PERIOD, 0.4 * PERIOD)
    frame = scene.server_frame(0, 0.0, W, H, fps=FS)
    with RealtimeClient(client=client, clock=clock, display_fps=FC,
                        executor=InlineExecutor()) as c:
        report = c.run(pose_of(scene), 0.05, feed=[(-0.1, frame)], warm_up=True)
    assert len(client.rendered) == 1 + len(report.frames)
    assert report.warm_up_ms == pytest.approx(0.4 * PERIOD * 1e3)
    assert report.summary()["warm_up_seed_ms"] is None


@pytest.mark.parametrize("seconds", [0.001, 0.0, -1.0, float("nan"), float("inf"), "1", True])
def test_run_needs_at_least_one_frame(scene, seconds):
    with RealtimeClient(clock=FakeClock()) as c, pytest.raises(InvalidInputError, match="seconds"):
        c.run(pose_of(scene), seconds)


@pytest.mark.parametrize(
    ("call", "named"),
    [
        (lambda c, f, pose: c.submit(f, pose_time="x"), "pose_time"),
        (lambda c, f, pose: c.submit(f, pose_time=float("nan")), "pose_time"),
        (lambda c, f, pose: c.submit(3), "packet"),
        (lambda c, f, pose: c.submit(memoryview(b"ab" * 40)[::2]), "C-contiguous"),
        (lambda c, f, pose: c.run(None, 0.02), "pose"),
        (lambda c, f, pose: c.run(pose, 0.02, feed=None), "feed"),
        (lambda c, f, pose: c.run(pose, 0.02, start_time=float("inf")), "start_time"),
        (lambda c, f, pose: c.run(pose, 0.02, on_frame=3), "on_frame"),
        (lambda c, f, pose: c.run(pose, 0.02, warm_up="yes"), "warm_up"),
        (lambda c, f, pose: c.run(pose, 0.02, stereo=1), "stereo"),
        # The items of the feed as the run takes them (it may be a generator: not read ahead).
        (lambda c, f, pose: c.run(pose, 0.02, feed=[1, 2]), r"feed\[0\]"),
        (lambda c, f, pose: c.run(pose, 0.02, feed=[(0.0, f), ("x", f)]), r"feed\[1\]\[0\]"),
        (lambda c, f, pose: c.run(pose, 0.02, feed=[(0.0, 5)]), r"feed\[0\]\[1\]"),
    ],
)
def test_submit_and_run_refuse_bad_arguments_before_the_worker_sees_them(
    scene, frames, call, named
):
    # A bad pose_time was taken and failed later inside run() with a bare TypeError; a bad
    # pose or feed item did the same.
    with RealtimeClient(clock=FakeClock(), executor=InlineExecutor()) as c:
        with pytest.raises(InvalidInputError, match=named):
            call(c, frames[0], pose_of(scene))
        # The client still works after the refusal.
        c.submit(frames[0]).result()
        assert len(c.run(pose_of(scene), 2 * PERIOD).frames) == 2


def test_a_closed_realtime_client_refuses_work(scene, frames):
    c = RealtimeClient(clock=FakeClock(), executor=InlineExecutor())
    c.close()
    for call in (lambda: c.submit(frames[0]), lambda: c.run(pose_of(scene), 0.02)):
        with pytest.raises(InvalidInputError, match="closed"):
            call()


def test_a_missed_deadline_leaves_the_older_image_up_at_the_slots_shown(scene):
    # What bench --realtime --score scores: the image up at each refresh slot. Interpolated
    # frames of 1.2 refreshes miss, then the rate halves; both show in the slots.
    from splitrender.evaluation.shown import ShownRecorder

    n_slots = round(0.4 * FC)
    recorder = ShownRecorder(range(n_slots), 0.0, FC)
    made: list[Any] = []

    def on_frame(image: Any, record: rt.DisplayFrame) -> None:
        made.append((record, image))
        recorder(image, record)

    report, _ = mode_cost_run(scene, 6, 0.4, defer=False, on_frame=on_frame)
    shown = recorder.finish(n_slots)
    # The first frame missed too: its slot showed nothing yet (a headset's start-up).
    assert not made[0][0].met
    assert [s.slot for s in shown] == list(range(1, n_slots))
    at = {s.slot: s for s in shown}
    missed = [(i, r) for i, (r, _) in enumerate(made) if not r.met and i > 0]
    halved = [(i, r) for i, (r, _) in enumerate(made) if r.met and r.divisor == 2]
    assert missed and halved
    for i, (r, image) in enumerate(made):
        if r.met and r.divisor == 1:  # on time at the full rate: its own slot
            assert at[r.index].frame is r and at[r.index].stale == 0
            assert at[r.index].image[0] is image
    for i, r in missed:  # done 1.2 refreshes after its own: its slot shows the frame before
        assert at[r.index].frame is made[i - 1][0] and at[r.index].stale >= 1
        assert at[r.index + 1].frame is r and at[r.index + 1].stale == 1
    for i, r in halved:  # shown from the second refresh for two refreshes, a refresh late
        assert at[r.index].frame is made[i - 1][0]
        after = [r.index + k for k in (1, 2) if r.index + k < n_slots]
        assert all(at[s].frame is r for s in after)
        assert [at[s].stale for s in after] == [1, 2][: len(after)]
    assert list(report.frames) == [r for r, _ in made]


# -- splitrender bench --realtime ---------------------------------------------------------------

REALTIME_KEYS = ("method", "source", "width", "height", "frames", "deadline_misses",
                 "frame_ms_p50", "frame_ms_p99", "decode_ms_per_server_frame")


def test_bench_realtime_on_a_builtin_scene_writes_its_summary(tmp_path, monkeypatch):
    import json
    import tempfile

    from splitrender.cli.dispatch import main

    from PIL import Image

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the stream cache
    out, plot = tmp_path / "rt.json", tmp_path / "rt.png"
    assert main(["bench", "--realtime", "--scale", "0.05", "--seconds", "0.25",
                 "--json", str(out), "--plot", str(plot), "--quiet"]) == 0
    with Image.open(plot) as im:
        assert im.format == "PNG" and im.size == (1200, 672)  # 10 x 5.6 in at 120 dpi
    r = json.loads(out.read_text())
    assert list(r)[:5] == ["method", "source", "width", "height", "looped"]
    assert "summary" not in r
    assert all(k in r for k in REALTIME_KEYS)
    assert (r["method"], r["width"], r["height"]) == ("ours", 128, 72)
    # Every refresh of the run got a frame, was dropped after a late one, or repeated a frame
    # at a divided rate.
    assert r["frames"] + r["dropped"] + r["repeated"] == 30
    assert r["max_divisor"] == 2 and r["prepare_threads"] == rt.PREPARE_THREADS == 1
    assert sum(r["frames_by_divisor"].values()) == r["frames"]
    assert r["server_frames_received"] >= 3 and r["decode_ms_per_server_frame"] > 0
    assert sum(r["modes"].values()) == r["frames"]
    # The machine it ran on, as splitrender.machine finds it.
    here = this_machine()
    assert (r["processor"], r["cpus"], r["simd"]) == (here.processor, here.cpus, here.simd)


def test_bench_realtime_refuses_a_stream_whose_packets_do_not_decode(
    tmp_path, frames, capsys
):
    # It showed held frames, "decode n/a" and exited 0: a live display goes on past such a
    # packet, but a benchmark of the stream measures nothing of it.
    from splitrender.cli.dispatch import main
    from splitrender.codec.coder import CodecConfig, StreamEncoder

    with StreamEncoder(CodecConfig(bitrate_mbps=2.0)) as enc:
        packets = [enc.encode(f) for f in frames[:3]]
    # Well-formed packets, but the first is not a key frame: none can be decoded.
    sr.write_stream(tmp_path / "s.srs", packets[1:])
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--stream", str(tmp_path / "s.srs"), "--seconds",
                 "0.25", "--display-priority", "normal", "--json", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"splitrender: error: {tmp_path / 's.srs'}: ") and len(err.splitlines()) == 1
    assert "packets did not decode; the first: frame 0: not a key frame" in err
    assert not out.exists()


def test_the_report_counts_the_packets_that_did_not_decode(scene, frames):
    with RealtimeClient(clock=FakeClock(), executor=InlineExecutor()) as c:
        assert isinstance(c.submit(b"garbage").exception(), StreamError)
        c.submit(frames[0]).result()
        report = c.run(pose_of(scene), 2 * PERIOD)
    assert report.summary()["packets_undecodable"] == 1
    assert report.undecodable == ["frame ?: packet of 7 bytes is shorter than the 32-byte header"]


def test_bench_realtime_plays_a_stream_file_and_loops_it(tmp_path, scene, frames, capsys):
    import json

    from splitrender.cli.dispatch import main
    from splitrender.codec.coder import CodecConfig, StreamEncoder

    with StreamEncoder(CodecConfig(bitrate_mbps=2.0)) as enc:
        sr.write_stream(tmp_path / "s.srs", [enc.encode(f) for f in frames[:3]])
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--stream", str(tmp_path / "s.srs"), "--seconds",
                 "0.5", "--methods", "ours_extrapolate", "--json", str(out), "--quiet"]) == 0
    r = json.loads(out.read_text())
    assert (r["method"], r["width"], r["height"], r["looped"]) == ("ours_extrapolate", W, H, True)
    assert r["exclusive"] is False and r["worker_priority"] == "idle"
    assert r["display_priority"] == "realtime" and r["display_scheduling"].startswith(
        ("realtime", "normal (real-time scheduling refused"))
    assert r["warm_up_ms"] > 0
    # 0.5 s at 10 FPS: frames 0..5 sent, the 3 packets of the file twice, each a server period
    # before its time. Frames 3.. are the file's packets again: at least one of them must have
    # been received. The last one, sent 0.1 s before the run ends, may still be decoding then on
    # a loaded machine (the worker runs at idle priority), so it is not required.
    assert 4 <= r["server_frames_received"] <= 6
    assert r["eyes"] == 1
    assert "source looped" in capsys.readouterr().out


def test_bench_realtime_stereo_renders_two_eyes_a_frame(tmp_path, frames, capsys):
    import json

    from splitrender.cli.dispatch import main
    from splitrender.codec.coder import CodecConfig, StreamEncoder

    with StreamEncoder(CodecConfig(bitrate_mbps=2.0)) as enc:
        sr.write_stream(tmp_path / "s.srs", [enc.encode(f) for f in frames[:3]])
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--stereo", "--stream", str(tmp_path / "s.srs"),
                 "--seconds", "0.25", "--json", str(out), "--quiet"]) == 0
    r = json.loads(out.read_text())
    assert r["eyes"] == 2 and r["frames"] + r["dropped"] + r["repeated"] == 30
    assert f"two eyes of {W}x{H} + aux" in capsys.readouterr().out


def test_bench_realtime_exclusive_renders_every_frame_from_its_prepared_pair(
    tmp_path, scene, frames, capsys, monkeypatch
):
    import json

    from splitrender.cli.dispatch import main
    from splitrender.codec.coder import CodecConfig, StreamEncoder

    with StreamEncoder(CodecConfig(bitrate_mbps=2.0)) as enc:
        sr.write_stream(tmp_path / "s.srs", [enc.encode(f) for f in frames[:3]])
    # --prepare-threads reaches every preparation the worker does.
    threads = []

    def prepare_pair(*args, threads_=threads, **kw):
        threads_.append(kw["threads"])
        return sr.prepare_pair(*args, **kw)

    monkeypatch.setattr(rt, "prepare_pair", prepare_pair)
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--exclusive", "--stream", str(tmp_path / "s.srs"),
                 "--seconds", "0.25", "--fps", "40", "--worker-priority", "low",
                 "--display-priority", "normal", "--max-divisor", "1", "--prepare-threads",
                 "3", "--json", str(out), "--quiet"]) == 0
    r = json.loads(out.read_text())
    assert r["prepare_threads"] == 3 and threads and set(threads) == {3}
    assert r["exclusive"] is True and r["server_frames_late"] == 0
    # --fps sets the display rate: 0.25 s at 40 FPS is 10 refreshes; --max-divisor 1 holds it.
    assert r["display_fps"] == 40.0 and r["frames"] + r["dropped"] == 10
    assert r["max_divisor"] == 1 and r["full_rate_pct"] == 100.0 and r["repeated"] == 0
    assert r["worker_priority"] == "low"
    assert (r["display_priority"], r["display_scheduling"]) == ("normal", "normal")
    # Each frame was usable before the display went on: no frame extrapolated or held.
    assert r["modes"]["interpolate"] == r["frames"] and r["prepared_pct"] == 100.0
    assert "exclusive" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--stream", "x.srs"], "--stream goes with --realtime"),
        (["--exclusive"], "--exclusive goes with --realtime"),
        (["--worker-priority", "low"], "--worker-priority goes with --realtime"),
        (["--display-priority", "normal"], "--display-priority goes with --realtime"),
        (["--fps", "60"], "--fps goes with --realtime"),
        (["--max-divisor", "2"], "--max-divisor goes with --realtime"),
        (["--prepare-threads", "2"], "--prepare-threads goes with --realtime"),
        (["--stereo"], "--stereo goes with --realtime"),
        (["--always-interpolate"], "--always-interpolate goes with --realtime"),
        (["--score"], "--score goes with --realtime"),
        (["--no-vmaf"], "--no-vmaf goes with --realtime"),
        (["--realtime", "--no-vmaf"], "--no-vmaf goes with --score"),
        (["--realtime", "--stream", "s.srs", "--score", "5"],
         "--score: a stream file carries no ground truth; score a built-in --scene"),
        (["--realtime", "--score", "--seconds", "0.2"], "--score: 0.2 s is 24 refreshes"),
        (["--realtime", "--backend", "wgpu", "--prepare-threads", "2"],
         "--prepare-threads goes with --backend cpu"),
        (["--realtime", "--fps", "0.001", "--seconds", "1"], "--seconds 1 at --fps 0.001"),
        (["--realtime", "--methods", "ours,timewarp"], "one method"),
        (["--realtime", "--backend", "wgpu", "--methods", "timewarp"], "no wgpu kernel"),
        (["--realtime", "--stream", "missing.srs"], "missing.srs"),
        (["--plot", "p.png"], "--plot goes with --realtime"),
        # It used to time five frames per method and say nothing of --seconds.
        (["--seconds", "2"], "--seconds goes with --realtime"),
        (["--realtime", "--frames", "3"], "--frames: not with --realtime, which runs for"),
        (["--json", "."], "--json: . is a directory; expected a file name"),
        # The outputs are checked before the run: a result that cannot be written is not made.
        (["--realtime", "--plot", "."], "--plot: . is a directory; expected a file name"),
        (["--realtime", "--stream", "s.srs", "--plot", "s.srs"],
         "--plot s.srs: the output is the stream s.srs"),
        (["--realtime", "--json", "a", "--plot", "./a"], "--plot: a is the --json file too"),
    ],
)
def test_bench_realtime_argument_errors_exit_2(argv, message, tmp_path, monkeypatch, capsys):
    from splitrender.cli.dispatch import main

    monkeypatch.chdir(tmp_path)
    assert main(["bench", *argv, "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_realtime_figure_draws_every_frame_and_marks_each_miss():
    from splitrender.client.realtime import DisplayFrame, RealtimeReport
    from splitrender.evaluation.bench_realtime import MODE_COLOURS, RealtimeBench, realtime_figure

    fps = 120.0
    period = 1.0 / fps
    # (mode, ms from the refresh to the start, render ms): frame 3 renders too long, frame 5
    # starts late, frame 8 far beyond the plotted range (four periods: the p99 of 150 frames
    # is below that); the rest fit.
    plan = [("interpolate", 0.1, 2.0)] * 3 + [("interpolate", 0.1, 9.0)] + [
        ("extrapolate", 0.2, 3.0), ("extrapolate", 6.0, 3.0), ("hold", 0.1, 0.5),
        ("extrapolate", 0.1, 3.0), ("extrapolate", 0.1, 200.0)]
    plan += [("interpolate", 0.1, 2.0)] * (150 - len(plan))
    deferred = {7}  # extrapolated where interpolating would have missed: drawn apart
    report = RealtimeReport(display_fps=fps)
    for n, (mode, wait, render) in enumerate(plan):
        tick = n * period
        start = tick + wait / 1e3
        report.add(DisplayFrame(
            index=n, time=n * period, start=start, done=start + render / 1e3,
            deadline=tick + period, mode=mode, older=None, newer=0, alpha=None,
            server_age_ms=None if n == 0 else 10.0 * n, prepared=True,
            deferred=n in deferred))
    b = RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", report.summary(),
                      frames=tuple(report.frames), processor="Test CPU", cpus=2, simd="avx2")
    fig = realtime_figure(b)
    top, low = fig.axes
    points = {}
    for c in top.collections:
        points[c.get_label()] = [tuple(xy) for xy in np.asarray(c.get_offsets())]
    missed = [(n, wait + render) for n, (_, wait, render) in enumerate(plan)
              if wait + render > 1e3 * period]
    assert [n for n, _ in missed] == [3, 5, 8]
    cross = points["deadline missed (3)"]
    ceiling = top.get_ylim()[1] / 1.05
    assert [x for x, _ in cross] == pytest.approx([n * period for n, _ in missed])
    # Each at its time from the refresh to done; frame 8 at the top edge of the range.
    assert [y for _, y in cross] == pytest.approx([9.1, 9.0, ceiling])
    assert ceiling == pytest.approx(4e3 * period)
    for mode in MODE_COLOURS:
        frames = [n for n, (m, _, _) in enumerate(plan) if m == mode and n not in deferred]
        drawn = points[f"{mode} ({len(frames)})"]
        inside = [n for n in frames if plan[n][2] < 100]
        assert [x for x, _ in drawn] == pytest.approx([n * period for n in inside])
    ((x, y),) = points["extrapolate, instead of interpolating (1)"]
    assert (x, y) == (pytest.approx(7 * period), pytest.approx(3.1))
    # The refresh period as the line every miss is above.
    (line,) = [ln for ln in top.get_lines() if ln.get_label().startswith("refresh period")]
    assert list(line.get_ydata()) == pytest.approx([1e3 * period] * 2)
    # Below: the newest server frame's age of every frame that had one.
    (age,) = low.get_lines()
    assert list(age.get_ydata()) == [10.0 * n for n in range(1, len(plan))]
    assert "3 deadline misses" in top.get_title()
    # The machine on a line of its own, and beside it the host's share where it was counted.
    assert top.get_title().splitlines()[1] == "Test CPU, 2 CPUs, CPU row loops AVX2"
    report.host_steal = 0.125
    stolen = dataclasses.replace(b, summary=report.summary())
    assert realtime_figure(stolen).axes[0].get_title().splitlines()[1] == (
        "Test CPU, 2 CPUs, CPU row loops AVX2; the host took 12.5 % of the CPU time (steal)")
    bare = dataclasses.replace(stolen, processor="", cpus=0, simd="")
    assert realtime_figure(bare).axes[0].get_title().splitlines()[1] == (
        "the host took 12.5 % of the CPU time (steal)")


@pytest.mark.parametrize("with_refresh", [True, False])
def test_realtime_figure_judges_half_rate_frames_on_their_own_deadline(with_refresh):
    from splitrender.client.realtime import DisplayFrame, RealtimeReport
    from splitrender.evaluation.bench_realtime import RealtimeBench, realtime_figure

    period = 1.0 / 120.0
    report = RealtimeReport(display_fps=120.0)
    # Four full-rate frames of 12 ms (all late), then half-rate frames of 12 ms (on time) and
    # one of 20 ms (late at half rate too).
    renders = [(1, 12.0)] * 4 + [(2, 12.0)] * 10 + [(2, 20.0)]
    n = 0
    for d, render in renders:
        tick = n * period
        report.add(DisplayFrame(
            index=n, time=tick, start=tick, done=tick + render / 1e3,
            deadline=tick + d * period, mode="extrapolate", older=None, newer=0, alpha=None,
            server_age_ms=None, prepared=True, divisor=d,
            # Without its refresh (frames recorded before it existed), from the deadline.
            refresh=tick if with_refresh else None))
        n += 2 if d == 2 else 1
    b = RealtimeBench("ours", "test", W, H, False, False, "idle", "normal", report.summary(),
                      frames=tuple(report.frames))
    top, _ = realtime_figure(b).axes
    points = {c.get_label(): np.asarray(c.get_offsets()) for c in top.collections}
    # Every frame at its time from its refresh; the misses are the four full-rate frames and
    # the last one, not the half-rate frames of 12 ms.
    assert list(points["extrapolate (15)"][:, 1]) == pytest.approx([r for _, r in renders])
    cross = points["deadline missed (5)"]
    assert list(cross[:, 1]) == pytest.approx([12.0] * 4 + [20.0])
    labels = [ln.get_label() for ln in top.get_lines()]
    (half,) = [ln for ln in top.get_lines() if ln.get_label().startswith("deadline at 60 FPS")]
    assert list(half.get_ydata()) == pytest.approx([2e3 * period] * 2)
    assert "deadline at 60 FPS (11 frames)" in labels


# -- the GPU display: pairs uploaded on the worker, made current with no copy -----------------

needs_gpu = pytest.mark.skipif(
    not sr.gpu.available(),
    reason="no wgpu adapter (apt-get install mesa-vulkan-drivers gives Mesa's lavapipe)",
)


@needs_gpu
def test_gpu_display_uses_pairs_uploaded_on_the_worker_and_loads_none_itself(
    scene, frames, monkeypatch
):
    from splitrender.gpu import GpuReprojector

    # Which reprojector loaded a pair on the display path (GpuReprojector._load), and on which
    # thread each pair was uploaded.
    loads: list[GpuReprojector] = []
    uploads: list[str] = []
    real_load, real_upload = GpuReprojector._load, GpuReprojector.upload

    def load(self, *a, **kw):  # type: ignore[no-untyped-def]
        loads.append(self)
        return real_load(self, *a, **kw)

    def upload(self, *a, **kw):  # type: ignore[no-untyped-def]
        uploads.append(threading.current_thread().name)
        return real_upload(self, *a, **kw)

    monkeypatch.setattr(GpuReprojector, "_load", load)
    monkeypatch.setattr(GpuReprojector, "upload", upload)
    plain = Client("ours", backend="wgpu")
    clock = FakeClock()
    with RealtimeClient("ours", clock=clock, display_fps=FC, backend="wgpu") as c:
        assert c.client.backend == "wgpu"
        for f in frames[:3]:
            plain.receive(f)
            c.submit(f)
            c.wait()
        # The worker thread uploaded every pair the frames open.
        assert set(c.client._uploaded) == {(None, 0), (0, 1), (None, 1), (1, 2), (None, 2)}
        assert len(uploads) == 5
        assert all(n.startswith("splitrender-receive") for n in uploads)
        pairs = set()
        for n in range(1, 24):
            t = n / FC
            cam = scene.rig(t, W, H)[0]
            image = c.render(cam, t)
            info = c.client.last_info
            pairs.add((info.older, info.newer))
            assert c.client.was_prepared(info.older, info.newer)
            # The same bytes as a GPU client that loads each pair on its first frame.
            np.testing.assert_array_equal(image, plain.render(cam, t))
        assert pairs == {(0, 1), (1, 2)}
        # Every pair was made current from its upload: the display loaded none itself.
        assert c.client.gpu not in loads and plain.gpu in loads
    # No pair went up twice on the worker (the plain client's loads upload on this thread).
    assert sum(n.startswith("splitrender-receive") for n in uploads) == 5


@needs_gpu
def test_uploaded_pairs_are_dropped_with_their_frames_and_refused_on_the_cpu(scene, frames):
    gpu_client = Client("ours", backend="wgpu", capacity=2)
    for f in frames[:2]:
        gpu_client.receive(f)
    assert gpu_client.gpu is not None
    pair = gpu_client.gpu.upload(frames[0], frames[1])
    assert pair.has_older and pair.device_bytes > 0
    gpu_client.adopt_uploaded(0, 1, pair)
    assert gpu_client.was_prepared(0, 1)
    with pytest.raises(InvalidInputError, match="expected held frames"):
        gpu_client.adopt_uploaded(1, 2, pair)
    gpu_client.render(scene.rig(0.05, W, H)[0], 0.05)  # installs the pair
    # Frame 2 arrives and displaces frame 0 once the display moves past it: the pair is
    # retired, for the uploading side to drop, and no longer used.
    gpu_client.receive(frames[2])
    gpu_client.render(scene.rig(0.15, W, H)[0], 0.15)
    assert not gpu_client.was_prepared(0, 1)
    retired = gpu_client.retired_uploads()
    assert pair in retired and gpu_client.retired_uploads() == []
    cpu_client = Client("ours")
    cpu_client.receive(frames[0])
    with pytest.raises(InvalidInputError, match="renders on the CPU"):
        cpu_client.adopt_uploaded(None, 0, pair)
    with pytest.raises(InvalidInputError, match="pair: expected"):
        gpu_client.gpu.install("not a pair")  # type: ignore[arg-type]


@needs_gpu
def test_bench_realtime_on_the_gpu_uploads_on_the_worker(tmp_path, monkeypatch, capsys):
    import json
    import tempfile

    from splitrender.cli.dispatch import main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the stream cache
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--backend", "wgpu", "--scale", "0.05", "--seconds",
                 "0.25", "--exclusive", "--json", str(out), "--quiet"]) == 0
    r = json.loads(out.read_text())
    assert r["backend"] == "wgpu" and r["adapter"] == sr.gpu.adapter()
    # 30 refreshes; on a loaded machine the governor halves the rate for some (a wall-clock run:
    # the count of frames is not what this test is about).
    assert 0 < r["frames"] and r["frames"] + r["dropped"] <= 30
    assert r["server_frames_late"] == 0
    # Every frame rendered a pair uploaded by the worker.
    assert r["prepared_pct"] == 100.0 and r["prepare_ms_per_server_frame"] > 0
    assert "pair upload" in capsys.readouterr().out


def test_a_damaged_cached_stream_is_encoded_again(tmp_path, monkeypatch):
    # A flipped byte in the cached stream failed every later `bench --realtime` with "frame 0:
    # packet CRC mismatch", which named neither the file nor the fix: only its count was read.
    import tempfile

    from splitrender.codec.stream import StreamFile, unpack_packet
    from splitrender.evaluation.bench_realtime import _scene_stream

    class Said:
        def __init__(self):
            self.stages = []

        def stage(self, text):
            self.stages.append(text)

        def bar(self, *args, **kwargs):
            pass

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    said = Said()
    path = _scene_stream("courtyard", 0.02, 3, said)
    packets = list(StreamFile(path).packets())
    data = bytearray(path.read_bytes())
    data[data.find(packets[1]) + len(packets[1]) // 2] ^= 0x55
    path.write_bytes(data)
    assert _scene_stream("courtyard", 0.02, 3, said) == path
    assert [unpack_packet(p).index for p in StreamFile(path).packets()] == [0, 1, 2]
    assert not any(s.startswith("reusing") for s in said.stages)
    _scene_stream("courtyard", 0.02, 3, said)
    assert said.stages[-1].startswith("reusing the cached stream")
