"""The mirror model: elevation and bearing of a world direction <-> raw image point (design §2).

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
from dataclasses import dataclass

import numpy as np

from kernel.angles import wrap_angle
from kernel.panorama import elevation_of_row, row_of_elevation
from kernel.sensor_settings import MirrorSettings, PanoramaSettings


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


def hyperboloid_elevation(r: np.ndarray, a: float, b: float, focal_px: float) -> np.ndarray:
    """Inverse of :func:`hyperboloid_radius`: elevation (rad), seen from the mirror's focus,
    of the world direction imaged at radius ``r`` (px); NaN where the pixel's ray misses the
    mirror (§3.7.2)."""
    r = np.asarray(r, dtype=float)
    c = math.hypot(a, b)
    q = r / focal_px
    # Pixel ray from the pinhole P = (0, −c): (ρ, Z) = (k q, k − c), k > 0. On the mirror
    # Z²/b² − ρ²/a² = 1:  k² (1/b² − q²/a²) − k (2c/b²) + (c²/b² − 1) = 0.
    A = 1.0 / b**2 - q**2 / a**2
    B = -2.0 * c / b**2
    C = a**2 / b**2
    disc = B * B - 4.0 * A * C
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        roots = np.stack([(-B - sq) / (2.0 * A), (-B + sq) / (2.0 * A)])
    # The mirror is the upper sheet (Z >= b); the pixel sees its first hit there.
    on_sheet = np.isfinite(roots) & (roots > 0) & (roots - c >= b * (1.0 - 1e-9))
    k = np.where(on_sheet, roots, np.inf).min(axis=0)
    rho, z = k * q, k - c
    with np.errstate(invalid="ignore"):
        phi = np.arctan2(z - c, rho)  # direction from the focus F = (0, c) to the hit point
    return np.where(np.isfinite(k), phi, np.nan)


@dataclass(frozen=True)
class Azimuth:
    """Image angle α (counter-clockwise, image y up) of a bearing: α = s β + offset, s = −1
    when ``mirrored``; the rule of every radial camera model (kernel/camera_models.py)."""

    mirrored: bool
    offset: float

    def image_angle(self, bearing: np.ndarray) -> np.ndarray:
        sign = -1.0 if self.mirrored else 1.0
        return sign * np.asarray(bearing, dtype=float) + self.offset

    def bearing(self, alpha: np.ndarray) -> np.ndarray:
        """The bearing, in (−π, π], of image angle ``alpha``."""
        sign = -1.0 if self.mirrored else 1.0
        return np.asarray(wrap_angle(sign * (np.asarray(alpha, dtype=float) - self.offset)))


class MirrorModel:
    """Maps panorama (row, bearing) to raw image points for one configuration."""

    def __init__(self, mirror: MirrorSettings, panorama: PanoramaSettings) -> None:
        self.mirror = mirror
        self.panorama = panorama
        self.top = math.radians(panorama.elevation_top_deg)
        self.bottom = math.radians(panorama.elevation_bottom_deg)
        self.azimuth = Azimuth(mirror.mirrored, mirror.bearing_offset_rad)

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

    def row_of_radius(self, r: np.ndarray) -> np.ndarray:
        """Fractional panorama row imaged at radius ``r`` (px): the inverse of
        :meth:`radius_of_row` (NaN outside the mirror, or outside the polynomial's range)."""
        r = np.asarray(r, dtype=float)
        m, p = self.mirror, self.panorama
        if m.model == "hyperboloid":
            phi = hyperboloid_elevation(r, m.a_m, m.b_m, m.focal_px)
            return np.asarray(row_of_elevation(phi, p.height, self.top, self.bottom))
        # The polynomial need not be invertible in closed form: invert it on a fine table
        # of rows (it must be monotonic over the band, as any usable radial model is).
        rows = np.linspace(-0.5, p.height - 0.5, 8 * p.height + 1)
        radii = self.radius_of_row(rows)
        if not np.all(np.diff(radii) < 0):
            raise ValueError("mirror.poly_coeffs: the radius must grow from the bottom row "
                             "to the top row")
        out = np.interp(r, radii[::-1], rows[::-1], left=np.nan, right=np.nan)
        return np.asarray(out)

    def radius_of_elevation(self, phi: np.ndarray) -> np.ndarray:
        """Image radius (px) of elevation ``phi`` (rad)."""
        m, p = self.mirror, self.panorama
        if m.model == "hyperboloid":
            return hyperboloid_radius(np.asarray(phi, dtype=float), m.a_m, m.b_m, m.focal_px)
        return self.radius_of_row(np.asarray(row_of_elevation(phi, p.height, self.top,
                                                              self.bottom)))

    def elevation_of_radius(self, r: np.ndarray) -> np.ndarray:
        """Elevation (rad) imaged at radius ``r`` (px)."""
        m, p = self.mirror, self.panorama
        if m.model == "hyperboloid":
            return hyperboloid_elevation(np.asarray(r, dtype=float), m.a_m, m.b_m, m.focal_px)
        return np.asarray(elevation_of_row(self.row_of_radius(r), p.height, self.top,
                                           self.bottom))

    def image_angle(self, bearing: np.ndarray) -> np.ndarray:
        return self.azimuth.image_angle(bearing)

    def image_point(self, row: np.ndarray, bearing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw image (u, v) in pixels of panorama row ``row`` looking along ``bearing``."""
        r = self.radius_of_row(row)
        alpha = self.image_angle(bearing)
        u = self.mirror.center_x_px + r * np.cos(alpha)
        v = self.mirror.center_y_px - r * np.sin(alpha)
        return u, v

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Raw image (u, v) in pixels of the world direction (bearing, elevation), both in
        radians in the robot frame (bearing CCW from the forward axis)."""
        r = self.radius_of_elevation(elevation)
        alpha = self.image_angle(bearing)
        return (self.mirror.center_x_px + r * np.cos(alpha),
                self.mirror.center_y_px - r * np.sin(alpha))

    def direction_of_point(self, u: np.ndarray, v: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`point_of_direction`: (bearing in (−π, π], elevation) in radians
        of raw image point (u, v); the elevation is NaN where the pixel misses the mirror."""
        du = np.asarray(u, dtype=float) - self.mirror.center_x_px
        dv = self.mirror.center_y_px - np.asarray(v, dtype=float)
        return (self.azimuth.bearing(np.arctan2(dv, du)),
                self.elevation_of_radius(np.hypot(du, dv)))

    def row_radius_range(self) -> tuple[float, float]:
        """Image radii of the bottom and top panorama rows (for checks and rendering)."""
        r = self.radius_of_row(np.array([self.panorama.height - 0.5, -0.5]))
        return float(r[0]), float(r[1])
