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

from __future__ import annotations

import importlib
import sys
from types import ModuleType  # not `import types`: that name is our submodule's
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

#: Where each public name lives. ``import splitrender`` imports none of them: each is imported
#: on first use (PEP 562 ``__getattr__``), so that the ``splitrender`` command starts without
#: numpy, the native module and the codec (a few tenths of a second, during which Ctrl-C would
#: otherwise end in a traceback: :func:`splitrender.cli.main` imports them where it catches it).
_HOMES: dict[str, tuple[str, ...]] = {
    "splitrender._native": ("BidirHistory", "__version__"),
    "splitrender.client": ("Client", "PlaybackResult", "RealtimeClient", "play"),
    "splitrender.codec": (
        "CodecConfig", "DecodedStream", "StreamDecoder", "StreamEncoder", "StreamStats",
        "read_stream", "stream_stats", "write_stream",
    ),
    "splitrender.errors": (
        "InvalidInputError", "OutOfMemoryError", "SplitRenderError", "StreamError",
    ),
    "splitrender.evaluation": ("metrics",),
    "splitrender.net": ("NetworkModel", "Schedule"),
    "splitrender.reproject": (
        "METHODS", "apply_shadows", "prepare_pair", "reproject", "reproject_alpha", "scene_flow",
    ),
    "splitrender.scene": (
        "SCENE_NAMES", "ClientFrame", "DatasetError", "ModelPlacement", "Recording",
        "RecordingError", "Scene", "SyntheticScene", "Trace", "TraceError", "export_dataset",
        "import_dataset", "load_recording", "load_trace", "write_recording",
    ),
    "splitrender.types": (
        "MAX_SIDE", "Camera", "CameraFrame", "ClientRequest", "Reprojection", "ReprojectOptions",
        "ServerFrame", "ShadowBuffers",
    ),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name: str) -> Any:
    """The public name ``name``, imported from its module on first use and kept; or the
    submodule ``name`` (``splitrender.gpu`` after a bare ``import splitrender``, as when this
    module imported everything)."""
    module = _HOME.get(name)
    if module is not None:
        value = getattr(importlib.import_module(module), name)
        globals()[name] = value
        return value
    if not name.startswith("__"):
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise  # a module it imports is missing: that is the error to see
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(ModuleType):
    """The package's module type: the import system binds every submodule to its package as it
    loads it, and ``splitrender.reproject`` is both a module and, as the package's attribute,
    the public function of that name (as it was when this module imported everything). The
    module must not take the function's place."""

    def __setattr__(self, name: str, value: object) -> None:
        if (name in _HOME and isinstance(value, ModuleType)
                and value.__name__ == f"{__name__}.{name}"):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


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
