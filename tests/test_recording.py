"""Recordings (splitrender.scene.recording) and ``splitrender render``."""

from __future__ import annotations

import hashlib
import io
import json
import re
import struct
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import splitrender as sr
from splitrender.cli import main
from splitrender.scene.recording import (
    ClientFrame,
    Recording,
    RecordingError,
    load_recording,
    plan,
    write_recording,
)
from splitrender.scene.builtin import MAX_SAMPLES, Scene, load_trace

SCALE, SECONDS = 0.04, 0.3  # 102 x 58; 4 server and 36 client frames
TRACES = Path(__file__).resolve().parents[2] / "shared" / "traces"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "lab"
    write_recording(out, "lab", seconds=SECONDS, scale=SCALE)
    return out


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def test_plan() -> None:
    assert plan(0.3, 10, 120) == (4, 36)
    assert plan(2.0, 10, 120) == (21, 240)


@pytest.mark.parametrize(
    ("rates", "what"),
    [({"fs": 1e6}, "fs"), ({"fc": 1e6}, "fc"), ({"fs": 1e300, "fc": 1e300}, "fs")],
)
def test_frame_counts_are_bounded(tmp_path: Path, rates: dict[str, float], what: str) -> None:
    # fs=1e6 planned 300,000 server frames to render; refused before anything is written.
    out = tmp_path / "r"
    with pytest.raises(RecordingError, match=f"{what}: .* more than 50000 frames"):
        write_recording(out, "lab", seconds=SECONDS, scale=SCALE, **rates)  # type: ignore[arg-type]
    assert not out.exists()


@pytest.mark.parametrize("seconds", [0.0, -1.0, float("nan"), float("inf"), True, "2"])
def test_a_recordings_render_refuses_a_bad_length(seconds: object) -> None:
    """RecordingRender (what eval's sweep tasks run, without write_recording's argument
    checks) checks the settings itself."""
    from splitrender.scene.recording import RecordingRender, RecordingSettings

    with pytest.raises(RecordingError, match=f"^seconds: expected a finite number > 0, got "
                                             f"{re.escape(repr(seconds))}$"):
        settings = RecordingSettings(seconds=seconds, scale=SCALE)  # type: ignore[arg-type]
        RecordingRender("lab", settings)


@pytest.mark.parametrize("samples", [0, MAX_SAMPLES + 1, True, 2.0])
def test_a_recordings_render_refuses_a_bad_sample_count(samples: object) -> None:
    from splitrender.scene.recording import RecordingRender, RecordingSettings

    with pytest.raises(RecordingError, match=f"^samples: expected an int in 1..{MAX_SAMPLES} or "
                                             f"None, got {re.escape(repr(samples))}$"):
        settings = RecordingSettings(samples=samples, scale=SCALE)  # type: ignore[arg-type]
        RecordingRender("lab", settings)


def test_a_recording_longer_than_its_scene_is_refused() -> None:
    from splitrender.scene.recording import RecordingRender, RecordingSettings

    duration = Scene("lab").duration
    with pytest.raises(RecordingError, match=f"^seconds: scene 'lab' lasts {duration:g} s, "
                                             f"asked for {duration + 1:g} s$"):
        RecordingRender("lab", RecordingSettings(seconds=duration + 1, scale=SCALE))


def test_round_trip(recorded: Path) -> None:
    rec = load_recording(recorded)
    assert rec.scene == "lab" and rec.variant == "dynamic" and not rec.stereo
    assert rec.samples == {"main": 3, "aux": 3, "client": 3}
    assert (len(rec.server_frames), len(rec.client_frames)) == (4, 36)
    scene = Scene("lab")
    for k in (0, 3):
        want = scene.server_frame(k, SCALE)
        got = rec.server_frames[k]
        assert isinstance(got, sr.ServerFrame) and got.index == k
        assert got.time == want.time
        for a, b in zip((got.main, *got.aux), (want.main, *want.aux)):
            assert np.array_equal(a.camera.view, b.camera.view)
            assert np.array_equal(a.camera.proj, b.camera.proj)
            for name in ("color", "depth", "motion_fwd", "motion_bwd"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), name
            for d in ("shadow_fwd", "shadow_bwd"):
                sa, sb = getattr(a, d), getattr(b, d)
                for f in ("bits", "s_min", "s_max"):
                    assert np.array_equal(getattr(sa, f), getattr(sb, f))
    assert np.array_equal(rec.server_pose(2), scene.server_pose(2, 10.0))
    c = rec.client_frames[-1]
    assert isinstance(c, ClientFrame) and c.index == 35 and c.time == 35 / 120
    ((cam, img),) = scene.client_frames(35, SCALE)
    assert np.array_equal(c.ground_truth, img) and np.array_equal(c.camera.view, cam.view)
    assert np.array_equal(c.pose, scene.client_pose(35 / 120))
    req = c.request
    assert isinstance(req, sr.ClientRequest) and req.time == c.time
    assert len(rec.client_frames[1:4]) == 3 and sum(1 for _ in rec.server_frames) == 4
    rec.verify()
    # Plain numpy reads the frame files too.
    with np.load(recorded / "server" / "000001.npz") as z:
        assert z["main.color"].shape == (58, 102, 3)


