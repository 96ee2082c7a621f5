"""The wgpu backend (issue 6) against the CPU path on the built-in dynamic scenes.

The GPU tests skip with a message when no wgpu adapter exists (install ``mesa-vulkan-drivers``
for lavapipe); CI installs lavapipe and sets ``REPROJ_WGPU_REQUIRE_ADAPTER=1``, which turns a
missing adapter into a failure. The error path (no adapter) is tested in a subprocess that hides
every adapter, so it runs everywhere.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap

import numpy as np
import numpy.typing as npt
import pytest
import splitrender as sr
from splitrender import gpu
from splitrender.errors import GpuUnavailableError, InvalidInputError, SplitRenderError

HAVE_GPU = gpu.available()
needs_gpu = pytest.mark.skipif(
    not HAVE_GPU,
    reason="no wgpu adapter (apt-get install mesa-vulkan-drivers gives Mesa's lavapipe)",
)

#: 2560·0.0625 × 1440·0.0625 = 160×90 main camera, 80×45 auxiliary cameras.
SCALE = 0.0625
#: Least share of identical pixels (and source codes) and largest mean absolute difference
#: (8-bit units). On lavapipe, which CI runs, every comparison here is bit-identical (Mesa 22.3.6,
#: LLVM 15; so is every case of crates/reproj-wgpu/tests/parity.rs at 150x84, 160x90 and 128x72),
#: and it must stay so: a kernel wrong in a handful of pixels fails (with 99.5 % and 0.5, a
#: dynamic-shadow blend weighted the wrong way round passed on courtyard and colonnade). Other
#: adapters keep the looser bound, which has not been measured against.
ON_LAVAPIPE = HAVE_GPU and "llvmpipe" in gpu.adapter()
MIN_EQUAL = 1.0 if ON_LAVAPIPE else 0.995
MAX_MAD = 0.0 if ON_LAVAPIPE else 0.5

Pair = tuple[sr.Scene, sr.ServerFrame, sr.ServerFrame]


def _agreement(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8]) -> tuple[float, float]:
    equal = float(np.all(a == b, axis=2).mean())
    mad = float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())
    return equal, mad


def test_adapter_present_where_required() -> None:
    if os.environ.get("REPROJ_WGPU_REQUIRE_ADAPTER") != "1":
        pytest.skip("REPROJ_WGPU_REQUIRE_ADAPTER is not 1 (CI sets it after installing lavapipe)")
    assert HAVE_GPU, "REPROJ_WGPU_REQUIRE_ADAPTER=1 but no wgpu adapter was found"


@pytest.fixture(scope="module", params=["courtyard", "colonnade", "lab"])
def pair(request: pytest.FixtureRequest) -> Pair:
    if not HAVE_GPU:
        pytest.skip("no wgpu adapter (apt-get install mesa-vulkan-drivers gives lavapipe)")
    scene = sr.Scene(request.param)
    return scene, scene.server_frame(2, SCALE), scene.server_frame(3, SCALE)


@needs_gpu
@pytest.mark.parametrize(
    ("method", "n"),
    [("ours", 29), ("ours", 39), ("ours_extrapolate", 39), ("forward_splat", 38)],
    ids=["ours-interpolate", "ours-extrapolate", "ours_extrapolate", "forward_splat"],
)
def test_wgpu_matches_cpu_on_builtin_scenes(pair: Pair, method: str, n: int) -> None:
    scene, f0, f1 = pair
    # Client frame n at 120 FPS: 29 is α = 5/12 between frames 2 and 3, 38/39 extrapolate.
    camera, _ = scene.client_frames(n, SCALE)[0]
    request = sr.ClientRequest(camera, n / 120)
    previous = np.full((camera.height, camera.width, 3), 77, np.uint8)
    cpu = sr.reproject(f0, f1, request, method, previous=previous, diagnostics=True)
    wgpu = sr.reproject(
        f0, f1, request, method, previous=previous, diagnostics=True, backend="wgpu"
    )
    equal, mad = _agreement(wgpu.image, cpu.image)
    assert equal >= MIN_EQUAL and mad <= MAX_MAD, (
        f"{scene.name} {method}: {100 * equal:.3f} % equal, MAD {mad:.4f}"
    )
    assert float((wgpu.source == cpu.source).mean()) >= MIN_EQUAL
    # Not vacuous: most pixels found a match on the CPU.
    assert float((cpu.source != 0).mean()) > 0.5


@needs_gpu
def test_fallback_splat_equals_int64(pair: Pair) -> None:
    scene, f0, f1 = pair
    camera, _ = scene.client_frames(29, SCALE)[0]
    alpha = 5 / 12
    fallback = gpu.GpuReprojector(force_32bit_atomics=True)
    assert fallback.atomics == "int32"
    native = gpu.GpuReprojector()
    images = [g.reproject(f0, f1, camera, alpha, "ours") for g in (fallback, native)]
    cpu = sr.reproject_alpha(f0, f1, camera, alpha, "ours")
    equal, mad = _agreement(images[0], cpu)
    assert equal >= MIN_EQUAL and mad <= MAX_MAD
    if native.atomics == "int64":
        np.testing.assert_array_equal(images[0], images[1])


@needs_gpu
def test_client_on_wgpu_plays_like_cpu() -> None:
    """A short session through :func:`splitrender.play`: pairs change, frames extrapolate when
    late, and the previous output stays on the device between client frames."""
    scene = sr.Scene("courtyard")
    frames = [scene.server_frame(k, SCALE) for k in range(4)]
    cams = [scene.client_frames(n, SCALE, fc=40.0)[0][0] for n in range(11)]
    # Sent 100 ms ahead of their time: 60 ms of latency makes the client extrapolate, then
    # interpolate once the next frame is in; 140 ms makes it hold first.
    modes: set[str] = set()
    for latency in (60.0, 140.0):
        net = sr.NetworkModel(client_fps=40.0, latency_ms=latency)
        runs = {
            b: sr.play(frames, cams, net, fps=40.0, method="ours", backend=b)
            for b in ("cpu", "wgpu")
        }
        assert runs["cpu"].modes() == runs["wgpu"].modes()
        modes |= set(runs["cpu"].modes())
        for n, (a, b) in enumerate(zip(runs["wgpu"].images, runs["cpu"].images, strict=True)):
            equal, mad = _agreement(a, b)
            assert equal >= MIN_EQUAL and mad <= MAX_MAD, f"{latency} ms, frame {n}: {equal}, {mad}"
    assert modes == {"hold", "extrapolate", "interpolate"}


@needs_gpu
def test_gpu_reprojector_keeps_frames_on_the_device(pair: Pair) -> None:
    scene, f0, f1 = pair
    g = gpu.GpuReprojector()
    with pytest.raises(SplitRenderError, match="load"):
        g.render(scene.client_frames(29, SCALE)[0][0], 0.4)
    g.load(f0, f1)
    prev: npt.NDArray[np.uint8] | None = None
    for n in (25, 26, 30):
        camera, _ = scene.client_frames(n, SCALE)[0]
        alpha = (n - 24) / 12
        cpu = sr.reproject_alpha(f0, f1, camera, alpha, "ours", previous=prev)
        img = g.render(camera, alpha, "ours", previous="keep", slot=1)
        equal, mad = _agreement(img, cpu)
        assert equal >= MIN_EQUAL and mad <= MAX_MAD
        prev = cpu
    assert "GpuReprojector(adapter=" in repr(g)


def test_backend_choice_is_checked(pair_synthetic: tuple[sr.ServerFrame, sr.ServerFrame]) -> None:
    f0, f1 = pair_synthetic
    camera = f1.main.camera
    with pytest.raises(InvalidInputError, match="unknown backend 'vulkan'"):
        sr.reproject_alpha(f0, f1, camera, 0.5, "ours", backend="vulkan")
    with pytest.raises(InvalidInputError, match="no wgpu kernel"):
        sr.reproject_alpha(f0, f1, camera, 0.5, "timewarp", backend="wgpu")
    with pytest.raises(InvalidInputError, match="no wgpu kernel"):
        sr.Client("backward_bidir", backend="wgpu")


@needs_gpu
def test_wgpu_errors_are_the_cpu_errors(
    pair_synthetic: tuple[sr.ServerFrame, sr.ServerFrame],
) -> None:
    f0, f1 = pair_synthetic
    camera = f1.main.camera
    messages = []
    for backend in ("cpu", "wgpu"):
        with pytest.raises(InvalidInputError, match=r"outside the supported range \[1, 3\]") as e:
            sr.reproject_alpha(f0, f1, camera, 0.5, "ours_extrapolate", backend=backend)
        messages.append(str(e.value))
    assert messages[0] == messages[1]
    g = gpu.GpuReprojector()
    g.load(f0, f1)
    with pytest.raises(InvalidInputError, match="unknown option 'nope'"):
        g._native.render("ours", camera.to_native(), 0.5, {"nope": 1})
    with pytest.raises(InvalidInputError, match=r"previous: expected uint8 array of shape \(32, 48, 3\)"):
        g.render(camera, 0.5, previous=np.zeros((4, 4, 3), np.uint8))
    # The arguments are checked before the device is asked (they raised bare ValueError,
    # TypeError and OverflowError, and slot 8 was refused as outside "0..8").
    for kwargs, named in (
        (dict(alpha="x"), "alpha: expected a float"),
        (dict(alpha=10**400), "alpha: expected a finite float"),
        (dict(alpha=1e308), "alpha = 1e308 is outside"),
        (dict(slot=8), r"slot: expected an int in \[0, 7\], got 8"),
        (dict(slot=1.5), "slot: expected an int"),
        (dict(method=None), "method: expected a str"),
        (dict(camera=None), "camera: expected Camera"),
        (dict(diagnostics="x"), "diagnostics: expected a bool"),
    ):
        with pytest.raises(InvalidInputError, match=named):
            g.render(**{"camera": camera, "alpha": 0.5, **kwargs})
    assert gpu.OUTPUT_SLOTS == 8
    g.render(camera, 0.5, slot=gpu.OUTPUT_SLOTS - 1)
    # Rendering with no pair loaded is the caller's mistake (it was a bare SplitRenderError,
    # which the command line treats as an internal failure).
    g.unload()
    with pytest.raises(InvalidInputError, match="no server frames on the device"):
        g.render(camera, 0.5)


def test_gpu_reprojector_arguments_are_checked(
    pair_synthetic: tuple[sr.ServerFrame, sr.ServerFrame],
) -> None:
    # bool() of anything had been taken: "no" chose the 32-bit splat, and diagnostics="no"
    # returned a Reprojection. The constructor's is checked before any adapter is asked for.
    with pytest.raises(InvalidInputError, match="force_32bit_atomics: expected a bool"):
        gpu.GpuReprojector(force_32bit_atomics="no")  # type: ignore[arg-type]
    if not HAVE_GPU:
        return
    f0, f1 = pair_synthetic
    g = gpu.GpuReprojector()
    with pytest.raises(InvalidInputError, match="diagnostics: expected a bool"):
        g.reproject(f0, f1, f1.main.camera, 0.5, diagnostics="no")  # type: ignore[arg-type]
    # upload takes frames from any thread (no @checked): its own checks name the argument.
    with pytest.raises(InvalidInputError, match="^older: expected a ServerFrame or None, got str$"):
        g.upload("f0", f1)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="^newer: expected a ServerFrame, got NoneType$"):
        g.upload(f0, None)  # type: ignore[arg-type]
    g.load(f0, f1)
    with pytest.raises(InvalidInputError, match="^previous: expected an image, 'keep' or None, "
                       "got 'last'$"):
        g.render(f1.main.camera, 0.5, previous="last")  # type: ignore[arg-type]
    assert g.render(f1.main.camera, 0.5, previous="keep").shape == (*f1.main.depth.shape, 3)
    # The extension's own: an image and keep=True at once (the Python layer passes one).
    cam = f1.main.camera
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    with pytest.raises(InvalidInputError, match="^previous: pass either an image or keep=True$"):
        g._native.render("ours", cam.to_native(), 0.5, sr.ReprojectOptions().to_native(), image,
                         True, 0, False, True)


@needs_gpu
def test_a_client_image_beyond_the_devices_buffers_is_the_callers_error(
    pair_synthetic: tuple[sr.ServerFrame, sr.ServerFrame],
) -> None:
    # wgpu's own refusal (a bind group's validation error) had come back as the base class,
    # which the command line reports as an internal failure. lavapipe binds at most 128 MiB;
    # a GPU with a larger limit would render this camera, so only lavapipe is held to it.
    if "llvmpipe" not in gpu.adapter():
        pytest.skip("the refusal is checked on lavapipe, whose limit the camera exceeds")
    f0, f1 = pair_synthetic
    big = sr.Camera(f1.main.camera.view, f1.main.camera.proj, 8192, 4096)
    g = gpu.GpuReprojector()
    g.load(f0, f1)
    with pytest.raises(InvalidInputError, match=r"of the 8192x4096 client image needs \d+ "
                       "bytes, above this device's storage binding limit"):
        g.render(big, 0.5)
    g.render(f1.main.camera, 0.5)  # still usable


@needs_gpu
def test_an_unused_older_frame_is_not_uploaded(
    pair_synthetic: tuple[sr.ServerFrame, sr.ServerFrame],
) -> None:
    # Extrapolating, the CPU path does not look into the older frame's matrices; the GPU path
    # uploaded it and refused a singular camera there alone.
    f0, f1 = pair_synthetic
    bad = dataclasses.replace(f0, main=dataclasses.replace(
        f0.main, camera=sr.Camera(np.zeros((4, 4)), f0.main.camera.proj, 48, 32)))
    for method in ("ours_extrapolate", "forward_splat"):
        opts = sr.ReprojectOptions(splat_bidirectional=False)
        cpu, gpu_ = (sr.reproject_alpha(bad, f1, f1.main.camera, 1.5, method, options=opts,
                                        backend=b) for b in ("cpu", "wgpu"))
        assert cpu.shape == gpu_.shape
    with pytest.raises(InvalidInputError, match="older.main"):
        sr.reproject_alpha(bad, f1, f1.main.camera, 0.5, "ours", backend="wgpu")


@pytest.fixture(scope="module")
def pair_synthetic() -> tuple[sr.ServerFrame, sr.ServerFrame]:
    scene = sr.SyntheticScene(dynamic=True)
    return scene.server_frame(0, 0.0, 48, 32), scene.server_frame(1, 0.1, 48, 32)


def test_no_adapter_raises_a_clear_error() -> None:
    """With every adapter hidden (WGPU_BACKEND names a backend this platform lacks), asking for
    wgpu raises GpuUnavailableError saying how to get one; the CPU path is unaffected."""
    code = textwrap.dedent(
        """
        import splitrender as sr
        from splitrender import gpu
        from splitrender.errors import GpuUnavailableError, SplitRenderError
        scene = sr.SyntheticScene(dynamic=True)
        f0 = scene.server_frame(0, 0.0, 24, 16)
        f1 = scene.server_frame(1, 0.1, 24, 16)
        assert not gpu.available()
        sr.reproject_alpha(f0, f1, f1.main.camera, 0.5, "ours")
        for make in (lambda: sr.reproject_alpha(f0, f1, f1.main.camera, 0.5, "ours", backend="wgpu"),
                     lambda: sr.Client("ours", backend="wgpu")):
            try:
                make()
            except GpuUnavailableError as e:
                assert isinstance(e, SplitRenderError)
                assert "mesa-vulkan-drivers" in str(e), str(e)
            else:
                raise AssertionError("no error")
        print("ok")
        """
    )
    r = _python(code, WGPU_BACKEND="metal" if sys.platform != "darwin" else "dx12")
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def _python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``code`` run by a fresh interpreter (the device is created once per process) with
    ``env`` added to the environment."""
    return subprocess.run(
        [sys.executable, "-c", code],
        check=False,
        env=dict(os.environ, **env),
        capture_output=True,
        text=True,
        timeout=120,
    )


