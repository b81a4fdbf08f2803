"""Look-up-table unwarping of the raw image into the cylindrical panorama (§3.7.2).

The map from every panorama pixel (including the wrap margin) to its raw image point is
computed once per configuration; each frame is then one ``cv2.remap``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from kernel.camera_models import Projection, camera_model
from kernel.panorama import bearing_of_column, elevation_of_row, geometry_checksum
from kernel.sensor_settings import PanoramaSettings

PRESCALE_ABOVE = 1.3  # raw pixels a panorama pixel (median) above which frames are shrunk


def _median_footprint(u: np.ndarray, v: np.ndarray) -> float:
    """The median raw-image step of one panorama pixel (geometric mean of a column's and
    a row's step) over the pixels the camera sees."""
    col = np.hypot(np.diff(u, axis=1), np.diff(v, axis=1))[:-1, :]
    row = np.hypot(np.diff(u, axis=0), np.diff(v, axis=0))[:, :-1]
    seen = (u[:-1, :-1] >= 0) & (u[:-1, 1:] >= 0) & (u[1:, :-1] >= 0)
    steps = np.sqrt(col * row)[seen & (col < 50) & (row < 50)]  # not across a seam
    return float(np.median(steps)) if steps.size else 1.0


class Unwarper:
    """Raw camera image -> panorama of shape ``(H, W + 2m[, 3])``, whichever the camera
    model (kernel/camera_models.py)."""

    def __init__(self, projection: Projection, panorama: PanoramaSettings) -> None:
        self.projection = projection
        self.panorama = panorama
        self.model = camera_model(projection, panorama)
        H, W, m = panorama.height, panorama.width, panorama.wrap_margin
        rows = np.arange(H, dtype=float)[:, None]
        cols = (np.arange(W + 2 * m) - m) % W  # array column -> core column
        bearings = np.asarray(bearing_of_column(cols.astype(float), W))[None, :]
        u, v = self.model.image_point(np.broadcast_to(rows, (H, W + 2 * m)),
                                      np.broadcast_to(bearings, (H, W + 2 * m)))
        u = np.where(np.isfinite(u), u, -1.0)
        v = np.where(np.isfinite(v), v, -1.0)
        # A frame whose left and right edges meet (equirectangular) is read across them.
        self._border = (cv2.BORDER_WRAP if getattr(self.model, "wraps_horizontally", False)
                        else cv2.BORDER_CONSTANT)
        # A camera that images the band at a finer step than the panorama's (a 360° camera's
        # frames: 1.8-1.9 raw pixels a panorama pixel) is first shrunk by area averaging, as
        # a camera of the panorama's resolution would have seen it: bilinear sampling alone
        # would alias its texture and keep its noise.
        footprint = _median_footprint(u[:, m:m + W], v[:, m:m + W])
        self.prescale = 1.0 / footprint if footprint > PRESCALE_ABOVE else 1.0
        self._u, self._v = u, v
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        if self.prescale == 1.0:  # fixed-point maps: remap's fastest path
            self._map1, self._map2 = cv2.convertMaps(u.astype(np.float32),
                                                     v.astype(np.float32), cv2.CV_16SC2)

    def unwarp(self, raw: np.ndarray) -> np.ndarray:
        """One frame: ``(h, w[, 3])`` uint8 raw image -> ``(H, W + 2m[, 3])`` uint8."""
        if raw.dtype != np.uint8 or raw.ndim not in (2, 3):
            raise ValueError(f"raw image must be uint8 (h, w) or (h, w, 3), got {raw.dtype} "
                             f"{raw.shape}")
        if self.prescale != 1.0:
            h, w = raw.shape[:2]
            size = (max(1, round(w * self.prescale)), max(1, round(h * self.prescale)))
            map1, map2 = self._maps.get(size) or self._scaled_maps(size, w, h)
            return cv2.remap(cv2.resize(raw, size, interpolation=cv2.INTER_AREA), map1, map2,
                             interpolation=cv2.INTER_LINEAR, borderMode=self._border,
                             borderValue=0)
        return cv2.remap(raw, self._map1, self._map2, interpolation=cv2.INTER_LINEAR,
                         borderMode=self._border, borderValue=0)

    def _scaled_maps(self, size: tuple[int, int], w: int, h: int
                     ) -> tuple[np.ndarray, np.ndarray]:
        """The look-up table into a frame of ``w`` x ``h`` shrunk to ``size``."""
        sx, sy = size[0] / w, size[1] / h
        u = np.where(self._u >= 0, (self._u + 0.5) * sx - 0.5, -1.0)
        v = np.where(self._v >= 0, (self._v + 0.5) * sy - 0.5, -1.0)
        maps = cv2.convertMaps(u.astype(np.float32), v.astype(np.float32), cv2.CV_16SC2)
        self._maps[size] = maps
        return maps

    def geometry_checksum(self) -> str:
        """Digest of the camera model's and panorama's settings that define this panorama
        geometry (stored with a map, docs/design.md §6)."""
        return geometry_checksum(self.projection, self.panorama)

    def floor_distance_of_rows(self) -> np.ndarray:
        """Horizontal distance (m) to the floor point seen by each row; inf at or above the
        horizon. From the camera height: D = h / tan(−φ)."""
        p = self.panorama
        phi = np.asarray(elevation_of_row(np.arange(p.height, dtype=float), p.height,
                                          math.radians(p.elevation_top_deg),
                                          math.radians(p.elevation_bottom_deg)))
        with np.errstate(divide="ignore"):
            return np.where(phi < 0, p.camera_height_m / np.tan(-phi), np.inf)

    def horizon_row(self) -> float:
        """Fractional row of elevation 0."""
        p = self.panorama
        top, bottom = p.elevation_top_deg, p.elevation_bottom_deg
        return top * p.height / (top - bottom) - 0.5
