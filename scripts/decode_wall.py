"""Wall-clock decode time of one 1280x720 server frame, as ``splitrender bench`` measures it
(the two courtyard frames it caches, 10 Mb/s, one decoder kept across passes, an untimed first
pass), with more passes and, with ``--fifo``, the timed passes under ``SCHED_FIFO``.

On a machine shared with other jobs a wall-clock figure mostly measures those jobs. ``--fifo``
(root, Linux) lets the decoding threads pre-empt every ordinary thread for the second or two of
the timed passes, which approximates an idle machine: the encoding before them runs at normal
priority, and the kernel's real-time throttling (95 % of each second by default) still leaves
the others a share. Use it briefly, alternating the versions compared:

    PYTHONPATH=python python scripts/decode_wall.py --fifo --passes 15
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.evaluation.bench import _recording


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--passes", type=int, default=15)
    ap.add_argument("--fifo", action="store_true", help="time under SCHED_FIFO (priority 10)")
    args = ap.parse_args()
    rec = _recording("courtyard", 0.5, print)
    f0, f1 = rec.server_frames[0], rec.server_frames[1]
    w, h = f0.main.camera.width, f0.main.camera.height
    with StreamEncoder(CodecConfig.scaled(w, h)) as enc:
        packets = [enc.encode(f0), enc.encode(f1)]
    if args.fifo:
        # Before the decoder starts its worker threads, which inherit the policy.
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    walls, cpus = [], []
    try:
        with StreamDecoder() as dec:
            for i in range(args.passes + 1):
                c0, t0 = time.process_time(), time.perf_counter()
                out = [dec.decode(p) for p in packets]
                dt, dc = time.perf_counter() - t0, time.process_time() - c0
                del out  # the decoder may reuse the arrays of the pass before
                if i:
                    walls.append(dt / len(packets))
                    cpus.append(dc / len(packets))
    finally:
        if args.fifo:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    print(
        f"{w}x{h} + aux, {len(walls)} passes{' (SCHED_FIFO)' if args.fifo else ''}: wall min "
        f"{min(walls) * 1e3:.1f} median {statistics.median(walls) * 1e3:.1f} ms, CPU (all "
        f"threads) min {min(cpus) * 1e3:.1f} median {statistics.median(cpus) * 1e3:.1f} ms "
        f"per server frame; load average {os.getloadavg()[0]:.2f}"
    )


if __name__ == "__main__":
    main()
