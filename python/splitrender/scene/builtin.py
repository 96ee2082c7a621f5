"""The built-in scenes of the reference renderer (crates/reproj-scene) and client motion.

:class:`Scene` wraps ``splitrender._native.Scene`` and returns the dataclasses the client
consumes (:class:`~splitrender.types.ServerFrame`, :class:`~splitrender.types.Camera`).

Client motion (shared/DESIGN.md "Prediction error") comes from one of two sources, both giving
camera-to-world ``float64[4, 4]`` head poses (the camera looks along its -z):

- :class:`PathMotion`: the scene's head-box path plus the anchor's deterministic deviation; the
  client sees the anchor at ``t``, the server renders frame ``k`` at the head box of ``t_k`` with
  the deviation of ``t_k - d`` (``d`` = ``prediction_delay``, 0.1 s by default);
- :class:`TraceMotion`: a recorded head trace (:func:`load_trace`, format in
  shared/traces/README.md) re-anchored at the scene's head box at ``t = 0``: the client sees
  ``A · T(0)^-1 · T(t)`` (translation optionally scaled), and the server renders frame ``k`` at the
  trace pose ``prediction_delay`` (default :data:`PREDICTION_DELAY`) earlier (clamped at the
  trace's start), an imperfect prediction.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Sequence
from typing import Any, Protocol, TypeGuard

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.errors import InvalidInputError
from splitrender.files import JSON_KINDS, read_json, read_regular
from splitrender.types import Camera, CameraFrame, ServerFrame, ShadowBuffers
from splitrender.types import (  # argument checks
    BOOL,
    PATH,
    check_float,
    check_int,
    check_items,
    check_path,
    checked,
    floats,
    instances,
    ints,
)

__all__ = [
    "MAX_SAMPLES",
    "ModelPlacement",
    "PREDICTION_DELAY",
    "SCENE_NAMES",
    "ClientMotion",
    "PathMotion",
    "Scene",
    "Trace",
    "TraceError",
    "TraceMotion",
    "default_samples",
    "load_trace",
]

#: Names of the built-in scenes.
SCENE_NAMES: tuple[str, ...] = tuple(_native.scene_names())
#: Largest number of colour sub-samples per pixel side the renderer takes.
MAX_SAMPLES: int = _native.MAX_SAMPLES
#: How much older the pose the server predicts with is than the client's actual one (seconds).
PREDICTION_DELAY = 0.1
#: Largest trace file read (bytes): 25 s at 60 Hz is about 60 KB.
MAX_TRACE_BYTES = 64 * 1024 * 1024
#: Largest scene description read (bytes): a JSON list of placed models is a few KB.
MAX_DESCRIPTION_BYTES = 16 * 1024 * 1024
_MAX_ANIMATION = 2**32 - 1

F64 = npt.NDArray[np.float64]


def default_samples(width: int, height: int) -> int:
    """The renderer's default colour sub-samples per pixel side for a ``width x height`` camera:
    3 (9 per pixel) up to 640x360 pixels, 2 (4 per pixel) above.

    Colour (server colour, ``S_min``/``S_max``, ground truth) is the box-filtered mean of an
    ``n x n`` ordered grid of sub-samples per pixel; depth, motion and the shadow bits stay at the
    pixel centre (crates/reproj-scene/src/render.rs, "Colour supersampling")."""
    return _native.default_samples(width, height)


def _check_samples(samples: int | None) -> int | None:
    if samples is None:
        return None
    if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= MAX_SAMPLES:
        raise InvalidInputError(
            f"samples: expected an int in 1..{MAX_SAMPLES} per pixel side or None, got {samples!r}"
        )
    return samples


#: What :meth:`Scene.digest` hashes first: the version of its definition.
DIGEST_KIND = "splitrender-scene/1"


def _model_identity(m: ModelPlacement, sha: str, resources: list[str]) -> dict[str, Any]:
    """What :meth:`Scene.digest` takes of the placed model ``m``: its placement, ``sha`` the
    SHA-256 (hex) of its file and ``resources`` that of each file its glTF document references
    by a relative URI (``buffers``, then ``images``, in order; ``data:`` URIs are in the
    document's own bytes), as the native loader read them (``_native.Scene.model_files``)."""
    return {
        # + 0.0: -0.0 as 0.0 (the same placement).
        "position": [float(v) + 0.0 for v in m.position],
        "yaw_deg": m.yaw_deg + 0.0,
        "scale": m.scale,
        "animation": m.animation,
        "time_offset": m.time_offset + 0.0,
        "speed": m.speed,
        "sha256": sha,
        "resources": resources,
    }


class TraceError(InvalidInputError):
    """A head-trace file that cannot be read or is malformed; the message names file and line."""


def _camera_frame(d: dict[str, Any]) -> CameraFrame:
    camera = Camera(d["view"], d["proj"], d["width"], d["height"])
    return CameraFrame(
        camera,
        d["color"],
        d["depth"],
        d["motion_fwd"],
        d["motion_bwd"],
        ShadowBuffers(d["shadow_fwd_bits"], d["shadow_fwd_min"], d["shadow_fwd_max"]),
        ShadowBuffers(d["shadow_bwd_bits"], d["shadow_bwd_min"], d["shadow_bwd_max"]),
    )


@dataclass(frozen=True)
class ModelPlacement:
    """A glTF 2.0 model placed into a built-in scene: scaled by ``scale``, turned by ``yaw_deg``
    about +y, moved to ``position`` (metres); ``animation`` is the index of the glTF animation to
    play (``None``: the rest pose), starting at ``time_offset`` seconds of model time and running
    at ``speed`` model seconds per scene second."""

    path: str
    position: tuple[float, float, float]
    yaw_deg: float = 0.0
    scale: float = 1.0
    animation: int | None = 0
    time_offset: float = 0.0
    speed: float = 1.0

    def __post_init__(self) -> None:
        where = f"ModelPlacement({self.path!r})"
        # An os.PathLike (which check_path takes) as its str: the native Scene takes only a str
        # (a pathlib.Path raised TypeError from Scene(models=...)).
        object.__setattr__(self, "path", os.fspath(check_path(f"{where}.path", self.path)))
        position = check_items(f"{where}.position", self.position, floats())
        if len(position) != 3:
            raise InvalidInputError(
                f"{self.path}: position must be 3 finite numbers, got {self.position}"
            )
        object.__setattr__(self, "position", tuple(position))
        for name in ("yaw_deg", "time_offset"):
            object.__setattr__(self, name, check_float(f"{where}.{name}", getattr(self, name)))
        for name in ("scale", "speed"):
            v = check_float(f"{where}.{name}", getattr(self, name), positive=True)
            object.__setattr__(self, name, v)
        if self.animation is not None:
            # The upper bound keeps the index within the native usize (10**300 raised
            # OverflowError); kept as a plain int (a numpy integer passes the check).
            v = check_int(f"{where}.animation", self.animation, 0, _MAX_ANIMATION)
            object.__setattr__(self, "animation", v)

    def to_native(
        self,
    ) -> tuple[str, tuple[float, float, float], float, float, int | None, float, float]:
        return (
            self.path,
            (float(self.position[0]), float(self.position[1]), float(self.position[2])),
            self.yaw_deg,
            self.scale,
            self.animation,
            self.time_offset,
            self.speed,
        )


class Scene:
    """A built-in scene (:data:`SCENE_NAMES`), ``"static"`` or ``"dynamic"``, built once.

    Raises :class:`~splitrender.errors.InvalidInputError` for an unknown name or variant, listing
    the valid ones."""

    __slots__ = ("_native", "models")

    def __init__(
        self, name: str, variant: str = "dynamic", models: Sequence[ModelPlacement] = ()
    ) -> None:
        if not isinstance(name, str) or not isinstance(variant, str):
            raise InvalidInputError(
                f"Scene: expected name and variant as str, got {name!r}, {variant!r}"
            )
        models = check_items("Scene.models", models)
        for i, m in enumerate(models):
            if not isinstance(m, ModelPlacement):
                raise InvalidInputError(
                    f"Scene: models[{i}]: expected a ModelPlacement, got {type(m).__name__}"
                )
        self.models = tuple(models)
        self._native = _native.Scene(
            name, variant, [m.to_native() for m in self.models] if self.models else None
        )

    @classmethod
    @checked(path=PATH)
    def from_description(cls, path: str | os.PathLike[str]) -> Scene:
        """A scene from a JSON description: a built-in environment and glTF models placed in it::

            {"scene": "courtyard", "variant": "dynamic",
             "models": [{"path": "Fox.glb", "position": [1, 0, -3], "yaw_deg": 90,
                         "scale": 0.02, "animation": 2, "time_offset": 0, "speed": 1}]}

        Model paths are relative to the description's folder. Every key of a model but ``path``
        and ``position`` is optional (defaults as :class:`ModelPlacement`). Each key takes its
        JSON type only: strings for ``scene``, ``variant`` and ``path``, an array of 3 numbers
        for ``position``, numbers (not ``true``/``false`` or a string of digits) for the others.

        Raises:
            InvalidInputError: naming the file and the problem (unreadable, not JSON, unknown or
                missing keys, a value of another JSON type (naming the key and the type
                expected) or out of range, a glTF model that does not load).
        """
        p = Path(path)
        try:
            doc = read_json(p, MAX_DESCRIPTION_BYTES, "scene description", InvalidInputError)
        except OSError as e:
            raise InvalidInputError(f"{p}: cannot read the scene description: {e}") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("scene"), str):
            raise InvalidInputError(f"{p}: expected an object with a \"scene\" name")
        unknown = set(doc) - {"scene", "variant", "models"}
        if unknown:
            raise InvalidInputError(f"{p}: unknown keys {sorted(unknown)}")
        entries = doc.get("models", [])
        if not isinstance(entries, list):
            # A number raised TypeError from enumerate(), a string or object was walked as
            # a sequence of its characters or keys (issue 15, found by the fuzz suite).
            raise InvalidInputError(
                f"{p}: models: expected an array of objects, got {_json_text(entries)}"
            )
        models = []
        for i, m in enumerate(entries):
            if not isinstance(m, dict) or "path" not in m or "position" not in m:
                raise InvalidInputError(f"{p}: models[{i}]: expected an object with path and position")
            extra = set(m) - {"path", "position", "yaw_deg", "scale", "animation", "time_offset", "speed"}
            if extra:
                raise InvalidInputError(f"{p}: models[{i}]: unknown keys {sorted(extra)}")
            try:
                models.append(
                    ModelPlacement(
                        path=str(p.parent / _json_string("path", m["path"])),
                        position=_json_position(m["position"]),
                        yaw_deg=_json_number("yaw_deg", m.get("yaw_deg", 0.0)),
                        scale=_json_number("scale", m.get("scale", 1.0)),
                        animation=_animation_index(m.get("animation", 0)),
                        time_offset=_json_number("time_offset", m.get("time_offset", 0.0)),
                        speed=_json_number("speed", m.get("speed", 1.0)),
                    )
                )
            except (TypeError, ValueError, OverflowError) as e:
                raise InvalidInputError(f"{p}: models[{i}]: {e}") from None
        variant = doc.get("variant", "dynamic")
        if not isinstance(variant, str):
            # str() made null the variant "None", reported as an unknown variant.
            raise InvalidInputError(f"{p}: variant: expected a string, got {_json_text(variant)}")
        try:
            return cls(doc["scene"], variant, models)
        except InvalidInputError as e:
            raise InvalidInputError(f"{p}: {e}") from None

    def __repr__(self) -> str:
        return f"Scene({self.name!r}, {self.variant!r})"

    @property
    def name(self) -> str:
        return self._native.name

    @property
    def variant(self) -> str:
        return self._native.variant

    @property
    def duration(self) -> float:
        """Length of the animation and of the head-box path (seconds)."""
        return self._native.duration

    @property
    def near(self) -> float:
        return self._native.near

    @property
    def far(self) -> float:
        return self._native.far

    @checked(scale=floats(positive=True))
    def main_size(self, scale: float) -> tuple[int, int]:
        """Main camera ``(width, height)`` at ``scale``: ``round(2560·scale) x round(1440·scale)``."""
        return self._native.main_size(scale)

    @checked(scale=floats(positive=True))
    def camera_sizes(self, scale: float) -> list[tuple[int, int]]:
        """The rig's camera sizes at ``scale``, ``[main, left, right]`` as ``(width, height)``,
        without rendering a frame: :meth:`main_size` and the auxiliary cameras of half its
        sides, rounded down, at least 1 (the renderer's own rule)."""
        return self._native.camera_sizes(scale)

    @checked(t=floats())
    def head_box(self, t: float) -> F64:
        """The head box's camera-to-world pose at ``t`` (no deviation)."""
        return self._native.head_box(t)

    @checked(t=floats())
    def client_pose(self, t: float) -> F64:
        """The client's actual camera-to-world pose at ``t`` on the scene's path."""
        return self._native.client_pose(t)

    @checked(k=ints(0, (1 << 31) - 1), fps=floats(positive=True))
    def server_pose(self, k: int, fps: float = 10.0) -> F64:
        """The predicted pose the server renders frame ``k`` at on the scene's path."""
        return self._native.server_pose(k, fps)

    @checked(
        k=ints(0, (1 << 31) - 1), scale=floats(positive=True), fps=floats(positive=True),
        subframes=ints(1, 16),
    )
    def server_frame(
        self,
        k: int,
        scale: float,
        fps: float = 10.0,
        subframes: int = 4,
        *,
        pose: F64 | None = None,
        samples: int | None = None,
    ) -> ServerFrame:
        """Server frame ``k`` (time ``k / fps``): every buffer of the main and both auxiliary
        cameras, rendered at ``pose`` (camera-to-world) or the scene's predicted pose, colour
        from ``samples x samples`` sub-samples per pixel (``None``: :func:`default_samples` of
        each camera's size)."""
        d = self._native.render_server_frame(
            k, scale, fps, subframes, pose, _check_samples(samples)
        )
        return ServerFrame(
            d["index"],
            d["time"],
            _camera_frame(d["main"]),
            tuple(_camera_frame(a) for a in d["aux"]),
        )

    @checked(
        n=ints(0, (1 << 31) - 1), scale=floats(positive=True), fc=floats(positive=True),
        stereo=BOOL,
    )
    def client_frames(
        self,
        n: int,
        scale: float,
        fc: float = 120.0,
        stereo: bool = False,
        *,
        pose: F64 | None = None,
        samples: int | None = None,
    ) -> list[tuple[Camera, npt.NDArray[np.uint8]]]:
        """Ground truth of client frame ``n`` (time ``n / fc``), one ``(camera, image)`` per eye
        (``[left, right]`` when ``stereo``), at ``pose`` or the client's actual pose, with the
        same colour filter as :meth:`server_frame`'s main camera for the same ``samples``."""
        eyes = self._native.render_client_frame(
            n, scale, fc, stereo, pose, _check_samples(samples)
        )
        return [(Camera(v, p, w, h), img) for v, p, w, h, img in eyes]

    @checked(camera=instances(Camera), t=floats())
    def ground_truth(
        self, camera: Camera, t: float, *, samples: int | None = None
    ) -> npt.NDArray[np.uint8]:
        """Ground-truth RGB8 image at any ``camera`` and time ``t``, colour from ``samples x
        samples`` sub-samples per pixel (``None``: :func:`default_samples` of its size)."""
        return self._native.render_ground_truth(*camera.to_native(), t, _check_samples(samples))

    @checked(prediction_delay=floats(lo=0.0, hi=10.0))
    def path_motion(self, prediction_delay: float = PREDICTION_DELAY) -> PathMotion:
        return PathMotion(self, prediction_delay)

    def digest(self) -> bytes:
        """The SHA-256 that identifies what this scene renders (32 bytes): its built-in scene,
        its variant and, per placed model in order, the placement's numbers and the bytes of
        the model file and of every file it references (a ``.gltf``'s buffers and images, a
        ``.glb``'s external ones). Not the model paths or the description's own text: a copy
        of a description and its models in another folder, or reformatted, has the same
        digest; another model file, placement or variant has another. ``splitrender serve``
        sends it in its welcome and ``connect`` compares it with its ``--scene``'s
        (docs/protocol.md, "Scene digest", gives the exact text hashed).

        The files' digests are of the bytes the glTF loader read when this scene was built,
        each file read once (a file changed since has no effect on what this scene renders, nor
        on its digest); it reads no file.
        """
        files = self._native.model_files
        models = [
            _model_identity(m, sha, resources)
            for m, (sha, resources) in zip(self.models, files, strict=True)
        ]
        text = json.dumps(
            {"digest": DIGEST_KIND, "scene": self.name, "variant": self.variant,
             "models": models},
            sort_keys=True, separators=(",", ":"), allow_nan=False, ensure_ascii=True,
        )
        return hashlib.sha256(text.encode("ascii")).digest()


