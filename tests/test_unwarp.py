"""The LUT unwarper against an analytic raw image (design §2, §3.7.2), without the renderer."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from daemon.vision.unwarp import Unwarper
from kernel.mirror import MirrorModel
from kernel.panorama import bearing_of_column, core_of, elevation_of_row
from kernel.sensor_settings import MirrorSettings, PanoramaSettings


def _brightness(bearing: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """A smooth pattern over directions, so interpolation error stays small."""
    return 128.0 + 60.0 * np.sin(3.0 * bearing) + 50.0 * np.cos(6.0 * elevation)


def _analytic_raw(mirror: MirrorSettings, pano: PanoramaSettings) -> np.ndarray:
    """(480, 640) grey raw image whose every pixel shows ``_brightness`` of its direction."""
    u, v = np.meshgrid(np.arange(640, dtype=float), np.arange(480, dtype=float))
    bearing, elevation = MirrorModel(mirror, pano).direction_of_point(u, v)
    value = np.where(np.isfinite(elevation), _brightness(bearing, elevation), 0.0)
    return np.clip(np.round(value), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("mirror", [
    MirrorSettings(),
    MirrorSettings(center_x_px=305.3, center_y_px=251.8, bearing_offset_rad=0.7,
                   mirrored=False),
    MirrorSettings(model="polynomial", poly_coeffs=[0.05, 0.6, 0.35]),
], ids=["default", "offset-unmirrored", "polynomial"])
def test_each_panorama_pixel_shows_its_direction(mirror: MirrorSettings) -> None:
    pano = PanoramaSettings()
    unwarper = Unwarper(mirror, pano)
    out = unwarper.unwarp(_analytic_raw(mirror, pano))
    H, W, m = pano.height, pano.width, pano.wrap_margin
    assert out.shape == (H, W + 2 * m) and out.dtype == np.uint8
    bearing = np.asarray(bearing_of_column(np.arange(W, dtype=float), W))[None, :]
    elevation = np.asarray(elevation_of_row(np.arange(H, dtype=float), H,
                                            math.radians(pano.elevation_top_deg),
                                            math.radians(pano.elevation_bottom_deg)))[:, None]
    expected = _brightness(bearing, elevation)
    error = np.abs(core_of(out, m).astype(float) - expected)
    assert float(np.percentile(error, 99)) <= 2.0 and float(error.mean()) <= 0.6
    # The wrap margin repeats the other end of the core (§3.7.2).
    assert np.array_equal(out[:, :m], out[:, W: W + m])
    assert np.array_equal(out[:, -m:], out[:, m: 2 * m])


def test_colour_input_and_shapes() -> None:
    pano = PanoramaSettings(width=360, height=60, wrap_margin=8)
    unwarper = Unwarper(MirrorSettings(), pano)
    grey = _analytic_raw(MirrorSettings(), pano)
    colour = np.stack([grey, 255 - grey, grey // 2], axis=2)
    out = unwarper.unwarp(colour)
    assert out.shape == (60, 376, 3)
    assert np.array_equal(out[..., 0], unwarper.unwarp(grey))
    with pytest.raises(ValueError, match="uint8"):
        unwarper.unwarp(np.zeros((480, 640, 3, 1), np.uint8))


def test_geometry_checksum_and_floor_distances() -> None:
    mirror, pano = MirrorSettings(), PanoramaSettings()
    base = Unwarper(mirror, pano).geometry_checksum()
    assert base == Unwarper(mirror, pano).geometry_checksum()
    assert base != Unwarper(dataclasses.replace(mirror, focal_px=521.0), pano).geometry_checksum()
    assert base != Unwarper(mirror, dataclasses.replace(pano, height=121)).geometry_checksum()
    u = Unwarper(mirror, pano)
    d = u.floor_distance_of_rows()
    rows = np.arange(pano.height)
    phi = np.asarray(elevation_of_row(rows.astype(float), pano.height,
                                      math.radians(pano.elevation_top_deg),
                                      math.radians(pano.elevation_bottom_deg)))
    below = phi < 0
    # A floor point at distance D is seen at elevation −atan(h / D).
    assert np.allclose(-np.arctan(pano.camera_height_m / d[below]), phi[below])
    assert np.all(np.isinf(d[~below]))
