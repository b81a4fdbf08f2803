"""The mirror model of design §2: hyperboloid optics, polynomial model, azimuth, inverses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from kernel.mirror import MirrorModel, hyperboloid_elevation, hyperboloid_radius
from kernel.sensor_settings import MirrorSettings, PanoramaSettings

A, B, F = MirrorSettings().a_m, MirrorSettings().b_m, MirrorSettings().focal_px


def _mirror_point(phi: float, a: float, b: float) -> tuple[float, float]:
    """The point of the upper sheet Z = b sqrt(1 + ρ²/a²) seen from the upper focus at
    elevation ``phi``, by bisection on ρ (independent of the closed form under test)."""
    c = math.hypot(a, b)

    def elevation(rho: float) -> float:
        return math.atan2(b * math.sqrt(1 + rho**2 / a**2) - c, rho)

    lo, hi = 1e-9, 10.0 * a  # the elevation grows with ρ (to 47° at 10 a)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if elevation(mid) < phi else (lo, mid)
    rho = 0.5 * (lo + hi)
    return rho, b * math.sqrt(1 + rho**2 / a**2)


@pytest.mark.parametrize("phi_deg", [-70.0, -45.0, -20.0, 0.0, 15.0, 25.0, 35.0])
def test_hyperboloid_reflects_rays_aimed_at_the_focus_into_the_pinhole(phi_deg: float) -> None:
    phi = math.radians(phi_deg)
    c = math.hypot(A, B)
    rho, z = _mirror_point(phi, A, B)
    # Law of reflection at M: d' = d − 2 (d·n) n with n the unit surface normal.
    n = np.array([-2 * rho / A**2, 2 * z / B**2])
    n /= np.linalg.norm(n)
    d = -np.array([math.cos(phi), math.sin(phi)])  # travelling towards the focus
    reflected = d - 2 * np.dot(d, n) * n
    to_pinhole = np.array([0.0, -c]) - np.array([rho, z])
    to_pinhole /= np.linalg.norm(to_pinhole)
    assert np.dot(reflected, to_pinhole) == pytest.approx(1.0, abs=1e-9)
    # The pinhole camera (optical axis +Z, focal length f) images M at r = f ρ / (Z + c).
    r = float(hyperboloid_radius(np.array([phi]), A, B, F)[0])
    assert r == pytest.approx(F * rho / (z + c), rel=1e-9)


def test_hyperboloid_inverse_and_misses() -> None:
    phi = np.radians(np.linspace(-85.0, 45.0, 131))
    r = hyperboloid_radius(phi, A, B, F)
    assert np.all(np.diff(r) > 0)  # higher elevations further out
    assert np.allclose(hyperboloid_elevation(r, A, B, F), phi, atol=1e-9)
    # Pixel rays steeper than the mirror's asymptote (r > f a / b) miss it.
    assert np.isnan(hyperboloid_elevation(np.array([1.01 * F * A / B]), A, B, F)[0])


@pytest.mark.parametrize("model", ["hyperboloid", "polynomial"])
@pytest.mark.parametrize(("mirrored", "offset"), [(True, 0.0), (False, 0.0), (True, 1.2),
                                                  (False, -2.5)])
def test_point_of_direction_and_back(model: str, mirrored: bool, offset: float) -> None:
    mirror = MirrorSettings(model=model, poly_coeffs=[0.0, 0.7, 0.3], mirrored=mirrored,
                            bearing_offset_rad=offset, center_x_px=310.5, center_y_px=245.0)
    pano = PanoramaSettings()
    mm = MirrorModel(mirror, pano)
    rng = np.random.default_rng(3)
    bearing = rng.uniform(-math.pi, math.pi, 500)
    elevation = rng.uniform(math.radians(pano.elevation_bottom_deg),
                            math.radians(pano.elevation_top_deg), 500)
    u, v = mm.point_of_direction(bearing, elevation)
    b2, e2 = mm.direction_of_point(u, v)
    assert np.allclose(e2, elevation, atol=1e-6)
    assert np.allclose(np.angle(np.exp(1j * (b2 - bearing))), 0.0, atol=1e-9)
    # The band-row form agrees with the direction form.
    rows = rng.uniform(-0.5, pano.height - 0.5, 100)
    assert np.allclose(mm.row_of_radius(mm.radius_of_row(rows)), rows, atol=1e-3)


def test_azimuth_conventions() -> None:
    pano = PanoramaSettings()
    left = math.pi / 2  # a direction on the robot's left, at the horizon
    mirrored = MirrorModel(MirrorSettings(mirrored=True), pano)
    u, v = mirrored.point_of_direction(np.array([left]), np.array([0.0]))
    assert abs(u[0] - 320.0) < 1e-6 and v[0] > 240.0 + 100  # mirrored: below the centre
    direct = MirrorModel(MirrorSettings(mirrored=False), pano)
    u, v = direct.point_of_direction(np.array([left]), np.array([0.0]))
    assert v[0] < 240.0 - 100
    turned = MirrorModel(MirrorSettings(bearing_offset_rad=math.pi / 2), pano)
    u, v = turned.point_of_direction(np.array([0.0]), np.array([0.0]))  # straight ahead
    assert abs(u[0] - 320.0) < 1e-6 and v[0] < 240.0 - 100  # forward is image "up"


def test_default_geometry_is_physically_consistent() -> None:
    """The default band lies on the default mirror's donut; its bottom row sees the floor
    about 1.4 m away and its top row looks above the horizon."""
    m, p = MirrorSettings(), PanoramaSettings()
    mm = MirrorModel(m, p)
    r_bottom, r_top = mm.row_radius_range()
    assert m.r_inner_px < r_bottom < r_top < m.r_outer_px
    assert m.r_outer_px < min(m.center_x_px, m.center_y_px)  # fits the 640 x 480 image
    bottom = math.radians(p.elevation_bottom_deg)
    assert 1.2 < p.camera_height_m / math.tan(-bottom) < 1.6
    assert p.elevation_top_deg > 10.0


def test_polynomial_must_be_monotonic() -> None:
    mirror = MirrorSettings(model="polynomial", poly_coeffs=[0.5, -1.0, 0.0])
    mm = MirrorModel(mirror, PanoramaSettings())
    with pytest.raises(ValueError, match="poly_coeffs"):
        mm.row_of_radius(np.array([100.0]))
    linear = MirrorModel(dataclasses.replace(mirror, poly_coeffs=[0.0, 1.0]), PanoramaSettings())
    # Linear: the bottom edge of the band at r_inner, the top edge at r_outer.
    assert np.allclose(linear.radius_of_row(np.array([119.5, -0.5])), [50.0, 228.0])
    assert np.isnan(linear.row_of_radius(np.array([20.0]))[0])
