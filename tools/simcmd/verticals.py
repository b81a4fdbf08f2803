"""``placecell-sim verticals [--config C] IMAGE... [--json]``: how vertical the world's
vertical edges stand in the panorama a camera model unwarps (docs/design.md §2 "Other
cameras", issue 34).

The method needs one property of its camera: a panorama column is a bearing. Then a
vertical edge in the world — a door frame, a wall's corner, a calibration board held
upright — lies in a plane through the camera's vertical axis and is a column of the
panorama. A wrong model bends it: a centre a few pixels off slants the edges by a
sinusoid of their bearing (the mirror's by up to ~0.5° a pixel), a wrong radial polynomial
curves them. So the check unwarps each image through the configured model, finds the
long, nearly vertical edges in the panorama (Canny and a probabilistic Hough transform),
refits each on the sub-pixel peak of the horizontal gradient row by row, and reports
their slant in degrees: ``atan`` of the columns the edge moves per row, in panorama
pixels.

The answer is the median and the 90th percentile of |slant| over the edges of all the
images (each edge weighted once); no edge long enough in any image is refused, naming
the images, rather than answered.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import cv2
import numpy as np

from daemon.config import PlacecellConfig
from daemon.vision.ncc import subpixel_peak
from daemon.vision.unwarp import Unwarper
from kernel.errors import PlacecellError
from kernel.panorama import core_of, to_grey
from tools.simcmd import load_config

MAX_TILT_DEG = 30.0  # segments further from vertical are not vertical edges
MIN_LENGTH_OF_HEIGHT = 0.25  # an edge spans at least this fraction of the panorama's rows
MIN_FITTED_FRACTION = 0.6  # of its rows with a clear gradient peak, or it is dropped


@dataclass(frozen=True)
class EdgeSlant:
    slant_deg: float  # + leans right going down the panorama
    rows: int  # rows the fit used
    row: float  # the middle of the rows fitted
    column: float  # where the edge crosses that row


def vertical_edge_slants(grey: np.ndarray, min_length_px: int) -> list[EdgeSlant]:
    """The nearly vertical edges of a grey panorama (no wrap margin), each fitted as
    column = a + b row on the sub-pixel peaks of |∂I/∂x| along its Hough segment."""
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0)
    gx = np.abs(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3))
    edges = cv2.Canny(np.clip(smooth, 0, 255).astype(np.uint8), 40, 100)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 360, threshold=int(min_length_px * 0.6),
                            minLineLength=min_length_px, maxLineGap=2)
    if lines is None:
        return []
    width = grey.shape[1]
    out = []
    for x1, y1, x2, y2 in (tuple(int(v) for v in line) for line in lines.reshape(-1, 4)):
        if abs(x2 - x1) > abs(y2 - y1) * math.tan(math.radians(MAX_TILT_DEG)):
            continue
        if y1 > y2:
            x1, y1, x2, y2 = x2, y2, x1, y1
        rows, cols = [], []
        for y in range(y1 + 2, y2 - 1):  # the ends are where Canny's segment is least sure
            c = int(round(x1 + (x2 - x1) * (y - y1) / max(y2 - y1, 1)))
            if c < 2 or c > width - 3:
                continue
            _, peak, _ = subpixel_peak(gx[None, y, c - 2:c + 3])
            if peak in (0.0, 4.0):
                continue  # the peak is not inside the window: another edge
            rows.append(y)
            cols.append(c - 2 + peak)
        if len(rows) < MIN_FITTED_FRACTION * min_length_px:
            continue
        b, a = np.polyfit(rows, cols, 1)
        middle = 0.5 * (rows[0] + rows[-1])
        out.append(EdgeSlant(math.degrees(math.atan(b)), len(rows), middle,
                             float(a + b * middle)))
    return out


def panorama_slants(image: np.ndarray, config: PlacecellConfig,
                    unwarper: Unwarper | None = None) -> list[EdgeSlant]:
    """:func:`vertical_edge_slants` of ``image`` unwarped through ``config``'s camera."""
    unwarper = unwarper or Unwarper(config.projection, config.panorama)
    grey = to_grey(core_of(unwarper.unwarp(image), config.panorama.wrap_margin))
    return vertical_edge_slants(grey, max(12, int(grey.shape[0] * MIN_LENGTH_OF_HEIGHT)))


def summary(slants: list[EdgeSlant]) -> dict[str, float | int]:
    magnitude = np.abs([s.slant_deg for s in slants])
    return {"edges": len(slants),
            "median_abs_slant_deg": round(float(np.median(magnitude)), 3),
            "p90_abs_slant_deg": round(float(np.percentile(magnitude, 90)), 3),
            "max_abs_slant_deg": round(float(magnitude.max()), 3)}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", nargs="+", help="raw images from the camera (PNG, JPEG, ...)")
    p.add_argument("--config", help="daemon configuration naming the camera model "
                   "([camera] model and its section)")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    unwarper = Unwarper(config.projection, config.panorama)
    per_image: dict[str, list[EdgeSlant]] = {}
    for name in args.images:
        image = cv2.imread(name, cv2.IMREAD_COLOR)
        if image is None:
            raise PlacecellError(f"cannot read {name} as an image")
        per_image[name] = panorama_slants(image, config, unwarper)
    found = [s for slants in per_image.values() for s in slants]
    if not found:
        raise PlacecellError(
            f"no vertical edge of at least {MIN_LENGTH_OF_HEIGHT:.0%} of the panorama's "
            f"height in {', '.join(per_image)}: nothing to measure the slant on (the "
            "images need upright edges: door frames, wall corners, a board held upright)")
    result = {"model": config.camera.model, **summary(found),
              "images": {name: summary(s) if s else {"edges": 0}
                         for name, s in per_image.items()}}
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"{config.camera.model}: {result['edges']} vertical edges, |slant| median "
          f"{result['median_abs_slant_deg']}°, 90 % within {result['p90_abs_slant_deg']}°, "
          f"max {result['max_abs_slant_deg']}°")
    for name, s in result["images"].items():  # type: ignore[union-attr]
        print(f"  {name}: {s}")
    return 0