class ClientMotion(Protocol):
    """A source of head poses (camera-to-world ``float64[4, 4]``)."""

    def client_pose(self, t: float) -> F64: ...
    def server_pose(self, k: int, fs: float) -> F64: ...
    def describe(self) -> dict[str, Any]: ...


def _check_delay(prediction_delay: float) -> float:
    d = prediction_delay
    if isinstance(d, bool) or not isinstance(d, (int, float)) or not (math.isfinite(d) and d >= 0):
        raise InvalidInputError(
            f"prediction_delay: expected a finite number of seconds >= 0, got {d!r}"
        )
    return float(d)


class PathMotion:
    """The scene's head-box path with the deterministic anchor deviation (DESIGN.md).

    The server predicts with the deviation ``prediction_delay`` seconds old (default
    :data:`PREDICTION_DELAY`, the renderer's own :meth:`Scene.server_pose`); other delays model
    a server at a higher rate with a shorter prediction window (seeds/000 Fig. 6: 30 FPS with
    33.3 ms, 60 FPS with 16.7 ms). The deviation at ``t`` is ``head_box(t)^-1 · client_pose(t)``,
    so the server pose is ``head_box(t_k) · head_box(t_k - d)^-1 · client_pose(t_k - d)``."""

    __slots__ = ("prediction_delay", "scene")

    def __init__(self, scene: Scene, prediction_delay: float = PREDICTION_DELAY) -> None:
        self.scene = scene
        self.prediction_delay = _check_delay(prediction_delay)

    def client_pose(self, t: float) -> F64:
        return self.scene.client_pose(t)

    def server_pose(self, k: int, fs: float) -> F64:
        if self.prediction_delay == PREDICTION_DELAY:
            return self.scene.server_pose(k, fs)
        t = k / fs
        back = t - self.prediction_delay
        deviation = np.linalg.inv(self.scene.head_box(back)) @ self.scene.client_pose(back)
        out: F64 = self.scene.head_box(t) @ deviation
        return _rigid(out)

    def describe(self) -> dict[str, Any]:
        return {"source": "path", "prediction_delay": self.prediction_delay}


