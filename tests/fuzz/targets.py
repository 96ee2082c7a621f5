"""What is fuzzed: per kind, the valid seeds, the structure-aware mutations and the parser run on
them, with the check that makes "accepted" mean "accepting was right".

A :class:`Kind` makes a :class:`Case` in the parent (pure byte and JSON work: no threads), whose
``run`` executes in the forked child and returns normally only when the input was accepted and
what was read back is well-formed; otherwise it raises (a specific error, :class:`WrongAccept`,
:class:`Corrupted`, or whatever escaped).

Why accepting is right, per kind (the check each ``run`` makes):

- ``packet``, ``stream-file``: a mutation with the CRCs made consistent may change payload bytes
  (a different but valid HEVC picture, different zstd bits) or header values inside their limits
  (another time, index or matrix); the decoded frames must pass ``check_server_frame`` (dtype,
  shape, layout of every buffer) and have the packet's camera sizes. A mutation that leaves a
  CRC stale must be refused.
- ``stream-writer``: the writer either finishes (the file reads back exactly the packets
  written) or fails and leaves the previous file byte for byte and no temporary file.
- ``recording``: a mutation with the SHA-256 and size in the manifest made consistent may
  change pixel values or informational fields (scene name, near/far); every frame must load
  and pass ``check_server_frame`` with the manifest's sizes.
- ``recording-writer``, ``dataset-writer``: as ``stream-writer``, for folders: a failed write
  leaves the previous recording loadable and unchanged, and no output folder.
- ``dataset``: bit flips in a PNG's pixels (with its CRC fixed by the mutation of a valid
  image) or cam.json values inside their ranges give other pixels or cameras; the import must
  give frames that pass ``check_server_frame``.
- ``trace``: a line of other finite numbers is another valid trace; the loaded trace must have
  finite, strictly increasing times from 0, finite positions and unit rotations.
- ``scene-description``, ``gltf``, ``glb``: another valid placement or model; the scene must
  render a small server frame that passes ``check_server_frame`` with finite camera matrices.
- ``cli``: exit status 0 without a traceback (and for ``serve``, which serves until
  interrupted, "listening on" printed before the time limit; so for a ``relay`` without
  ``--seconds`` or with more than :data:`RELAY_BOUNDED_S` of it, "relaying"; a command line
  without an option that bounds its work, :data:`BOUNDED_BY`, or with more of it than its
  seed, still running at the limit).
"""

from __future__ import annotations

import base64
import errno
import functools
import hashlib
import io
import json
import math
import os
import random
import shutil
import struct
import sys
import zipfile
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zstandard

from tests.fuzz.harness import (
    CLI_ERROR,
    Corrupted,
    DiskFull,
    Outcome,
    Verdict,
    WrongAccept,
)
from tests.fuzz.mutate import (
    BOUNDARY_FLOATS,
    dumps,
    mutate_bytes,
    mutate_json,
    reorder,
    set_float,
    set_int,
)

# --------------------------------------------------------------------------------------------
# Seeds: generated once per run, in a child (the encoder and the renderer start threads).

SEED_SECONDS = 0.25  # 30 client frames at 120 Hz: enough for `play` and `demo` (25 needed)
SEED_SCALE = 0.01  # 26 x 14 main camera
SMALL_SECONDS = 0.05  # 2 server and 6 client frames


def build_seeds(root: Path) -> None:
    """Writes every seed under ``root``: a recording, its stream and packets, a dataset, a head
    trace, a glTF quad (JSON with an embedded buffer, and GLB, both animated) and a scene
    description placing it."""
    import splitrender as sr
    from splitrender.codec import CodecConfig, StreamEncoder
    from splitrender.codec.stream import write_stream

    rec = root / "rec"
    sr.write_recording(rec, "lab", seconds=SEED_SECONDS, scale=SEED_SCALE, samples=1)
    # The recording and dataset kinds read every frame of theirs in each case: a shorter one.
    sr.write_recording(root / "rec-small", "lab", seconds=SMALL_SECONDS, scale=SEED_SCALE,
                       samples=1)
    recording = sr.load_recording(rec)
    with StreamEncoder(CodecConfig(bitrate_mbps=0.5, gop=2)) as enc:
        packets = [enc.encode(f) for f in recording.server_frames]
    write_stream(root / "stream.srs", packets, fps=10.0)
    for i, p in enumerate(packets):
        (root / f"packet{i}.bin").write_bytes(p)
    sr.export_dataset(root / "rec-small", root / "dataset")
    # `eval --dataset` needs a picture FFmpeg's minterpolate can take (26 x 14 is refused).
    sr.write_recording(root / "rec-eval", "lab", seconds=SEED_SECONDS, scale=0.025, samples=1)
    sr.export_dataset(root / "rec-eval", root / "dataset-eval")
    lines = [
        f"{0.01 * i:.3f} {1.6 + 0.001 * i:.4f} {-0.02 * i:.3f} {i:.1f} {2 * i:.1f} {0.5 * i:.1f} "
        f"{16.667 * i:.3f}"
        for i in range(20)
    ]
    (root / "trace.txt").write_text("\n".join(lines) + "\n")
    gltf, blob = quad_gltf()
    (root / "quad.gltf").write_text(json.dumps(gltf))
    (root / "quad.bin").write_bytes(blob)
    (root / "quad.glb").write_bytes(glb_bytes(gltf, blob))
    (root / "scene.json").write_text(json.dumps(SCENE_DESCRIPTION))


def quad_gltf() -> tuple[dict[str, Any], bytes]:
    """A 2 m quad (two triangles, white material) with a translation animation of two keys,
    its buffer in ``quad.bin``: small, but with every part a model loader walks."""
    pos = [-1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 0.0, -1.0, 2.0, 0.0]
    times = [0.0, 1.0]
    moves = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0]
    blob = (
        struct.pack("<12f", *pos)
        + struct.pack("<6H", 0, 1, 2, 0, 2, 3)
        + b"\0" * 4  # the key times start at byte 64, as their buffer view says
        + struct.pack("<2f", *times)
        + struct.pack("<6f", *moves)
    )
    gltf: dict[str, Any] = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [0.0, 0.0, 0.0], "rotation": [0.0, 0.0, 0.0, 1.0],
                   "scale": [1.0, 1.0, 1.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}}],
        "buffers": [{"byteLength": len(blob), "uri": "quad.bin"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
            {"buffer": 0, "byteOffset": 64, "byteLength": 8},
            {"buffer": 0, "byteOffset": 72, "byteLength": 24},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-1.0, 0.0, 0.0], "max": [1.0, 2.0, 0.0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR",
             "min": [0.0], "max": [1.0]},
            {"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"},
        ],
        "animations": [{
            "samplers": [{"input": 2, "output": 3, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
        }],
    }
    return gltf, blob


def glb_bytes(gltf: dict[str, Any], blob: bytes) -> bytes:
    """The GLB container of ``gltf`` with ``blob`` as its BIN chunk (buffer 0 without a uri)."""
    doc = json.loads(json.dumps(gltf))
    del doc["buffers"][0]["uri"]
    text = dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary = blob + b"\0" * (-len(blob) % 4)
    body = (
        struct.pack("<II", len(text), 0x4E4F534A) + text
        + struct.pack("<II", len(binary), 0x004E4942) + binary
    )
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


SCENE_DESCRIPTION: dict[str, Any] = {
    "scene": "lab",
    "variant": "static",
    "models": [{"path": "quad.gltf", "position": [0.0, 0.0, -2.0], "yaw_deg": 30.0,
                "scale": 0.5, "animation": 0, "time_offset": 0.0, "speed": 1.0}],
}


# --------------------------------------------------------------------------------------------
# Cases


@dataclass
class Case:
    """One mutated input: ``run`` executes in the child (see the module docstring)."""

    kind: str
    index: int
    mutation: str
    run: Callable[[], None]
    fsize_limit: int | None = None
    time_limit: float | None = None
    cli: bool = False  # run() raises SystemExit with the exit status; classified from the log


@dataclass
class Kind:
    name: str
    make: Callable[[random.Random, Path, Path], tuple[str, Callable[[], None], dict[str, Any]]]
    time_limit: float = 20.0
    weight: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict)


