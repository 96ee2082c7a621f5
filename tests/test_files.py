"""splitrender.files: write_atomic (a failed write leaves the previous file intact, nothing
else); read_regular and read_json (only regular files, size-capped reads, parse failures as the
caller's exception); names and outputs cannot escape their folder or overwrite an input."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from splitrender.codec.stream import StreamFile
from splitrender.errors import InvalidInputError, StreamError
from splitrender.files import (
    OutputFolder,
    check_apart,
    check_output_file,
    check_name,
    joined,
    read_json,
    read_json_object,
    read_regular,
    rename_new_folder,
    temporary_beside,
    write_atomic,
)
from splitrender.scene.builtin import TraceError, load_trace


def test_write_atomic_replaces_the_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    write_atomic(path, "first\n")
    write_atomic(path, b"second\n")
    assert path.read_bytes() == b"second\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_a_write_into_a_missing_folder_names_the_path_given(tmp_path: Path) -> None:
    # The error named the hidden temporary file (".x.srs.partial-<pid>-<n>"), never given.
    from splitrender.codec.stream import write_stream

    for write in (lambda p: write_atomic(p, b"x"), lambda p: write_stream(p, [])):
        dest = tmp_path / "nope" / "x.srs"
        with pytest.raises(FileNotFoundError, match="its folder .* does not exist") as e:
            write(dest)
        assert e.value.filename == str(dest)
        (tmp_path / "file").write_bytes(b"")
        with pytest.raises(NotADirectoryError, match="is not a folder") as e:
            write(tmp_path / "file" / "x.srs")
        assert e.value.filename == str(tmp_path / "file" / "x.srs")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


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


@contextmanager
def _deadline(seconds: int) -> Iterator[None]:
    """Fails the test instead of hanging it (a blocking read of a FIFO is the bug tested)."""

    def expired(signum: int, frame: object) -> None:
        raise AssertionError(f"still blocked after {seconds} s")

    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def test_writers_refuse_to_replace_a_fifo_or_device(tmp_path: Path) -> None:
    """The final rename would replace the node itself (as root, an output of /dev/zero once
    replaced the device); a link is replaced as a link and stays allowed."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(InvalidInputError, match="FIFO"):
        write_atomic(fifo, b"x")
    with pytest.raises(InvalidInputError, match="FIFO"):
        temporary_beside(fifo)
    assert fifo.is_fifo() and [p.name for p in tmp_path.iterdir()] == ["pipe"]
    link = tmp_path / "link"
    link.symlink_to("/dev/null")
    write_atomic(link, b"y")
    assert not link.is_symlink() and link.read_bytes() == b"y"
    assert Path("/dev/null").is_char_device()


def test_check_output_file_refuses_what_a_file_cannot_be_renamed_over(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "dir").mkdir()
    with pytest.raises(InvalidInputError, match="dir is a directory; expected a file name"):
        check_output_file(tmp_path / "dir")
    with pytest.raises(InvalidInputError, match="FIFO"):
        check_output_file(tmp_path / "pipe")
    (tmp_path / "file").write_bytes(b"x")
    (tmp_path / "link").symlink_to("/dev/null")
    for ok in ("file", "link", "new"):
        check_output_file(tmp_path / ok)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "file", "link", "pipe"]


def test_read_regular_refuses_a_fifo_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "trace.txt"
    os.mkfifo(fifo)
    with _deadline(5), pytest.raises(InvalidInputError, match="FIFO.*expected a regular file"):
        read_regular(fifo, 1000, "trace", InvalidInputError)


def test_load_trace_of_a_fifo_or_dev_zero_is_a_trace_error(tmp_path: Path) -> None:
    # The FIFO blocked load_trace forever; /dev/zero (st_size 0) was read until memory ran out.
    fifo = tmp_path / "fifo.txt"
    os.mkfifo(fifo)
    with _deadline(5), pytest.raises(TraceError, match="fifo.txt: trace file is a FIFO"):
        load_trace(fifo)
    zero = tmp_path / "zero.txt"
    zero.symlink_to("/dev/zero")
    with _deadline(5), pytest.raises(TraceError, match="zero.txt: trace file is a character"):
        load_trace(zero)


def test_stream_file_of_a_fifo_is_a_stream_error(tmp_path: Path) -> None:
    # open() of the FIFO blocked until a writer came.
    fifo = tmp_path / "s.srs"
    os.mkfifo(fifo)
    with _deadline(5), pytest.raises(StreamError, match="s.srs: stream file is a FIFO"):
        StreamFile(fifo)


def test_read_regular_refuses_devices_directories_and_links_to_them(tmp_path: Path) -> None:
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    with pytest.raises(InvalidInputError, match="zero.json: trace is a character device"):
        read_regular(link, 1000, "trace", InvalidInputError)
    with pytest.raises(InvalidInputError, match="a directory"):
        read_regular(tmp_path, 1000, "trace", InvalidInputError)


