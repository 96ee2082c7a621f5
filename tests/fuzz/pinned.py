"""Hand-picked cases: one per input check that matters, run by the CI profile besides its
random draw (``python -m tests.fuzz --ci``; ``--pinned`` runs these alone).

The random draw of 250 cases need not reach a given check: one audit found that removing
``load_trace``'s non-finite check, or a scene description's check that ``models`` is a list,
left the CI profile passing (its draw held no such case). Each case here builds one input from
the seeds and runs it through its kind's own ``run`` (tests/fuzz/targets.py); it must end as a
*specific error* whose text matches :attr:`Pinned.expect` (for a command line, the one
``splitrender SUBCOMMAND: error:`` line): accepted, it counts as "wrongly accepted"; refused by
another error than the one expected (a later check catching what the pinned one let through),
as "not the expected error". :data:`PINNED` lists them; the list is written into
docs/fuzz-results.md by ``python -m tests.fuzz --out``.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import struct
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.fuzz import targets
from tests.fuzz.mutate import dumps

Made = tuple[str, Callable[[], None], dict[str, Any]]


@dataclass(frozen=True)
class Pinned:
    """One hand-picked case: ``make(seeds, work)`` writes its input under ``work`` and returns
    ``(what, run, options)`` as a kind's ``make`` does."""

    kind: str  #: the kind whose run it uses (its time limit, and the CLI's classification)
    name: str
    check: str  #: the check it pins, in words (for the docs)
    expect: str  #: a regular expression the specific error's text must match (re.search)
    make: Callable[[Path, Path], Made]


# -- traces: px py pz pitch yaw roll t_ms, 20 lines -------------------------------------------


def _trace(line: int, field: int, value: str) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        lines = (seeds / "trace.txt").read_text().splitlines()
        fields = lines[line - 1].split()
        fields[field - 1] = value
        lines[line - 1] = " ".join(fields)
        (path := work / "trace.txt").write_text("\n".join(lines) + "\n")
        return f"line {line} field {field} -> {value!r}", targets.trace_run(path), {}

    return make


def _trace_time_repeated(seeds: Path, work: Path) -> Made:
    lines = (seeds / "trace.txt").read_text().splitlines()
    lines[9] = " ".join([*lines[9].split()[:6], lines[8].split()[6]])
    (path := work / "trace.txt").write_text("\n".join(lines) + "\n")
    return "line 10 at line 9's time", targets.trace_run(path), {}


# -- scene descriptions -------------------------------------------------------------------------


def _description(edit: Callable[[dict[str, Any]], str]) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        for n in ("quad.gltf", "quad.bin"):
            shutil.copy(seeds / n, work / n)
        doc = json.loads((seeds / "scene.json").read_text())
        what = edit(doc)
        (path := work / "scene.json").write_text(dumps(doc))
        return what, targets.description_run(path), {}

    return make


def _models_number(doc: dict[str, Any]) -> str:
    doc["models"] = 3
    return "models: 3"


def _models_object(doc: dict[str, Any]) -> str:
    doc["models"] = doc["models"][0]  # walked as its keys before the check
    return "models: the placement object itself, not in an array"


def _position_short(doc: dict[str, Any]) -> str:
    doc["models"][0]["position"] = [0.0, -2.0]
    return "models[0].position: 2 numbers"


def _scale_infinite(doc: dict[str, Any]) -> str:
    doc["models"][0]["scale"] = 1e400  # written as Infinity; JSON parsers read it as inf
    return "models[0].scale: Infinity"


# -- packets and stream files -------------------------------------------------------------------


def _packet_stale_crc(seeds: Path, work: Path) -> Made:
    data = bytearray((seeds / "packet0.bin").read_bytes())
    data[-1] ^= 0x01  # a payload bit, the CRC not updated
    what = "last payload byte flipped, CRC left stale"
    return what, targets.packet_run(bytes(data), None, what, True), {}


