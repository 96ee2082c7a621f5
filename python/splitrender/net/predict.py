"""Head-pose prediction for the live server: from the poses the client sent (display time,
world-from-camera), the pose at a future display time (seeds/000 §3: the server renders at a
*predicted* pose; the client corrects the rest by reprojection).

A predictor is anything with :meth:`PosePredictor.add` and :meth:`PosePredictor.predict`
(:class:`PosePredictor`); :data:`PREDICTORS` names the built-in ones for ``splitrender serve
--predictor``. The default, :class:`ConstantVelocity`, extrapolates translation linearly and
rotation at constant angular velocity, both estimated over the last ``window`` seconds of
samples; :class:`LastPose` holds the newest pose (no prediction: the baseline).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Protocol

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation  # type: ignore[import-untyped,unused-ignore]

from splitrender.errors import InvalidInputError
from splitrender.net.protocol import MAX_POSITION

__all__ = ["PREDICTORS", "ConstantVelocity", "LastPose", "PosePredictor", "make_predictor"]

_F64 = npt.NDArray[np.float64]


class PosePredictor(Protocol):
    """Poses in (display time order is not assumed: the datagrams may be reordered), a
    predicted pose out."""

    def add(self, time: float, pose: _F64) -> None: ...

    def predict(self, time: float) -> _F64 | None:
        """The pose at display ``time`` (``None`` before the first sample)."""
        ...

    @property
    def newest_time(self) -> float | None:
        """Display time of the newest sample (``None`` before the first)."""
        ...


class LastPose:
    """The newest sample's pose, whatever the time asked for."""

    def __init__(self) -> None:
        self._t: float | None = None
        self._pose: _F64 | None = None

    def add(self, time: float, pose: _F64) -> None:
        if self._t is None or time > self._t:  # newest wins; a reordered older one is ignored
            self._t, self._pose = time, np.array(pose, dtype=np.float64)

    def predict(self, time: float) -> _F64 | None:
        return None if self._pose is None else self._pose.copy()

    @property
    def newest_time(self) -> float | None:
        return self._t


class ConstantVelocity:
    """Constant linear and angular velocity over the samples of the last ``window`` seconds
    (the newest and the oldest in the window: a longer baseline than two consecutive samples
    at 120 Hz, so that pose noise is not amplified by the extrapolation). ``max_ahead`` caps
    how far it extrapolates (seconds past the newest sample): beyond it the motion model is
    worth less than holding still.

    The samples come from the network: at most :data:`MAX_SAMPLES` are kept (the oldest go
    first), and two closer than :data:`MIN_BASELINE_S` give no velocity (the newest pose is
    held): samples a hair apart made the extrapolation infinite. A prediction is kept within
    the positions a pose may have (:data:`~splitrender.net.protocol.MAX_POSITION`)."""

    #: Most samples kept: a display at 1000 Hz fills a 50 ms window with 50.
    MAX_SAMPLES = 256
    #: Shortest time between the oldest and newest sample that velocities are taken over.
    MIN_BASELINE_S = 1e-3

    def __init__(self, window: float = 0.05, max_ahead: float = 0.5) -> None:
        if not (math.isfinite(window) and window > 0 and math.isfinite(max_ahead)):
            raise InvalidInputError(
                f"ConstantVelocity: expected window > 0 and a finite max_ahead, got "
                f"{window!r}, {max_ahead!r}"
            )
        self.window = float(window)
        self.max_ahead = float(max_ahead)
        self._samples: deque[tuple[float, _F64]] = deque(maxlen=self.MAX_SAMPLES)

    def add(self, time: float, pose: _F64) -> None:
        s = self._samples
        if s and time <= s[-1][0]:
            return  # reordered or repeated: newest wins
        s.append((float(time), np.array(pose, dtype=np.float64)))
        while len(s) > 2 and s[1][0] <= time - self.window:
            s.popleft()

    @property
    def newest_time(self) -> float | None:
        return self._samples[-1][0] if self._samples else None

    def predict(self, time: float) -> _F64 | None:
        s = self._samples
        if not s:
            return None
        t1, p1 = s[-1]
        if len(s) < 2:
            return np.array(p1, dtype=np.float64)
        t0, p0 = s[0]
        if t1 - t0 < self.MIN_BASELINE_S:
            return np.array(p1, dtype=np.float64)
        ahead = min(time - t1, self.max_ahead)
        f = ahead / (t1 - t0)
        out = np.eye(4)
        out[:3, 3] = np.clip(p1[:3, 3] + f * (p1[:3, 3] - p0[:3, 3]), -MAX_POSITION,
                             MAX_POSITION)
        r0 = Rotation.from_matrix(p0[:3, :3])
        r1 = Rotation.from_matrix(p1[:3, :3])
        step = (r1 * r0.inv()).as_rotvec()  # world-frame rotation from t0 to t1
        out[:3, :3] = (Rotation.from_rotvec(f * step) * r1).as_matrix()
        return np.asarray(out, dtype=np.float64)


#: The predictors ``splitrender serve --predictor`` offers.
PREDICTORS: tuple[str, ...] = ("constant-velocity", "last")


def make_predictor(name: str) -> PosePredictor:
    """A new predictor of :data:`PREDICTORS` by name."""
    if name == "constant-velocity":
        return ConstantVelocity()
    if name == "last":
        return LastPose()
    raise InvalidInputError(f"predictor: expected one of {', '.join(PREDICTORS)}, got {name!r}")
