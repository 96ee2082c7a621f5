"""The command line's user errors (issue 15): each class of mistake, one case per class, exits with
status 2 and exactly one ``splitrender[ COMMAND]: error: ...`` line naming what was wrong and
what was expected, whether argparse refuses it at parse time or a command refuses it later; a
failure that is not the caller's exits 1 and says it is a bug. Also: ``play REC --recording
OTHER`` is refused, and ``demo --video-fps`` writes a video at the requested rate."""

from __future__ import annotations

import errno
import os
import re
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import splitrender as sr
from splitrender.cli import main
from splitrender.errors import InvalidInputError, SplitRenderError, is_user_error

av = pytest.importorskip("av")

#: courtyard at 77x43 for 0.25 s: 4 server frames, 30 client frames.
SCALE, SECONDS = 0.03, 0.25
ERROR_LINE = re.compile(r"^splitrender(?: [\w-]+)*: error: \S.*$")


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A recording, its stream file, and inputs of every wrong kind."""
    d = tmp_path_factory.mktemp("cli-errors")
    rec = sr.write_recording(d / "rec", "courtyard", seconds=SECONDS, scale=SCALE)
    stream = d / "rec.srs"
    with sr.StreamEncoder(sr.CodecConfig.scaled(77, 43)) as enc:
        sr.write_stream(stream, [enc.encode(f) for f in sr.load_recording(rec).server_frames])
    other = sr.write_recording(d / "other", "courtyard", variant="static", seconds=SECONDS,
                               scale=SCALE)
    (d / "garbage").write_bytes(bytes(range(256)) * 8)
    (d / "dir").mkdir()
    os.mkfifo(d / "fifo")
    (d / "bad.json").write_text('{"scene": ')
    (d / "models.json").write_text('{"scene": "courtyard", "models": 5}')
    bad_rec = d / "bad-rec"
    bad_rec.mkdir()
    (bad_rec / "manifest.json").write_text("{")
    return {"rec": rec, "stream": stream, "other": other, "garbage": d / "garbage",
            "dir": d / "dir", "fifo": d / "fifo", "bad_json": d / "bad.json",
            "models_json": d / "models.json", "bad_rec": bad_rec, "tmp": d}


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``main(argv)``'s exit status (argparse exits through SystemExit) and its stderr."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    return code, capsys.readouterr().err


#: (class of mistake, argv with {name} placeholders for ``files``, words the line must hold).
CASES: list[tuple[str, list[str], tuple[str, ...]]] = [
    ("not a number", ["encode", "{rec}", "--out", "{tmp}/a.srs", "--bitrate", "x"],
     ("--bitrate", "expected a number", "'x'")),
    ("NaN", ["render", "courtyard", "--out", "{tmp}/r", "--seconds", "nan"],
     ("--seconds", "expected a finite number")),
    ("infinity", ["render", "courtyard", "--out", "{tmp}/r", "--trace-scale", "inf"],
     ("--trace-scale", "expected a finite number")),
    ("zero", ["play", "{rec}", "--out", "{tmp}/p", "--seconds", "0"],
     ("--seconds", ">= 0.01")),
    ("negative", ["demo", "--out", "{tmp}/d", "--latency", "-1"], ("--latency", "0..60000")),
    ("zero stride", ["eval", "--out", "{tmp}/e", "--flip-every", "0"],
     ("--flip-every", "a frame stride in 1..1000", "got 0")),
    ("tiny", ["demo", "--out", "{tmp}/d", "--video-fps", "1e-9"],
     ("--video-fps", ">= 1", "1e-9")),
    ("huge", ["demo", "--out", "{tmp}/d", "--scale", "1e300"], ("--scale", "<= 6.4")),
    ("zero rate", ["bench", "--realtime", "--fps", "0"], ("--fps", ">= 0.001", "got 0")),
    ("no refreshes to score", ["bench", "--realtime", "--score", "0"],
     ("--score", "1..100000", "got 0")),
    ("zero threads", ["bench", "--realtime", "--prepare-threads", "0"],
     ("--prepare-threads", "a thread count in 1..256", "got 0")),
    ("huge integer", ["example", "--width", "1" + "0" * 400], ("--width", "1..16384")),
    ("missing input", ["encode", "{tmp}/missing", "--out", "{tmp}/a.srs"], ("missing",)),
    ("malformed recording", ["encode", "{bad_rec}", "--out", "{tmp}/a.srs"],
     ("manifest.json",)),
    ("stream where a recording is expected", ["encode", "{stream}", "--out", "{tmp}/a.srs"],
     ("rec.srs",)),
    ("garbage where a stream is expected",
     ["play", "{garbage}", "--recording", "{rec}", "--out", "{tmp}/p", "--no-vmaf"],
     ("garbage",)),
    ("a recording with --recording", ["play", "{rec}", "--recording", "{other}", "--out",
                                      "{tmp}/p", "--no-vmaf"],
     ("--recording", "only with a stream file")),
    ("FIFO as a file", ["render", "courtyard", "--out", "{tmp}/r", "--trace", "{fifo}"],
     ("fifo", "regular file")),
    ("directory as a file", ["bench", "--realtime", "--stream", "{dir}", "--scale", "0.03"],
     ("dir", "expected a stream file")),
    ("malformed JSON", ["render", "{bad_json}", "--out", "{tmp}/r"], ("bad.json",)),
    ("JSON of the wrong shape", ["render", "{models_json}", "--out", "{tmp}/r"],
     ("models", "expected an array")),
    ("output under a file", ["encode", "{rec}", "--out", "{garbage}/a.srs"],
     ("--out", "not a directory")),
    # mkdir's "File exists" named no folder that was expected.
    ("directory output that is a file", ["example", "--out", "{garbage}"],
     ("garbage: exists and is not a folder; expected a folder for the outputs",)),
    ("play into a file", ["play", "{rec}", "--out", "{garbage}", "--no-vmaf"],
     ("garbage: exists and is not a folder",)),
    ("demo into a file", ["demo", "--out", "{garbage}", "--scale", "0.03"],
     ("garbage: exists and is not a folder",)),
    # Path("") is the current directory, which was then read as the input.
    ("empty input path", ["encode", "", "--out", "{tmp}/a.srs"],
     ("REC", "expected a path, got ''")),
    ("empty source", ["play", "", "--out", "{tmp}/p"], ("SOURCE", "got ''")),
    ("empty trace", ["render", "courtyard", "--out", "{tmp}/r", "--trace", ""],
     ("--trace", "expected a path, got ''")),
    # Any file was called a stream file, and --recording asked for.
    ("not a stream file", ["play", "{garbage}", "--out", "{tmp}/p"],
     ("garbage", "expected a recording folder, a stream file or a built-in scene")),
    ("output inside the input", ["encode", "{rec}", "--out", "{rec}/manifest.json"],
     ("expected a path outside it",)),
    # Every scored frame would be black: refused before the render, not by a task after it.
    ("eval delay past the session", ["eval", "--out", "{tmp}/e", "--seconds", "0.25",
                                     "--delays", "0,40"],
     ("--delays", "40 client frames is past the last scored frame", "expected at most 17")),
    # eval wrote its results, its imported recording or its cache into the dataset it read.
    ("eval output inside the dataset", ["eval", "--dataset", "{dir}", "--out", "{dir}/e"],
     ("--out", "lies inside the dataset", "expected a path outside it")),
    ("eval cache inside the dataset", ["eval", "--dataset", "{dir}", "--out", "{tmp}/e",
                                       "--cache", "{dir}/cache"],
     ("--cache", "lies inside the dataset")),
    ("refused destination", ["render", "courtyard", "--out", "{rec}", "--scale", "0.03",
                             "--seconds", "0.1"],
     ("already exists",)),
    ("not a dataset", ["dataset", "import", "{rec}", "--out", "{tmp}/imported"], ("main",)),
    ("name escaping its folder", ["dataset", "export", "{rec}", "--out", "{tmp}/ds",
                                  "--aux-names", "../x,y"],
     ("../x",)),
    ("unknown name", ["demo", "--out", "{tmp}/d", "--scene", "nosuch"], ("nosuch",)),
    ("unknown choice", ["play", "{rec}", "--out", "{tmp}/p", "--method", "nosuch"],
     ("--method", "nosuch")),
    ("contradictory options", ["play", "{stream}", "--recording", "{rec}", "--bitrate", "1",
                               "--out", "{tmp}/p"],
     ("--bitrate",)),
    # An empty token let in a client that sends none (connect's default); a rate below what a
    # client accepts made every client refuse the welcome; a hello that cannot be encoded
    # ended in a traceback on the network thread, then an idle timeout read as a refusal.
    ("empty token", ["serve", "--token", "", "--port", "0"], ("--token", "non-empty")),
    ("server rate no client takes", ["serve", "--fps", "0.05", "--port", "0"],
     ("--fps", "at least 0.1")),
    ("token too long", ["connect", "127.0.0.1:9", "--insecure", "--out", "{tmp}/c", "--token",
                        "a" * 65],
     ("--token", "at most 64 bytes")),
    # Found after the whole session, which was lost.
    ("connect into a file", ["connect", "127.0.0.1:9", "--insecure", "--out", "{garbage}"],
     ("--out", "garbage: exists and is not a folder")),
    ("display rate below a hello's", ["connect", "127.0.0.1:9", "--insecure", "--out",
                                      "{tmp}/c", "--fps", "0.5"],
     ("--fps", "at least 1")),
    ("all lost", ["relay", "--loss", "1", "--seconds", "0.1"], ("--loss", "below 1")),
    # argparse reads a value starting with '-' as an option and said only "expected one
    # argument", though the option was given one.
    ("value starting with a dash", ["relay", "--bandwidth-at", "-1:0.5", "--seconds", "0.1"],
     ("--bandwidth-at", "is written --bandwidth-at=-1:0.5")),
    ("bandwidth step without a colon", ["relay", "--bandwidth-at=5", "--seconds", "0.1"],
     ("--bandwidth-at", "expected SECONDS:MBPS", "got '5'")),
    ("bandwidth step of a negative rate", ["relay", "--bandwidth-at=1:-5", "--seconds", "0.1"],
     ("--bandwidth-at", "expected SECONDS:MBPS", "got '1:-5'")),
    ("bandwidth step after the longest run", ["relay", "--bandwidth-at=1e9:5", "--seconds",
                                              "0.1"],
     ("--bandwidth-at", "expected SECONDS:MBPS", "got '1e9:5'")),
    # One datagram went round 186,000 times in 1.5 s.
    ("relay to itself", ["relay", "--listen", "127.0.0.1:47330", "--target", "localhost:47330",
                         "--seconds", "0.1"], ("listen and target", "forward to itself")),
    # A reserved name (RFC 2606), refused before any lookup: nothing is contacted.
    ("address not on loopback", ["relay", "--listen", "relay.invalid:0", "--seconds", "0.1"],
     ("relay.invalid",)),
]


@pytest.mark.parametrize("what, argv, words", CASES, ids=[c[0] for c in CASES])
def test_user_error_exits_2_with_one_line(
    files: dict[str, Path], capsys: pytest.CaptureFixture[str], what: str, argv: list[str],
    words: tuple[str, ...],
) -> None:
    args = [a.format(**{k: str(v) for k, v in files.items()}) for a in argv]
    if args[0] not in ("example", "serve"):
        args.append("--quiet")
    code, err = run(args, capsys)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and ERROR_LINE.match(lines[0]), (what, code, err)
    assert "Traceback" not in err and "internal error" not in err
    for w in words:
        assert w in lines[0], (what, w, lines[0])


def test_the_table_has_a_case_per_class() -> None:
    assert len(CASES) >= 18 and len({c[0] for c in CASES}) == len(CASES)


def test_play_of_a_recording_refuses_another_recording_and_writes_nothing(
    files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # The recording SOURCE has its own client poses and ground truth: --recording OTHER used to
    # be ignored silently (the play scored SOURCE's frames against SOURCE's ground truth).
    out = files["tmp"] / "play-other"
    code, err = run(["play", str(files["rec"]), "--recording", str(files["other"]), "--out",
                     str(out), "--no-vmaf", "--quiet"], capsys)
    assert code == 2 and err == (
        f"splitrender: error: --recording: only with a stream file SOURCE; {files['rec']} is a "
        "recording, which has its own client poses and ground truth\n"
    )
    assert not out.exists()


def test_internal_failure_exits_1_and_says_it_is_a_bug(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import splitrender.cli.example as example

    def broken(args: Any) -> int:
        raise KeyError("frame")

    monkeypatch.setattr(example, "run", broken)
    monkeypatch.delenv("SPLITRENDER_DEBUG", raising=False)
    code, err = run(["example", "--out", str(tmp_path / "e")], capsys)
    assert code == 1 and len(err.splitlines()) == 1, err
    assert err.startswith("splitrender: internal error: KeyError: 'frame'")
    assert "bug" in err and "SPLITRENDER_DEBUG=1" in err and "Traceback" not in err

    monkeypatch.setenv("SPLITRENDER_DEBUG", "1")
    code, err = run(["example", "--out", str(tmp_path / "e")], capsys)
    assert code == 1 and err.startswith("Traceback") and "in broken" in err
    assert err.splitlines()[-1].startswith("splitrender: internal error: KeyError")


def test_ctrl_c_while_the_parsers_are_built_is_an_interrupt_not_a_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # The parsers took a few tenths of a second to build outside main()'s handlers: Ctrl-C
    # then printed a KeyboardInterrupt traceback of 20-30 lines.
    import splitrender.cli.example as example

    def interrupted(sub: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(example, "add", interrupted)
    assert run(["example", "--out", "x"], capsys) == (130, "splitrender: interrupted\n")


@pytest.mark.parametrize("module", ["numpy", "splitrender._native", "splitrender.cli.args"])
@pytest.mark.parametrize("entry", ["script", "-m"])
def test_ctrl_c_while_the_command_imports_its_modules_is_an_interrupt(
    module: str, entry: str
) -> None:
    # The console script imports `splitrender.cli` before any of our code runs; that imported
    # the whole package (numpy, the native module, the codec: ~0.3 s), and Ctrl-C then printed
    # a traceback. A fresh interpreter whose import of `module` is interrupted, as the console
    # script (`from splitrender.cli import main`) and `python -m splitrender` start.
    import subprocess
    import sys

    start = ("from splitrender.cli import main\nsys.exit(main(['--version']))\n"
             if entry == "script" else "import runpy\nrunpy.run_module('splitrender', "
             "run_name='__main__', alter_sys=True)\n")
    code = (
        "import sys\n"
        "class Interrupt:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if name == {module!r}:\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupt())\n"
        "sys.argv = ['splitrender', '--version']\n"
    ) + start
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert (done.returncode, done.stderr, done.stdout) == (130, "splitrender: interrupted\n", "")


def test_sigterm_unwinds_as_an_interrupt_and_leaves_no_temporary_file(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # `timeout` and service managers send SIGTERM: an encode left its `.partial` file and a
    # render its folder (Ctrl-C cleaned both up).
    import signal
    import time

    import splitrender.cli.example as example
    from splitrender.codec.stream import StreamWriter

    before = signal.getsignal(signal.SIGTERM)
    slept: list[bool] = []

    def terminated_while_writing(args: Any) -> int:
        with StreamWriter(tmp_path / "x.srs"):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises in here
            slept.append(True)
        return 0

    monkeypatch.setattr(example, "run", terminated_while_writing)
    code, err = run(["example", "--out", str(tmp_path / "e")], capsys)
    assert (code, err) == (143, "splitrender: terminated\n")
    assert not slept  # the handler raised at once: the sleep never ended
    assert list(tmp_path.iterdir()) == []  # neither the stream nor its temporary file
    assert signal.getsignal(signal.SIGTERM) == before  # main() gave the handler back


def test_a_full_disk_exits_1_with_one_line_and_is_not_called_a_bug(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import splitrender.cli.example as example

    def full(args: Any) -> int:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "video.mp4"))

    monkeypatch.setattr(example, "run", full)
    code, err = run(["example", "--out", str(tmp_path / "e")], capsys)
    assert code == 1
    assert err == f"splitrender: error: {tmp_path / 'video.mp4'}: No space left on device\n"


def test_memory_running_out_in_python_exits_1_with_one_line_and_is_not_called_a_bug(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import numpy as np

    import splitrender.cli.example as example

    def hungry(args: Any) -> int:
        np.empty(1 << 62, dtype=np.uint8)  # numpy's own MemoryError, no allocation made
        return 0

    monkeypatch.setattr(example, "run", hungry)
    code, err = run(["example", "--out", str(tmp_path / "e")], capsys)
    assert code == 1 and len(err.splitlines()) == 1, err
    assert err.startswith("splitrender: error: out of memory (Unable to allocate 4.00 EiB")
    assert "bug" not in err and "Traceback" not in err


def test_a_reader_that_goes_away_ends_the_command_quietly() -> None:
    # `splitrender ... | head`: the pipe breaks when the command next writes. In a subprocess,
    # so that its stdout is a real pipe.
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import splitrender.cli.example as example\n"
        "def broken(args):\n"
        "    print('x' * 100000)\n"  # more than a pipe holds: blocks until the reader is gone
        "example.run = broken\n"
        "from splitrender.cli.dispatch import main\n"
        "sys.exit(main(['example']))\n"
    )
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.read(10)
        proc.stdout.close()
        err = proc.stderr.read().decode()
        assert proc.wait(timeout=60) == 141, err
    assert err == ""


@pytest.mark.parametrize(
    "error, user",
    [
        (InvalidInputError("x"), True),
        (sr.StreamError("x"), True),
        (sr.RecordingError("x"), True),
        (sr.DatasetError("x"), True),
        (sr.TraceError("x"), True),
        (SplitRenderError("internal error in reproject (please report)"), False),
        (FileNotFoundError(errno.ENOENT, "No such file or directory", "f"), True),
        (PermissionError(errno.EACCES, "Permission denied", "f"), True),
        (OSError(errno.ENOSPC, "No space left on device", "f"), False),
        (KeyError("x"), False),
        (ValueError("x"), False),
    ],
)
def test_whose_fault_follows_the_class(error: BaseException, user: bool) -> None:
    assert is_user_error(error) is user


def test_every_error_class_is_the_callers_but_the_base() -> None:
    """A new subclass of SplitRenderError is a user error (exit 2): list it here deliberately,
    or raise SplitRenderError itself for failures that are not the caller's."""
    import splitrender.evaluation.bench  # noqa: F401  (defines BenchArgumentError)
    import splitrender.evaluation.experiments  # noqa: F401  (EvalArgumentError)
    import splitrender.evaluation.sweep  # noqa: F401  (SweepError and its subclasses)
    import splitrender.net.protocol  # noqa: F401

    def subclasses(c: type) -> set[str]:
        return {s.__name__ for s in c.__subclasses__()} | {
            n for s in c.__subclasses__() for n in subclasses(s)
        }

    assert subclasses(SplitRenderError) == {
        "InvalidInputError", "StreamError", "GpuUnavailableError", "ProtocolError",
        # legal sizes whose memory the machine could not reserve (before anything is allocated).
        "OutOfMemoryError",
        "RecordingError", "DatasetError", "TraceError", "DemoArgumentError",
        "EvalArgumentError", "BenchArgumentError",
        # eval's sweep (issue 16): Ray missing, --address unreachable, a task that raised (its
        # one line names the task, its inputs and how to resume).
        "SweepError", "RayMissingError", "ClusterUnreachableError", "TaskFailedError",
        # a cache entry changed after it was written: the message names the entry to remove.
        "DamagedCacheError",
        # the one that is not: the GPU device was lost (exit 1, as SplitRenderError itself).
        "GpuDeviceLostError",
    }
    from splitrender.errors import GpuDeviceLostError, is_user_error

    assert not is_user_error(GpuDeviceLostError("the GPU device was lost (Destroyed)"))