def _packet_matrix_nan(seeds: Path, work: Path) -> Made:
    head, block, payloads = targets._split_packet((seeds / "packet0.bin").read_bytes())
    struct.pack_into("<d", block, 4 + 8, float("nan"))  # camera 0's first matrix element
    what = "camera 0 matrix[0] -> nan (CRC consistent)"
    return what, targets.packet_run(targets.join_packet(head, block, payloads), None, what,
                                    True), {}


def _packet_zero_cameras(seeds: Path, work: Path) -> Made:
    # The attack: 16 cameras of 8192x4096 whose buffers are all ZERO (no payload).
    head, block, _ = targets._split_packet((seeds / "packet0.bin").read_bytes())
    n = 16
    cam = struct.pack("<II", 8192, 4096) + bytes(block[4 + 8 : 4 + targets._BLOCK_CAMERA])
    zero = b"".join(struct.pack("<BBBBI", c, k, 3, 0, 0) for c in range(n) for k in range(4))
    b = struct.pack("<BBH", n, 0, 4 * n) + cam * n + zero
    what = f"{n} cameras of 8192x4096, every buffer ZERO"
    return what, targets.packet_run(targets.join_packet(head, b, b""), None, what, False), {}


def _stream_truncated(seeds: Path, work: Path) -> Made:
    data = (seeds / "stream.srs").read_bytes()
    (path := work / "s.srs").write_bytes(data[: len(data) // 2])
    what = f"truncated to {len(data) // 2} of {len(data)} bytes (no trailer)"
    return what, targets.stream_run(path, what, True), {}


def _stream_index_far(seeds: Path, work: Path) -> Made:
    data = bytearray((seeds / "stream.srs").read_bytes())
    struct.pack_into("<Q", data, len(data) - 16, (1 << 63) - 1)
    (path := work / "s.srs").write_bytes(bytes(data))
    what = "trailer's index offset -> 2^63 - 1"
    return what, targets.stream_run(path, what, True), {}


def _stream_writer_full(seeds: Path, work: Path) -> Made:
    good = (seeds / "stream.srs").read_bytes()
    packets: list[bytes | None] = [(seeds / f"packet{i}.bin").read_bytes() for i in range(2)]
    (path := work / "out.srs").write_bytes(good)
    return ("write_stream over a stream, file size limit 100 bytes (a full disk)",
            targets.stream_writer_run(path, good, packets, work), {"fsize_limit": 100})


# -- recordings and datasets ----------------------------------------------------------------------


def _recording(edit: Callable[[Path, dict[str, Any]], str]) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        shutil.copytree(seeds / "rec-small", rec := work / "rec")
        manifest = json.loads((rec / "manifest.json").read_text())
        what = edit(rec, manifest)
        return what, targets.recording_run(rec), {}

    return make


def _frame_changed(rec: Path, manifest: dict[str, Any]) -> str:
    entry = manifest["server_frames"][0]
    data = bytearray((rec / entry["file"]).read_bytes())
    data[len(data) // 2] ^= 0x40
    (rec / entry["file"]).write_bytes(bytes(data))
    return f"{entry['file']}: a byte changed, the manifest's SHA-256 not updated"


def _npy_shape_huge(rec: Path, manifest: dict[str, Any]) -> str:
    entry = manifest["server_frames"][0]
    src = zipfile.ZipFile(io.BytesIO((rec / entry["file"]).read_bytes()))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as dst:
        for n in src.namelist():
            raw = src.read(n)
            if n == "main.color.npy":  # (h, w, 3) -> (1000000, h, w, 3): 1.1 TB, data unchanged
                n_head = struct.unpack_from("<H", raw, 8)[0]
                head = raw[10 : 10 + n_head].decode("latin1").replace("(", "(1000000, ")
                head = head.rstrip(" \n")[: n_head - 1].ljust(n_head - 1) + "\n"
                raw = raw[:10] + head.encode("latin1") + raw[10 + n_head :]
            dst.writestr(n, raw)
    new = buf.getvalue()
    (rec / entry["file"]).write_bytes(new)
    entry["bytes"], entry["sha256"] = len(new), hashlib.sha256(new).hexdigest()
    (rec / "manifest.json").write_text(json.dumps(manifest))
    return (f"{entry['file']}: main.color.npy's shape (1000000, h, w, 3) (manifest size and "
            "SHA-256 updated)")


def _fs_zero(rec: Path, manifest: dict[str, Any]) -> str:
    manifest["fs"] = 0
    (rec / "manifest.json").write_text(json.dumps(manifest))
    return "manifest fs -> 0"


def _recording_writer_full(seeds: Path, work: Path) -> Made:
    shutil.copytree(seeds / "rec-small", out := work / "rec")
    return ("write_recording over a recording, file size limit 5000 bytes (a full disk)",
            targets.recording_writer_run(out, work), {"fsize_limit": 5000})


def _dataset(edit: Callable[[Path], str]) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        shutil.copytree(seeds / "dataset", ds := work / "ds")
        return edit(ds), targets.dataset_run(ds), {}

    return make


def _resolution_huge(ds: Path) -> str:
    cam = ds / "main" / "cam.json"
    doc = json.loads(cam.read_text())
    doc["resolution"]["x"] = 1 << 31
    cam.write_text(json.dumps(doc))
    return "main/cam.json: resolution x -> 2^31"


def _depth_missing(ds: Path) -> str:
    (ds / "main" / "depth" / "0001.exr").unlink()
    return "main/depth/0001.exr removed"


def _dataset_writer_escape(seeds: Path, work: Path) -> Made:
    names = ("left", "../../x")
    return (f"export_dataset with aux_names={names}",
            targets.dataset_writer_run(seeds / "rec-small", work / "ds", names, "client_ol"), {})


# -- models ---------------------------------------------------------------------------------------


def _gltf(edit: Callable[[dict[str, Any]], str]) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        for n in ("quad.gltf", "quad.bin"):
            shutil.copy(seeds / n, work / n)
        gltf = json.loads((seeds / "quad.gltf").read_text())
        what = edit(gltf)
        (path := work / "quad.gltf").write_text(dumps(gltf))
        return what, targets.placed_model_run(path, 0), {}

    return make


def _count_huge(gltf: dict[str, Any]) -> str:
    gltf["accessors"][0]["count"] = 1 << 31
    return "accessors[0].count -> 2^31 (past its buffer view)"


def _glb_length_huge(seeds: Path, work: Path) -> Made:
    data = bytearray((seeds / "quad.glb").read_bytes())
    struct.pack_into("<I", data, 8, 0xFFFFFFFF)
    (path := work / "quad.glb").write_bytes(bytes(data))
    return "GLB header length -> 2^32 - 1", targets.placed_model_run(path, 0), {}


# -- command line ---------------------------------------------------------------------------------


def _cli(args: Callable[[Path, Path], list[str]]) -> Callable[[Path, Path], Made]:
    def make(seeds: Path, work: Path) -> Made:
        argv = args(seeds, work)
        shown = " ".join(argv).replace(str(seeds), "SEEDS").replace(str(work), "CASE")
        return f"splitrender {shown}", targets.cli_run(argv, work), {"cli": True}

    return make


def _render_seconds_nan(seeds: Path, work: Path) -> list[str]:
    return ["render", "lab", "--out", str(work / "out"), "--seconds", "nan", "--scale", "0.01",
            "--samples", "1", "--quiet"]


def _play_stream_as_recording(seeds: Path, work: Path) -> list[str]:
    return ["play", str(seeds / "rec"), "--recording", str(seeds / "stream.srs"), "--out",
            str(work / "out"), "--no-vmaf", "--quiet"]


PINNED: tuple[Pinned, ...] = (
    Pinned("trace", "nan-position", "load_trace: every number finite",
           r"TraceError: .*trace\.txt:3: non-finite value", _trace(3, 1, "nan")),
    Pinned("trace", "inf-time", "load_trace: every number finite (a time of inf)",
           r"TraceError: .*trace\.txt:20: non-finite value", _trace(20, 7, "inf")),
    Pinned("trace", "time-repeated", "load_trace: strictly increasing times",
           r"TraceError: .*trace\.txt:10: time .* is not after", _trace_time_repeated),
    Pinned("scene-description", "models-number", "from_description: models is an array",
           r"InvalidInputError: .*models: expected an array of objects, got an integer 3",
           _description(_models_number)),
    Pinned("scene-description", "models-object", "from_description: models is an array",
           r"InvalidInputError: .*models: expected an array of objects",
           _description(_models_object)),
    Pinned("scene-description", "position-short", "from_description: position of 3 numbers",
           r"InvalidInputError: .*models\[0\]: position: expected an array of 3",
           _description(_position_short)),
    Pinned("scene-description", "scale-infinite", "from_description: finite numbers",
           r"InvalidInputError: .*models\[0\]: .*scale: expected a finite",
           _description(_scale_infinite)),
    Pinned("packet", "stale-crc", "unpack_packet: the packet's CRC-32",
           r"StreamError: .*CRC", _packet_stale_crc),
    Pinned("packet", "matrix-nan", "the decoder: finite camera matrices",
           r"StreamError: .*camera matrices are not finite", _packet_matrix_nan),
    Pinned("packet", "zero-cameras", "the decoder: sizes checked before allocating",
           r"StreamError: .*beyond the decoder's limit", _packet_zero_cameras),
    Pinned("stream-file", "truncated", "StreamFile: the trailer and index",
           r"StreamError: .*truncated file", _stream_truncated),
    Pinned("stream-file", "index-far", "StreamFile: the index offset within the file",
           r"StreamError: .*index offset \d+ outside the file", _stream_index_far),
    Pinned("stream-writer", "disk-full",
           "write_stream on a full disk: EFBIG passed on, the previous file kept",
           r"EFBIG", _stream_writer_full),
    Pinned("recording", "frame-changed", "load_recording: each file's SHA-256",
           r"RecordingError: .*SHA-256", _recording(_frame_changed)),
    Pinned("recording", "npy-shape-huge", "load_recording: npy shapes checked before reading",
           r"RecordingError: .*main\.color: uint8 \(1000000, ", _recording(_npy_shape_huge)),
    Pinned("recording", "fs-zero", "load_recording: the manifest's rates",
           r"RecordingError: .*field 'fs': expected a finite number > 0", _recording(_fs_zero)),
    Pinned("recording-writer", "disk-full",
           "write_recording on a full disk: EFBIG passed on, the previous one kept",
           r"EFBIG", _recording_writer_full),
    Pinned("dataset", "resolution-huge", "import_dataset: cam.json's resolution in range",
           r"DatasetError: .*resolution: expected ints in", _dataset(_resolution_huge)),
    Pinned("dataset", "depth-missing", "import_dataset: every frame's files present",
           r"DatasetError: .*0001\.exr: missing file", _dataset(_depth_missing)),
    Pinned("dataset-writer", "name-escapes", "export_dataset: folder names stay inside",
           r"DatasetError: aux_names\[1\]: expected a plain name", _dataset_writer_escape),
    Pinned("gltf", "count-huge", "the glTF loader: an accessor's bytes within the memory budget",
           r"InvalidInputError: .*accessor 0 \(POSITION\) with count", _gltf(_count_huge)),
    Pinned("glb", "length-huge", "the GLB reader: the header's length",
           r"InvalidInputError: .*GLB header length 4294967295", _glb_length_huge),
    Pinned("cli", "seconds-nan", "the command line: --seconds a finite number",
           r"^splitrender render: error: argument --seconds: expected a finite",
           _cli(_render_seconds_nan)),
    Pinned("cli", "stream-as-recording", "the command line: --recording only with a stream",
           r"^splitrender: error: --recording: only with a stream file",
           _cli(_play_stream_as_recording)),
)