@pytest.fixture
def server_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The indices of the server frames read from the recordings opened after it, in order."""
    read: list[int] = []
    load = Recording._server

    def spy(self: Recording, k: int) -> sr.ServerFrame:
        read.append(k)
        return load(self, k)

    # Before the recording is opened: its frame views hold the bound loader.
    monkeypatch.setattr(Recording, "_server", spy)
    return read


def test_a_slice_of_frames_reads_each_frame_when_it_is_asked_for(
    recorded: Path, server_reads: list[int]
) -> None:
    read = server_reads
    rec = load_recording(recorded)
    part = rec.server_frames[1:4]
    assert len(part) == 3 and read == []  # a view: nothing read yet
    assert part[-1].time == rec.server_frames[3].time and read == [3, 3]
    assert [f.time for f in part] == [f.time for f in rec.server_frames[1:]]
    assert read == [3, 3, 1, 2, 3, 1, 2, 3]
    assert len(part[::2]) == 2 and part[::2][1].time == rec.server_frames[3].time
    with pytest.raises(IndexError):
        part[3]
    # Negative indices count from the end, as a list's: -len is the first, one more refused.
    assert part[-3].time == rec.server_frames[1].time
    with pytest.raises(IndexError):
        part[-4]


def test_raw_rate_comes_from_the_manifest_and_equals_the_frames_bytes(
    recorded: Path, server_reads: list[int]
) -> None:
    # The uncompressed rate of a play or of Table 1 read every server frame once more only to
    # sum its buffers' sizes; the manifest's camera sizes give the same count.
    from splitrender.client.playback import frame_nbytes
    from splitrender.evaluation.pipeline import raw_mbps

    rec = load_recording(recorded)
    mbps = raw_mbps(rec)
    assert server_reads == []
    sizes = {frame_nbytes(f) for f in rec.server_frames}
    assert sizes == {rec.server_nbytes} and rec.server_nbytes > 51 * 102 * 58
    assert mbps == pytest.approx(rec.server_nbytes * 8 * rec.fs / 1e6)


def test_deterministic(recorded: Path, tmp_path: Path) -> None:
    again = write_recording(tmp_path / "again", "lab", seconds=SECONDS, scale=SCALE)
    assert _files(again) == _files(recorded)


def test_stereo_and_trace(tmp_path: Path) -> None:
    lines = [f"0 0 {-t:.5f} 0 {20 * t:.5f} 0 {t * 1000:.4f}" for t in np.arange(0, 0.6, 1 / 60)]
    tp = tmp_path / "walk.txt"
    tp.write_text("\n".join(lines) + "\n")
    out = write_recording(
        tmp_path / "r",
        "courtyard",
        variant="static",
        seconds=0.1,
        scale=SCALE,
        stereo=True,
        trace=load_trace(tp),
    )
    rec = load_recording(out)
    assert rec.manifest["client_motion"]["file"] == "walk.txt"
    c = rec.client_frames[6]
    assert len(c.cameras) == 2 and len(c.requests) == 2
    f = rec.server_frames[1]
    assert not f.main.motion_fwd.any()  # type: ignore[union-attr]
    with pytest.raises(RecordingError, match="trace lasts"):
        write_recording(tmp_path / "long", "lab", seconds=1.0, scale=SCALE, trace=load_trace(tp))


def test_interrupted_render_leaves_nothing_complete(tmp_path: Path) -> None:
    out = tmp_path / "cut"

    def stop(done: int, total: int) -> None:
        if done == total // 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_recording(out, "lab", seconds=SECONDS, scale=SCALE, progress=stop)
    assert list(tmp_path.iterdir()) == []


def test_partial_and_incomplete_are_refused(recorded: Path, tmp_path: Path) -> None:
    partial = tmp_path / "lab.partial-1234"
    shutil.copytree(recorded, partial)
    with pytest.raises(RecordingError, match="unfinished recording"):
        load_recording(partial)
    incomplete = tmp_path / "incomplete"
    shutil.copytree(recorded, incomplete)
    (incomplete / "manifest.json").unlink()
    with pytest.raises(RecordingError, match=r"manifest.json: missing"):
        load_recording(incomplete)
    with pytest.raises(RecordingError, match="no such recording"):
        load_recording(tmp_path / "nothing")


def test_an_output_named_as_an_unfinished_recording_is_refused(tmp_path: Path) -> None:
    # A render into x.partial-1 completed, and every reader then refused it as unfinished.
    out = tmp_path / "x.partial-1"
    with pytest.raises(RecordingError, match="x.partial-1: a name ending in .partial-N"):
        write_recording(out, "lab", seconds=SECONDS, scale=SCALE)
    assert not any(tmp_path.iterdir())


def test_existing_output_needs_overwrite(recorded: Path) -> None:
    with pytest.raises(RecordingError, match="already exists"):
        write_recording(recorded, "lab", seconds=SECONDS, scale=SCALE)


def test_a_failed_overwrite_puts_the_previous_recording_back(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "rec"
    shutil.copytree(recorded, out)
    before = _files(out)
    rename = Path.rename

    def failing(self: Path, target: str | Path) -> Path:
        if ".partial-" in self.name:  # the finished recording cannot be moved into place
            raise OSError(5, "Input/output error")
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", failing)
    with pytest.raises(OSError, match="Input/output error"):
        write_recording(out, "lab", seconds=SECONDS, scale=SCALE, overwrite=True)
    assert _files(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["rec"]


def test_a_file_or_link_is_not_replaced_even_with_overwrite(recorded: Path, tmp_path: Path) -> None:
    # Issue 15: overwrite=True renamed a regular file aside, rendered everything, then failed.
    file = tmp_path / "notes.txt"
    file.write_text("keep me\n")
    link = tmp_path / "link"
    link.symlink_to(recorded, target_is_directory=True)
    for out in (file, link):
        with pytest.raises(RecordingError, match=f"{out.name}: exists and is not a directory"):
            write_recording(out, "lab", seconds=SECONDS, scale=SCALE, overwrite=True)
    assert file.read_text() == "keep me\n" and link.resolve() == recorded.resolve()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "notes.txt"]


@pytest.fixture
def copy(recorded: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(recorded, tmp_path / "copy"))


def _change_manifest(
    root: Path, change: dict[str, object] | Callable[[dict[str, Any]], None]
) -> Path:
    """Rewrites ``root``'s manifest with ``change`` (fields to replace, or a function that edits
    the parsed document in place); returns the manifest's path."""
    p = root / "manifest.json"
    m = json.loads(p.read_text())
    if callable(change):
        change(m)
    else:
        m.update(change)
    p.write_text(json.dumps(m))
    return p