def _well_formed(where: str, frame: object, sizes: list[tuple[int, int]] | None = None) -> None:
    from splitrender.errors import InvalidInputError
    from splitrender.types import ServerFrame, check_server_frame

    try:
        check_server_frame(where, frame)
    except InvalidInputError as e:
        raise WrongAccept(f"{where}: accepted but not well-formed: {e}") from None
    assert isinstance(frame, ServerFrame)
    cams = [frame.main, *frame.aux]
    got = [(c.camera.width, c.camera.height) for c in cams]
    if sizes is not None and got != sizes:
        raise WrongAccept(f"{where}: camera sizes {got}, the input says {sizes}")
    for c in cams:
        if not (np.isfinite(c.camera.view).all() and np.isfinite(c.camera.proj).all()):
            raise WrongAccept(f"{where}: accepted with non-finite camera matrices")


def special_file(path: Path, rng: random.Random) -> str:
    """Replaces the file ``path`` by something that is not a regular file of bounded size: a
    FIFO (an open() of it blocks), a link to /dev/zero (endless, st_size 0), a folder, a
    dangling link or a link loop. Returns what it is."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    what = rng.choice(("fifo", "zero", "folder", "dangling", "loop"))
    if what == "fifo":
        os.mkfifo(path)
    elif what == "zero":
        path.symlink_to("/dev/zero")
    elif what == "folder":
        path.mkdir()
    elif what == "dangling":
        path.symlink_to(path.with_name("missing-target"))
    else:
        path.symlink_to(path.name)
    return f"{path.name} replaced by a {what}"


# -- packets ----------------------------------------------------------------------------------

_BLOCK_CAMERA = 264


def _split_packet(data: bytes) -> tuple[bytes, bytearray, bytes]:
    m = struct.unpack_from("<I", data, 24)[0]
    block = zstandard.ZstdDecompressor().decompress(data[32 : 32 + m])
    return data[:32], bytearray(block), data[32 + m :]


def join_packet(head: bytes, block: bytes | bytearray, payloads: bytes) -> bytes:
    """A packet from its parts with a consistent block length and CRC: a hostile sender
    writes consistent CRCs, so mutations must get past them to reach the parser."""
    packed = zstandard.ZstdCompressor(write_content_size=True).compress(bytes(block))
    head = head[:24] + struct.pack("<I", len(packed))
    crc = zlib.crc32(payloads, zlib.crc32(packed, zlib.crc32(head)))
    return head + struct.pack("<I", crc) + packed + payloads


def _entries(block: bytes | bytearray) -> list[tuple[int, int, int]]:
    """``(offset, size with its pairs, payload length)`` of each table entry of a block."""
    n_cam, _, n_buf = struct.unpack_from("<BBH", block, 0)
    pos = 4 + n_cam * _BLOCK_CAMERA
    out = []
    for _ in range(n_buf):
        n_par, length = block[pos + 3], struct.unpack_from("<I", block, pos + 4)[0]
        out.append((pos, 8 + 8 * n_par, length))
        pos += 8 + 8 * n_par
    return out


def mutate_packet(data: bytes, rng: random.Random) -> tuple[bytes, str, bool]:
    """``(packet, description, must_refuse)``: one structure-aware mutation of a valid packet."""
    head, block, payloads = _split_packet(data)
    entries = _entries(block)
    op = rng.choice(("fixed", "stale-crc", "block-int", "block-int", "block-float",
                     "block-bytes", "entries", "payload", "payload", "huge"))
    if op == "fixed":
        off, width, name = rng.choice(((4, 2, "version"), (6, 2, "flags"), (8, 8, "index"),
                                       (16, 0, "time"), (24, 4, "block length")))
        if width:
            h, what = set_int(head, off, width, rng)
        else:
            h, what = set_float(head, off, rng)
        if name == "block length":  # the length is the field under test: keep it, fix the CRC
            crc = zlib.crc32(data[32:], zlib.crc32(h[:28]))
            return h[:28] + struct.pack("<I", crc) + data[32:], f"{name} {what}", False
        return join_packet(h, block, payloads), f"{name} {what}", False
    if op == "stale-crc":
        out, what = mutate_bytes(data, rng)
        return out, f"{what}, CRC left stale", out != data
    if op in ("block-int", "block-float"):
        fields: list[tuple[int, int, str]] = [(0, 1, "cameras"), (1, 1, "reserved"), (2, 2, "entries")]
        n_cam = block[0]
        for i in range(n_cam):
            base = 4 + i * _BLOCK_CAMERA
            fields += [(base, 4, f"camera {i} width"), (base + 4, 4, f"camera {i} height")]
        for j, (pos, size, _) in enumerate(entries):
            fields += [(pos, 1, f"entry {j} camera"), (pos + 1, 1, f"entry {j} kind"),
                       (pos + 2, 1, f"entry {j} codec"), (pos + 3, 1, f"entry {j} pairs"),
                       (pos + 4, 4, f"entry {j} payload length")]
        if op == "block-int":
            off, width, name = rng.choice(fields)
            b, what = set_int(bytes(block), off, width, rng)
            return join_packet(head, b, payloads), f"{name} {what}", False
        floats = [(4 + i * _BLOCK_CAMERA + 8 + 8 * k, f"camera {i} matrix[{k}]")
                  for i in range(n_cam) for k in range(32)]
        pairs = [(pos + 8 + 4 * k, f"entry {j} scale/offset[{k}]")
                 for j, (pos, size, _) in enumerate(entries) for k in range((size - 8) // 4)]
        if pairs and rng.random() < 0.5:
            off, name = rng.choice(pairs)
            v = rng.choice(BOUNDARY_FLOATS)
            edited = bytearray(block)
            edited[off : off + 4] = struct.pack("<f", v if abs(v) < 3.4e38 or not math.isfinite(v) else math.inf)
            return join_packet(head, edited, payloads), f"{name} -> f32 {v!r}", not math.isfinite(v)
        off, name = rng.choice(floats)
        b2, what = set_float(bytes(block), off, rng)
        v = struct.unpack_from("<d", b2, off)[0]
        return join_packet(head, b2, payloads), f"{name} {what}", not math.isfinite(v)
    if op == "block-bytes":
        b3, what = mutate_bytes(bytes(block), rng)
        return join_packet(head, b3, payloads), f"header block: {what}", False
    if op == "entries":
        # Entries reordered, dropped or duplicated, payloads following their entries (or not).
        spans, at = [], 0
        for pos, size, length in entries:
            spans.append((bytes(block[pos : pos + size]), payloads[at : at + length]))
            at += length
        new, what = reorder(spans, rng)
        start = entries[0][0] if entries else len(block)
        b4 = bytearray(block[:start]) + b"".join(e for e, _ in new)
        struct.pack_into("<H", b4, 2, len(new))
        moved = rng.random() < 0.7
        pl = b"".join(p for _, p in new) if moved else payloads
        return (join_packet(head, b4, pl),
                f"entries: {what} ({'payloads moved along' if moved else 'payloads kept'})", False)
    if op == "payload":
        if not payloads:
            return join_packet(head, block, b"\0"), "one payload byte appended", True
        p, what = mutate_bytes(payloads, rng)
        return join_packet(head, block, p), f"payloads: {what}", False
    # The attack: many large cameras whose buffers are all ZERO (no payload bytes).
    n = rng.choice((1, 2, 4, 16))
    cw, ch = rng.choice(((8192, 4096), (16384, 2048), (4096, 4096), (5793, 5793)))
    cams = b"".join(struct.pack("<II", cw, ch) + bytes(block[4 + 8 : 4 + _BLOCK_CAMERA])
                    for _ in range(n))
    zero = b"".join(struct.pack("<BBBBI", c, k, 3, 0, 0) for c in range(n) for k in (0, 1, 2, 3))
    b5 = struct.pack("<BBH", n, 0, 4 * n) + cams + zero
    return join_packet(head, b5, b""), f"{n} cameras of {cw}x{ch}, every buffer ZERO", False


def _packet_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    which = rng.randrange(2)
    good = [(seeds / f"packet{i}.bin").read_bytes() for i in range(2)]
    data, what, must_refuse = mutate_packet(good[which], rng)
    return f"packet {which}: {what}", packet_run(data, good[0] if which == 1 else None, what,
                                                 must_refuse), {}


def packet_run(
    data: bytes, before: bytes | None, what: str, must_refuse: bool
) -> Callable[[], None]:
    """The ``packet`` kind's run: decodes ``data`` (after the packet ``before``, when given)
    and checks the frame."""

    def run() -> None:
        from splitrender.codec.coder import StreamDecoder
        from splitrender.codec.stream import unpack_packet

        p = unpack_packet(data)
        with StreamDecoder() as d:
            if before is not None:
                d.decode(before)
            frame = d.decode(data)
        if must_refuse:
            raise WrongAccept(f"accepted a packet that must be refused ({what})")
        _well_formed("decoded", frame, [(c.width, c.height) for c in p.cameras])

    return run


# -- stream files -----------------------------------------------------------------------------


def _stream_layout(data: bytes) -> tuple[list[int], int]:
    """``(record offsets, index offset)`` of a container file with a trailer."""
    index = struct.unpack_from("<Q", data, len(data) - 16)[0]
    offs, pos = [], 24
    while pos < index:
        offs.append(pos)
        pos += 4 + struct.unpack_from("<I", data, pos)[0]
    return offs, index


def _fix_index_crc(data: bytes, index: int) -> bytes:
    n = struct.unpack_from("<I", data, index + 4)[0]
    end = index + 8 + 24 * n
    if end + 4 > len(data) - 16:
        return data
    crc = zlib.crc32(data[index + 8 : end])
    return data[:end] + struct.pack("<I", crc) + data[end + 4 :]


def _stream_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    from splitrender.codec.stream import write_stream

    data = (seeds / "stream.srs").read_bytes()
    offs, index = _stream_layout(data)
    packets = [data[o + 4 : o + 4 + struct.unpack_from("<I", data, o)[0]] for o in offs]
    op = rng.choice(("header", "record-length", "index", "index", "trailer", "bytes",
                     "reorder", "packet", "truncate", "special"))
    path = work / "s.srs"
    must_refuse = False
    if op == "special":
        out, what = b"", ""
    elif op == "header":
        off, width, name = rng.choice(((0, 1, "magic"), (8, 2, "version"), (10, 2, "reserved"),
                                       (12, 4, "reserved"), (16, 0, "fps")))
        out, what = set_int(data, off, width, rng) if width else set_float(data, off, rng)
        what = f"{name} {what}"
    elif op == "record-length":
        o = rng.choice(offs)
        out, what = set_int(data, o, 4, rng)
        what = f"record length {what}"
    elif op == "index":
        n = struct.unpack_from("<I", data, index + 4)[0]
        fields = [(index + 4, 4, "index count")]
        for i in range(n):
            e = index + 8 + 24 * i
            fields += [(e, 8, f"index {i} frame"), (e + 8, 8, f"index {i} offset"),
                       (e + 16, 1, f"index {i} key")]
        off, width, name = rng.choice(fields)
        out, what = set_int(data, off, width, rng)
        fix = rng.random() < 0.7
        if fix:
            out = _fix_index_crc(out, index)
        what = f"{name} {what}{' (index CRC fixed)' if fix else ''}"
    elif op == "trailer":
        out, what = set_int(data, len(data) - 16, 8, rng)
        what = f"trailer index offset {what}"
    elif op == "bytes":
        out, what = mutate_bytes(data, rng)
    elif op == "truncate":
        cut = rng.randrange(len(data))
        out, what = data[:cut], f"truncated to {cut} of {len(data)} bytes (no trailer)"
    elif op == "reorder":
        new, what = reorder(packets, rng)
        write_stream(path, new, fps=10.0)  # a well-formed container of reordered packets
        out, what = path.read_bytes(), f"packets {what}, index rebuilt"
    else:
        o = rng.choice(offs)
        n = struct.unpack_from("<I", data, o)[0]
        out, what = mutate_bytes(data, rng, o + 4, o + 4 + n)
        what = f"inside record at {o}: {what} (packet CRC stale)"
        must_refuse = len(out) == len(data) and out != data
    path.write_bytes(out)
    if op == "special":
        what = special_file(path, rng)
    return what, stream_run(path, what, must_refuse), {}


def stream_run(path: Path, what: str, must_refuse: bool) -> Callable[[], None]:
    """The ``stream-file`` kind's run: reads and decodes every packet of ``path``."""

    def run() -> None:
        from splitrender.codec.coder import StreamDecoder
        from splitrender.codec.stream import StreamFile, unpack_packet

        f = StreamFile(path)
        frames = []
        with StreamDecoder() as d:
            for data in f.packets():
                frames.append((d.decode(data), unpack_packet(data)))
        for key in f.key_frames[:2]:
            for _ in f.packets(start=key):
                pass
        if must_refuse:
            raise WrongAccept(f"accepted a stream that must be refused ({what})")
        for k, (frame, packet) in enumerate(frames):
            _well_formed(f"frame {k}", frame, [(c.width, c.height) for c in packet.cameras])

    return run


