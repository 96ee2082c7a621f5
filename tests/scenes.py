"""Tiny analytic scenes in pure numpy (no native code), for the property tests.

Everything follows shared/DESIGN.md "Conventions": right-handed world, +y up, a camera looks along
its −z; row-major ``H×W`` images with row 0 at the top; pixel centre of column ``i``, row ``j`` at
NDC ``x = (2i+1)/W − 1``, ``y = 1 − (2j+1)/H``; reversed depth ``Z = n(f − d)/(d(f − n))`` (1 at the
near plane, 0 at the far plane); matrices act on column vectors, ``P = proj @ view``.

A scene is a list of :class:`Card`: axis-aligned textured rectangles (possibly infinite) in a
plane ``z = const`` facing the +z axis, moving at a constant world velocity in x/y per server
interval. Depth, colour and object motion are exact for any camera and time, by ray casting the
cards analytically (nearest hit wins). The texture is piecewise constant: square cells of a given
world size, each with a pseudo-random RGB8 colour, attached to the card (it moves with it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

NEAR = 0.1
FAR = 100.0


# --------------------------------------------------------------------------------------------
# Camera matrices (the same formulas as reproj-core `Mat4::perspective` / `Mat4::look_at`).
# --------------------------------------------------------------------------------------------


def perspective(
    fov_y_deg: float, aspect: float, near: float = NEAR, far: float = FAR
) -> np.ndarray:
    """Reversed-depth perspective projection with a finite far plane (DESIGN.md)."""
    fy = 1.0 / math.tan(math.radians(fov_y_deg) * 0.5)
    a = near / (far - near)
    b = near * far / (far - near)
    return np.array(
        [
            [fy / aspect, 0.0, 0.0, 0.0],
            [0.0, fy, 0.0, 0.0],
            [0.0, 0.0, a, b],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def look_at(
    eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 1.0, 0.0)
) -> np.ndarray:
    """World→camera matrix of a camera at ``eye`` looking at ``target`` (looks along its −z)."""
    eye = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    x = np.cross(f, np.asarray(up, dtype=np.float64))
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    z = -f
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = x, y, z
    m[0, 3], m[1, 3], m[2, 3] = -x @ eye, -y @ eye, -z @ eye
    return m


def yawed_target(eye: Sequence[float], yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """A look-at target one metre from ``eye``: looking down −z, yawed left (+) about +y, pitched up."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    d = np.array(
        [-math.sin(yaw) * math.cos(pitch), math.sin(pitch), -math.cos(yaw) * math.cos(pitch)]
    )
    return np.asarray(eye, dtype=np.float64) + d


@dataclasses.dataclass(frozen=True)
class Cam:
    """A plain camera (duck-types ``sr.Camera``: ``view``, ``proj``, ``width``, ``height``)."""

    view: np.ndarray
    proj: np.ndarray
    width: int
    height: int

    @staticmethod
    def make(eye, target, *, fov_y_deg=60.0, width=64, height=48, near=NEAR, far=FAR) -> Cam:
        return Cam(
            look_at(eye, target), perspective(fov_y_deg, width / height, near, far), width, height
        )

    @property
    def vp(self) -> np.ndarray:
        return np.asarray(self.proj, dtype=np.float64) @ np.asarray(self.view, dtype=np.float64)

    @property
    def eye(self) -> np.ndarray:
        return np.linalg.inv(np.asarray(self.view, dtype=np.float64))[:3, 3]


def as_cam(camera) -> Cam:
    """Any object with ``view``/``proj``/``width``/``height`` (e.g. ``sr.Camera``) as a :class:`Cam`."""
    return Cam(
        np.asarray(camera.view, dtype=np.float64),
        np.asarray(camera.proj, dtype=np.float64),
        int(camera.width),
        int(camera.height),
    )