@needs_gpu
def test_a_lost_device_fails_as_such_and_the_client_goes_on_on_the_cpu() -> None:
    """A driver reset or a removed GPU loses the device (here: wgpu's destroy). Rendering then
    raised a SplitRenderError about an invalid encoder, and an upload panicked inside wgpu
    (mapping a buffer made invalid by the loss), printing a Rust backtrace. Now every call on
    the lost device raises GpuDeviceLostError (not the caller's error), a client and the
    real-time loop go on on the CPU with the same bytes as a CPU client, whichever thread met
    the loss, and a new reprojector runs on a new device. In a child process: the device is
    the process's."""
    code = textwrap.dedent(
        """
        import numpy as np
        import splitrender as sr
        from splitrender import _native
        from splitrender.client.realtime import RealtimeClient
        from splitrender.errors import GpuDeviceLostError, is_user_error

        W, H, FC = 96, 54, 120.0
        scene = sr.SyntheticScene(dynamic=True)
        frames = [scene.server_frame(k, k / 10, W, H) for k in range(4)]


        def cam(n):
            return scene.rig(n / FC, W, H)[0]


        def lost_on(make):
            try:
                make()
            except GpuDeviceLostError as e:
                assert "the GPU device was lost (Destroyed)" in str(e), str(e)
                assert not is_user_error(e)
                return
            raise AssertionError("no GpuDeviceLostError")


        # The display meets the loss: that frame and the rest render on the CPU, the same bytes.
        cpu = sr.Client("ours")
        with RealtimeClient("ours", display_fps=FC, backend="wgpu") as c:
            for f in frames[:2]:
                cpu.receive(f); c.submit(f); c.wait()
            gpu = c.client.gpu
            for n in range(1, 4):
                assert np.array_equal(c.render(cam(n), n / FC), cpu.render(cam(n), n / FC))
            assert c.client.backend == "wgpu" and c.client.gpu_lost is None and gpu.lost is None
            _native._wgpu_lose_device_for_test()
            assert gpu.lost == "Destroyed", gpu.lost
            for n in range(4, 8):
                assert np.array_equal(c.render(cam(n), n / FC), cpu.render(cam(n), n / FC)), n
            assert c.client.backend == "cpu" and c.client.gpu is None
            assert "Destroyed" in c.client.gpu_lost
            # Every call on the lost device fails as such (no panic on the upload's mapping).
            lost_on(lambda: gpu.upload(frames[0], frames[1]))
            lost_on(lambda: gpu.load(frames[0], frames[1]))
            lost_on(lambda: gpu.render(cam(1), 0.5, "ours"))
            # Frames received after it are prepared by the worker for the CPU.
            for f in frames[2:]:
                cpu.receive(f); c.submit(f); c.wait()
            for n in range(13, 30):
                assert np.array_equal(c.render(cam(n), n / FC), cpu.render(cam(n), n / FC)), n
                info = c.client.last_info
                assert c.client.was_prepared(info.older, info.newer), n

        # The per-call API and a new client run on a new device.
        again = sr.reproject_alpha(frames[0], frames[1], cam(6), 0.5, "ours", backend="wgpu")
        assert again.shape == (H, W, 3)

        # The worker meets the loss first (an upload): the client goes to the CPU before any frame
        # fails, and the display's frames are the CPU's bytes.
        cpu = sr.Client("ours")
        with RealtimeClient("ours", display_fps=FC, backend="wgpu") as c:
            for f in frames[:2]:
                cpu.receive(f); c.submit(f); c.wait()
            assert np.array_equal(c.render(cam(3), 3 / FC), cpu.render(cam(3), 3 / FC))
            _native._wgpu_lose_device_for_test()
            cpu.receive(frames[2]); c.submit(frames[2]); c.wait()
            assert c.client.gpu_lost is not None and c.client.backend == "cpu"
            for n in range(13, 20):
                assert np.array_equal(c.render(cam(n), n / FC), cpu.render(cam(n), n / FC)), n

        # A run: the loss is reported (RealtimeReport.gpu_lost, the summary's gpu_lost) and the
        # display goes on with frames from the server frames.
        with RealtimeClient("ours", display_fps=FC, backend="wgpu") as c:
            modes = []

            def on_frame(image, rec):
                modes.append(rec.mode)
                if len(modes) == 5:
                    _native._wgpu_lose_device_for_test()

            report = c.run(lambda t: scene.rig(t, W, H)[0], 0.25, feed=[(0.0, f) for f in frames],
                           on_frame=on_frame)
            assert "Destroyed" in report.summary()["gpu_lost"]
            assert len(modes) > 10 and modes[-1] != "hold", modes
        print("ok")
        """
    )
    r = _python(code)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr
    assert "panicked" not in r.stderr and "internal error" not in r.stderr, r.stderr


