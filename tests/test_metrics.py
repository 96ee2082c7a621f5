"""splitrender.evaluation.metrics against cases with known answers (REFERENCE.md §6 settings)."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from splitrender import metrics as M
from splitrender.errors import InvalidInputError, SplitRenderError


def textured(h: int = 64, w: int = 64, seed: int = 0) -> np.ndarray:
    """A smooth-ish random texture (blocks of 4x4), uint8."""
    rng = np.random.default_rng(seed)
    base = rng.random((h // 4 + 1, w // 4 + 1, 3)) * 200 + 20
    return np.asarray(np.kron(base, np.ones((4, 4, 1)))[:h, :w], dtype=np.uint8)


def moving_sequence(n: int = 6, h: int = 64, w: int = 64) -> list[np.ndarray]:
    """A texture translating 2 px per frame (so VMAF's motion feature is non-zero)."""
    big = textured(h, w + 2 * n, seed=3)
    return [np.ascontiguousarray(big[:, 2 * i : 2 * i + w]) for i in range(n)]


def box_blur(img: np.ndarray, r: int = 2) -> np.ndarray:
    x = img.astype(np.float64)
    pad = np.pad(x, ((r, r), (r, r), (0, 0)), mode="edge")
    out = np.zeros_like(x)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            out += pad[dy : dy + x.shape[0], dx : dx + x.shape[1]]
    return np.asarray(np.rint(out / (2 * r + 1) ** 2), dtype=np.uint8)


def test_identical_images_have_perfect_scores() -> None:
    a = textured(40, 56)
    assert M.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert M.psnr(a, a) == M.PSNR_CAP_DB == 100.0
    assert M.flip(a, a) == 0.0
    assert float(M.flip_map(a, a).max()) == 0.0


def test_psnr_of_a_uniform_offset() -> None:
    a = np.full((16, 24, 3), 100, np.uint8)
    b = a + np.uint8(10)
    assert M.psnr(a, b) == pytest.approx(20 * math.log10(255 / 10), abs=1e-9)
    # float input in [0, 1] gives the same value
    assert M.psnr(a / 255.0, b / 255.0) == pytest.approx(M.psnr(a, b), abs=1e-9)


def _coverage(n: int) -> np.ndarray:
    """Sum of the 11-tap Gaussian's weights inside an image of n pixels, per position."""
    x = np.arange(-5, 6, dtype=np.float64)
    g = np.exp(-(x**2) / (2 * 1.5**2))
    g /= g.sum()
    return np.array([sum(g[k + 5] for k in range(-5, 6) if 0 <= i + k < n) for i in range(n)])


def test_ssim_of_a_constant_shift_follows_the_formula_with_zero_padding() -> None:
    h, w, va, vb = 20, 30, 100, 140
    a, b = np.full((h, w, 3), va, np.uint8), np.full((h, w, 3), vb, np.uint8)
    x, y = va / 255, vb / 255
    c1, c2 = 0.01**2, 0.03**2
    # Interior: no variance, so SSIM = luminance term.
    smap = M.ssim_map(a, b)
    assert smap[10, 15, 0] == pytest.approx((2 * x * y + c1) / (x * x + y * y + c1), abs=1e-12)
    # Everywhere: zero padding scales the means by the window coverage c and adds variance
    # v^2 c (1 - c) (the reference's conv2d with padding 5).
    cov = np.outer(_coverage(h), _coverage(w))
    mx, my = cov * x, cov * y
    sxy = x * y * cov * (1 - cov)
    sxx, syy = x * x * cov * (1 - cov), y * y * cov * (1 - cov)
    expect = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sxx + syy + c2))
    np.testing.assert_allclose(smap[..., 1], expect, rtol=0, atol=1e-12)
    assert M.ssim(a, b) == pytest.approx(float(expect.mean()), abs=1e-12)


def test_metrics_take_strided_views() -> None:
    # ssim and ssim_map refused a transposed image ("x: expected a C-contiguous array, got a
    # non-contiguous float64 view") that psnr and flip took.
    a = textured(48, 64, seed=1)
    b = textured(48, 64, seed=2)
    at, bt = a.transpose(1, 0, 2), b.transpose(1, 0, 2)
    assert not at.flags.c_contiguous
    assert M.ssim(at, bt) == M.ssim(at.copy(), bt.copy())
    np.testing.assert_array_equal(M.ssim_map(at, bt), M.ssim_map(at.copy(), bt.copy()))
    assert M.ssim(a[::2], b[::2]) == M.ssim(a[::2].copy(), b[::2].copy())