@pytest.mark.parametrize("fps", [1.0, 12.5, 29.97, 120.0, 240.0])
def test_video_has_the_requested_rate(tmp_path: Path, fps: float) -> None:
    from splitrender.evaluation.demo import _Video

    path = tmp_path / "v.mp4"
    with _Video(path, 32, 16, fps) as video:
        for k in range(3):
            video.write(np.full((16, 32, 3), 80 * k, np.uint8))
    with av.open(str(path)) as c:
        rate = c.streams.video[0].average_rate
        assert c.streams.video[0].frames in (0, 3)
    assert rate == Fraction(fps).limit_denominator(1001)
    assert abs(float(rate) - fps) <= 1e-6 * fps


@pytest.mark.parametrize("fps", [0.0, -1.0, 1e-9, 1e300, float("nan"), float("inf")])
def test_video_refuses_a_rate_it_cannot_store(tmp_path: Path, fps: float) -> None:
    from splitrender.evaluation.demo import _Video

    with pytest.raises(InvalidInputError, match="frame rate"):
        _Video(tmp_path / "v.mp4", 32, 16, fps)
    assert list(tmp_path.iterdir()) == []


def test_demo_video_fps_is_the_rate_of_the_video(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--scale", "0.03", "--seconds", "0.25", "--methods", "timewarp",
                 "--no-vmaf", "--quiet", "--video-fps", "12.5", "--out", str(out)]) == 0
    with av.open(str(out / "video.mp4")) as c:
        stream = c.streams.video[0]
        assert stream.average_rate == Fraction(25, 2)
        assert sum(1 for _ in c.decode(stream)) == 30
