"""Find the mirror's donut in a raw image: centre and inner/outer radii (SPEC §2).

A starting point for ``[mirror]`` on a new camera, real or rendered:
1. the bright mirror region against the dark surround (Otsu threshold, largest blob,
   enclosing circle) gives a first centre and outer radius;
2. in a polar resampling around that centre, each of 360 rays gives the radius of the
   strongest fall in brightness near the rim (outer edge) and the strongest rise near the
   middle (the camera's own dark reflection: inner edge);
3. circles are fitted to both edge sets by least squares with outlier rejection, and the
   polar step is repeated once around the refined centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from kernel.errors import PlacecellError


class MirrorNotFoundError(PlacecellError):
    """No donut could be found in the image."""


@dataclass(frozen=True)
class MirrorGeometry:
    center_x_px: float
    center_y_px: float
    r_inner_px: float
    r_outer_px: float
    outer_residual_px: float  # RMS distance of the rim edge points from the fitted circle
    inner_residual_px: float


def fit_circle(x: np.ndarray, y: np.ndarray, iterations: int = 3
               ) -> tuple[float, float, float, float]:
    """Least-squares circle (Kasa fit) with outlier rejection: (cx, cy, r, rms residual)."""
    keep = np.ones(len(x), bool)
    cx = cy = r = rms = float("nan")
    for _ in range(iterations):
        if keep.sum() < 3:
            raise MirrorNotFoundError("too few edge points to fit a circle")
        xs, ys = x[keep], y[keep]
        # x² + y² = 2 cx x + 2 cy y + (r² − cx² − cy²): linear in the unknowns.
        A = np.column_stack([2 * xs, 2 * ys, np.ones_like(xs)])
        b = xs**2 + ys**2
        (cx, cy, k), *_ = np.linalg.lstsq(A, b, rcond=None)
        r = float(np.sqrt(k + cx**2 + cy**2))
        resid = np.abs(np.hypot(x - cx, y - cy) - r)
        rms = float(np.sqrt(np.mean(resid[keep] ** 2)))
        mad = float(np.median(resid[keep])) + 1e-6
        keep = resid < max(3.0 * 1.4826 * mad, 0.75)
    return float(cx), float(cy), r, rms


def _rough(grey: np.ndarray) -> tuple[float, float, float]:
    thresh, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    bright = (grey > max(10.0, 0.5 * thresh)).astype(np.uint8)
    mask = np.asarray(cv2.morphologyEx(bright, cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8)))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise MirrorNotFoundError("the image has no bright region that could be a mirror")
    biggest = max(contours, key=cv2.contourArea)
    (cx, cy), r = cv2.minEnclosingCircle(biggest)
    if r < 10:
        raise MirrorNotFoundError(f"the brightest region is too small for a mirror ({r:.0f} px)")
    return float(cx), float(cy), float(r)


def _edges(grey: np.ndarray, cx: float, cy: float, r_max: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius of the rim edge and of the inner edge on each of 360 rays."""
    n_r = int(np.ceil(r_max))
    # WARP_FILL_OUTLIERS: rays leaving the image read 0 (dark surround); without it
    # OpenCV leaves those pixels uninitialised, which made results vary run to run.
    polar = cv2.warpPolar(grey.astype(np.float32), (n_r, 360), (cx, cy), r_max,
                          cv2.INTER_LINEAR + cv2.WARP_POLAR_LINEAR + cv2.WARP_FILL_OUTLIERS)
    polar = cv2.GaussianBlur(polar, (1, 5), 0)  # smooth along the angle only
    grad = np.gradient(polar, axis=1)
    scale = r_max / n_r
    r_rough = r_max / 1.25
    lo, hi = int(0.6 * r_rough / scale), min(n_r - 1, int(1.2 * r_rough / scale))
    # Rim: walking in from outside, the first strong fall in brightness (mirror -> dark
    # surround). Scanning from outside means dark things seen in the mirror, further in,
    # cannot be taken for it: among the falls steeper than half the ray's steepest, the
    # outermost wins.
    band = grad[:, lo:hi]
    steep = band <= 0.5 * band.min(axis=1, keepdims=True)
    outermost = band.shape[1] - 1 - np.argmax(steep[:, ::-1], axis=1)
    outer = (lo + outermost) * scale
    # Inner edge: the first departure, walking out from the centre, from the uniform level
    # of the camera's own reflection (texture further out cannot be mistaken for it).
    core = polar[:, : max(2, int(0.03 * r_rough / scale))]
    level = float(np.median(core))
    spread = float(np.std(core))
    departed = np.abs(polar - level) > max(12.0, 4.0 * spread)
    departed[:, hi:] = True
    inner = np.argmax(departed, axis=1) * scale
    angles = np.radians(np.arange(360) + 0.5)
    return angles, outer, inner


def detect_mirror(image: np.ndarray) -> MirrorGeometry:
    """Centre and radii of the mirror donut in a raw ``uint8`` image (grey or BGR)."""
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or min(image.shape[:2]) < 32:
        raise MirrorNotFoundError(f"expected a uint8 image of at least 32 x 32 px, got "
                                  f"{image.dtype} {image.shape}")
    raw_grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    grey = np.asarray(cv2.GaussianBlur(raw_grey, (5, 5), 0))
    cx, cy, r = _rough(grey)
    r_in = out_rms = in_rms = 0.0
    for _ in range(2):
        angles, outer, inner = _edges(grey, cx, cy, 1.25 * r)
        ocx, ocy, r, out_rms = fit_circle(cx + outer * np.cos(angles),
                                          cy + outer * np.sin(angles))
        _, _, r_in, in_rms = fit_circle(cx + inner * np.cos(angles),
                                        cy + inner * np.sin(angles))
        cx, cy = ocx, ocy
    return MirrorGeometry(round(cx, 2), round(cy, 2), round(r_in, 2), round(r, 2),
                          round(out_rms, 3), round(in_rms, 3))
