"""``splitrender dataset export`` and ``import``: recordings to and from the authors' dataset layout."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from splitrender.cli.args import add_out, add_quiet, command, names, run_stages, wrote_dir
from splitrender.progress import Progress

__all__ = ["add"]

_AUX = ("left", "right")
_CLIENT = "client_ol"


def add(sub: Any) -> None:
    ds = command(
        sub, "dataset", None,
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
    ex = command(
        dsub, "export", export,
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
    ex.add_argument("recording", metavar="REC", type=Path, help="recording directory")
    add_out(ex, "dataset directory to write (missing or empty)")
    _add_layout_options(ex, "--aux-names")
    im = command(
        dsub, "import", import_,
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
    im.add_argument("dataset", metavar="DIR", type=Path, help="dataset directory")
    add_out(im, "recording directory to write", "REC")
    im.add_argument("--force", action="store_true", help="replace REC if it exists")
    _add_layout_options(im, "--aux")


def _add_layout_options(p: argparse.ArgumentParser, aux_flag: str) -> None:
    p.add_argument(aux_flag, type=names, default=_AUX, metavar="LIST",
                   help="the directories of the two auxiliary cameras, in rig order "
                   f"(default: {','.join(_AUX)})")
    p.add_argument("--client", default=_CLIENT, metavar="NAME",
                   help="the directory of the client cameras (cam.json) and ground truth "
                   "(color/) (default: %(default)s)")
    add_quiet(p)


def export(args: argparse.Namespace) -> int:
    from splitrender.scene.dataset import export_dataset
    from splitrender.scene.recording import load_recording

    def work(bar: Progress) -> Path:
        rec = load_recording(args.recording)
        bar.stage(f"exporting {len(rec.server_frames)} server frames and "
                  f"{len(rec.client_frames)} client frames of {args.recording} into {args.out}")
        return export_dataset(rec, args.out, aux_names=tuple(args.aux_names), client=args.client)

    return run_stages(1, args.quiet, work, wrote_dir)


def import_(args: argparse.Namespace) -> int:
    from splitrender.scene.dataset import import_dataset_as_recording

    return run_stages(
        2, args.quiet,
        lambda bar: import_dataset_as_recording(args.dataset, args.out, aux=tuple(args.aux),
                                                client=args.client, overwrite=args.force,
                                                stages=bar),
        wrote_dir,
    )
