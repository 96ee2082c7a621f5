"""``splitrender dataset export`` and ``import``: recordings to and from the authors' dataset layout."""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.cli.args import fail, names
from splitrender.errors import SplitRenderError
from splitrender.progress import Progress

__all__ = ["add", "import_recording"]

_AUX = ("left", "right")
_CLIENT = "client_ol"


def add(sub: Any) -> None:
    ds = sub.add_parser(
        "dataset",
        help="export a recording to, or import one from, the authors' dataset layout",
        description=(
            "Convert between recordings (`splitrender render`, docs/recording-format.md) and "
            "the dataset layout of the paper's reference implementation (docs/dataset-format.md: "
            "per camera a directory with cam.json, color/NNNN.png, depth/NNNN.exr, "
            "forward/backwardFlowField/NNNN.exr and the forward/backward shadow PNGs; the client "
            "cameras and ground truth in a client directory). See `splitrender dataset export "
            "--help` and `splitrender dataset import --help`."
        ),
    )
    dsub = ds.add_subparsers(dest="dataset_command", metavar="ACTION", parser_class=type(ds))
    dsub.required = True
    ex = dsub.add_parser(
        "export",
        help="write a recording in the authors' dataset layout",
        description=(
            "Write the recording REC in the authors' dataset layout under DIR (created; it must "
            "not exist or be empty), as splitrender.export_dataset does: the main camera in "
            "DIR/main/, our auxiliary cameras in DIR/<--aux-names>/, the client's cameras and "
            "ground truth (the left eye of a stereo recording) in DIR/<--client>/. Depth and "
            "motion are written as half floats (relative error <= 2^-11); colours, shadow bits "
            "and matrices are exact. The rates go to every cam.json (serverFps, shadowFps = "
            "serverFps x subframes, clientFps); the scene name, scale and client motion of the "
            "manifest are not part of the layout."
        ),
    )
    ex.set_defaults(run=export)
    ex.add_argument("recording", metavar="REC", type=Path, help="recording directory")
    ex.add_argument("--out", type=Path, required=True, metavar="DIR",
                    help="dataset directory to write (missing or empty)")
    _add_layout_options(ex, "--aux-names")
    im = dsub.add_parser(
        "import",
        help="read a dataset in the authors' layout into a recording",
        description=(
            "Read the dataset in the authors' layout under DIR, as splitrender.import_dataset "
            "does (main camera in DIR/main/, the two auxiliary cameras --aux, the client cameras "
            "and ground truth in --client; converted to our conventions, see "
            "docs/dataset-format.md), and write it as the recording REC, which `splitrender "
            "play`, `encode` and the API read like a rendered one. Server frame k is at "
            "k / serverFps, client frame n at n / clientFps; the recording lasts N / clientFps "
            "s for the N client frames whose times lie before the last server frame's, so that "
            "every client frame has a pair. Its manifest says scene = the folder's name, "
            "variant 'dataset', client_motion {source: 'dataset'}, samples 1 (unknown) and the "
            "scale, near and far derived from the main camera (width / 2560, its projection). "
            "Buffers the layout has no slot for (frame 0's backward ones) are zero: no motion, "
            "no shadow change. The client directory must have color/ (the ground truth) and "
            "the client cameras the main camera's size. REC is written as REC.partial-<pid> and "
            "renamed when complete."
        ),
    )
    im.set_defaults(run=import_)
    im.add_argument("dataset", metavar="DIR", type=Path, help="dataset directory")
    im.add_argument("--out", type=Path, required=True, metavar="REC",
                    help="recording directory to write")
    im.add_argument("--force", action="store_true", help="replace REC if it exists")
    _add_layout_options(im, "--aux")


