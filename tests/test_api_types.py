"""Wrong types and out-of-range values at the public boundary (issue 15, "types leak through").

Every callable that ``splitrender.__all__`` (and ``splitrender.metrics.__all__``) makes public
(functions, constructors, public methods) is listed in :data:`TABLE` with a valid call and bad
values for each of its parameters, or in :data:`EXEMPT` with the reason. Each bad value must
raise an exception of the package's hierarchy naming the parameter, never a bare TypeError,
ValueError, OverflowError, struct.error or AttributeError from deeper down. A new public name, a
new public method or a new parameter that is in neither table fails
:func:`test_every_public_callable_is_in_the_table`.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import splitrender as sr
from splitrender.errors import InvalidInputError, SplitRenderError

#: Bad values by what a parameter takes. ``BIG`` is an int no float can hold.
BIG = 10**400
NUMBER = [None, "x", [], math.nan, math.inf, -math.inf, BIG]
POSITIVE = [*NUMBER, 0, -1.0]
INT = [None, "x", 1.5, math.nan, BIG, True]
COUNT = [*INT, -1]
PATH = [None, 0, [], ""]
SEQUENCE = [None, 0, math.nan, object()]
BOOL = [None, "x", 2]
STR = [None, 0, []]
CALLABLE = ["x", 0]
THING = [None, "x", 0, []]  # an object of a given class, required
OPTIONAL_THING = ["x", 0, []]  # an object of a given class, or None

W, H = 16, 16


class Fixtures:
    """Valid arguments, made once."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.syn = sr.SyntheticScene()
        self.f0 = self.syn.server_frame(0, 0.0, W, H)
        self.f1 = self.syn.server_frame(1, 0.1, W, H)
        self.cam = self.syn.client_camera(0.05, W, H)
        with sr.StreamEncoder(sr.CodecConfig(bitrate_mbps=1.0)) as enc:
            self.packets = [enc.encode(self.f0), enc.encode(self.f1)]
        self.stream = tmp / "s.srs"
        sr.write_stream(self.stream, self.packets)
        self.trace_file = tmp / "trace.txt"
        self.trace_file.write_text("0 0 0 0 0 0 0\n0 0 0 0 0 0 100\n")
        self.trace = sr.load_trace(self.trace_file)
        self.client = sr.Client()
        self.client.receive(self.f0)
        self.client.receive(self.f1)
        self.img = np.zeros((H, W, 3), np.uint8)
        self.img32 = np.zeros((32, 32, 3), np.uint8)  # VMAF takes 32 pixels a side
        self.rec = sr.load_recording(sr.write_recording(tmp / "rec1", "courtyard", seconds=0.1,
                                                        scale=0.01))


Entry = tuple[Callable[[Fixtures], Callable[..., Any]], Callable[[Fixtures], dict[str, Any]],
              dict[str, list[Any]]]


def _m(f: Fixtures) -> Any:
    return f.f0.main


