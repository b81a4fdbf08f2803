"""placecell-eval experiments of the landmark level, run as a person would."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cv2
import numpy as np

from daemon.config import load
from hal.sim.render import Renderer
from hal.sim.world import load_world
from tests.daemon_harness import REPO, venv_bin


def test_recognise_on_camera_images(tmp_path: Path) -> None:
    """Images made by rendering stand in for photographs of a real mirror camera."""
    c = load(None)
    renderer = Renderer(load_world("generate:office:1"), c.projection, c.panorama, (640, 480))
    rng = np.random.default_rng(0)
    poses = {"a": (3.0, 10.0, 0.0), "b": (3.0, 10.0, 0.0), "same": (3.0, 10.0, 0.0),
             "near": (3.2, 10.1, 0.1), "elsewhere": (15.0, 4.0, 1.0)}
    for name, pose in poses.items():
        cv2.imwrite(str(tmp_path / f"{name}.png"),
                    renderer.donut(pose, noise_sigma=2.0, rng=rng))
    out = subprocess.run(
        [venv_bin("placecell-eval"), "recognise", "--reference", str(tmp_path / "a.png"),
         str(tmp_path / "b.png"), "--images", str(tmp_path / "same.png"),
         str(tmp_path / "near.png"), str(tmp_path / "elsewhere.png"), "--json",
         "--plots", str(tmp_path / "plots")],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    same, near, elsewhere = result["metrics"]["lrp"]
    assert same > 0.9 and same > near > elsewhere
    mirror = result["metrics"]["mirror"]
    assert abs(mirror["center_x_px"] - 320) <= 2 and abs(mirror["r_outer_px"] - 228) <= 3
    assert len(list((tmp_path / "plots").glob("*.png"))) == 4
    bad = subprocess.run(
        [venv_bin("placecell-eval"), "recognise", "--reference", str(tmp_path / "a.png"),
         str(tmp_path / "b.png"), "--images", str(tmp_path / "same.png"), "--mirror", "1,2"],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--mirror" in bad.stderr


def test_depth_experiment_prints_its_metrics_and_draws(tmp_path: Path) -> None:
    out = subprocess.run([venv_bin("placecell-eval"), "depth", "--artificial", "--places", "1",
                          "--json", "--plots", str(tmp_path / "figures")], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["experiment"] == "depth"
    metrics = result["metrics"]
    assert set(metrics) >= {"median_error_m", "max_error_m", "coverage_2sigma"}
    assert metrics["landmarks"] == 16 and metrics["median_error_m"] < 0.10
    # Covariances neither absurdly wider nor narrower than the errors (an honest Gaussian:
    # 1.39; one place at the corridor's end is no calibration: `placecell-eval depth` runs ten).
    assert 0.05 < metrics["median_mahalanobis_sq"] < 8.0
    figure = cv2.imread(str(tmp_path / "figures" / "depth.png"))
    assert figure is not None and figure.shape == (560, 560, 3)
    assert (figure < 200).any(axis=2).mean() > 0.01  # points, bars and axes were drawn


def test_depth_of_hand_identified_markers(tmp_path: Path) -> None:
    """The thesis's protocol (§4.6.4): the markers within 1 m, pointed at by hand."""
    command = [venv_bin("placecell-eval"), "depth", "--artificial", "--hand-markers",
               "--places", "1", "--json"]
    out = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    metrics = json.loads(out.stdout)["metrics"]
    assert 4 <= metrics["landmarks"] == metrics["landmarks_within_1m"] <= 8
    assert metrics["median_error_m"] < 0.05
    wrong = subprocess.run(command[:2] + command[3:], cwd=REPO, capture_output=True,
                           text=True, timeout=60)
    assert wrong.returncode == 2 and "--hand-markers needs --artificial" in wrong.stderr


def test_recognition_range_compares_selections_and_explains(tmp_path: Path) -> None:
    out = subprocess.run([venv_bin("placecell-eval"), "recognition-range", "--places", "1",
                          "--json", "--plots", str(tmp_path / "figures")], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    metrics = json.loads(out.stdout)["metrics"]
    # Both sets are recognised around their own reference, not everywhere on the grid.
    grid_area = (2 * 2.0) ** 2
    for name in ("tbl", "static"):
        assert 0.5 < metrics[f"{name}_area_m2"] < grid_area
    assert metrics["oracle_area_m2"] >= 0.5
    assert 0.0 <= metrics["static_light_area_m2"] < grid_area
    correlation = metrics["candidate_usefulness_correlation"]
    assert set(correlation) == {"tbl_score", "valley_r"}
    assert all(-1.0 <= c <= 1.0 for c in correlation.values())
    assert correlation["valley_r"] > 0.2  # distinct templates do stand out from the room
    assert sorted(p.name for p in (tmp_path / "figures").glob("*.png")) == [
        "range-00-static.png", "range-00-tbl.png"]


def test_plots_refused_where_an_experiment_draws_none() -> None:
    out = subprocess.run([venv_bin("placecell-eval"), "robustness", "--plots", "x"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "draws no figures" in out.stderr
