"""``placecell-eval recognise --reference A.png B.png --images X.png ...
[--mirror auto|CX,CY,R_IN,R_OUT] [--json] [--plots DIR]``

For people with a real mirror camera: learn a landmark set by static selection (docs/design.md §3)
from two raw reference images taken at the same spot, and print its LRP (§3.4) in each
further image. The raw images are unwarped with the mirror geometry found by
detect-mirror (``auto``, from the first reference image) or given; an uncalibrated real
mirror is unwarped with the linear radial model between the given radii.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from daemon.config import load
from daemon.vision.detect_mirror import detect_mirror
from daemon.vision.landmarks import TEMPLATE, LandmarkSet
from daemon.vision.recognition import lrp_bruteforce
from daemon.vision.selection import select_static
from daemon.vision.unwarp import Unwarper
from kernel.errors import PlacecellError
from kernel.panorama import to_grey
from kernel.sensor_settings import MirrorSettings

KEEP = 16
DRAWS_PLOTS = True  # --plots DIR: the landmarks drawn on each panorama


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--reference", nargs=2, required=True, metavar=("A", "B"),
                   help="two raw images at the reference spot")
    p.add_argument("--images", nargs="+", required=True, help="raw images to recognise in")
    p.add_argument("--mirror", default="auto",
                   help="auto (detect from A) or CX,CY,R_IN,R_OUT in pixels")


def _read(path: str) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise PlacecellError(f"cannot read {path} as an image")
    return image


def _mirror(spec: str, reference: np.ndarray) -> MirrorSettings:
    if spec == "auto":
        g = detect_mirror(reference)
        if g.r_inner_px is None:
            raise PlacecellError("--mirror auto: the camera's reflection (inner radius) was "
                                 "not found; give --mirror CX,CY,R_IN,R_OUT")
        cx, cy, r_in, r_out = g.center_x_px, g.center_y_px, g.r_inner_px, g.r_outer_px
    else:
        try:
            cx, cy, r_in, r_out = (float(v) for v in spec.split(","))
        except ValueError as e:
            raise PlacecellError(f"--mirror {spec!r}: expected auto or CX,CY,R_IN,R_OUT") from e
    try:
        return MirrorSettings(model="polynomial", center_x_px=cx, center_y_px=cy,
                              r_inner_px=r_in, r_outer_px=r_out, poly_coeffs=[0.0, 1.0])
    except ValueError as e:
        raise PlacecellError(f"mirror geometry: {e}") from e


def run(args: argparse.Namespace) -> dict[str, Any]:
    config = load(None)
    ref_a, ref_b = _read(args.reference[0]), _read(args.reference[1])
    if ref_a.shape != ref_b.shape:
        raise PlacecellError("the two reference images differ in size")
    mirror = _mirror(args.mirror, ref_a)
    unwarper = Unwarper(mirror, config.panorama)
    margin = config.panorama.wrap_margin
    pano_a, pano_b = unwarper.unwarp(ref_a), unwarper.unwarp(ref_b)
    landmarks = select_static(pano_a, pano_b, margin).best(KEEP)
    lrps, panoramas = [], []
    for path in args.images:
        pano = unwarper.unwarp(_read(path))
        panoramas.append(pano)
        lrps.append(round(lrp_bruteforce(to_grey(pano), landmarks), 4))
    if args.plots:
        _plot(Path(args.plots), [pano_a, *panoramas], ["reference", *args.images], landmarks)
    return {
        "world": {"kind": "real images", "seed": None},
        "config": {"mirror": dataclasses.asdict(mirror), "landmarks": len(landmarks.landmarks)},
        "metrics": {"lrp": lrps, "images": list(args.images),
                    "mirror": {"center_x_px": mirror.center_x_px,
                               "center_y_px": mirror.center_y_px,
                               "r_inner_px": mirror.r_inner_px,
                               "r_outer_px": mirror.r_outer_px}},
    }


def _plot(out: Path, panoramas: list[np.ndarray], names: list[str],
          landmarks: LandmarkSet) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for k, (pano, name) in enumerate(zip(panoramas, names, strict=True)):
        vis = pano.copy() if pano.ndim == 3 else cv2.cvtColor(pano, cv2.COLOR_GRAY2BGR)
        grey = to_grey(pano)
        for lm in landmarks.landmarks:
            if k == 0:
                x, y = lm.col + landmarks.margin, lm.row
            else:  # where the template matches best in this image
                scores = cv2.matchTemplate(grey, lm.template, cv2.TM_CCOEFF_NORMED)
                yx = np.unravel_index(int(np.argmax(scores)), scores.shape)
                y, x = int(yx[0]), int(yx[1])
            cv2.rectangle(vis, (int(x), int(y)), (int(x) + TEMPLATE - 1, int(y) + TEMPLATE - 1),
                          (0, 0, 255), 1)
        scale = 2
        vis = cv2.resize(vis, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        cv2.putText(vis, Path(name).name, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1, cv2.LINE_AA)
        cv2.imwrite(str(out / f"{k:02d}-{Path(name).stem}.png"), vis)
