"""``placecell-sim detect-mirror IMAGE [--json]``: find the donut in a raw camera image."""

from __future__ import annotations

import argparse
import dataclasses
import json

import cv2

from daemon.vision.detect_mirror import detect_mirror
from kernel.errors import PlacecellError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("image", help="a raw mirror-camera image (PNG, JPEG, ...)")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    image = cv2.imread(args.image, cv2.IMREAD_COLOR)
    if image is None:
        raise PlacecellError(f"cannot read {args.image} as an image")
    g = detect_mirror(image)
    if args.json:
        print(json.dumps(dataclasses.asdict(g)))
    else:
        print(f"# {args.image}: {image.shape[1]} x {image.shape[0]} px")
        print(f"# rim from {g.rim_rays} of 360 rays over {g.rim_arc_deg:.0f} deg, RMS "
              f"{g.outer_residual_px} px" + ("; cut by the image border, fitted on the "
                                             "visible arc" if g.clipped else "")
              + ("; a lit ring round the mirror was seen and left out" if g.ring_outside
                 else ""))
        if g.r_inner_px is None:
            print(f"# inner edge from {g.inner_rays} of 360 rays: not measured (the "
                  "camera's reflection was not found); set r_inner_px by hand")
        else:
            print(f"# inner edge from {g.inner_rays} of 360 rays, RMS "
                  f"{g.inner_residual_px} px")
        print("[mirror]")
        for key in ("center_x_px", "center_y_px", "r_inner_px", "r_outer_px"):
            value = getattr(g, key)
            if value is not None:
                print(f"{key} = {value}")
    return 0
