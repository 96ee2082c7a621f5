"""``splitrender example``: every method on one client frame of the analytic synthetic scene."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.cli.args import add_out, command, side
from splitrender.files import OutputFolder
from splitrender.imageio import montage, write_png
from splitrender.reproject import METHODS, reproject
from splitrender.scene.synthetic import SyntheticScene
from splitrender.types import ClientRequest


def add(sub: Any) -> None:
    ex = command(sub, "example", run)
    add_out(ex, "output directory, created if missing (default: %(default)s)",
            default=Path("splitrender-out"))
    ex.add_argument(
        "--width", type=side, default=640, metavar="W", help="main camera width (default: 640)"
    )
    ex.add_argument(
        "--height",
        type=side,
        default=360,
        metavar="H",
        help="main camera height (default: 360)",
    )
    ex.add_argument(
        "--static",
        action="store_true",
        help="freeze the moving objects (default: dynamic scene)",
    )


def _progress(step: int, total: int, text: str) -> None:
    print(f"[{step}/{total}] {text}", flush=True)


def run(args: argparse.Namespace) -> int:
    # The PNGs are moved into OUT together once all are made (montage.png last): an interrupted
    # run leaves the previous ones.
    outputs = OutputFolder(args.out, ("ground_truth.png", *(f"{m}.png" for m in METHODS),
                                      "montage.png"))
    with outputs as stage:
        lines = _run(args, stage)
    print("\n".join(lines))
    return 0


def _run(args: argparse.Namespace, out: Path) -> list[str]:
    """The example, its PNGs written into ``out``; returns the lines to print."""
    fps, client_fps, n = 10.0, 120.0, 7
    t = n / client_fps
    scene = SyntheticScene(dynamic=not args.static)
    total = 3 + len(METHODS)
    t0 = time.perf_counter()
    _progress(1, total, f"rendering server frame 0 (t = 0.000 s) at {args.width}x{args.height}")
    f0 = scene.server_frame(0, 0.0, args.width, args.height, fps=fps)
    _progress(2, total, f"rendering server frame 1 (t = {1 / fps:.3f} s)")
    f1 = scene.server_frame(1, 1.0 / fps, args.width, args.height, fps=fps)
    _progress(3, total, f"rendering ground truth at the client pose (t = {t:.4f} s)")
    # The client's actual head deviates from the path the server rendered (a prediction error).
    camera = scene.client_camera(t, args.width, args.height)
    truth = scene.ground_truth(camera, t)
    write_png(out / "ground_truth.png", truth)
    request = ClientRequest(camera, t)
    images = [truth]
    results: list[tuple[str, float, float, float]] = []
    for k, method in enumerate(METHODS):
        _progress(4 + k, total, f"reprojecting with {method}")
        start = time.perf_counter()
        r = reproject(f0, f1, request, method, diagnostics=True)
        ms = (time.perf_counter() - start) * 1e3
        mae = float(np.abs(r.image.astype(np.int16) - truth.astype(np.int16)).mean())
        coverage = float(r.matched.mean())
        write_png(out / f"{method}.png", r.image)
        images.append(r.image)
        results.append((method, mae, coverage, ms))
    labels = ["ground truth", *(f"{m}  MAE {mae:.2f}" for m, mae, _, _ in results)]
    write_png(out / "montage.png", montage(images, columns=3, labels=labels))
    return [
        f"done in {time.perf_counter() - t0:.1f} s; wrote {len(images) + 1} PNGs to {args.out}/",
        f"montage.png, row by row: ground_truth, {', '.join(METHODS)} (each captioned)",
        f"client frame {n} at t = {t:.4f} s (alpha = {t * fps:.3f}); MAE against ground truth:",
        f"  {'method':<18} {'MAE':>7} {'matched':>8} {'time':>9}",
        *(f"  {method:<18} {mae:7.2f} {coverage:8.1%} {ms:7.1f} ms"
          for method, mae, coverage, ms in results),
        "time: one stand-alone call; ours's includes preparing the server-frame pair (done once",
        "per pair by a client; `splitrender bench` times the display frames after it)",
    ]


