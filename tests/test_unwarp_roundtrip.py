"""The daemon's unwarping against directly rendered panoramas (issue 3, point 1)."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from daemon.config import load
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import Decoration, Wall, World, load_world
from kernel.mirror import MirrorModel, hyperboloid_radius
from kernel.panorama import (
    add_wrap_margin,
    bearing_of_column,
    column_of_bearing,
    core_of,
)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * math.log10(255.0**2 / mse)


def column_shift(a: np.ndarray, b: np.ndarray) -> float:
    """Sub-column horizontal shift between two panoramas (phase correlation)."""
    ga = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY).astype(np.float64)
    gb = cv2.cvtColor(b, cv2.COLOR_BGR2GRAY).astype(np.float64)
    (dx, _), _ = cv2.phaseCorrelate(ga, gb)
    return float(dx)


@pytest.mark.parametrize(("spec", "pose"), [
    ("generate:office:1", (3.0, 10.0, 0.0)),
    ("generate:office:2", (14.2, 9.7, 1.1)),
    ("generate:open-room:3", (3.5, 5.0, -2.0)),
    ("generate:corridor:4", (8.0, 1.2, 0.4)),
])
def test_round_trip_psnr_and_bearing(spec: str, pose: tuple[float, float, float]) -> None:
    c = load(None)
    renderer = Renderer(load_world(spec), c.projection, c.panorama, (640, 480))
    direct = renderer.panorama(pose)
    unwarped = core_of(Unwarper(c.projection, c.panorama).unwarp(renderer.donut(pose)),
                       c.panorama.wrap_margin)
    assert unwarped.shape == direct.shape == (120, 720, 3)
    assert psnr(direct, unwarped) >= 28.0
    assert abs(column_shift(direct, unwarped)) <= 0.5


def test_polynomial_model_round_trip() -> None:
    c = load(None)
    mirror = dataclasses.replace(c.mirror, model="polynomial", poly_coeffs=[0.0, 0.8, 0.2])
    renderer = Renderer(load_world("generate:office:5"), mirror, c.panorama, (640, 480))
    pose = (9.0, 10.0, 0.3)
    direct = renderer.panorama(pose)
    unwarped = core_of(Unwarper(mirror, c.panorama).unwarp(renderer.donut(pose)),
                       c.panorama.wrap_margin)
    assert psnr(direct, unwarped) >= 28.0
    assert abs(column_shift(direct, unwarped)) <= 0.5


def _marker_room() -> World:
    """A 6 m square room around the origin, one poster straight ahead (+x) and one on the
    left (+y), nothing else that is red."""
    def wall(a: tuple[float, float], b: tuple[float, float], deco: tuple = ()) -> Wall:
        return Wall((a, b), "plain", (200, 200, 200), decorations=deco)
    poster = (Decoration("marker", 2.7, 0.6, 1.2, 0.6, 5),)
    return World("markers", (wall((3.0, -3.0), (3.0, 3.0), poster),
                             wall((3.0, 3.0), (-3.0, 3.0), poster),
                             wall((-3.0, 3.0), (-3.0, -3.0)), wall((-3.0, -3.0), (3.0, -3.0))))


def test_panorama_columns_look_along_their_bearings() -> None:
    """A marker ahead shows at bearing 0 (column W/2), one on the left at +90° (W/4)."""
    c = load(None)
    renderer = Renderer(_marker_room(), c.projection, c.panorama, (640, 480))
    pano = core_of(Unwarper(c.projection, c.panorama).unwarp(renderer.donut((0.0, 0.0, 0.0))),
                   c.panorama.wrap_margin)
    grey = cv2.cvtColor(pano, cv2.COLOR_BGR2GRAY).astype(float)
    dark = (grey < 60).sum(axis=0)  # marker cells are black on a light wall
    cols = np.nonzero(dark > 3)[0]
    W = c.panorama.width
    ahead = cols[np.abs(cols - W / 2) < 40]
    left = cols[np.abs(cols - W / 4) < 40]
    assert len(ahead) and len(left)
    assert abs(float(bearing_of_column(ahead.mean(), W))) < math.radians(2.0)
    assert abs(float(bearing_of_column(left.mean(), W)) - math.pi / 2) < math.radians(2.0)


def test_conventions_are_inverse() -> None:
    W = 720
    cols = np.arange(W, dtype=float)
    assert np.allclose(column_of_bearing(bearing_of_column(cols, W), W), cols)
    core = np.arange(2 * 10 * 3).reshape(2, 10, 3)
    wrapped = add_wrap_margin(core, 2)
    assert np.array_equal(wrapped[:, :2], core[:, -2:])
    assert np.array_equal(wrapped[:, -2:], core[:, :2])
    assert np.array_equal(core_of(wrapped, 2), core)


def test_hyperboloid_radius_grows_with_elevation() -> None:
    c = load(None)
    phi = np.radians(np.linspace(-60, 30, 50))
    r = hyperboloid_radius(phi, c.mirror.a_m, c.mirror.b_m, c.mirror.focal_px)
    assert np.all(np.diff(r) > 0)
    r_bottom, r_top = MirrorModel(c.projection, c.panorama).row_radius_range()
    assert c.mirror.r_inner_px <= r_bottom < r_top <= c.mirror.r_outer_px


def test_unwarp_rejects_bad_images_and_knows_floor_distances() -> None:
    c = load(None)
    u = Unwarper(c.projection, c.panorama)
    with pytest.raises(ValueError, match="uint8"):
        u.unwarp(np.zeros((480, 640), np.float32))
    d = u.floor_distance_of_rows()
    assert np.isinf(d[0]) and np.all(np.diff(d[np.isfinite(d)]) < 0)
    assert 1.3 < d[-1] < 1.5  # the bottom row sees the floor about 1.4 m away
    assert 40 < u.horizon_row() < 45