def test_ssim_interior_matches_scikit_image() -> None:
    skm = pytest.importorskip("skimage.metrics")
    a = textured(48, 64, seed=1)
    rng = np.random.default_rng(2)
    b = np.clip(a.astype(int) + rng.integers(-25, 26, a.shape), 0, 255).astype(np.uint8)
    _, full = skm.structural_similarity(
        a / 255.0,
        b / 255.0,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=2,
        full=True,
    )
    ours = M.ssim_map(a, b)
    np.testing.assert_allclose(ours[5:-5, 5:-5], full[5:-5, 5:-5], rtol=0, atol=1e-10)
    assert M.ssim(a, b) == pytest.approx(M.ssim(b, a), abs=1e-12)


def test_distortion_orders_ssim_psnr_and_flip() -> None:
    a = textured(64, 64, seed=4)
    rng = np.random.default_rng(5)
    noise = rng.standard_normal(a.shape)
    scores = []
    for amp in (2.0, 8.0, 24.0, 64.0):
        b = np.clip(np.rint(a + amp * noise), 0, 255).astype(np.uint8)
        scores.append((M.ssim(a, b), M.psnr(a, b), M.flip(b, a)))
    ssims, psnrs, flips = zip(*scores)
    assert all(x > y for x, y in itertools.pairwise(ssims))
    assert all(x > y for x, y in itertools.pairwise(psnrs))
    assert all(x < y for x, y in itertools.pairwise(flips))
    assert 0.0 < flips[0] and flips[-1] < 1.0


def test_flip_map_mean_is_flip() -> None:
    a = textured(32, 48, seed=6)
    b = box_blur(a)
    fmap = M.flip_map(b, a)
    assert fmap.shape == (32, 48) and fmap.dtype == np.float32
    assert float(fmap.mean()) == pytest.approx(M.flip(b, a), rel=1e-5)


@pytest.mark.parametrize(
    ("a", "b", "match"),
    [
        (np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8), "same shape"),
        (np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3), np.float32), "same dtype"),
        (np.zeros((8, 8), np.uint8), np.zeros((8, 8), np.uint8), r"\(H, W, 3\)"),
        (np.zeros((8, 8, 3), np.int16), np.zeros((8, 8, 3), np.int16), "dtype uint8"),
        (np.full((8, 8, 3), 2.0), np.zeros((8, 8, 3)), r"\[0, 1\]"),
        (np.full((8, 8, 3), np.nan), np.zeros((8, 8, 3)), "finite"),
        (np.zeros((0, 8, 3), np.uint8), np.zeros((0, 8, 3), np.uint8), "non-empty image"),
        (np.zeros((8, 0, 3), np.uint8), np.zeros((8, 0, 3), np.uint8), "non-empty image"),
    ],
)
def test_invalid_images_are_refused(a: np.ndarray, b: np.ndarray, match: str) -> None:
    for f in (M.ssim, M.psnr, M.flip):
        with pytest.raises(InvalidInputError, match=match):
            f(a, b)


def test_vmaf_of_identical_sequences_is_about_100() -> None:
    seq = moving_sequence(6)
    scores = M.vmaf(seq, seq)
    assert len(scores) == 6
    # libvmaf's motion feature is 0 on the first frame, which costs it ~2.6 points.
    assert scores[0] == pytest.approx(100.0, abs=3.0)
    assert all(s == pytest.approx(100.0, abs=0.01) for s in scores[1:])


def test_vmaf_is_lower_for_a_blurred_sequence() -> None:
    seq = moving_sequence(6)
    mild = [box_blur(f, 1) for f in seq]
    strong = [box_blur(f, 3) for f in seq]
    v_id = np.mean(M.vmaf(seq, seq))
    v_mild = np.mean(M.vmaf(mild, seq))
    v_strong = np.mean(M.vmaf(strong, seq))
    assert v_id > v_mild > v_strong
    assert v_id - v_strong > 10.0


def test_vmaf_refuses_bad_sequences() -> None:
    seq = moving_sequence(3)
    with pytest.raises(InvalidInputError, match="same number of frames"):
        M.vmaf(seq, seq[:2])
    tiny = [np.zeros((16, 64, 3), np.uint8)] * 2
    with pytest.raises(InvalidInputError, match="at least 32x32"):
        M.vmaf(tiny, tiny)
    with pytest.raises(InvalidInputError, match=r"reference\[1\]"):
        M.vmaf(seq, [seq[0], np.zeros((8, 8, 3), np.uint8), seq[2]])
    shapes = r"expected the same frame shape, got \(64, 64, 3\) and \(40, 64, 3\)"
    with pytest.raises(InvalidInputError, match=shapes):
        M.vmaf(seq, [f[:40] for f in seq])


