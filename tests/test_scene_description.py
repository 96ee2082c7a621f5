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


@pytest.mark.parametrize(
    ("doc", "problem"),
    [
        ('["courtyard"]', 'expected an object with a "scene" name'),
        ('{"variant": "static"}', 'expected an object with a "scene" name'),
        ('{"scene": 3}', 'expected an object with a "scene" name'),
        ('{"scene": "courtyard", "models": [3]}',
         r"models\[0\]: expected an object with path and position"),
        ('{"scene": "courtyard", "models": [{"path": "quad.gltf"}]}',
         r"models\[0\]: expected an object with path and position"),
        ('{"scene": "courtyard", "models": [{"position": [0, 0, 0]}]}',
         r"models\[0\]: expected an object with path and position"),
        ('{"scene": "courtyard", "models": [{"path": "quad.gltf", "position": [0, 0, 0], '
         '"colour": 1, "yaw": 2}]}', r"models\[0\]: unknown keys \['colour', 'yaw'\]"),
    ],
)
def test_description_structure_is_checked(tmp_path: Path, doc: str, problem: str) -> None:
    _write_quad(tmp_path)
    desc = tmp_path / "scene.json"
    desc.write_text(doc)
    with pytest.raises(sr.InvalidInputError, match=rf"scene\.json: {problem}$"):
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


def test_description_models_null_is_named_as_json(tmp_path: Path) -> None:
    # "got NoneType": the Python name of JSON's null.
    desc = tmp_path / "scene.json"
    desc.write_text('{"scene": "courtyard", "models": null}')
    with pytest.raises(sr.InvalidInputError,
                       match=r"scene\.json: models: expected an array of objects, got null$"):
        sr.Scene.from_description(desc)


def test_model_placement_keeps_an_animation_index_as_a_plain_int() -> None:
    m = sr.ModelPlacement("m.glb", (0, 0, 0), animation=np.int64(2))
    assert type(m.animation) is int and m.animation == 2
    assert sr.ModelPlacement("m.glb", (0, 0, 0), animation=None).animation is None
    with pytest.raises(sr.InvalidInputError, match=r"animation: expected an int in \[0, "):
        sr.ModelPlacement("m.glb", (0, 0, 0), animation=-1)


def test_model_placement_takes_a_pathlike(tmp_path: Path) -> None:
    # ModelPlacement took a pathlib.Path, and Scene(models=...) then raised TypeError ("cannot
    # be converted to 'PyString'") from the native constructor.
    model = sr.ModelPlacement(_write_quad(tmp_path), (0.0, 0.0, -3.0), animation=None)
    assert model.path == str(tmp_path / "quad.gltf")
    assert len(sr.Scene("courtyard", "static", [model]).models) == 1


@pytest.mark.parametrize("command", ["render", "serve"])
def test_cli_names_a_gltf_model_given_as_the_scene(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    # render said 'unknown scene ".../quad.gltf"'; serve read the model as a description
    # ("scene description is not UTF-8" for a GLB).
    model = _write_quad(tmp_path)
    args = (["render", str(model), "--out", str(tmp_path / "rec")] if command == "render"
            else ["serve", "--scene", str(model), "--port", "0"])
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert f"{model} is a glTF model, not a scene; expected a built-in scene" in err
    assert '"models": [{"path": "quad.gltf", "position": [0, 0, -3]}]' in err
    assert not (tmp_path / "rec").exists()


def test_render_cli_refuses_variant_with_a_description(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --variant was ignored: the description's own variant was rendered.
    _write_quad(tmp_path)
    desc = _describe(tmp_path)
    out = tmp_path / "rec"
    assert main(["render", str(desc), "--variant", "dynamic", "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"splitrender: error: --variant: only for a built-in scene; the scene description "
        f'{desc} names its own ("variant", default dynamic)\n'
    )
    assert not out.exists()


def test_render_cli_takes_a_description_named_in_upper_case(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # "scene.JSON" was taken for a built-in scene's name: 'unknown scene "...scene.JSON"'.
    desc = tmp_path / "scene.JSON"
    desc.write_text('{"scene": "courtyard", "models": 3}')
    assert main(["render", str(desc), "--out", str(tmp_path / "rec")]) == 2
    assert capsys.readouterr().err == (
        f"splitrender: error: {desc}: models: expected an array of objects, got an integer 3\n"
    )


def test_render_cli_force_keeps_a_model_inside_the_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --force replaced the recording folder, and the glTF model the description placed from
    # inside it went with the old recording (check_apart saw the description and trace only).
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "manifest.json").write_text("{}")  # what --force takes for a recording
    model = _write_quad(rec)
    desc = tmp_path / "scene.json"
    desc.write_text(json.dumps({"scene": "courtyard", "variant": "static", "models": [
        {"path": "rec/quad.gltf", "position": [0, 0, -3]}]}))
    args = ["render", str(desc), "--out", str(rec), "--force", "--seconds", "0.1",
            "--scale", "0.02", "--quiet"]
    assert main(args) == 2
    assert capsys.readouterr().err == (
        f"splitrender: error: {rec}: the output holds the glTF model {model}; expected a path "
        "outside it\n"
    )
    assert model.is_file() and (rec / "manifest.json").read_text() == "{}"
