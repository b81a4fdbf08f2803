"""Camera models beside the mirror (kernel/camera_models.py, issue 34): each maps
directions to pixels and back, agrees with OpenCV's fisheye model where OpenCV has one,
reads OCamCalib's file, and its simulated image unwarps to the panorama the simulator
draws directly."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import from_dict, load
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.camera_models import (
    MODEL_NAMES,
    EquirectangularModel,
    FisheyeModel,
    camera_model,
    read_ocamcalib,
    write_ocamcalib,
)
from kernel.errors import ConfigError
from kernel.mirror import MirrorModel
from kernel.panorama import core_of, geometry_checksum, to_grey
from kernel.sensor_settings import (
    EquirectangularSettings,
    FisheyeSettings,
)
from tools.eval.cameras import ocamcalib_of_mirror, with_camera_model

CONFIG = load(None)


def directions_seen(model_name: str, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Random bearings and elevations within the panorama band and what the model sees."""
    rng = np.random.default_rng(7)
    p = CONFIG.panorama
    bottom = max(p.elevation_bottom_deg, -15.0) if model_name == "fisheye" else \
        p.elevation_bottom_deg
    return (rng.uniform(-math.pi, math.pi, n),
            np.radians(rng.uniform(bottom, p.elevation_top_deg, n)))


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_each_model_maps_a_direction_to_a_pixel_and_back(name: str) -> None:
    cfg = with_camera_model(CONFIG, name)
    model = camera_model(cfg.projection, cfg.panorama)
    bearing, elevation = directions_seen(name)
    u, v = model.point_of_direction(bearing, elevation)
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(v))
    w, h = cfg.camera.sim.image_width, cfg.camera.sim.image_height
    assert np.all((u > -1) & (u < w) & (v > -1) & (v < h)), "inside the simulated frame"
    back_bearing, back_elevation = model.direction_of_point(u, v)
    bearing_error = np.angle(np.exp(1j * (back_bearing - bearing)))
    assert np.max(np.abs(bearing_error)) < 1e-3
    assert np.max(np.abs(back_elevation - elevation)) < 2e-3


def test_the_fisheye_model_is_opencvs_where_opencv_projects() -> None:
    """Against cv2.fisheye.projectPoints and undistortPoints (incidence below 80°)."""
    k = [[300.0, 0.0, 322.0], [0.0, 298.0, 241.0], [0.0, 0.0, 1.0]]
    d = [0.05, -0.01, 0.004, -0.0008]
    model = FisheyeModel(FisheyeSettings(projection="opencv", camera_matrix=k, distortion=d,
                                         fov_deg=200.0, mirrored=False),
                         CONFIG.panorama)
    rng = np.random.default_rng(3)
    theta = rng.uniform(0.05, math.radians(80), 300)
    alpha = rng.uniform(-math.pi, math.pi, 300)
    # OpenCV's camera frame: x right, y down, z along the optical axis (up here).
    points = np.stack([np.sin(theta) * np.cos(alpha), -np.sin(theta) * np.sin(alpha),
                       np.cos(theta)], axis=1).reshape(-1, 1, 3)
    pixels, _ = cv2.fisheye.projectPoints(points, np.zeros(3), np.zeros(3), np.array(k),
                                          np.array(d))
    u, v = model.point_of_direction(alpha, math.pi / 2 - theta)
    assert np.max(np.hypot(u - pixels[:, 0, 0], v - pixels[:, 0, 1])) < 1e-6
    undistorted = cv2.fisheye.undistortPoints(pixels, np.array(k), np.array(d))[:, 0]
    bearing, elevation = model.direction_of_point(u, v)
    expected = np.arctan(np.hypot(undistorted[:, 0], undistorted[:, 1]))
    assert np.max(np.abs((math.pi / 2 - elevation) - expected)) < 1e-6
    assert np.max(np.abs(np.angle(np.exp(1j * (bearing - alpha))))) < 1e-9


def test_a_fisheye_sees_nothing_beyond_its_field_of_view() -> None:
    model = FisheyeModel(FisheyeSettings(fov_deg=200.0), CONFIG.panorama)
    u, _ = model.point_of_direction(np.array([0.0, 0.0]), np.radians([-9.0, -11.0]))
    assert np.isfinite(u[0]) and np.isnan(u[1])
    _, elevation = model.direction_of_point(np.array([320.0 + 236.0]), np.array([240.0]))
    assert np.isnan(elevation[0]), "outside the image circle"


def test_the_equirectangular_frame_middle_column_and_horizon() -> None:
    s = EquirectangularSettings(width_px=1000, height_px=500, horizon_row_px=260.0,
                                bearing_offset_rad=0.3)
    model = EquirectangularModel(s, CONFIG.panorama)
    bearing, elevation = model.direction_of_point(np.array([499.5, 749.5]),
                                                  np.array([260.0, 135.0]))
    assert bearing[0] == pytest.approx(0.3)  # the middle column: the offset
    assert bearing[1] == pytest.approx(0.3 - math.pi / 2)  # a quarter right: clockwise
    assert elevation[0] == pytest.approx(0.0)
    assert elevation[1] == pytest.approx(math.radians(45.0))


