"""Shared pytest configuration: hypothesis profiles and small synthetic fixtures.

Hypothesis profiles: ``ci`` (the default; 25 examples, no deadline, so slow shared CI machines do
not flake) and ``dev`` (more examples, for local runs). Select with ``HYPOTHESIS_PROFILE=dev``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, settings

import splitrender as sr

def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Leaves out the long fuzz profile (``@pytest.mark.fuzz``) unless ``-m`` names ``fuzz``."""
    if "fuzz" in (config.getoption("markexpr") or ""):
        return
    kept = [item for item in items if item.get_closest_marker("fuzz") is None]
    if len(kept) != len(items):
        config.hook.pytest_deselected(items=[i for i in items if i.get_closest_marker("fuzz")])
        items[:] = kept


settings.register_profile(
    "ci",
    max_examples=25,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("dev", max_examples=200, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session", autouse=True)
def _sweep_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """``eval``'s default cache (docs/sweeps.md) in a folder of this session, not the user's
    cache: tests compute what they check, and leave nothing behind."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPLITRENDER_CACHE", str(tmp_path_factory.mktemp("sweep-cache")))
        yield

#: Main camera size of the small fixtures (auxiliary cameras are half of it).
SMALL_W, SMALL_H = 48, 32
FPS = 10.0


@dataclass(frozen=True)
class Pair:
    """Two consecutive server frames of the synthetic scene and a client request between them."""

    older: sr.ServerFrame
    newer: sr.ServerFrame
    request: sr.ClientRequest
    scene: sr.SyntheticScene

    @property
    def alpha(self) -> float:
        return (self.request.time - self.older.time) / (self.newer.time - self.older.time)


def make_pair(dynamic: bool = True, width: int = SMALL_W, height: int = SMALL_H) -> Pair:
    scene = sr.SyntheticScene(dynamic=dynamic)
    f0 = scene.server_frame(0, 0.0, width, height, fps=FPS)
    f1 = scene.server_frame(1, 1.0 / FPS, width, height, fps=FPS)
    t = 7 / 120
    camera, _ = scene.rig(t, width, height)
    return Pair(f0, f1, sr.ClientRequest(camera, t), scene)


@pytest.fixture(scope="session")
def pair() -> Pair:
    """A small dynamic pair (48x32 main, 24x16 auxiliary cameras), client at frame 7 of 120 FPS."""
    return make_pair()