def test_evaluate_sequence_skips_the_first_and_last_frames() -> None:
    n, skip = 30, 12
    truth = moving_sequence(n)
    # Garbage only in the skipped frames: the means must be perfect.
    rendered = [f.copy() for f in truth]
    for i in list(range(skip)) + list(range(n - skip, n)):
        rendered[i] = 255 - truth[i]
    seen: list[tuple[str, int, int]] = []
    res = M.evaluate_sequence(
        rendered, truth, skip=skip, progress=lambda s, d, t: seen.append((s, d, t))
    )
    assert res.frames == list(range(skip, n - skip))
    assert len(res.per_frame) == n - 2 * skip
    assert res.mean["ssim"] == pytest.approx(1.0, abs=1e-12)
    assert res.mean["flip"] == 0.0
    assert res.mean["psnr"] == M.PSNR_CAP_DB and res.mse == 0.0
    assert res.mean["vmaf"] == pytest.approx(100.0, abs=0.01)
    assert ("psnr", n - 2 * skip, n - 2 * skip) in seen and ("vmaf", 1, 1) in seen
    assert res.to_dict()["mean"]["psnr"] == M.PSNR_CAP_DB


def test_sequence_psnr_is_that_of_the_mean_mse_and_never_infinite() -> None:
    """A sequence with identical frames (a head standing still) has a finite PSNR: the PSNR of
    the mean squared error over its frames, not the mean of per-frame PSNRs (inf there)."""
    truth = [textured(24, 32, seed=s) for s in range(5)]
    rendered = [t.copy() for t in truth]
    rendered[3] = np.clip(truth[3].astype(np.int16) + 8, 0, 255).astype(np.uint8)
    res = M.evaluate_sequence(rendered, truth, skip=1, metrics=("psnr",))
    mses = [float(np.mean(((r / 255.0) - (t / 255.0)) ** 2)) for r, t in
            zip(rendered[1:4], truth[1:4])]
    assert [row["psnr"] for row in res.per_frame][:2] == [M.PSNR_CAP_DB] * 2
    assert res.mse == pytest.approx(np.mean(mses), rel=1e-12)
    assert res.mean["psnr"] == pytest.approx(-10 * math.log10(np.mean(mses)), rel=1e-12)
    assert math.isfinite(res.mean["psnr"]) and res.mean["psnr"] < M.PSNR_CAP_DB
    # The cap: at and below an MSE of 1e-10, and for 0; refused for negative or NaN.
    assert M.psnr_of_mse(0.0) == M.psnr_of_mse(1e-12) == M.PSNR_CAP_DB
    assert M.psnr_of_mse(1e-9) == pytest.approx(90.0)
    for bad in (-1e-3, float("nan"), float("inf")):
        with pytest.raises(InvalidInputError):
            M.psnr_of_mse(bad)


def test_flip_every_scores_flip_on_every_nth_frame_and_averages_those() -> None:
    truth = [textured(32, 32, seed=i) for i in range(11)]
    rendered = [np.clip(t.astype(int) + 3 * i, 0, 255).astype(np.uint8)
                for i, t in enumerate(truth)]
    full = M.evaluate_sequence(rendered, truth, skip=1, metrics=("ssim", "flip"))
    calls: list[tuple[str, int, int]] = []
    res = M.evaluate_sequence(rendered, truth, skip=1, metrics=("ssim", "flip"), flip_every=4,
                              progress=lambda m, done, total: calls.append((m, done, total)))
    # The 9 scored frames are 1..9; FLIP on the 1st, 5th and 9th of them, SSIM on all.
    assert [i for i, row in zip(res.frames, res.per_frame) if "flip" in row] == [1, 5, 9]
    assert all("ssim" in row for row in res.per_frame)
    sampled = [full.per_frame[j]["flip"] for j in (0, 4, 8)]
    assert [row["flip"] for row in res.per_frame if "flip" in row] == sampled
    assert res.mean["flip"] == pytest.approx(np.mean(sampled))
    assert res.mean["ssim"] == full.mean["ssim"]
    assert calls[-1] == ("flip", 3, 3)
    with pytest.raises(InvalidInputError, match="flip_every"):
        M.evaluate_sequence(rendered, truth, skip=1, flip_every=0)


