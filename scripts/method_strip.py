"""Side-by-side images of the methods at chosen client frames of a recording: what the tables'
numbers look like.

For each requested client frame ``n`` one PNG: the ground truth, then each method's client
frame, and below each method its per-pixel error against the ground truth (the largest
absolute difference of the three channels, ×4, as grey). Every method plays the recording's
left eye uncompressed over the ideal link (Table 1's setting; the frames are the ones its rows
score), from the start up to the last requested frame. A crop (``--crop x,y,w,h`` in pixels of
the client frame) keeps full resolution where the eye should look; without one the whole frame
is written at ``--zoom`` (default ½) of its size.

    python scripts/method_strip.py REC --frames 54,150 --out docs/results-720p/courtyard/frames

Writes ``OUT/frame_NNNN.png`` and ``OUT/frames.json`` (the recording's scene, variant, scale
and length; per frame each method's mode, α, the server frames used and its PSNR on the frame).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image, ImageDraw

from splitrender.client.playback import play
from splitrender.evaluation.metrics import psnr
from splitrender.files import write_atomic
from splitrender.scene.recording import load_recording
from splitrender.types import ReprojectOptions

METHODS = "ours,ours_extrapolate,timewarp,forward_splat,backward_bidir"
LABEL_H = 18


def _crop(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    parts = [int(v) for v in text.split(",")]
    if len(parts) != 4 or min(parts) < 0 or parts[2] == 0 or parts[3] == 0:
        raise SystemExit(f"--crop: expected x,y,w,h (pixels, w and h > 0), got {text!r}")
    return parts[0], parts[1], parts[2], parts[3]


def _tile(img: npt.NDArray[np.uint8], label: str, crop: tuple[int, int, int, int] | None,
          zoom: float) -> Image.Image:
    h, w = img.shape[:2]
    if crop is not None:
        x, y, cw, ch = crop
        if x + cw > w or y + ch > h:
            raise SystemExit(f"--crop {x},{y},{cw},{ch} reaches outside the {w}x{h} frame")
        im = Image.fromarray(np.ascontiguousarray(img[y:y + ch, x:x + cw]))
    else:
        im = Image.fromarray(img).resize((max(1, round(w * zoom)), max(1, round(h * zoom))),
                                         Image.Resampling.BOX)
    out = Image.new("RGB", (im.width, im.height + LABEL_H), "white")
    out.paste(im, (0, LABEL_H))
    ImageDraw.Draw(out).text((4, 3), label, fill="black")
    return out


def _error(img: npt.NDArray[np.uint8], truth: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    e = np.abs(img.astype(np.int16) - truth.astype(np.int16)).max(axis=-1)
    g = np.clip(e * 4, 0, 255).astype(np.uint8)
    return np.repeat(g[..., None], 3, axis=-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--frames", required=True, help="client frame indices, comma-separated")
    ap.add_argument("--methods", default=METHODS, help=f"comma-separated (default {METHODS})")
    ap.add_argument("--crop", help="x,y,w,h in client-frame pixels (default: the whole frame)")
    ap.add_argument("--zoom", type=float, default=0.5,
                    help="scale of the whole frame when there is no crop (default 0.5)")
    ap.add_argument("--out", type=Path, required=True, help="output directory")
    a = ap.parse_args()

    rec = load_recording(a.recording)
    wanted = sorted({int(v) for v in a.frames.split(",")})
    n_client = len(rec.client_frames)
    if not wanted or wanted[0] < 0 or wanted[-1] >= n_client:
        raise SystemExit(f"--frames: expected indices in 0..{n_client - 1}, got {a.frames!r}")
    if not (math.isfinite(a.zoom) and 0 < a.zoom <= 1):
        raise SystemExit(f"--zoom: expected a number in (0, 1], got {a.zoom}")
    crop = _crop(a.crop)
    methods = [m for m in a.methods.split(",") if m]
    cams = [c.cameras[0] for c in rec.client_frames[: wanted[-1] + 1]]
    options = ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes)

    shots: dict[str, dict[int, tuple[npt.NDArray[np.uint8], Any]]] = {}
    for m in methods:
        got: dict[int, tuple[npt.NDArray[np.uint8], Any]] = {}

        def keep(n: int, image: npt.NDArray[np.uint8], info: Any,
                 got: dict[int, tuple[npt.NDArray[np.uint8], Any]] = got) -> None:
            if n in wanted:
                got[n] = (np.array(image, copy=True), info)

        play(rec.server_frames, cams, None, rec.fc, m, options=options, keep_images=False,
             on_frame=keep)
        shots[m] = got
        print(f"{m}: played {len(cams)} client frames")

    a.out.mkdir(parents=True, exist_ok=True)
    manifest = json.loads((a.recording / "manifest.json").read_text(encoding="utf-8"))
    meta: dict[str, Any] = {
        "recording": {k: manifest.get(k) for k in ("scene", "variant", "scale", "seconds")},
        "eye": "left", "link": "ideal, uncompressed", "crop": crop, "frames": {},
    }
    for n in wanted:
        truth = rec.client_frames[n].ground_truths[0]
        top = [_tile(truth, f"ground truth, frame {n}", crop, a.zoom)]
        bottom = [_tile(np.full_like(truth, 255), "", crop, a.zoom)]
        meta["frames"][str(n)] = {}
        for m in methods:
            img, info = shots[m][n]
            p = psnr(img, truth)
            top.append(_tile(img, f"{m} ({info.mode}, PSNR {p:.1f} dB)", crop, a.zoom))
            bottom.append(_tile(_error(img, truth), f"{m} |error| x4", crop, a.zoom))
            meta["frames"][str(n)][m] = {"mode": info.mode, "alpha": info.alpha,
                                         "older": info.older, "newer": info.newer, "psnr": p}
        tw, th = top[0].width, top[0].height
        sheet = Image.new("RGB", (tw * len(top), 2 * th), "white")
        for i, (t, b) in enumerate(zip(top, bottom)):
            sheet.paste(t, (i * tw, 0))
            sheet.paste(b, (i * tw, th))
        path = a.out / f"frame_{n:04d}.png"
        tmp = path.with_suffix(".png.part")
        sheet.save(tmp, format="PNG", optimize=True)
        tmp.replace(path)
        print(f"wrote {path}")
    write_atomic(a.out / "frames.json", json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
