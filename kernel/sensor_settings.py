"""Settings of the panoramic sensor: mirror geometry and the unwarped panorama (design §2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.settings import setting


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
    bearing_offset_rad: float = setting(
        0.0, ge=-3.141592653589793, le=3.141592653589793,
        doc="image azimuth of the robot's forward axis",
    )
    mirrored: bool = setting(
        True, doc="image azimuth runs clockwise for counter-clockwise bearings"
    )

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