def test_evaluate_sequence_per_frame_values_and_errors() -> None:
    truth = [textured(32, 32, seed=i) for i in range(7)]
    rendered = [np.clip(t.astype(int) + i, 0, 255).astype(np.uint8) for i, t in enumerate(truth)]
    res = M.evaluate_sequence(rendered, truth, skip=2, metrics=("psnr", "ssim"))
    assert res.frames == [2, 3, 4]
    for row, i in zip(res.per_frame, res.frames):
        assert set(row) == {"ssim", "psnr"}
        assert row["psnr"] == pytest.approx(M.psnr(rendered[i], truth[i]))
    assert res.mean["ssim"] == pytest.approx(np.mean([r["ssim"] for r in res.per_frame]))
    # PSNR's mean is the PSNR of the mean MSE, at most the mean PSNR (log is concave).
    mse = np.mean([10 ** (-r["psnr"] / 10) for r in res.per_frame])
    assert res.mean["psnr"] == pytest.approx(-10 * np.log10(mse))
    assert res.mean["psnr"] < np.mean([r["psnr"] for r in res.per_frame])
    with pytest.raises(InvalidInputError, match="more than 2\\*skip"):
        M.evaluate_sequence(rendered, truth, skip=4)
    with pytest.raises(InvalidInputError, match="metrics"):
        M.evaluate_sequence(rendered, truth, skip=2, metrics=("lpips",))
    with pytest.raises(InvalidInputError, match="same number of frames"):
        M.evaluate_sequence(rendered, truth[:-1], skip=2)
    with pytest.raises(InvalidInputError, match=r"^rendered and truth: expected the same frame"):
        M.evaluate_sequence(rendered, [t[:16] for t in truth], skip=2)


def test_vmaf_reports_an_ffmpeg_failure(monkeypatch: pytest.MonkeyPatch) -> None:
    # A binary that exits at once without reading its inputs: the writers must not hang.
    monkeypatch.setattr(M, "_ffmpeg", lambda: "false")
    seq = moving_sequence(3)
    with pytest.raises(SplitRenderError, match="ffmpeg exited with status 1"):
        M.vmaf(seq, seq)


def test_vmaf_of_one_stacked_input_equals_vmaf_of_two_inputs(tmp_path: Path) -> None:
    """vmaf() gives ffmpeg each pair as one picture (distorted above reference) and crops the
    two apart; libvmaf must score exactly what it scores with the two sequences as two inputs."""
    truth = moving_sequence(9, 48, 80)
    rng = np.random.default_rng(3)
    dist = [np.clip(t.astype(int) + rng.integers(-30, 31, t.shape), 0, 255).astype(np.uint8)
            for t in truth]
    cmd = [M._ffmpeg(), "-hide_banner", "-nostdin", "-v", "error"]
    for name, seq in (("d", dist), ("r", truth)):
        (tmp_path / f"{name}.rgb").write_bytes(b"".join(f.tobytes() for f in seq))
        cmd += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", "80x48", "-r", "120",
                "-i", str(tmp_path / f"{name}.rgb")]
    log = tmp_path / "log.json"
    cmd += ["-lavfi", "[0:v]format=yuv444p[d];[1:v]format=yuv444p[r];"
            f"[d][r]libvmaf=log_fmt=json:log_path={log}", "-f", "null", "-"]
    subprocess.run(cmd, check=True, timeout=60)
    frames = sorted(json.loads(log.read_text())["frames"], key=lambda f: int(f["frameNum"]))
    two_inputs = [float(f["metrics"]["vmaf"]) for f in frames]
    assert M.vmaf(dist, truth) == two_inputs
    assert M.vmaf(truth, dist) != two_inputs  # the order (which is the reference) matters


