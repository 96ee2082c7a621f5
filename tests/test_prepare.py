"""`prepare_pair` / `BidirHistory.prepare`: a pair's client-independent work done ahead of its
first client frame (for the real-time loop), observed through `BidirHistory.pair_builds`."""

from __future__ import annotations

import dataclasses
import threading

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
    for bad in [0, -1, 100_000]:
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
