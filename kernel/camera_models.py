"""Camera models: where a world direction falls in the raw image, and back (design §2).

The method needs one property of its camera: a column of the panorama is a bearing. Each
model here maps a direction — bearing β (rad, counter-clockwise from the robot's forward
axis) and elevation φ (rad, above the horizontal through the camera's viewpoint) — to a
raw image point (u column, v row, pixels) and back. The unwarper turns that into one
look-up table into the same cylindrical panorama band, so nothing above it knows which
camera the robot has. ``[camera] model`` picks one:

- ``mirror``: the hyperboloidal or polynomial mirror (kernel/mirror.py, thesis §3.7.2);
- ``ocamcalib``: Scaramuzza's omnidirectional model, as OCamCalib writes it
  (calib_results.txt: :func:`read_ocamcalib`), for catadioptric and fisheye cameras;
- ``fisheye``: an upward fisheye, OpenCV's model (cv2.fisheye, Kannala-Brandt) or
  equidistant from its field of view;
- ``equirectangular``: a 360° camera's equirectangular frames;
- ``dual-fisheye``: a 360° camera's raw frames, two fisheyes side by side.

Radial models share the azimuth rule of the mirror: image angle α (counter-clockwise,
image y up) = s β + offset, s = −1 when ``mirrored`` (kernel/mirror.py, ``Azimuth``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Protocol, get_args

import numpy as np

from kernel.angles import wrap_angle
from kernel.errors import ConfigError
from kernel.mirror import Azimuth, MirrorModel
from kernel.panorama import elevation_of_row
from kernel.sensor_settings import (
    CameraModelName,
    DualFisheyeSettings,
    EquirectangularSettings,
    FisheyeSettings,
    MirrorSettings,
    OcamcalibSettings,
    PanoramaSettings,
)

MODEL_NAMES: tuple[CameraModelName, ...] = get_args(CameraModelName)

Projection = (MirrorSettings | OcamcalibSettings | FisheyeSettings | EquirectangularSettings
              | DualFisheyeSettings)

Points = tuple[np.ndarray, np.ndarray]


class CameraModel(Protocol):
    """What the unwarper, the simulator and the calibration need of a camera."""

    top: float  # elevations (rad) of the panorama's top and bottom rows
    bottom: float

    def image_point(self, row: np.ndarray, bearing: np.ndarray) -> Points:
        """Raw (u, v) of panorama row ``row`` looking along ``bearing``."""

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        """Raw (u, v) of a direction; NaN where the camera does not see it."""

    def direction_of_point(self, u: np.ndarray, v: np.ndarray) -> Points:
        """(bearing in (−π, π], elevation) of raw pixels; the elevation is NaN where the
        pixel sees nothing of the world (outside the image circle, the camera itself)."""


def camera_model(projection: Projection, panorama: PanoramaSettings) -> CameraModel:
    """The model of a camera's settings (the [mirror] section or one of [camera.*])."""
    if isinstance(projection, MirrorSettings):
        return MirrorModel(projection, panorama)
    if isinstance(projection, OcamcalibSettings):
        return OcamcalibModel(projection, panorama)
    if isinstance(projection, FisheyeSettings):
        return FisheyeModel(projection, panorama)
    if isinstance(projection, EquirectangularSettings):
        return EquirectangularModel(projection, panorama)
    return DualFisheyeModel(projection, panorama)


class _Band:
    """Panorama rows as elevations: image_point from point_of_direction."""

    def __init__(self, panorama: PanoramaSettings) -> None:
        self.panorama = panorama
        self.top = math.radians(panorama.elevation_top_deg)
        self.bottom = math.radians(panorama.elevation_bottom_deg)

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        raise NotImplementedError

    def image_point(self, row: np.ndarray, bearing: np.ndarray) -> Points:
        phi = elevation_of_row(np.asarray(row, dtype=float), self.panorama.height, self.top,
                               self.bottom)
        return self.point_of_direction(bearing, np.asarray(phi))


