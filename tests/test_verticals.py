"""`placecell-sim verticals` (tools/simcmd/verticals.py, issue 34's done-when 2): the slant
of vertical edges in the unwarped panorama, measured to a tenth of a degree, near zero
for each camera model rendered and unwarped through itself, and degrees when the
model's centre is a few pixels off."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import PlacecellConfig, load
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.camera_models import MODEL_NAMES
from tools.eval.cameras import with_camera_model
from tools.sim_cli import main as sim_main
from tools.simcmd.verticals import panorama_slants, summary, vertical_edge_slants

CONFIG = load(None)
WORLD = load_world("generate:office:1")


def _edge_panorama(slant_deg: float, column: float = 300.0) -> np.ndarray:
    """A 120 x 720 panorama, dark left of a straight edge through (column, row 60) leaning
    ``slant_deg``, bright right of it; drawn 8x finer and area-averaged (anti-aliased)."""
    k = 8
    rows, cols = np.mgrid[0:120 * k, 0:720 * k]
    y, x = (rows + 0.5) / k - 0.5, (cols + 0.5) / k - 0.5
    edge = column + math.tan(math.radians(slant_deg)) * (y - 60.0)
    fine = np.where(x > edge, 200.0, 40.0).astype(np.float32)
    return cv2.resize(fine, (720, 120), interpolation=cv2.INTER_AREA)


@pytest.mark.parametrize("slant", [0.0, 0.4, -2.0, 5.0])
def test_a_drawn_edges_slant_is_measured_to_a_tenth_of_a_degree(slant: float) -> None:
    found = vertical_edge_slants(_edge_panorama(slant), 30)
    assert len(found) >= 1
    for edge in found:
        assert edge.slant_deg == pytest.approx(slant, abs=0.1)
        expected = 300.0 + math.tan(math.radians(slant)) * (edge.row - 60.0)
        assert edge.column == pytest.approx(expected, abs=0.1)


def test_a_panorama_without_vertical_edges_has_none() -> None:
    flat = np.full((120, 720), 90, np.uint8)
    stripes = np.tile(np.repeat([40, 200], 10)[:, None], (6, 720)).astype(np.uint8)
    assert vertical_edge_slants(flat, 30) == []
    assert vertical_edge_slants(stripes, 30) == []  # horizontal edges only


def _off_centre(cfg: PlacecellConfig, px: float) -> PlacecellConfig:
    """The same camera believed ``px`` pixels further right than it is (a dual fisheye's
    lenses: further down, where the error tilts instead of turning the view)."""
    p = cfg.projection
    moved = {f: getattr(p, f) + px for f in ("center_x_px", "center_col_px",
                                             "front_center_y_px", "back_center_y_px")
             if hasattr(p, f)}
    assert moved, f"{type(p).__name__} has no centre"
    section = {"mirror": "mirror", "ocamcalib": "ocamcalib", "fisheye": "fisheye",
               "dual-fisheye": "dual_fisheye"}[cfg.camera.model]
    if section == "mirror":
        return dataclasses.replace(cfg, mirror=dataclasses.replace(cfg.mirror, **moved))
    camera = dataclasses.replace(cfg.camera, **{
        section: dataclasses.replace(getattr(cfg.camera, section), **moved)})
    return dataclasses.replace(cfg, camera=camera)


def _slants(rendered_by: PlacecellConfig, unwarped_by: PlacecellConfig) -> dict[str, float | int]:
    cam = rendered_by.camera.sim
    renderer = Renderer(WORLD, rendered_by.projection, rendered_by.panorama,
                        (cam.image_width, cam.image_height))
    x, y, _ = WORLD.start_pose
    found = []
    for i, pose in enumerate([tuple(WORLD.start_pose), (x + 1.0, y, 0.3)]):
        image = renderer.donut(pose, noise_sigma=2.0, rng=np.random.default_rng(i))
        found += panorama_slants(image, unwarped_by)
    return summary(found)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_each_models_panorama_keeps_vertical_edges_vertical(name: str) -> None:
    """Rendered and unwarped through the same model: the office's door frames and corners
    stand within 0.1° (median) and 0.3° (90 %); a model whose centre is 6 px off slants
    them by degrees — the check can tell a right calibration from a wrong one."""
    cfg = with_camera_model(CONFIG, name)
    right = _slants(cfg, cfg)
    assert int(right["edges"]) >= 10
    assert right["median_abs_slant_deg"] <= 0.1 and right["p90_abs_slant_deg"] <= 0.3
    if name != "equirectangular":  # its frame has no centre to get wrong
        wrong = _slants(cfg, _off_centre(cfg, 6.0))
        assert wrong["median_abs_slant_deg"] >= 5 * max(right["median_abs_slant_deg"], 0.02)


def test_the_command_reports_the_slant_and_refuses_images_without_edges(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cam = CONFIG.camera.sim
    renderer = Renderer(WORLD, CONFIG.projection, CONFIG.panorama,
                        (cam.image_width, cam.image_height))
    donut = tmp_path / "donut.png"
    cv2.imwrite(str(donut), renderer.donut(tuple(WORLD.start_pose)))
    assert sim_main(["verticals", "--config", "config/placecell.toml", "--json",
                     str(donut)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "mirror" and out["edges"] >= 5
    assert out["median_abs_slant_deg"] <= 0.1
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((cam.image_height, cam.image_width, 3), 80, np.uint8))
    assert sim_main(["verticals", "--config", "config/placecell.toml", str(blank)]) == 2
    assert "blank.png: nothing to measure" in capsys.readouterr().err
