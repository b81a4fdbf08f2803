"""Panorama conventions shared by every module that reads or writes panoramas (docs/design.md §2).

A panorama array has shape ``(H, W + 2m, ...)``: the *core* of W columns covers 360°, and
``m`` wrap-margin columns copied from the other end stand on both sides (§3.7.2), so a
template crossing the seam can be matched in one piece.

Core column ``c`` (0 <= c < W) looks along bearing

    beta(c) = pi - 2 pi (c + 0.5) / W                                  (radians, CCW from +x)

so column 0 looks backwards-left, column W/2 straight ahead, and bearings decrease to the
right as in a person's view. Array column = core column + m.

Row ``r`` (0 <= r < H) looks at elevation (linear in elevation from top to bottom)

    phi(r) = top - (top - bottom) (r + 0.5) / H
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from kernel.angles import TWO_PI, wrap_angle
from kernel.sensor_settings import MirrorSettings

__all__ = ["TWO_PI", "wrap_angle", "bearing_of_column", "column_of_bearing", "elevation_of_row",
           "row_of_elevation", "add_wrap_margin", "core_of", "to_grey", "geometry_checksum"]


def bearing_of_column(c: float | np.ndarray, width: int) -> float | np.ndarray:
    """Bearing (rad) of core column ``c`` (may be fractional)."""
    return wrap_angle(math.pi - TWO_PI * (np.asarray(c, dtype=float) + 0.5) / width)


def column_of_bearing(beta: float | np.ndarray, width: int) -> float | np.ndarray:
    """Fractional core column in [-0.5, W - 0.5) of bearing ``beta``."""
    c = (math.pi - np.asarray(beta, dtype=float)) * width / TWO_PI - 0.5
    c = np.mod(c + 0.5, width) - 0.5
    return float(c) if np.ndim(c) == 0 else c


def elevation_of_row(r: float | np.ndarray, height: int, top: float, bottom: float
                     ) -> float | np.ndarray:
    """Elevation (rad) of row ``r``; ``top``/``bottom`` elevations (rad) of the band."""
    e = top - (top - bottom) * (np.asarray(r, dtype=float) + 0.5) / height
    return float(e) if np.ndim(e) == 0 else e


def row_of_elevation(phi: float | np.ndarray, height: int, top: float, bottom: float
                     ) -> float | np.ndarray:
    r = (top - np.asarray(phi, dtype=float)) * height / (top - bottom) - 0.5
    return float(r) if np.ndim(r) == 0 else r


def add_wrap_margin(core: np.ndarray, margin: int) -> np.ndarray:
    """``(H, W, ...)`` core -> ``(H, W + 2 margin, ...)`` with columns copied across the seam."""
    if margin == 0:
        return core
    return np.concatenate([core[:, -margin:], core, core[:, :margin]], axis=1)


def core_of(panorama: np.ndarray, margin: int) -> np.ndarray:
    """The W core columns of a panorama with wrap margin."""
    return panorama[:, margin: panorama.shape[1] - margin] if margin else panorama


def to_grey(image: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` BGR -> ``(H, W)`` uint8 grey; grey input is returned as is."""
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def geometry_checksum(projection: object, panorama: object) -> str:
    """A short digest of everything that defines the panorama geometry (the camera model's
    settings and the panorama's): the map store refuses a map made with another one
    (docs/design.md §6). The mirror's digest is the one maps had before other cameras."""
    import dataclasses
    import hashlib
    import json

    camera = dataclasses.asdict(projection)  # type: ignore[call-overload]
    if isinstance(projection, MirrorSettings):
        doc = {"mirror": camera, "panorama": dataclasses.asdict(panorama)}  # type: ignore[call-overload]
    else:  # the values, not where they were read from
        camera = {k: v for k, v in camera.items() if k != "file"}
        doc = {"camera": {type(projection).__name__: camera},
               "panorama": dataclasses.asdict(panorama)}  # type: ignore[call-overload]
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]