def test_ocamcalib_fitted_to_the_mirror_is_the_mirror() -> None:
    """The default mirror written as OCamCalib would calibrate it lands every direction
    of the band within 0.1 px of where the mirror model puts it."""
    ocam = camera_model(ocamcalib_of_mirror(CONFIG.mirror, CONFIG.panorama), CONFIG.panorama)
    mirror = MirrorModel(CONFIG.mirror, CONFIG.panorama)
    bearing, elevation = directions_seen("mirror")
    u1, v1 = ocam.point_of_direction(bearing, elevation)
    u2, v2 = mirror.point_of_direction(bearing, elevation)
    assert np.max(np.hypot(u1 - u2, v1 - v2)) < 0.1


def test_an_ocamcalib_file_is_read_as_the_toolbox_writes_it(tmp_path: Path) -> None:
    s = dataclasses.replace(ocamcalib_of_mirror(CONFIG.mirror, CONFIG.panorama),
                            affine=[0.9998, 0.0003, -0.0002], center_row_px=238.25)
    path = tmp_path / "calib_results.txt"
    path.write_text(write_ocamcalib(s))
    values = read_ocamcalib(path)
    assert values["affine"] == pytest.approx(s.affine)
    assert values["pol"] == pytest.approx(s.pol, rel=1e-12)
    assert values["center_row_px"] == 238.25
    assert (values["image_height_px"], values["image_width_px"]) == (480, 640)
    cfg = from_dict({"camera": {"model": "ocamcalib", "ocamcalib": {
        "file": str(path), "min_radius_px": 50.0}}})
    assert cfg.projection.invpol == pytest.approx(s.invpol, rel=1e-12)  # type: ignore[union-attr]
    assert cfg.camera.ocamcalib.min_radius_px == 50.0  # what the file does not say stays


@pytest.mark.parametrize(("text", "named"), [
    ("5 1 2 3\n", "data lines"),
    ("3 -100 0 0.002\n4 1 2 3\n240 320\n1 0 0\n480 640\n", "world2cam polynomial"),
    ("3 -100 0 0.002\n2 1 2\n240 x\n1 0 0\n480 640\n", "centre (row column) line"),
    ("3 -100 0 0.002\n2 1 2\n240 320\n1 0\n480 640\n", "affine parameters"),
    ("3 -100 0 0.002\n2 1 2\n240 320\n1 0 0\n480.5 640\n", "image size"),
])
def test_a_broken_ocamcalib_file_is_refused_naming_what_is_wrong(
        tmp_path: Path, text: str, named: str) -> None:
    path = tmp_path / "calib_results.txt"
    path.write_text("#polynomial coefficients\n\n" + text)
    with pytest.raises(ConfigError, match="camera.ocamcalib.file") as e:
        from_dict({"camera": {"ocamcalib": {"file": str(path)}}})
    assert named in str(e.value)


def test_camera_model_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="camera.model"):
        from_dict({"camera": {"model": "pinhole"}})
    with pytest.raises(ConfigError, match="camera_matrix must be 3 x 3"):
        from_dict({"camera": {"fisheye": {"camera_matrix": [[1.0, 0.0], [0.0, 1.0]]}}})
    with pytest.raises(ConfigError, match="singular"):
        from_dict({"camera": {"ocamcalib": {"affine": [1.0, 1.0, 1.0]}}})


def test_the_geometry_checksum_tells_the_models_apart_and_keeps_the_mirrors() -> None:
    """Maps learned before other cameras existed still open: the mirror's digest is the
    one it always was; another model's map is another geometry."""
    mirror_doc = {"mirror": dataclasses.asdict(CONFIG.mirror),
                  "panorama": dataclasses.asdict(CONFIG.panorama)}
    before = hashlib.sha256(json.dumps(mirror_doc, sort_keys=True).encode()).hexdigest()[:16]
    assert geometry_checksum(CONFIG.projection, CONFIG.panorama) == before
    digests = {geometry_checksum(with_camera_model(CONFIG, m).projection, CONFIG.panorama)
               for m in MODEL_NAMES}
    assert len(digests) == len(MODEL_NAMES)
    moved = dataclasses.replace(CONFIG.camera.ocamcalib, file="/elsewhere/calib.txt")
    assert geometry_checksum(moved, CONFIG.panorama) == geometry_checksum(
        CONFIG.camera.ocamcalib, CONFIG.panorama), "where the file was read is not geometry"


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_each_simulated_camera_unwarps_to_the_panorama_the_simulator_draws(name: str) -> None:
    """Rendered through the model and unwarped through it, the office looks as the
    simulator draws it directly (grey NCC over the rows the camera sees)."""
    cfg = with_camera_model(CONFIG, name)
    size = (cfg.camera.sim.image_width, cfg.camera.sim.image_height)
    renderer = Renderer(load_world("generate:office:2"), cfg.projection, cfg.panorama, size)
    pose = (14.2, 9.7, 1.1)
    raw = renderer.donut(pose)
    assert raw.shape == (size[1], size[0], 3)
    unwarped = to_grey(core_of(Unwarper(cfg.projection, cfg.panorama).unwarp(raw),
                               cfg.panorama.wrap_margin)).astype(float)
    direct = to_grey(renderer.panorama(pose)).astype(float)
    seen = unwarped.mean(axis=1) > 1.0
    assert seen.sum() >= (75 if name == "fisheye" else 120)
    a, b = unwarped[seen] - unwarped[seen].mean(), direct[seen] - direct[seen].mean()
    assert float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum())) > 0.97