#: name -> (the callable, from the fixtures; a valid call's keyword arguments; bad values per
#: parameter). Every parameter of the callable appears in the bad values.
TABLE: dict[str, Entry] = {
    "apply_shadows": (
        lambda f: sr.apply_shadows,
        lambda f: dict(frame_color=_m(f).color, shadow=_m(f).shadow_fwd, alpha=0.5, subframes=4,
                       role="older"),
        dict(frame_color=THING, shadow=THING, alpha=NUMBER, subframes=[*INT, 0, 17],
             role=[*STR, "x"]),
    ),
    "prepare_pair": (
        lambda f: sr.prepare_pair,
        lambda f: dict(older=f.f0, newer=f.f1, camera=f.cam, method="ours", options=None,
                       history=sr.BidirHistory(), threads=None),
        dict(older=OPTIONAL_THING, newer=THING, camera=THING, method=[*STR, "x"],
             options=OPTIONAL_THING, history=THING, threads=[*INT[1:], -1, 0, 257]),
    ),
    "reproject": (
        lambda f: sr.reproject,
        lambda f: dict(older=f.f0, newer=f.f1, request=sr.ClientRequest(f.cam, 0.05),
                       method="ours", options=None, previous=None, diagnostics=False,
                       history=None, backend="cpu"),
        dict(older=OPTIONAL_THING, newer=THING, request=THING, method=[*STR, "x"],
             options=OPTIONAL_THING, previous=OPTIONAL_THING, diagnostics=BOOL,
             history=OPTIONAL_THING, backend=[*STR, "x"]),
    ),
    "reproject_alpha": (
        lambda f: sr.reproject_alpha,
        lambda f: dict(older=f.f0, newer=f.f1, camera=f.cam, alpha=0.5, method="ours",
                       options=None, previous=None, diagnostics=False, history=None,
                       backend="cpu"),
        dict(older=OPTIONAL_THING, newer=THING, camera=THING, alpha=NUMBER, method=[*STR, "x"],
             options=OPTIONAL_THING, previous=OPTIONAL_THING, diagnostics=BOOL,
             history=OPTIONAL_THING, backend=[*STR, "x"]),
    ),
    "scene_flow": (
        lambda f: sr.scene_flow,
        lambda f: dict(source=_m(f), client=f.cam, w=0.5, direction="forward"),
        dict(source=THING, client=THING, w=NUMBER, direction=[*STR, "x"]),
    ),
    "play": (
        lambda f: sr.play,
        lambda f: dict(frames=[f.f0, f.f1], cameras=[f.cam] * 3, network=None, fps=120.0,
                       method="ours", options=None, frame_sizes=None, lead=None,
                       keep_images=True, on_frame=None, backend="cpu"),
        dict(frames=SEQUENCE, cameras=[*SEQUENCE, ["x"]], network=OPTIONAL_THING, fps=POSITIVE,
             method=[*STR, "x"], options=OPTIONAL_THING, frame_sizes=[0, math.nan, ["x"], [-1]],
             lead=NUMBER[1:], keep_images=BOOL, on_frame=CALLABLE, backend=[*STR, "x"]),
    ),
    "read_stream": (
        lambda f: lambda **k: list(sr.read_stream(**k)),
        lambda f: dict(path=f.stream, start=None),
        dict(path=PATH, start=COUNT[1:]),
    ),
    "write_stream": (
        lambda f: sr.write_stream,
        lambda f: dict(path=f.tmp / "w.srs", packets=f.packets, fps=10.0),
        dict(path=PATH, packets=[*SEQUENCE, [None], ["x"]], fps=POSITIVE),
    ),
    "stream_stats": (
        lambda f: sr.stream_stats,
        lambda f: dict(packets=f.packets, fps=10.0),
        dict(packets=[*SEQUENCE, [None], ["x"]], fps=POSITIVE),
    ),
    "load_recording": (lambda f: sr.load_recording, lambda f: dict(path=f.tmp),
                       dict(path=PATH)),
    "Recording.eye": (lambda f: f.rec.eye, lambda f: dict(eye=0, n=2),
                      dict(eye=[*COUNT, 2, 1], n=[*COUNT[1:], BIG])),
    "load_trace": (lambda f: sr.load_trace, lambda f: dict(path=f.trace_file), dict(path=PATH)),
    "write_recording": (
        lambda f: sr.write_recording,
        lambda f: dict(out=f.tmp / "rec", scene="courtyard", variant="dynamic", seconds=0.1,
                       scale=0.01, fs=10.0, fc=120.0, subframes=4, stereo=False, trace=None,
                       translation_scale=1.0, samples=1, overwrite=False, progress=None),
        dict(out=PATH, scene=[None, 0, [], "nosuch"], variant=[*STR, "x"], seconds=POSITIVE,
             scale=POSITIVE, fs=POSITIVE, fc=POSITIVE, subframes=[*INT, 0], stereo=BOOL,
             trace=OPTIONAL_THING, translation_scale=NUMBER, samples=[*INT[1:], 0],
             overwrite=BOOL, progress=CALLABLE),
    ),
    "export_dataset": (
        lambda f: sr.export_dataset,
        lambda f: dict(recording=f.tmp / "no-rec", out_dir=f.tmp / "ds", aux_names=("l", "r"),
                       client="c"),
        dict(recording=[None, 0, []], out_dir=PATH, aux_names=[*SEQUENCE, "lr", [1, 2]],
             client=[*STR, "../x"]),
    ),
    "import_dataset": (
        lambda f: sr.import_dataset,
        lambda f: dict(in_dir=f.tmp / "no-ds", aux=("l", "r"), client="c"),
        dict(in_dir=PATH, aux=[*SEQUENCE, [1, 2]], client=[0, [], ""]),
    ),
    "Camera": (
        lambda f: sr.Camera,
        lambda f: dict(view=f.cam.view, proj=f.cam.proj, width=W, height=H),
        # A complex matrix was cast to real with a warning (its imaginary part dropped).
        dict(view=[None, "x", [[BIG] * 4] * 4, np.zeros(3), np.eye(4, dtype=complex)],
             proj=[None, "x", [[1] * 4] * 3, np.eye(4) + 1j],
             width=[*COUNT, 0, 16385], height=[*COUNT, 0]),
    ),
    "Camera.look_at": (
        lambda f: sr.Camera.look_at,
        lambda f: dict(eye=(0, 0, 0), target=(0, 0, -1), fov_y_deg=60.0, width=W, height=H,
                       near=0.1, far=100.0, up=(0, 1, 0)),
        dict(eye=[None, "x", (1, 2), (BIG, 0, 0)], target=[None, (1, 2)], fov_y_deg=POSITIVE,
             width=COUNT, height=COUNT, near=POSITIVE, far=POSITIVE, up=[None, 1]),
    ),
    "Camera.stereo": (lambda f: f.cam.stereo, lambda f: dict(ipd=0.07), dict(ipd=POSITIVE)),
    "CameraFrame": (
        lambda f: sr.CameraFrame,
        lambda f: dict(camera=_m(f).camera, color=_m(f).color, depth=_m(f).depth),
        dict(camera=THING, color=THING, depth=THING, motion_fwd=OPTIONAL_THING,
             motion_bwd=OPTIONAL_THING, shadow_fwd=OPTIONAL_THING, shadow_bwd=OPTIONAL_THING),
    ),
    "CameraFrame.to_native": (lambda f: _m(f).to_native, lambda f: dict(direction="fwd"),
                              dict(direction=[*STR, "x"])),
    "ClientRequest": (lambda f: sr.ClientRequest, lambda f: dict(camera=f.cam, time=0.0),
                      dict(camera=THING, time=NUMBER)),
    "ReprojectOptions": (
        lambda f: sr.ReprojectOptions, lambda f: {},
        {**{n: POSITIVE for n in ("eps_e", "eps_z", "eps_o", "aux_threshold_scale",
                                  "server_fps")},
         **{n: [*COUNT, 100] for n in ("window", "fpi_iterations", "bidir_iterations",
                                       "shadow_subframes")},
         **{n: BOOL for n in ("use_shadows", "use_aux", "blend", "splat_bidirectional")}},
    ),
    "ReprojectOptions.replace": (lambda f: sr.ReprojectOptions().replace, lambda f: {},
                                 dict(changes=[{"eps_e": "x"}, {"nosuch": 1}])),
    "ServerFrame": (
        lambda f: sr.ServerFrame, lambda f: dict(index=0, time=0.0, main=_m(f), aux=f.f0.aux),
        dict(index=COUNT, time=NUMBER, main=THING, aux=[None, 0, "x", [None]], span=[*INT, 0, 17]),
    ),
    "ServerFrame.to_native": (lambda f: f.f0.to_native, lambda f: dict(direction="fwd"),
                              dict(direction=[*STR, "x"])),
    "ShadowBuffers": (
        lambda f: sr.ShadowBuffers,
        lambda f: dict(bits=_m(f).shadow_fwd.bits, s_min=_m(f).shadow_fwd.s_min,
                       s_max=_m(f).shadow_fwd.s_max),
        dict(bits=THING, s_min=THING, s_max=THING),
    ),
    "Reprojection": (
        lambda f: sr.Reprojection,
        lambda f: dict(image=f.img, source=np.zeros((H, W), np.uint8),
                       error=np.zeros((H, W), np.float32)),
        dict(image=THING, source=THING, error=THING),
    ),
    "Client": (
        lambda f: sr.Client,
        lambda f: dict(method="ours", options=None, server_fps=None, capacity=4, backend="cpu"),
        dict(method=[*STR, "x"], options=OPTIONAL_THING, server_fps=POSITIVE[1:],
             capacity=[*COUNT, 0], backend=[*STR, "x"]),
    ),
    "Client.receive": (lambda f: sr.Client().receive,
                       lambda f: dict(frame=f.f0, arrival_time=None),
                       dict(frame=THING, arrival_time=NUMBER[1:])),
    "Client.choose": (lambda f: f.client.choose, lambda f: dict(time=0.05, interpolate=True),
                      dict(time=NUMBER, interpolate=BOOL)),
    "Client.render": (lambda f: f.client.render,
                      lambda f: dict(camera=f.cam, time=0.05, eye=0, interpolate=True),
                      dict(camera=THING, time=NUMBER, eye=[*INT, 2, -1], interpolate=BOOL)),
    "Client.held_frame": (lambda f: f.client.held_frame, lambda f: dict(index=0),
                          dict(index=INT)),
    "Client.was_prepared": (lambda f: f.client.was_prepared, lambda f: dict(older=0, newer=1),
                            dict(older=INT[1:], newer=INT)),
    "Client.lose_gpu": (lambda f: f.client.lose_gpu, lambda f: dict(reason="lost"),
                        dict(reason=STR)),
    "Client.adopt_prepared": (
        lambda f: f.client.adopt_prepared,
        lambda f: dict(older=0, newer=1, history=sr.BidirHistory()),
        dict(older=INT[1:], newer=INT, history=THING),
    ),
    "CodecConfig": (
        lambda f: sr.CodecConfig, lambda f: {},
        dict(bitrate_mbps=[*POSITIVE, 1e300],
             camera_shares=[*SEQUENCE, (1.0, "x"), (BIG,), (), (0.5, 0.3), (1.0, 0.0)],
             color_share=NUMBER, depth_share=NUMBER, motion_share=NUMBER,
             shadow_color_share=NUMBER, chroma=[*STR, "x"], preset=[*STR, "x"],
             fps=POSITIVE, gop=[*COUNT, 0], vbv_buffer_s=POSITIVE, uncompressed=BOOL,
             zstd_level=[*COUNT, 0], lossless_share=[*NUMBER, -0.1, 1.5],
             exact_static_motion=BOOL, rate_feedback=BOOL, threads=COUNT),
    ),
    "CodecConfig.scaled": (
        lambda f: sr.CodecConfig.scaled, lambda f: dict(width=W, height=H, paper_mbps=40.0),
        dict(width=[*COUNT, 0], height=[*COUNT, 0], paper_mbps=POSITIVE,
             kwargs=[{"fps": "x"}, {"nosuch": 1}]),
    ),
    "ModelPlacement": (
        lambda f: sr.ModelPlacement, lambda f: dict(path="x.glb", position=(0, 0, 0)),
        dict(path=PATH, position=[None, 0, (1, 2), (math.nan, 0, 0), ("x", 0, 0)],
             yaw_deg=NUMBER, scale=POSITIVE, animation=INT[1:], time_offset=NUMBER,
             speed=POSITIVE),
    ),
    "NetworkModel": (
        lambda f: sr.NetworkModel, lambda f: {},
        dict(bandwidth_mbps=POSITIVE[1:], latency_ms=[*NUMBER, -1.0],
             jitter_ms=[*NUMBER, -1.0], extra_delay_frames=COUNT, loss=[*NUMBER, 2.0],
             seed=COUNT, client_fps=POSITIVE),
    ),
    "NetworkModel.arrival_times": (
        lambda f: sr.NetworkModel().arrival_times, lambda f: dict(send_times=[0.0, 0.1]),
        dict(send_times=[*SEQUENCE, ["x"], [BIG]], sizes=[0, math.nan, ["x"], [-1]]),
    ),
    "Schedule.build": (
        lambda f: sr.Schedule.build, lambda f: dict(frame_times=[0.0, 0.1]),
        dict(frame_times=[None, math.nan, BIG, -1, ["x"], object()], network=OPTIONAL_THING,
             client_fps=POSITIVE, server_fps=POSITIVE, n_client_frames=[*INT[1:], -1],
             frame_sizes=[0, ["x"]], lead=NUMBER[1:], method=[*STR, "x"],
             splat_bidirectional=BOOL, capacity=[*COUNT, 1]),
    ),
    "RealtimeClient": (
        lambda f: lambda **k: sr.RealtimeClient(**k).close(), lambda f: {},
        dict(method=[*STR, "x"], options=OPTIONAL_THING, display_fps=POSITIVE,
             clock=OPTIONAL_THING, client=OPTIONAL_THING, capacity=[*COUNT, 0],
             prepare_threads=[*INT[1:], -1, 0, 257], decoder=OPTIONAL_THING, executor=OPTIONAL_THING,
             worker_priority=[*STR, "x", "IDLE"], display_priority=[*STR, "x", "idle"],
             backend=[*STR, "x", "WGPU"], max_divisor=[*COUNT, 0, 17], defer_interpolation=BOOL,
             keep_frames=[*INT[1:], -1], on_handover=CALLABLE),
    ),
    "Scene": (lambda f: sr.Scene, lambda f: dict(name="courtyard"),
              dict(name=[*STR, "x"], variant=[*STR, "x"], models=[*SEQUENCE, ["x"]])),
    "Scene.from_description": (lambda f: sr.Scene.from_description,
                               lambda f: dict(path=f.trace_file), dict(path=PATH)),
    "Scene.main_size": (lambda f: sr.Scene("courtyard").main_size, lambda f: dict(scale=0.1),
                        dict(scale=POSITIVE)),
    "Scene.camera_sizes": (lambda f: sr.Scene("courtyard").camera_sizes,
                           lambda f: dict(scale=0.1), dict(scale=POSITIVE)),
    "Scene.head_box": (lambda f: sr.Scene("courtyard").head_box, lambda f: dict(t=0.1),
                       dict(t=NUMBER)),
    "Scene.client_pose": (lambda f: sr.Scene("courtyard").client_pose, lambda f: dict(t=0.1),
                          dict(t=NUMBER)),
    "Scene.server_pose": (lambda f: sr.Scene("courtyard").server_pose, lambda f: dict(k=1),
                          dict(k=COUNT, fps=POSITIVE)),
    "Scene.server_frame": (
        lambda f: sr.Scene("courtyard").server_frame, lambda f: dict(k=0, scale=0.01),
        dict(k=COUNT, scale=POSITIVE, fps=POSITIVE, subframes=[*COUNT, 0], pose=["x", 0],
             samples=[*INT[1:], 0]),
    ),
    "Scene.client_frames": (
        lambda f: sr.Scene("courtyard").client_frames, lambda f: dict(n=0, scale=0.01),
        dict(n=COUNT, scale=POSITIVE, fc=POSITIVE, stereo=BOOL, pose=["x", 0],
             samples=[*INT[1:], 0]),
    ),
    "Scene.ground_truth": (
        lambda f: sr.Scene("courtyard").ground_truth, lambda f: dict(camera=f.cam, t=0.1),
        dict(camera=THING, t=NUMBER, samples=[*INT[1:], 0]),
    ),
    "Scene.digest": (lambda f: sr.Scene("courtyard").digest, lambda f: {}, {}),
    "Scene.path_motion": (lambda f: sr.Scene("courtyard").path_motion, lambda f: {},
                          dict(prediction_delay=[*NUMBER[1:], -1.0])),
    "DecodedStream": (lambda f: sr.DecodedStream, lambda f: dict(packets=f.packets),
                      dict(packets=[*SEQUENCE, [None], ["x"], [b"", 0]])),
    "StreamDecoder": (lambda f: sr.StreamDecoder, lambda f: {},
                      dict(threads=COUNT, max_pixels=[*COUNT, 0])),
    "StreamDecoder.decode": (lambda f: sr.StreamDecoder().decode,
                             lambda f: dict(data=f.packets[0]),
                             dict(data=[None, "x", 0, [], b"", b"\0" * 64])),
    "StreamEncoder": (lambda f: sr.StreamEncoder, lambda f: {}, dict(config=OPTIONAL_THING)),
    "StreamEncoder.encode": (lambda f: sr.StreamEncoder().encode, lambda f: dict(frame=f.f0),
                             dict(frame=THING)),
    "StreamEncoder.set_bitrate": (lambda f: sr.StreamEncoder().set_bitrate,
                                  lambda f: dict(mbps=1.0), dict(mbps=[*POSITIVE, 1e300])),
    "StreamStats": (lambda f: sr.StreamStats, lambda f: dict(fps=10.0),
                    dict(fps=POSITIVE, frames=COUNT, header_bytes=COUNT,
                         bytes_by_buffer=[None, "x", {"a": "x"}, {1: 5}])),
    "StreamStats.add": (lambda f: sr.StreamStats(10.0).add, lambda f: dict(packet=f.packets[0]),
                        dict(packet=[None, "x", 0, b""])),
    "SyntheticScene": (lambda f: sr.SyntheticScene, lambda f: {}, dict(dynamic=BOOL)),
    "SyntheticScene.head_pose": (lambda f: f.syn.head_pose, lambda f: dict(t=0.1),
                                 dict(t=NUMBER)),
    "SyntheticScene.head_deviation": (lambda f: f.syn.head_deviation, lambda f: dict(t=0.1),
                                      dict(t=NUMBER)),
    "SyntheticScene.rig": (lambda f: f.syn.rig, lambda f: dict(t=0.1, width=W, height=H),
                           dict(t=NUMBER, width=[*COUNT, 0], height=[*COUNT, 0])),
    "SyntheticScene.client_camera": (lambda f: f.syn.client_camera,
                                     lambda f: dict(t=0.1, width=W, height=H),
                                     dict(t=NUMBER, width=[*COUNT, 0], height=[*COUNT, 0])),
    "SyntheticScene.render": (
        lambda f: f.syn.render, lambda f: dict(camera=f.cam, time=0.1),
        dict(camera=THING, time=NUMBER, fps=POSITIVE, subframes=[*COUNT, 0]),
    ),
    "SyntheticScene.server_frame": (
        lambda f: f.syn.server_frame, lambda f: dict(index=0, time=0.0, width=W, height=H),
        dict(index=COUNT, time=NUMBER, width=[*COUNT, 0], height=[*COUNT, 0], fps=POSITIVE,
             subframes=[*COUNT, 0]),
    ),
    "SyntheticScene.ground_truth": (lambda f: f.syn.ground_truth,
                                    lambda f: dict(camera=f.cam, time=0.1),
                                    dict(camera=THING, time=NUMBER)),
    "Trace.pose": (lambda f: f.trace.pose, lambda f: dict(t=0.01), dict(t=NUMBER)),
    "metrics.psnr": (lambda f: sr.metrics.psnr, lambda f: dict(a=f.img, b=f.img),
                     dict(a=THING, b=THING)),
    "metrics.psnr_of_mse": (lambda f: sr.metrics.psnr_of_mse, lambda f: dict(mse=0.01),
                            dict(mse=[*NUMBER, -1e-9])),
    "metrics.ssim": (lambda f: sr.metrics.ssim, lambda f: dict(a=f.img, b=f.img),
                     dict(a=THING, b=THING)),
    "metrics.ssim_map": (lambda f: sr.metrics.ssim_map, lambda f: dict(a=f.img, b=f.img),
                         dict(a=THING, b=THING)),
    "metrics.flip": (lambda f: sr.metrics.flip, lambda f: dict(test=f.img, reference=f.img),
                     dict(test=THING, reference=THING, ppd=POSITIVE)),
    "metrics.flip_map": (lambda f: sr.metrics.flip_map,
                         lambda f: dict(test=f.img, reference=f.img),
                         dict(test=THING, reference=THING, ppd=POSITIVE)),
    "metrics.vmaf": (lambda f: sr.metrics.vmaf,
                     lambda f: dict(distorted=[f.img32], reference=[f.img32]),
                     dict(distorted=THING, reference=THING, fps=POSITIVE,
                          threads=[*INT[1:], -1])),
    "metrics.evaluate_sequence": (
        lambda f: sr.metrics.evaluate_sequence,
        lambda f: dict(rendered=[f.img] * 3, truth=[f.img] * 3, skip=0, metrics=("psnr",)),
        dict(rendered=THING, truth=THING, skip=[*COUNT], metrics=[None, "psnr", ["x"], 0],
             fps=POSITIVE, ppd=POSITIVE, progress=CALLABLE, flip_every=[*INT, 0, 1 << 21]),
    ),
    "metrics.SequenceScorer": (
        lambda f: sr.metrics.SequenceScorer,
        lambda f: dict(n=3, skip=0, metrics=("psnr",)),
        dict(n=[*COUNT, 0], skip=[*COUNT], metrics=[None, "psnr", ["x"], 0], fps=POSITIVE,
             ppd=POSITIVE, progress=CALLABLE, flip_every=[*INT, 0, 1 << 21]),
    ),
    "metrics.SequenceScorer.add": (
        lambda f: sr.metrics.SequenceScorer(3, 0, ("psnr",)).add,
        lambda f: dict(rendered=f.img, truth=f.img),
        dict(rendered=THING, truth=THING),
    ),
}

