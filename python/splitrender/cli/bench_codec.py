"""The codec benchmark's command line: ``python -m splitrender.cli.bench_codec [--frames N]
[--sizes 640x360,...] [--paper-mbps MBPS] [--preset P] [--chroma] [--profile]``.

What it measures and prints is :mod:`splitrender.evaluation.bench_codec`'s (its
:func:`~splitrender.evaluation.bench_codec.report` and
:func:`~splitrender.evaluation.bench_codec.profile`); this module checks the arguments: one-line
errors with exit status 2, through the ``splitrender`` command's parser and argument types.
"""

from __future__ import annotations

import argparse

from splitrender.cli.args import Parser, bitrate, count, names, side
from splitrender.codec.coder import MAX_BITRATE_MBPS, X265_PRESETS, CodecConfig, oversized_picture
from splitrender.evaluation import bench_codec
from splitrender.scene.synthetic import SyntheticScene
from splitrender.types import MAX_SIDE

#: How the module is run (its documented command), the name its argument errors open with.
PROG = "python -m splitrender.cli.bench_codec"


def sizes(text: str) -> tuple[tuple[int, int], ...]:
    """``--sizes``: comma-separated main-camera sizes ``WxH``, each side 1..MAX_SIDE (what the
    scene and the codec take), whose stream (with the rig's two half-size auxiliary cameras)
    the codec can carry; an ``ArgumentTypeError`` otherwise. Checked here, before any frame is
    rendered: a bad size failed as a traceback of the scene's or the codec's checks."""
    out = []
    for item in names(text):
        # Without an "x" (or with a second one) a side is "" (or "36x2"), which side() refuses.
        w, _, h = item.partition("x")
        try:
            size = side(w), side(h)
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"expected WxH sizes like 640x360, each side 1..{MAX_SIDE}, got {item!r}"
            ) from None
        # The rig's own camera sizes (its auxiliary cameras' rounding included).
        main, aux = SyntheticScene().rig(0.0, *size)
        over = oversized_picture([(c.width, c.height) for c in (main, *aux)])
        if over is not None:
            pic, pw, ph = over
            raise argparse.ArgumentTypeError(
                f"{item} makes the codec's {pic} {pw}x{ph}, beyond its {MAX_SIDE} pixels a "
                "side; expected a smaller size, or one nearer to square"
            )
        out.append(size)
    return tuple(out)


def main(argv: list[str] | None = None) -> None:
    ap = Parser(prog=PROG, description=(
        "Encode and decode the synthetic dynamic scene at each main-camera size (two half-size "
        "auxiliary cameras, every buffer) and print times, bit-rates and errors; or, with "
        "--profile, where the decode time of two 1280x720 courtyard frames goes."
    ))
    ap.add_argument("--frames", type=count, default=20, metavar="N",
                    help="server frames per run (default: %(default)s)")
    ap.add_argument("--sizes", type=sizes, default="640x360,1280x720", metavar="WxH,...",
                    help="main-camera sizes (default: %(default)s)")
    ap.add_argument("--paper-mbps", type=bitrate, default=40.0, metavar="MBPS",
                    help="bitrate at the paper's 2560x1440, scaled by pixel count "
                    "(default: %(default)s)")
    ap.add_argument("--preset", choices=X265_PRESETS, default=CodecConfig().preset,
                    help="x265 preset (default: %(default)s)")
    ap.add_argument("--chroma", action="store_true", help="also compare 4:4:4 and 4:2:0")
    ap.add_argument("--profile", action="store_true",
                    help="only the decode-time profile of two 1280x720 courtyard frames")
    args = ap.parse_args(argv)
    for w, h in args.sizes:
        # CodecConfig bounds the scaled target, not --paper-mbps: a large size can take it
        # past the bound (a traceback at the first run otherwise).
        target = args.paper_mbps * w * h / (2560 * 1440)
        if target > MAX_BITRATE_MBPS:
            ap.error(
                f"argument --paper-mbps: {args.paper_mbps:g} Mb/s scaled to {w}x{h} is "
                f"{target:g} Mb/s; expected at most the codec's {MAX_BITRATE_MBPS:g} Mb/s"
            )
    if args.profile:
        bench_codec.profile()
    else:
        bench_codec.report(args.sizes, args.frames, args.paper_mbps, args.preset, args.chroma)


if __name__ == "__main__":
    main()