def _rigid(m: F64) -> F64:
    """``m`` with its rotation re-orthonormalised and its last row exactly ``0 0 0 1`` (the
    renderer checks rigidity; products of poses drift by rounding)."""
    out = np.array(m, dtype=np.float64)
    u, _, vt = np.linalg.svd(out[:3, :3])
    out[:3, :3] = u @ vt
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def _quat_from_euler(pitch: F64, yaw: F64, roll: F64) -> F64:
    """``(w, x, y, z)`` of glm's ``quat(vec3(pitch, yaw, roll))`` (radians): ``Rz(roll)·Ry(yaw)·
    Rx(pitch)``, which is how the recording code builds its orientation."""
    cx, sx = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cz, sz = np.cos(roll / 2), np.sin(roll / 2)
    return np.stack(
        [
            cx * cy * cz + sx * sy * sz,
            sx * cy * cz - cx * sy * sz,
            cx * sy * cz + sx * cy * sz,
            cx * cy * sz - sx * sy * cz,
        ],
        axis=-1,
    )


def _quat_matrix(q: F64) -> F64:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass(frozen=True, slots=True, eq=False)
class Trace:
    """A recorded head trace: ``times`` (seconds from the first line), ``positions``
    ``float64[N, 3]`` (metres) and unit quaternions ``rotations`` ``float64[N, 4]`` (w, x, y, z)."""

    name: str
    sha256: str
    times: F64
    positions: F64
    rotations: F64

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @checked(t=floats())
    def pose(self, t: float) -> F64:
        """Camera-to-world pose at ``t`` seconds (clamped to the trace): positions interpolated
        linearly, orientations by normalised quaternion interpolation."""
        ts = self.times
        t = min(max(float(t), 0.0), float(ts[-1]))
        i = int(np.searchsorted(ts, t, side="right")) - 1
        i = min(max(i, 0), len(ts) - 1)
        j = min(i + 1, len(ts) - 1)
        s = 0.0 if j == i else (t - ts[i]) / (ts[j] - ts[i])
        p = (1 - s) * self.positions[i] + s * self.positions[j]
        qa, qb = self.rotations[i], self.rotations[j]
        if float(np.dot(qa, qb)) < 0.0:
            qb = -qb
        q = (1 - s) * qa + s * qb
        m = np.eye(4)
        m[:3, :3] = _quat_matrix(q / np.linalg.norm(q))
        m[:3, 3] = p
        return m


