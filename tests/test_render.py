"""The renderer against geometry computed here: walls, floor, ceiling, people, camera effects."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from hal.sim.render import CAMERA_BODY_BGR, Person, Renderer
from hal.sim.world import Wall, World, load_world
from kernel.panorama import bearing_of_column, elevation_of_row
from kernel.sensor_settings import MirrorSettings, PanoramaSettings

HALF_X, HALF_Y = 4.0, 3.0  # a plain green 8 x 6 m room centred on the origin
GREEN = (40, 170, 40)
MIRROR, PANO = MirrorSettings(), PanoramaSettings()


@pytest.fixture(scope="module")
def room() -> Renderer:
    corners = ((HALF_X, -HALF_Y), (HALF_X, HALF_Y), (-HALF_X, HALF_Y), (-HALF_X, -HALF_Y))
    world = World("green-room", (Wall(corners, "plain", GREEN, closed=True),),
                  floor_colour=(60, 80, 110), ceiling_colour=(225, 225, 225))
    return Renderer(world, MIRROR, PANO, (640, 480))


def _expected_rows(pose: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Per column: elevations (rad) where the wall meets the floor and the ceiling."""
    x, y, yaw = pose
    angles = yaw + np.asarray(bearing_of_column(np.arange(PANO.width, dtype=float),
                                                PANO.width))
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (HALF_X - x) / c, (-HALF_X - x) / c)
        ty = np.where(s > 0, (HALF_Y - y) / s, (-HALF_Y - y) / s)
    d = np.minimum(np.abs(tx), np.abs(ty))  # distance to the room's wall along each column
    h = PANO.camera_height_m
    return -np.arctan(h / d), np.arctan((2.5 - h) / d)


def _row_elevations() -> np.ndarray:
    return np.asarray(elevation_of_row(np.arange(PANO.height, dtype=float), PANO.height,
                                       math.radians(PANO.elevation_top_deg),
                                       math.radians(PANO.elevation_bottom_deg)))


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (1.3, -0.8, 0.7), (-2.9, 2.1, -2.4)])
def test_walls_floor_and_ceiling_where_geometry_puts_them(room: Renderer,
                                                          pose: tuple[float, float, float]
                                                          ) -> None:
    floor_edge, ceiling_edge = _expected_rows(pose)
    phi = _row_elevations()[:, None]
    step = math.radians(PANO.elevation_top_deg - PANO.elevation_bottom_deg) / PANO.height
    sure_floor = phi < floor_edge[None, :] - step
    sure_wall = (phi > floor_edge[None, :] + step) & (phi < ceiling_edge[None, :] - step)
    sure_ceiling = phi > ceiling_edge[None, :] + step
    mask = room.floor_mask(pose)
    assert mask[sure_floor].all() and not mask[sure_wall | sure_ceiling].any()
    pano = room.panorama(pose).astype(int)
    b, g, r = pano[..., 0], pano[..., 1], pano[..., 2]
    green = (g > r + 80) & (g > b + 80)
    assert green[sure_wall].all() and not green[sure_floor | sure_ceiling].any()
    bright = (b > 160) & (g > 160) & (r > 160)
    assert sure_ceiling.any() and bright[sure_ceiling].all()


def test_turning_the_robot_shifts_the_panorama_by_whole_columns(room: Renderer) -> None:
    base = room.panorama((0.6, 0.4, 0.3))
    k = 37
    turned = room.panorama((0.6, 0.4, 0.3 + k * 2 * math.pi / PANO.width))
    diff = np.abs(np.roll(base, k, axis=1).astype(int) - turned.astype(int))
    assert float(diff.mean()) < 1.0


def test_gain_scales_brightness(room: Renderer) -> None:
    pose = (0.2, 0.1, 0.0)
    full = room.panorama(pose).astype(float)
    half = room.panorama(pose, gain=0.5).astype(float)
    assert np.abs(half - 0.5 * full).max() <= 1.0


