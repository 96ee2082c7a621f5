"""splitrender.files: a failed write leaves the previous file intact, nothing else; names and
outputs cannot escape their folder or overwrite an input."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from splitrender.errors import InvalidInputError
from splitrender.files import check_apart, check_name, joined, write_atomic


def test_write_atomic_replaces_the_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    write_atomic(path, "first\n")
    write_atomic(path, b"second\n")
    assert path.read_bytes() == b"second\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_a_failed_write_keeps_the_previous_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "results.json"
    write_atomic(path, "good\n")

    def full_disk(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_atomic(path, "half of a new file")
    assert path.read_text() == "good\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


@pytest.mark.parametrize("name", ["", ".", "..", "../x", "a/b", "a\\b", "/abs", "x\0", None, 3])
def test_check_name_refuses_anything_but_a_plain_name(name: object) -> None:
    with pytest.raises(InvalidInputError, match=r"--aux: expected a plain name .* got"):
        check_name(name, "--aux")


def test_joined_stays_inside_the_folder(tmp_path: Path) -> None:
    assert joined(tmp_path, "left", "aux") == tmp_path / "left"
    (tmp_path / "link").symlink_to(tmp_path.parent)  # a link already there leads out
    with pytest.raises(ValueError, match="link leads outside"):
        joined(tmp_path, "link", "aux", ValueError)


def test_check_apart(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    rec.mkdir()
    check_apart(tmp_path / "s.srs", {"recording": rec})
    check_apart(tmp_path / "rec2", {"recording": rec})  # a common prefix is not inside
    check_apart(tmp_path, {"recording": rec})  # beside the input: only a replaced one holds it
    for out, problem in [
        (rec / "manifest.json", "lies inside the recording"),
        (rec / ".." / "rec", "is the recording"),
        (tmp_path, "holds the recording"),
    ]:
        with pytest.raises(InvalidInputError, match=f"the output {problem} {rec}; expected"):
            check_apart(out, {"recording": rec}, replaced=True)