# -- writers ----------------------------------------------------------------------------------


def _tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*")) if p.is_file()
    }


def _leftovers(folder: Path, name: str) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(f".{name}.partial")
            or p.name.startswith(f"{name}.partial")]


def _disk_full() -> None:
    """Called while handling a writer's exception, its output checked: the simulated full disk
    (EFBIG) is the error a writer must let through, as the caller's ``OSError``."""
    e = sys.exc_info()[1]
    if isinstance(e, OSError) and e.errno == errno.EFBIG:
        raise DiskFull(f"OSError EFBIG (the simulated full disk): {e}") from None


def _stream_writer_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    good = (seeds / "stream.srs").read_bytes()
    packets = [(seeds / f"packet{i}.bin").read_bytes() for i in range(2)]
    path = work / "out.srs"
    path.write_bytes(good)  # the previous good file the writer must not destroy
    op = rng.choice(("disk-full", "disk-full", "raises", "bad-packet", "ok"))
    opts: dict[str, Any] = {}
    items: list[bytes | None] = [*packets, *packets]
    if op == "disk-full":
        limit = rng.randrange(1, sum(len(p) + 4 for p in packets) * 2 + 24 + 100)
        opts["fsize_limit"] = limit
        what = f"file size limit {limit} bytes (a full disk)"
    elif op == "raises":
        at = rng.randrange(len(items) + 1)
        items.insert(at, None)
        what = f"the packet iterator raises after {at} packets"
    elif op == "bad-packet":
        bad, w = mutate_bytes(packets[0], rng, 0, 32)
        at = rng.randrange(len(items) + 1)
        items.insert(at, bad)
        what = f"packet {at} mangled ({w})"
    else:
        what = "four valid packets"
    return what, stream_writer_run(path, good, items, work), opts


