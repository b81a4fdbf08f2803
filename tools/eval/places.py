"""Learning places on the simulated robot for evaluations: the daemon's own learn_place
through the HAL sim backends in lock-step; the evaluator keeps the renderer for test views
and the true reference pose (never handed to the method)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from daemon.config import PlacecellConfig, load
from daemon.mapping.tbl import CandidateChooser
from daemon.service.learning import run_tbl
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.unwarp import Unwarper
from hal.registry import HalContext, create_base, create_camera
from hal.sim.factory import shared_sim_robot
from hal.sim.render import Person, Renderer


@dataclass
class LearnedPlace:
    pose: tuple[float, float, float]  # true reference pose (evaluator only)
    tbl: LandmarkSet  # Turn Back and Look: 16 landmarks with depths
    static: LandmarkSet  # the 16 best of static selection alone, same reference frames
    renderer: Renderer
    candidates: LandmarkSet  # all TBL candidates, with their TBL scores and depths
    candidate_valley: np.ndarray  # their valley measure r from static selection, same order
    candidate_light_ncc: np.ndarray  # their self-match under TBL's light test, same order


def learn(world: str, pose: tuple[float, float, float], seed: int,
          config: PlacecellConfig | None = None,
          choose: CandidateChooser | None = None) -> LearnedPlace:
    base_config = config or load(None)
    cfg = dataclasses.replace(base_config, sim=dataclasses.replace(
        base_config.sim, world=world, start_pose=list(pose), realtime=False, seed=seed,
        scenario=""))
    ctx = HalContext(cfg)
    camera, base = create_camera(cfg.camera, ctx), create_base(cfg.base, ctx)
    camera.open()
    base.open()
    robot = shared_sim_robot(ctx)
    reference = robot.true_pose()
    unwarper = Unwarper(cfg.projection, cfg.panorama)
    tbl = run_tbl(camera, base, unwarper, cfg.tbl, choose=choose, mount=cfg.mount)
    assert robot.renderer is not None
    # Static-only: the 16 best by valley measure of the very candidates TBL started from
    # (same reference frames), so the two sets differ by the dynamic phase alone, not by
    # the noise in two other frames.
    static = tbl.candidates.best(16)
    return LearnedPlace(reference, tbl.result(), static, robot.renderer, tbl.scored(),
                        np.array([lm.score for lm in tbl.candidates.landmarks]),
                        tbl.light_ncc)


def view(place: LearnedPlace, unwarper: Unwarper, pose: tuple[float, float, float],
         rng: np.random.Generator, *, gain: float = 1.0,
         people: tuple[Person, ...] = ()) -> np.ndarray:
    """The panorama the robot would unwarp at ``pose`` (noise sigma 2)."""
    raw = place.renderer.donut(pose, people=people, gain=gain, noise_sigma=2.0, rng=rng)
    return unwarper.unwarp(raw)