class OcamcalibModel(_Band):
    """Scaramuzza's unified model (OCamCalib; Scaramuzza, Martinelli and Siegwart 2006).

    A pixel (row, column) is moved to the distortion centre (xc, yc) and through the
    inverse of the affine matrix [[c, d], [e, 1]] to (x′, y′); its ray is
    (x′, y′, pol(ρ)), ρ = |(x′, y′)| (cam2world). Back, a ray at incidence
    θ = atan(z / |(x, y)|) lies at ρ = invpol(θ) (world2cam). OCamCalib's z grows away
    from what the image centre sees: up for a camera looking up at a mirror (the centre
    sees the camera), down for an upward fisheye (the centre sees the zenith)."""

    def __init__(self, s: OcamcalibSettings, panorama: PanoramaSettings) -> None:
        super().__init__(panorama)
        self.s = s
        self.pol = np.asarray(s.pol, dtype=float)
        self.invpol = np.asarray(s.invpol, dtype=float)
        self.up = 1.0 if s.lens == "catadioptric" else -1.0  # z of "up"
        self.azimuth = Azimuth(s.mirrored, s.bearing_offset_rad)

    def _seen(self, rho: np.ndarray) -> np.ndarray:
        s = self.s
        ok = np.isfinite(rho) & (rho >= s.min_radius_px)
        return ok & (rho <= s.max_radius_px) if s.max_radius_px else ok

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        alpha = self.azimuth.image_angle(bearing)
        theta = self.up * np.asarray(elevation, dtype=float)
        rho = np.polynomial.polynomial.polyval(theta, self.invpol)
        rho = np.where(self._seen(rho), rho, np.nan)
        x, y = -np.sin(alpha) * rho, np.cos(alpha) * rho  # x along rows (down), y columns
        c, d, e = self.s.affine
        return x * e + y + self.s.center_col_px, x * c + y * d + self.s.center_row_px

    def direction_of_point(self, u: np.ndarray, v: np.ndarray) -> Points:
        c, d, e = self.s.affine
        dr = np.asarray(v, dtype=float) - self.s.center_row_px
        dc = np.asarray(u, dtype=float) - self.s.center_col_px
        inv = 1.0 / (c - d * e)
        x = inv * (dr - d * dc)
        y = inv * (-e * dr + c * dc)
        rho = np.hypot(x, y)
        z = np.polynomial.polynomial.polyval(rho, self.pol)
        elevation = np.where(self._seen(rho), np.arctan2(self.up * z, rho), np.nan)
        return self.azimuth.bearing(np.arctan2(-x, y)), elevation


