"""Reproject one client frame of the synthetic dynamic scene with every method.

    python examples/reproject_synthetic.py [WIDTH HEIGHT]

Prints, per method, the fraction of pixels matched and the mean absolute error against the exact
ground truth at the client's pose. (`splitrender example` does the same and also writes PNGs.)
"""

from __future__ import annotations

import sys

import numpy as np

import splitrender as sr


def main() -> None:
    width, height = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) == 3 else (640, 360)
    scene = sr.SyntheticScene(dynamic=True)
    # Two consecutive server frames at 10 FPS: main camera plus two auxiliary cameras each.
    f0 = scene.server_frame(0, 0.0, width, height)
    f1 = scene.server_frame(1, 0.1, width, height)
    # Client frame 7 at 120 FPS, at the client's own pose (between the two server poses).
    t = 7 / 120
    camera, _ = scene.rig(t, width, height)
    request = sr.ClientRequest(camera, t)
    truth = scene.ground_truth(camera, t)
    for method in sr.METHODS:
        r = sr.reproject(f0, f1, request, method, diagnostics=True)
        mae = np.abs(r.image.astype(np.int16) - truth).mean()
        print(f"{method:<18} matched {r.matched.mean():6.1%}  MAE {mae:6.2f}")


if __name__ == "__main__":
    main()
