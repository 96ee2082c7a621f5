"""Peak memory (RSS) of one score task's work: ``ours`` played over a recording's left eye and
scored (SSIM, PSNR, VMAF), the way the sweep does it now (``new``: lazy server frames and ground
truths, each client frame scored as it is made, no images kept) or the way it did before
(``old``: every server frame, ground truth and client frame held until the end). Both print the
same metrics.

    python scripts/score_memory.py RECORDING new
    python scripts/score_memory.py RECORDING old
"""

from __future__ import annotations

import argparse
import resource
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from splitrender.evaluation.pipeline import play_and_score_eyes
from splitrender.evaluation.sweep_tasks import _eye
from splitrender.net.model import NetworkModel
from splitrender.scene.recording import load_recording
from splitrender.types import ReprojectOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("way", choices=("new", "old"))
    a = ap.parse_args()
    rec = load_recording(a.recording)
    old = a.way == "old"
    cams, truth = _eye(rec, 0)
    server: Sequence[Any] = rec.server_frames
    if old:
        truth, server = list(truth), list(server)
    t0 = time.monotonic()
    [s] = play_and_score_eyes(
        server, [cams], [truth], "ours", NetworkModel(client_fps=rec.fc), rec.fc,
        ("ssim", "psnr", "vmaf"), keep_images=old,
        options=ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes),
    )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    means = {k: round(v, 4) for k, v in s.metrics.mean.items()}
    print(f"{a.way}: peak RSS {peak_mb} MB; {means}; {time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()
