"""Import/export of the authors' dataset layout (splitrender.scene.dataset; REFERENCE.md §1)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

import splitrender as sr
from splitrender import _native
from splitrender.scene import dataset
from splitrender.scene.dataset import (
    DatasetError,
    bits_from_rgba,
    bits_to_rgba,
    dataset_info,
    import_dataset_as_recording,
    matrix_to_unity,
    motion_from_theirs,
    motion_to_theirs,
)

_HALF_REL = 2.0**-11  # half float: 11 significant bits, round to nearest
_HALF_ABS = 2.0**-24  # subnormal spacing


def _half_ok(a: np.ndarray, b: np.ndarray) -> bool:
    """|a − b| within the half-float rounding bound of ``a``."""
    return bool(np.all(np.abs(a - b) <= np.abs(a) * _HALF_REL + _HALF_ABS))


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> sr.Recording:
    d = tmp_path_factory.mktemp("rec")
    return sr.load_recording(sr.write_recording(d / "r", "courtyard", seconds=0.25, scale=0.04))


@pytest.fixture(scope="module")
def exported(recording: sr.Recording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return sr.export_dataset(recording, tmp_path_factory.mktemp("ds") / "out")


def test_layout(recording: sr.Recording, exported: Path) -> None:
    for cam in ("main", "left", "right"):
        d = exported / cam
        cj = json.loads((d / "cam.json").read_text())
        assert len(cj["frames"]) == len(recording.server_frames)
        assert set(cj["frames"][0]["w2c"]) == {f"e{r}{c}" for r in range(4) for c in range(4)}
        assert cj["serverFps"] == recording.fs and cj["clientFps"] == recording.fc
        assert cj["shadowFps"] == recording.fs * recording.subframes
        for sub in ("color", "depth", "forwardFlowField", "backwardFlowField",
                    "forwardShadowInfo", "forwardShadowColorA", "forwardShadowColorB",
                    "backwardShadowInfo", "backwardShadowColorA", "backwardShadowColorB"):
            assert (d / sub).is_dir(), sub
        assert (d / "color" / "0000.png").is_file()
        hdr = OpenEXR.File(str(d / "depth" / "0000.exr"), header_only=True).header()
        assert len(hdr["channels"]) == 1
        with OpenEXR.File(str(d / "forwardFlowField" / "0000.exr"), separate_channels=True) as f:
            ch = f.channels()
            assert set(ch) == {"R", "G", "B"} and ch["R"].pixels.dtype == np.float16
        # Backward buffers are numbered by the older frame: none for the last frame's idx.
        last = len(recording.server_frames) - 1
        assert not (d / "backwardFlowField" / f"{last:04d}.exr").exists()
        with Image.open(d / "forwardShadowInfo" / "0000.png") as im:
            assert im.mode == "RGBA"
    assert len(json.loads((exported / "client_ol" / "cam.json").read_text())["frames"]) == len(
        recording.client_frames
    )


def test_round_trip(recording: sr.Recording, exported: Path) -> None:
    imp = sr.import_dataset(exported)
    orig = list(recording.server_frames)
    assert len(imp.server_frames) == len(orig)
    for k, (a, b) in enumerate(zip(orig, imp.server_frames)):
        assert b.index == a.index and b.time == pytest.approx(a.time)
        assert len(b.aux) == len(a.aux) == 2
        for ca, cb in zip((a.main, *a.aux), (b.main, *b.aux)):
            assert cb.camera.shape == ca.camera.shape
            np.testing.assert_allclose(cb.camera.view, ca.camera.view, atol=1e-6, rtol=0)
            np.testing.assert_allclose(cb.camera.proj, ca.camera.proj, atol=1e-6, rtol=0)
            np.testing.assert_array_equal(cb.color, ca.color)
            assert _half_ok(ca.depth, cb.depth), f"depth of frame {k}"
            assert ca.motion_fwd is not None and cb.motion_fwd is not None
            assert _half_ok(ca.motion_fwd, cb.motion_fwd), f"motion_fwd of frame {k}"
            assert ca.shadow_fwd is not None and cb.shadow_fwd is not None
            for x, y in zip(ca.shadow_fwd.to_native(), cb.shadow_fwd.to_native()):
                np.testing.assert_array_equal(x, y)
            if k == 0:  # toward frame -1: no slot in the layout
                assert cb.motion_bwd is None and cb.shadow_bwd is None
                continue
            assert ca.motion_bwd is not None and cb.motion_bwd is not None
            assert _half_ok(ca.motion_bwd, cb.motion_bwd), f"motion_bwd of frame {k}"
            assert ca.shadow_bwd is not None and cb.shadow_bwd is not None
            for x, y in zip(ca.shadow_bwd.to_native(), cb.shadow_bwd.to_native()):
                np.testing.assert_array_equal(x, y)
    cf = list(recording.client_frames)
    assert len(imp.client_requests) == len(cf) == len(imp.ground_truth)
    for c, r, g in zip(cf, imp.client_requests, imp.ground_truth):
        assert r.time == pytest.approx(c.time)
        np.testing.assert_allclose(r.camera.view, c.camera.view, atol=1e-6, rtol=0)
        np.testing.assert_allclose(r.camera.proj, c.camera.proj, atol=1e-6, rtol=0)
        assert g is not None
        np.testing.assert_array_equal(g, c.ground_truth)
    info = dataset_info(exported)
    assert info.server_fps == recording.fs and info.client_fps == recording.fc
    assert info.subframes == recording.subframes


def _half_depth(f: sr.ServerFrame) -> sr.ServerFrame:
    def cam(c: sr.CameraFrame) -> sr.CameraFrame:
        return dataclasses.replace(c, depth=c.depth.astype(np.float16).astype(np.float32))

    return sr.ServerFrame(f.index, f.time, cam(f.main), tuple(cam(a) for a in f.aux))


def test_imported_frames_reproject_alike(recording: sr.Recording, exported: Path) -> None:
    imp = sr.import_dataset(exported)
    cams = [c.camera for c in recording.client_frames]
    opts = sr.ReprojectOptions(shadow_subframes=recording.subframes, server_fps=recording.fs)
    orig = list(recording.server_frames)
    a = sr.play(orig, cams, fps=recording.fc, options=opts)
    b = sr.play(imp.server_frames, [r.camera for r in imp.client_requests], fps=recording.fc,
                options=opts)
    same = [float(np.mean(np.all(x == y, axis=-1))) for x, y in zip(a.images, b.images)]
    # Half-float depth moves a few depth-test decisions at edges (eps_z = 0.001 vs a half ulp of
    # 2^-11 near Z = 1): on this recording 99.55 % of pixels are identical on average and at
    # least 98.99 % in every frame.
    assert np.mean(same) >= 0.99, f"only {np.mean(same):.2%} of pixels identical on average"
    assert min(same) >= 0.98, f"client frame {int(np.argmin(same))}: only {min(same):.2%}"
    # ... and that is all of it: the originals with their depth rounded to half reproject to
    # exactly the imported frames' images (motion rounding changes no pixel here).
    c = sr.play([_half_depth(f) for f in orig], cams, fps=recording.fc, options=opts)
    for n, (x, y) in enumerate(zip(c.images, b.images)):
        np.testing.assert_array_equal(x, y, err_msg=f"client frame {n}")


def test_export_refuses_non_empty(recording: sr.Recording, exported: Path) -> None:
    with pytest.raises(DatasetError, match="not an empty directory"):
        sr.export_dataset(recording, exported)


@pytest.mark.parametrize(
    ("aux_names", "client", "what"),
    [
        (("../../x", "right"), "client_ol", r"aux_names\[0\]"),
        (("left", "a/b"), "client_ol", r"aux_names\[1\]"),
        (("left", "right"), "..", "client"),
        (("left", "right"), "", "client"),
        (("left", "right"), "/tmp/elsewhere", "client"),
        (("left", "c:\\x"), "client_ol", r"aux_names\[1\]"),
    ],
)
def test_export_names_stay_inside_the_output(
    recording: sr.Recording, tmp_path: Path, aux_names: tuple[str, str], client: str, what: str
) -> None:
    # Issue 15: aux_names=("../../x", ...) wrote outside the output folder.
    out = tmp_path / "a" / "b" / "ds"
    with pytest.raises(DatasetError, match=f"{what}: expected a plain name"):
        sr.export_dataset(recording, out, aux_names=aux_names, client=client)
    assert list(tmp_path.rglob("*")) == []


@pytest.mark.parametrize(
    ("aux_names", "client", "problem"),
    [
        (("left",), "client_ol", r"2 auxiliary cameras but only 1 aux_names"),
        (("left", "left"), "client_ol",
         r"camera directory names must differ, got \['main', 'left', 'left', 'client_ol'\]"),
        (("main", "right"), "client_ol", r"camera directory names must differ"),
        (("left", "right"), "right", r"camera directory names must differ"),
    ],
)
def test_export_names_each_camera_a_folder_of_its_own(
    recording: sr.Recording, tmp_path: Path, aux_names: tuple[str, ...], client: str,
    problem: str,
) -> None:
    # One folder for two cameras would have held the files of the one written last.
    out = tmp_path / "ds"
    with pytest.raises(DatasetError, match=problem):
        sr.export_dataset(recording, out, aux_names=aux_names, client=client)
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_export_leaves_no_dataset(
    recording: sr.Recording, exported: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 15: the export wrote in place, so a failure left a dataset with cameras or frames
    # missing under the final name.
    from splitrender.scene import dataset

    write_png, calls = dataset.write_png, []

    def full_disk(*args: object, **kwargs: object) -> None:
        calls.append(1)
        if len(calls) == 20:
            raise OSError(28, "No space left on device")
        write_png(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(dataset, "write_png", full_disk)
    empty = tmp_path / "empty"
    empty.mkdir()
    for out in (tmp_path / "new" / "ds", empty):
        calls.clear()
        with pytest.raises(OSError, match="No space left"):
            sr.export_dataset(recording, out)
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == ["empty", "new"]
    monkeypatch.undo()
    sr.export_dataset(recording, empty)  # an empty folder is replaced by the finished export
    assert sorted(p.name for p in empty.iterdir()) == sorted(p.name for p in exported.iterdir())


def test_an_export_keeps_what_another_run_wrote_meanwhile(
    recording: sr.Recording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Two exports to one new folder: the second to finish failed on the rename with an
    # OSError naming its hidden temporary folder ("Directory not empty").
    out = tmp_path / "ds"
    write_layout = dataset._write_layout

    def another_run_finishes_first(*args: object, **kwargs: object) -> None:
        write_layout(*args, **kwargs)  # type: ignore[arg-type]
        out.mkdir()
        (out / "theirs").write_text("kept")

    monkeypatch.setattr(dataset, "_write_layout", another_run_finishes_first)
    with pytest.raises(DatasetError, match=f"^{out}: appeared while this one was written"):
        sr.export_dataset(recording, out)
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # the temporary folder removed
    assert [p.name for p in out.iterdir()] == ["theirs"]


def test_export_and_import_refuse_an_output_inside_the_input(
    recording: sr.Recording, exported: Path
) -> None:
    before = sorted(p.name for p in recording.path.iterdir())
    for out in (recording.path, recording.path / "ds"):
        with pytest.raises(DatasetError, match="the output (is|lies inside) the recording"):
            sr.export_dataset(recording, out)
    assert sorted(p.name for p in recording.path.iterdir()) == before
    with pytest.raises(DatasetError, match="the output is the dataset"):
        import_dataset_as_recording(exported, exported, overwrite=True)
    with pytest.raises(DatasetError, match="the output holds the dataset"):
        import_dataset_as_recording(exported, exported.parent, overwrite=True)
    assert (exported / "main" / "cam.json").is_file()


# ----------------------------------------------------------------------------------------------
# A hand-written dataset: a 4x4 camera at the origin looking down -z at the plane z = -2.

N, F = 1.0, 3.0
A, B = N / (F - N), F * N / (F - N)
# Unity 2022.3 style: right-handed view (looks along -z), reversed-Z [0, 1] projection, y up.
PROJ = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, A, B], [0, 0, -1.0, 0]])  # 90° fov
VIEW = np.eye(4)
D_PLANE = (-2.0 * A + B) / 2.0  # reversed device depth of z_view = -2: 0.25


def _write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {k: v.astype(np.float16) for k, v in channels.items()}).write(str(path))


def _write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def _their_normalised(proj: np.ndarray) -> np.ndarray:
    """REFERENCE.md §1.3: P = F_y · D · Z · P_stored."""
    z = np.diag([1.0, 1, -1, 1])
    z[2, 3] = 1.0  # z -> w - z
    d = np.diag([1.0, 1, 2, 1])
    d[2, 3] = -1.0  # z -> 2z - w
    fy = np.diag([1.0, -1, 1, 1])
    return fy @ d @ z @ proj


@pytest.fixture()
def handmade(tmp_path: Path) -> Path:
    root = tmp_path / "ds"
    frames = [{"idx": i, "w2c": matrix_to_unity(VIEW), "proj": matrix_to_unity(PROJ)} for i in (7, 8)]
    for cam in ("main",):
        d = root / cam
        d.mkdir(parents=True)
        (d / "cam.json").write_text(json.dumps(
            {"frames": frames, "resolution": {"x": 4, "y": 4}, "serverFps": 10, "shadowFps": 40}))
        for idx in (7, 8):
            color = np.zeros((4, 4, 3), np.uint8)
            color[0] = (255, 0, 0)  # first stored row: red
            color[:, 0] = (0, 0, 255)  # first column: blue
            _write_png(d / "color" / f"{idx:04d}.png", color)
            _write_exr(d / "depth" / f"{idx:04d}.exr", {"Z": np.full((4, 4), D_PLANE)})
        flow = np.broadcast_to(np.array([0.5, 0.5, -0.2]), (4, 4, 3))
        for kind in ("forwardFlowField", "backwardFlowField"):
            _write_exr(d / kind / "0007.exr", {c: flow[..., i] for i, c in enumerate("RGB")})
        info = np.zeros((4, 4, 4), np.uint8)
        info[..., :3] = (0x12, 0x34, 0x56)
        info[..., 3] = 7  # ignored
        _write_png(d / "forwardShadowInfo" / "0007.png", info)
        _write_png(d / "forwardShadowColorA" / "0007.png", np.full((4, 4, 4), 9, np.uint8))
        _write_png(d / "forwardShadowColorB" / "0007.png", np.full((4, 4, 4), 200, np.uint8))
    c = root / "client_ol"
    c.mkdir()
    (c / "cam.json").write_text(json.dumps({"frames": [frames[0]], "clientFps": 120}))
    return root


def test_handmade_conventions(handmade: Path) -> None:
    # Our projection is the same Unity-style matrix.
    np.testing.assert_allclose(_native.perspective(90.0, 1.0, N, F), PROJ, atol=1e-12)
    imp = sr.import_dataset(handmade, aux=())
    assert len(imp.server_frames) == 2 and imp.server_frames[1].time == pytest.approx(0.1)
    f0, f1 = imp.server_frames[0].main, imp.server_frames[1].main
    np.testing.assert_array_equal(f0.camera.proj, PROJ)
    np.testing.assert_array_equal(f0.camera.view, VIEW)
    np.testing.assert_array_equal(f0.depth, np.float32(D_PLANE))  # depth unchanged
    assert tuple(f0.color[0, 1]) == (255, 0, 0) and tuple(f0.color[1, 0]) == (0, 0, 255)

    inv = np.linalg.inv(f0.camera.proj @ f0.camera.view)
    theirs = _their_normalised(PROJ) @ VIEW
    theirs_inv = np.linalg.inv(theirs)
    assert f0.motion_fwd is not None and f1.motion_bwd is not None
    assert f0.motion_bwd is None and f1.motion_fwd is None
    np.testing.assert_allclose(f0.motion_fwd, f1.motion_bwd)
    np.testing.assert_allclose(f0.motion_fwd[0, 0], [0.5, -0.5, 0.1], atol=1e-3)
    for j in range(4):
        for i in range(4):
            # Our pixel centre (y up, row 0 at the top) and reversed depth.
            p = np.array([(2 * i + 1) / 4 - 1, 1 - (2 * j + 1) / 4, f0.depth[j, i], 1.0])
            x = inv @ p
            x /= x[3]
            # On the plane z = -2, 90° fov: world (2x, 2y, -2); row 0 (red) is the top (y > 0).
            np.testing.assert_allclose(x[:3], [2 * p[0], 2 * p[1], -2.0], atol=1e-6)
            if j == 0:
                assert x[1] > 0
            # The reference's normalised NDC of that point: x, y_n = -y (row j), z_n = 1 - 2d.
            c = theirs @ x
            c /= c[3]
            np.testing.assert_allclose(
                c[:3], [2 * (i + 0.5) / 4 - 1, 2 * (j + 0.5) / 4 - 1, 1 - 2 * D_PLANE], atol=1e-6
            )
            # Motion: adding theirs in their NDC and ours in ours gives the same world point.
            t = theirs_inv @ np.append(c[:3] + [0.5, 0.5, -0.2], 1.0)
            o = inv @ np.append(p[:3] + f0.motion_fwd[j, i], 1.0)
            np.testing.assert_allclose(t[:3] / t[3], o[:3] / o[3], rtol=2e-3, atol=2e-3)
    assert f0.shadow_fwd is not None and f1.shadow_bwd is None
    assert int(f0.shadow_fwd.bits[2, 3]) == 0x123456
    assert np.all(f0.shadow_fwd.s_min == 9) and np.all(f0.shadow_fwd.s_max == 200)
    (r,) = imp.client_requests
    assert r.camera.shape == (4, 4) and r.time == 0.0
    assert imp.ground_truth == [None]


def test_handmade_colorb_missing_uses_base(handmade: Path) -> None:
    shutil.rmtree(handmade / "main" / "forwardShadowColorB")
    f0 = sr.import_dataset(handmade, aux=()).server_frames[0].main
    assert f0.shadow_fwd is not None
    np.testing.assert_array_equal(f0.shadow_fwd.s_max, f0.color)


def test_conversions_invert() -> None:
    rng = np.random.default_rng(1)
    m = rng.normal(size=(5, 6, 3)).astype(np.float32)
    np.testing.assert_array_equal(motion_from_theirs(motion_to_theirs(m)), m)
    bits = rng.integers(0, 1 << 24, size=(5, 6), dtype=np.uint32)
    np.testing.assert_array_equal(bits_from_rgba(bits_to_rgba(bits)), bits)
    with pytest.raises(DatasetError):
        bits_to_rgba(np.full((1, 1), 1 << 24, np.uint32))


def test_error_missing_cam_json(handmade: Path) -> None:
    (handmade / "main" / "cam.json").unlink()
    with pytest.raises(DatasetError, match=r"main[/\\]cam\.json: missing file"):
        sr.import_dataset(handmade, aux=())


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        # serverFps of 401 digits: math.isfinite() of it raised OverflowError.
        ('{"serverFps": 1' + "0" * 400 + "}", "integer of 401 digits"),
        ('{"frames": ' + "[" * 100_000, "nested too deeply"),
    ],
)
def test_error_hostile_cam_json(handmade: Path, text: str, problem: str) -> None:
    (handmade / "main" / "cam.json").write_text(text)
    with pytest.raises(DatasetError, match=rf"main[/\\]cam\.json: .*{problem}"):
        sr.import_dataset(handmade, aux=())


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"resolution": [160, 90]}, r"resolution: expected \{x, y\}, got \[160, 90\]"),
        ({"frames": {}}, r"frames: expected a non-empty array"),
        ({"frames": []}, r"frames: expected a non-empty array"),
        ({"frames": [7]}, r"frames\[0\]: expected an object"),
        ({"frames": [{"idx": -1}]}, r"frames\[0\].idx: expected an int >= 0, got -1"),
        ({"frames": [{"idx": True}]}, r"frames\[0\].idx: expected an int >= 0, got True"),
    ],
)
def test_error_cam_json_of_another_shape(
    handmade: Path, change: dict[str, object], problem: str
) -> None:
    cam = handmade / "main" / "cam.json"
    cam.write_text(json.dumps({**json.loads(cam.read_text()), **change}))
    with pytest.raises(DatasetError, match=rf"main[/\\]cam\.json: {problem}"):
        sr.import_dataset(handmade, aux=())


def test_error_frame_rates_out_of_range(handmade: Path) -> None:
    # shadowFps / serverFps was an infinity, and floor() of it raised OverflowError.
    cam = handmade / "main" / "cam.json"
    m = json.loads(cam.read_text())
    cam.write_text(json.dumps({**m, "serverFps": 1e-300, "shadowFps": 1e300}))
    with pytest.raises(DatasetError, match=r"cam\.json: serverFps: expected a number in"):
        dataset_info(handmade, client=None).subframes


def test_error_cam_json_not_a_regular_file(handmade: Path) -> None:
    (handmade / "main" / "cam.json").unlink()
    (handmade / "main" / "cam.json").symlink_to("/dev/zero")
    with pytest.raises(DatasetError, match=r"cam\.json: camera file is a character device"):
        sr.import_dataset(handmade, aux=())


def test_error_missing_file(handmade: Path) -> None:
    (handmade / "main" / "depth" / "0008.exr").unlink()
    with pytest.raises(DatasetError, match=r"depth[/\\]0008\.exr: missing file"):
        sr.import_dataset(handmade, aux=())
    with pytest.raises(DatasetError, match=r"left: missing auxiliary camera directory"):
        sr.import_dataset(handmade)


def test_error_broken_png(handmade: Path) -> None:
    # Found by the fuzz suite: Pillow reports a malformed chunk as SyntaxError.
    p = handmade / "main" / "color" / "0007.png"
    data = p.read_bytes()
    at = data.index(b"IDAT") - 4
    n = int.from_bytes(data[at : at + 4], "big")
    # IDAT declared 8 bytes short: the image data runs on into what is read as the next chunk.
    p.write_bytes(data[:at] + (n - 8).to_bytes(4, "big") + data[at + 4 :])
    with pytest.raises(DatasetError, match=r"color[/\\]0007\.png: cannot read PNG"):
        sr.import_dataset(handmade, aux=())


def test_error_png_whose_first_chunk_is_not_ihdr(handmade: Path) -> None:
    # Pillow opens a PNG with a text chunk ahead of IHDR; the bit depth is read from the IHDR
    # at its fixed place, so such a file is refused rather than read at another chunk's bytes.
    p = handmade / "main" / "color" / "0007.png"
    data = p.read_bytes()
    text = b"tEXt" + b"k\x00v"
    chunk = struct.pack(">I", 3) + text + struct.pack(">I", zlib.crc32(text))
    p.write_bytes(data[:8] + chunk + data[8:])
    with pytest.raises(DatasetError, match=r"color[/\\]0007\.png: cannot read PNG: the first "
                                           r"chunk is not IHDR$"):
        sr.import_dataset(handmade, aux=())


def test_error_wrong_resolution(handmade: Path) -> None:
    _write_png(handmade / "main" / "color" / "0007.png", np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"color[/\\]0007\.png: resolution 5x4 .* 4x4"):
        sr.import_dataset(handmade, aux=())


def test_error_wrong_exr_resolution_and_channels(handmade: Path) -> None:
    _write_exr(handmade / "main" / "depth" / "0007.exr", {"Z": np.zeros((3, 4))})
    with pytest.raises(DatasetError, match=r"depth[/\\]0007\.exr: resolution 4x3"):
        sr.import_dataset(handmade, aux=())
    _write_exr(handmade / "main" / "depth" / "0007.exr",
               {"R": np.zeros((4, 4)), "G": np.zeros((4, 4))})
    with pytest.raises(DatasetError, match=r"0007\.exr: expected a single-channel depth EXR"):
        sr.import_dataset(handmade, aux=())


def test_error_a_file_that_is_not_an_exr(handmade: Path) -> None:
    # A PNG named .exr: refused by its first four bytes, in our words.
    png = (handmade / "main" / "color" / "0007.png").read_bytes()
    (handmade / "main" / "depth" / "0007.exr").write_bytes(png)
    with pytest.raises(DatasetError, match=r"depth[/\\]0007\.exr: cannot read EXR: not an "
                                           r"OpenEXR file \(no magic number\)$"):
        sr.import_dataset(handmade, aux=())


def test_flow_with_an_alpha_channel_is_read_as_rgb(handmade: Path) -> None:
    # "R, G, B (A optional)": a flow EXR that also holds A reads the same motion.
    before = sr.import_dataset(handmade, aux=()).server_frames[0].main.motion_fwd
    flow = np.broadcast_to(np.array([0.5, 0.5, -0.2]), (4, 4, 3))
    _write_exr(handmade / "main" / "forwardFlowField" / "0007.exr",
               {**{c: flow[..., i] for i, c in enumerate("RGB")}, "A": np.ones((4, 4))})
    after = sr.import_dataset(handmade, aux=()).server_frames[0].main.motion_fwd
    assert before is not None and after is not None
    np.testing.assert_array_equal(after, before)


def test_error_singular_view_projection(handmade: Path) -> None:
    # Each matrix invertible alone, their product not (in the kernels' own test): w2c scales z
    # by 1e-11 and the projection's near plane lies at 100.
    near, far = 100.0, 1000.0
    proj = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0],
                     [0, 0, near / (far - near), far * near / (far - near)], [0, 0, -1.0, 0]])
    view = np.diag([1.0, 1.0, 1e-11, 1.0])
    assert _native.singular_camera(view, np.eye(4)) is None
    assert _native.singular_camera(np.eye(4), proj) is None
    frames = json.loads((handmade / "main" / "cam.json").read_text())["frames"]
    frames[1] = {**frames[1], "w2c": matrix_to_unity(view), "proj": matrix_to_unity(proj)}
    _edit_cam(handmade, "main", frames=frames)
    with pytest.raises(DatasetError, match=r"main[/\\]cam\.json: frames\[1\]: proj · w2c is "
                                           r"singular, expected an invertible view-projection$"):
        sr.import_dataset(handmade, aux=())


def test_error_bad_matrix(handmade: Path) -> None:
    p = handmade / "main" / "cam.json"
    cj = json.loads(p.read_text())
    del cj["frames"][1]["proj"]["e23"]
    p.write_text(json.dumps(cj))
    with pytest.raises(DatasetError, match=r"cam\.json: frames\[1\]\.proj: e23"):
        sr.import_dataset(handmade, aux=())
    cj["frames"][1]["proj"] = [1.0] * 16  # a flat list, not Unity's object
    p.write_text(json.dumps(cj))
    with pytest.raises(DatasetError, match=r"cam\.json: frames\[1\]\.proj: expected an object "
                                           r"with keys e00\.\.e33, got list$"):
        sr.import_dataset(handmade, aux=())


def _edit_cam(root: Path, cam: str, **fields: object) -> dict:
    """Rewrites ``root/cam/cam.json`` with ``fields`` replaced; returns the new document."""
    p = root / cam / "cam.json"
    doc = {**json.loads(p.read_text()), **fields}
    p.write_text(json.dumps(doc))
    return doc


def _recording_ready(root: Path) -> None:
    """Makes the handmade dataset importable as a recording: two aux cameras, ground truth."""
    for a in ("left", "right"):
        shutil.copytree(root / "main", root / a)
    _write_png(root / "client_ol" / "color" / "0007.png", np.zeros((4, 4, 3), np.uint8))


def test_a_recording_needs_the_client_folder_its_ground_truth_and_the_main_size(
    handmade: Path, tmp_path: Path
) -> None:
    """import_dataset_as_recording's own checks: a recording holds the ground truth at the
    main camera's size."""
    _recording_ready(handmade)
    out = tmp_path / "rec"

    def refused(match: str) -> None:
        with pytest.raises(DatasetError, match=match):
            import_dataset_as_recording(handmade, out)
        assert not out.exists()

    client = handmade / "client_ol"
    _edit_cam(handmade, "client_ol", resolution={"x": 8, "y": 4})
    refused(r"client_ol[/\\]cam\.json: client size 8x4, a recording needs the main camera's "
            r"4x4$")
    _edit_cam(handmade, "client_ol", resolution={"x": 4, "y": 4})
    shutil.rmtree(client / "color")
    refused(r"client_ol[/\\]color: missing; a recording needs the ground truth$")
    shutil.rmtree(client)
    refused(r"client_ol: missing client directory$")
    with pytest.raises(DatasetError, match=r"client_ol: missing client directory$"):
        sr.import_dataset(handmade)  # (the layout's own check: the above is dataset_info's)


