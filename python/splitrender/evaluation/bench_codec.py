"""Benchmark of the codec: ``python -m splitrender.evaluation.bench_codec [--frames N] [--sizes 640x360,...]``.

For each main-camera size (two auxiliary cameras at half size, every buffer) it encodes and
decodes a run of the synthetic dynamic scene at the paper's 40 Mb/s scaled by pixel count and
prints: encode and decode milliseconds per server frame (mean over all frames, and over key /
non-key frames), the realtime factor at ``f_s`` (``1/f_s`` divided by the time per frame; >= 1 is
realtime), the achieved bitrate and its split, colour PSNR, depth and motion errors, and how many
static pixels would decode to exactly zero motion without the static mask. With ``--chroma`` it
also compares 4:4:4 and 4:2:0 colour at equal bitrate.

``--profile`` instead encodes the two server frames of ``splitrender bench`` (courtyard at
1280x720, cached in the temporary directory) at the paper's 40 Mb/s scaled and prints, per HEVC
picture of each packet, its pixels, pixel format, bytes and the CPU time of FFmpeg's decoding
alone (its own single-threaded decoder, median of 5), then the CPU and wall time of
``StreamDecoder.decode`` per server frame and the load average: where the decode time goes
(docs/codec-results.md, "Decode time").
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import av
import numpy as np

from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.codec.stream import Codec, stream_stats, unpack_packet
from splitrender.scene.synthetic import SyntheticScene
from splitrender.types import CameraFrame, ServerFrame


def _cams(f: ServerFrame) -> list[CameraFrame]:
    return [f.main, *f.aux]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)


def run(
    w: int, h: int, n: int, cfg: CodecConfig, frames: list[ServerFrame]
) -> dict[str, float]:
    enc_t, dec_t, keys = [], [], []
    packets, decoded = [], []
    with StreamEncoder(cfg) as enc, StreamDecoder() as dec:
        for f in frames:
            t0 = time.perf_counter()
            p = enc.encode(f)
            t1 = time.perf_counter()
            out = dec.decode(p)
            t2 = time.perf_counter()
            enc_t.append(t1 - t0)
            dec_t.append(t2 - t1)
            keys.append(f.index % cfg.gop == 0)
            packets.append(p)
            decoded.append(out)
    st = stream_stats(packets, cfg.fps)
    k = np.array(keys)
    e, d = np.array(enc_t) * 1e3, np.array(dec_t) * 1e3
    psnr, derr, merr = [], [], []
    for f, g in zip(frames, decoded):
        for a, b in zip(_cams(f), _cams(g)):
            psnr.append(_psnr(a.color, b.color))
            derr.append(float(np.abs(a.depth - b.depth).mean() / np.ptp(a.depth)))
            if a.motion_fwd is not None and b.motion_fwd is not None:
                span = np.ptp(a.motion_fwd.reshape(-1, 3), axis=0) + 1e-12
                merr.append(
                    float(
                        (
                            np.abs(a.motion_fwd - b.motion_fwd).reshape(-1, 3).mean(0)
                            / span
                        ).max()
                    )
                )
    return {
        "enc_ms": float(e.mean()),
        "enc_key_ms": float(e[k].mean()),
        "enc_p_ms": float(e[~k].mean()) if (~k).any() else float("nan"),
        "dec_ms": float(d.mean()),
        "dec_key_ms": float(d[k].mean()),
        "dec_p_ms": float(d[~k].mean()) if (~k).any() else float("nan"),
        "mbps": st.mbps_total(),
        "psnr": float(np.mean(psnr)),
        "depth_err": float(np.mean(derr)),
        "motion_err": float(np.mean(merr)),
        "stats": st,  # type: ignore[dict-item]
    }


def static_without_mask(frames: list[ServerFrame], cfg: CodecConfig) -> float:
    """Fraction of static pixels (motion exactly 0) that decode to exactly 0 without the mask."""
    hit = tot = 0
    with StreamEncoder(cfg) as enc, StreamDecoder() as dec:
        for f in frames:
            g = dec.decode(enc.encode(f))
            for a, b in zip(_cams(f), _cams(g)):
                for ma, mb in (
                    (a.motion_fwd, b.motion_fwd),
                    (a.motion_bwd, b.motion_bwd),
                ):
                    if ma is None or mb is None:
                        continue
                    s = (ma == 0).all(axis=2)
                    tot += int(s.sum())
                    hit += int((mb[s] == 0).all(axis=1).sum())
    return hit / max(tot, 1)


def profile(repeats: int = 5) -> None:
    """Where the decoding of one 1280x720 server frame goes (see the module docstring)."""
    from splitrender.codec.coder import _hevc_decoder
    from splitrender.evaluation.bench import _recording

    rec = _recording("courtyard", 0.5, print)
    f0, f1 = rec.server_frames[0], rec.server_frames[1]
    w, h = f0.main.camera.width, f0.main.camera.height
    cfg = CodecConfig.scaled(w, h)
    with StreamEncoder(cfg) as enc:
        packets = [enc.encode(f0), enc.encode(f1)]
    print(
        f"{w}x{h} + aux, {cfg.bitrate_mbps:g} Mb/s, chroma {cfg.chroma}; packets "
        f"{[len(p) for p in packets]} bytes"
    )
    print(
        f"{'picture':20} {'frame':>5} {'pixels':>9} {'format':10} {'bytes':>7} {'CPU ms':>7}"
    )
    cpu: dict[tuple[str, int], list[float]] = {}
    info: dict[tuple[str, int], tuple[int, str, int]] = {}
    for _ in range(repeats):
        decoders: dict[str, object] = {}
        for i, packet in enumerate(packets):
            for b in unpack_packet(packet).buffers:
                if b.codec != Codec.HEVC:
                    continue
                ctx = decoders.get(b.name)
                if ctx is None:
                    ctx = decoders[b.name] = _hevc_decoder(1 << 14, 1 << 13)
                t0 = time.thread_time()
                frame = ctx.decode(av.Packet(bytes(b.payload)))[0]  # type: ignore[attr-defined]
                cpu.setdefault((b.name, i), []).append(time.thread_time() - t0)
                info[(b.name, i)] = (
                    frame.width * frame.height,
                    frame.format.name,
                    len(b.payload),
                )
    totals = [0.0, 0.0]
    for (name, i), ts in cpu.items():
        px, fmt, n = info[(name, i)]
        ms = statistics.median(ts) * 1e3
        totals[i] += ms
        print(f"{name:20} {i:5} {px:9} {fmt:10} {n:7} {ms:7.2f}")
    print(
        f"FFmpeg decoding alone, CPU ms per frame: key {totals[0]:.1f}, other {totals[1]:.1f}"
    )
    walls, cpus = [], []
    for _ in range(repeats):
        with StreamDecoder() as dec:
            c0, t0 = time.process_time(), time.perf_counter()
            for p in packets:
                dec.decode(p)
            walls.append((time.perf_counter() - t0) / len(packets))
            cpus.append((time.process_time() - c0) / len(packets))
    print(
        f"StreamDecoder.decode per server frame (median of {repeats}, frames 0 and 1): wall "
        f"{statistics.median(walls) * 1e3:.1f} ms, CPU (all threads) "
        f"{statistics.median(cpus) * 1e3:.1f} ms; load average {os.getloadavg()}"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--sizes", default="640x360,1280x720")
    ap.add_argument("--paper-mbps", type=float, default=40.0)
    ap.add_argument("--preset", default=CodecConfig().preset)
    ap.add_argument(
        "--chroma", action="store_true", help="also compare 4:4:4 and 4:2:0"
    )
    ap.add_argument(
        "--profile",
        action="store_true",
        help="only the decode-time profile of two 1280x720 courtyard frames",
    )
    args = ap.parse_args(argv)
    if args.profile:
        profile()
        return
    print(
        f"cpus: {os.cpu_count()}, frames per run: {args.frames}, preset {args.preset}"
    )
    scene = SyntheticScene(dynamic=True)
    for size in args.sizes.split(","):
        w, h = (int(x) for x in size.split("x"))
        frames = [scene.server_frame(i, i / 10, w, h) for i in range(args.frames)]
        cfg = CodecConfig.scaled(w, h, args.paper_mbps, preset=args.preset)
        r = run(w, h, args.frames, cfg, frames)
        rt = (1000 / cfg.fps) / r["enc_ms"]
        print(
            f"\n{w}x{h} (+2x {w // 2}x{h // 2}), target {cfg.bitrate_mbps:.3f} Mb/s "
            f"(paper {args.paper_mbps:g} Mb/s scaled), gop {cfg.gop}, chroma {cfg.chroma}"
        )
        print(
            f"  encode {r['enc_ms']:.1f} ms/frame (key {r['enc_key_ms']:.1f}, other "
            f"{r['enc_p_ms']:.1f}); realtime factor at f_s={cfg.fps:g}: {rt:.2f}"
        )
        print(
            f"  decode {r['dec_ms']:.1f} ms/frame (key {r['dec_key_ms']:.1f}, other "
            f"{r['dec_p_ms']:.1f}); realtime factor: {(1000 / cfg.fps) / r['dec_ms']:.2f}"
        )
        print(
            f"  achieved {r['mbps']:.3f} Mb/s ({100 * (r['mbps'] / cfg.bitrate_mbps - 1):+.1f} %); "
            f"colour PSNR {r['psnr']:.2f} dB; mean |depth err| / range {r['depth_err']:.5f}; "
            f"mean |motion err| / range (worst channel) {r['motion_err']:.5f}"
        )
        print("  " + r["stats"].format().replace("\n", "\n  "))  # type: ignore[attr-defined]
        frac = static_without_mask(
            frames[: min(6, len(frames))],
            CodecConfig.scaled(
                w, h, args.paper_mbps, preset=args.preset, exact_static_motion=False
            ),
        )
        print(
            f"  without the static mask, {100 * frac:.3f} % of static pixels decode to exact 0"
        )
        if args.chroma:
            for chroma in ("444", "420"):
                c = CodecConfig.scaled(
                    w, h, args.paper_mbps, preset=args.preset, chroma=chroma
                )
                rc = run(w, h, args.frames, c, frames)
                print(
                    f"  chroma {chroma}: colour PSNR {rc['psnr']:.2f} dB at {rc['mbps']:.3f} Mb/s, "
                    f"encode {rc['enc_ms']:.1f} ms, decode {rc['dec_ms']:.1f} ms"
                )


if __name__ == "__main__":
    main()
