"""Hostile glTF models placed from a scene description (issue 15): each reported example raises
InvalidInputError naming the file, what was wrong and what was expected, with no panic text on
stderr. The models are written by the tests (a quad with a translation animation)."""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import splitrender as sr
from conftest import QUAD_POSITIONS, quad_blob, quad_document


def _glb(doc: dict[str, Any], blob: bytes) -> bytes:
    del doc["buffers"][0]["uri"]
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    return (
        b"glTF"
        + struct.pack("<II", 2, total)
        + struct.pack("<I", len(js))
        + b"JSON"
        + js
        + struct.pack("<I", len(blob))
        + b"BIN\0"
        + blob
    )


def _place(folder: Path, model: bytes, name: str, **placement: object) -> sr.Scene:
    (folder / name).write_bytes(model)
    desc = folder / "scene.json"
    entry = {"path": name, "position": [0.0, 0.0, 0.0], **placement}
    desc.write_text(json.dumps({"scene": "courtyard", "variant": "static", "models": [entry]}))
    return sr.Scene.from_description(desc)


def _edited(
    edit: Callable[[dict[str, Any]], None], positions: list[float] = QUAD_POSITIONS
) -> bytes:
    blob = quad_blob(positions, animated=True)
    doc = quad_document(blob, animated=True)
    edit(doc)
    return json.dumps(doc).encode()


def _stride(d: dict[str, Any]) -> None:
    d["bufferViews"][0]["byteStride"] = 4


def _missing_node(d: dict[str, Any]) -> None:
    d["animations"][0]["channels"][0]["target"]["node"] = 99


def _sparse(d: dict[str, Any], accessor: int, count: int, given: int, values: int) -> None:
    """Accessor ``accessor`` made sparse: ``count`` elements, zero (no buffer view) but for the
    first ``given`` ones, whose indices are read from the quad's index view (0, 1, 2, ...) and
    values from view ``values``."""
    a = d["accessors"][accessor]
    del a["bufferView"]
    a["count"] = count
    a["sparse"] = {
        "count": given,
        "indices": {"bufferView": 1, "componentType": 5123},
        "values": {"bufferView": values},
    }


def _huge_sparse(d: dict[str, Any]) -> None:
    _sparse(d, 0, 500_000_000, 1, 0)


def _vec2(d: dict[str, Any]) -> None:
    d["accessors"][0]["type"] = "VEC2"


def _zero_quaternion(d: dict[str, Any]) -> None:
    d["nodes"][0]["rotation"] = [0, 0, 0, 0]


def _huge_matrix(d: dict[str, Any]) -> None:
    d["nodes"][0]["matrix"] = [1e39, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    d["animations"] = []


def _no_mesh(d: dict[str, Any]) -> None:
    del d["nodes"][0]["mesh"]


def _many_instances(d: dict[str, Any]) -> None:
    # A 300 kB file of 16,000 instances of one mesh took 14 s to render 0.01 s (every instant
    # the renderer takes places every object); one of 200,000 ran past 200 s.
    d["nodes"] += [{"mesh": 0} for _ in range(5000)]
    d["scenes"][0]["nodes"] = list(range(len(d["nodes"])))


def _keep(d: dict[str, Any]) -> None:
    pass


_NAN = [float("nan")] + QUAD_POSITIONS[1:]
_INF = QUAD_POSITIONS[:3] + [float("inf")] + QUAD_POSITIONS[4:]

CASES = [
    ("stride", _edited(_stride), "accessor 0 (POSITION): byteStride 4 is smaller than the element size 12"),
    ("missing_node", _edited(_missing_node), "animation 0 channel 0 targets node 99, which does not exist (1 nodes)"),
    ("huge_sparse", _edited(_huge_sparse), "accessor 0 (POSITION) with count 500000000: decoding it needs"),
    ("nan", _edited(_keep, _NAN), "accessor 0 (POSITION): element 0 is [NaN, 0.0, 0.0], expected finite numbers"),
    ("inf", _edited(_keep, _INF), "accessor 0 (POSITION): element 1 is [inf, 0.0, 0.0], expected finite numbers"),
    ("vec2", _edited(_vec2), "accessor 0 (POSITION): type VEC2, expected VEC3"),
    ("zero_quaternion", _edited(_zero_quaternion), "rotation [0.0, 0.0, 0.0, 0.0] has length 0, expected a unit quaternion"),
    ("huge_matrix", _edited(_huge_matrix), "node 0 matrix: value inf is not finite or beyond ±1e15"),
    ("no_mesh", _edited(_no_mesh), "the model's scene has no mesh node with triangles, expected at least one"),
    ("many_instances", _edited(_many_instances), "5001 mesh nodes to place beside the scene's"),
]


@pytest.mark.parametrize(("name", "model", "message"), CASES, ids=[c[0] for c in CASES])
def test_hostile_model_is_refused(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], name: str, model: bytes, message: str
) -> None:
    with pytest.raises(sr.InvalidInputError, match=rf"{name}\.gltf: .*{re.escape(message)}"):
        _place(tmp_path, model, f"{name}.gltf")
    assert "panicked" not in capfd.readouterr().err


