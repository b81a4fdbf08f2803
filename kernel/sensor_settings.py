"""Settings of the panoramic sensor: mirror geometry and the unwarped panorama (design §2)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from kernel.settings import setting

_AZIMUTH_DOC = "image azimuth of the robot's forward axis"


def _bearing_offset(doc: str) -> Any:
    """The azimuth offset of a camera model (kernel/mirror.py Azimuth), in (−π, π]."""
    return setting(0.0, ge=-math.pi, le=math.pi, doc=doc)


def _mirrored(more: str) -> Any:
    """Whether a radial camera model's image is mirrored (kernel/mirror.py Azimuth)."""
    return setting(True, doc="image azimuth runs clockwise for counter-clockwise bearings"
                   + more)


@dataclass(frozen=True)
class MirrorSettings:
    """Where the mirror's donut lies in the raw image and how radius maps to elevation."""

    model: Literal["hyperboloid", "polynomial"] = setting(
        "hyperboloid", doc="radius-to-elevation model: hyperboloid (design §2) or polynomial"
    )
    center_x_px: float = setting(320.0, ge=0.0, doc="donut centre, image column")
    center_y_px: float = setting(240.0, ge=0.0, doc="donut centre, image row")
    r_inner_px: float = setting(50.0, gt=0.0, doc="inner donut radius used for the panorama")
    r_outer_px: float = setting(228.0, gt=0.0, doc="outer donut radius used for the panorama")
    # Hyperboloid (X²+Y²)/a² − Z²/b² = −1, foci at ±c, c² = a² + b² (docs/design.md §2).
    a_m: float = setting(0.0233, gt=0.0, doc="hyperboloid semi-axis a")
    b_m: float = setting(0.0281, gt=0.0, doc="hyperboloid semi-axis b")
    focal_px: float = setting(520.0, gt=0.0, doc="camera focal length in pixels")
    # Polynomial model: normalised radius (0 at r_inner, 1 at r_outer) as a polynomial
    # of the normalised panorama row counted from the bottom (0) to the top (1).
    poly_coeffs: list[float] = setting([0.0, 1.0], doc="radial polynomial, lowest order first")
    bearing_offset_rad: float = _bearing_offset(_AZIMUTH_DOC)
    mirrored: bool = _mirrored("")

    def __post_init__(self) -> None:
        if self.r_outer_px <= self.r_inner_px:
            raise ValueError(
                f"r_outer_px ({self.r_outer_px}) must be larger than r_inner_px ({self.r_inner_px})"
            )


@dataclass(frozen=True)
class PanoramaSettings:
    """The unwarped cylindrical panorama (docs/design.md §2)."""

    width: int = setting(720, ge=64, le=4096, doc="columns over 360 degrees")
    height: int = setting(120, ge=16, le=1024, doc="rows over the elevation band")
    wrap_margin: int = setting(16, ge=0, le=256, doc="columns copied across the seam (§3.7.2)")
    elevation_top_deg: float = setting(25.0, gt=-90.0, lt=90.0, doc="elevation of row 0")
    elevation_bottom_deg: float = setting(-45.0, gt=-90.0, lt=90.0, doc="elevation of last row")
    camera_height_m: float = setting(1.40, gt=0.0, le=5.0, doc="mirror focus above the floor")

    def __post_init__(self) -> None:
        if self.elevation_bottom_deg >= self.elevation_top_deg:
            raise ValueError("elevation_bottom_deg must be below elevation_top_deg")


# ------------------------------------------------------------------ other camera models
# Each is one way of imaging the world that the panorama is unwarped from (design §2,
# kernel/camera_models.py); `[camera] model` picks one, the mirror ([mirror]) by default.

CameraModelName = Literal["mirror", "ocamcalib", "fisheye", "equirectangular", "dual-fisheye"]



