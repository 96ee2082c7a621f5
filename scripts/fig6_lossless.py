"""Figure 6's ``ours`` points with the encoder's lossless parts itemised: per scene and
paper-equivalent bit-rate, the achieved rate, the lossless parts' and the colour picture's
rates, which cameras' shadow bitfields were left out (``CodecConfig.lossless_share``) in how
many frames, and SSIM / PSNR / VMAF of ``ours`` (l = 0, the ideal link) on the decoded frames.

    python scripts/fig6_lossless.py --scenes lab,courtyard --bitrates 10,20,40 \\
        --recordings DIR --out rows.json [--share 0.25]

Each scene's recording (dynamic, ``--scale``, ``--seconds``) is rendered into
``DIR/<scene>`` once and read from there by later runs, so that runs of two versions of the
code (e.g. before and after an encoder change, each from its own checkout) score the very same
frames. ``digest`` is the SHA-256 of the stream's packets: two runs with the same digest coded
the same bytes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import Any

import splitrender as sr
from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.codec.stream import stream_stats
from splitrender.evaluation.pipeline import play_and_score_eyes
from splitrender.files import write_atomic
from splitrender.net.model import NetworkModel
from splitrender.scene.recording import load_recording
from splitrender.types import ReprojectOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="lab,courtyard")
    ap.add_argument("--bitrates", default="10,20,40",
                    help="paper-equivalent Mb/s at 2560x1440, comma-separated")
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--share", type=float, default=None,
                    help="CodecConfig.lossless_share (default: the encoder's own default)")
    ap.add_argument("--recordings", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    rows: list[dict[str, Any]] = []
    for scene in a.scenes.split(","):
        path = a.recordings / scene
        if not path.exists():
            sr.write_recording(path, scene, variant="dynamic", seconds=a.seconds, scale=a.scale)
        rec = load_recording(path)
        cams, truth = rec.eye(0)
        w, h = cams[0].width, cams[0].height
        for paper in (float(r) for r in a.bitrates.split(",")):
            extra = {} if a.share is None else {"lossless_share": a.share}
            cfg = CodecConfig.scaled(w, h, paper, **extra)
            packets, decoded, left_out = [], [], []
            with StreamEncoder(cfg) as enc, StreamDecoder() as dec:
                for f in rec.server_frames:
                    packets.append(enc.encode(f))
                    # (getattr: the same script runs on code from before the field existed)
                    left_out.append(getattr(enc.last, "shadows_left_out", ()))
                    decoded.append(dec.decode(packets[-1]))
            stats = stream_stats(packets, rec.fs)
            by = stats.mbps_by_buffer()
            [scored] = play_and_score_eyes(
                decoded, [cams], [truth], "ours", NetworkModel(client_fps=rec.fc), rec.fc,
                ["ssim", "psnr", "vmaf"], frame_sizes=[len(p) for p in packets],
                options=ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes),
                keep_images=False)
            score = scored.row()
            row = {
                "scene": scene, "paper_mbps": paper, "target_mbps": cfg.bitrate_mbps,
                "mbps": stats.mbps_total(),
                "lossless_mbps": sum(v for k, v in by.items() if not k.startswith("picture.")),
                "colour_mbps": by.get("picture.color", 0.0),
                "left_out": sorted({c for lo in left_out for c in lo}),
                "frames_left_out": sum(1 for lo in left_out if lo),
                **{m: score[m] for m in ("ssim", "psnr", "vmaf")},
                "digest": hashlib.sha256(b"".join(packets)).hexdigest()[:16],
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    write_atomic(a.out, json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