def test_huge_placement_scale_is_refused(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(sr.InvalidInputError, match=r"placed with scale 1e40, .*expected at most 1e15 m"):
        _place(tmp_path, _edited(_keep), "quad.gltf", scale=1e40)
    assert "panicked" not in capfd.readouterr().err


def test_glb_length_beyond_the_file(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    blob = quad_blob(animated=True)
    glb = _glb(quad_document(blob, animated=True), blob)
    # The valid file loads, so the refusal below is the length's doing.
    _place(tmp_path, glb, "ok.glb")
    bad = glb[:8] + struct.pack("<I", 0xFFFFFFFF) + glb[12:]
    with pytest.raises(
        sr.InvalidInputError, match=re.escape(f"GLB header length 4294967295, expected 20..={len(glb)}")
    ):
        _place(tmp_path, bad, "bad.glb")
    assert "panicked" not in capfd.readouterr().err


def test_models_of_a_description_share_the_fixed_decode_allowance(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # Each model had 64 MiB of decoding on top of 64 bytes per byte of its file: a description
    # placing one 738-byte file 10 times held 0.9 GB, and up to 4,000 placements are allowed.
    def sparse(d: dict[str, Any]) -> None:
        _huge_sparse(d)
        d["accessors"][0]["count"] = 750_000  # 36 MB decoded: one fits in 64 MiB, two do not

    (tmp_path / "big.gltf").write_bytes(_edited(sparse))
    desc = tmp_path / "scene.json"
    entry = {"path": "big.gltf", "position": [0.0, 0.0, 0.0]}
    desc.write_text(json.dumps({"scene": "courtyard", "variant": "static", "models": [entry]}))
    sr.Scene.from_description(desc)  # alone it loads
    desc.write_text(json.dumps({"scene": "courtyard", "variant": "static",
                                "models": [entry, entry]}))
    with pytest.raises(sr.InvalidInputError, match=r"big\.gltf: accessor 0 \(POSITION\) with "
                       r"count 750000: .*a fixed allowance the models of a scene share"):
        sr.Scene.from_description(desc)
    assert "panicked" not in capfd.readouterr().err


def _sparse_indices(d: dict[str, Any]) -> None:
    # 999,999 indices from a sparse accessor: zero (no buffer view) but for the first three,
    # 0, 1, 2 (read from the quad's own indices): one triangle and 333,332 with every corner
    # at vertex 0, in a file of about a kilobyte.
    _sparse(d, 1, 999_999, 3, 1)


def _one_triangle(d: dict[str, Any]) -> None:
    d["accessors"][1]["count"] = 3


def test_a_sparse_accessor_of_coincident_triangles_loads_and_changes_no_pixel(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # The renderer's BVH build is quadratic in coincident triangle boxes: this file's
    # 333,332 degenerate triangles kept its load busy for hours. Triangles no ray can hit are
    # left out of the BVH (and copies share one entry); the image is the one triangle's.
    import subprocess
    import sys

    model = _edited(_sparse_indices)
    assert len(model) < 1500
    (tmp_path / "one.gltf").write_bytes(_edited(_one_triangle))
    (tmp_path / "sparse.gltf").write_bytes(model)
    pose = sr.Scene("courtyard", "static").server_pose(0, 10.0)
    spot = pose[:3, 3] - 3.0 * pose[:3, 2] - (0.0, 1.0, 0.0)
    for name in ("one", "sparse"):
        entry = {"path": f"{name}.gltf", "position": [float(v) for v in spot]}
        (tmp_path / f"{name}.json").write_text(
            json.dumps({"scene": "courtyard", "variant": "static", "models": [entry]}))
    # In a child process, so that a return of the stall fails this test instead of the run.
    script = (
        "import sys, splitrender as sr\n"
        "plain = sr.Scene('courtyard', 'static').server_frame(0, 0.03).main\n"
        "one, sparse = [sr.Scene.from_description(p).server_frame(0, 0.03).main\n"
        "               for p in sys.argv[1:]]\n"
        "print((one.color != plain.color).any(axis=2).mean(),\n"
        "      (sparse.color != one.color).sum(), (sparse.depth != one.depth).sum())\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "one.json"), str(tmp_path / "sparse.json")],
        capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    shown, colour, depth = done.stdout.split()
    assert float(shown) > 0.02, f"the triangle covers only {float(shown):.1%} of the image"
    assert (colour, depth) == ("0", "0"), done.stdout
    assert "panicked" not in capfd.readouterr().err