def test_person_subtends_the_right_angles(room: Renderer) -> None:
    d, person = 2.0, Person(2.0, 0.0, radius=0.25, height=1.75)
    clear = room.panorama((0.0, 0.0, 0.0))
    seen = room.panorama((0.0, 0.0, 0.0), people=[person])
    changed = np.abs(clear.astype(int) - seen.astype(int)).sum(axis=2) > 30
    cols = np.nonzero(changed.any(axis=0))[0]
    width_cols = 2 * math.asin(person.radius / d) * PANO.width / (2 * math.pi)
    assert abs(len(cols) - width_cols) <= 2.5 and abs(cols.mean() - (PANO.width - 1) / 2) < 1.5
    rows = np.nonzero(changed[:, PANO.width // 2])[0]
    top = math.atan((person.height - PANO.camera_height_m) / (d - person.radius))
    assert abs(_row_elevations()[rows.min()] - top) < math.radians(1.5)
    # Its feet: the floor in front of it (nearer than 1.75 m) is still seen below them.
    feet = -math.atan(PANO.camera_height_m / (d - person.radius))
    assert abs(_row_elevations()[rows.max()] - feet) < math.radians(1.5)


def test_donut_outside_black_inside_camera_and_noise(room: Renderer) -> None:
    pose = (0.3, -0.2, 1.0)
    clean = room.donut(pose)
    assert clean.shape == (480, 640, 3) and clean.dtype == np.uint8
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    r = np.hypot(u - MIRROR.center_x_px, v - MIRROR.center_y_px)
    assert clean[r > MIRROR.r_outer_px + 2].max() == 0
    assert np.all(clean[r < MIRROR.r_inner_px - 2] == CAMERA_BODY_BGR)
    mirror_area = (r > MIRROR.r_inner_px + 2) & (r < MIRROR.r_outer_px - 2)
    assert clean[mirror_area].std() > 20  # the world is there
    a = room.donut(pose, noise_sigma=5.0, rng=np.random.default_rng(1))
    b = room.donut(pose, noise_sigma=5.0, rng=np.random.default_rng(1))
    c = room.donut(pose, noise_sigma=5.0, rng=np.random.default_rng(2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    unclipped = mirror_area[..., None] & (clean > 20) & (clean < 235)
    noise = a.astype(float) - clean.astype(float)
    assert abs(float(noise[unclipped].std()) - 5.0) < 0.3
    assert abs(float(noise[unclipped].mean())) < 0.1
    with pytest.raises(ValueError, match="rng"):
        room.donut(pose, noise_sigma=1.0)


def test_blur_softens_the_donut() -> None:
    world = load_world("generate:office:2")
    renderer = Renderer(world, MIRROR, PANO, (640, 480))
    sharp = renderer.donut(world.start_pose)
    blurred = renderer.donut(world.start_pose, blur_sigma_px=1.5)

    def detail(img: np.ndarray) -> float:
        return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var())

    assert detail(blurred) < 0.5 * detail(sharp)


def test_hard_floors_mirror_the_walls_and_darken_beside_them() -> None:
    """Glossy tiles show the green walls in the floor near their foot; a shadowed floor is
    darker right beside a wall than in the middle of the room; the mask is the same."""
    corners = ((HALF_X, -HALF_Y), (HALF_X, HALF_Y), (-HALF_X, HALF_Y), (-HALF_X, -HALF_Y))
    walls = (Wall(corners, "plain", GREEN, closed=True),)
    plain = World("plain", walls, floor_texture="tiles")
    glossy = World("glossy", walls, floor_texture="tiles", floor_gloss=0.4)
    shadowed = World("shadowed", walls, floor_shadow=0.6)
    pose = (HALF_X - 1.6, 0.0, 0.0)  # 1.6 m from the wall ahead (column W / 2)
    views = {w.name: Renderer(w, MIRROR, PANO, (640, 480)) for w in (plain, glossy, shadowed,
                                                                 World("fine", walls))}
    mask = views["plain"].floor_mask(pose)
    assert np.array_equal(mask, views["glossy"].floor_mask(pose))
    rows = np.flatnonzero(mask[:, PANO.width // 2])
    foot = rows[:3]  # the floor just short of the wall ahead
    p, g = (views[k].panorama(pose).astype(int)[foot, PANO.width // 2] for k in ("plain", "glossy"))
    assert (g[:, 1] - g[:, 2]).mean() > (p[:, 1] - p[:, 2]).mean() + 20  # greener
    s, f = (views[k].panorama(pose).astype(int)[:, PANO.width // 2].sum(axis=1)
            for k in ("shadowed", "fine"))
    by_wall, farther = s[foot].mean() / f[foot].mean(), s[rows[-3:]].mean() / f[rows[-3:]].mean()
    assert by_wall < 0.7 and farther > by_wall + 0.1, (by_wall, farther)  # 0.2 m out
