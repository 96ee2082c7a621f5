"""The codec on a built-in scene (issue 4): the achieved total bitrate within ±10 % of the target at
the paper's 20/40/80 Mb/s scaled by pixel count, and `ours` on decoded server frames at the
default bitrate close to `ours` on the uncompressed ones.

Scene: ``courtyard`` dynamic at scale 0.2 (main camera 512x288, auxiliary cameras 256x144), 20
server frames at 10 FPS (2 s, two GOPs of 10). Figures and their discussion are in
docs/codec-results.md; run with ``-s`` to print them.

Scale 0.2 rather than 0.125: at 320x180 the paper's 20 Mb/s scales to 0.3125 Mb/s, and the parts
no rate control can shrink (packet headers and camera records, plus the lossless static-motion
masks and shadow bitfields) took most of it with stream format 1 (+24 %). That is a fixed-cost
floor of the format, not a rate-control error (docs/codec-results.md)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
import splitrender as sr
from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.evaluation.metrics import psnr, ssim
from splitrender.codec.stream import stream_stats

pytestmark = pytest.mark.slow  # ~20-35 s of rendering at 2 cores, then 5-12 s per encode

SCENE = "courtyard"
SCALE = 0.2
N_SERVER = 20  # 2 s at 10 FPS: two GOPs, so the key-frame rate feedback acts once
CLIENT_FPS = 30.0  # α in {0, 1/3, 2/3}; 120 Hz would only add more of the same α values
N_CLIENT = 30  # client frames 0 .. 29 (0 .. 0.97 s): server frames 0 .. 10


@pytest.fixture(scope="module")
def scene() -> sr.Scene:
    return sr.Scene(SCENE, "dynamic")


@pytest.fixture(scope="module")
def frames(scene: sr.Scene) -> list[sr.ServerFrame]:
    return [scene.server_frame(k, SCALE) for k in range(N_SERVER)]


Encoded = dict[float, tuple[CodecConfig, list[bytes]]]


@pytest.fixture(scope="module")
def encoded() -> Encoded:
    """Streams already encoded in this module, by paper Mb/s (the default-rate stream serves
    both tests)."""
    return {}


def _encode(
    frames: list[sr.ServerFrame], paper_mbps: float, cache: Encoded
) -> tuple[CodecConfig, list[bytes]]:
    """The packets of all ``frames`` at the paper's ``paper_mbps`` scaled by pixel count."""
    if paper_mbps not in cache:
        w, h = frames[0].main.camera.width, frames[0].main.camera.height
        cfg = CodecConfig.scaled(w, h, paper_mbps)
        with StreamEncoder(cfg) as enc:
            cache[paper_mbps] = (cfg, [enc.encode(f) for f in frames])
    return cache[paper_mbps]


@pytest.mark.parametrize("paper_mbps", [20.0, 40.0, 80.0])
def test_bitrate_within_ten_percent_on_builtin_scene(
    frames: list[sr.ServerFrame], encoded: Encoded, paper_mbps: float
) -> None:
    """Measured (courtyard dynamic, 512x288, 20 frames, stream format 4): 20 -> 0.80 Mb/s
    target, 0.8357 achieved (+4.5 %); 40 -> 1.6, 1.6090 (+0.6 %); 80 -> 3.2, 3.1777 (-0.7 %).
    The ±10 % asserted (issue 13's requirement) is about twice the worst of them. (Format 3:
    +1.1 %, +0.8 %, -0.7 %.)"""
    w, h = frames[0].main.camera.width, frames[0].main.camera.height
    cfg, packets = _encode(frames, paper_mbps, encoded)
    stats = stream_stats(packets, cfg.fps)
    got = stats.mbps_total()
    err = got / cfg.bitrate_mbps - 1
    print(
        f"\n{SCENE} {w}x{h}, paper {paper_mbps:g} Mb/s: target {cfg.bitrate_mbps:.4f} Mb/s, "
        f"achieved {got:.4f} Mb/s ({err:+.1%})\n{stats.format()}"
    )
    assert abs(err) <= 0.10, (
        f"{SCENE} {w}x{h} at paper {paper_mbps:g} Mb/s: achieved {got:.4f} Mb/s vs target "
        f"{cfg.bitrate_mbps:.4f} Mb/s ({err:+.1%})"
    )