@pytest.mark.parametrize(
    ("changes", "problem"),
    [
        # Version 1 recordings were point-sampled: refused, naming both versions.
        ({"version": 1}, "format version 1, this splitrender reads version 2"),
        ({"version": 3}, "format version 3"),
        ({"samples": {"main": 0, "aux": 3, "client": 3}}, "samples.main"),
        ({"format": "other"}, "format 'other'"),
        ({"subframes": 0}, "subframes"),
        ({"cameras": {"main": [0, 5]}}, "cameras.main"),
        ({"server_frames": []}, "server_frames: empty"),
        # In JSON's terms, not Python's ("expected <class 'int'>, got str"), and naming the
        # entry of a frame list.
        ({"fs": "10"}, "field 'fs': expected a number, got a string$"),
        ({"subframes": 2.5}, "field 'subframes': expected an integer, got a number$"),
        ({"stereo": 0}, "field 'stereo': expected true or false, got an integer$"),
        ({"cameras": [1]}, "field 'cameras': expected an object, got an array$"),
        ({"client_frames": [{"index": None}]},
         "field 'client_frames\\[0\\].index': expected an integer, got null$"),
        ({"client_frames": [{}]}, "missing field 'client_frames\\[0\\].index'$"),
    ],
)
def test_bad_manifest(copy: Path, changes: dict[str, object], problem: str) -> None:
    _change_manifest(copy, changes)
    with pytest.raises(RecordingError, match=problem) as e:
        load_recording(copy)
    assert "manifest.json" in str(e.value)