@pytest.mark.parametrize("resolution", [{"x": 0, "y": 4}, {"x": 4, "y": True},
                                        {"x": 4.0, "y": 4}, {"x": 4, "y": 1 << 40}])
def test_error_resolution_out_of_range(handmade: Path, resolution: dict) -> None:
    _edit_cam(handmade, "main", resolution=resolution)
    with pytest.raises(DatasetError, match=r"main[/\\]cam\.json: resolution: expected ints in "
                                           r"1\.\.\d+, got "):
        sr.import_dataset(handmade, aux=())


def test_error_duplicate_idx(handmade: Path) -> None:
    # Two frames with one idx read the same colour, depth and pair files: accepted before.
    frames = json.loads((handmade / "main" / "cam.json").read_text())["frames"]
    _edit_cam(handmade, "main", frames=[frames[0], {**frames[1], "idx": 7}])
    with pytest.raises(
        DatasetError,
        match=r"main[/\\]cam\.json: frames\[0\] and frames\[1\] both have idx 7, expected a "
        r"distinct idx per frame",
    ):
        sr.import_dataset(handmade, aux=())
    with pytest.raises(DatasetError, match=r"both have idx 7"):
        dataset_info(handmade, client=None)
    # The client's idx names its ground truth alone: repeated without ground truth it reads no
    # file (the reference ignores it), with ground truth two client frames would share one.
    _edit_cam(handmade, "main", frames=frames)
    _edit_cam(handmade, "client_ol", frames=[frames[0], frames[0]])
    assert len(sr.import_dataset(handmade, aux=()).client_requests) == 2
    _write_png(handmade / "client_ol" / "color" / "0007.png", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(
        DatasetError, match=r"client_ol[/\\]cam\.json: frames\[0\] and frames\[1\] both have idx 7"
    ):
        sr.import_dataset(handmade, aux=())


def test_idx_may_decrease(handmade: Path) -> None:
    # Time and pairing follow the list order, the idx only names files (REFERENCE.md §1.2): the
    # handmade frames numbered 8, 7 read 0008 then 0007, and the pair (0, 1) the files 0008.
    main = handmade / "main"
    for kind in ("forwardFlowField", "backwardFlowField"):
        (main / kind / "0007.exr").rename(main / kind / "0008.exr")
    for kind in ("forwardShadowInfo", "forwardShadowColorA", "forwardShadowColorB"):
        (main / kind / "0007.png").rename(main / kind / "0008.png")
    frames = json.loads((main / "cam.json").read_text())["frames"]
    _edit_cam(handmade, "main", frames=[{**frames[0], "idx": 8}, {**frames[1], "idx": 7}])
    imp = sr.import_dataset(handmade, aux=())
    f0, f1 = imp.server_frames[0].main, imp.server_frames[1].main
    assert f0.motion_fwd is not None and f1.motion_bwd is not None and f0.shadow_fwd is not None


def _set(m: np.ndarray, r: int, c: int, v: float) -> np.ndarray:
    out = m.copy()
    out[r, c] = v
    return out


_GL = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, -(F + N) / (F - N), -2 * F * N / (F - N)],
                [0, 0, -1.0, 0]])  # OpenGL, depth [-1, 1] not reversed