@checked(path=PATH)
def load_trace(path: str | os.PathLike[str]) -> Trace:
    """Reads a head trace: one pose per line, ``px py pz pitch yaw roll t_ms`` (metres, degrees,
    milliseconds, strictly increasing times); blank lines are skipped.

    Raises :class:`TraceError` naming the file (and ``file:line`` for a bad line) and the
    problem."""
    p = Path(path)
    try:
        data = read_regular(p, MAX_TRACE_BYTES, "trace file", TraceError)
    except OSError as e:
        raise TraceError(f"{p}: cannot read trace: {e.strerror or e}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise TraceError(f"{p}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        where = f"{p}:{lineno}"
        if len(fields) != 7:
            raise TraceError(
                f"{where}: expected 7 numbers 'px py pz pitch yaw roll t_ms', got {len(fields)}"
            )
        try:
            row = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not _is_float(f))
            raise TraceError(f"{where}: not a number: {bad!r}") from None
        if not all(math.isfinite(v) for v in row):
            raise TraceError(f"{where}: non-finite value in {line.strip()!r}")
        if rows and row[6] <= rows[-1][6]:
            raise TraceError(
                f"{where}: time {row[6]} ms is not after the previous line's {rows[-1][6]} ms"
            )
        rows.append(row)
    if not rows:
        raise TraceError(f"{p}: empty trace (no pose lines)")
    a = np.array(rows, dtype=np.float64)
    q = _quat_from_euler(*np.radians(a[:, 3:6]).T)
    return Trace(
        name=p.name,
        sha256=hashlib.sha256(data).hexdigest(),
        times=(a[:, 6] - a[0, 6]) / 1000.0,
        positions=a[:, 0:3].copy(),
        rotations=q,
    )


