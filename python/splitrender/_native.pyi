"""Stubs of ``splitrender._native``, the PyO3 bindings of reproj-core (crates/reproj-py).

Array arguments must be C-contiguous numpy arrays of exactly the dtype shown (no casting); a
camera tuple ``Cam`` is ``(view f64[4,4], proj f64[4,4], color u8[H,W,3], depth f32[H,W],
motion f32[H,W,3] | None, shadow (bits u32[H,W], s_min u8[H,W,3], s_max u8[H,W,3]) | None)``
and a frame is ``(main: Cam, aux: list[Cam])``. Every error is a ``SplitRenderError``; invalid
input raises ``InvalidInputError`` (also a ``ValueError``) naming the offending argument.
"""

from collections.abc import Sequence
from typing import Any, final

import numpy as np
import numpy.typing as npt

_F64 = npt.NDArray[np.float64]
_F32 = npt.NDArray[np.float32]
_U8 = npt.NDArray[np.uint8]
_U32 = npt.NDArray[np.uint32]
_Shadow = tuple[_U32, _U8, _U8]
_Cam = tuple[_F64, _F64, _U8, _F32, _F32 | None, _Shadow | None]
_Frame = tuple[_Cam, list[_Cam]] | tuple[_Cam, tuple[_Cam, ...]]
_Client = tuple[_F64, _F64, int, int]
_Vec3 = tuple[float, float, float]

__all__ = [
    "__version__",
    "METHODS",
    "SplitRenderError",
    "InvalidInputError",
    "OutOfMemoryError",
    "StreamError",
    "GpuUnavailableError",
    "GpuDeviceLostError",
    "BidirHistory",
    "reproject",
    "scene_flow",
    "apply_shadows",
    "perspective",
    "look_at",
    "singular_camera",
    "render_thread_ids",
    "simd_tier",
    "dequantise_depth",
    "dequantise_motion",
    "shadow_colour",
    "block_mean",
    "ssim",
    "synthetic_render_server",
    "synthetic_ground_truth",
    "synthetic_rig",
    "synthetic_head_pose",
    "Scene",
    "scene_names",
    "default_samples",
    "MAX_PREPARE_THREADS",
    "MAX_SAMPLES",
    "GPU_OUTPUT_SLOTS",
    "WgpuPair",
    "WgpuReprojector",
    "wgpu_adapter",
    "_panic_for_test",
    "_wgpu_lose_device_for_test",
]

__version__: str
METHODS: list[str]
MAX_SAMPLES: int
MAX_PREPARE_THREADS: int
GPU_OUTPUT_SLOTS: int

class SplitRenderError(Exception): ...
class InvalidInputError(SplitRenderError, ValueError): ...
class OutOfMemoryError(SplitRenderError, MemoryError): ...
class StreamError(SplitRenderError): ...
class GpuUnavailableError(SplitRenderError): ...
class GpuDeviceLostError(SplitRenderError): ...

@final
class BidirHistory:
    def __new__(cls) -> BidirHistory: ...
    def reset(self) -> None: ...
    def prepare(
        self,
        method: str,
        older: _Frame | None,
        newer: _Frame,
        client: _Client,
        options: dict[str, Any] | None = None,
        threads: int | None = None,
    ) -> None: ...
    @property
    def pair_builds(self) -> int: ...

