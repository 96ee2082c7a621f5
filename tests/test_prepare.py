"""`prepare_pair` / `BidirHistory.prepare`: a pair's client-independent work done ahead of its
first client frame (for the real-time loop), observed through `BidirHistory.pair_builds`."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import FPS, Pair

import splitrender as sr
from splitrender import _native


def _frames(pair: Pair) -> list[sr.ServerFrame]:
    w, h = pair.request.camera.width, pair.request.camera.height
    return [pair.older, pair.newer, pair.scene.server_frame(2, 2 / FPS, w, h, fps=FPS)]


def _camera(pair: Pair, t: float) -> sr.Camera:
    w, h = pair.request.camera.width, pair.request.camera.height
    return pair.scene.rig(t, w, h)[0]


@pytest.mark.parametrize("threads", [None, 1, 2])
def test_prepared_pair_is_not_rebuilt_and_gives_the_same_images(
    pair: Pair, threads: int | None
) -> None:
    frames = _frames(pair)
    history = sr.BidirHistory()
    assert history.pair_builds == 0
    for k, builds in [(0, 1), (1, 2)]:
        older, newer = frames[k], frames[k + 1]
        sr.prepare_pair(older, newer, _camera(pair, older.time), history=history, threads=threads)
        # A different pair rebuilds (no reset in between: the history notices by itself).
        assert history.pair_builds == builds
        # Preparing the same pair again keeps the work.
        sr.prepare_pair(older, newer, pair.request.camera, history=history, threads=threads)
        assert history.pair_builds == builds
        for alpha in [0.0, 0.25, 0.6, 0.95]:
            camera = _camera(pair, older.time + alpha / FPS)
            kept = sr.reproject_alpha(older, newer, camera, alpha, history=history)
            fresh = sr.reproject_alpha(older, newer, camera, alpha)
            np.testing.assert_array_equal(kept, fresh)
            assert history.pair_builds == builds, alpha


@pytest.mark.parametrize("method", ["ours_extrapolate", "forward_splat"])
def test_extrapolation_is_prepared_without_the_older_frame(pair: Pair, method: str) -> None:
    history = sr.BidirHistory()
    sr.prepare_pair(None, pair.newer, pair.request.camera, method, history=history)
    assert history.pair_builds == 1
    for alpha in [1.0, 1.4]:
        kept = sr.reproject_alpha(None, pair.newer, pair.request.camera, alpha, method, history=history)
        fresh = sr.reproject_alpha(None, pair.newer, pair.request.camera, alpha, method)
        np.testing.assert_array_equal(kept, fresh)
    assert history.pair_builds == 1


def test_prepared_with_the_options_given(pair: Pair) -> None:
    # eps_z and aux_threshold_scale shape the pair's work (a history rebuilds when they change):
    # frames displayed with the options the pair was prepared with reuse it.
    options = sr.ReprojectOptions(eps_z=0.01, aux_threshold_scale=2.0)
    history = sr.BidirHistory()
    cam = pair.request.camera
    sr.prepare_pair(pair.older, pair.newer, cam, options=options, history=history)
    kept = sr.reproject_alpha(pair.older, pair.newer, cam, pair.alpha, options=options,
                              history=history)
    assert history.pair_builds == 1
    fresh = sr.reproject_alpha(pair.older, pair.newer, cam, pair.alpha, options=options)
    np.testing.assert_array_equal(kept, fresh)
    # Not vacuous: other options need other work.
    sr.reproject_alpha(pair.older, pair.newer, cam, pair.alpha, history=history)
    assert history.pair_builds == 2


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux's /proc")
def test_threads_runs_the_work_on_a_pool_of_that_many_threads(pair: Pair) -> None:
    # The dedicated pools are kept, their threads named reproj-pool{N}-{i} (reproj_core::pool);
    # 7 threads is a count no other test asks for.
    def pool_threads() -> list[str]:
        names = (p.read_text().strip() for p in Path("/proc/self/task").glob("*/comm"))
        return sorted(n for n in names if n.startswith("reproj-pool7-"))

    history = sr.BidirHistory()
    sr.prepare_pair(pair.older, pair.newer, pair.request.camera, history=history, threads=7)
    assert history.pair_builds == 1
    # A thread names itself as it starts: those that ran the work have, the rest soon will.
    want = [f"reproj-pool7-{i}" for i in range(7)]
    deadline = time.monotonic() + 5.0
    while pool_threads() != want and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pool_threads() == want


def test_each_method_prepares_its_own_work(pair: Pair) -> None:
    # With both frames given, the extrapolating methods prepare their own work (not `ours`'s
    # interpolation): their frames reuse it, the other method's do not.
    cam = pair.request.camera
    for method, other in (("ours_extrapolate", "forward_splat"), ("forward_splat", "ours")):
        history = sr.BidirHistory()
        sr.prepare_pair(pair.older, pair.newer, cam, method, history=history)
        sr.reproject_alpha(pair.older, pair.newer, cam, 1.2, method, history=history)
        assert history.pair_builds == 1, method
        sr.reproject_alpha(pair.older, pair.newer, cam, 0.5 if other == "ours" else 1.2, other,
                           history=history)
        assert history.pair_builds == 2, (method, other)


def test_without_prepare_the_first_frame_builds(pair: Pair) -> None:
    history = sr.BidirHistory()
    sr.reproject(pair.older, pair.newer, pair.request, history=history)
    assert history.pair_builds == 1
    sr.prepare_pair(pair.older, pair.newer, pair.request.camera, history=history)
    assert history.pair_builds == 1
    # reset() forgets the pair; the count goes on.
    history.reset()
    sr.prepare_pair(pair.older, pair.newer, pair.request.camera, history=history)
    assert history.pair_builds == 2


@pytest.mark.parametrize("method", ["timewarp", "backward_bidir"])
def test_methods_without_pair_state_do_nothing(pair: Pair, method: str) -> None:
    history = sr.BidirHistory()
    sr.prepare_pair(pair.older, pair.newer, pair.request.camera, method, history=history)
    assert history.pair_builds == 0
    # They still check their arguments as reproject does.
    with pytest.raises(sr.InvalidInputError, match="needs both frames"):
        sr.prepare_pair(None, pair.newer, pair.request.camera, "backward_bidir", history=history)


def test_invalid_arguments_are_named(pair: Pair) -> None:
    history = sr.BidirHistory()
    cam = pair.request.camera
    with pytest.raises(sr.InvalidInputError, match="unknown method 'nope'"):
        sr.prepare_pair(pair.older, pair.newer, cam, "nope", history=history)
    with pytest.raises(sr.InvalidInputError, match="camera: expected a Camera"):
        sr.prepare_pair(pair.older, pair.newer, "cam", history=history)  # type: ignore[arg-type]
    with pytest.raises(sr.InvalidInputError, match="history: expected a BidirHistory"):
        sr.prepare_pair(pair.older, pair.newer, cam, history=None)  # type: ignore[arg-type]
    with pytest.raises(sr.InvalidInputError, match="older: expected a ServerFrame"):
        sr.prepare_pair(1, pair.newer, cam, history=history)  # type: ignore[arg-type]
    for bad in [0, -1, _native.MAX_PREPARE_THREADS + 1, 100_000]:
        with pytest.raises(sr.InvalidInputError, match="threads"):
            sr.prepare_pair(pair.older, pair.newer, cam, history=history, threads=bad)
    with pytest.raises(sr.InvalidInputError, match="threads"):
        sr.prepare_pair(pair.older, pair.newer, cam, history=history, threads=1.5)  # type: ignore[arg-type]
    # Frames that do not make a pair are refused as reproject refuses them.
    one_aux = dataclasses.replace(pair.newer, aux=pair.newer.aux[:1])
    with pytest.raises(sr.InvalidInputError, match="older.aux has 2 cameras but newer.aux has 1"):
        sr.prepare_pair(pair.older, one_aux, cam, history=history)
    assert history.pair_builds == 0


def test_native_prepare_from_a_background_thread(pair: Pair) -> None:
    # The native method directly, as the stub types it, from a thread as the real-time loop
    # calls it, on a dedicated pool.
    history = _native.BidirHistory()
    args = (
        "ours",
        pair.older.to_native("fwd"),
        pair.newer.to_native("bwd"),
        pair.request.camera.to_native(),
    )
    errors: list[BaseException] = []

    def work() -> None:
        try:
            history.prepare(*args, threads=2)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert not errors and history.pair_builds == 1
