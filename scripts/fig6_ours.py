"""Figure 6's ``ours`` curve alone, on a recording that already exists (a stream-format change
must show that quality at a given bit-rate did not drop; docs/codec-results.md).

``splitrender eval --bitrates`` also renders the recording and the timewarp and video-streaming
reference lines, and its cache keys hold a fingerprint of the code, so a before/after pair of
runs renders everything twice (about half an hour each on two cores). This runs only what a
codec change touches, with the very task functions ``eval`` runs (``encode_stream`` and
``score_play`` of :mod:`splitrender.evaluation.sweep_tasks`: same codec settings, same client
path, same metrics as Figure 6: SSIM, PSNR, VMAF, no FLIP), on one recording given by its
folder (e.g. ``OUT/recordings/courtyard-dynamic`` of an earlier ``eval``), so that "before" and
"after" see identical frames:

    python scripts/fig6_ours.py REC --bitrates 10,20,40,60,100 --out rows.json

Prints one line per bit-rate and writes the rows (paper Mb/s, target, achieved Mb/s, SSIM,
PSNR, VMAF) as JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import asdict
from pathlib import Path

from splitrender.codec.coder import CodecConfig
from splitrender.evaluation.pipeline import network_json
from splitrender.evaluation.sweep import Cache, Task
from splitrender.evaluation.sweep_tasks import encode_stream, score_play
from splitrender.files import write_atomic
from splitrender.net.model import NetworkModel
from splitrender.scene.recording import load_recording


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--bitrates", default="10,20,40,60,100",
                    help="paper-equivalent Mb/s at 2560x1440, comma-separated")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rec = load_recording(args.recording)
    w, h = rec.manifest["cameras"]["main"]
    net = network_json(NetworkModel(extra_delay_frames=0, client_fps=rec.fc))
    rows = []
    with tempfile.TemporaryDirectory(prefix="fig6-ours-") as tmp:
        cache = Cache(tmp)
        cache.prepare()
        paths = {"recording": str(args.recording)}
        for paper in sorted(float(b) for b in args.bitrates.split(",")):
            cc = CodecConfig.scaled(w, h, paper_mbps=paper)
            key = f"stream-{paper:g}"
            encode_stream(Task(key, "encode", "", {"codec": asdict(cc)}, ("rec",), paths), cache)
            info = json.loads(cache.stream_info(key).read_text())
            score = Task(f"ours-{paper:g}", "score", "", {
                "method": "ours", "eye": 0, "stream": True, "network": net,
                "metrics": ["ssim", "psnr", "vmaf"], "flip_every": 1, "backend": "cpu",
                "own_rates": False,
            }, ("rec", key), paths)
            score_play(score, cache)
            got = cache.read_row(score.key)
            row = {"paper_mbps": paper, "target_mbps": cc.bitrate_mbps,
                   "mbps": info["mbps"], "bytes": sum(info["sizes"]),
                   **{m: got[m] for m in ("ssim", "psnr", "vmaf", "frames")}}
            rows.append(row)
            print(f"paper {paper:g} Mb/s: target {cc.bitrate_mbps:.4g}, achieved "
                  f"{row['mbps']:.4g} ({100 * (row['mbps'] / cc.bitrate_mbps - 1):+.1f} %), "
                  f"SSIM {row['ssim']:.4f}, PSNR {row['psnr']:.2f} dB, VMAF {row['vmaf']:.2f}",
                  flush=True)
    write_atomic(args.out, json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