def reproject(
    method: str,
    older: _Frame | None,
    newer: _Frame,
    client: _Client,
    alpha: float,
    options: dict[str, Any] | None = None,
    previous: _U8 | None = None,
    diagnostics: bool = False,
    history: BidirHistory | None = None,
) -> _U8 | tuple[_U8, _U8, _F32]: ...
def scene_flow(
    view: _F64,
    proj: _F64,
    depth: _F32,
    motion: _F32 | None,
    client: _Client,
    w: float,
) -> _F32: ...
def apply_shadows(
    color: _U8,
    bits: _U32,
    s_min: _U8,
    s_max: _U8,
    alpha: float,
    subframes: int,
    role: str,
) -> _U8: ...
def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> _F64: ...
def look_at(eye: _Vec3, target: _Vec3, up: _Vec3 | None = None) -> _F64: ...
def singular_camera(view: _F64, proj: _F64) -> str | None: ...
def render_thread_ids() -> list[int]: ...
def simd_tier() -> str: ...
def dequantise_depth(
    codes: npt.NDArray[np.uint16],
    x: int,
    y: int,
    w: int,
    h: int,
    scale: float,
    offset: float,
    invalid_mask: npt.NDArray[np.bool_] | None = None,
    out: _F32 | None = None,
) -> _F32: ...
def dequantise_motion(
    codes: npt.NDArray[np.uint16],
    tiles: Sequence[tuple[int, int]],
    w: int,
    h: int,
    scale: tuple[float, float, float],
    offset: tuple[float, float, float],
    static_mask: npt.NDArray[np.bool_] | None = None,
    invalid_mask: npt.NDArray[np.bool_] | None = None,
    out: _F32 | None = None,
) -> _F32: ...
def shadow_colour(
    luma: _U8,
    cb: _U8,
    cr: _U8,
    x: int,
    y: int,
    bits: _U32,
    out: _U8 | None = None,
    half: bool = False,
) -> _U8: ...
def block_mean(a: _F32, weight: npt.NDArray[np.bool_]) -> tuple[_F32, npt.NDArray[np.bool_]]: ...
def ssim(
    x: _F64, y: _F64, want_map: bool = False
) -> tuple[float, _F64 | None]: ...
def synthetic_render_server(
    dynamic: bool, camera: _Client, time: float, interval: float, subframes: int
) -> dict[str, npt.NDArray[Any]]: ...
def synthetic_ground_truth(dynamic: bool, camera: _Client, time: float) -> _U8: ...
def synthetic_rig(
    eye: _Vec3, target: _Vec3, width: int, height: int
) -> list[tuple[_F64, _F64, int, int]]: ...
def synthetic_head_pose(t: float) -> tuple[_Vec3, _Vec3]: ...
def scene_names() -> list[str]: ...
def default_samples(width: int, height: int) -> int: ...
@final
class Scene:
    """A built-in scene of the reference renderer (reproj-scene), built once."""

    def __new__(
        cls,
        name: str,
        variant: str = "dynamic",
        models: (
            list[
                tuple[
                    str,
                    tuple[float, float, float],
                    float,
                    float,
                    int | None,
                    float,
                    float,
                ]
            ]
            | None
        ) = None,
    ) -> Scene: ...
    @property
    def name(self) -> str: ...
    @property
    def variant(self) -> str: ...
    @property
    def model_files(self) -> list[tuple[str, list[str]]]: ...
    @property
    def duration(self) -> float: ...
    @property
    def near(self) -> float: ...
    @property
    def far(self) -> float: ...
    def main_size(self, scale: float) -> tuple[int, int]: ...
    def camera_sizes(self, scale: float) -> list[tuple[int, int]]: ...
    def head_box(self, t: float) -> _F64: ...
    def client_pose(self, t: float) -> _F64: ...
    def server_pose(self, k: int, fs: float) -> _F64: ...
    def render_server_frame(
        self,
        k: int,
        scale: float,
        fs: float = 10.0,
        subframes: int = 4,
        pose: _F64 | None = None,
        samples: int | None = None,
    ) -> dict[str, Any]: ...
    def render_client_frame(
        self,
        n: int,
        scale: float,
        fc: float = 120.0,
        stereo: bool = False,
        pose: _F64 | None = None,
        samples: int | None = None,
    ) -> list[tuple[_F64, _F64, int, int, _U8]]: ...
    def render_ground_truth(
        self,
        view: _F64,
        proj: _F64,
        width: int,
        height: int,
        t: float,
        samples: int | None = None,
    ) -> _U8: ...

def wgpu_adapter() -> str: ...
@final
class WgpuPair:
    """A pair of server frames on the device (``WgpuReprojector.upload``)."""

    @property
    def has_older(self) -> bool: ...
    @property
    def device_bytes(self) -> int: ...

@final
class WgpuReprojector:
    """The client reprojection on the GPU (reproj-wgpu), server frames kept on the device."""

    def __new__(cls, force_32bit_atomics: bool = False) -> WgpuReprojector: ...
    @property
    def adapter(self) -> str: ...
    @property
    def atomics(self) -> str: ...
    @property
    def lost(self) -> str | None: ...
    def upload(self, older: _Frame | None, newer: _Frame) -> WgpuPair: ...
    def install(self, pair: WgpuPair) -> WgpuPair | None: ...
    def render(
        self,
        method: str,
        client: _Client,
        alpha: float,
        options: dict[str, Any] | None = None,
        previous: _U8 | None = None,
        keep: bool = False,
        slot: int = 0,
        diagnostics: bool = False,
        download: bool = True,
    ) -> _U8 | tuple[_U8, _U8, _F32] | None: ...
    def unload(self) -> None: ...

def _panic_for_test() -> None: ...
def _wgpu_lose_device_for_test() -> None: ...
