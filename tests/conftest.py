"""Shared pytest configuration: hypothesis profiles and small synthetic fixtures.

Hypothesis profiles: ``ci`` (the default; 25 examples, no deadline, so slow shared CI machines do
not flake) and ``dev`` (more examples, for local runs). Select with ``HYPOTHESIS_PROFILE=dev``.
"""

from __future__ import annotations

import base64
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

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


#: The vertices of a 2 m x 2 m vertical quad facing +z (x in -1..1, y in 0..2): the glTF tests'
#: model, written by hand so that they need no asset.
QUAD_POSITIONS = [-1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 0.0, -1.0, 2.0, 0.0]


def quad_blob(positions: list[float] = QUAD_POSITIONS, *, animated: bool = False) -> bytes:
    """The quad's buffer: positions (48 bytes) and indices (12); with ``animated``, key times
    (8) and translations (24) of a 1 m move along x in 1 s."""
    blob = struct.pack("<12f", *positions) + struct.pack("<6H", 0, 1, 2, 0, 2, 3)
    if animated:
        blob += struct.pack("<2f", 0.0, 1.0) + struct.pack("<6f", 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    return blob


def quad_document(blob: bytes, *, animated: bool = False, material: bool = False) -> dict[str, Any]:
    """The glTF document of a :func:`quad_blob` buffer (embedded as a data URI): one node with
    the quad's mesh; with ``material`` a white base colour, with ``animated`` the translation
    animation (the blob must then hold its keys)."""
    primitive: dict[str, Any] = {"attributes": {"POSITION": 0}, "indices": 1}
    doc: dict[str, Any] = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [primitive]}],
        "buffers": [
            {
                "byteLength": len(blob),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode(),
            }
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-1, 0, 0], "max": [1, 2, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    }
    if material:
        primitive["material"] = 0
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}}]
    if animated:
        doc["bufferViews"] += [
            {"buffer": 0, "byteOffset": 60, "byteLength": 8},
            {"buffer": 0, "byteOffset": 68, "byteLength": 24},
        ]
        doc["accessors"] += [
            {"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR"},
            {"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"},
        ]
        doc["animations"] = [
            {
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
                "samplers": [{"input": 2, "output": 3}],
            }
        ]
    return doc