@pytest.mark.parametrize(
    ("proj", "problem"),
    [
        (np.zeros((4, 4)), r"bottom row \(0, 0, 0, 0\), expected \(0, 0, -1, 0\): a perspective"),
        (np.diag([1.0, 1.0, -0.5, 1.0]), r"bottom row \(0, 0, 0, 1\), expected \(0, 0, -1, 0\)"),
        (_set(PROJ, 1, 1, 0.0), "singular matrix, expected an invertible perspective"),
        (_GL, r"near plane 3 and far plane 1\.5 \(from e22, e23\), expected a reversed-Z \[0, 1\]"),
        (_set(PROJ, 2, 2, 0.0), r"near plane 1\.5 and far plane inf .* 0 < near < far < inf"),
        (_set(PROJ, 2, 2, -1.0), r"near plane inf and far plane -1\.5"),
    ],
    ids=["zero", "orthographic", "singular", "opengl", "infinite-far", "near-infinite"],
)
def test_error_proj_not_a_reversed_z_perspective(
    handmade: Path, proj: np.ndarray, problem: str
) -> None:
    # Accepted before: play failed much later, or near/far fell back to 0.1 / 1000 unannounced.
    for cam in ("main", "client_ol"):
        p = handmade / cam / "cam.json"
        original = p.read_text()
        doc = json.loads(original)
        doc["frames"][-1]["proj"] = matrix_to_unity(proj)
        p.write_text(json.dumps(doc))
        k = len(doc["frames"]) - 1
        where = rf"{cam}[/\\]cam\.json: frames\[{k}\]\.proj: "
        with pytest.raises(DatasetError, match=where + problem):
            sr.import_dataset(handmade, aux=())
        p.write_text(original)


