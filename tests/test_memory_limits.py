"""Legal sizes too large for the machine: ``OutOfMemoryError`` before anything is allocated, never
an abort.

An allocation that fails inside Rust aborts the process with a backtrace on stderr; the
bindings reserve each call's bound first (``crates/reproj-py/src/memory.rs``). Each test runs a
child process under an address-space limit (``RLIMIT_AS``) that the call's bound exceeds,
checks the error, its message and a clean stderr, and that a small call still runs under the
same limit (the limit refuses the size, not everything). Before the reservation, the first
test's call ended in ``memory allocation of 2304000 bytes failed`` and status 134.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

#: The child's address space: a few times what the interpreter, numpy and the extension map
#: with two rayon threads (about 0.45 GB measured), far below any call refused here.
LIMIT = 2 << 30

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="RLIMIT_AS limits the address space on Linux"
)


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    # Two threads and two malloc arenas: each thread's arena reserves address space, so the
    # child's own use must not depend on the machine's core count.
    env = dict(os.environ, RAYON_NUM_THREADS="2", MALLOC_ARENA_MAX="2")
    return subprocess.run(
        args, capture_output=True, text=True, timeout=120, env=env, preexec_fn=_limited
    )


def _python(code: str) -> subprocess.CompletedProcess[str]:
    return _run([sys.executable, "-c", textwrap.dedent(code)])


def _clean(result: subprocess.CompletedProcess[str]) -> None:
    assert result.returncode == 0, result.stderr
    assert result.stderr == "", result.stderr


def test_a_synthetic_frame_too_large_raises_out_of_memory_error_and_a_small_one_renders() -> None:
    result = _python("""
        from splitrender.errors import OutOfMemoryError, SplitRenderError
        from splitrender.scene import SyntheticScene
        scene = SyntheticScene()
        print("small", scene.server_frame(0, 0.0, 64, 36).main.color.shape)
        try:
            scene.server_frame(0, 0.0, 12000, 12000)
        except OutOfMemoryError as e:
            assert isinstance(e, MemoryError) and isinstance(e, SplitRenderError)
            print("refused:", e)
    """)
    _clean(result)
    assert "small (36, 64, 3)" in result.stdout
    assert "refused: synthetic_render_server: a 12000x12000 camera: needs about 15.0 GiB" in (
        result.stdout
    )


def test_the_reference_renderer_refuses_a_server_frame_and_a_ground_truth_too_large() -> None:
    result = _python("""
        from splitrender.errors import OutOfMemoryError
        from splitrender.scene.builtin import Scene
        scene = Scene("courtyard")
        print("small", scene.server_frame(0, 0.03).main.color.shape)
        for call in (
            lambda: scene.server_frame(0, 6.4),
            lambda: scene.client_frames(0, 6.4, stereo=True),
        ):
            try:
                call()
            except OutOfMemoryError as e:
                print("refused:", e)
    """)
    _clean(result)
    assert "small (43, 77, 3)" in result.stdout
    refused = [line for line in result.stdout.splitlines() if line.startswith("refused:")]
    assert len(refused) == 2, result.stdout
    assert "a 16384x9216 server frame and two" in refused[0]
    assert "2 16384x9216 image(s)" in refused[1]


def test_reproject_refuses_a_client_too_large_before_allocating_its_output() -> None:
    result = _python("""
        import numpy as np
        import splitrender as sr
        from splitrender.errors import OutOfMemoryError
        from splitrender.scene import SyntheticScene
        scene = SyntheticScene()
        f0 = scene.server_frame(0, 0.0, 64, 36)
        f1 = scene.server_frame(1, 0.1, 64, 36)
        small = sr.Camera(f1.main.camera.view, f1.main.camera.proj, 64, 36)
        print("small", sr.reproject_alpha(f0, f1, small, 0.5).shape)
        huge = sr.Camera(f1.main.camera.view, f1.main.camera.proj, 16384, 16384)
        try:
            sr.reproject_alpha(f0, f1, huge, 0.5)
        except OutOfMemoryError as e:
            print("refused:", e)
    """)
    _clean(result)
    assert "small (36, 64, 3)" in result.stdout
    assert "refused: reproject: ours to a 16384x16384 client from a 64x36 main camera" in (
        result.stdout
    )


def test_the_command_line_exits_2_with_one_line_and_leaves_no_directory(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    result = _run(
        [sys.executable, "-m", "splitrender", "render", "courtyard", "--out", str(out),
         "--scale", "6.4", "--seconds", "0.1", "--quiet"]
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs about" in lines[0] and "GiB" in lines[0], result.stderr
    assert "memory allocation" not in result.stderr
    assert list(tmp_path.iterdir()) == []
