"""Tracking landmark templates between frames (docs/design.md §3, thesis §4.5.2).

Each template is matched with zero-mean NCC in a small window around its predicted
position (from odometry and the landmark's depth where known, else its last position);
windows are cut modulo the panorama width, so templates crossing the seam are tracked
like any other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daemon.vision.landmarks import TEMPLATE
from daemon.vision.ncc import ncc_map, subpixel_peak
from kernel.panorama import TWO_PI, column_of_bearing, core_of


@dataclass(frozen=True)
class Track:
    """Where each template was found: core column and row of its top-left pixel
    (fractional, sub-pixel), and the NCC score."""

    cols: np.ndarray
    rows: np.ndarray
    scores: np.ndarray


def predict_column(bearing: float, depth: float, pose: tuple[float, float, float],
                   width: int) -> float:
    """Core column (template left edge) where a landmark at (depth, bearing) in the
    reference frame appears from ``pose`` = (x, y, θ) relative to the reference:
    φ = atan2(d sinγ − y, d cosγ − x) − θ   (§4.6, the observation model)."""
    x, y, theta = pose
    phi = math.atan2(depth * math.sin(bearing) - y, depth * math.cos(bearing) - x) - theta
    return float(column_of_bearing(phi, width)) - (TEMPLATE - 1) / 2.0


def track(panorama_grey: np.ndarray, margin: int, templates: np.ndarray, cols: np.ndarray,
          rows: np.ndarray, radius_cols: int = 12, radius_rows: int = 6) -> Track:
    """Find each (16, 16) template near its predicted (col, row)."""
    core = core_of(panorama_grey, margin)
    H, W = core.shape
    out_c = np.empty(len(templates))
    out_r = np.empty(len(templates))
    out_s = np.empty(len(templates))
    for i, (tpl, c, r) in enumerate(zip(templates, cols, rows, strict=True)):
        c0 = int(math.floor(c)) - radius_cols
        r0 = max(0, min(H - TEMPLATE, int(round(r)) - radius_rows))
        r1 = min(H, r0 + 2 * radius_rows + TEMPLATE)
        idx = np.arange(c0, c0 + 2 * radius_cols + TEMPLATE) % W  # across the seam
        window = np.take(core[r0:r1], idx, axis=1)
        score, x, y = subpixel_peak(ncc_map(window, tpl))
        out_c[i] = (c0 + x) % W
        out_r[i] = r0 + y
        out_s[i] = score
    return Track(out_c, out_r, out_s)


def column_to_bearing_of_centre(col: np.ndarray, width: int) -> np.ndarray:
    """Bearing of the template centre for fractional left columns."""
    c = np.asarray(col, dtype=float) + (TEMPLATE - 1) / 2.0
    b = math.pi - TWO_PI * (c + 0.5) / width
    return np.asarray(np.mod(b + math.pi, TWO_PI) - math.pi)
