"""``placecell-eval mapping``: places learned on the robot's own along a tour of every
room (design §6, thesis §7.1).

First pass: the simulated robot (lock-step) drives a ``tour`` of the world; the daemon's
own pieces run on every frame — the Localiser with autonomous acquisition watching the
place learned last, Turn Back and Look (``drive_tbl``) when the background is reached,
the Mapper storing each place with its transition in a real map file. Second pass along
the same tour with the finished map: a frame is *covered* when some place's LRP exceeds
its background by ``--margin`` (0.05). The evaluator picks which places to try at a frame
by the true distance to their reference poses (``--near`` m; a lower bound on coverage),
reads truth from the simulator only, and never hands it to the method.

Metrics: ``places``, ``path_m`` (driven by the autopilot, TBL excluded), ``coverage``,
``min_spacing_m`` (between true reference poses), ``places_per_10m``, ``learn_s_mean``
(robot seconds per Turn Back and Look), ``learn_failures``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from daemon.config import PlacecellConfig, load
from daemon.localisation.localiser import Localiser
from daemon.mapping.place import Place
from daemon.service.learning import DeviceSensors, drive_tbl
from daemon.service.mapper import Link, Mapper
from daemon.store.sqlite_store import MapStore
from hal.registry import HalContext, create_base, create_camera
from hal.sim.factory import build_sim_robot
from hal.sim.robot import SimRobot
from hal.sim.scenario import Scenario, scenario_from_dict
from kernel.errors import LearningError
from kernel.panorama import geometry_checksum
from kernel.types import Frame

RETRY_AFTER_M = 0.5  # a place that could not be learned: try again this far on


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speed", type=float, default=0.4, help="tour speed, m/s")
    p.add_argument("--frame-rate", type=float, default=5.0, help="camera frames per second")
    p.add_argument("--laps", type=int, default=1)
    p.add_argument("--margin", type=float, default=0.05,
                   help="covered: LRP above the place's background by this")
    p.add_argument("--near", type=float, default=5.0,
                   help="places tried at a frame: reference within this many metres")
    p.add_argument("--every-m", type=float, default=0.25,
                   help="second pass: one frame every this far along the tour")
    p.add_argument("--world", help="a world file or generate:<kind>:<seed> (default: from "
                   "--world-kind and --world-seed)")


def _world(args: argparse.Namespace) -> str:
    return args.world or f"generate:{args.world_kind}:{args.world_seed}"


def _scenario(args: argparse.Namespace) -> Scenario:
    return scenario_from_dict({
        "name": "mapping-tour", "world": _world(args), "frame_rate_hz": args.frame_rate,
        "trajectory": {"kind": "tour", "speed": args.speed, "laps": args.laps,
                       "resume_after_s": 1.0}})


def _devices(cfg: PlacecellConfig, scenario: Scenario) -> tuple[Any, Any, SimRobot]:
    ctx = HalContext(cfg)
    robot = ctx.shared("sim.robot", lambda: build_sim_robot(cfg, scenario))
    camera, base = create_camera(cfg.camera, ctx), create_base(cfg.base, ctx)
    camera.open()
    base.open()
    return camera, base, robot


def run(args: argparse.Namespace) -> dict[str, Any]:
    base_cfg = load(None)
    cfg = dataclasses.replace(base_cfg, sim=dataclasses.replace(
        base_cfg.sim, realtime=False, seed=args.seed, scenario=""))
    scenario = _scenario(args)
    with tempfile.TemporaryDirectory() as tmp:
        places, refs, stats = _first_pass(cfg, scenario, Path(tmp) / "map.db")
        coverage, frames = _second_pass(cfg, scenario, places, refs, args)
    spacing = min((math.dist(a[:2], b[:2]) for i, a in enumerate(refs) for b in refs[i + 1:]),
                  default=float("nan"))
    return {
        "world": {"spec": _world(args)},
        "config": {"speed_m_s": args.speed, "frame_rate_hz": args.frame_rate,
                   "laps": args.laps, "margin": args.margin, "near_m": args.near,
                   "acquisition": dataclasses.asdict(cfg.mapping.acquisition) | {
                       "enabled": True}},
        "metrics": {
            "places": len(places), "path_m": round(stats["path_m"], 2),
            "coverage": round(coverage, 4), "coverage_frames": frames,
            "min_spacing_m": round(spacing, 3),
            "places_per_10m": round(10.0 * len(places) / max(stats["path_m"], 1e-9), 3),
            "learn_s_mean": round(float(np.mean(stats["learn_s"])), 2)
            if stats["learn_s"] else None,
            "learn_failures": stats["failures"],
            "wall_s": round(stats["wall_s"], 1),
        },
    }


def _first_pass(cfg: PlacecellConfig, scenario: Scenario, map_path: Path
                ) -> tuple[list[Place], list[tuple[float, float, float]], dict[str, Any]]:
    t_wall = time.perf_counter()
    camera, base, robot = _devices(cfg, scenario)
    acq = dataclasses.replace(cfg.mapping.acquisition, enabled=True)
    localiser = Localiser(cfg.mirror, cfg.panorama, acquisition=acq)
    store = MapStore.open(map_path, geometry_checksum(cfg.mirror, cfg.panorama))
    mapper = Mapper(store, cfg.odometry)

    def odometry(samples: list[Any]) -> None:
        localiser.add_odometry(samples)
        mapper.on_odometry(samples)

    sensors = DeviceSensors(camera, base, cfg.tbl, on_odometry=odometry)
    refs: list[tuple[float, float, float]] = []
    learn_s: list[float] = []
    failures, path_m = 0, 0.0
    retry_at_m: float | None = 0.0  # the first place as soon as possible
    last_pose = robot.true_pose()
    deadline_s = scenario.end_time_s() * 3 + 600.0
    with store:
        while not robot.autopilot_done() and robot.now_ns() / 1e9 < deadline_s:
            frame, _ = sensors.frame()
            pose = robot.true_pose()
            path_m += math.dist(pose[:2], last_pose[:2])
            last_pose = pose
            belief = localiser.process_frame(frame)
            if belief.closed_transition is not None:
                mapper.add_transition(belief.closed_transition)
            for place_id, background in belief.backgrounds:
                mapper.set_background(place_id, background)
            decision = belief.acquisition
            due = retry_at_m is not None and path_m >= retry_at_m
            if decision is None and not due:
                continue
            if decision is not None:
                mapper.set_background(decision.place_id, decision.background_lrp)
                localiser.know_place(mapper.graph.place(decision.place_id))
            link: list[Link | None] = []
            start_ns = frame.stamp_ns
            try:
                tbl = drive_tbl(sensors, base, localiser.unwarper, cfg.tbl,
                                on_start=functools.partial(_begin, mapper, link, localiser))
            except LearningError:
                mapper.cancel_place()
                failures += 1
                retry_at_m = path_m + RETRY_AFTER_M
                continue
            learn_s.append((robot.now_ns() - start_ns) / 1e9)
            ref = _reference_pose(robot)
            stored, added = mapper.add_place(Place(
                tbl.result(), tbl.reference_panorama, created_unix_s=time.time(),
                local_space=localiser.place_profile(tbl.reference_panorama)), link[0])
            refs.append(ref)
            localiser.place_learned(stored, added)  # as the daemon does after a learn job
            for changed in mapper.measure_cross_backgrounds(stored.id):
                localiser.know_place(changed)
            retry_at_m = None
            last_pose = robot.true_pose()
        places = mapper.graph.places
    camera.close()
    base.close()
    return places, refs, {"path_m": path_m, "learn_s": learn_s, "failures": failures,
                          "wall_s": time.perf_counter() - t_wall}


def _begin(mapper: Mapper, link: list[Link | None], localiser: Localiser, start: Any
           ) -> None:
    link.append(mapper.begin_place(start, localiser.reliable_estimate()))


def _reference_pose(robot: SimRobot) -> tuple[float, float, float]:
    """The true pose at a reference frame: TBL drives the cross back to it, so the pose
    when the cross is done is the reference pose (the simulator executes moves exactly)."""
    return robot.true_pose()


def _second_pass(cfg: PlacecellConfig, scenario: Scenario, places: list[Place],
                 refs: list[tuple[float, float, float]], args: argparse.Namespace
                 ) -> tuple[float, int]:
    """Coverage of the tour by the finished map."""
    if not places:
        return 0.0, 0
    robot = build_sim_robot(cfg, scenario)
    localiser = Localiser(cfg.mirror, cfg.panorama, settings=cfg.localisation)
    for place in places:  # with the backgrounds the first pass measured
        localiser.know_place(place)
    rng = np.random.default_rng(args.seed)
    covered = total = 0
    step_ns = int(1e9 / 50)
    last = robot.true_pose()
    run = args.every_m
    while not robot.autopilot_done():
        robot.advance_to(robot.now_ns() + step_ns)
        pose = robot.true_pose()
        run += math.dist(pose[:2], last[:2])
        last = pose
        if run < args.every_m:
            continue
        run = 0.0
        assert robot.renderer is not None
        raw = robot.renderer.donut(pose, noise_sigma=cfg.camera.sim.noise_sigma, rng=rng)
        near = [places[i].id for i, r in enumerate(refs)
                if math.dist(r[:2], pose[:2]) <= args.near]
        scores = localiser.recognise(Frame(raw, robot.now_ns(), total), near)
        best = max((sc.lead for sc in scores), default=-1.0)
        covered += int(best >= args.margin)
        total += 1
    return covered / max(total, 1), total