class FisheyeModel(_Band):
    """An upward fisheye: a direction θ = π/2 − φ from the zenith lies at the distorted
    radius θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) (OpenCV's cv2.fisheye, Kannala and
    Brandt 2006), u = fx (x′ + skew y′) + cx, v = fy y′ + cy with (x′, y′) = θd (cos α,
    −sin α). Equidistant: k = 0 and f = radius / (fov / 2). Written for any θ, so lenses
    wider than 180° work (OpenCV's own projection divides by z)."""

    NEWTON_STEPS = 20

    def __init__(self, s: FisheyeSettings, panorama: PanoramaSettings) -> None:
        super().__init__(panorama)
        self.half_fov = math.radians(s.fov_deg) / 2.0
        if s.projection == "opencv":
            k = s.camera_matrix
            self.fx, self.fy, self.cx, self.cy = k[0][0], k[1][1], k[0][2], k[1][2]
            self.skew = k[0][1] / k[0][0]
            self.k = np.asarray(s.distortion, dtype=float)
        else:
            self.fx = self.fy = s.radius_px / self.half_fov
            self.cx, self.cy, self.skew = s.center_x_px, s.center_y_px, 0.0
            self.k = np.zeros(4)
        self.azimuth = Azimuth(s.mirrored, s.bearing_offset_rad)

    def distorted(self, theta: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        k1, k2, k3, k4 = self.k
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def incidence(self, theta_d: np.ndarray) -> np.ndarray:
        """θ of a distorted radius θd (Newton's method, as cv2.fisheye.undistortPoints);
        NaN where it does not converge to a θ within the field of view."""
        k1, k2, k3, k4 = self.k
        theta = np.array(theta_d, dtype=float)
        for _ in range(self.NEWTON_STEPS):
            t2 = theta * theta
            slope = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - (self.distorted(theta) - theta_d) / slope
        ok = (np.abs(self.distorted(theta) - theta_d) < 1e-6) & (theta >= 0) & (
            theta <= self.half_fov)
        return np.where(ok, theta, np.nan)

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        theta = math.pi / 2 - np.asarray(elevation, dtype=float)
        theta = np.where((theta >= 0) & (theta <= self.half_fov), theta, np.nan)
        alpha = self.azimuth.image_angle(bearing)
        r = self.distorted(theta)
        x, y = r * np.cos(alpha), -r * np.sin(alpha)
        return self.fx * (x + self.skew * y) + self.cx, self.fy * y + self.cy

    def direction_of_point(self, u: np.ndarray, v: np.ndarray) -> Points:
        y = (np.asarray(v, dtype=float) - self.cy) / self.fy
        x = (np.asarray(u, dtype=float) - self.cx) / self.fx - self.skew * y
        theta = self.incidence(np.hypot(x, y))
        return self.azimuth.bearing(np.arctan2(-y, x)), math.pi / 2 - theta


class EquirectangularModel(_Band):
    """Longitude λ = 2π (u + ½) / W − π across the frame (the middle column λ = 0, the
    frame not mirrored: right is clockwise), elevation φ = (horizon − v) π / H down it."""

    wraps_horizontally = True  # the frame's left and right edges meet

    def __init__(self, s: EquirectangularSettings, panorama: PanoramaSettings) -> None:
        super().__init__(panorama)
        self.s = s

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        s = self.s
        lam = np.mod(s.bearing_offset_rad - np.asarray(bearing, dtype=float) + math.pi,
                     2 * math.pi) - math.pi
        phi = np.asarray(elevation, dtype=float)
        phi = np.where(np.abs(phi) <= math.pi / 2, phi, np.nan)
        return ((lam + math.pi) * s.width_px / (2 * math.pi) - 0.5,
                s.horizon_row_px - phi * s.height_px / math.pi)

    def direction_of_point(self, u: np.ndarray, v: np.ndarray) -> Points:
        s = self.s
        lam = 2 * math.pi * (np.asarray(u, dtype=float) + 0.5) / s.width_px - math.pi
        phi = (s.horizon_row_px - np.asarray(v, dtype=float)) * math.pi / s.height_px
        return (_half_open(s.bearing_offset_rad - lam),
                np.where(np.abs(phi) <= math.pi / 2, phi, np.nan))


class DualFisheyeModel(_Band):
    """Two equidistant fisheyes back to back, optical axes level: the front one (left
    half) along the bearing ``bearing_offset_rad``, the back one (right half) opposite.
    A direction d = (cos φ cos β, cos φ sin β, sin φ) (x forward, y left, z up) is seen
    by the lens it faces, at θ from its axis and radius f θ; looking along its axis, a
    lens has the robot's right (front) or left (back) to the image's right and up up."""

    def __init__(self, s: DualFisheyeSettings, panorama: PanoramaSettings) -> None:
        super().__init__(panorama)
        self.s = s
        self.half_fov = math.radians(s.fov_deg) / 2.0
        self.f = s.radius_px / self.half_fov

    def point_of_direction(self, bearing: np.ndarray, elevation: np.ndarray) -> Points:
        s = self.s
        b = np.asarray(bearing, dtype=float) - s.bearing_offset_rad
        phi = np.asarray(elevation, dtype=float)
        dx, dy, dz = np.cos(phi) * np.cos(b), np.cos(phi) * np.sin(b), np.sin(phi)
        front = dx >= 0
        theta = np.arccos(np.clip(np.abs(dx), -1.0, 1.0))
        side = np.hypot(dy, dz)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(side > 1e-12, self.f * theta / side, 0.0)
        right = np.where(front, -dy, dy) * scale  # the image's right and down, from the centre
        down = -dz * scale
        u = np.where(front, s.front_center_x_px, s.back_center_x_px) + right
        v = np.where(front, s.front_center_y_px, s.back_center_y_px) + down
        return u, v

    def direction_of_point(self, u: np.ndarray, v: np.ndarray) -> Points:
        s = self.s
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        front = u < s.width_px / 2
        right = u - np.where(front, s.front_center_x_px, s.back_center_x_px)
        down = v - np.where(front, s.front_center_y_px, s.back_center_y_px)
        r = np.hypot(right, down)
        theta = r / self.f
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(r > 1e-12, np.sin(theta) / r, 0.0)
        dx = np.where(front, np.cos(theta), -np.cos(theta))
        dy = np.where(front, -right, right) * k
        dz = -down * k
        elevation = np.arcsin(np.clip(dz, -1.0, 1.0))
        elevation = np.where(theta <= self.half_fov, elevation, np.nan)
        return _half_open(np.arctan2(dy, dx) + s.bearing_offset_rad), elevation


def read_ocamcalib(path: str | Path) -> dict[str, Any]:
    """The values of OCamCalib's ``calib_results.txt`` (as the MATLAB toolbox and its
    successors write it) as [camera.ocamcalib] keys. Its data lines, '#' comments between:
    the cam2world polynomial (its length, then a0 a1 ...), the world2cam polynomial (its
    length, then its coefficients), the centre (row, column), the affine c d e, the image
    height and width. ConfigError naming the file and the line otherwise."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise ConfigError(f"cannot read OCamCalib file {p}: {e.strerror}") from e
    lines = [ln.strip() for ln in text.splitlines()]
    data = [ln for ln in lines if ln and not ln.startswith("#")]
    names = ("cam2world polynomial", "world2cam polynomial", "centre (row column)",
             "affine parameters (c d e)", "image size (height width)")
    if len(data) < len(names):
        raise ConfigError(f"OCamCalib file {p}: {len(data)} data lines, expected "
                          f"{len(names)} ({', '.join(names)})")
    rows: list[list[float]] = []
    for name, line in zip(names, data, strict=False):
        try:
            values = [float(x) for x in line.split()]
        except ValueError:
            raise ConfigError(f"OCamCalib file {p}: the {name} line {line[:60]!r} is not "
                              "numbers") from None
        if not all(math.isfinite(x) for x in values):
            raise ConfigError(f"OCamCalib file {p}: the {name} line holds a non-finite number")
        rows.append(values)
    for k in (0, 1):
        n = rows[k][0] if rows[k] else -1
        if n != int(n) or n < 1 or len(rows[k]) != int(n) + 1:
            raise ConfigError(f"OCamCalib file {p}: the {names[k]} line must give its length "
                              f"and then that many coefficients, got {len(rows[k])} numbers")
    for k, count in ((2, 2), (3, 3), (4, 2)):
        if len(rows[k]) != count:
            raise ConfigError(f"OCamCalib file {p}: the {names[k]} line must hold {count} "
                              f"numbers, got {len(rows[k])}")
    height, width = rows[4]
    if height != int(height) or width != int(width) or height < 1 or width < 1:
        raise ConfigError(f"OCamCalib file {p}: the image size {height} x {width} is not "
                          "two positive whole numbers")
    return {"pol": rows[0][1:], "invpol": rows[1][1:], "center_row_px": rows[2][0],
            "center_col_px": rows[2][1], "affine": rows[3], "image_height_px": int(height),
            "image_width_px": int(width)}


def write_ocamcalib(s: OcamcalibSettings) -> str:
    """``calib_results.txt`` text of the values of ``s`` (as OCamCalib writes it)."""
    def poly(c: list[float]) -> str:
        return f"{len(c)} " + " ".join(f"{x:.15e}" for x in c)

    return "\n".join([
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB)."
        " These are used by cam2world", "", poly(s.pol), "",
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in "
        "MATLAB). These are used by world2cam", "", poly(s.invpol), "",
        '#center: "row" and "column" coordinates (x and y) of the distortion center in '
        "pixels", "", f"{s.center_row_px:.6f} {s.center_col_px:.6f}", "",
        '#affine parameters "c", "d", "e"', "", " ".join(f"{x:.6f}" for x in s.affine), "",
        '#image size: "height" and "width"', "", f"{s.image_height_px} {s.image_width_px}",
        ""])


def _half_open(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to (−π, π], as arrays."""
    return np.asarray(wrap_angle(np.asarray(angle, dtype=float)))
