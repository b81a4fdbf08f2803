"""``placecell-sim calibrate --model M IMAGE... [--fov-deg F] [--ocamcalib FILE]
[--lens catadioptric|fisheye] [--json]``: the configuration of a camera model from its
images (docs/design.md §2 "Other cameras").

What the images show is measured; what they cannot show is asked for, never guessed:

- ``mirror``: the donut's circles (detect-mirror), as ``[mirror]``;
- ``fisheye``: the image circle (the rim of the bright region, as detect-mirror finds it)
  as the equidistant model's centre and radius; the lens's field of view is its data
  sheet's (``--fov-deg``);
- ``dual-fisheye``: both circles, one in each half of the frame;
- ``equirectangular``: a full frame is 2:1 (360° by 180°), its horizon the middle row;
  another shape is refused;
- ``ocamcalib``: OCamCalib's ``calib_results.txt`` checked against the images: the same
  size, its distortion centre on the image circle's centre; the circles' radii bound the
  pixels that see the world.

Several images of one camera: each is measured, and the answer is their median with the
spread between them (how sure it is). Refused, with the reason, when an image cannot be
measured or the images disagree by more than ``MAX_SPREAD_PX``.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

import cv2
import numpy as np

from daemon.vision.detect_mirror import MirrorGeometry, detect_mirror
from kernel.camera_models import read_ocamcalib
from kernel.errors import PlacecellError

MODELS = ("mirror", "fisheye", "dual-fisheye", "equirectangular", "ocamcalib")
MAX_SPREAD_PX = 2.0  # images of one camera disagreeing by more: refused
MAX_CENTRE_OFFSET_PX = 8.0  # an OCamCalib centre this far from the image circle's: refused
MAX_RADIUS_MISMATCH_PX = 4.0  # the two circles of a dual fisheye


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", nargs="+", help="raw images from the camera (PNG, JPEG, ...)")
    p.add_argument("--model", choices=MODELS, required=True)
    p.add_argument("--fov-deg", type=float, help="the lens's field of view, from its data "
                   "sheet (fisheye, dual-fisheye: one lens)")
    p.add_argument("--ocamcalib", help="OCamCalib's calib_results.txt (ocamcalib)")
    p.add_argument("--lens", choices=("catadioptric", "fisheye"), default="catadioptric",
                   help="ocamcalib: what the image centre sees (the camera, or the zenith)")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    images = [_read(path) for path in args.images]
    section, values, notes = CALIBRATIONS[args.model](images, args)
    if args.json:
        print(json.dumps({"section": section, "values": values, "notes": notes}))
        return 0
    for note in notes:
        print(f"# {note}")
    print("[camera]")
    print(f'model = "{args.model}"')
    print(f"[{section}]")
    for key, value in values.items():
        print(f"{key} = {json.dumps(value)}")
    return 0


def _read(path: str) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise PlacecellError(f"cannot read {path} as an image")
    return image


def _same_size(images: list[np.ndarray]) -> tuple[int, int]:
    sizes = {im.shape[:2] for im in images}
    if len(sizes) != 1:
        raise PlacecellError(f"the images are of {len(sizes)} sizes "
                             f"({', '.join(f'{w} x {h}' for h, w in sorted(sizes))}): one "
                             "camera at one resolution, please")
    h, w = sizes.pop()
    return w, h


def _agreed(name: str, values: list[float]) -> tuple[float, float]:
    """The median of one measurement over the images and its spread (max - min)."""
    spread = max(values) - min(values)
    if spread > MAX_SPREAD_PX:
        raise PlacecellError(f"the images disagree on the {name} by {spread:.1f} px (more "
                             f"than {MAX_SPREAD_PX} px): the camera moved between them, or "
                             "some are not of this camera")
    return float(np.median(values)), spread


def _circles(images: list[np.ndarray]) -> tuple[dict[str, float], list[str], list[MirrorGeometry]]:
    """Centre and outer radius of the bright circle in each image, agreed."""
    found = [detect_mirror(im) for im in images]  # MirrorNotFoundError says why
    cx, scx = _agreed("centre's column", [g.center_x_px for g in found])
    cy, scy = _agreed("centre's row", [g.center_y_px for g in found])
    r, sr = _agreed("circle's radius", [g.r_outer_px for g in found])
    rms = max(g.outer_residual_px for g in found)
    notes = [f"image circle from {len(found)} image(s): rim RMS at most {rms} px, spread "
             f"between images {max(scx, scy):.2f} px (centre) and {sr:.2f} px (radius)"]
    if any(g.clipped for g in found):
        notes.append("the circle is cut by the frame: fitted on its visible arc")
    return {"cx": cx, "cy": cy, "r": r}, notes, found


def _fov(args: argparse.Namespace) -> float:
    if args.fov_deg is None:
        raise PlacecellError("a photo shows the image circle, not the angle it spans: give "
                             "--fov-deg from the lens's data sheet")
    if not 0.0 < args.fov_deg <= 360.0:
        raise PlacecellError(f"--fov-deg {args.fov_deg} is not a field of view (0-360)")
    return float(args.fov_deg)


Calibration = tuple[str, dict[str, Any], list[str]]


def _mirror(images: list[np.ndarray], args: argparse.Namespace) -> Calibration:
    _same_size(images)
    circle, notes, found = _circles(images)
    values = {"center_x_px": round(circle["cx"], 2), "center_y_px": round(circle["cy"], 2),
              "r_outer_px": round(circle["r"], 2)}
    inner = [g.r_inner_px for g in found if g.r_inner_px is not None]
    if len(inner) == len(found):
        values["r_inner_px"] = round(_agreed("inner radius", inner)[0], 2)
    else:
        notes.append("the camera's own reflection was not found in every image: set "
                     "r_inner_px by hand")
    return "mirror", values, notes


def _fisheye(images: list[np.ndarray], args: argparse.Namespace) -> Calibration:
    _same_size(images)
    fov = _fov(args)
    circle, notes, _ = _circles(images)
    notes.append(f"equidistant over {fov:g} deg (the lens's data sheet); for OpenCV's "
                 "model calibrate with cv2.fisheye.calibrate and give camera_matrix and "
                 "distortion instead")
    return "camera.fisheye", {"projection": "equidistant",
                              "center_x_px": round(circle["cx"], 2),
                              "center_y_px": round(circle["cy"], 2),
                              "radius_px": round(circle["r"], 2), "fov_deg": fov}, notes


def _dual_fisheye(images: list[np.ndarray], args: argparse.Namespace) -> Calibration:
    w, h = _same_size(images)
    fov = _fov(args)
    halves = []
    for side in (0, 1):  # the other half blacked out: coordinates stay the frame's
        masked = []
        for im in images:
            m = im.copy()
            m[:, (w // 2 if side == 0 else 0):(w if side == 0 else w // 2)] = 0
            masked.append(m)
        halves.append(_circles(masked))
    (front, notes_f, _), (back, notes_b, _) = halves
    if abs(front["r"] - back["r"]) > MAX_RADIUS_MISMATCH_PX:
        raise PlacecellError(f"the two circles' radii differ by {abs(front['r'] - back['r']):.1f}"
                             f" px (more than {MAX_RADIUS_MISMATCH_PX}): not one camera's two "
                             "lenses side by side")
    notes = [f"front (left) lens: {notes_f[0]}", f"back (right) lens: {notes_b[0]}"]
    return "camera.dual_fisheye", {
        "width_px": w, "height_px": h, "fov_deg": fov,
        "radius_px": round((front["r"] + back["r"]) / 2, 2),
        "front_center_x_px": round(front["cx"], 2), "front_center_y_px": round(front["cy"], 2),
        "back_center_x_px": round(back["cx"], 2), "back_center_y_px": round(back["cy"], 2),
    }, notes


def _equirectangular(images: list[np.ndarray], args: argparse.Namespace) -> Calibration:
    w, h = _same_size(images)
    if abs(w / h - 2.0) > 0.01:
        raise PlacecellError(f"a {w} x {h} frame is not 2:1: a full equirectangular frame "
                             "spans 360 x 180 degrees; for a cropped one give "
                             "horizon_row_px yourself")
    return "camera.equirectangular", {"width_px": w, "height_px": h,
                                      "horizon_row_px": (h - 1) / 2}, [
        f"a full {w} x {h} equirectangular frame: its horizon is the middle row for a "
        "level camera", "bearing_offset_rad: the bearing the middle column sees; turn it "
        "until a thing straight ahead of the robot sits in the panorama's middle column"]


def _ocamcalib(images: list[np.ndarray], args: argparse.Namespace) -> Calibration:
    if not args.ocamcalib:
        raise PlacecellError("give OCamCalib's calib_results.txt with --ocamcalib: its "
                             "polynomials come from a calibration pattern, not one photo")
    calib = read_ocamcalib(args.ocamcalib)
    w, h = _same_size(images)
    if (calib["image_width_px"], calib["image_height_px"]) != (w, h):
        raise PlacecellError(f"{args.ocamcalib} was calibrated at {calib['image_width_px']} x "
                             f"{calib['image_height_px']}, the images are {w} x {h}")
    circle, notes, found = _circles(images)
    off = math.hypot(calib["center_col_px"] - circle["cx"], calib["center_row_px"] - circle["cy"])
    if off > MAX_CENTRE_OFFSET_PX:
        raise PlacecellError(f"the calibration's distortion centre is {off:.1f} px from the "
                             f"image circle's centre (more than {MAX_CENTRE_OFFSET_PX}): "
                             "another camera, or the camera moved in its mount")
    notes.append(f"the calibration's centre is {off:.1f} px from the image circle's")
    values: dict[str, Any] = {"file": args.ocamcalib, "lens": args.lens,
                              "max_radius_px": round(circle["r"], 2)}
    inner = [g.r_inner_px for g in found if g.r_inner_px is not None]
    if args.lens == "catadioptric" and len(inner) == len(found):
        values["min_radius_px"] = round(_agreed("inner radius", inner)[0], 2)
    return "camera.ocamcalib", values, notes


CALIBRATIONS = {"mirror": _mirror, "fisheye": _fisheye, "dual-fisheye": _dual_fisheye,
                "equirectangular": _equirectangular, "ocamcalib": _ocamcalib}
