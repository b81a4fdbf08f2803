"""Builds the one simulated robot of a configuration (shared by the sim camera and base)."""

from __future__ import annotations

import dataclasses
from typing import Any

from hal.sim.render import Renderer
from hal.sim.robot import SimRobot
from hal.sim.scenario import Scenario, load_scenario
from hal.sim.world import load_world
from kernel.se2 import SE2


def build_sim_robot(config: Any, scenario: Scenario | None = None, *,
                    camera: bool = True) -> SimRobot:
    """A SimRobot from a PlacecellConfig; the scenario (config.sim.scenario, or the one
    given) may override the world, start pose, frame rate, noise and drift. Without
    ``camera`` no renderer is built (a base alone, e.g. for the XR4000 emulator)."""
    sim = config.sim
    if scenario is None and sim.scenario:
        scenario = load_scenario(sim.scenario)
    world = load_world(scenario.world if scenario else sim.world)
    camera_settings = config.camera.sim
    base = config.base.sim
    if scenario is not None:
        if scenario.frame_rate_hz is not None:
            camera_settings = dataclasses.replace(camera_settings,
                                                  rate_hz=scenario.frame_rate_hz)
        if scenario.drift:
            base = dataclasses.replace(base, **scenario.drift)
    start = tuple(sim.start_pose)
    if scenario is not None and scenario.start_pose is not None:
        start = scenario.start_pose
    elif not sim.scenario and tuple(sim.start_pose) == (0.0, 0.0, 0.0):
        start = world.start_pose  # the world's own start when none is configured
    c = config.camera
    mount = SE2(c.mount_x_m, c.mount_y_m, c.mount_yaw_rad).compose(
        SE2(sim.mount_error_x_m, sim.mount_error_y_m, sim.mount_error_yaw_rad))
    renderer = Renderer(world, config.projection, config.panorama,
                        (camera_settings.image_width, camera_settings.image_height)
                        ) if camera else None
    robot = SimRobot(renderer, camera_settings, base, seed=sim.seed, realtime=sim.realtime,
                     start_pose=(float(start[0]), float(start[1]), float(start[2])),
                     scenario=scenario, camera_mount=mount.as_tuple())
    if sim.truth_out:
        robot.write_truth_to(sim.truth_out)
    return robot


def shared_sim_robot(context: Any) -> SimRobot:
    """The context's one simulated robot, built on first use."""
    robot: SimRobot = context.shared("sim.robot", lambda: build_sim_robot(context.config))
    return robot
