"""Argument types, checks and shared options of the ``splitrender`` subcommands."""

from __future__ import annotations

import argparse
from typing import Any, NoReturn

from splitrender.reproject import METHODS
from splitrender.types import MAX_SIDE

PROG = "splitrender"


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``splitrender: error: ...``) and no usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def side(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= MAX_SIDE:
        raise argparse.ArgumentTypeError(f"expected a size in 1..{MAX_SIDE}, got {v}")
    return v


def samples(text: str) -> int:
    from splitrender.scene.builtin import MAX_SAMPLES

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= MAX_SAMPLES:
        raise argparse.ArgumentTypeError(f"expected 1..{MAX_SAMPLES} per pixel side, got {v}")
    return v


SAMPLES_HELP = (
    "colour sub-samples per pixel side N: server colour, shadow colours and ground truth are "
    "the mean of N x N samples (depth, motion and shadow bits stay at the pixel centre); "
    "default: 3 up to 640x360 pixels per camera, 2 above"
)


def positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return v


def methods(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of methods")
    for m in names:
        if m not in METHODS:
            raise argparse.ArgumentTypeError(
                f"unknown method {m!r}; expected some of: {','.join(METHODS)}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a method is listed twice in {text!r}")
    return names


def count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= 100000:
        raise argparse.ArgumentTypeError(f"expected an integer in 1..100000, got {v}")
    return v


def frames_delay(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 0 <= v <= 1000:
        raise argparse.ArgumentTypeError(f"expected an integer in 0..1000, got {v}")
    return v


def add_backend(p: Any, scope: str) -> None:
    p.add_argument(
        "--backend", choices=("cpu", "wgpu"), default="cpu",
        help=f"where the reprojection runs: cpu (reproj-core) or wgpu (GPU compute shaders; "
        f"{scope}; without a GPU, Mesa's lavapipe: apt-get install mesa-vulkan-drivers) "
        "(default: %(default)s)",
    )


def names(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list")
    return names


def bitrates(text: str) -> tuple[float, ...]:
    return tuple(positive(t) for t in names(text))


def delays(text: str) -> tuple[int, ...]:
    return tuple(frames_delay(t) for t in names(text))


def eval_methods(text: str) -> tuple[str, ...]:
    from splitrender.evaluation.experiments import VIDEO_INTERP

    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of methods")
    for m in names:
        if m not in METHODS and m != VIDEO_INTERP:
            raise argparse.ArgumentTypeError(
                f"unknown method {m!r}; expected some of: {','.join((*METHODS, VIDEO_INTERP))}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a method is listed twice in {text!r}")
    return names