def test_vmaf_failing_after_more_frames_than_it_queues_does_not_hang(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # ffmpeg gone before it opened its input, and more frames than the feeding queue holds: the
    # producer must not wait for a reader that never comes.
    monkeypatch.setattr(M, "_ffmpeg", lambda: "false")
    seq = moving_sequence(4 * M._VMAF_QUEUE)
    with pytest.raises(SplitRenderError, match="ffmpeg exited with status 1"):
        M.vmaf(seq, seq)


def test_sequence_scorer_frame_by_frame_equals_evaluate_sequence() -> None:
    truth = moving_sequence(30, 48, 64)
    rng = np.random.default_rng(7)  # noise of 0 to 24 levels: VMAF from 100 down to ~88
    rendered = [np.clip(t.astype(int) + rng.integers(-1, 2, t.shape) * (6 * (i % 5)), 0, 255)
                .astype(np.uint8) for i, t in enumerate(truth)]
    whole = M.evaluate_sequence(rendered, truth, skip=3, flip_every=4)
    with M.SequenceScorer(30, 3, flip_every=4) as scorer:
        for r, t in zip(rendered, truth):
            scorer.add(r, t)
        res = scorer.finish()
    assert res == whole
    # Against the per-image functions and vmaf() of the whole sequences, the rendered frames
    # first: VMAF is not symmetric and varies from frame to frame here, so a scorer that fed
    # ffmpeg the truth as the distorted side, or took another frame's score, fails.
    whole_vmaf = M.vmaf(rendered, truth)
    assert M.vmaf(truth, rendered) != whole_vmaf
    assert len(set(whole_vmaf[3:27])) > 5
    for row, i in zip(res.per_frame, res.frames):
        assert row["ssim"] == M.ssim(rendered[i], truth[i])
        assert row["psnr"] == M.psnr(rendered[i], truth[i])
        assert row["vmaf"] == whole_vmaf[i]
        assert ("flip" in row) == ((i - 3) % 4 == 0)
        if "flip" in row:
            assert row["flip"] == M.flip(rendered[i], truth[i])
    with M.SequenceScorer(5, 1, ("psnr",)) as scorer:
        scorer.add(truth[0], truth[0])
        with pytest.raises(InvalidInputError, match="expected 5 frames, got 1"):
            scorer.finish()
    with M.SequenceScorer(3, 1, ("psnr",)) as scorer:
        for _ in range(3):
            scorer.add(truth[0], truth[0])
        with pytest.raises(InvalidInputError, match="^rendered: expected 3 frames, got more$"):
            scorer.add(truth[0], truth[0])
        assert scorer.finish().frames == [1]
    with M.SequenceScorer(3, 1, ("psnr",)) as scorer:
        with pytest.raises(InvalidInputError, match=r"^rendered\[0\] and truth\[0\]: expected"):
            scorer.add(truth[0], truth[0][:16])
    tiny = np.zeros((16, 64, 3), np.uint8)
    with M.SequenceScorer(3, 1, ("vmaf",)) as scorer:
        with pytest.raises(InvalidInputError, match="^vmaf: expected frames of at least 32x32"):
            scorer.add(tiny, tiny)


def test_sequence_scorer_refuses_a_frame_of_another_shape_and_ends_ffmpeg() -> None:
    seq = moving_sequence(6, 48, 64)
    with pytest.raises(InvalidInputError, match=r"rendered\[3\]: expected the shape of frame 0"):
        with M.SequenceScorer(6, 1) as scorer:
            for i in range(3):
                scorer.add(seq[i], seq[i])
            vmaf = scorer._vmaf
            assert vmaf is not None and vmaf._proc is not None
            scorer.add(seq[3][:32], seq[3][:32])
    # Leaving the block ended ffmpeg (it was waiting for more frames).
    assert vmaf._proc.poll() is not None


def test_vmaf_waits_for_an_ffmpeg_slow_to_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a loaded machine ffmpeg may open its input long after the frames are queued: the
    writer must keep waiting for it (releasing it early left ffmpeg waiting for a writer)."""
    real = M._ffmpeg()
    slow = tmp_path / "slow-ffmpeg"
    slow.write_text(f'#!/bin/sh\nsleep 1.5\nexec "{real}" "$@"\n')
    slow.chmod(0o755)
    seq = moving_sequence(4)
    expected = M.vmaf(seq, seq)
    monkeypatch.setattr(M, "_ffmpeg", lambda: str(slow))
    got: list[list[float]] = []
    t = threading.Thread(target=lambda: got.append(M.vmaf(seq, seq)), daemon=True)
    t.start()
    t.join(60)
    assert not t.is_alive(), "vmaf hung waiting for ffmpeg"
    assert got == [expected]


def test_float_frames_are_scored_as_the_uint8_frames_they_round_to() -> None:
    """evaluate_sequence takes float frames in [0, 1] and scores them as the uint8 frames they
    round to (not truncate to: (k - 0.4) / 255 is level k)."""
    truth = [textured(32, 32, seed=i) for i in range(3)]
    rendered = [np.clip(t.astype(int) + 5 * i - 4, 0, 255).astype(np.uint8)
                for i, t in enumerate(truth)]
    as_u8 = M.evaluate_sequence(rendered, truth, skip=1, metrics=("psnr", "ssim"))
    assert min(int(f.min()) for f in rendered + truth) >= 1
    as_float = M.evaluate_sequence([(r - 0.4) / 255.0 for r in rendered],
                                   [(t - 0.4) / 255.0 for t in truth], skip=1,
                                   metrics=("psnr", "ssim"))
    assert as_float == as_u8
