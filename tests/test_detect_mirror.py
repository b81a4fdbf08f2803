"""detect-mirror on rendered donuts with noise (issue 3, point 2)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import load
from daemon.vision.detect_mirror import MirrorNotFoundError, detect_mirror
from hal.sim.render import Renderer
from hal.sim.world import load_world
from tests.daemon_harness import REPO, venv_bin

CASES = [  # world, centre x, centre y, r_inner, r_outer, noise sigma
    ("generate:office:1", 320.0, 240.0, 50.0, 228.0, 4.0),
    ("generate:open-room:2", 300.5, 250.2, 45.0, 210.0, 6.0),
    ("generate:corridor:3", 333.0, 228.0, 60.0, 200.0, 4.0),
    ("generate:aliased-corridor:4", 310.0, 235.0, 40.0, 215.0, 8.0),
    ("generate:office:7", 318.3, 244.6, 55.0, 225.0, 4.0),
]


def _render(spec: str, cx: float, cy: float, r_in: float, r_out: float, noise: float,
            seed: int = 0, turn: bool = False) -> np.ndarray:
    c = load(None)
    mirror = dataclasses.replace(c.mirror, center_x_px=cx, center_y_px=cy, r_inner_px=r_in,
                                 r_outer_px=r_out)
    world = load_world(spec)
    renderer = Renderer(world, mirror, c.panorama, (640, 480))
    x, y, yaw = world.start_pose
    pose = (x + 0.7, y - 0.3, yaw + 1.0) if turn else (x, y, yaw)
    return renderer.donut(pose, noise_sigma=noise, rng=np.random.default_rng(seed))


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_recovers_centre_and_radii(spec: str, cx: float, cy: float, r_in: float,
                                   r_out: float, noise: float) -> None:
    for seed, turn in ((0, False), (1, True), (2, False), (3, True)):
        g = detect_mirror(_render(spec, cx, cy, r_in, r_out, noise, seed, turn))
        assert abs(g.center_x_px - cx) <= 2.0 and abs(g.center_y_px - cy) <= 2.0
        assert abs(g.r_outer_px - r_out) <= 3.0
        assert abs(g.r_inner_px - r_in) <= 3.0


def test_cli_prints_a_mirror_section(tmp_path: Path) -> None:
    path = tmp_path / "donut.png"
    cv2.imwrite(str(path), _render(*CASES[0]))
    out = subprocess.run([venv_bin("placecell-sim"), "detect-mirror", str(path), "--json"],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    g = json.loads(out.stdout)
    assert abs(g["center_x_px"] - 320.0) <= 2 and abs(g["r_outer_px"] - 228.0) <= 3
    human = subprocess.run([venv_bin("placecell-sim"), "detect-mirror", str(path)],
                           cwd=REPO, capture_output=True, text=True, timeout=60)
    assert "[mirror]" in human.stdout and "r_inner_px" in human.stdout


def test_refuses_images_without_a_mirror(tmp_path: Path) -> None:
    with pytest.raises(MirrorNotFoundError):
        detect_mirror(np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(MirrorNotFoundError):
        detect_mirror(np.zeros((10, 10), np.uint8))
    bad = tmp_path / "not-an-image.png"
    bad.write_text("hello")
    out = subprocess.run([venv_bin("placecell-sim"), "detect-mirror", str(bad)], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "cannot read" in out.stderr