def test_read_regular_caps_the_read_at_the_limit(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    path.write_bytes(b"x" * 11)
    assert read_regular(path, 11, "trace", InvalidInputError) == b"x" * 11
    with pytest.raises(InvalidInputError, match="more than 10 bytes"):
        read_regular(path, 10, "trace", InvalidInputError)
    with pytest.raises(FileNotFoundError):
        read_regular(tmp_path / "missing", 10, "trace", InvalidInputError)


def test_read_regular_asks_for_no_more_than_the_file_holds(tmp_path: Path) -> None:
    # A read allocates what it asks for: every manifest or cam.json of a few hundred bytes,
    # read under its 64 MiB limit, held 64 MiB while it was read.
    import tracemalloc

    small = tmp_path / "manifest.json"
    small.write_bytes(b"{}" * 500)
    tracemalloc.start()
    try:
        assert read_regular(small, 64 << 20, "manifest", InvalidInputError) == b"{}" * 500
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, peak


def test_read_regular_reads_a_file_that_grew_since_its_size_was_taken(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The first read asks for one byte past st_size; a file longer by then is read on, up to
    # the limit (here st_size is made to say 10 for a file of 1000 bytes).
    import splitrender.files as files

    path = tmp_path / "grown.json"
    path.write_bytes(b"x" * 1000)
    real = os.fstat
    monkeypatch.setattr(files.os, "fstat", lambda fd: os.stat_result(
        tuple(real(fd))[:6] + (10,) + tuple(real(fd))[7:10]))
    assert read_regular(path, 1000, "manifest", InvalidInputError) == b"x" * 1000
    with pytest.raises(InvalidInputError, match="more than 999 bytes"):
        read_regular(path, 999, "manifest", InvalidInputError)


def test_read_regular_reads_at_most_one_byte_past_the_limit(tmp_path: Path) -> None:
    # The test above passed with f.read() of the whole file: a 64 MiB file (sparse: nothing on
    # disk) refused with a limit of 10 bytes must not be read into memory first.
    import tracemalloc

    big = tmp_path / "big.json"
    with big.open("wb") as f:
        f.truncate(64 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(InvalidInputError, match="more than 10 bytes"):
            read_regular(big, 10, "manifest", InvalidInputError)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f"{peak} bytes allocated to refuse a file over 10 bytes"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"fs": 1' + "0" * 400 + "}", "integer of 401 digits, expected at most 308"),
        ('{"fs": 1' + "0" * 5000 + "}", "integer of 5001 digits"),
        ("{ not json", "not valid JSON"),
    ],
)
def test_read_json_reports_every_parse_failure_as_the_callers_error(
    tmp_path: Path, text: str, problem: str
) -> None:
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match=problem):
        read_json(path, 1 << 20, "manifest", InvalidInputError)


def test_read_json_refuses_bytes_that_are_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_bytes(b'{"a": "' + bytes([0xFF]) + b'"}')
    with pytest.raises(InvalidInputError, match="not UTF-8"):
        read_json(path, 1 << 20, "manifest", InvalidInputError)


def test_read_json_keeps_ordinary_numbers(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_text('{"a": -12, "b": 1' + "0" * 307 + ', "c": 0.5}')
    assert read_json(path, 1 << 20, "manifest", InvalidInputError) == {
        "a": -12, "b": 10**307, "c": 0.5
    }


@pytest.mark.parametrize("text", ["[]", "3", "null", '"x"', "[{}]"])
def test_read_json_object_refuses_any_other_json_value(tmp_path: Path, text: str) -> None:
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match=f"^{path}: expected a JSON object$"):
        read_json_object(path, 1 << 20, "manifest", InvalidInputError)
    path.write_text('{"a": [1]}')
    assert read_json_object(path, 1 << 20, "manifest", InvalidInputError) == {"a": [1]}
    with pytest.raises(InvalidInputError, match="nothing here"):
        read_json_object(tmp_path / "no.json", 99, "manifest", InvalidInputError,
                         missing="nothing here")


def test_rename_new_folder_lets_a_failure_with_nothing_at_the_output_through(
    tmp_path: Path,
) -> None:
    # Only something at the output is "another run": a rename that fails with the output still
    # missing (here: the finished folder is gone) keeps its own error.
    out = tmp_path / "out"
    with pytest.raises(FileNotFoundError):
        rename_new_folder(tmp_path / "gone", out, InvalidInputError)
    assert not out.exists()
    (tmp_path / "done").mkdir()
    (out / "theirs").mkdir(parents=True)
    with pytest.raises(InvalidInputError, match="appeared while this one was written"):
        rename_new_folder(tmp_path / "done", out, InvalidInputError)
    assert (out / "theirs").is_dir() and (tmp_path / "done").is_dir()


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


def _tree(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): p.read_text() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _run(out: Path, frames: list[str], summary: str | None, fail: bool = False) -> None:
    """A command writing ``frames`` and then ``summary`` through an OutputFolder."""
    with OutputFolder(out, ("frames", "video.mp4", "summary.json")) as stage:
        (stage / "frames").mkdir()
        for name in frames:
            (stage / "frames" / name).write_text(f"new {name}")
        if fail:
            raise KeyboardInterrupt
        if summary is not None:
            (stage / "summary.json").write_text(summary)


