"""Simulator and unwarping speed: ``render_fps`` and ``unwarp_ms`` (issue: simulator).

render_fps: raw mirror-camera frames per second (the 720 x 120-column view ray-cast and
warped into the 640 x 480 donut, with noise) at poses along a path in a generated office.
unwarp_ms: the daemon's LUT unwarp of one such frame into the 720 x 120 panorama.
"""

from __future__ import annotations

import itertools

import numpy as np

from daemon.config import load
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import load_world
from tools.bench.timing import median_seconds


def run(repeats: int) -> dict[str, float]:
    config = load(None)
    world = load_world("generate:office:1")
    renderer = Renderer(world, config.projection, config.panorama, (640, 480))
    poses = itertools.cycle([(3.0 + 0.5 * i, 10.0, 0.1 * i) for i in range(20)])
    rng = np.random.default_rng(0)

    def render() -> None:
        renderer.donut(next(poses), noise_sigma=2.0, rng=rng)

    render_s = median_seconds(render, repeats, inner=10)
    unwarper = Unwarper(config.projection, config.panorama)
    raw = renderer.donut((3.0, 10.0, 0.0), noise_sigma=2.0, rng=rng)
    unwarp_s = median_seconds(lambda: unwarper.unwarp(raw), repeats, inner=50)
    return {"render_fps": round(1.0 / render_s, 1), "unwarp_ms": round(unwarp_s * 1e3, 3)}