def _animation_index(v: object) -> int | None:
    """A description's ``animation``: null or a whole number (``int()`` of 1e400, which JSON
    parses as infinity, raised OverflowError)."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v):
        raise ValueError(f"animation: expected an integer >= 0 or null, got {v!r}")
    return int(v)


def _json_text(value: object) -> str:
    """A JSON value as a message names it: its kind and its (shortened) text."""
    text = json.dumps(value)
    if len(text) > 40:
        text = text[:37] + "..."
    if value is None or isinstance(value, bool):
        return text  # null, true, false
    return f"{JSON_KINDS.get(type(value), type(value).__name__)} {text}"


# A description's values are taken with their JSON type only: float() took true as 1.0 and the
# string "2" as 2.0, and tuple() walked the string "123" as the position (1, 2, 3). The
# ValueError is named after the model by Scene.from_description, as _animation_index's is.


def _is_number(value: object) -> TypeGuard[int | float]:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _json_number(key: str, value: object) -> float:
    """A description's number ``key`` (an int or a float; its range is ModelPlacement's)."""
    if not _is_number(value):
        raise ValueError(f"{key}: expected a number, got {_json_text(value)}")
    return value  # an int as it is: ModelPlacement converts it (and refuses one too large)


def _json_position(value: object) -> tuple[float, float, float]:
    """A description's ``position``: an array of exactly 3 numbers."""
    if not (isinstance(value, list) and len(value) == 3 and all(map(_is_number, value))):
        raise ValueError(f"position: expected an array of 3 numbers, got {_json_text(value)}")
    return (value[0], value[1], value[2])