def _add_layout_options(p: Any, aux_flag: str) -> None:
    p.add_argument(aux_flag, type=names, default=_AUX, metavar="LIST",
                   help="the directories of the two auxiliary cameras, in rig order "
                   f"(default: {','.join(_AUX)})")
    p.add_argument("--client", default=_CLIENT, metavar="NAME",
                   help="the directory of the client cameras (cam.json) and ground truth "
                   "(color/) (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def export(args: argparse.Namespace) -> int:
    from splitrender.scene.dataset import export_dataset
    from splitrender.scene.recording import load_recording

    bar = Progress(1, not args.quiet)
    try:
        rec = load_recording(args.recording)
        bar.stage(f"exporting {len(rec.server_frames)} server frames and "
                  f"{len(rec.client_frames)} client frames of {args.recording} into {args.out}")
        out = export_dataset(rec, args.out, aux_names=tuple(args.aux_names), client=args.client)
    except SplitRenderError as e:
        return fail(str(e))
    finally:
        bar.close()
    print(f"wrote {out}/ in {bar.elapsed():.1f} s")
    return 0


def import_(args: argparse.Namespace) -> int:
    bar = Progress(2, not args.quiet)
    try:
        out = import_recording(args.dataset, args.out, aux=tuple(args.aux), client=args.client,
                               overwrite=args.force, stages=bar)
    except SplitRenderError as e:
        return fail(str(e))
    finally:
        bar.close()
    print(f"wrote {out}/ in {bar.elapsed():.1f} s")
    return 0


def _near_far(proj: npt.NDArray[np.float64]) -> tuple[float, float]:
    """Near and far planes of a reversed-Z perspective projection (``z' = A z + B``,
    ``near = B / (1 + A)``, ``far = B / A``); 0.1 / 1000 when they cannot be read from it."""
    a, b = float(proj[2, 2]), float(proj[2, 3])
    near = b / (1.0 + a) if 1.0 + a != 0 else math.nan
    far = b / a if a != 0 else math.inf
    if not (math.isfinite(near) and near > 0):
        near = 0.1
    if not (math.isfinite(far) and far > near):
        far = 1000.0
    return near, far


def import_recording(
    in_dir: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    aux: Sequence[str] = _AUX,
    client: str = _CLIENT,
    overwrite: bool = False,
    stages: Progress | None = None,
) -> Path:
    """Reads the dataset in the authors' layout under ``in_dir`` (:func:`import_dataset`) and
    writes it as a recording to ``out`` (see ``splitrender dataset import --help``); returns
    ``out``. ``stages`` gets two stages (reading, writing).

    Raises:
        DatasetError: the dataset cannot be read or cannot be a recording (not two auxiliary
            cameras, no ground truth, a client size other than the main camera's).
        RecordingError: ``out`` exists (without ``overwrite``).
    """
    from splitrender.scene.dataset import DatasetError, dataset_info, import_dataset
    from splitrender.scene.recording import (
        FORMAT,
        VERSION,
        RecordingError,
        _npz_bytes,
        _server_arrays,
        plan,
    )
    from splitrender._native import __version__
    from splitrender.types import CameraFrame, ServerFrame, ShadowBuffers

    root, dest = Path(in_dir), Path(out)
    if len(aux) != 2:
        raise DatasetError(f"--aux: a recording has two auxiliary cameras, got {len(aux)}")
    if dest.exists() and not overwrite:
        raise RecordingError(f"{dest}: already exists (choose another --out or pass --force)")
    if stages is not None:
        stages.stage(f"reading the dataset {root}")
    data = import_dataset(root, aux, client)
    info = dataset_info(root, client)
    fs, fc = info.server_fps, info.client_fps
    if not data.client_requests or any(t is None for t in data.ground_truth):
        raise DatasetError(f"{root / client}/color: missing; a recording needs the ground truth")
    w, h = data.server_frames[0].main.camera.width, data.server_frames[0].main.camera.height
    cw, ch = data.client_requests[0].camera.width, data.client_requests[0].camera.height
    if (cw, ch) != (w, h):
        raise DatasetError(f"{root / client}/cam.json: client size {cw}x{ch}, a recording "
                           f"needs the main camera's {w}x{h}")
    n_server = len(data.server_frames)
    n_client = len(data.client_requests)
    while n_client > 0 and plan(n_client / fc, fs, fc)[0] > n_server:
        n_client -= 1
    if n_client == 0:
        raise DatasetError(f"{root}: no client frame lies between two server frames")

    def filled(cf: CameraFrame) -> CameraFrame:
        cw, ch = cf.camera.width, cf.camera.height
        zero3 = np.zeros((ch, cw, 3), np.float32)
        no_shadow = ShadowBuffers(np.zeros((ch, cw), np.uint32), np.zeros((ch, cw, 3), np.uint8),
                                  np.zeros((ch, cw, 3), np.uint8))
        return CameraFrame(
            cf.camera, cf.color, cf.depth,
            zero3 if cf.motion_fwd is None else cf.motion_fwd,
            zero3 if cf.motion_bwd is None else cf.motion_bwd,
            no_shadow if cf.shadow_fwd is None else cf.shadow_fwd,
            no_shadow if cf.shadow_bwd is None else cf.shadow_bwd,
        )

    tmp = dest.with_name(f"{dest.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    total = n_server + n_client
    bar: Callable[[int, int, str], None] = (lambda d, t, u: None) if stages is None else stages.bar
    if stages is not None:
        stages.stage(f"writing {n_server} server frames and {n_client} client frames into {dest}")
    try:
        (tmp / "server").mkdir(parents=True)
        (tmp / "client").mkdir()

        def entry(kind: str, index: int, time: float, blob: bytes) -> dict[str, Any]:
            rel = f"{kind}/{index:06d}.npz"
            (tmp / rel).write_bytes(blob)
            return {"index": index, "time": time, "file": rel, "bytes": len(blob),
                    "sha256": hashlib.sha256(blob).hexdigest()}

        server = []
        for k, f in enumerate(data.server_frames):
            full = ServerFrame(f.index, f.time, filled(f.main), tuple(filled(a) for a in f.aux))
            pose = np.linalg.inv(f.main.camera.view).astype(np.float64)
            server.append(entry("server", k, k / fs, _npz_bytes(_server_arrays(pose, full))))
            bar(k + 1, total, "frames")
        clients = []
        for n in range(n_client):
            cam = data.client_requests[n].camera
            truth = data.ground_truth[n]
            assert truth is not None
            arrays: list[tuple[str, Any]] = [("pose", np.linalg.inv(cam.view)),
                                             ("eye0.view", cam.view), ("eye0.proj", cam.proj),
                                             ("eye0.color", truth)]
            clients.append(entry("client", n, n / fc, _npz_bytes(arrays)))
            bar(n_server + n + 1, total, "frames")
        near, far = _near_far(data.server_frames[0].main.camera.proj)
        manifest = {
            "format": FORMAT,
            "version": VERSION,
            "generator": f"splitrender {__version__} (dataset import)",
            "scene": root.resolve().name,
            "variant": "dataset",
            "scale": w / 2560,
            "fs": fs,
            "fc": fc,
            "subframes": min(16, info.subframes),
            "seconds": n_client / fc,
            "stereo": False,
            "samples": {"main": 1, "aux": 1, "client": 1},
            "near": near,
            "far": far,
            "cameras": {
                "main": [w, h],
                "aux": [[a.camera.width, a.camera.height] for a in data.server_frames[0].aux],
                "client": [w, h],
                "eyes": 1,
            },
            "client_motion": {"source": "dataset", "dir": str(root)},
            "server_frames": server,
            "client_frames": clients,
        }
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n",
                                           encoding="utf-8")
        if dest.exists():
            old = dest.with_name(f"{dest.name}.old-{os.getpid()}")
            dest.rename(old)
            tmp.rename(dest)
            shutil.rmtree(old)
        else:
            tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
