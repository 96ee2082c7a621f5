"""Where server frames come from: the built-in scenes of the reference renderer and client motion
(:mod:`.builtin`), recordings of rendered sessions (:mod:`.recording`), the authors' dataset layout
(:mod:`.dataset`) and the analytic synthetic fixture (:mod:`.synthetic`)."""

from splitrender.scene.builtin import (
    SCENE_NAMES,
    ModelPlacement,
    Scene,
    Trace,
    TraceError,
    load_trace,
)
from splitrender.scene.dataset import DatasetError, export_dataset, import_dataset
from splitrender.scene.recording import (
    ClientFrame,
    Recording,
    RecordingError,
    load_recording,
    write_recording,
)
from splitrender.scene.synthetic import SyntheticScene

__all__ = [
    "SCENE_NAMES",
    "ClientFrame",
    "DatasetError",
    "ModelPlacement",
    "Recording",
    "RecordingError",
    "Scene",
    "SyntheticScene",
    "Trace",
    "TraceError",
    "export_dataset",
    "import_dataset",
    "load_recording",
    "load_trace",
    "write_recording",
]