def _scores(
    images: list[npt.NDArray[np.uint8]], gts: list[npt.NDArray[np.uint8]]
) -> tuple[float, float]:
    """Mean PSNR (dB) and mean SSIM over the client frames."""
    p = [psnr(a, g) for a, g in zip(images, gts)]
    s = [ssim(a, g) for a, g in zip(images, gts)]
    return float(np.mean(p)), float(np.mean(s))


def test_ours_on_decoded_close_to_uncompressed_on_builtin_scene(
    scene: sr.Scene, frames: list[sr.ServerFrame], encoded: Encoded
) -> None:
    """Client frames 0..29 at 30 Hz (ideal network), `ours`, against the client's ground truth,
    at the default bitrate (the paper's 40 Mb/s scaled: 1.6 Mb/s at 512x288).

    Measured (stream format 3): uncompressed PSNR 30.54 dB / SSIM 0.8928, decoded 29.63 dB /
    0.8590 (mean drop 0.90 dB and 0.034; worst single frame 1.12 dB). The reprojection error of
    `ours` itself (disocclusions, shadows) is part of both; SSIM sees the codec's loss of fine
    texture. Asserted: mean PSNR drop <= 1.0 dB, every frame's drop <= 1.5 dB (1.1x and 1.3x the
    measured figures), mean SSIM drop <= 0.07 (2x)."""
    w, h = frames[0].main.camera.width, frames[0].main.camera.height
    n = int(N_CLIENT / CLIENT_FPS * 10) + 2  # up to the frame after the last client time
    used = frames[:n]
    cfg, packets = _encode(frames, 40.0, encoded)  # CodecConfig.scaled's default: paper 40 Mb/s
    assert cfg == CodecConfig.scaled(w, h)
    packets = packets[:n]
    with StreamDecoder() as decoder:
        decoded = [decoder.decode(p) for p in packets]
    gt_views = [scene.client_frames(n, SCALE, fc=CLIENT_FPS)[0] for n in range(N_CLIENT)]
    cameras = [c for c, _ in gt_views]
    gts = [img for _, img in gt_views]
    raw = sr.play(used, cameras, fps=CLIENT_FPS, method="ours")
    dec = sr.play(
        decoded,
        cameras,
        fps=CLIENT_FPS,
        method="ours",
        frame_sizes=[len(p) for p in packets],
    )
    assert raw.modes() == dec.modes()
    p_raw, s_raw = _scores(raw.images, gts)
    p_dec, s_dec = _scores(dec.images, gts)
    drops = [psnr(a, g) - psnr(b, g) for a, b, g in zip(raw.images, dec.images, gts)]
    stats = stream_stats(packets, cfg.fps)
    print(
        f"\n{SCENE} {w}x{h}, {cfg.bitrate_mbps:.4f} Mb/s target, {stats.mbps_total():.4f} "
        f"achieved over {len(packets)} frames; ours vs ground truth over {N_CLIENT} client "
        f"frames at {CLIENT_FPS:g} Hz ({raw.summary()}):\n"
        f"  uncompressed PSNR {p_raw:.2f} dB SSIM {s_raw:.4f}\n"
        f"  decoded      PSNR {p_dec:.2f} dB SSIM {s_dec:.4f}\n"
        f"  PSNR drop mean {p_raw - p_dec:.2f} dB, worst frame {max(drops):.2f} dB"
    )
    assert p_raw - p_dec <= 1.0, (p_raw, p_dec)
    assert max(drops) <= 1.5, drops
    assert s_raw - s_dec <= 0.07, (s_raw, s_dec)
