"""splitrender: image-based split rendering.

A server renders sparse frames (colour, depth, object motion, dynamic-shadow data) for a main
camera and two auxiliary cameras; the client synthesises display-rate frames at its actual pose by
bidirectional image-based reprojection (Steiner et al. 2025). The kernels are native
(``splitrender._native``, Rust); this package holds the data model and the Python API.

The sub-packages follow the data flow (shared/DESIGN.md, "Package layout"); imports point down it:
:mod:`~splitrender.types`, :mod:`~splitrender.errors` and :mod:`~splitrender.tally` at the
bottom, then :mod:`~splitrender.reproject` and :mod:`~splitrender.gpu` (one client frame),
:mod:`.scene` (where server frames come from), :mod:`.codec` (frames <-> packets), :mod:`.net`
(the network), :mod:`.client`, and on top :mod:`.evaluation` and :mod:`.cli`.

Conventions: shared/DESIGN.md ("Conventions").
"""

from splitrender._native import BidirHistory, __version__
from splitrender.client import Client, PlaybackResult, RealtimeClient, play
from splitrender.codec import (
    CodecConfig,
    DecodedStream,
    StreamDecoder,
    StreamEncoder,
    StreamStats,
    read_stream,
    stream_stats,
    write_stream,
)
from splitrender.errors import (
    InvalidInputError,
    OutOfMemoryError,
    SplitRenderError,
    StreamError,
)
from splitrender.evaluation import metrics
from splitrender.net import NetworkModel, Schedule
from splitrender.reproject import (
    METHODS,
    apply_shadows,
    prepare_pair,
    reproject,
    reproject_alpha,
    scene_flow,
)
from splitrender.scene import (
    SCENE_NAMES,
    ClientFrame,
    DatasetError,
    ModelPlacement,
    Recording,
    RecordingError,
    Scene,
    SyntheticScene,
    Trace,
    TraceError,
    export_dataset,
    import_dataset,
    load_recording,
    load_trace,
    write_recording,
)
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
    "DecodedStream",
    "InvalidInputError",
    "OutOfMemoryError",
    "ModelPlacement",
    "NetworkModel",
    "PlaybackResult",
    "RealtimeClient",
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
    "prepare_pair",
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
