"""The analytic synthetic scene of reproj-core (``reproj_core::synthetic``): a back wall, a floor,
a moving textured sphere and a bobbing cube under one soft-shadowing light, ray cast exactly, so
every server buffer is consistent and ground truth exists at any pose and time.

Used by the tests, the benchmarks and ``splitrender example`` until the reference renderer exists.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.types import Camera, CameraFrame, ServerFrame, ShadowBuffers
from splitrender.types import (  # argument checks
    MAX_SIDE,
    check_bool,
    checked,
    floats,
    instances,
    ints,
)

__all__ = ["SyntheticScene"]


def _camera(native: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int, int]) -> Camera:
    view, proj, width, height = native
    return Camera(view, proj, width, height)


class SyntheticScene:
    """The scene; ``dynamic=False`` freezes the sphere and the cube at their ``t = 0`` pose."""

    __slots__ = ("dynamic",)

    dynamic: bool

    def __init__(self, dynamic: bool = True) -> None:
        self.dynamic = check_bool("dynamic", dynamic)

    def __repr__(self) -> str:
        return f"SyntheticScene(dynamic={self.dynamic})"

    @staticmethod
    @checked(t=floats())
    def head_pose(t: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """The deterministic head path: ``(eye, target)`` at time ``t``."""
        return _native.synthetic_head_pose(t)

    @checked(t=floats(), width=ints(1, MAX_SIDE), height=ints(1, MAX_SIDE))
    def rig(self, t: float, width: int, height: int) -> tuple[Camera, tuple[Camera, Camera]]:
        """The DESIGN.md camera rig at the head pose of time ``t``: the main camera (60°,
        ``width x height``) and the two auxiliary cameras (80°, half size, 20 cm left/right,
        yawed 10° outward)."""
        eye, target = _native.synthetic_head_pose(t)
        main, left, right = _native.synthetic_rig(eye, target, width, height)
        return _camera(main), (_camera(left), _camera(right))

    @staticmethod
    @checked(t=floats())
    def head_deviation(t: float) -> tuple[float, float, float]:
        """The actual head's deterministic deviation from the predicted path at time ``t``
        (metres, a sum of slow sines of a few centimetres, as DESIGN.md's anchor): the server
        renders at :meth:`head_pose`, the client sees ``head_pose(t) + head_deviation(t)``, so the
        client never sits exactly on the pose the server predicted."""
        two_pi = 2.0 * np.pi
        return (
            0.05 * np.sin(two_pi * 0.9 * t + 0.3) + 0.02 * np.sin(two_pi * 2.3 * t),
            0.02 * np.sin(two_pi * 1.3 * t + 1.1),
            0.03 * np.sin(two_pi * 0.7 * t + 2.0),
        )

    @checked(t=floats(), width=ints(1, MAX_SIDE), height=ints(1, MAX_SIDE))
    def client_camera(self, t: float, width: int, height: int) -> Camera:
        """The client's actual main camera at ``t``: the rig's main camera moved by
        :meth:`head_deviation` and turned towards a target shifted by twice that (about 1° of
        extra yaw and pitch)."""
        eye, target = _native.synthetic_head_pose(t)
        d = self.head_deviation(t)
        return Camera.look_at(
            [e + dv for e, dv in zip(eye, d)],
            [g + 2.0 * dv for g, dv in zip(target, d)],
            width=width,
            height=height,
        )

    @checked(
        camera=instances(Camera), time=floats(), fps=floats(positive=True), subframes=ints(1, 16),
    )
    def render(
        self, camera: Camera, time: float, *, fps: float = 10.0, subframes: int = 4
    ) -> CameraFrame:
        """Every server buffer of ``camera`` at ``time``: colour, depth, forward and backward
        motion (one server interval ``1/fps``) and forward and backward shadow buffers with
        ``subframes`` subframes."""
        b = _native.synthetic_render_server(
            self.dynamic, camera.to_native(), time, 1.0 / fps, subframes
        )
        return CameraFrame(
            camera=camera,
            color=b["color"],
            depth=b["depth"],
            motion_fwd=b["motion_fwd"],
            motion_bwd=b["motion_bwd"],
            shadow_fwd=ShadowBuffers(
                b["shadow_fwd_bits"], b["shadow_fwd_min"], b["shadow_fwd_max"]
            ),
            shadow_bwd=ShadowBuffers(
                b["shadow_bwd_bits"], b["shadow_bwd_min"], b["shadow_bwd_max"]
            ),
        )

    @checked(
        index=ints(0, (1 << 31) - 1), time=floats(), width=ints(1, MAX_SIDE),
        height=ints(1, MAX_SIDE), fps=floats(positive=True), subframes=ints(1, 16),
    )
    def server_frame(
        self,
        index: int,
        time: float,
        width: int,
        height: int,
        *,
        fps: float = 10.0,
        subframes: int = 4,
    ) -> ServerFrame:
        """Server frame ``index`` at ``time``: the rig at the head pose of ``time`` (main camera
        ``width x height`` and two auxiliary cameras), every buffer rendered."""
        main, aux = self.rig(time, width, height)
        return ServerFrame(
            index=index,
            time=time,
            main=self.render(main, time, fps=fps, subframes=subframes),
            aux=tuple(self.render(a, time, fps=fps, subframes=subframes) for a in aux),
        )

    @checked(camera=instances(Camera), time=floats())
    def ground_truth(self, camera: Camera, time: float) -> npt.NDArray[np.uint8]:
        """The exact image (``uint8[H, W, 3]``) at ``camera`` and ``time``."""
        return _native.synthetic_ground_truth(self.dynamic, camera.to_native(), time)
