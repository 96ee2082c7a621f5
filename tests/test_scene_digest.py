"""Scene.digest is of the bytes the glTF loader read when the scene was built (docs/protocol.md,
"Scene digest"): the native loader hashes each file it reads, once; Python reads no file."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from conftest import quad_blob, quad_document
from splitrender.scene import Scene

#: The digest of :func:`_describe`'s description, as the Python re-reading code (before the
#: loader hashed the files) computed it: the text hashed is unchanged.
GOLDEN = "f71d8a36a0bcac3d1beeaf94548c0f899172df0fcdb24e62a769832ebfc4ba77"


def _describe(folder: Path, blob: bytes) -> Path:
    """A description placing a quad whose buffer is an external (percent-encoded) ``.bin``."""
    folder.mkdir()
    doc = quad_document(blob)
    doc["buffers"][0]["uri"] = "quad%20data.bin"
    (folder / "quad.gltf").write_text(json.dumps(doc))
    (folder / "quad data.bin").write_bytes(blob)
    (folder / "scene.json").write_text(json.dumps({"scene": "courtyard", "variant": "dynamic",
        "models": [{"path": "quad.gltf", "position": [0, 0, -3]}]}))
    return folder / "scene.json"


def test_the_digest_is_of_the_bytes_loaded_not_of_the_files_now(tmp_path: Path) -> None:
    blob = quad_blob()
    scene = Scene.from_description(_describe(tmp_path / "a", blob))
    first = scene.digest()
    assert first.hex() == GOLDEN
    # The .bin changed after the scene was built: what it renders, and its digest, are not.
    other = bytearray(blob)
    other[0] ^= 1
    (tmp_path / "a" / "quad data.bin").write_bytes(bytes(other))
    assert scene.digest() == first
    # Nor does a file gone since: the digest reads no file.
    (tmp_path / "a" / "quad.gltf").unlink()
    assert scene.digest() == first
    # A scene built from the other .bin is another scene.
    assert Scene.from_description(_describe(tmp_path / "b", bytes(other))).digest() != first


def test_the_native_scene_records_the_sha256_of_each_file_read(tmp_path: Path) -> None:
    scene = Scene.from_description(_describe(tmp_path / "a", quad_blob()))
    folder = tmp_path / "a"
    sha = [hashlib.sha256((folder / n).read_bytes()).hexdigest()
           for n in ("quad.gltf", "quad data.bin")]
    assert scene._native.model_files == [(sha[0], [sha[1]])]
    assert Scene("courtyard")._native.model_files == []
