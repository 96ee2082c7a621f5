"""Benchmark of the codec (its command line: ``python -m splitrender.cli.bench_codec [--frames N]
[--sizes 640x360,...]``).

For each main-camera size (two auxiliary cameras at half size, every buffer) it encodes and
decodes a run of the synthetic dynamic scene at the paper's 40 Mb/s scaled by pixel count and
prints: encode and decode milliseconds per server frame (mean over all frames, and over key /
non-key frames), the realtime factor at ``f_s`` (``1/f_s`` divided by the time per frame; >= 1 is
realtime), the achieved bitrate and its split, colour PSNR, depth and motion errors, and how many
static pixels would decode to exactly zero motion without the static mask (:func:`report`). With
``--chroma`` it also compares 4:4:4 and 4:2:0 colour at equal bitrate.

``--profile`` (:func:`profile`) instead encodes the two server frames of ``splitrender bench``
(courtyard at 1280x720, cached in the temporary directory) at the paper's 40 Mb/s scaled and
prints where the decode time goes (docs/performance.md, "Codec"), as minima of CPU time over
repeated runs: per HEVC picture of each packet its size, pixel format, bytes and FFmpeg's
decoding alone (a new decoder, and one kept across frames as a client's is);
``StreamDecoder.decode`` on one thread per step (FFmpeg, colour conversion, copies,
dequantisation, lossless parts); and the CPU and wall time of ``StreamDecoder.decode`` per
server frame with its default threads, the key frame's and the other's apart.
"""

from __future__ import annotations

import os
import statistics
import time
from typing import Any

import av
import numpy as np

from splitrender.codec.coder import (
    CodecConfig,
    StreamDecoder,
    StreamEncoder,
)
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


#: The steps of ``StreamDecoder.decode`` that ``--profile`` times: part of the name cProfile
#: gives each function (``file:function``), or a tuple of such parts.
_STEPS: dict[str, str | tuple[str, ...]] = {
    "FFmpeg HEVC decoding": "method 'decode' of 'av.codec.context.CodecContext'",
    "colour picture to RGB (swscale)": "method 'reformat' of 'av.video.frame.VideoFrame'",
    "colour tiles into the client's arrays": ("copyto", "method 'copy' of 'numpy.ndarray'"),
    "depth dequantisation (core)": "dequantise_depth",
    "motion dequantisation + 2x2 (core)": "dequantise_motion",
    "shadow colours at set bits (core)": "_native.shadow_colour>",
    "lossless masks and bitfields (zstd)": "coder.py:_lossless",
    "packet parsing and checks": "stream.py:unpack_packet",
    "total (StreamDecoder._decode)": "coder.py:_decode",
}


def _step_times(stats: dict[tuple[str, int, str], tuple[Any, ...]]) -> dict[str, float]:
    """Seconds per step of one cProfile run (``pstats.Stats.stats``), cumulative per function."""
    out = dict.fromkeys(_STEPS, 0.0)
    for (file, _, func), (_, _, _, cum, _) in stats.items():
        name = f"{file}:{func}"
        for step, parts in _STEPS.items():
            if any(p in name for p in ((parts,) if isinstance(parts, str) else parts)):
                out[step] += cum
    return out