def test_output_folder_replaces_the_outputs_together(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "video.mp4").write_text("old video")  # of an earlier run: not made by this one
    (out / "frames").mkdir()
    (out / "frames" / "0009.png").write_text("old 9")
    _run(out, ["0000.png", "0001.png"], "run 2")
    # Every owned name is this run's (the old video and frame 9 gone), the rest left alone,
    # and no staging folder remains.
    assert _tree(out) == {"frames/0000.png": "new 0000.png", "frames/0001.png": "new 0001.png",
                          "notes.txt": "mine", "summary.json": "run 2"}
    assert sorted(p.name for p in out.iterdir()) == ["frames", "notes.txt", "summary.json"]


def test_output_folder_moves_the_summary_in_last_and_the_old_outputs_out_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Until the summary is in place the folder must not claim a complete run, so it is moved in
    # after every other output; no test looked at the order (the summary first passed).
    out = tmp_path / "out"
    _run(out, ["0000.png"], "run 1")
    rename, moves = os.rename, []

    def spy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        moves.append((Path(src).parent == out, Path(dst).parent == out, Path(src).name))
        rename(src, dst)

    monkeypatch.setattr(os, "rename", spy)
    with OutputFolder(out, ("frames", "video.mp4", "summary.json")) as stage:
        (stage / "summary.json").write_text("run 2")
        (stage / "video.mp4").write_text("new video")
        (stage / "frames").mkdir()
    aside = [name for from_out, _, name in moves if from_out]
    placed = [name for from_out, to_out, name in moves if to_out and not from_out]
    assert sorted(aside) == ["frames", "summary.json"] and moves[:2] == [
        (True, False, n) for n in aside]
    assert placed == ["frames", "video.mp4", "summary.json"]
    assert _tree(out) == {"summary.json": "run 2", "video.mp4": "new video"}


def test_an_interrupted_output_folder_keeps_the_previous_outputs(tmp_path: Path) -> None:
    # A failed play wrote its frames into OUT as it went, beside the old play.json.
    out = tmp_path / "out"
    _run(out, ["0000.png", "0001.png"], "run 1")
    before = _tree(out)
    with pytest.raises(KeyboardInterrupt):
        _run(out, ["0000.png"], "run 2", fail=True)
    assert _tree(out) == before
    assert sorted(p.name for p in out.iterdir()) == ["frames", "summary.json"]
    # A folder made for the run that failed is removed again.
    fresh = tmp_path / "fresh"
    with pytest.raises(KeyboardInterrupt):
        _run(fresh, ["0000.png"], None, fail=True)
    assert not fresh.exists()


def test_output_folder_puts_the_old_outputs_back_when_a_move_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    _run(out, ["0000.png"], "run 1")
    before = _tree(out)
    rename = os.rename

    def fail_on_summary(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        # The new summary's move fails (the old one's move back is let through).
        if Path(dst) == out / "summary.json" and Path(src).read_text() == "run 2":
            raise OSError(5, "Input/output error")
        rename(src, dst)

    monkeypatch.setattr(os, "rename", fail_on_summary)
    with pytest.raises(OSError, match="Input/output error"):
        _run(out, ["0000.png", "0001.png"], "run 2")
    assert _tree(out) == before
    assert sorted(p.name for p in out.iterdir()) == ["frames", "summary.json"]


def test_output_folder_refuses_a_file_as_the_folder(tmp_path: Path) -> None:
    # mkdir said only "[Errno 17] File exists".
    file = tmp_path / "out"
    file.write_text("a file")
    with pytest.raises(InvalidInputError, match="exists and is not a folder; expected a folder"):
        _run(file, [], "x")
    assert file.read_text() == "a file"


def test_output_folder_check_finds_a_folder_it_cannot_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # check() only looked for "exists and is not a folder": `connect --out /proc/self` (or a
    # read-only folder) ran its whole session, then failed making ".partial-...".
    if Path("/proc/self").is_dir():  # a folder that takes no entry, whoever runs this
        with pytest.raises(InvalidInputError, match=r"^/proc/self: cannot write the outputs "
                           "there: No such file or directory; expected a folder"):
            OutputFolder("/proc/self", ("a",)).check()
        with pytest.raises(InvalidInputError, match=r"^/proc/self/new/out: cannot write the "
                           r"outputs there \(in /proc/self, to create it\): No such file"):
            OutputFolder("/proc/self/new/out", ("a",)).check()
    # A folder that can be written, existing or to be made: the check leaves nothing behind.
    (tmp_path / "there").mkdir()
    OutputFolder(tmp_path / "there", ("a",)).check()
    OutputFolder(tmp_path / "new" / "out", ("a",)).check()
    assert [p.name for p in tmp_path.iterdir()] == ["there"]
    assert not any((tmp_path / "there").iterdir())
    # A read-only one (simulated: root writes into any folder), named with the system's words.
    import tempfile

    def read_only(*args: object, **kwargs: object) -> str:
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    with pytest.raises(InvalidInputError, match=f"^{tmp_path / 'there'}: cannot write the "
                       "outputs there: Read-only file system"):
        OutputFolder(tmp_path / "there", ("a",)).check()
