"""``placecell-sim record SCENARIO --out run.mcap``: a scenario simulated into an MCAP file.

The simulation runs in lock-step (as fast as it renders), through the same `sim` camera and
base backends the daemon uses; frames, odometry, base status and ground truth are written.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging

from daemon import config as config_mod
from hal.recording import Recorder
from hal.registry import HalContext, create_base, create_camera
from hal.sim.factory import shared_sim_robot
from hal.sim.scenario import load_scenario
from tools.simcmd import load_config

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario TOML (config/scenarios/)")
    p.add_argument("--out", required=True, help="MCAP file to write")
    p.add_argument("--config", help="daemon configuration for camera/mirror settings "
                                    "(default: config/placecell.toml or built-in)")
    p.add_argument("--jpeg", action="store_true", help="JPEG frames (smaller, lossy); "
                                                       "default PNG (lossless)")
    p.add_argument("--seed", type=int, help="simulator seed (default: the config's)")
    p.add_argument("--duration", type=float, help="seconds to record (default: scenario's)")


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    sim = dataclasses.replace(config.sim, scenario=str(args.scenario), realtime=False,
                              seed=config.sim.seed if args.seed is None else args.seed)
    config = dataclasses.replace(config, sim=sim,
                                 camera=dataclasses.replace(config.camera, backend="sim"),
                                 base=dataclasses.replace(config.base, backend="sim"))
    scenario = load_scenario(args.scenario)
    duration = args.duration if args.duration is not None else scenario.end_time_s()
    metadata = {"source": "placecell-sim record", "scenario": str(args.scenario),
                "scenario_name": scenario.name, "world": scenario.world,
                "duration_s": str(duration), "config": config_mod.to_toml(config)}
    context = HalContext(config)
    camera, base = create_camera(config.camera, context), create_base(config.base, context)
    camera.open()
    base.open()
    robot = shared_sim_robot(context)
    recorder = Recorder(args.out, metadata, image_format="jpeg" if args.jpeg else "png")
    frames = samples = 0
    try:
        while robot.now_ns() < duration * 1e9:
            frame = camera.read(1.0)
            recorder.write_frame(frame)
            recorder.write_ground_truth(*robot.ground_truth())
            for odo in robot.odometry_samples():
                recorder.write_odometry(odo)
                samples += 1
            recorder.write_status(frame.stamp_ns, base.status())
            frames += 1
    finally:
        recorder.close()
        camera.close()
        base.close()
    print(f"wrote {args.out}: {frames} frames, {samples} odometry samples, {duration:.1f} s")
    return 0