def stream_writer_run(path: Path, good: bytes, items: list[bytes | None],
                      work: Path) -> Callable[[], None]:
    """The ``stream-writer`` kind's run: writes ``items`` (``None``: the iterator is
    interrupted there) over ``path``, whose bytes are ``good``."""

    def packet_iter() -> Iterator[bytes]:
        for p in items:
            if p is None:
                raise KeyboardInterrupt("interrupted by the fuzz case")
            yield p

    def run() -> None:
        from splitrender.codec.stream import read_stream, write_stream

        try:
            write_stream(path, packet_iter(), fps=10.0)
        except BaseException:
            if path.read_bytes() != good:
                raise Corrupted("the write failed and the previous file changed") from None
            if _leftovers(work, path.name):
                raise Corrupted(f"temporary files left: {_leftovers(work, path.name)}") from None
            _disk_full()
            raise
        back = list(read_stream(path))
        if back != [p for p in items if p is not None]:
            raise Corrupted("the written file does not read back as the packets written")

    def wrapped() -> None:
        try:
            run()
        except KeyboardInterrupt:
            pass  # the interruption the case made, handled as it should be (checked above)

    return wrapped


def _recording_writer_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    out = work / "rec"
    shutil.copytree(seeds / "rec-small", out)
    limit = rng.randrange(1, 40_000)
    return (f"write_recording over a recording, file size limit {limit} bytes",
            recording_writer_run(out, work), {"fsize_limit": limit})


def recording_writer_run(out: Path, work: Path) -> Callable[[], None]:
    """The ``recording-writer`` kind's run: writes a recording over the recording ``out``."""
    before = _tree_digest(out)

    def run() -> None:
        import splitrender as sr

        try:
            sr.write_recording(out, "lab", seconds=SMALL_SECONDS, scale=SEED_SCALE, samples=1,
                               overwrite=True)
        except BaseException:
            if not out.is_dir() or _tree_digest(out) != before:
                raise Corrupted("the write failed and the previous recording changed") from None
            if _leftovers(work, out.name):
                raise Corrupted(f"partial folders left: {_leftovers(work, out.name)}") from None
            sr.load_recording(out).verify()
            _disk_full()
            raise
        sr.load_recording(out).verify()

    return run


def _dataset_writer_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    out = work / "ds"
    opts: dict[str, Any] = {}
    names: tuple[str, ...] = ("left", "right")
    client = "client_ol"
    if rng.random() < 0.5:
        limit = rng.randrange(1, 20_000)
        opts["fsize_limit"] = limit
        what = f"export_dataset, file size limit {limit} bytes"
    else:
        bad = rng.choice(("../../x", "..", ".", "", "a/b", "/abs", "x\x00y", "left", "c\\d"))
        if rng.random() < 0.5:
            names = (names[0], bad)
        else:
            client = bad
        what = f"export_dataset with aux_names={names}, client={client!r}"
    return what, dataset_writer_run(seeds / "rec-small", out, names, client), opts


def dataset_writer_run(
    rec: Path, out: Path, names: tuple[str, ...], client: str
) -> Callable[[], None]:
    """The ``dataset-writer`` kind's run: exports the recording ``rec`` to ``out`` with
    ``names`` for the auxiliary cameras' folders and ``client`` for the client's."""
    work = out.parent

    def run() -> None:
        import splitrender as sr
        from splitrender.scene.dataset import import_dataset

        outside = sorted(p.name for p in work.parent.iterdir())
        try:
            sr.export_dataset(rec, out, aux_names=names, client=client)
        except BaseException:
            if out.exists() and any(out.iterdir()):
                raise Corrupted("the export failed and left files in its output folder") from None
            if sorted(p.name for p in work.parent.iterdir()) != outside:
                raise Corrupted("the export failed and wrote outside its folder") from None
            _disk_full()
            raise
        if len(set(names)) < 2 or client in names:
            raise WrongAccept(f"two cameras written to one folder ({names}, {client!r})")
        data = import_dataset(out, names, client)
        for k, f in enumerate(data.server_frames):
            _well_formed(f"frame {k}", f)

    return run


# -- recordings -------------------------------------------------------------------------------