#: Public callables without a row, and why.
EXEMPT: dict[str, str] = {
    "BidirHistory": "takes no arguments",
    "BidirHistory.reset": "takes no arguments",
    "Camera.to_native": "takes no arguments",
    "ShadowBuffers.to_native": "takes no arguments",
    "ModelPlacement.to_native": "takes no arguments",
    "ReprojectOptions.to_native": "takes no arguments",
    "CodecConfig.shares": "takes no arguments",
    "NetworkModel.link": "takes no arguments",
    "Client.retired_histories": "takes no arguments",
    "Client.retired_uploads": "takes no arguments",
    "Client.adopt_uploaded": "needs a wgpu client and a pair on its device "
    "(tests/test_realtime.py: refused on the CPU and for frames not held); its arguments go "
    "through the same checks as adopt_prepared's",
    "Client.reset": "takes no arguments",
    "RealtimeClient.close": "takes no arguments",
    "StreamEncoder.close": "takes no arguments",
    "StreamEncoder.request_key_frame": "takes no arguments",
    "StreamStats.mbps_by_buffer": "takes no arguments",
    "StreamStats.mbps_by_camera": "takes no arguments",
    "StreamStats.mbps_total": "takes no arguments",
    "StreamStats.format": "takes no arguments",
    "Schedule.modes": "takes no arguments",
    "Schedule.summary": "takes no arguments",
    "PlaybackResult.modes": "takes no arguments",
    "PlaybackResult.summary": "takes no arguments",
    "PlaybackResult.schedule": "takes no arguments",
    "Recording.verify": "takes no arguments",
    "PlaybackResult": "a result that play() builds, not an input; its fields are read back",
    "Schedule": "a plan that Schedule.build() makes from checked arguments",
    "Recording": "made by load_recording(), which checks the manifest it is given",
    "ClientFrame": "a record that load_recording() builds from a checked recording",
    "Trace": "made by load_trace(), which checks the file",
    "metrics.SequenceMetrics": "a result of evaluate_sequence(), not an input",
    "metrics.SequenceMetrics.to_dict": "takes no arguments",
    "metrics.SequenceScorer.finish": "takes no arguments",
    "metrics.SequenceScorer.close": "takes no arguments",
    "Recording.server_pose": "a recording's own pose table, indexed like a list",
    "Recording.server_cameras": "a recording's own camera table, indexed like a list",
    "RealtimeClient.submit": "covered by test_realtime (packets and frames, threads)",
    "RealtimeClient.wait": "covered by test_realtime",
    "RealtimeClient.render": "the same checks as Client.render, which it calls (interpolate "
    "checked by its own decorator first)",
    "RealtimeClient.run": "covered by test_realtime (seconds: NaN, inf, 0, bool)",
    "BidirHistory.prepare": "native, takes the bindings' frame tuples: "
                            "test_bidir_history_prepare_checks_its_arguments",
}


