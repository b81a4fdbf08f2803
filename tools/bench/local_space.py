"""Local space (design §4): ``local_space_ms`` (one frame into the floor grid — colour
model, gradient boundary, fusion — and its profile), ``profile_match_1000_ms`` (one
profile matched against a thousand places' under all 16 rotations).

The frame: the office (seed 1) with the patterned carpet (hal/sim/worldgen.py FLOORS),
rendered at its start pose through the mirror and unwarped as the daemon does; the
floor learned from it first (``LocalSpace.learn_floor``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from daemon.config import load
from daemon.vision.local_space import CAP_M, LocalSpace, match_many
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.panorama import core_of
from tools.bench.timing import median_seconds

WORLD = "generate:office:1:carpet"


def run(repeats: int) -> dict[str, Any]:
    config = load(None)
    world = load_world(WORLD)
    cam = config.camera.sim
    renderer = Renderer(world, config.projection, config.panorama,
                        (cam.image_width, cam.image_height))
    unwarper = Unwarper(config.projection, config.panorama)
    raw = renderer.donut(world.start_pose, noise_sigma=cam.noise_sigma,
                         rng=np.random.default_rng(1))
    core = core_of(unwarper.unwarp(raw), config.panorama.wrap_margin)
    local = LocalSpace((config.panorama.height, config.panorama.width),
                       int(math.floor(unwarper.horizon_row())),
                       unwarper.floor_distance_of_rows())
    local.learn_floor(core)

    def frame() -> None:
        local.update(core)
        local.profile()

    here = local.profile()
    others = np.random.default_rng(2).uniform(0.0, CAP_M, (1000, here.shape[0]))
    return {
        "local_space_ms": round(median_seconds(frame, repeats, inner=10) * 1e3, 3),
        "profile_match_1000_ms": round(median_seconds(
            lambda: match_many(here, others, CAP_M), repeats, inner=10) * 1e3, 3),
    }