def _rewrite_npz_member(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """The npz with one member's npy header or data mutated (a valid zip around it)."""
    src = zipfile.ZipFile(io.BytesIO(data))
    names = src.namelist()
    victim = rng.choice(names)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as dst:
        for n in names:
            raw = src.read(n)
            if n == victim:
                hlen = struct.unpack_from("<H", raw, 8)[0]
                if rng.random() < 0.5:
                    header = raw[10 : 10 + hlen].decode("latin1")
                    new = rng.choice((
                        header.replace("<f4", "<f8"), header.replace("|u1", "<u2"),
                        header.replace("<f4", "|O"), header.replace("False", "True"),
                        header.replace("(", "(1000000, "), header.replace("(", "(0, "),
                        header.replace("<f8", ">f8"), "{'descr': '<f4'",
                    ))
                    new += " " * max(0, hlen - len(new))
                    raw = raw[:8] + struct.pack("<H", len(new)) + new.encode("latin1") + raw[10 + hlen :]
                    what = f"{victim}: npy header -> {new.strip()[:60]!r}"
                else:
                    raw, what = mutate_bytes(raw, rng, 0, len(raw))
                    what = f"{victim}: {what}"
            dst.writestr(n, raw)
    return buf.getvalue(), what


def _recording_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    rec = work / "rec"
    shutil.copytree(seeds / "rec-small", rec)
    mpath = rec / "manifest.json"
    manifest = json.loads(mpath.read_text())
    op = rng.choice(("manifest", "manifest", "npz-bytes", "npz-member", "npz-member", "remove",
                     "raw-manifest", "special"))
    if op == "special":
        victim = rng.choice([mpath, rec / manifest["server_frames"][0]["file"],
                             rec / manifest["client_frames"][-1]["file"]])
        what = f"{victim.relative_to(rec).parent}/{special_file(victim, rng)}"
    elif op == "manifest":
        focus = [("version",), ("cameras", "main"), ("cameras", "aux", 0), ("cameras", "eyes"),
                 ("server_frames",), ("client_frames",), ("server_frames", 0, "bytes"),
                 ("server_frames", 1, "time"), ("fs",), ("fc",), ("samples",), ("stereo",),
                 ("server_frames", 0, "file"), ("subframes",)]
        doc, what = mutate_json(manifest, rng, focus)
        mpath.write_text(dumps(doc))
    elif op == "raw-manifest":
        raw, what = mutate_bytes(mpath.read_bytes(), rng)
        mpath.write_bytes(raw)
        what = f"manifest.json: {what}"
    elif op in ("npz-bytes", "npz-member"):
        kind = rng.choice(("server_frames", "client_frames"))
        i = rng.randrange(len(manifest[kind]))
        entry = manifest[kind][i]
        p = rec / entry["file"]
        if op == "npz-bytes":
            new, what = mutate_bytes(p.read_bytes(), rng)
        else:
            new, what = _rewrite_npz_member(p.read_bytes(), rng)
        p.write_bytes(new)
        if rng.random() < 0.8:  # a consistent manifest: the mutation reaches the npz parser
            entry["bytes"], entry["sha256"] = len(new), hashlib.sha256(new).hexdigest()
            mpath.write_text(json.dumps(manifest))
            what += " (manifest size and SHA-256 updated)"
        what = f"{entry['file']}: {what}"
    else:
        victim = rng.choice(sorted(q for q in rec.rglob("*") if q.is_file()))
        victim.unlink()
        what = f"{victim.relative_to(rec)} removed"
    return what, recording_run(rec), {}


def recording_run(rec: Path) -> Callable[[], None]:
    """The ``recording`` kind's run: loads ``rec`` and checks every frame."""

    def run() -> None:
        import splitrender as sr

        r = sr.load_recording(rec)
        m = r.manifest
        sizes = [tuple(m["cameras"]["main"]), *(tuple(a) for a in m["cameras"]["aux"])]
        for k, f in enumerate(r.server_frames):
            _well_formed(f"server frame {k}", f, [(int(w), int(h)) for w, h in sizes])
        for c in r.client_frames:
            for req in c.requests:
                if not np.isfinite(req.camera.view).all():
                    raise WrongAccept("client camera not finite")
            if c.ground_truth.shape != (c.camera.height, c.camera.width, 3):
                raise WrongAccept(f"ground truth of shape {c.ground_truth.shape}")

    return run


# -- datasets ---------------------------------------------------------------------------------


def _dataset_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    ds = work / "ds"
    shutil.copytree(seeds / "dataset", ds)
    op = rng.choice(("cam", "cam", "cam", "image", "image", "remove", "special"))
    if op == "special":
        victim = rng.choice([ds / "main" / "cam.json", ds / "client_ol" / "cam.json",
                             ds / "left" / "color" / "0000.png", ds / "main" / "depth" / "0001.exr",
                             ds / "right" / "forwardShadowInfo" / "0000.png"])
        what = f"{victim.relative_to(ds).parent}/{special_file(victim, rng)}"
    elif op == "cam":
        cam = ds / rng.choice(("main", "left", "right", "client_ol")) / "cam.json"
        doc = json.loads(cam.read_text())
        focus = [("resolution",), ("resolution", "x"), ("frames",), ("frames", 0, "idx"),
                 ("frames", 0, "w2c"), ("frames", 0, "w2c", "e00"), ("frames", 0, "proj", "e11"),
                 ("serverFps",), ("shadowFps",), ("clientFps",)]
        new_doc, what = mutate_json(doc, rng, focus)
        cam.write_text(dumps(new_doc))
        what = f"{cam.relative_to(ds)}: {what}"
    elif op == "image":
        victim = rng.choice(sorted(q for q in ds.rglob("*") if q.suffix in (".png", ".exr")))
        new, w = mutate_bytes(victim.read_bytes(), rng)
        victim.write_bytes(new)
        what = f"{victim.relative_to(ds)}: {w}"
    else:
        victim = rng.choice(sorted(ds.rglob("*")))
        if victim.is_dir():
            shutil.rmtree(victim)
        else:
            victim.unlink()
        what = f"{victim.relative_to(ds)} removed"
    return what, dataset_run(ds), {}


def dataset_run(ds: Path) -> Callable[[], None]:
    """The ``dataset`` kind's run: imports ``ds`` and checks every frame."""

    def run() -> None:
        from splitrender.scene.dataset import dataset_info, import_dataset

        data = import_dataset(ds)
        info = dataset_info(ds)
        if not (info.server_fps > 0 and info.client_fps > 0 and info.subframes >= 1):
            raise WrongAccept(f"rates {info}")
        for k, f in enumerate(data.server_frames):
            _well_formed(f"frame {k}", f)
        for req, truth in zip(data.client_requests, data.ground_truth):
            if truth is not None and truth.shape != (req.camera.height, req.camera.width, 3):
                raise WrongAccept(f"ground truth of shape {truth.shape}")
            if not math.isfinite(req.time):
                raise WrongAccept(f"client time {req.time}")

    return run


# -- traces -----------------------------------------------------------------------------------


def _trace_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    text = (seeds / "trace.txt").read_text()
    lines = text.splitlines()
    op = rng.choice(("field", "field", "lines", "bytes", "columns", "encoding", "special"))
    if op == "special":
        out, what = b"", ""
    elif op == "field":
        i = rng.randrange(len(lines))
        fields = lines[i].split()
        j = rng.randrange(len(fields))
        v = rng.choice(("nan", "inf", "-inf", "1e309", "-1e309", "1e308", "-1e308", "1e-320", "0",
                        "-0", "x", "0x10", "1_000", "", "１", "1e", "+", "9" * 400,
                        fields[j] + fields[j], str(float(fields[j]) - 1000)))
        fields[j] = v
        lines[i] = " ".join(fields)
        what = f"line {i + 1} field {j + 1} -> {v[:20]!r}"
        out = ("\n".join(lines) + "\n").encode()
    elif op == "lines":
        new, what = reorder(lines, rng)
        out = ("\n".join(new) + "\n").encode()
        what = f"lines {what}"
    elif op == "columns":
        i = rng.randrange(len(lines))
        lines[i] = rng.choice((lines[i] + " 1", " ".join(lines[i].split()[:-1]), lines[i].replace(" ", "\t"),
                               lines[i].replace(" ", ",")))
        out = ("\n".join(lines) + "\n").encode()
        what = f"line {i + 1} columns changed"
    elif op == "encoding":
        out, what = rng.choice(((b"\xff\xfe" + text.encode("utf-16-le"), "UTF-16"),
                                (text.replace("\n", "\r\n").encode(), "CRLF"),
                                (b"", "empty file"), (b"\n\n \n", "blank lines only"),
                                (text.encode() + b"\x00", "trailing NUL")))
    else:
        out, what = mutate_bytes(text.encode(), rng)
    path = work / "trace.txt"
    path.write_bytes(out)
    if op == "special":
        what = special_file(path, rng)
    return what, trace_run(path), {}


def trace_run(path: Path) -> Callable[[], None]:
    """The ``trace`` kind's run: loads the trace ``path`` and checks what it holds."""

    def run() -> None:
        from splitrender.scene.builtin import load_trace

        t = load_trace(path)
        ts = t.times
        if not (np.isfinite(ts).all() and ts[0] == 0 and (np.diff(ts) > 0).all()):
            raise WrongAccept(f"times not finite and strictly increasing from 0: {ts[:5]}...")
        if not np.isfinite(t.positions).all():
            raise WrongAccept("non-finite positions")
        if not np.allclose(np.linalg.norm(t.rotations, axis=1), 1.0):
            raise WrongAccept("rotations not unit quaternions")
        for s in (0.0, t.duration / 2, t.duration):
            if not np.isfinite(t.pose(s)).all():
                raise WrongAccept(f"pose({s}) not finite")

    return run


# -- scene descriptions, glTF, GLB --------------------------------------------------------------


def _render_check(scene: Any) -> None:
    frame = scene.server_frame(0, 0.01, samples=1)
    _well_formed("rendered", frame)


def _placed_model(
    path: Path, what: str, rng: random.Random
) -> tuple[str, Callable[[], None], dict[str, Any]]:
    """The case of a (mutated) model file: placed in front of the camera, animated or at rest,
    loaded and rendered."""
    anim = rng.choice((0, None))
    return f"{what} (animation {anim})", placed_model_run(path, anim), {}


def placed_model_run(path: Path, anim: int | None) -> Callable[[], None]:
    """The ``gltf`` and ``glb`` kinds' run: the model ``path`` placed in front of the camera,
    loaded and rendered."""

    def run() -> None:
        from splitrender.scene.builtin import ModelPlacement, Scene

        scene = Scene("lab", "static", [ModelPlacement(str(path), (0.0, 0.0, -2.0), animation=anim)])
        _render_check(scene)

    return run


def _copy_model(seeds: Path, work: Path) -> None:
    for n in ("quad.gltf", "quad.bin", "quad.glb"):
        shutil.copy(seeds / n, work / n)


def _description_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    _copy_model(seeds, work)
    doc = json.loads((seeds / "scene.json").read_text())
    if rng.random() < 0.1:
        (work / "scene.json").write_text("{}")
        what = special_file(work / "scene.json", rng)
    elif rng.random() < 0.15:
        raw, what = mutate_bytes(json.dumps(doc).encode(), rng)
        (work / "scene.json").write_bytes(raw)
    else:
        focus = [("scene",), ("variant",), ("models",), ("models", 0), ("models", 0, "path"),
                 ("models", 0, "position"), ("models", 0, "position", 1), ("models", 0, "scale"),
                 ("models", 0, "animation"), ("models", 0, "speed"), ("models", 0, "yaw_deg"),
                 ("models", 0, "time_offset")]
        new, what = mutate_json(doc, rng, focus)
        (work / "scene.json").write_text(dumps(new))
    return what, description_run(work / "scene.json"), {}


def description_run(path: Path) -> Callable[[], None]:
    """The ``scene-description`` kind's run: the scene of the description ``path``, loaded and
    rendered."""

    def run() -> None:
        from splitrender.scene.builtin import Scene

        scene = Scene.from_description(path)
        _render_check(scene)

    return run


def _gltf_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    _copy_model(seeds, work)
    gltf = json.loads((seeds / "quad.gltf").read_text())
    op = rng.choice(("json", "json", "json", "bin", "embedded"))
    if op == "json":
        focus = [("accessors", 0, "count"), ("accessors", 0, "byteOffset"), ("accessors", 0, "type"),
                 ("accessors", 0, "componentType"), ("accessors", 1, "count"),
                 ("accessors", 1, "componentType"), ("bufferViews", 0, "byteLength"),
                 ("bufferViews", 0, "byteOffset"), ("bufferViews", 1, "byteStride"),
                 ("bufferViews", 0, "buffer"), ("buffers", 0, "byteLength"), ("buffers", 0, "uri"),
                 ("nodes", 0, "translation"), ("nodes", 0, "rotation"), ("nodes", 0, "scale"),
                 ("nodes", 0, "mesh"), ("meshes", 0, "primitives", 0, "indices"),
                 ("meshes", 0, "primitives", 0, "attributes", "POSITION"),
                 ("animations", 0, "channels", 0, "target", "node"),
                 ("animations", 0, "samplers", 0, "input"), ("animations", 0, "samplers", 0, "output"),
                 ("scenes", 0, "nodes"), ("scene",), ("asset", "version")]
        if rng.random() < 0.2:
            gltf["bufferViews"][0]["byteStride"] = rng.choice((4, 8, 12, 16, 0, 255, 256))
            what = f"bufferViews/0/byteStride = {gltf['bufferViews'][0]['byteStride']}"
            new: Any = gltf
        elif rng.random() < 0.2:
            gltf["nodes"][0]["matrix"] = [rng.choice((0.0, 1e39, 1.0, -1.0)) for _ in range(16)]
            what = "nodes/0/matrix set"
            new = gltf
        else:
            new, what = mutate_json(gltf, rng, focus)
        (work / "quad.gltf").write_text(dumps(new))
    elif op == "bin":
        blob = (seeds / "quad.bin").read_bytes()
        if rng.random() < 0.5:
            k = rng.randrange(len(blob) // 4)
            v = rng.choice(BOUNDARY_FLOATS)
            b = bytearray(blob)
            b[4 * k : 4 * k + 4] = struct.pack("<f", v if abs(v) < 3.4e38 or not math.isfinite(v) else math.inf)
            new_blob, what = bytes(b), f"quad.bin float {k} -> {v!r}"
        else:
            new_blob, what = mutate_bytes(blob, rng)
            what = f"quad.bin: {what}"
        (work / "quad.bin").write_bytes(new_blob)
    else:
        blob = (seeds / "quad.bin").read_bytes()
        uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        uri = rng.choice((uri[:-4], uri + "!!", uri.replace("base64,", "base64,="), uri,
                          "data:application/octet-stream;base64,", "data:text/plain,abc"))
        gltf["buffers"][0]["uri"] = uri
        (work / "quad.gltf").write_text(json.dumps(gltf))
        what = f"buffer as a data URI ({uri[:40]}..., {len(uri)} chars)"
    return _placed_model(work / "quad.gltf", what, rng)


def _glb_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    _copy_model(seeds, work)
    data = (seeds / "quad.glb").read_bytes()
    json_len = struct.unpack_from("<I", data, 12)[0]
    bin_at = 20 + json_len
    op = rng.choice(("header", "chunk", "chunk", "json", "bin", "bytes"))
    if op == "header":
        off, width, name = rng.choice(((0, 1, "magic"), (4, 4, "version"), (8, 4, "length")))
        out, what = set_int(data, off, width, rng)
        what = f"GLB {name} {what}"
    elif op == "chunk":
        off, name = rng.choice(((12, "JSON chunk length"), (16, "JSON chunk type"),
                                (bin_at, "BIN chunk length"), (bin_at + 4, "BIN chunk type")))
        out, what = set_int(data, off, 4, rng)
        what = f"{name} {what}"
    elif op == "json":
        gltf, blob = quad_gltf()
        new, what = mutate_json(gltf, rng, [("accessors", 0, "count"), ("bufferViews", 0, "byteLength"),
                                            ("buffers", 0, "byteLength"), ("accessors", 1, "byteOffset")])
        if isinstance(new, dict) and isinstance(new.get("buffers"), list) and new["buffers"] \
                and isinstance(new["buffers"][0], dict):
            new["buffers"][0]["uri"] = "x"
        try:
            out = glb_bytes(new, blob)
        except (KeyError, TypeError, IndexError):
            text = dumps(new).encode()
            text += b" " * (-len(text) % 4)
            body = struct.pack("<II", len(text), 0x4E4F534A) + text
            out = struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body
        what = f"GLB JSON: {what}"
    elif op == "bin":
        out, what = mutate_bytes(data, rng, bin_at + 8, len(data))
        what = f"GLB BIN: {what}"
    else:
        out, what = mutate_bytes(data, rng)
    (work / "quad.glb").write_bytes(out)
    return _placed_model(work / "quad.glb", what, rng)


# -- command line -----------------------------------------------------------------------------


def cli_seeds(seeds: Path, work: Path) -> list[list[str]]:
    """One small valid command line per subcommand (each finishes in about a second here)."""
    rec, ds, srs = str(seeds / "rec"), str(seeds / "dataset"), str(seeds / "stream.srs")
    out = str(work / "out")
    return [
        ["example", "--out", out, "--width", "32", "--height", "16"],
        ["render", "lab", "--out", out, "--seconds", "0.05", "--scale", "0.01", "--samples", "1",
         "--quiet"],
        ["render", "lab", "--out", out, "--seconds", "0.05", "--scale", "0.01", "--samples", "1",
         "--trace", str(seeds / "trace.txt"), "--quiet"],
        ["render", str(seeds / "scene.json"), "--out", out, "--seconds", "0.05", "--scale",
         "0.01", "--samples", "1", "--quiet"],
        ["encode", rec, "--out", str(work / "out.srs"), "--bitrate", "0.5", "--quiet"],
        ["play", rec, "--out", out, "--seconds", "0.21", "--no-vmaf", "--quiet"],
        ["play", srs, "--recording", rec, "--out", out, "--no-vmaf", "--quiet"],
        ["demo", "--scene", "lab", "--out", out, "--scale", "0.01", "--seconds", "0.21",
         "--no-vmaf", "--quiet"],
        ["bench", "--scene", "lab", "--scale", "0.02", "--frames", "2", "--quiet"],
        ["eval", "--out", out, "--dataset", str(seeds / "dataset-eval"), "--no-vmaf", "--quiet"],
        ["dataset", "export", rec, "--out", out, "--quiet"],
        ["dataset", "import", ds, "--out", out, "--quiet"],
        ["serve", "--port", "0", "--scene", "lab", "--scale", "0.02", "--sessions", "1"],
        ["connect", "127.0.0.1:9", "--insecure", "--seconds", "0.1", "--out", out, "--quiet"],
        ["relay", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", "--seconds", "0.3",
         "--quiet"],
    ]


#: Garbage values of command-line arguments. System paths (/dev/zero, /dev/null) are given as
#: links in the case's folder: the harness runs as whatever user it is given, root included,
#: and a writer renaming its result over such a path must replace the link, never the device.
_CLI_VALUES = (
    "", "0", "-1", "nan", "inf", "-inf", "1e300", "1e-300", "1e-9", "9" * 400, "0x10", "x", "--",
    "-", "1,2", ",", "1:2", "ours,ours", "DEV/zero", "DEV/null", ".", "..", "\x01",
    "a" * 5000, "65536", "4294967296", "-0", "1e309", "none",
)


def mutate_argv(argv: list[str], rng: random.Random, seeds: Path, work: Path) -> tuple[list[str], str]:
    """One mutation of a command line: a value replaced by a boundary or garbage value or by a
    path of the wrong kind, an option dropped, duplicated or unknown, arguments swapped."""
    out = list(argv)
    positions = list(range(1, len(out)))
    values = [i for i in positions if not out[i].startswith("--")]
    op = rng.choice(("value", "value", "value", "path", "drop", "dup", "unknown", "swap"))
    if op in ("value", "path") and values:
        i = rng.choice(values)
        if op == "path":
            fifo = work / "fifo"
            if not fifo.exists():
                os.mkfifo(fifo)
            v = rng.choice((str(fifo), str(seeds / "trace.txt"), str(seeds / "rec"),
                            str(seeds / "rec" / "manifest.json"), str(seeds / "stream.srs"),
                            str(seeds / "dataset"), str(work / "missing"), str(seeds / "quad.glb"),
                            str(seeds / "rec" / "server")))
        else:
            v = rng.choice(_CLI_VALUES)
            if v.startswith("DEV/"):
                link = work / f"dev-{v[4:]}"
                if not link.is_symlink():
                    link.symlink_to(f"/dev/{v[4:]}")
                v = str(link)
        old = out[i]
        out[i] = v
        return out, f"argument {i} {old[-30:]!r} -> {v[:40]!r}"
    if op == "drop" and len(out) > 1:
        i = rng.choice(positions)
        n = 2 if out[i].startswith("--") and i + 1 < len(out) and not out[i + 1].startswith("--") \
            and rng.random() < 0.5 else 1
        del out[i : i + n]
        return out, f"{n} argument(s) at {i} dropped"
    if op == "dup" and positions:
        i = rng.choice(positions)
        out[i:i] = out[i : i + 2]
        return out, f"arguments at {i} repeated"
    if op == "swap" and len(positions) >= 2:
        i, j = rng.sample(positions, 2)
        out[i], out[j] = out[j], out[i]
        return out, f"arguments {i} and {j} swapped"
    out.insert(rng.randrange(1, len(out) + 1), rng.choice(("--bogus", "-x", "--out", "--help=1")))
    return out, "an unknown or repeated option inserted"


def _cli_case(rng: random.Random, seeds: Path, work: Path) -> tuple[str, Callable[[], None], dict[str, Any]]:
    # The command lines read and write copies: a mutation such as `render --out SEEDS/rec
    # --force` must not replace the seeds of the cases that follow.
    shared = seeds
    seeds = work / "seeds"
    shutil.copytree(shared, seeds, ignore=shutil.ignore_patterns("rec-small", "rec-eval"),
                    symlinks=True)
    base = rng.choice(cli_seeds(seeds, work))
    argv, what = mutate_argv(base, rng, seeds, work)
    shown = " ".join(a if len(a) < 40 else a[:37] + "..." for a in argv)
    text = f"{what}: splitrender {shown}".replace(str(seeds), "SEEDS").replace(str(work), "CASE")
    text = text.replace(str(shared), "SEEDS")
    return text, cli_run(argv, work), {
        "cli": True, "serve": runs_until_stopped(argv), "long": runs_long_by_design(argv)
    }


#: The most ``relay --seconds`` a ``cli`` case waits for the relay to end by itself (its time
#: limit is 40 s, the relay's own limit a day).
RELAY_BOUNDED_S = 20.0


def runs_until_stopped(argv: list[str]) -> bool:
    """Whether the command line runs until interrupted by design: ``serve``, and a ``relay``
    without ``--seconds`` (a mutation may drop it) or with more than :data:`RELAY_BOUNDED_S`
    of it (the last one given, as argparse takes it). Such a run is accepted once it says it
    serves; a ``relay`` that ends by itself is left to end, and its exit status judged."""
    if argv[:1] == ["serve"]:
        return True
    if argv[:1] != ["relay"]:
        return False
    given = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--seconds"]
    if "--seconds" not in argv:
        return True
    try:
        return bool(given) and float(given[-1]) > RELAY_BOUNDED_S
    except ValueError:
        return False  # refused by the command line's own check


#: The options that keep each subcommand's seed (:func:`cli_seeds`) small: without one of them
#: its default applies, and with a larger value than the seed's it asks for more, either of
#: which can make minutes of work (``eval`` without ``--dataset`` evaluates the built-in
#: scenes: seed 7202, case cli:64; ``bench --frames 65536``: seed 7205, case cli:120).
BOUNDED_BY: dict[str, tuple[str, ...]] = {
    "render": ("--seconds", "--scale", "--samples"),
    "demo": ("--scale", "--seconds"),
    "bench": ("--scale", "--frames"),
    "eval": ("--dataset",),
}


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


@functools.cache
def _seed_bounds() -> dict[str, dict[str, float | None]]:
    """Each :data:`BOUNDED_BY` option's value in its subcommand's seeds (``None``: not a
    number, such as ``--dataset``'s folder), read from :func:`cli_seeds` itself, once: the seeds
    do not change, and every ``cli`` case asks (the callers only read the result)."""
    out: dict[str, dict[str, float | None]] = {}
    for argv in cli_seeds(Path("SEEDS"), Path("CASE")):
        for opt in BOUNDED_BY.get(argv[0], ()):
            out.setdefault(argv[0], {})[opt] = _number(argv[argv.index(opt) + 1])
    return out


def runs_long_by_design(argv: list[str]) -> bool:
    """Whether the command line lacks one of the options that bound its subcommand's work
    (:data:`BOUNDED_BY`) or gives one a larger number than its seeds do (the last value
    given, as argparse takes it), so that a run past the case's time limit is what it asked
    for: such a run is stopped at the limit and accepted if it has not failed by then."""
    bounds = _seed_bounds().get(argv[0], {}) if argv else {}
    for opt, seed in bounds.items():
        if opt not in argv:
            return True
        given = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == opt]
        value = _number(given[-1]) if given else None
        if seed is not None and value is not None and value > seed:
            return True
    return False


def cli_run(argv: list[str], work: Path) -> Callable[[], None]:
    """The ``cli`` kind's run: ``splitrender ARGV`` in the folder ``work``; raises SystemExit
    with its exit status (:func:`classify_cli` reads the rest from its output)."""

    def run() -> None:
        from splitrender.cli import main

        os.chdir(work)  # relative outputs of a mutated command line land in the case's folder
        raise SystemExit(main(argv))

    return run


def classify_cli(verdict: Verdict, output: str) -> Verdict:
    """The CLI's outcome from the child's exit status (carried in the verdict's detail) and
    output: 2 with exactly one error line is specific, 0 is accepted."""
    if not verdict.detail.startswith("exit ") or verdict.outcome != Outcome.ACCEPTED:
        return verdict
    status = verdict.detail.split()[1]
    errs = CLI_ERROR.findall(output)
    lines = [ln for ln in output.splitlines() if CLI_ERROR.match(ln)]
    if "Traceback" in output:
        return Verdict(Outcome.GENERIC, f"exit {status} with a traceback: {output.strip().splitlines()[-1][:200]}")
    if status == "0":
        return Verdict(Outcome.ACCEPTED, "exit 0")
    if status == "2" and len(errs) == 1:
        return Verdict(Outcome.SPECIFIC, lines[0][:300])
    if status == "2" and "usage:" in output:  # argparse's own --help=1 and friends
        return Verdict(Outcome.GENERIC, f"exit 2 with a usage dump: {output.strip()[:200]}")
    first = lines[0][:250] if lines else output.strip()[:250]
    return Verdict(Outcome.GENERIC, f"exit {status} with {len(errs)} error lines: {first}")


KINDS: dict[str, Kind] = {
    k.name: k
    for k in (
        Kind("packet", _packet_case, weight=3.0),
        Kind("stream-file", _stream_case, weight=2.0),
        Kind("stream-writer", _stream_writer_case, weight=0.7),
        Kind("recording", _recording_case, weight=2.0),
        Kind("recording-writer", _recording_writer_case, weight=0.3, time_limit=40.0),
        Kind("dataset", _dataset_case, weight=1.5),
        Kind("dataset-writer", _dataset_writer_case, weight=0.5, time_limit=40.0),
        Kind("trace", _trace_case, weight=1.5),
        Kind("scene-description", _description_case, weight=1.0),
        Kind("gltf", _gltf_case, weight=1.5),
        Kind("glb", _glb_case, weight=1.0),
        Kind("cli", _cli_case, weight=1.0, time_limit=40.0),
    )
}
