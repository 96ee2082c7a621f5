"""The synthetic two-frame dynamic scene (issue #2): quality ranking, determinism, invalid depth.

A textured sphere and a bobbing cube move in front of a textured wall and floor, with soft dynamic
shadows (reproj-core ``synthetic``). The client camera is off the server path: the rig's main
camera at a time between the two server frames, moved 5 cm sideways and yawed 2°. Main 320×180,
auxiliary cameras 160×90, so each reprojection takes milliseconds.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import scenes
import splitrender as sr
from splitrender import _native as native

W, H = 320, 180
FPS = 10.0
K = 3  # the older server frame's index
ALPHA = 0.5
NONE = sr.Reprojection.SOURCE_NONE


def yaw_matrix(deg: float) -> np.ndarray:
    s, c = math.sin(math.radians(deg)), math.cos(math.radians(deg))
    return np.array(
        [[c, 0.0, s, 0.0], [0.0, 1.0, 0.0, 0.0], [-s, 0.0, c, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )


def offset_camera(cam: sr.Camera, sideways: float, yaw_deg: float) -> sr.Camera:
    """``cam`` moved ``sideways`` metres along its own x axis and yawed ``yaw_deg`` degrees."""
    t = np.eye(4)
    t[0, 3] = -sideways
    view = yaw_matrix(-yaw_deg) @ t @ np.asarray(cam.view, dtype=np.float64)
    return sr.Camera(view, np.asarray(cam.proj, dtype=np.float64), cam.width, cam.height)


@functools.lru_cache(maxsize=4)
def build(k: int, alpha: float):
    """Server frames ``k`` and ``k+1``, the off-path client at ``t_k + α·Δ`` and its ground truth."""
    scene = sr.SyntheticScene(dynamic=True)
    t0, t1 = k / FPS, (k + 1) / FPS
    t = t0 + alpha * (t1 - t0)
    older = scene.server_frame(k, t0, W, H, fps=FPS, subframes=4)
    newer = scene.server_frame(k + 1, t1, W, H, fps=FPS, subframes=4)
    main, _aux = scene.rig(t, W, H)
    client = offset_camera(main, 0.05, 2.0)
    truth = np.asarray(scene.ground_truth(client, t))
    return scene, older, newer, client, t, truth


@pytest.fixture
def setup():
    return build(K, ALPHA)


def black() -> np.ndarray:
    return np.zeros((H, W, 3), dtype=np.uint8)


def mae(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


@pytest.mark.parametrize(("k", "alpha"), [(K, ALPHA), (7, 0.25), (12, 0.75)])
def test_ours_beats_every_baseline_on_the_synthetic_dynamic_scene(k, alpha):
    _, older, newer, client, t, truth = build(k, alpha)
    request = sr.ClientRequest(client, t)
    assert truth.shape == (H, W, 3)
    results: dict[str, float] = {}
    images: dict[str, np.ndarray] = {}

    def record(name, image):
        image = np.asarray(image)
        assert image.shape == (H, W, 3) and image.dtype == np.uint8
        images[name] = image
        results[name] = mae(image, truth)

    record("ours", sr.reproject(older, newer, request, "ours", previous=black()))
    # The paper's splatting baseline (and timewarp) are unidirectional: `reproject` runs them from
    # the newest frame at or before the display time, F_k, with α = 1 + alpha (seeds/000 §4.2).
    record("forward_splat", sr.reproject(older, newer, request, "forward_splat", previous=black()))
    # The stronger variant: splat both frames of the same pair as ours (no FPI, no blending).
    record(
        "forward_splat (bidirectional)",
        sr.reproject(
            older,
            newer,
            request,
            "forward_splat",
            options=sr.ReprojectOptions(splat_bidirectional=True),
            previous=black(),
        ),
    )
    record("timewarp", sr.reproject(older, newer, request, "timewarp", previous=black()))
    record(
        "backward_bidir", sr.reproject(older, newer, request, "backward_bidir", previous=black())
    )
    figures = ", ".join(f"{k}: {v:.3f}" for k, v in results.items())
    # A stub that writes nothing leaves the black previous frame: report that plainly.
    stubs = [k for k, img in images.items() if not img.any()]
    ours = results["ours"]
    # Sanity against garbage: far below the error of an all-black frame (≈ 114 here).
    black_mae = mae(black(), truth)
    assert ours < 0.25 * black_mae, (
        f"ours is far from the ground truth (MAE {ours:.3f}, black {black_mae:.1f}); all: {figures}"
    )
    for name, value in results.items():
        if name == "ours":
            continue
        assert ours < value, (
            f"frames {k}/{k + 1}, alpha={alpha}: ours (MAE {ours:.3f}) does not beat {name} "
            f"(MAE {value:.3f}); all: {figures}"
            + (f"; methods that wrote nothing (stubs?): {stubs}" if stubs else "")
        )
    # The whole-image MAE is mostly the static surfaces' resampling error (ours ≈ 10.5 here):
    # object motion handled wrongly moves it by under 10 % and ours still wins. On the pixels
    # that show a moving object at the client pose (from the native renderer, not from the
    # Python wiring under test) ours measured 16.5–18.5 and the baselines 33–57; object motion
    # ignored (zero) or the backward motion buffer replaced by the forward one gave 25.8–44.
    moving = _moving_pixels(client, t)
    assert moving.sum() > 1000, f"only {moving.sum()} moving pixels: the check would be vacuous"
    on_moving = {name: mae(img[moving], truth[moving]) for name, img in images.items()}
    shown = ", ".join(f"{k}: {v:.2f}" for k, v in on_moving.items())
    assert on_moving["ours"] < 24.0, f"ours on the moving objects: {shown}"
    for name, value in on_moving.items():
        assert name == "ours" or on_moving["ours"] < value, f"on the moving objects: {shown}"


def _moving_pixels(client: sr.Camera, t: float) -> np.ndarray:
    """Pixels of ``client`` at ``t`` that see a moving object (non-zero object motion)."""
    b = native.synthetic_render_server(True, client.to_native(), t, 1.0 / FPS, 4)
    return np.asarray((b["motion_fwd"] != 0).any(axis=-1) | (b["motion_bwd"] != 0).any(axis=-1))


def test_ours_is_deterministic(setup):
    _, older, newer, client, t, _ = setup
    request = sr.ClientRequest(client, t)
    prev = np.random.default_rng(7).integers(0, 256, (H, W, 3), dtype=np.uint8)
    a = sr.reproject(older, newer, request, "ours", previous=prev, diagnostics=True)
    b = sr.reproject(older, newer, request, "ours", previous=prev.copy(), diagnostics=True)
    assert np.asarray(a.image).tobytes() == np.asarray(b.image).tobytes()
    assert np.asarray(a.source).tobytes() == np.asarray(b.source).tobytes()
    assert np.asarray(a.error).tobytes() == np.asarray(b.error).tobytes()
    # The previous frame passed in is not modified in place.
    assert (prev == np.random.default_rng(7).integers(0, 256, (H, W, 3), dtype=np.uint8)).all()


def with_depth(frame, mask_fn):
    """``frame`` with the depth of every camera replaced where ``mask_fn(camera_index, shape)``."""
    cams = [frame.main, *frame.aux]
    out = []
    for k, cf in enumerate(cams):
        depth = np.array(cf.depth, dtype=np.float32, copy=True)
        depth[mask_fn(k, depth.shape)] = np.nan
        out.append(
            sr.CameraFrame(
                cf.camera,
                cf.color,
                depth,
                motion_fwd=cf.motion_fwd,
                motion_bwd=cf.motion_bwd,
                shadow_fwd=cf.shadow_fwd,
                shadow_bwd=cf.shadow_bwd,
            )
        )
    return sr.ServerFrame(frame.index, frame.time, out[0], tuple(out[1:]))


def test_all_nan_depth_keeps_the_previous_frame(setup):
    _, older, newer, client, t, _ = setup
    everywhere = lambda k, shape: np.ones(shape, dtype=bool)
    o, n = with_depth(older, everywhere), with_depth(newer, everywhere)
    prev = np.random.default_rng(3).integers(0, 256, (H, W, 3), dtype=np.uint8)
    r = sr.reproject(
        o, n, sr.ClientRequest(client, t), "ours", previous=prev.copy(), diagnostics=True
    )
    assert (np.asarray(r.source) == NONE).all()
    assert np.isnan(np.asarray(r.error)).all()
    assert np.asarray(r.image).tobytes() == prev.tobytes()


def _project_pixels(cam, pts):
    """Pixel coordinates (float, column/row) of world points in ``cam`` and whether in front."""
    c = scenes.as_cam(cam)
    ndc, w = scenes.project(c.vp, pts)
    col = (ndc[..., 0] + 1.0) * 0.5 * c.width
    row = (1.0 - ndc[..., 1]) * 0.5 * c.height
    return col, row, w > 0


def test_nan_depth_region_keeps_the_previous_frame(setup):
    """A block of NaN depth on the wall in both main images (no auxiliary cameras): client pixels
    that see a point inside that block in both frames (3 px inside its border, beyond ε_e) keep the
    previous frame exactly; pixels that see points well outside it (in both frames) are unaffected;
    nothing else is garbage (every matched pixel has a finite error below ε_e)."""
    scene, older, newer, client, t, _ = setup
    r0, r1, c0, c1 = 10, 90, 20, 140  # upper-left part of the main images: the back wall
    block = lambda k, shape: (
        (np.arange(shape[0])[:, None] >= r0)
        & (np.arange(shape[0])[:, None] < r1)
        & (np.arange(shape[1])[None, :] >= c0)
        & (np.arange(shape[1])[None, :] < c1)
        & (k == 0)
    )
    o, n = with_depth(older, block), with_depth(newer, block)
    request = sr.ClientRequest(client, t)
    opts = sr.ReprojectOptions(use_aux=False)
    prev = np.random.default_rng(5).integers(0, 256, (H, W, 3), dtype=np.uint8)
    bad = sr.reproject(o, n, request, "ours", options=opts, previous=prev.copy(), diagnostics=True)
    clean = sr.reproject(
        older, newer, request, "ours", options=opts, previous=prev.copy(), diagnostics=True
    )
    img, src, err = np.asarray(bad.image), np.asarray(bad.source), np.asarray(bad.error)

    # Where the client sees each pixel's surface point; on static surfaces (zero motion) it is the
    # same world point at both server times. The client-pose depth comes from the scene renderer.
    cam = scenes.as_cam(client)
    at_client = scene.render(client, t, fps=FPS)
    depth = np.asarray(at_client.depth)
    static = (np.asarray(at_client.motion_fwd) == 0).all(axis=-1) & (
        np.asarray(at_client.motion_bwd) == 0
    ).all(axis=-1)
    x, y = scenes.pixel_ndc(W, H)
    pts = scenes.unproject(cam.vp, np.stack([x, y, depth.astype(np.float64)], axis=-1))
    deep = static.copy()
    clear = np.ones((H, W), dtype=bool)
    for frame in (older, newer):
        col, row, front = _project_pixels(frame.main.camera, pts)
        deep &= front & (col >= c0 + 3) & (col < c1 - 3) & (row >= r0 + 3) & (row < r1 - 3)
        inside_grown = (col >= c0 - 4) & (col < c1 + 4) & (row >= r0 - 4) & (row < r1 + 4)
        clear &= ~inside_grown
    assert deep.sum() > 500, (
        f"the NaN block covers only {deep.sum()} client pixels; the test would be vacuous"
    )
    assert (src[deep] == NONE).all(), (
        f"{(src[deep] != NONE).sum()} pixels matched a NaN-depth source pixel"
    )
    assert (img[deep] == prev[deep]).all()
    # Nothing else is garbage: every pixel is either the previous frame (no match) or a match with a
    # finite error, and its colour stays as close to the ground truth as without the NaN block.
    assert (img[src == NONE] == prev[src == NONE]).all()
    assert np.isfinite(err[src != NONE]).all()
    # Below ε_e, which reproj-core gives at the paper's 1440-pixel short side and scales to keep
    # its size in pixels: 0.002 · 1440 / 180 here (aspect-scaled NDC, like the error).
    eps_e = opts.eps_e * 1440 / min(W, H)
    assert (err[src != NONE] < eps_e).all(), float(np.nanmax(err))
    same = (img == np.asarray(clean.image)).all(axis=-1)
    assert same[clear].mean() >= 0.999, (
        f"{(~same & clear).sum()} pixels far from the NaN block changed when it was introduced"
    )


@pytest.mark.parametrize("k", [3, 12])
def test_shadow_buffers_bring_the_key_colour_towards_the_ground_truth(k):
    """The synthetic scene's shadow buffers, applied at ``α`` (eqs. 9–11), give static pixels
    under a moving shadow a colour nearer the ground truth at ``t_k + α·Δ`` (same camera) than
    the key colour: forward buffers of frame ``k`` at α = 0.5, 0.75, backward buffers of frame
    ``k+1`` at α = 0.25, 0.5. Measured: at most 0.67 of the key colour's MAE; the forward
    buffers given the backward ones, or S_min and S_max swapped, gave 1.4–5."""
    scene = sr.SyntheticScene(dynamic=True)
    for index, role, alphas in ((k, "older", (0.5, 0.75)), (k + 1, "newer", (0.25, 0.5))):
        t_frame = index / FPS
        cf = scene.render(scene.rig(t_frame, W, H)[0], t_frame, fps=FPS, subframes=4)
        shadow = cf.shadow_fwd if role == "older" else cf.shadow_bwd
        assert shadow is not None and cf.motion_fwd is not None and cf.motion_bwd is not None
        static = ~(np.asarray(cf.motion_fwd) != 0).any(axis=-1)
        static &= ~(np.asarray(cf.motion_bwd) != 0).any(axis=-1)
        shaded = static & (np.asarray(shadow.bits) != 0)
        assert shaded.sum() > 150, f"only {shaded.sum()} shadowed pixels: vacuous"
        applied = key = 0.0
        for alpha in alphas:
            t = between(k, alpha)
            truth = np.asarray(scene.ground_truth(cf.camera, t))[shaded]
            got = np.asarray(sr.apply_shadows(cf.color, shadow, alpha, subframes=4, role=role))
            applied += mae(got[shaded], truth)
            key += mae(np.asarray(cf.color)[shaded], truth)
        assert applied < 0.8 * key, (
            f"frame {index} ({role}): shadows applied MAE {applied:.2f}, key colour {key:.2f}"
        )


def between(k: int, alpha: float) -> float:
    """The time ``t_k + α·Δ`` between server frames ``k`` and ``k+1``."""
    return (k + alpha) / FPS