def profile(repeats: int = 7) -> None:
    """Where the decoding of one 1280x720 server frame goes (see the module docstring).

    Every figure is the minimum over ``repeats`` runs of per-thread CPU time
    (``time.thread_time``; ``time.process_time`` for all threads together): on a shared machine
    the minimum is what the code costs, a median also counts the other jobs."""
    import cProfile
    import pstats

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
        f"{[len(p) for p in packets]} bytes; CPU ms, minimum of {repeats}"
    )
    print("\n1. FFmpeg alone, each picture on its own single-threaded decoder")
    print(
        f"{'picture':17} {'frame':>5} {'size':>9} {'format':9} {'bytes':>7} "
        f"{'new decoder':>11} {'kept decoder':>12} {'ns/sample':>9}"
    )
    cpu: dict[tuple[str, int, bool], list[float]] = {}
    info: dict[tuple[str, int], tuple[str, str, int, float]] = {}
    for kept in (False, True):
        decoders: dict[str, Any] = {}
        for r in range(repeats + kept):
            if not kept:
                decoders = {}
            for i, packet in enumerate(packets):
                for b in unpack_packet(packet).buffers:
                    if b.codec != Codec.HEVC:
                        continue
                    ctx = decoders.get(b.name)
                    if ctx is None:
                        ctx = decoders[b.name] = _hevc_decoder(1 << 14, 1 << 13)
                    pkt = av.Packet(bytes(b.payload))
                    t0 = time.thread_time()
                    frame = ctx.decode(pkt)[0]
                    dt = time.thread_time() - t0
                    if kept and r == 0:
                        continue  # warm-up: the kept decoders' buffers are allocated here
                    cpu.setdefault((b.name, i, kept), []).append(dt)
                    fmt = frame.format.name
                    samples = frame.width * frame.height * (
                        1.5 if fmt.endswith("420p") else 1.0 if fmt.startswith("gray") else 3.0
                    )
                    info[(b.name, i)] = (
                        f"{frame.width}x{frame.height}", fmt, len(b.payload), samples
                    )
                    del frame
    totals = {(i, kept): 0.0 for i in (0, 1) for kept in (False, True)}
    for (name, i), (size, fmt, n, samples) in sorted(info.items(), key=lambda x: x[0][1]):
        new, old = min(cpu[(name, i, False)]) * 1e3, min(cpu[(name, i, True)]) * 1e3
        totals[(i, False)] += new
        totals[(i, True)] += old
        print(
            f"{name:17} {i:5} {size:>9} {fmt:9} {n:7} {new:11.2f} {old:12.2f} "
            f"{old * 1e6 / samples:9.2f}"
        )
    for i, what in ((0, "key frame"), (1, "other")):
        print(
            f"{'all 3 (' + what + ')':51} {totals[(i, False)]:11.1f} {totals[(i, True)]:12.1f}"
        )

    print("\n2. StreamDecoder.decode on one thread (threads=1), a decoder kept across frames;")
    print("   per step, CPU ms per server frame (mean of frames 0 and 1)")
    steps: dict[str, list[float]] = {}
    with StreamDecoder(threads=1) as dec:
        for p in packets:
            dec.decode(p)
        for _ in range(repeats):
            prof = cProfile.Profile(time.thread_time)
            prof.enable()
            kept_frames = [dec.decode(p) for p in packets]
            prof.disable()
            del kept_frames
            for step, t in _step_times(pstats.Stats(prof).stats).items():  # type: ignore[attr-defined]
                steps.setdefault(step, []).append(t / len(packets))
    accounted = 0.0
    for step, ts in steps.items():
        ms = min(ts) * 1e3
        if step.startswith("total"):
            print(f"   {'other Python (checks, dicts, arrays)':40} {ms - accounted:7.1f}")
        else:
            accounted += ms
        print(f"   {step:40} {ms:7.1f}")

    print("\n3. StreamDecoder.decode per server frame, default threads (frames 0 and 1)")
    for kept in (False, True):
        walls, cpus = [], []
        each: list[list[float]] = [[] for _ in packets]  # wall per packet: key frame, other
        dec = StreamDecoder()
        for r in range(repeats + kept):
            if not kept:
                dec.close()
                dec = StreamDecoder()
            c0, t0 = time.process_time(), time.perf_counter()
            out, ends = [], []
            for p in packets:
                out.append(dec.decode(p))
                ends.append(time.perf_counter())
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            del out
            if kept and r == 0:
                continue
            walls.append(dt / len(packets))
            cpus.append(dc / len(packets))
            for i, (begin, end) in enumerate(zip([t0, *ends], ends)):
                each[i].append(end - begin)
        dec.close()
        print(
            f"   {'kept decoder (a running stream)' if kept else 'new decoder per pair':32} "
            f"CPU (all threads) min {min(cpus) * 1e3:6.1f} ms, wall min "
            f"{min(walls) * 1e3:6.1f} median {statistics.median(walls) * 1e3:6.1f} ms"
        )
        if kept:
            # The key frame's colour picture is the longest single job: the wall time's share
            # of the CPU time says how well the pictures share the cores (1/threads at best).
            med = [statistics.median(w) * 1e3 for w in each]
            print(
                f"   {'':32} wall median key frame {med[0]:6.1f} ms, other {med[1]:6.1f} "
                f"ms; wall / CPU {statistics.median(walls) / statistics.median(cpus):.2f}"
            )
    print(f"load average {os.getloadavg()}")


def report(
    sizes: tuple[tuple[int, int], ...], frames_per_run: int, paper_mbps: float, preset: str,
    compare_chroma: bool,
) -> None:
    """Prints the benchmark of the module's docstring for each main-camera size of ``sizes``
    (checked by the caller: :func:`splitrender.cli.bench_codec.sizes`)."""
    print(
        f"cpus: {os.cpu_count()}, frames per run: {frames_per_run}, preset {preset}"
    )
    scene = SyntheticScene(dynamic=True)
    for w, h in sizes:
        frames = [scene.server_frame(i, i / 10, w, h) for i in range(frames_per_run)]
        cfg = CodecConfig.scaled(w, h, paper_mbps, preset=preset)
        r = run(w, h, frames_per_run, cfg, frames)
        rt = (1000 / cfg.fps) / r["enc_ms"]
        print(
            f"\n{w}x{h} (+2x {w // 2}x{h // 2}), target {cfg.bitrate_mbps:.3f} Mb/s "
            f"(paper {paper_mbps:g} Mb/s scaled), gop {cfg.gop}, chroma {cfg.chroma}"
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
                w, h, paper_mbps, preset=preset, exact_static_motion=False
            ),
        )
        print(
            f"  without the static mask, {100 * frac:.3f} % of static pixels decode to exact 0"
        )
        if compare_chroma:
            for chroma in ("444", "420"):
                c = CodecConfig.scaled(
                    w, h, paper_mbps, preset=preset, chroma=chroma
                )
                rc = run(w, h, frames_per_run, c, frames)
                print(
                    f"  chroma {chroma}: colour PSNR {rc['psnr']:.2f} dB at {rc['mbps']:.3f} Mb/s, "
                    f"encode {rc['enc_ms']:.1f} ms, decode {rc['dec_ms']:.1f} ms"
                )
