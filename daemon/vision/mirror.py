"""The mirror model: elevation and bearing of a world direction <-> raw image point (SPEC §2).

Hyperboloid (X² + Y²)/a² − Z²/b² = −1 with foci at (0, 0, ±c), c² = a² + b² (§3.7.2,
Yamazawa et al. 1995). The mirror is the upper sheet; the camera's pinhole sits at the lower
focus (0, 0, −c) looking up. A ray from a world point aimed at the upper focus F = (0, 0, c)
reflects into the pinhole, so the elevation φ of a point seen from F maps one-to-one to an
image radius r(φ): intersect the ray with the mirror, project the hit point through the
pinhole (focal length f in pixels).

The polynomial model serves uncalibrated cameras: the normalised radius
(r − r_in)/(r_out − r_in) is a polynomial of the normalised panorama row u (0 at the bottom
row, 1 at the top row).

Azimuth: image angle α (counter-clockwise, image y up) = s·β + offset, s = −1 when
``mirrored`` (a camera looking up at a mirror sees the world mirrored).
"""

from __future__ import annotations

import math

import numpy as np

from daemon.vision.panorama import elevation_of_row
from daemon.vision.settings import MirrorSettings, PanoramaSettings


def hyperboloid_radius(phi: np.ndarray, a: float, b: float, focal_px: float) -> np.ndarray:
    """Image radius (px) of elevation ``phi`` (rad) seen from the mirror's focus; NaN where
    the ray misses the mirror sheet."""
    phi = np.asarray(phi, dtype=float)
    c = math.hypot(a, b)
    s_phi, c_phi = np.sin(phi), np.cos(phi)
    # Hit point M = F + s (cos φ, sin φ) in the (ρ, Z) half-plane, on Z²/b² − ρ²/a² = 1:
    #   s² (sin²φ/b² − cos²φ/a²) + s (2 c sin φ / b²) + (c²/b² − 1) = 0,  c²/b² − 1 = a²/b².
    A = s_phi**2 / b**2 - c_phi**2 / a**2
    B = 2.0 * c * s_phi / b**2
    C = a**2 / b**2
    disc = np.sqrt(np.maximum(B * B - 4.0 * A * C, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.stack([(-B + disc) / (2.0 * A), (-B - disc) / (2.0 * A)])
    s = np.where(roots > 0, roots, np.inf).min(axis=0)
    rho = s * c_phi
    z = c + s * s_phi
    with np.errstate(invalid="ignore"):
        r = focal_px * rho / (z + c)  # pinhole at (0, 0, −c), optical axis +Z
    return np.where(np.isfinite(r), r, np.nan)


class MirrorModel:
    """Maps panorama (row, bearing) to raw image points for one configuration."""

    def __init__(self, mirror: MirrorSettings, panorama: PanoramaSettings) -> None:
        self.mirror = mirror
        self.panorama = panorama
        self.top = math.radians(panorama.elevation_top_deg)
        self.bottom = math.radians(panorama.elevation_bottom_deg)

    def radius_of_row(self, row: np.ndarray) -> np.ndarray:
        """Image radius (px) of (fractional) panorama rows."""
        row = np.asarray(row, dtype=float)
        m = self.mirror
        if m.model == "hyperboloid":
            phi = np.asarray(elevation_of_row(row, self.panorama.height, self.top, self.bottom))
            return hyperboloid_radius(phi, m.a_m, m.b_m, m.focal_px)
        u = 1.0 - (row + 0.5) / self.panorama.height  # 0 at the bottom row, 1 at the top
        norm = np.polynomial.polynomial.polyval(u, np.asarray(m.poly_coeffs, dtype=float))
        return np.asarray(m.r_inner_px + (m.r_outer_px - m.r_inner_px) * norm)

    def image_angle(self, bearing: np.ndarray) -> np.ndarray:
        sign = -1.0 if self.mirror.mirrored else 1.0
        return sign * np.asarray(bearing, dtype=float) + self.mirror.bearing_offset_rad

    def bearing_of_image_angle(self, alpha: np.ndarray) -> np.ndarray:
        sign = -1.0 if self.mirror.mirrored else 1.0
        return sign * (np.asarray(alpha, dtype=float) - self.mirror.bearing_offset_rad)

    def image_point(self, row: np.ndarray, bearing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw image (u, v) in pixels of panorama row ``row`` looking along ``bearing``."""
        r = self.radius_of_row(row)
        alpha = self.image_angle(bearing)
        u = self.mirror.center_x_px + r * np.cos(alpha)
        v = self.mirror.center_y_px - r * np.sin(alpha)
        return u, v

    def row_radius_range(self) -> tuple[float, float]:
        """Image radii of the bottom and top panorama rows (for checks and rendering)."""
        r = self.radius_of_row(np.array([self.panorama.height - 0.5, -0.5]))
        return float(r[0]), float(r[1])