def public_callables() -> dict[str, tuple[Callable[..., Any], bool]]:
    """Every public callable, named as in the tables, and whether it is a constructor."""
    found: dict[str, tuple[Callable[..., Any], bool]] = {}
    spaces: list[tuple[str, Any, list[str]]] = [("", sr, list(sr.__all__)),
                                                ("metrics.", sr.metrics, list(sr.metrics.__all__))]
    for prefix, module, names in spaces:
        for name in names:
            obj = getattr(module, name)
            if inspect.ismodule(obj) or not callable(obj):
                continue
            if isinstance(obj, type) and issubclass(obj, BaseException):
                continue
            found[prefix + name] = (obj, isinstance(obj, type))
            if isinstance(obj, type):
                for attr, value in vars(obj).items():
                    if attr.startswith("_") or isinstance(value, property):
                        continue
                    if callable(value) or isinstance(value, (classmethod, staticmethod)):
                        found[f"{prefix}{name}.{attr}"] = (getattr(obj, attr), False)
    return found


def parameters(fn: Callable[..., Any], constructor: bool) -> set[str]:
    try:
        sig = inspect.signature(fn)
    except ValueError:  # a native method without a text signature
        return set()
    return {p for p in sig.parameters if p not in ("self", "cls")}


def test_every_public_callable_is_in_the_table() -> None:
    found = public_callables()
    assert not set(TABLE) & set(EXEMPT)
    assert set(found) - set(TABLE) - set(EXEMPT) == set(), "add a row to TABLE (or EXEMPT)"
    assert set(TABLE) | set(EXEMPT) <= set(found), "a row names no public callable"
    for name, (_, _, bad) in TABLE.items():
        fn, constructor = found[name]
        params = parameters(fn, constructor)
        if params:
            assert set(bad) == params, f"{name}: bad values for {sorted(params - set(bad))}"


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory: pytest.TempPathFactory) -> Fixtures:
    return Fixtures(tmp_path_factory.mktemp("api-types"))


