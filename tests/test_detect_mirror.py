"""detect-mirror on rendered donuts: with noise, with dark things touching the rim, with
the rim cut by the frame, with a lit ring round the mirror; and what it refuses."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import load
from daemon.vision.detect_mirror import MirrorGeometry, MirrorNotFoundError, detect_mirror
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


def _occlude(img: np.ndarray, cx: float, cy: float, r_out: float, fraction: float,
             seed: int) -> np.ndarray:
    """Dark things (a person) and checkerboards seen in the mirror where it meets the rim,
    ``fraction`` of the rim in 1-3 pieces, each reaching 25-45 % of the way in."""
    rng = np.random.default_rng(seed)
    out = img.copy()
    pieces = int(rng.integers(1, 4))
    start, span = rng.uniform(0, 2 * math.pi), fraction * 2 * math.pi / pieces
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    board = (((xx // 12) + (yy // 12)) % 2 * 230 + 10).astype(np.uint8)
    for k in range(pieces):
        a = np.linspace(start + k * 2 * math.pi / pieces,
                        start + k * 2 * math.pi / pieces + span, 30)
        depth = rng.uniform(0.25, 0.45) * r_out
        rim = [(cx + (r_out - 0.5) * math.cos(t), cy + (r_out - 0.5) * math.sin(t)) for t in a]
        inner = [(cx + (r_out - depth) * math.cos(t), cy + (r_out - depth) * math.sin(t))
                 for t in a[::-1]]
        mask = np.zeros(img.shape[:2], np.uint8)
        cv2.fillPoly(mask, [np.array(rim + inner, np.int32)], 1)
        out[mask == 1] = int(rng.integers(5, 40)) if k % 2 == 0 else board[mask == 1, None]
    return out


def _ring(img: np.ndarray, cx: float, cy: float, r_out: float, gap: float, width: float,
          noise: float, seed: int) -> np.ndarray:
    """A lit ring (the mirror's mount or housing) ``gap`` px outside the rim."""
    out = img.copy()
    cv2.circle(out, (round(cx), round(cy)), round(r_out + gap + width / 2), (220, 220, 220),
               round(width), lineType=cv2.LINE_AA)
    noisy = out + np.random.default_rng(seed).normal(0.0, noise, out.shape)
    return np.clip(noisy, 0, 255).astype(np.uint8)


def _highlight(img: np.ndarray, cx: float, cy: float, r_in: float, seed: int) -> np.ndarray:
    """A bright spot inside the camera's dark reflection (the lens's own reflection, a
    lamp seen in it): 15-35 % of the disc's radius, anywhere within 60 % of it."""
    rng = np.random.default_rng(seed)
    radius = rng.uniform(0.15, 0.35) * r_in
    off, angle = rng.uniform(0.0, 0.6 * r_in - radius), rng.uniform(0.0, 2 * math.pi)
    spot = np.zeros(img.shape[:2], np.float32)
    cv2.circle(spot, (round(cx + off * math.cos(angle)), round(cy + off * math.sin(angle))),
               round(radius), 1.0, -1, lineType=cv2.LINE_AA)
    spot = cv2.GaussianBlur(spot, (0, 0), 1.5)[..., None]
    return (img * (1.0 - spot) + rng.uniform(180.0, 250.0) * spot).astype(np.uint8)


def _shift(img: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """The camera looking off-centre: the donut moved, the frame cutting it."""
    return cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]),
                          (img.shape[1], img.shape[0]), borderValue=(0, 0, 0))


def _assert_found(g: MirrorGeometry, cx: float, cy: float, r_in: float, r_out: float
                  ) -> None:
    assert abs(g.center_x_px - cx) <= 2.0 and abs(g.center_y_px - cy) <= 2.0, g
    assert abs(g.r_outer_px - r_out) <= 3.0, g
    assert g.r_inner_px is not None and abs(g.r_inner_px - r_in) <= 3.0, g


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_dark_things_on_up_to_a_third_of_the_rim(spec: str, cx: float, cy: float,
                                                  r_in: float, r_out: float,
                                                  noise: float) -> None:
    base = _render(spec, cx, cy, r_in, r_out, noise)
    for seed, fraction in ((1, 0.2), (2, 0.33), (3, 0.33)):
        g = detect_mirror(_occlude(base, cx, cy, r_out, fraction, seed))
        _assert_found(g, cx, cy, r_in, r_out)
        assert not g.clipped and not g.ring_outside


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_a_rim_cut_by_the_frame_is_fitted_on_its_visible_arc(
        spec: str, cx: float, cy: float, r_in: float, r_out: float, noise: float) -> None:
    base = _render(spec, cx, cy, r_in, r_out, noise, seed=4, turn=True)
    for dx, dy in ((140, 0), (-60, 70), (0, -90)):
        g = detect_mirror(_shift(base, dx, dy))
        _assert_found(g, cx + dx, cy + dy, r_in, r_out)
        assert g.clipped and g.rim_arc_deg < 340.0, g  # and it says so


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_a_lit_ring_round_the_mirror_is_not_its_rim(spec: str, cx: float, cy: float,
                                                    r_in: float, r_out: float,
                                                    noise: float) -> None:
    base = _render(spec, cx, cy, r_in, r_out, noise, seed=5)
    for seed, (gap, width) in enumerate(((4, 8), (8, 16), (5, 30))):
        g = detect_mirror(_ring(base, cx, cy, r_out, gap, width, noise, seed))
        _assert_found(g, cx, cy, r_in, r_out)
        assert g.ring_outside


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_the_inner_circle_is_the_dark_disc_not_a_highlight_inside_it(
        spec: str, cx: float, cy: float, r_in: float, r_out: float, noise: float) -> None:
    """The inner radius is the edge of the camera's own dark reflection, never a bright
    spot inside it (before this was handled it reported the spot's edge, 30-50 px in)."""
    img = _render(spec, cx, cy, r_in, r_out, noise)
    for seed in range(3):
        _assert_found(detect_mirror(_highlight(img, cx, cy, r_in, seed)), cx, cy, r_in, r_out)


@pytest.mark.parametrize(("dx", "dy"), [(480, 0), (0, 400), (-460, 300)])
def test_refuses_when_too_little_of_the_rim_is_in_the_frame(dx: int, dy: int) -> None:
    spec, cx, cy, r_in, r_out, noise = CASES[0]
    with pytest.raises(MirrorNotFoundError, match="rim is seen on only"):
        detect_mirror(_shift(_render(spec, cx, cy, r_in, r_out, noise), dx, dy))


@pytest.mark.parametrize(("spec", "cx", "cy", "r_in", "r_out", "noise"), CASES)
def test_recovers_centre_and_radii(spec: str, cx: float, cy: float, r_in: float,
                                   r_out: float, noise: float) -> None:
    for seed, turn in ((0, False), (1, True), (2, False), (3, True)):
        g = detect_mirror(_render(spec, cx, cy, r_in, r_out, noise, seed, turn))
        _assert_found(g, cx, cy, r_in, r_out)
        assert not g.clipped and not g.ring_outside and g.rim_arc_deg >= 340.0


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
    assert "rim from" in human.stdout and "inner edge from" in human.stdout


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