def _cut(key: str, n: int) -> Callable[[dict[str, Any]], None]:
    def cut(m: dict[str, Any]) -> None:
        m[key] = m[key][:n]
    return cut


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        # seconds=1e6 reached play as "n: expected an int in [0, 50000], got 120000000".
        ({"seconds": 1e6}, "'seconds' and 'fs': 1e\\+06 s at 10 frames/s is more than 50000"),
        ({"seconds": 1e300}, "more than 50000 frames"),
        # Cut lists failed later under metrics' names, or (server frames) played held frames
        # scored as if the recording were whole.
        (_cut("client_frames", 3), "4 server frames and 3 client frames listed; 0.3 s at "
         "fs=10 and fc=120 plan 4 and 36"),
        (_cut("server_frames", 1), "1 server frames and 36 client frames listed"),
        ({"seconds": 0.1}, "plan 2 and 12"),
    ],
)
def test_the_frame_lists_are_the_ones_the_manifest_plans(
    copy: Path, change: dict[str, object] | Callable[[dict[str, Any]], None], problem: str
) -> None:
    _change_manifest(copy, change)
    with pytest.raises(RecordingError, match=f"manifest.json: .*{problem}"):
        load_recording(copy)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        # fs of 401 digits: float() of it raised OverflowError.
        ('{"fs": 1' + "0" * 400 + "}", "integer of 401 digits"),
        ("[" * 100_000, "nested too deeply"),
    ],
)
def test_hostile_manifest_numbers_and_nesting(copy: Path, text: str, problem: str) -> None:
    (copy / "manifest.json").write_text(text)
    with pytest.raises(RecordingError, match=f"manifest.json: recording manifest.*{problem}"):
        load_recording(copy)


def test_manifest_and_frames_must_be_regular_files(copy: Path) -> None:
    # A link to /dev/zero (st_size 0) was read until memory ran out.
    frame = copy / "client" / "000001.npz"
    frame.unlink()
    frame.symlink_to("/dev/zero")
    with pytest.raises(RecordingError, match="000001.npz: frame file is a character device"):
        load_recording(copy).client_frames[1]
    (copy / "manifest.json").unlink()
    (copy / "manifest.json").symlink_to("/dev/zero")
    with pytest.raises(RecordingError, match="manifest.json: .*character device"):
        load_recording(copy)


def test_missing_corrupted_and_oversized_files(copy: Path) -> None:
    f1 = copy / "server" / "000001.npz"
    f1.unlink()
    rec = load_recording(copy)
    with pytest.raises(RecordingError, match="000001.npz: missing file"):
        rec.server_frames[1]
    c2 = copy / "client" / "000002.npz"
    data = bytearray(c2.read_bytes())
    data[-100] ^= 0xFF
    c2.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="000002.npz: SHA-256"):
        rec.client_frames[2]
    c3 = copy / "client" / "000003.npz"
    c3.write_bytes(c3.read_bytes() + b"x" * 10)
    with pytest.raises(RecordingError, match=r"000003.npz: frame file is more than \d+ bytes"):
        rec.client_frames[3]
    rec.server_frames[0]  # untouched files still load