@dataclass(frozen=True)
class OcamcalibSettings:
    """Scaramuzza's omnidirectional model as OCamCalib calibrates it (its calib_results.txt:
    ``file``, read when the configuration is loaded, or the values below)."""

    file: str = setting("", doc="OCamCalib's calib_results.txt; its values replace the "
                        "ones below when the configuration is loaded")
    lens: Literal["catadioptric", "fisheye"] = setting(
        "catadioptric", doc="what the image centre sees: the camera itself below "
        "(catadioptric, a camera looking up at a mirror) or the zenith (an upward fisheye)")
    pol: list[float] = setting([-1.0], doc="cam2world polynomial a0, a1, ... (ss)")
    invpol: list[float] = setting([1.0], doc="world2cam polynomial of the incidence angle")
    center_row_px: float = setting(240.0, ge=0.0, doc="distortion centre, image row (xc)")
    center_col_px: float = setting(320.0, ge=0.0, doc="distortion centre, image column (yc)")
    affine: list[float] = setting([1.0, 0.0, 0.0], doc="affine parameters c, d, e")
    image_height_px: int = setting(480, ge=1, doc="calibrated image height")
    image_width_px: int = setting(640, ge=1, doc="calibrated image width")
    min_radius_px: float = setting(0.0, ge=0.0, doc="pixels nearer the centre see nothing "
                                   "of the world (a mirror's inner rim; 0: none)")
    max_radius_px: float = setting(0.0, ge=0.0, doc="pixels further out see nothing (the "
                                   "outer rim; 0: the image's edge)")
    mirrored: bool = _mirrored("")
    bearing_offset_rad: float = _bearing_offset(_AZIMUTH_DOC)

    def __post_init__(self) -> None:
        if len(self.affine) != 3:
            raise ValueError(f"affine must hold c, d, e: got {len(self.affine)} values")
        if abs(self.affine[0] - self.affine[1] * self.affine[2]) < 1e-9:
            raise ValueError("affine (c, d, e): c - d e is 0, the matrix is singular")
        if not self.pol or not self.invpol:
            raise ValueError("pol and invpol need at least one coefficient each")
        if self.max_radius_px and self.max_radius_px <= self.min_radius_px:
            raise ValueError("max_radius_px must be above min_radius_px")


@dataclass(frozen=True)
class FisheyeSettings:
    """An upward fisheye lens: OpenCV's model (cv2.fisheye, Kannala-Brandt: θd = θ (1 +
    k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)) with K and D as its calibration writes them, or the
    equidistant model (θd = θ) from the image circle and the field of view."""

    projection: Literal["opencv", "equidistant"] = setting(
        "equidistant", doc="opencv: camera_matrix and distortion; equidistant: the circle "
        "(center, radius_px) spans fov_deg")
    camera_matrix: list[list[float]] = setting(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], doc="K, 3 x 3 (opencv)")
    distortion: list[float] = setting([0.0, 0.0, 0.0, 0.0], doc="D = k1..k4 (opencv)")
    center_x_px: float = setting(320.0, ge=0.0, doc="image circle's centre, column "
                                 "(equidistant)")
    center_y_px: float = setting(240.0, ge=0.0, doc="image circle's centre, row (equidistant)")
    radius_px: float = setting(235.0, gt=0.0, doc="image circle's radius (equidistant)")
    fov_deg: float = setting(220.0, gt=0.0, le=360.0, doc="the lens's field of view: "
                             "directions further than half of it from the zenith are not seen")
    mirrored: bool = _mirrored(" (so it does for a camera looking up)")
    bearing_offset_rad: float = _bearing_offset(_AZIMUTH_DOC)

    def __post_init__(self) -> None:
        k = self.camera_matrix
        if len(k) != 3 or any(len(row) != 3 for row in k):
            raise ValueError("camera_matrix must be 3 x 3 (K as OpenCV writes it)")
        if self.projection == "opencv" and (k[0][0] <= 0 or k[1][1] <= 0):
            raise ValueError("camera_matrix: the focal lengths K[0][0] and K[1][1] must be "
                             "positive")
        if len(self.distortion) != 4:
            raise ValueError(f"distortion must hold k1..k4: got {len(self.distortion)} "
                             "values")


@dataclass(frozen=True)
class EquirectangularSettings:
    """A 360° camera's equirectangular frames: 360° across, 180° down."""

    width_px: int = setting(1280, ge=16, doc="frame width (360 degrees)")
    height_px: int = setting(640, ge=8, doc="frame height (180 degrees)")
    horizon_row_px: float = setting(319.5, doc="row of elevation 0 (the middle row of a "
                                    "level camera)")
    bearing_offset_rad: float = _bearing_offset("bearing seen by the frame's middle column")


@dataclass(frozen=True)
class DualFisheyeSettings:
    """A consumer 360° camera's raw frames: two equidistant fisheyes side by side, the
    left looking forward, the right backward (optical axes level)."""

    width_px: int = setting(1280, ge=16, doc="frame width (both circles)")
    height_px: int = setting(640, ge=8, doc="frame height")
    fov_deg: float = setting(195.0, gt=180.0, le=360.0, doc="each lens's field of view")
    radius_px: float = setting(316.0, gt=0.0, doc="each image circle's radius")
    front_center_x_px: float = setting(319.5, ge=0.0, doc="front lens's centre, column")
    front_center_y_px: float = setting(319.5, ge=0.0, doc="front lens's centre, row")
    back_center_x_px: float = setting(959.5, ge=0.0, doc="back lens's centre, column")
    back_center_y_px: float = setting(319.5, ge=0.0, doc="back lens's centre, row")
    bearing_offset_rad: float = _bearing_offset("bearing of the front lens's axis")
