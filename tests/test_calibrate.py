"""``placecell-sim calibrate`` (issue 34): each camera model's configuration from rendered
images of it, how sure it is, and what it refuses rather than guess."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import load
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.camera_models import write_ocamcalib
from tools.eval.cameras import with_camera_model
from tools.sim_cli import main as sim_main

CONFIG = load(None)


def _images(model: str, tmp_path: Path, count: int = 2) -> list[str]:
    """Views of office 3 from the model's simulated camera, noisy, from a few poses."""
    cfg = with_camera_model(CONFIG, model)
    world = load_world("generate:office:3")
    renderer = Renderer(world, cfg.projection, cfg.panorama,
                        (cfg.camera.sim.image_width, cfg.camera.sim.image_height))
    x, y, yaw = world.start_pose
    paths = []
    for k in range(count):
        path = tmp_path / f"{model}-{k}.png"
        cv2.imwrite(str(path), renderer.donut((x + 0.8 * k, y + 0.3 * k, yaw + k),
                                              noise_sigma=3.0, rng=np.random.default_rng(k)))
        paths.append(str(path))
    return paths


def _calibrate(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code = sim_main(["calibrate", "--json", *args])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else {}), err


def test_a_fisheye_image_circle_and_the_given_field_of_view(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = _images("fisheye", tmp_path)
    code, _, err = _calibrate(capsys, "--model", "fisheye", *images)
    assert code == 2 and "--fov-deg" in err  # a photo does not show the angle: asked
    code, out, _ = _calibrate(capsys, "--model", "fisheye", "--fov-deg", "220", *images)
    assert code == 0 and out["section"] == "camera.fisheye"
    truth = CONFIG.camera.fisheye
    v = out["values"]
    assert abs(v["center_x_px"] - truth.center_x_px) <= 1.0
    assert abs(v["center_y_px"] - truth.center_y_px) <= 1.0
    assert abs(v["radius_px"] - truth.radius_px) <= 2.0 and v["fov_deg"] == 220.0
    assert "spread between images" in out["notes"][0]  # how sure it is


def test_a_dual_fisheye_frame_gives_both_circles(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _calibrate(capsys, "--model", "dual-fisheye", "--fov-deg", "195",
                              *_images("dual-fisheye", tmp_path))
    assert code == 0
    truth, v = CONFIG.camera.dual_fisheye, out["values"]
    for key in ("front_center_x_px", "front_center_y_px", "back_center_x_px",
                "back_center_y_px"):
        assert abs(v[key] - getattr(truth, key)) <= 1.0, key
    assert abs(v["radius_px"] - truth.radius_px) <= 2.0


def test_an_equirectangular_frame_is_2_to_1_or_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = _images("equirectangular", tmp_path, count=1)
    code, out, _ = _calibrate(capsys, "--model", "equirectangular", *images)
    assert code == 0 and out["values"] == {"width_px": 1280, "height_px": 640,
                                           "horizon_row_px": 319.5}
    cropped = tmp_path / "cropped.png"
    cv2.imwrite(str(cropped), cv2.imread(images[0])[100:540])
    code, _, err = _calibrate(capsys, "--model", "equirectangular", str(cropped))
    assert code == 2 and "not 2:1" in err


def test_an_ocamcalib_file_is_checked_against_the_images(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = _images("ocamcalib", tmp_path)
    calibration = with_camera_model(CONFIG, "ocamcalib").camera.ocamcalib
    good = tmp_path / "calib_results.txt"
    good.write_text(write_ocamcalib(calibration))
    code, out, _ = _calibrate(capsys, "--model", "ocamcalib", "--ocamcalib", str(good), *images)
    assert code == 0
    assert abs(out["values"]["min_radius_px"] - calibration.min_radius_px) <= 2.0
    assert abs(out["values"]["max_radius_px"] - calibration.max_radius_px) <= 2.0
    moved = tmp_path / "moved.txt"
    moved.write_text(write_ocamcalib(dataclasses.replace(
        calibration, center_col_px=calibration.center_col_px + 20.0)))
    code, _, err = _calibrate(capsys, "--model", "ocamcalib", "--ocamcalib", str(moved),
                              *images)
    assert code == 2 and "from the image circle's centre" in err
    other_size = tmp_path / "other_size.txt"
    other_size.write_text(write_ocamcalib(dataclasses.replace(calibration,
                                                              image_width_px=800)))
    code, _, err = _calibrate(capsys, "--model", "ocamcalib", "--ocamcalib",
                              str(other_size), *images)
    assert code == 2 and "calibrated at 800 x 480" in err


def test_images_of_a_camera_that_moved_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = _images("fisheye", tmp_path)
    shifted = tmp_path / "shifted.png"
    img = cv2.imread(images[1])
    cv2.imwrite(str(shifted), cv2.warpAffine(img, np.float32([[1, 0, 6], [0, 1, 0]]),
                                             (img.shape[1], img.shape[0])))
    code, _, err = _calibrate(capsys, "--model", "fisheye", "--fov-deg", "220", images[0],
                              str(shifted))
    assert code == 2 and "disagree" in err
