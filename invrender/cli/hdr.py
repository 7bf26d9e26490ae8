"""``invrender hdr``: merge an exposure bracket of 8-bit photographs into one linear EXR, with the
camera response recovered from it (a CSV that ``response=`` reads, and its plot); a front over
:func:`invrender.io.hdr.merge_bracket`."""

from __future__ import annotations

import argparse
import math
import sys
from fractions import Fraction
from pathlib import Path

from invrender.cli.common import check_outputs
from invrender.cli.catalog import HDR_SAMPLES as DEFAULT_SAMPLES, HDR_SMOOTHNESS as DEFAULT_SMOOTHNESS  # invrender.io.hdr's

DOC = """\
Merge P >= 2 aligned 8-bit photographs of one still scene, taken at different exposure times, into
one linear HDR image (Debevec & Malik 1997, through OpenCV): the camera response is recovered from
the bracket itself, per channel, and written as a CSV (value,red,green,blue: code / 255 and the
linear response of that code, 1.0 at code 255) beside a plot of it.

Scale: a bracket fixes the response only up to one factor per channel; each channel is normalized
so that code 255 maps to 1, and the merged EXR is in the same units (a pixel of value E taken at
exposure time t reads the code whose response is E * t; code 255 from E * t = 1 on). Pixels clipped
in the shortest exposure hold lower bounds.

Exposure times come from --exposures (seconds or any common unit; fractions such as 1/250 allowed),
else from each file's EXIF ExposureTime.

examples:
  invrender hdr --out merged.exr a.jpg b.jpg c.jpg --exposures 1/250,1/60,1/15
  invrender hdr --out merged.exr bracket/*.jpg          # EXIF exposure times
"""


def parse_exposures(text: str) -> list[float]:
    """``"1/250,1/60,0.25"`` -> [0.004, 0.01666..., 0.25] (values are checked by the library)."""
    try:
        return [float(Fraction(p.strip())) if "/" in p else float(p) for p in text.split(",")]
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(f"expected comma-separated exposure times such as 1/250,1/60,0.25, got {text!r}") from None


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def add_parser(sub) -> None:
    h = sub.add_parser("hdr", help="merge an exposure bracket into a linear EXR and recover the camera response", description=DOC,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    h.add_argument("images", nargs="+", metavar="IMAGE", help="the bracket: 8-bit PNG/JPEG/TIFF files of one size, aligned")
    h.add_argument("--out", required=True, metavar="MERGED.exr", help="the merged linear image, an .exr")
    h.add_argument("--exposures", type=parse_exposures, default=None, metavar="T1,T2,...", help="exposure times, one per image in their order (default: each file's EXIF ExposureTime)")
    h.add_argument("--curve", default=None, metavar="CURVE.csv", help="the response CSV (default: OUT's stem + .response.csv)")
    h.add_argument("--plot", default=None, metavar="CURVE.png", help="the response plot (default: OUT's stem + .response.png)")
    h.add_argument("--samples", type=positive_int, default=DEFAULT_SAMPLES, help=f"pixels the calibration samples (default: {DEFAULT_SAMPLES})")
    h.add_argument("--smoothness", type=positive_float, default=DEFAULT_SMOOTHNESS, help=f"Debevec's lambda, the weight of the curve's smoothness (default: {DEFAULT_SMOOTHNESS:g})")
    h.set_defaults(run=run)


def run(args) -> int:
    from invrender.io.hdr import merge_bracket, response_figure, write_response_csv
    from invrender.io.images import write_image
    from invrender.io.reports import save_figure

    out = Path(args.out)
    stem = out.with_suffix("") if out.suffix.lower() == ".exr" else out
    (out,) = check_outputs([args.out], suffixes=(".exr",))
    (plot,) = check_outputs([args.plot or f"{stem}.response.png"], suffixes=(".png",))
    (curve,) = check_outputs([args.curve or f"{stem}.response.csv"], suffixes=(".csv",))

    hdr, response = merge_bracket(args.images, args.exposures, samples=args.samples, smoothness=args.smoothness)
    figure = response_figure(response, title=f"camera response recovered from {len(args.images)} exposures (Debevec)")
    write_image(out, hdr)
    write_response_csv(curve, response)
    save_figure(figure, plot)
    h, w, _ = hdr.shape
    print(f"merged {len(args.images)} images ({w}x{h}): radiance {float(hdr.min()):.4g} .. {float(hdr.max()):.4g} (code 255 at radiance x exposure = 1)")
    print(f"wrote {out}, {curve}, {plot}", file=sys.stderr)
    return 0
