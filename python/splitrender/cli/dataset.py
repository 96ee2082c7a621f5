"""``splitrender dataset export`` and ``import``: recordings to and from the authors' dataset layout."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from splitrender.cli.args import (
    add_out,
    add_quiet,
    command,
    in_path,
    names,
    run_stages,
    wrote_dir,
)
from splitrender.files import check_name
from splitrender.progress import Progress

__all__ = ["add"]

_AUX = ("left", "right")
_CLIENT = "client_ol"


def add(sub: Any) -> None:
    ds = command(sub, "dataset", None)
    dsub = ds.add_subparsers(dest="dataset_command", metavar="ACTION", parser_class=type(ds))
    dsub.required = True
    ex = command(dsub, "export", export, key="dataset export")
    ex.add_argument("recording", metavar="REC", type=in_path, help="recording directory")
    add_out(ex, "dataset directory to write (missing or empty)")
    _add_layout_options(ex, "--aux-names")
    im = command(dsub, "import", import_, key="dataset import")
    im.add_argument("dataset", metavar="DIR", type=in_path, help="dataset directory")
    add_out(im, "recording directory to write", "REC")
    im.add_argument("--force", action="store_true", help="replace REC if it exists")
    _add_layout_options(im, "--aux")


def _folder(text: str) -> str:
    """A camera folder's name (:func:`~splitrender.files.check_name`), refused here so that the
    message names the option, not the API's parameter."""
    try:
        return check_name(text, "", argparse.ArgumentTypeError)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix(": ")) from None


def _two_folders(text: str) -> tuple[str, ...]:
    """The two auxiliary cameras' folder names: a third name was ignored without a word."""
    got = names(text)
    if len(got) != 2:
        raise argparse.ArgumentTypeError(
            f"expected two names, the folders of the two auxiliary cameras in rig order; got "
            f"{len(got)}: {','.join(got)}"
        )
    return tuple(_folder(n) for n in got)


def _add_layout_options(p: argparse.ArgumentParser, aux_flag: str) -> None:
    p.add_argument(aux_flag, type=_two_folders, default=_AUX, metavar="LIST",
                   help="the directories of the two auxiliary cameras, in rig order "
                   f"(default: {','.join(_AUX)})")
    p.add_argument("--client", type=_folder, default=_CLIENT, metavar="NAME",
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
