"""Pure-numpy reference implementations, written from seeds/000 and shared/DESIGN.md.

- :func:`scene_flow`: eqs. 1, 12, 13 in float64 — unproject ``p̄`` and ``p̄ + O`` with ``P⁻¹``,
  interpolate linearly in world space by ``w``, project with the client ``P``:
  ``M_cam[p] = P_client(X + w·(P⁻¹(p̄+O) − P⁻¹(p̄))) − p̄``.
- :func:`shadow_color` / :func:`apply_shadows`: eqs. 9–11 with the edge-interval rules of
  REFERENCE.md §2.9 as the core applies them (see ``crates/reproj-core/src/shadow.rs``).

Vectorised, no native code.
"""

from __future__ import annotations

import numpy as np
from scenes import pixel_ndc

# --------------------------------------------------------------------------------------------
# Scene flow (eqs. 1, 12, 13)
# --------------------------------------------------------------------------------------------


def scene_flow(view, proj, depth, motion, client_view, client_proj, w):
    """Camera scene flow of every source pixel into the client, float64.

    Returns ``(flow, client_w)``: ``flow`` is ``H×W×3`` ``(Δx, Δy, ΔZ)`` in NDC, NaN where the pixel
    is invalid (non-finite depth or motion, depth outside ``[0, 1]``) or the moved point is not in
    front of the client camera (clip ``w ≤ 0``); ``client_w`` is that clip ``w`` (for callers that
    want to stay clear of the ``w = 0`` plane when comparing against float32 code).
    """
    depth = np.asarray(depth, dtype=np.float64)
    h, wd = depth.shape
    p = np.asarray(proj, dtype=np.float64) @ np.asarray(view, dtype=np.float64)
    pc = np.asarray(client_proj, dtype=np.float64) @ np.asarray(client_view, dtype=np.float64)
    inv = np.linalg.inv(p)
    x, y = pixel_ndc(wd, h)
    pbar = np.stack([x, y, depth, np.ones_like(depth)], axis=-1)
    if motion is None:
        o = np.zeros((h, wd, 3))
    else:
        o = np.asarray(motion, dtype=np.float64)
    valid = np.isfinite(depth) & (depth >= 0.0) & (depth <= 1.0) & np.isfinite(o).all(axis=-1)
    # Keep invalid pixels out of the arithmetic (their result is NaN anyway).
    pbar = np.where(valid[..., None], pbar, np.array([0.0, 0.0, 0.5, 1.0]))
    o = np.where(valid[..., None], o, 0.0)

    def unproj(q):
        hh = q @ inv.T
        return hh[..., :3] / hh[..., 3:4]

    x0 = unproj(pbar)
    x1 = unproj(pbar + np.concatenate([o, np.zeros((h, wd, 1))], axis=-1))
    xt = x0 + w * (x1 - x0)
    hc = xt @ pc[:, :3].T + pc[:, 3]
    cw = hc[..., 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = hc[..., :3] / cw[..., None]
    flow = ndc - pbar[..., :3]
    ok = valid & (cw > 0.0) & np.isfinite(flow).all(axis=-1)
    flow[~ok] = np.nan
    return flow, np.where(valid, cw, np.nan)


# --------------------------------------------------------------------------------------------
# Dynamic shadows (eqs. 9–11)
# --------------------------------------------------------------------------------------------


def levels(bits, subframes: int) -> np.ndarray:
    """``L_j = (Φ ≫ 2j) & 3`` for ``j < S``, shape ``[..., S]``."""
    b = np.asarray(bits, dtype=np.uint64)[..., None]
    j = np.arange(subframes, dtype=np.uint64)
    return ((b >> (np.uint64(2) * j)) & np.uint64(3)).astype(np.int64)


def subframe_color(base, bits, s_min, s_max, j: int, subframes: int) -> np.ndarray:
    """``C(j)`` (eq. 10 and the inner ``lerp`` of eq. 11), float64 ``[..., 3]``.

    The key frame (``j = 0``), subframes the buffer does not hold (``j ≥ S``), bitfield 0 and
    equal levels everywhere (``L_max = L_min``, where eq. 10 would be 0/0) give the key colour.
    ``A′``/``B′`` are ``S_min``/``S_max``, or the key colour where that extreme is the key frame's
    own level (DESIGN.md: then the stored colour is 0 and must not be used).
    """
    base = np.asarray(base, dtype=np.float64)
    if j == 0 or j >= subframes:
        return base.copy()
    lv = levels(bits, subframes)
    l0 = lv[..., 0]
    lmin, lmax = lv.min(axis=-1), lv.max(axis=-1)
    flat = (np.asarray(bits) == 0) | (lmax == lmin)
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(flat, 0.0, (lv[..., j] - lmin) / np.where(flat, 1, lmax - lmin))
    a = np.where((lmin == l0)[..., None], base, np.asarray(s_min, dtype=np.float64))
    b = np.where((lmax == l0)[..., None], base, np.asarray(s_max, dtype=np.float64))
    c = a + tau[..., None] * (b - a)
    return np.where(flat[..., None], base, c)


def shadow_color(
    base, bits, s_min, s_max, alpha, subframes: int = 4, role: str = "older"
) -> np.ndarray:
    """``c_S`` at ``α`` (eqs. 9–11), float64 ``[..., 3]`` before rounding.

    ``β = S·α`` (computed in float32 like the kernels, so that the interval choice agrees exactly
    at the interval boundaries), ``lo = ⌊β⌋``, ``hi = ⌈β⌉``, ``λ = β − lo``. Subframes map to buffer
    indices ``j = lo, hi`` for the older image (forward buffer, subframe ``j`` at ``t + j/S``) and
    ``j = S − lo, S − hi`` for the newer image (backward buffer, at ``t+1 − j/S``). Edge intervals
    that would need a subframe the buffer lacks hold subframe ``S − 1``; ``lo ≥ S`` (extrapolation)
    and ``hi = 0`` (``α = 0``) give the key colour.
    """
    base = np.asarray(base, dtype=np.float64)
    s = int(subframes)
    beta = float(np.float32(s) * np.float32(alpha))
    lo, hi = np.floor(beta), np.ceil(beta)
    if not (lo < s and hi > 0):
        return base.copy()
    lam = beta - lo
    lo_i, hi_i = int(lo), int(hi)
    if role == "older":
        j_lo, j_hi = lo_i, hi_i
    elif role == "newer":
        j_lo, j_hi = s - lo_i, s - hi_i
    else:
        raise ValueError(role)

    def c(j):
        return subframe_color(base, bits, s_min, s_max, j, s)

    if j_lo == j_hi or j_hi >= s:
        return c(j_lo)
    if j_lo >= s:
        return c(j_hi)
    a, b = c(j_lo), c(j_hi)
    return a + lam * (b - a)


def round_rgb(c) -> np.ndarray:
    """Round half up (the values are ≥ 0) and clamp to RGB8 (colours are rounded, not truncated)."""
    return np.clip(np.floor(np.asarray(c, dtype=np.float64) + 0.5), 0, 255).astype(np.uint8)


def apply_shadows(
    color, bits, s_min, s_max, alpha, subframes: int = 4, role: str = "older"
) -> np.ndarray:
    """Eqs. 9–11 over a whole image, RGB8."""
    return round_rgb(shadow_color(color, bits, s_min, s_max, alpha, subframes, role))
