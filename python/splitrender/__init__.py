"""splitrender: image-based split rendering.

A server renders sparse frames (colour, depth, object motion, dynamic-shadow data) for a main
camera and two auxiliary cameras; the client synthesises display-rate frames at its actual pose by
bidirectional image-based reprojection (Steiner et al. 2025). The kernels are native
(``splitrender._native``, Rust); this package holds the data model and the Python API.

Conventions: shared/DESIGN.md ("Conventions").
"""

from splitrender import metrics
from splitrender._native import BidirHistory, __version__
from splitrender.client import Client, PlaybackResult, play
from splitrender.codec import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.dataset import DatasetError, export_dataset, import_dataset
from splitrender.errors import InvalidInputError, SplitRenderError, StreamError
from splitrender.network import NetworkModel, Schedule
from splitrender.recording import (
    ClientFrame,
    Recording,
    RecordingError,
    load_recording,
    write_recording,
)
from splitrender.reproject import (
    METHODS,
    apply_shadows,
    reproject,
    reproject_alpha,
    scene_flow,
)
from splitrender.scenes import SCENE_NAMES, ModelPlacement, Scene, Trace, TraceError, load_trace
from splitrender.stream import StreamStats, read_stream, stream_stats, write_stream
from splitrender.synthetic import SyntheticScene
from splitrender.types import (
    MAX_SIDE,
    Camera,
    CameraFrame,
    ClientRequest,
    Reprojection,
    ReprojectOptions,
    ServerFrame,
    ShadowBuffers,
)

__all__ = [
    "MAX_SIDE",
    "METHODS",
    "SCENE_NAMES",
    "BidirHistory",
    "Camera",
    "CameraFrame",
    "Client",
    "ClientFrame",
    "ClientRequest",
    "CodecConfig",
    "DatasetError",
    "InvalidInputError",
    "ModelPlacement",
    "NetworkModel",
    "PlaybackResult",
    "Recording",
    "RecordingError",
    "Reprojection",
    "ReprojectOptions",
    "Scene",
    "Schedule",
    "ServerFrame",
    "ShadowBuffers",
    "SplitRenderError",
    "StreamDecoder",
    "StreamEncoder",
    "StreamError",
    "StreamStats",
    "SyntheticScene",
    "Trace",
    "TraceError",
    "__version__",
    "apply_shadows",
    "export_dataset",
    "import_dataset",
    "load_recording",
    "load_trace",
    "metrics",
    "play",
    "read_stream",
    "reproject",
    "reproject_alpha",
    "scene_flow",
    "stream_stats",
    "write_recording",
    "write_stream",
]