def test_error_singular_w2c(handmade: Path, tmp_path: Path) -> None:
    # Accepted by import_dataset; the recording import's np.linalg.inv raised LinAlgError.
    _recording_ready(handmade)
    for cam in ("main", "left", "right"):
        frames = json.loads((handmade / cam / "cam.json").read_text())["frames"]
        frames[0]["w2c"] = matrix_to_unity(np.zeros((4, 4)))
        _edit_cam(handmade, cam, frames=frames)
    match = r"main[/\\]cam\.json: frames\[0\]\.w2c: singular matrix, expected an invertible"
    with pytest.raises(DatasetError, match=match):
        sr.import_dataset(handmade)
    with pytest.raises(DatasetError, match=match):
        import_dataset_as_recording(handmade, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize(
    ("shadow_fps", "server_fps", "s"),
    [(5, 10, 0), (9.99, 10, 0), (130, 10, 13), (1000, 10, 100), (0.05, 0.1, 0)],
)
def test_error_shadow_subframes_out_of_range(
    handmade: Path, tmp_path: Path, shadow_fps: float, server_fps: float, s: int
) -> None:
    # S = floor(shadowFps / serverFps) was clamped into 1..16 without a word; the 24-bit
    # ShadowInfo holds 12 subframes, and S = 0 contradicts the shadow buffers this dataset has.
    _edit_cam(handmade, "main", shadowFps=shadow_fps, serverFps=server_fps)
    match = (
        rf"main[/\\]cam\.json: shadowFps: {shadow_fps:g} at serverFps {server_fps:g} gives "
        rf"floor\(shadowFps / serverFps\) = {s} shadow subframes, expected 1\.\.12 "
        rf"\(shadowFps from {server_fps:g} to below {13 * server_fps:g}\)"
    )
    with pytest.raises(DatasetError, match=match):
        dataset_info(handmade, client=None)
    _recording_ready(handmade)
    with pytest.raises(DatasetError, match=match):
        import_dataset_as_recording(handmade, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize(
    ("shadow_fps", "server_fps", "s"), [(10, 10, 1), (129.9, 10, 12), (0.7, 0.1, 7), (45, 10, 4)]
)
def test_shadow_subframes_floor_like_the_reference(
    handmade: Path, tmp_path: Path, shadow_fps: float, server_fps: float, s: int
) -> None:
    # REFERENCE.md §1.6 floors (0.7 / 0.1 is 6.999... in floats); the recording keeps S as is.
    _edit_cam(handmade, "main", shadowFps=shadow_fps, serverFps=server_fps)
    assert dataset_info(handmade, client=None).subframes == s
    _recording_ready(handmade)
    _edit_cam(handmade, "client_ol", clientFps=4 * server_fps)
    assert sr.load_recording(import_dataset_as_recording(handmade, tmp_path / "rec")).subframes == s


def test_no_shadow_subframes_without_shadow_buffers_is_taken_as_one(handmade: Path) -> None:
    # The reference plays such a dataset (without shadows); one subframe changes nothing.
    for d in handmade.iterdir():
        for sub in ("forward", "backward"):
            for kind in ("Info", "ColorA", "ColorB"):
                shutil.rmtree(d / f"{sub}Shadow{kind}", ignore_errors=True)
    _edit_cam(handmade, "main", shadowFps=5, serverFps=10)
    assert dataset_info(handmade, client=None).subframes == 1


# ----------------------------------------------------------------------------------------------
# Camera folder names and pixel formats on import (audit of the importer).


def _refused_everywhere(
    handmade: Path, tmp_path: Path, aux: tuple[str, str], client: str, match: str, info: bool
) -> None:
    """The names are refused by import_dataset, by import_dataset_as_recording (which writes
    nothing) and, with ``info``, by dataset_info."""
    _recording_ready(handmade)
    with pytest.raises(DatasetError, match=match):
        sr.import_dataset(handmade, aux=aux, client=client)
    with pytest.raises(DatasetError, match=match):
        import_dataset_as_recording(handmade, tmp_path / "rec", aux=aux, client=client)
    assert not (tmp_path / "rec").exists()
    if info:
        with pytest.raises(DatasetError, match=match):
            dataset_info(handmade, client=client)


@pytest.mark.parametrize(
    ("aux", "client", "what"),
    [
        (("../ds/left", "right"), "client_ol", r"aux\[0\]"),
        (("left", "a/b"), "client_ol", r"aux\[1\]"),
        (("left", ""), "client_ol", r"aux\[1\]"),
        (("..", "right"), "client_ol", r"aux\[0\]"),
        (("left", "right"), ".", "client"),
        (("left", "right"), "..", "client"),
        (("left", "right"), "../ds/client_ol", "client"),
        (("left", "c:\\x"), "client_ol", r"aux\[1\]"),
    ],
)
def test_import_camera_names_must_be_plain(
    handmade: Path, tmp_path: Path, aux: tuple[str, str], client: str, what: str
) -> None:
    # `--aux ../ds/left,right` read DIR/../ds/left and `--client .` DIR/cam.json; the export
    # already refused such names.
    _refused_everywhere(handmade, tmp_path, aux, client, f"{what}: expected a plain name",
                        info=what == "client")


def test_import_refuses_an_absolute_client_folder(handmade: Path) -> None:
    # A path of its own read a client folder from anywhere; it is a folder of the dataset.
    with pytest.raises(DatasetError, match="client: expected a plain name"):
        sr.import_dataset(handmade, aux=(), client=str(handmade / "client_ol"))


@pytest.mark.parametrize(
    ("aux", "client"),
    [
        (("left", "left"), "client_ol"),
        (("main", "right"), "client_ol"),
        (("left", "right"), "main"),
        (("left", "right"), "right"),
    ],
)
def test_import_camera_names_must_differ(
    handmade: Path, tmp_path: Path, aux: tuple[str, str], client: str
) -> None:
    # `--aux left,left` read one camera twice, `--client main` took the server's main colour
    # as the ground truth; the export refuses the same names.
    _refused_everywhere(handmade, tmp_path, aux, client,
                        r"camera directory names must differ, got \['main', ",
                        info=client == "main")


def _png_bytes(width: int, height: int, depth: int, colour_type: int, rows: bytes) -> bytes:
    """A PNG of any bit depth and colour type (Pillow writes no 16-bit RGB)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows))
            + chunk(b"IEND", b""))


def _save(path: Path, image: Image.Image, fmt: str = "PNG") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path, format=fmt)


def _grey16(path: Path) -> None:
    # 300 was read as 255.
    _save(path, Image.fromarray(np.full((4, 4), 300, np.uint16)))


def _rgb48(path: Path) -> None:
    # Each 16-bit sample was cut to its high byte.
    path.write_bytes(_png_bytes(4, 4, 16, 2, b"".join(b"\0" + b"\x01\x2c" * 12 for _ in range(4))))


@pytest.mark.parametrize(
    ("file", "write", "problem"),
    [
        ("main/color/0007.png", _grey16, r"a 16-bit PNG \(mode I;16\), expected 8 bits a sample"),
        ("main/color/0007.png", _rgb48, r"a 16-bit PNG \(mode RGB\), expected 8 bits a sample"),
        ("main/forwardShadowInfo/0007.png", _rgb48, r"a 16-bit PNG"),
        ("main/color/0007.png", lambda p: _save(p, Image.new("RGB", (4, 4)), "JPEG"),
         r"a JPEG file, expected an 8-bit PNG"),
    ],
    ids=["grey16", "rgb48", "info-rgb48", "jpeg"],
)
def test_import_refuses_a_png_that_is_not_8_bits_a_sample(
    handmade: Path, file: str, write: object, problem: str
) -> None:
    # Pillow read them without a word: a 16-bit grey 300 as 255, 16-bit RGB samples cut to
    # their high byte, a JPEG (lossy) named .png.
    path = handmade / file
    assert callable(write)
    write(path)
    name = file.replace("/", r"[/\\]").replace(".", r"\.")
    with pytest.raises(DatasetError, match=rf"{name}: {problem}"):
        sr.import_dataset(handmade, aux=())


def test_import_reads_every_8_bit_colour_type_as_the_authors_loader_does(
    handmade: Path,
) -> None:
    # Their loader reads every PNG as RGBA8 (REFERENCE.md §1.6), alpha ignored: grey, palette
    # and RGBA colour, an RGB shadow buffer are the same pixels as the RGB(A) files.
    before = sr.import_dataset(handmade, aux=())
    colour = handmade / "main" / "color" / "0007.png"
    rgb = np.asarray(Image.open(colour).convert("RGB"))
    info = handmade / "main" / "forwardShadowInfo" / "0007.png"
    rgba = np.asarray(Image.open(info).convert("RGBA"))
    for image in (Image.fromarray(rgb).convert("P"), Image.fromarray(rgb).convert("RGBA")):
        _save(colour, image)
        _save(info, Image.fromarray(rgba[..., :3]))  # RGB: no alpha
        after = sr.import_dataset(handmade, aux=())
        assert np.array_equal(after.server_frames[0].main.color,
                              before.server_frames[0].main.color)
        assert np.array_equal(after.server_frames[0].main.shadow_fwd.bits,
                              before.server_frames[0].main.shadow_fwd.bits)
    grey = handmade / "client_ol" / "color" / "0007.png"
    _write_png(grey, np.full((4, 4, 3), 77, np.uint8))
    want = sr.import_dataset(handmade, aux=()).ground_truth[0]
    _save(grey, Image.new("L", (4, 4), 77))
    assert np.array_equal(sr.import_dataset(handmade, aux=()).ground_truth[0], want)


# ----------------------------------------------------------------------------------------------
# A user-level audit of `splitrender dataset export/import`.


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``splitrender dataset ...``'s exit status and stderr."""
    from splitrender.cli.dispatch import main

    return main(["dataset", *argv, "--quiet"]), capsys.readouterr().err


def test_export_refuses_the_current_directory(
    recording: sr.Recording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # `dataset export REC --out .` in an empty folder was an internal error (ValueError: "."
    # has an empty name); `--out ../here` renamed the export over the working directory.
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    for out in (".", "../here"):
        with pytest.raises(DatasetError, match=rf"{re.escape(out)}: is the current directory"):
            sr.export_dataset(recording, out)
        code, err = _cli(["export", str(recording.path), "--out", out], capsys)
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith("splitrender: error: ") and "current directory" in err, err
    assert list(tmp_path.iterdir()) == [here] and list(here.iterdir()) == []


def test_export_names_the_output_when_its_folder_cannot_be_written(
    recording: sr.Recording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A read-only folder: the error named the hidden temporary folder (.ds.partial-123-0),
    # which the user never gave.
    mkdir = Path.mkdir

    def read_only(self: Path, *args: object, **kwargs: object) -> None:
        if self.parent == tmp_path:
            raise PermissionError(13, "Permission denied", str(self))
        mkdir(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "mkdir", read_only)
    with pytest.raises(PermissionError) as e:
        sr.export_dataset(recording, tmp_path / "ds")
    assert e.value.filename == str(tmp_path / "ds") and "partial" not in str(e.value)
    assert "no permission to write in its folder" in str(e.value)


def _exr_bomb(path: Path, kind: str) -> None:
    """``path``'s EXR rewritten with pixels beyond what its size in cam.json allows."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        pixels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    h, w = next(iter(pixels.values())).shape
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if kind == "part":  # a second part of 64x64 pixels, 8 channels
        big = {f"C{i}": np.zeros((64, 64), np.float16) for i in range(8)}
        second = dict(header, dataWindow=((0, 0), (63, 63)), displayWindow=((0, 0), (w - 1, h - 1)))
        OpenEXR.File([OpenEXR.Part(header, pixels, "a"), OpenEXR.Part(second, big, "b")]).write(
            str(path))
    elif kind == "channels":  # 64 more channels of the right size
        extra = {f"C{i}": np.zeros((h, w), np.float16) for i in range(64)}
        OpenEXR.File(header, {**pixels, **extra}).write(str(path))
    else:  # 32-bit unsigned integers for the depth
        OpenEXR.File(header, {k: (v * 1000).astype(np.uint32) for k, v in pixels.items()}).write(
            str(path))


@pytest.mark.parametrize(
    ("file", "kind", "problem"),
    [
        ("forwardFlowField/0007.exr", "part", r"2 parts, expected a single-part EXR"),
        ("depth/0007.exr", "part", r"2 parts, expected a single-part EXR"),
        ("forwardFlowField/0007.exr", "channels", r"expected channels R, G, B \(A optional\), "
         r"got channels \['B', 'C0', 'C1', 'C10', 'C11', 'C12', 'C13', 'C14'\] "
         r"\.\.\. \(67 in all\)"),
        ("depth/0007.exr", "uint", r"channel Z holds uint32 samples, expected half or float"),
    ],
    ids=["flow-two-parts", "depth-two-parts", "flow-extra-channels", "depth-uint"],
)
def test_import_refuses_exr_pixels_beyond_the_layout(
    handmade: Path, file: str, kind: str, problem: str
) -> None:
    # Every part and channel of an EXR was decoded (a 150 kB file with a second part of 3000 x
    # 3000 pixels took 135 MB; the size check covered part 0 alone), and integer depth was
    # read as float without a word.
    path = handmade / "main" / file
    _exr_bomb(path, kind)
    name = file.replace("/", r"[/\\]").replace(".", r"\.")
    with pytest.raises(DatasetError, match=rf"{name}: {problem}"):
        sr.import_dataset(handmade, aux=())


@pytest.mark.parametrize("special", ["/dev/zero", "dir"])
def test_import_names_a_buffer_that_is_not_a_regular_file(
    handmade: Path, special: str
) -> None:
    # Was "missing file" for a file that is there.
    path = handmade / "main" / "depth" / "0007.exr"
    path.unlink()
    if special == "dir":
        path.mkdir()
    else:
        path.symlink_to(special)
    with pytest.raises(DatasetError, match=r"0007\.exr: not a regular file \(a "):
        sr.import_dataset(handmade, aux=())


def test_import_reads_the_client_rate_from_the_client_cam_json(handmade: Path) -> None:
    # docs/dataset-format.md: clientFps from the client's cam.json, main's copy not read.
    _edit_cam(handmade, "main", clientFps=30)
    frames = json.loads((handmade / "client_ol" / "cam.json").read_text())["frames"]
    _edit_cam(handmade, "client_ol", clientFps=120, frames=frames * 2)
    times = [r.time for r in sr.import_dataset(handmade, aux=()).client_requests]
    assert times == [0.0, 1 / 120]
    assert dataset_info(handmade).client_fps == 120


def test_import_refuses_aux_frame_lists_of_another_length(handmade: Path) -> None:
    _recording_ready(handmade)
    frames = json.loads((handmade / "right" / "cam.json").read_text())["frames"]
    for aux_frames in (frames[:1], [*frames, {**frames[0], "idx": 9}]):
        _edit_cam(handmade, "right", frames=aux_frames)
        with pytest.raises(
            DatasetError,
            match=rf"right[/\\]cam\.json: {len(aux_frames)} frames, but main/cam\.json has 2",
        ):
            sr.import_dataset(handmade)


def _client_frames_at(handmade: Path, fc: float, count: int) -> None:
    """The hand-made dataset made recording-ready with ``count`` client frames at ``fc``, all
    at the first frame's pose, frame ``n``'s ground truth filled with the value ``n``."""
    _recording_ready(handmade)
    frames = json.loads((handmade / "client_ol" / "cam.json").read_text())["frames"]
    _edit_cam(handmade, "client_ol", clientFps=fc,
              frames=[{**frames[0], "idx": 7 + n} for n in range(count)])
    for n in range(count):
        _write_png(handmade / "client_ol" / "color" / f"{7 + n:04d}.png",
                   np.full((4, 4, 3), n, np.uint8))


def test_imported_recording_keeps_the_client_frames_between_server_frames(
    handmade: Path, tmp_path: Path
) -> None:
    # Server frames at 0 and 0.1 s; client frames at n / 40 s: those up to 0.1 s lie between
    # two server frames (or on the last), those after it are left out.
    _client_frames_at(handmade, 40, 7)
    rec = sr.load_recording(import_dataset_as_recording(handmade, tmp_path / "rec"))
    client = list(rec.client_frames)
    assert [c.time for c in client] == pytest.approx([0.0, 0.025, 0.05, 0.075, 0.1])
    assert [int(c.ground_truth[0, 0, 0]) for c in client] == [0, 1, 2, 3, 4]
    assert len(rec.server_frames) == 2


def test_import_refuses_more_client_frames_than_a_recording_holds(
    handmade: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # More than MAX_FRAMES client frames were read and written, and load_recording then refused
    # the recording ("... is more than 50000 frames"); now refused before any image is read.
    from splitrender.scene import dataset

    _recording_ready(handmade)
    frames = json.loads((handmade / "client_ol" / "cam.json").read_text())["frames"]
    _edit_cam(handmade, "client_ol", clientFps=40,
              frames=[{**frames[0], "idx": 7 + n} for n in range(4)])
    monkeypatch.setattr(dataset, "MAX_FRAMES", 3)
    read: list[Path] = []
    monkeypatch.setattr(dataset, "_read_png", lambda p, s: read.append(p))
    with pytest.raises(
        DatasetError,
        match=r"client_ol[/\\]cam\.json: 4 client frames lie between two server frames, a "
        r"recording holds at most 3",
    ):
        import_dataset_as_recording(handmade, tmp_path / "rec")
    assert read == [] and not (tmp_path / "rec").exists()


def test_export_writes_motion_beyond_half_range_as_infinite_without_a_warning(
    tmp_path: Path,
) -> None:
    # numpy's "RuntimeWarning: overflow encountered in cast" reached the command's stderr.
    import warnings

    from splitrender.scene import dataset

    motion = np.array([[[1e6, -1e6, 0.5]]], np.float32)
    path = tmp_path / "flow.exr"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dataset._write_exr(path, {c: motion[..., i] for i, c in enumerate("RGB")})
    back = dataset._read_exr(path, (1, 1), "flow")
    np.testing.assert_array_equal(back, [[[np.inf, -np.inf, 0.5]]])


# ----------------------------------------------------------------------------------------------
# The import as a recording holds one frame at a time (audit of the importer).


def _long_dataset(root: Path, n_server: int, w: int = 48, h: int = 32) -> int:
    """A dataset of ``n_server`` server frames of main, left and right (``w`` x ``h``, every
    buffer) and ``2·n_server − 1`` client frames with ground truth, all between two server
    frames; returns the bytes of one server frame's buffers (three cameras)."""
    rng = np.random.default_rng(3)
    files: dict[str, bytes] = {}
    scratch = root.parent / f"{root.name}-scratch"
    for name, write in (
        ("png", lambda p: _write_png(p, rng.integers(0, 256, (h, w, 4), np.uint8))),
        ("depth", lambda p: _write_exr(p, {"Y": rng.random((h, w))})),
        ("flow", lambda p: _write_exr(p, {c: rng.random((h, w)) - 0.5 for c in "RGB"})),
    ):
        path = scratch / f"{name}.{'png' if name == 'png' else 'exr'}"
        write(path)
        files[name] = path.read_bytes()
    frames = [{"idx": i, "w2c": matrix_to_unity(VIEW), "proj": matrix_to_unity(PROJ)}
              for i in range(2 * n_server)]
    for cam in ("main", "left", "right"):
        d = root / cam
        for sub in ("color", "depth", *dataset._FLOW.values(), *dataset._SHADOW["fwd"],
                    *dataset._SHADOW["bwd"]):
            (d / sub).mkdir(parents=True)
            kind = "png" if sub not in ("depth", *dataset._FLOW.values()) else (
                "depth" if sub == "depth" else "flow")
            for i in range(n_server):
                (d / sub / f"{i:04d}.{'png' if kind == 'png' else 'exr'}").write_bytes(
                    files[kind])
        (d / "cam.json").write_text(json.dumps({
            "frames": frames[:n_server], "resolution": {"x": w, "y": h}, "serverFps": 10,
            "shadowFps": 40}))
    c = root / "client_ol"
    (c / "color").mkdir(parents=True)
    for i in range(2 * n_server - 1):
        (c / "color" / f"{i:04d}.png").write_bytes(files["png"])
    (c / "cam.json").write_text(json.dumps({"frames": frames[:2 * n_server - 1],
                                            "resolution": {"x": w, "y": h}, "clientFps": 20}))
    return 3 * w * h * (3 + 4 + 2 * 12 + 2 * (4 + 3 + 3))


def test_import_as_recording_memory_does_not_grow_with_the_frame_count(tmp_path: Path) -> None:
    # Every frame of every camera was decoded into memory before the first was written (about
    # 100 MB per camera frame at 1920x1080): a long dataset could not be imported.
    import tracemalloc

    peaks = []
    for n in (3, 9):
        frame_bytes = _long_dataset(tmp_path / f"ds{n}", n)
        tracemalloc.start()
        try:
            out = import_dataset_as_recording(tmp_path / f"ds{n}", tmp_path / f"rec{n}")
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        rec = sr.load_recording(out)
        assert (len(rec.server_frames), len(rec.client_frames)) == (n, 2 * n - 1)
    # Six more server frames (and twelve more client frames) held at once would add
    # 6 x frame_bytes; the frames are read one at a time, so the peak stays put.
    assert peaks[1] - peaks[0] < frame_bytes // 2, (peaks, frame_bytes)


def test_import_as_recording_refuses_more_server_frames_than_a_recording_holds(
    handmade: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every server frame of the dataset is kept: more than MAX_FRAMES were read and written,
    # and load_recording refuses such a recording; now refused before any image is read.
    _recording_ready(handmade)
    monkeypatch.setattr(dataset, "MAX_FRAMES", 1)
    read: list[Path] = []
    monkeypatch.setattr(dataset, "_read_png", lambda p, s: read.append(p))
    with pytest.raises(
        DatasetError,
        match=r"main[/\\]cam\.json: 2 server frames, a recording holds at most 1",
    ):
        import_dataset_as_recording(handmade, tmp_path / "rec")
    assert read == [] and not (tmp_path / "rec").exists()


def test_an_image_the_import_cannot_read_leaves_the_output_as_it_was(
    handmade: Path, tmp_path: Path
) -> None:
    # The frames are read while the recording is written: a bad image found then must leave
    # no recording (and, with overwrite, the previous one).
    _recording_ready(handmade)
    rec = tmp_path / "rec"
    import_dataset_as_recording(handmade, rec)
    before = {p: p.read_bytes() for p in rec.rglob("*") if p.is_file()}
    (handmade / "right" / "depth" / "0008.exr").write_bytes(b"not an EXR")
    for out, overwrite in ((tmp_path / "new", False), (rec, True)):
        with pytest.raises(DatasetError, match=r"right[/\\]depth[/\\]0008\.exr: cannot read EXR"):
            import_dataset_as_recording(handmade, out, overwrite=overwrite)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "rec"]
    assert {p: p.read_bytes() for p in rec.rglob("*") if p.is_file()} == before


def test_import_help_says_which_client_frames_are_kept(handmade: Path, tmp_path: Path) -> None:
    # The help said "before the last server frame's"; a client frame at that very time is kept.
    from splitrender.cli.help import DESCRIPTION

    assert "at or before the last server frame's" in DESCRIPTION["dataset import"]
    _client_frames_at(handmade, 20, 3)
    rec = sr.load_recording(import_dataset_as_recording(handmade, tmp_path / "rec"))
    assert [c.time for c in rec.client_frames] == [0.0, 0.05, 0.1]  # the last server frame's
    assert rec.server_frames[-1].time == 0.1


@pytest.mark.parametrize(
    ("argv", "problem"),
    [
        # A third name was ignored without a word; the help speaks of two cameras.
        (["export", "{rec}", "--aux-names", "a,b,c"],
         "argument --aux-names: expected two names, the folders of the two auxiliary cameras "
         "in rig order; got 3: a,b,c"),
        # The messages named the API's parameters: "only 1 aux_names", "aux_names[0]: ...",
        # "client: ...".
        (["export", "{rec}", "--aux-names", "left"],
         "argument --aux-names: expected two names, the folders of the two auxiliary cameras "
         "in rig order; got 1: left"),
        (["export", "{rec}", "--aux-names", "../x,right"],
         "argument --aux-names: expected a plain name (not empty, no '/', '\\' or NUL, not '.' "
         "or '..'), got '../x'"),
        (["export", "{rec}", "--client", ""], "argument --client: expected a plain name"),
        (["import", "{ds}", "--client", ""], "argument --client: expected a plain name"),
        (["import", "{ds}", "--aux", "left,right,x"],
         "argument --aux: expected two names, the folders of the two auxiliary cameras in rig "
         "order; got 3: left,right,x"),
        (["import", "{ds}", "--aux", "left,.."], "argument --aux: expected a plain name"),
    ],
)
def test_command_line_messages_name_the_options(
    recording: sr.Recording, exported: Path, tmp_path: Path, argv: list[str], problem: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from splitrender.cli.dispatch import main

    out = tmp_path / "out"
    argv = [a.format(rec=recording.path, ds=exported) for a in argv]
    with pytest.raises(SystemExit) as e:  # argparse's exit, or main's status
        raise SystemExit(main(["dataset", *argv, "--out", str(out), "--quiet"]))
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith("splitrender dataset ") and problem in err, err
    assert not out.exists()
    # The Python API's messages name its parameters.
    with pytest.raises(DatasetError, match=r"^aux: a recording has two auxiliary cameras, got 3"):
        import_dataset_as_recording(exported, out, aux=("left", "right", "x"))


# ----------------------------------------------------------------------------------------------
# A corrupt EXR: one line of ours, nothing of the OpenEXR library's on stdout or stderr.


def _exr_table(data: bytes) -> int:
    """Where the offset table of the handmade EXR ``data`` starts: after its last attribute
    (``type``, ``scanlineimage``, the attributes being sorted by name) and the header's NUL."""
    return data.index(b"scanlineimage\x00") + len(b"scanlineimage\x00")


def _corrupt(data: bytes, kind: str) -> bytes:
    """The one-chunk (4 lines, ZIP) depth EXR ``data`` corrupted as ``kind`` says."""
    table = _exr_table(data)
    (chunk,) = struct.unpack_from("<Q", data, table)
    assert chunk == table + 8 and struct.unpack_from("<i", data, chunk) == (0,)
    if kind == "header":  # cut inside the attributes
        return data[:100]
    if kind == "name":  # cut inside the first attribute's type name
        return data[:20]
    if kind == "offset-table":
        return data[: table + 4]
    if kind == "chunk":  # inside the chunk's pixel data
        return data[:-5]
    if kind == "offset-past-end":
        return data[:table] + struct.pack("<Q", len(data) + 1000) + data[table + 8 :]
    # Garbage compressed data: a packed size below the 32 bytes of the 4 half lines (so ZIP),
    # then 20 bytes that are not a zlib stream.
    assert kind == "garbage"
    return data[: chunk + 4] + struct.pack("<i", 20) + bytes(range(7, 27))


_CORRUPTIONS = {
    "header": "truncated or corrupt header: attribute 'dataWindow' runs past the end of the "
              "file (100 bytes)",
    "name": "truncated or corrupt header: the attribute at byte 8 runs past the end of the "
            "file (20 bytes)",
    "offset-table": "truncated: its offset table (1 x 8 bytes) ends at byte 314, past the end "
                    "of the file (310 bytes)",
    "chunk": "truncated or corrupt chunk 0 (lines 0..3) at byte 314: 32 bytes of data, but "
             "only 27 follow its header in the file (349 bytes)",
    "offset-past-end": "truncated or corrupt offset table: chunk 0 (lines 0..3) at byte 1354, "
                       "past the end of the file (354 bytes)",
    "garbage": "(EXR_ERR_CORRUPT_CHUNK) Unable to decompress",
}


# Two of the five as a subprocess (each starts an interpreter); the API test below takes all,
# with fd 1 and 2 checked the same way.
@pytest.mark.parametrize("kind", ["offset-table", "garbage"])
def test_a_corrupt_exr_gets_one_line_of_ours_on_the_command_line(
    handmade: Path, tmp_path: Path, kind: str
) -> None:
    # The library printed its own lines (`PATH: (EXR_ERR_BAD_CHUNK_LEADER) ...` on stderr,
    # `Warning: Exception raised reading pixel data for part 0 - ...` on stdout) before ours,
    # which then said "Invalid part index '0': file has 0 parts."; a chunk offset past the end
    # of the file was taken without a word (the library rebuilt the table by scanning).
    _recording_ready(handmade)
    path = handmade / "main" / "depth" / "0007.exr"
    good = path.read_bytes()
    assert len(good) == 354  # the offsets in the messages
    path.write_bytes(_corrupt(good, kind))
    here = str(Path(sr.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [here, *filter(None, [os.environ.get("PYTHONPATH")])]))
    r = subprocess.run(
        [sys.executable, "-m", "splitrender", "dataset", "import", str(handmade), "--out",
         str(tmp_path / "rec"), "--quiet"],
        env=env, capture_output=True, text=True, timeout=120, check=False,
    )
    assert r.returncode == 2 and r.stdout == "", (r.returncode, r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.endswith("\n"), r.stderr
    assert r.stderr.startswith(f"splitrender: error: {path}: cannot read EXR: "), r.stderr
    assert _CORRUPTIONS[kind] in r.stderr, r.stderr
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize("kind", list(_CORRUPTIONS))
def test_a_corrupt_exr_says_nothing_of_the_library_to_an_api_caller(
    handmade: Path, kind: str, capfd: pytest.CaptureFixture[str]
) -> None:
    # As on the command line, for a program that calls the API: the error names the file and
    # what was wrong, and fd 1 and 2 hold nothing of the library's.
    path = handmade / "main" / "depth" / "0007.exr"
    path.write_bytes(_corrupt(path.read_bytes(), kind))
    with pytest.raises(DatasetError) as e:
        sr.import_dataset(handmade, aux=())
    assert str(e.value).startswith(f"{path}: cannot read EXR: ")
    assert _CORRUPTIONS[kind] in str(e.value)
    assert capfd.readouterr() == ("", "")


def _write_exr_as(path: Path, z: np.ndarray, compression: object) -> None:
    OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage},
                 {"Z": z.astype(np.float16)}).write(str(path))


def test_import_refuses_exr_chunks_out_of_place(handmade: Path) -> None:
    # One chunk a line (ZIPS): the 4 offsets are checked, each chunk's line and extent.
    path = handmade / "main" / "depth" / "0007.exr"
    _write_exr_as(path, np.full((4, 4), D_PLANE), OpenEXR.ZIPS_COMPRESSION)
    data = path.read_bytes()
    table = _exr_table(data)
    offsets = struct.unpack_from("<4Q", data, table)
    swapped = struct.pack("<4Q", offsets[1], offsets[0], *offsets[2:])
    path.write_bytes(data[:table] + swapped + data[table + 32 :])
    with pytest.raises(DatasetError, match=rf"0007\.exr: cannot read EXR: corrupt chunk 0 "
                       rf"\(lines 0\.\.0\) at byte {offsets[1]}: it says line 1, expected 0$"):
        sr.import_dataset(handmade, aux=())
    into_table = struct.pack("<4Q", table + 8, *offsets[1:])
    path.write_bytes(data[:table] + into_table + data[table + 32 :])
    with pytest.raises(DatasetError, match=rf"corrupt offset table: chunk 0 \(lines 0\.\.0\) "
                       rf"at byte {table + 8}, before the end of the table \(byte {table + 32}\)"):
        sr.import_dataset(handmade, aux=())
    # A packed size above what the line takes uncompressed (4 halves: 8 bytes) that fits the
    # file: the library said "packed data size says 9, must be between 0 and 8" on stderr.
    big = bytearray(data)
    struct.pack_into("<i", big, offsets[3] + 4, 9)
    path.write_bytes(bytes(big[: offsets[3] + 8 + 8]) + b"\0")
    with pytest.raises(DatasetError, match=r"corrupt chunk 3 \(lines 3\.\.3\) at byte \d+: 9 "
                       r"bytes of data, expected at most 8 \(its lines uncompressed\)$"):
        sr.import_dataset(handmade, aux=())


def test_import_refuses_exr_chunks_that_overlap(handmade: Path) -> None:
    # Uncompressed, one line a chunk: line 0's 8 bytes of pixels read as the leader of a chunk
    # for line 1 with 8 bytes, and chunk 1's offset points there, inside chunk 0.
    path = handmade / "main" / "depth" / "0007.exr"
    z = np.full((4, 4), D_PLANE)
    z[0] = np.frombuffer(struct.pack("<ii", 1, 8), np.float16)
    _write_exr_as(path, z, OpenEXR.NO_COMPRESSION)
    data = path.read_bytes()
    table = _exr_table(data)
    offsets = struct.unpack_from("<4Q", data, table)
    inside = offsets[0] + 8  # past chunk 0's leader: its pixels
    path.write_bytes(data[:table] + struct.pack("<4Q", offsets[0], inside, *offsets[2:])
                     + data[table + 32 :])
    with pytest.raises(DatasetError, match=rf"corrupt offset table: chunk 1 at byte {inside} "
                       rf"lies inside chunk 0 \(which ends at byte {offsets[0] + 16}\)$"):
        sr.import_dataset(handmade, aux=())


@pytest.mark.parametrize("order", ["INCREASING_Y", "DECREASING_Y"])
@pytest.mark.parametrize(
    "compression", ["NO", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "DWAA", "DWAB"]
)
def test_exrs_of_every_compression_and_line_order_pass_the_chunk_checks(
    tmp_path: Path, compression: str, order: str, capfd: pytest.CaptureFixture[str]
) -> None:
    # 40 lines: several chunks for all but DWAB's 256 lines; the offsets of a DECREASING_Y
    # file decrease. Each reads as the library reads it, without a word on fd 1 or 2.
    path = tmp_path / "z.exr"
    z = (np.arange(40 * 5).reshape(40, 5) % 11 / 8).astype(np.float16)
    OpenEXR.File({"compression": getattr(OpenEXR, f"{compression}_COMPRESSION"),
                  "type": OpenEXR.scanlineimage, "lineOrder": getattr(OpenEXR, order)},
                 {"Z": z}).write(str(path))
    with OpenEXR.File(str(path), separate_channels=True) as f:
        want = np.asarray(f.channels()["Z"].pixels, np.float32)
    np.testing.assert_array_equal(dataset._read_exr(path, (5, 40), "depth"), want)
    assert capfd.readouterr() == ("", "")


def test_what_others_write_while_the_library_is_captured_goes_where_it_went(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # fd 1 and 2 and sys.stdout are captured around the library's calls: the library's lines
    # are kept for the error, those of others (another thread) are passed on afterwards.
    path = tmp_path / "x.exr"
    with dataset._library_output(path) as said:
        os.write(2, f"{path}: (EXR_ERR_CORRUPT_CHUNK) bad\nanother's line\n".encode())
        print("Warning: Exception raised reading pixel data for part 0 - Unable to run decoder")
        print("printed by another")
        os.write(1, b"written by another\n")
    assert said == ["(EXR_ERR_CORRUPT_CHUNK) bad", "Unable to run decoder"]
    out, err = capfd.readouterr()
    assert out == "written by another\nprinted by another\n" and err == "another's line\n"
