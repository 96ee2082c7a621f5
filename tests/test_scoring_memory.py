"""The evaluation scores a long sequence without holding it: play_and_score_eyes with lazy
server frames and ground truths and ``keep_images=False`` keeps a bounded number of client
frames and ground truths alive (a 1280×720 score task used to hold every one of them: 5–8 GB).
Counted with weak references: the arrays are made by the native module, outside what
``tracemalloc`` sees."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Callable, Sequence
from typing import Any, TypeVar, overload

import numpy as np
import splitrender as sr
from splitrender.evaluation.pipeline import play_and_score_eyes

T = TypeVar("T")
W, H = 64, 36
FS, FC = 10.0, 120.0


class Lazy(Sequence[T]):
    """A sequence whose items are made when asked for, as a recording's frames are read."""

    def __init__(self, n: int, make: Callable[[int], T]) -> None:
        self._n, self._make = n, make

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, i: int) -> T: ...
    @overload
    def __getitem__(self, i: slice) -> list[T]: ...
    def __getitem__(self, i: int | slice) -> T | list[T]:
        if isinstance(i, slice):
            return [self._make(k) for k in range(*i.indices(self._n))]
        if not 0 <= i < self._n:
            raise IndexError(i)
        return self._make(i)


class Alive:
    """How many of the arrays it was shown are alive, and the most at any one time."""

    def __init__(self) -> None:
        self.now = self.most = 0

    def track(self, a: np.ndarray) -> np.ndarray:
        self.now += 1
        self.most = max(self.most, self.now)
        weakref.finalize(a, self._gone)
        return a

    def _gone(self) -> None:
        self.now -= 1


def most_alive(server_frames: int, keep_images: bool) -> tuple[int, int, Any]:
    """The most client images and ground truths alive at once while ``server_frames`` server
    frames (12 client frames each between them) are played and scored."""
    scene = sr.SyntheticScene(dynamic=True)
    n_client = (server_frames - 1) * 12
    frames = Lazy(server_frames, lambda k: scene.server_frame(k, k / FS, W, H, fps=FS))
    cams = [scene.rig(n / FC, W, H)[0] for n in range(n_client)]
    images, truths = Alive(), Alive()
    truth = Lazy(n_client, lambda n: truths.track(scene.ground_truth(cams[n], n / FC)))
    gc.collect()
    [scored] = play_and_score_eyes(
        frames, [cams], [truth], "ours", sr.NetworkModel(), FC, ("psnr", "vmaf"),
        keep_images=keep_images, on_frame=lambda eye, n, image, info: images.track(image),
    )
    return images.most, truths.most, scored


def test_scoring_holds_a_bounded_number_of_frames_whatever_the_length() -> None:
    short = most_alive(4, keep_images=False)  # 36 client frames
    long = most_alive(13, keep_images=False)  # 144
    assert len(long[2].metrics.frames) == 144 - 24 and long[2].playback.images == []
    assert np.isfinite(long[2].metrics.mean["vmaf"])
    assert long[:2] == short[:2] and max(long[:2]) <= 3, (short[:2], long[:2])
    # What the count would catch: a playback that keeps its images holds every one.
    kept = most_alive(13, keep_images=True)
    assert kept[0] == 144 and kept[2].metrics == long[2].metrics