#: Other words by which a message may name a parameter (the item of a sequence, the thing a
#: name names).
ALIASES: dict[str, tuple[str, ...]] = {
    "packets": ("packet",), "name": ("scene",), "data": ("packet",),
}

CALLS = [(name, param) for name, (_, _, bad) in TABLE.items() for param in bad]


@pytest.mark.parametrize("name, param", CALLS, ids=[f"{n}-{p}" for n, p in CALLS])
def test_a_bad_argument_raises_the_package_error_naming_it(
    fixtures: Fixtures, name: str, param: str
) -> None:
    get, valid, bad = TABLE[name]
    fn = get(fixtures)
    for value in bad[param]:
        kwargs = valid(fixtures)
        if param in ("changes", "kwargs"):  # **changes / **kwargs: the bad names and values
            kwargs = {**kwargs, **value}
        else:
            kwargs = {**kwargs, param: value}
        try:
            fn(**kwargs)
        except SplitRenderError as e:
            words = [param, *ALIASES.get(param, ())]
            if param in ("changes", "kwargs"):
                words = list(value)
            named = any(w in str(e) for w in words)
            assert named, f"{name}({param}={value!r}): the message does not name it: {e}"
        except Exception as e:  # noqa: BLE001  (the failure this test is for)
            pytest.fail(f"{name}({param}={value!r}) raised {type(e).__name__}: {e}")
        else:
            pytest.fail(f"{name}({param}={value!r}) was accepted")


@pytest.mark.parametrize(
    ("method", "threads", "named"),
    [(None, None, "method"), (3, None, "method"), ("ours", 10**400, "threads"),
     ("ours", "2", "threads"), ("ours", True, "threads"), ("ours", 0, "threads")],
)
def test_bidir_history_prepare_checks_its_arguments(
    method: Any, threads: Any, named: str
) -> None:
    """The native method takes Python objects and checks them itself (pyo3's conversions raised
    TypeError and OverflowError); the frames are never reached."""
    with pytest.raises(InvalidInputError, match=named):
        sr.BidirHistory().prepare(method, None, None, None, None, threads)  # type: ignore[arg-type]


def test_a_check_of_a_parameter_the_function_lacks_is_refused_where_it_is_written() -> None:
    # A misspelt name in @checked would otherwise check nothing, silently.
    from splitrender.types import checked, ints

    def scale(factor: int) -> int:
        return factor

    with pytest.raises(AssertionError, match=r"scale: no parameters \['factr'\]$"):
        checked(factr=ints(1, 8))(scale)
    assert checked(factor=ints(1, 8))(scale)(2) == 2
