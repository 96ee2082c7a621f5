"""Peak memory (RSS) of one score task's work: ``ours`` played over a recording's left eye and
scored (SSIM, PSNR, VMAF), the way the sweep does it now (``new``: lazy server frames and ground
truths, each client frame scored as it is made, no images kept) or the way it did before
(``old``: every server frame, ground truth and client frame held until the end). Both print the
same metrics.

With ``--bitrate MBPS`` the server frames are encoded first (the packets are held, as the
sweep's stream file) and played from the decoder: ``new`` decodes each when the client needs it
(``DecodedStream``); ``old`` and ``decoded`` (``new`` otherwise, the sweep of 2026-12-03 to
12-05) hold the whole run decoded (``decode_packets``).

    python scripts/score_memory.py RECORDING new|old [--bitrate 10]
    python scripts/score_memory.py RECORDING decoded --bitrate 10
"""

from __future__ import annotations

import argparse
import resource
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from splitrender.codec.coder import CodecConfig, DecodedStream, decode_packets
from splitrender.evaluation.pipeline import encode_packets, play_and_score_eyes
from splitrender.net.model import NetworkModel
from splitrender.scene.recording import load_recording
from splitrender.types import ReprojectOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("way", choices=("new", "old", "decoded"))
    ap.add_argument("--bitrate", type=float, default=None, help="encode at MBPS first")
    a = ap.parse_args()
    rec = load_recording(a.recording)
    old = a.way == "old"
    cams, truth = rec.eye(0)
    server: Iterable[Any] = rec.server_frames
    sizes = None
    if a.bitrate is not None:
        packets, _ = encode_packets(server, CodecConfig(bitrate_mbps=a.bitrate), rec.fs)
        sizes = [len(p) for p in packets]
        server = DecodedStream(packets) if a.way == "new" else decode_packets(packets)
    if old:
        truth, server = list(truth), list(server)
    t0 = time.monotonic()
    [s] = play_and_score_eyes(
        server, [cams], [truth], "ours", NetworkModel(client_fps=rec.fc), rec.fc,
        ("ssim", "psnr", "vmaf"), keep_images=old, frame_sizes=sizes,
        options=ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes),
    )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    means = {k: round(v, 4) for k, v in s.metrics.mean.items()}
    print(f"{a.way}: peak RSS {peak_mb} MB; {means}; {time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()
