"""glTF models placed into a built-in scene from a JSON description (issue 3)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import splitrender as sr
from conftest import quad_blob, quad_document
from splitrender.cli import main


def _write_quad(folder: Path) -> Path:
    """The quad of :func:`conftest.quad_document`, white: a big, visible model."""
    path = folder / "quad.gltf"
    path.write_text(json.dumps(quad_document(quad_blob(), material=True)))
    return path


def _describe(folder: Path, **model: object) -> Path:
    desc = folder / "scene.json"
    entry = {"path": "quad.gltf", "position": [0.0, 0.0, 0.0], "animation": None, **model}
    desc.write_text(json.dumps({"scene": "courtyard", "variant": "static", "models": [entry]}))
    return desc


def test_placed_model_is_rendered(tmp_path: Path) -> None:
    _write_quad(tmp_path)
    plain = sr.Scene("courtyard", "static")
    # In front of the first server camera, so it must cover part of the image.
    pose = np.asarray(plain._native.server_pose(0, 10.0))
    eye, forward = pose[:3, 3], -pose[:3, 2]
    spot = eye + 3.0 * forward
    desc = _describe(tmp_path, position=[float(spot[0]), float(spot[1]) - 1.0, float(spot[2])])
    placed = sr.Scene.from_description(desc)
    assert len(placed.models) == 1
    a = plain.server_frame(0, 0.04).main
    b = placed.server_frame(0, 0.04).main
    changed = (np.abs(a.color.astype(int) - b.color.astype(int)).sum(axis=2) > 0).mean()
    assert changed > 0.05, f"the model covers only {changed:.1%} of the image"
    # Nearer than the courtyard behind it where it shows.
    assert (b.depth >= a.depth - 1e-7).all()


def test_description_errors_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    with pytest.raises(sr.InvalidInputError, match="bad.json"):
        sr.Scene.from_description(bad)
    desc = _describe(tmp_path)  # the glTF file is missing
    with pytest.raises(sr.InvalidInputError, match="quad.gltf"):
        sr.Scene.from_description(desc)
    _write_quad(tmp_path)
    desc = _describe(tmp_path, scale=-1.0)
    with pytest.raises(sr.InvalidInputError, match="scale"):
        sr.Scene.from_description(desc)
    desc.write_text(json.dumps({"scene": "courtyard", "oops": 1}))
    with pytest.raises(sr.InvalidInputError, match="unknown keys"):
        sr.Scene.from_description(desc)
    # Found by the fuzz suite: a number raised TypeError, a string was walked letter by letter.
    for models in ("Infinity", "3", '"quad.gltf"', '{"path": "quad.gltf"}'):
        desc.write_text(f'{{"scene": "courtyard", "models": {models}}}')
        with pytest.raises(sr.InvalidInputError, match="models: expected an array of objects"):
            sr.Scene.from_description(desc)


def test_description_must_be_a_small_regular_file(tmp_path: Path) -> None:
    # /dev/zero reports st_size 0: it was read until memory ran out.
    zero = tmp_path / "zero.json"
    zero.symlink_to("/dev/zero")
    with pytest.raises(sr.InvalidInputError, match="zero.json: scene description is a character"):
        sr.Scene.from_description(zero)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)
    with pytest.raises(sr.InvalidInputError, match="deep.json: .*nested too deeply"):
        sr.Scene.from_description(deep)


@pytest.mark.parametrize("value", ["1e400", "1e300", "2.5", "true", '"2"'])
def test_description_animation_must_be_a_whole_number(tmp_path: Path, value: str) -> None:
    # 1e400 (infinity) and 1e300 raised OverflowError converting to the native index.
    desc = tmp_path / "scene.json"
    desc.write_text(
        '{"scene": "courtyard", "models": [{"path": "m.glb", "position": [0, 0, 0], '
        f'"animation": {value}}}]}}'
    )
    with pytest.raises(sr.InvalidInputError, match=r"scene.json: models\[0\]: .*animation"):
        sr.Scene.from_description(desc)


def test_render_cli_accepts_a_description(tmp_path: Path) -> None:
    _write_quad(tmp_path)
    desc = _describe(tmp_path)
    out = tmp_path / "rec"
    args = ["render", str(desc), "--out", str(out), "--seconds", "0.1", "--scale", "0.03", "--quiet"]
    assert main(args) == 0
    assert sr.load_recording(out).scene == "courtyard"


@pytest.mark.parametrize(
    ("entry", "problem"),
    [
        # The string was walked as the position (1, 2, 3).
        ({"position": "123"}, r"models\[0\]: position: expected an array of 3 numbers, got a "
                              r'string "123"'),
        # ... and "1e5" failed with "could not convert string to float: 'e'".
        ({"position": "1e5"}, r'models\[0\]: position: expected an array of 3 numbers, got a '
                              r'string "1e5"'),
        ({"position": [1, 2]}, r"models\[0\]: position: expected an array of 3 numbers, got an "
                               r"array \[1, 2\]"),
        ({"position": [1, 2, 3, 4]}, r"models\[0\]: position: expected an array of 3 numbers"),
        ({"position": [0, True, 0]}, r"models\[0\]: position: expected an array of 3 numbers, "
                                     r"got an array \[0, true, 0\]"),
        ({"position": [0, "2", 0]}, r"models\[0\]: position: expected an array of 3 numbers"),
        ({"position": {"x": 0}}, r"models\[0\]: position: expected an array of 3 numbers, got "
                                 r"an object"),
        # true was 1.0, "2" was 2.0.
        ({"yaw_deg": True}, r"models\[0\]: yaw_deg: expected a number, got true"),
        ({"scale": "2"}, r'models\[0\]: scale: expected a number, got a string "2"'),
        ({"time_offset": None}, r"models\[0\]: time_offset: expected a number, got null"),
        ({"speed": [1]}, r"models\[0\]: speed: expected a number, got an array \[1\]"),
        # 3 was the path "3".
        ({"path": 3}, r"models\[0\]: path: expected a string, got an integer 3"),
    ],
)
def test_description_values_must_have_their_json_type(
    tmp_path: Path, entry: dict[str, object], problem: str
) -> None:
    _write_quad(tmp_path)
    desc = _describe(tmp_path, **entry)
    with pytest.raises(sr.InvalidInputError, match=rf"scene\.json: {problem}"):
        sr.Scene.from_description(desc)
    # Values of their JSON type load, an int as a number like a float (JSON has one number).
    desc = _describe(tmp_path, position=[1, 0.5, -3], yaw_deg=90, scale=2, time_offset=0,
                     speed=1.5)
    (m,) = sr.Scene.from_description(desc).models
    assert m.position == (1.0, 0.5, -3.0) and (m.yaw_deg, m.scale, m.speed) == (90.0, 2.0, 1.5)


@pytest.mark.parametrize(("variant", "got"), [("null", "null"), ("3", "an integer 3"),
                                              ('["static"]', r'an array \["static"\]')])
def test_description_variant_must_be_a_string(tmp_path: Path, variant: str, got: str) -> None:
    # null was the variant "None" (an unknown variant), ["static"] the variant "['static']".
    desc = tmp_path / "scene.json"
    desc.write_text(f'{{"scene": "courtyard", "variant": {variant}}}')
    with pytest.raises(sr.InvalidInputError,
                       match=rf"scene\.json: variant: expected a string, got {got}$"):
        sr.Scene.from_description(desc)