def _json_string(key: str, value: object) -> str:
    """A description's string ``key`` (str() made 3 the path "3")."""
    if not isinstance(value, str):
        raise ValueError(f"{key}: expected a string, got {_json_text(value)}")
    return value


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class TraceMotion:
    """A head trace re-anchored at the scene's head box at ``t = 0``; ``translation_scale``
    scales the trace's motion (e.g. < 1 for a scene smaller than the one it was recorded in)."""

    __slots__ = ("_anchor", "_inv0", "prediction_delay", "trace", "translation_scale")

    def __init__(
        self,
        scene: Scene,
        trace: Trace,
        translation_scale: float = 1.0,
        prediction_delay: float = PREDICTION_DELAY,
    ) -> None:
        self.trace = trace
        self.translation_scale = check_float("translation_scale", translation_scale, lo=0.0)
        self.prediction_delay = _check_delay(prediction_delay)
        self._anchor = scene.head_box(0.0)
        self._inv0 = np.linalg.inv(trace.pose(0.0))

    def client_pose(self, t: float) -> F64:
        rel = self._inv0 @ self.trace.pose(t)
        rel[:3, 3] *= self.translation_scale
        # Re-orthonormalise the rotation so the renderer's rigidity check holds after products.
        return _rigid(self._anchor @ rel)

    def server_pose(self, k: int, fs: float) -> F64:
        return self.client_pose(k / fs - self.prediction_delay)

    def describe(self) -> dict[str, Any]:
        return {
            "source": "trace",
            "file": self.trace.name,
            "sha256": self.trace.sha256,
            "translation_scale": self.translation_scale,
            "prediction_delay": self.prediction_delay,
        }