def test_a_wgpu_backend_variable_naming_no_backend_is_named() -> None:
    """WGPU_BACKEND with a typo (or empty) selected no backend at all, and the error that followed
    said to install a Vulkan driver; it names the variable and what it may hold instead."""
    code = textwrap.dedent(
        """
        from splitrender import gpu
        from splitrender.errors import GpuUnavailableError
        try:
            gpu.adapter()
        except GpuUnavailableError as e:
            print(e)
        """
    )
    r = _python(code, WGPU_BACKEND="vulkna")
    assert r.returncode == 0, r.stderr
    assert "WGPU_BACKEND = \"vulkna\" names no wgpu backend" in r.stdout, r.stdout
    assert "expected a comma-separated list of vulkan, metal, dx12, gl" in r.stdout, r.stdout


def test_gpu_unavailable_error_is_in_the_hierarchy() -> None:
    assert issubclass(GpuUnavailableError, SplitRenderError)
    assert GpuUnavailableError.__module__ == "splitrender.errors"


def test_without_a_desktop_session_the_device_selection_layer_is_off(tmp_path) -> None:
    """Where nothing names a desktop session, Mesa's device-selection layer is turned off with
    its own variable; a session, or the user's own choice of either variable, leaves it."""
    absent = str(tmp_path / "absent")
    for env, turned_off in [
        ({}, True),
        ({"XDG_RUNTIME_DIR": absent}, True),  # set, but no directory: what the layer warns of
        ({"XDG_RUNTIME_DIR": ""}, True),
        ({"XDG_RUNTIME_DIR": str(tmp_path)}, False),
        ({"DISPLAY": ":0"}, False),
        ({"WAYLAND_DISPLAY": "wayland-0"}, False),
        ({"NODEVICE_SELECT": "0"}, False),
        ({"MESA_VK_DEVICE_SELECT": "10de:2330"}, False),
    ]:
        given = dict(env)
        assert gpu._headless_vulkan(given) is turned_off, env
        assert given == ({**env, "NODEVICE_SELECT": "1"} if turned_off else env)


@needs_gpu
def test_a_headless_process_writes_nothing_to_stderr_for_the_gpu() -> None:
    """Mesa's device-selection layer wrote "error: XDG_RUNTIME_DIR is invalid or not set in the
    environment." twice on stderr in a process without a desktop session (a server, CI) that
    asked for the wgpu backend; with the layer off there, the adapter is found and stderr stays
    empty."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("XDG_RUNTIME_DIR", "DISPLAY", "WAYLAND_DISPLAY", "NODEVICE_SELECT")}
    code = "from splitrender import gpu; print(gpu.adapter()); gpu.GpuReprojector()"
    r = subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == gpu.adapter(), r.stderr
    assert r.stderr == ""
