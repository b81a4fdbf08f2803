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
        # Fixed-point maps: remap's fastest path.
        self._map1, self._map2 = cv2.convertMaps(u.astype(np.float32), v.astype(np.float32),
                                                 cv2.CV_16SC2)

    def unwarp(self, raw: np.ndarray) -> np.ndarray:
        """One frame: ``(h, w[, 3])`` uint8 raw image -> ``(H, W + 2m[, 3])`` uint8."""
        if raw.dtype != np.uint8 or raw.ndim not in (2, 3):
            raise ValueError(f"raw image must be uint8 (h, w) or (h, w, 3), got {raw.dtype} "
                             f"{raw.shape}")
        return cv2.remap(raw, self._map1, self._map2, interpolation=cv2.INTER_LINEAR,
                         borderMode=self._border, borderValue=0)

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