@pytest.mark.parametrize(
    "header",
    [
        "{'descr': '<f8'",  # cut short: numpy's tokenizer raised TokenError (fuzz suite)
        "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 4),",
        "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 4)} )",
    ],
)
def test_malformed_npy_header(copy: Path, header: str) -> None:
    import hashlib

    p = copy / "server" / "000000.npz"
    buf = io.BytesIO()
    with zipfile.ZipFile(p) as src, zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as dst:
        for name in src.namelist():
            raw = src.read(name)
            if name == "pose.npy":
                text = header.ljust(118) + "\n"
                raw = raw[:8] + struct.pack("<H", len(text)) + text.encode("latin1")
            dst.writestr(name, raw)
    data = buf.getvalue()
    p.write_bytes(data)
    m = json.loads((copy / "manifest.json").read_text())
    m["server_frames"][0].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    (copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(RecordingError, match="000000.npz: not a valid npz"):
        load_recording(copy).server_frames[0]


def test_wrong_shape_is_rejected_before_reading(copy: Path) -> None:
    # A well-formed npz with a consistent manifest entry but a different array shape.
    import hashlib

    from splitrender.scene.recording import _npz_bytes

    p = copy / "client" / "000004.npz"
    with np.load(p) as z:
        arrays = [(k, z[k]) for k in ("pose", "eye0.view", "eye0.proj")]
    arrays.append(("eye0.color", np.zeros((10, 10, 3), np.uint8)))
    data = _npz_bytes(arrays)
    p.write_bytes(data)
    m = json.loads((copy / "manifest.json").read_text())
    m["client_frames"][4].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    (copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(RecordingError, match=r"eye0.color: uint8 \(10, 10, 3\), expected"):
        load_recording(copy).client_frames[4]
    with zipfile.ZipFile(p) as zf:
        assert zf.infolist()[0].date_time == (1980, 1, 1, 0, 0, 0)
    # Before reading: a member whose header declares a 4.8 GB image and carries no data at all
    # is refused by its header (reading it first would fail on the missing bytes instead).
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "|u1", "fortran_order": False, "shape": (40000, 40000, 3)}
    )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for k, a in arrays[:3]:
            member = io.BytesIO()
            np.lib.format.write_array(member, a, version=(1, 0))
            zf.writestr(f"{k}.npy", member.getvalue())
        zf.writestr("eye0.color.npy", header.getvalue())
    data = buf.getvalue()
    p.write_bytes(data)
    m["client_frames"][4].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    (copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(RecordingError, match=r"eye0.color: uint8 \(40000, 40000, 3\), expected"):
        load_recording(copy).client_frames[4]


def _replace_client_frame(copy: Path, index: int, arrays: list[tuple[str, Any]],
                          version: tuple[int, int] = (1, 0)) -> None:
    """Client frame ``index``'s file rewritten with ``arrays`` (npy ``version``), its manifest
    entry updated to match: the frame's content is what is then checked."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for k, a in arrays:
            member = io.BytesIO()
            np.lib.format.write_array(member, a, version=version)
            zf.writestr(f"{k}.npy", member.getvalue())
    data = buf.getvalue()
    (copy / "client" / f"{index:06d}.npz").write_bytes(data)
    _change_manifest(copy, lambda m: m["client_frames"][index].update(
        bytes=len(data), sha256=hashlib.sha256(data).hexdigest()))


def test_a_frame_file_with_other_members_or_npy_format_is_refused(copy: Path) -> None:
    with np.load(copy / "client" / "000004.npz") as z:
        arrays = [(k, z[k]) for k in z.files]
    names = sorted(f"{k}.npy" for k, _ in arrays)
    _replace_client_frame(copy, 4, [*arrays, ("extra", np.zeros(2))])
    with pytest.raises(RecordingError, match=re.escape(
            f"000004.npz: members {sorted([*names, 'extra.npy'])}, expected {names}")):
        load_recording(copy).client_frames[4]
    _replace_client_frame(copy, 4, arrays[1:])
    fewer = sorted(f"{k}.npy" for k, _ in arrays[1:])
    with pytest.raises(RecordingError, match=re.escape(f"members {fewer}, expected {names}")):
        load_recording(copy).client_frames[4]
    # npy format 2.0 (4-byte header length) holds the same arrays: only 1.0 is read.
    _replace_client_frame(copy, 4, arrays, version=(2, 0))
    with pytest.raises(RecordingError, match=r"000004\.npz: \S+: npy format \(2, 0\), "
                                             r"expected \(1, 0\)$"):
        load_recording(copy).client_frames[4]


def _cameras(**changes: object) -> Callable[[dict[str, Any]], None]:
    def edit(m: dict[str, Any]) -> None:
        m["cameras"].update(changes)
    return edit


def _entry(key: str, i: int, **changes: object) -> Callable[[dict[str, Any]], None]:
    def edit(m: dict[str, Any]) -> None:
        m[key][i].update(changes)
    return edit


def _shift_time(m: dict[str, Any]) -> None:
    m["server_frames"][1]["time"] += 0.05


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        ({"fs": 0}, "field 'fs': expected a finite number > 0, got 0$"),
        ({"near": -0.1}, "field 'near': expected a finite number > 0, got -0.1$"),
        (_cameras(aux=[[80, 45]]), r"cameras\.aux: expected two \[width, height\], got "
                                   r"\[\[80, 45\]\]$"),
        (_cameras(aux="x"), r"cameras\.aux: expected two \[width, height\], got 'x'$"),
        (_cameras(client=[4, 4]), r"cameras\.client: expected the main camera's size$"),
        (_cameras(eyes=2), r"cameras\.eyes: 2 does not match stereo=False$"),
        (_entry("server_frames", 0), None),  # unchanged: the manifest as written loads
        # The ends of the ranges load.
        ({"subframes": 1}, None),
        ({"subframes": 16}, None),
        ({"samples": {"main": 1, "aux": MAX_SAMPLES, "client": 1}}, None),
        ({"subframes": 17}, "field 'subframes': expected 1..16, got 17$"),
        ({"samples": {"main": 1, "aux": MAX_SAMPLES + 1, "client": 1}},
         f"samples.aux: expected an int in 1..{MAX_SAMPLES}, got {MAX_SAMPLES + 1}$"),
        (lambda m: m["server_frames"].__setitem__(0, 5),
         r"server_frames\[0\]: expected an object$"),
        (_entry("server_frames", 1, index=2), r"server_frames\[1\]: index/time 2/0\.1 out of "
                                              r"sequence$"),
        (_shift_time, r"server_frames\[1\]: index/time 1/0\.15\d* out of sequence$"),
        (_entry("client_frames", 2, file="client/000003.npz"),
         r"client_frames\[2\]: unexpected file name 'client/000003\.npz'$"),
        (_entry("server_frames", 0, bytes=-1), r"server_frames\[0\]: bad bytes or sha256$"),
        (_entry("server_frames", 0, sha256="0" * 63), r"server_frames\[0\]: bad bytes or "
                                                      r"sha256$"),
    ],
)
def test_bad_manifest_cameras_and_frame_entries(
    copy: Path, edit: dict[str, object] | Callable[[dict[str, Any]], None], problem: str | None
) -> None:
    p = _change_manifest(copy, edit)
    if problem is None:
        load_recording(copy)
        return
    with pytest.raises(RecordingError, match=problem) as e:
        load_recording(copy)
    assert str(e.value).startswith(f"{p}: ")


def test_cli_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["render", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--trace" in out and "--stereo" in out and "per server frame" in out


def test_cli_unknown_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["render", "atrium", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert 'unknown scene "atrium"' in err and "courtyard" in err


def test_cli_bad_trace(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    tp = tmp_path / "t.txt"
    tp.write_text("1 2 3\n")
    assert main(["render", "lab", "--out", str(tmp_path / "x"), "--trace", str(tp)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{tp}:1: expected 7 numbers" in err


def test_cli_render(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    args = [
        "render",
        "colonnade",
        "--out",
        str(out),
        "--seconds",
        "0.05",
        "--scale",
        "0.04",
    ]
    assert main([*args, "--variant", "static", "--samples", "2"]) == 0
    err = capsys.readouterr().err
    # stderr is not a terminal here: one plain line for the one stage, no bar.
    assert "\r" not in err
    assert err.splitlines()[0].startswith("[1/1] rendering colonnade (static) at 102x58")
    assert len(err.splitlines()) == 1
    rec = load_recording(out)
    assert rec.variant == "static" and rec.samples == {"main": 2, "aux": 2, "client": 2}
    with pytest.raises(SystemExit) as e:
        main([*args, "--force", "--samples", "9"])
    assert e.value.code == 2 and "--samples: expected 1..8" in capsys.readouterr().err


def test_cli_render_refuses_an_output_that_is_or_holds_an_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 15: --force removes the old DIR after the render, with the trace or scene in it.
    old = tmp_path / "r"
    old.mkdir()
    trace = old / "trace.txt"
    trace.write_text("0 0 0 0 0 0 0\n")
    for out, problem in [(old, "holds the trace"), (trace, "is the trace")]:
        argv = ["render", "colonnade", "--out", str(out), "--trace", str(trace), "--force"]
        assert main([*argv, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err == f"splitrender: error: {out}: the output {problem} {trace}; expected a path outside it\n"
    assert trace.read_text() == "0 0 0 0 0 0 0\n"


def test_force_replaces_only_a_recording_or_an_empty_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # --force removed any folder given as --out: notes, or a recording's own subfolder.
    argv = ["render", "courtyard", "--seconds", "0.01", "--scale", "0.02", "--quiet", "--force"]
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("important")
    rec = tmp_path / "rec"
    assert main([*argv, "--out", str(rec)]) == 0
    before = sorted(p.name for p in rec.rglob("*"))
    for out in (notes, rec / "server"):
        assert main([*argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err == (f"splitrender: error: {out}: is not a recording (no manifest.json) and "
                       "not empty; --force (overwrite=True) replaces only a recording or an "
                       "empty folder\n")
    assert (notes / "todo.txt").read_text() == "important"
    assert sorted(p.name for p in rec.rglob("*")) == before
    # The working directory, or one above it: refused before the render (it was an internal
    # error for ".", and after the whole render for "..").
    monkeypatch.chdir(rec)
    for out in (".", str(rec), ".."):
        assert main([*argv, "--out", out]) == 2
        assert "is the current directory or holds it" in capsys.readouterr().err
    # A recording, and an empty folder, are replaced.
    monkeypatch.chdir(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    for out in (rec, empty):
        assert main([*argv, "--out", str(out)]) == 0
        assert sr.load_recording(out).scene == "courtyard"


def test_cli_render_shared_trace(tmp_path: Path) -> None:
    trace = TRACES / "robot_lab_path.txt"
    if not trace.is_file():
        pytest.skip(f"{trace} not present")
    out = tmp_path / "r"
    args = ["render", "lab", "--out", str(out), "--seconds", "0.05", "--scale", "0.04"]
    assert main([*args, "--trace", str(trace), "--trace-scale", "0.5", "--quiet"]) == 0
    assert load_recording(out).manifest["client_motion"]["translation_scale"] == 0.5


def test_eye_reads_each_ground_truth_lazily(tmp_path: Path) -> None:
    """``Recording.eye`` gives the recording's cameras and ground truths, eye by eye, the
    truths read from the files when asked for rather than all held (the sweep's score tasks and
    ``splitrender play`` score through it)."""
    rec = load_recording(sr.write_recording(tmp_path / "rec", "courtyard", seconds=0.1,
                                            scale=0.03, stereo=True))
    for eye in (0, 1):
        cams, truth = rec.eye(eye)
        assert not isinstance(truth, list) and len(truth) == len(cams) == len(rec.client_frames)
        for n, c in enumerate(rec.client_frames):
            assert cams[n].view.tolist() == c.cameras[eye].view.tolist()
            assert (truth[n] == c.ground_truths[eye]).all()
        assert [t.tobytes() for t in truth[1:3]] == [truth[1].tobytes(), truth[2].tobytes()]
    assert not (rec.eye(0)[1][5] == rec.eye(1)[1][5]).all()  # the eyes differ
    cams, truth = rec.eye(1, 4)
    assert len(cams) == len(truth) == 4
    with pytest.raises(IndexError):
        truth[4]
    mono = load_recording(sr.write_recording(tmp_path / "mono", "courtyard", seconds=0.1,
                                             scale=0.03))
    with pytest.raises(sr.InvalidInputError, match="eye: 1 out of range; .* mono recording"):
        mono.eye(1)


def test_eye_reads_the_cameras_without_the_images(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``Recording.eye`` reads each client file once for its cameras, without the images' data
    (read once more, in full, when a ground truth is asked for), and still checks the file."""
    import splitrender.scene.recording as recording

    rec = load_recording(sr.write_recording(tmp_path / "rec", "courtyard", seconds=0.05,
                                            scale=0.03, stereo=True))
    reads: list[tuple[str, object]] = []
    real = recording._read_npz

    def counted(root, entry, spec, only=None):  # type: ignore[no-untyped-def]
        out = real(root, entry, spec, only)
        reads.append((entry["file"], None if only is None else sorted(out)))
        return out

    monkeypatch.setattr(recording, "_read_npz", counted)
    cams, truth = rec.eye(1)
    n = len(rec.manifest["client_frames"])
    assert len(cams) == n and reads == [
        (f"client/{k:06d}.npz", ["eye1.proj", "eye1.view"]) for k in range(n)]
    reads.clear()
    assert truth[2].shape == (*rec.manifest["cameras"]["client"][::-1], 3)
    assert reads == [("client/000002.npz", None)]
    # The matrices read are checked by the member's CRC-32; the images, not read, by the
    # file's SHA-256 when the ground truth is read.
    f = tmp_path / "rec" / "client" / "000001.npz"
    good = f.read_bytes()
    for member, cameras_fail in (("eye0.view.npy", True), ("eye0.color.npy", False)):
        data = bytearray(good)
        data[_member_data(good, member) + 130] ^= 0x01  # past the npy header: an array byte
        f.write_bytes(bytes(data))
        if cameras_fail:
            with pytest.raises(RecordingError, match="000001.npz: not a valid npz: .*CRC-32"):
                rec.eye(0)
        else:
            _, truth = rec.eye(0)
            with pytest.raises(RecordingError, match="000001.npz: SHA-256"):
                truth[1]


def _member_data(npz: bytes, name: str) -> int:
    """The offset in ``npz`` (a stored zip) of member ``name``'s data."""
    info = zipfile.ZipFile(io.BytesIO(npz)).getinfo(name)
    o = info.header_offset
    n, extra = struct.unpack("<HH", npz[o + 26:o + 30])
    return o + 30 + n + extra


def test_a_member_longer_than_its_array_is_refused(tmp_path: Path) -> None:
    """A member with bytes after its array is refused, whole or matrices only: otherwise the
    reader stops before the member's end, where zipfile checks its CRC-32."""
    rec = load_recording(sr.write_recording(tmp_path / "rec", "courtyard", seconds=0.05,
                                            scale=0.03))
    f = tmp_path / "rec" / "client" / "000000.npz"
    src = zipfile.ZipFile(io.BytesIO(f.read_bytes()))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as out:
        for info in src.infolist():
            extra = b"\0" * 8 if info.filename == "eye0.view.npy" else b""
            out.writestr(info, src.read(info) + extra)
    data = buf.getvalue()
    f.write_bytes(data)
    entry = rec.manifest["client_frames"][0]
    entry["bytes"], entry["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    for read in (lambda: rec.client_frames[0], lambda: rec.eye(0)):
        with pytest.raises(RecordingError, match="000000.npz: eye0.view: more bytes than"):
            read()


def test_more_server_frames_than_a_recording_holds_are_refused(copy: Path) -> None:
    # The plan bounds the client frames; the server list may be longer than planned (a dataset
    # import keeps every server frame), and 50,001 of them were accepted although
    # docs/recording-format.md says at most 50,000 of each.
    p = copy / "manifest.json"
    m = json.loads(p.read_text())
    entry = m["server_frames"][-1]
    m["server_frames"] += [
        {**entry, "index": k, "time": k / 10, "file": f"server/{k:06d}.npz"}
        for k in range(len(m["server_frames"]), 50_001)
    ]
    p.write_text(json.dumps(m))
    with pytest.raises(
        RecordingError,
        match=r"manifest\.json: server_frames: 50001 frames, a recording holds at most 50000",
    ):
        load_recording(copy)
    m["server_frames"] = m["server_frames"][:50_000]
    p.write_text(json.dumps(m))
    assert len(load_recording(copy).server_frames) == 50_000


def test_a_writer_refuses_more_frames_than_a_recording_holds(tmp_path: Path) -> None:
    # What load_recording refuses is not written: refused before any frame is made.
    from splitrender.scene.recording import LazyFrames, write_entries

    def never(i: int) -> tuple[float, bytes]:
        raise AssertionError("no frame is made")

    out = tmp_path / "r"
    with pytest.raises(RecordingError, match=r"r: server_frames: 50001 frames, a recording "
                       r"holds at most 50000"):
        write_entries(out, {}, LazyFrames(50_001, never), LazyFrames(1, never))
    assert list(tmp_path.iterdir()) == []


def test_a_recording_that_appears_while_another_is_written_is_kept(
    recorded: Path, tmp_path: Path
) -> None:
    # Two runs writing one new path: the second to finish moved the first's recording aside
    # and removed it (the overwrite branch ran because `out` existed by then), though neither
    # was asked to replace anything.
    out = tmp_path / "rec"
    done: list[int] = []

    def other_run_finishes(n: int, total: int) -> None:
        if not done:  # after the first frame: another run's recording lands at `out`
            shutil.copytree(recorded, out)
        done.append(n)

    before = _files(recorded)
    with pytest.raises(RecordingError, match="appeared while this one was written"):
        write_recording(out, "lab", seconds=SECONDS, scale=SCALE, progress=other_run_finishes)
    assert _files(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["rec"]  # the partial one removed