def pixel_ndc(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """NDC ``x``, ``y`` of every pixel centre, each ``H×W`` float64."""
    i = np.arange(width, dtype=np.float64)
    j = np.arange(height, dtype=np.float64)
    x = (2.0 * i + 1.0) / width - 1.0
    y = 1.0 - (2.0 * j + 1.0) / height
    return np.broadcast_to(x[None, :], (height, width)), np.broadcast_to(
        y[:, None], (height, width)
    )


def project(vp: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NDC ``(x, y, Z)`` of world points ``[..., 3]`` and their clip ``w``."""
    h = pts @ vp[:3, :3].T + vp[:3, 3]
    w = pts @ vp[3, :3] + vp[3, 3]
    return h / w[..., None], w


def unproject(vp: np.ndarray, ndc: np.ndarray) -> np.ndarray:
    """World points ``P⁻¹(x, y, Z, 1)`` (float64, with the perspective division)."""
    inv = np.linalg.inv(vp)
    h = ndc @ inv[:, :3].T + inv[:, 3]
    return h[..., :3] / h[..., 3:4]


# --------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------


def _mix(v: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    v = v.astype(np.uint64)
    with np.errstate(over="ignore"):
        v = (v ^ (v >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        v = (v ^ (v >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        v = v ^ (v >> np.uint64(31))
    return v


def cell_colors(seed: int, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """A pseudo-random RGB8 colour per integer texture cell ``(ix, iy)``."""
    with np.errstate(over="ignore"):
        k = (
            np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15)
            + ix.astype(np.int64).astype(np.uint64) * np.uint64(0xD1B54A32D192ED03)
            + iy.astype(np.int64).astype(np.uint64) * np.uint64(0x8CB92BA72F3D8DD7)
        )
    h = _mix(k)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(0xFF) for s in (0, 8, 16)], axis=-1)
    return rgb.astype(np.uint8)


# --------------------------------------------------------------------------------------------
# Cards and scenes
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Card:
    """A textured rectangle in the plane ``z = z`` (world), facing +z.

    ``x0..x1``, ``y0..y1`` are its extent at time 0 (infinite by default); it moves by
    ``velocity`` (world x/y per server interval), so at time ``τ`` it is displaced by ``τ·velocity``
    and its texture moves with it. ``cell`` is the texture's cell size in metres.
    """

    z: float
    cell: float
    seed: int = 0
    x0: float = -math.inf
    x1: float = math.inf
    y0: float = -math.inf
    y1: float = math.inf
    velocity: tuple[float, float] = (0.0, 0.0)

    @property
    def moving(self) -> bool:
        return self.velocity != (0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class Hit:
    """Per-pixel ray-cast result of one camera at one time."""

    color: np.ndarray  # H×W×3 uint8
    depth: np.ndarray  # H×W float32, reversed depth (0 = background at the far plane)
    card: np.ndarray  # H×W int, index of the card hit, −1 for none
    point: np.ndarray  # H×W×3 float64 world point (NaN where no card)


BACKGROUND = np.array([0, 0, 0], dtype=np.uint8)


def cast(cards: Sequence[Card], camera, time: float = 0.0) -> Hit:
    """Ray-casts ``cards`` at ``time`` from ``camera`` through every pixel centre (exact)."""
    cam = as_cam(camera)
    vp = cam.vp
    x, y = pixel_ndc(cam.width, cam.height)
    near_pt = unproject(vp, np.stack([x, y, np.ones_like(x)], axis=-1))
    far_pt = unproject(vp, np.stack([x, y, np.zeros_like(x)], axis=-1))
    origin = cam.eye
    d = far_pt - near_pt
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    h, w = cam.height, cam.width
    best_t = np.full((h, w), np.inf)
    card_idx = np.full((h, w), -1, dtype=np.int64)
    for k, c in enumerate(cards):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c.z - origin[2]) / d[..., 2]
        p = origin + t[..., None] * d
        ox, oy = c.velocity[0] * time, c.velocity[1] * time
        inside = (
            (t > 0)
            & (p[..., 0] - ox >= c.x0)
            & (p[..., 0] - ox < c.x1)
            & (p[..., 1] - oy >= c.y0)
            & (p[..., 1] - oy < c.y1)
        )
        better = inside & (t < best_t)
        best_t = np.where(better, t, best_t)
        card_idx = np.where(better, k, card_idx)
    point = origin + np.where(np.isfinite(best_t), best_t, np.nan)[..., None] * d
    ndc, _ = project(vp, point)
    # Geometry beyond the far plane (or in front of the near plane) is not rendered.
    visible = (card_idx >= 0) & (ndc[..., 2] >= 0.0) & (ndc[..., 2] <= 1.0)
    card_idx = np.where(visible, card_idx, -1)
    depth = np.where(visible, ndc[..., 2], 0.0).astype(np.float32)
    color = np.broadcast_to(BACKGROUND, (h, w, 3)).copy()
    for k, c in enumerate(cards):
        m = card_idx == k
        if not m.any():
            continue
        u = point[m, 0] - c.velocity[0] * time
        v = point[m, 1] - c.velocity[1] * time
        color[m] = cell_colors(c.seed, np.floor(u / c.cell), np.floor(v / c.cell))
    point = np.where((card_idx >= 0)[..., None], point, np.nan)
    return Hit(color=color, depth=depth, card=card_idx, point=point)


def motion(cards: Sequence[Card], camera, hit: Hit, dt: float) -> np.ndarray | None:
    """Object motion ``O[p] = P(X + dt·v) − P(X)`` in ``camera``'s NDC (DESIGN.md), ``float32``.

    ``dt = +1`` gives the forward motion of a frame at the older time, ``dt = −1`` the backward
    motion of the newer frame. Exactly zero on static cards; ``None`` when nothing moves.
    """
    if not any(c.moving for c in cards):
        return None
    cam = as_cam(camera)
    vp = cam.vp
    out = np.zeros(hit.card.shape + (3,), dtype=np.float64)
    for k, c in enumerate(cards):
        m = hit.card == k
        if not (c.moving and m.any()):
            continue
        x = hit.point[m]
        x2 = x + dt * np.array([c.velocity[0], c.velocity[1], 0.0])
        a, _ = project(vp, x)
        b, _ = project(vp, x2)
        out[m] = b - a
    return out.astype(np.float32)


def plane(depth: float, cell: float, seed: int = 0) -> list[Card]:
    """A single infinite textured plane at world ``z = −depth``."""
    return [Card(z=-depth, cell=cell, seed=seed)]


def cell_for_pixels(camera_distance: float, fov_y_deg: float, height: int, pixels: float) -> float:
    """Texture cell size (metres) that spans ``pixels`` pixels at ``camera_distance``."""
    return pixels * 2.0 * camera_distance * math.tan(math.radians(fov_y_deg) / 2.0) / height


def card_scene(
    seed: int = 0, *, back: float = 4.0, front: float = 2.0, velocity=(0.0, 0.0), cell=0.12
) -> list[Card]:
    """An infinite background plane at ``z = −back`` and a 0.8×0.6 m card at ``z = −front``."""
    return [
        Card(z=-back, cell=cell * back / front, seed=seed),
        Card(
            z=-front,
            cell=cell,
            seed=seed + 1,
            x0=-0.4,
            x1=0.4,
            y0=-0.3,
            y1=0.3,
            velocity=tuple(velocity),
        ),
    ]


# --------------------------------------------------------------------------------------------
# Random static frames (arbitrary depth maps; no geometric consistency needed)
# --------------------------------------------------------------------------------------------


def random_color(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    return rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)


def random_depth(
    rng: np.random.Generator,
    height: int,
    width: int,
    *,
    blocks: int = 4,
    far_plane: bool = False,
    near_plane: bool = False,
) -> np.ndarray:
    """A piecewise-constant-plus-noise reversed depth map in ``(0, 1)`` (discontinuities included).

    ``far_plane`` / ``near_plane`` put some blocks exactly at ``Z = 0`` (the far plane, where
    DESIGN.md puts the background) / ``Z = 1`` (the near plane); both are valid depths.
    """
    by = rng.integers(1, blocks + 1)
    bx = rng.integers(1, blocks + 1)
    coarse = rng.uniform(0.005, 0.5, size=(by, bx))
    rows = np.minimum((np.arange(height) * by) // height, by - 1)
    cols = np.minimum((np.arange(width) * bx) // width, bx - 1)
    z = coarse[rows][:, cols] * (1.0 + 0.05 * rng.standard_normal((height, width)))
    z = np.clip(z, 1e-4, 1.0)
    kind = rng.integers(0, 3, size=(by, bx))[rows][:, cols]  # 0: keep, 1: far plane, 2: near plane
    if far_plane:
        z = np.where(kind == 1, 0.0, z)
    if near_plane:
        z = np.where(kind == 2, 1.0, z)
    return z.astype(np.float32)


def random_shadow(rng: np.random.Generator, height: int, width: int, *, density: float = 0.3):
    """Random shadow buffers ``(bits u32, s_min u8, s_max u8)``; ``density`` of the bitfields nonzero."""
    bits = rng.integers(0, 2**32, size=(height, width), dtype=np.uint64).astype(np.uint32)
    bits[rng.random((height, width)) >= density] = 0
    s_min = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    s_max = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    return bits, s_min, s_max
