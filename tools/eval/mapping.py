"""``placecell-eval mapping``: places learned on the robot's own along a tour of every
room (design §6, thesis §7.1).

First pass: the simulated robot (lock-step) drives a ``tour`` of the world; the daemon's
own pieces run on every frame — the Localiser with autonomous acquisition watching the
place learned last, the daemon's MappingSession deciding when to learn and storing what
each belief and each place changes in a real map file, Turn Back and Look
(``drive_tbl``) when it asks for a place. Second pass along
the same tour with the finished map: a frame is *covered* when some place's LRP exceeds
its background by ``--margin`` (0.05) — the background measured as the robot left the
place, or for a place it never left (the last of the tour) the map's estimate of it
(daemon/mapping/backgrounds.py), as the global search takes it. The evaluator picks
which places to try at a frame by the true distance to their reference poses
(``--near`` m; a lower bound on coverage), reads truth from the simulator only, and never
hands it to the method.

Metrics: ``places``, ``path_m`` (driven by the autopilot, TBL excluded), ``coverage``,
``min_spacing_m`` (between true reference poses), ``places_per_10m``, ``learn_s_mean``
(robot seconds per Turn Back and Look), ``learn_failures``, ``first_pass_done`` (the
first pass drove the whole tour: False only if it ran out of time).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import json
import math
import tempfile
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from daemon.config import PlacecellConfig, load
from daemon.localisation.belief import MapUpdates
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser
from daemon.mapping.place import Place
from daemon.service.learning import DeviceSensors, drive_tbl
from daemon.service.mapper import Link, Mapper
from daemon.service.mapping_session import MappingSession
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
    p.add_argument("--coverage-margin", type=float,
                   help="[mapping.acquisition] coverage_margin (default: the configured)")
    p.add_argument("--map", type=Path, help="keep the first pass's map (and its references) "
                   "here and reuse it when built before with the same world and settings")
    p.add_argument("--trace", type=Path, help="write each frame here (JSON lines). First "
                   "pass (\"pass\": 1): true pose, the watched place, its LRP raw and "
                   "smoothed, the background it is expected to settle at, the decision, the "
                   "belief's state, place and pose. "
                   "Second pass (\"pass\": 2): true pose, covered, best place and lead, "
                   "nearest place's LRP and background")


def world_spec(args: argparse.Namespace) -> str:
    """The world of the experiment: --world, else generated from --world-kind and
    --world-seed."""
    return args.world or f"generate:{args.world_kind}:{args.world_seed}"


def _scenario(args: argparse.Namespace) -> Scenario:
    return scenario_from_dict({
        "name": "mapping-tour", "world": world_spec(args), "frame_rate_hz": args.frame_rate,
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
    if args.coverage_margin is not None:
        cfg = dataclasses.replace(cfg, mapping=dataclasses.replace(
            cfg.mapping, acquisition=dataclasses.replace(
                cfg.mapping.acquisition, coverage_margin=args.coverage_margin)))
    scenario = _scenario(args)
    key = json.dumps({"world": world_spec(args), "speed": args.speed, "laps": args.laps,
                      "frame_rate": args.frame_rate, "seed": args.seed,
                      "acquisition": dataclasses.asdict(cfg.mapping.acquisition)})
    with tempfile.TemporaryDirectory() as tmp, \
            (args.trace.open("w") if args.trace else contextlib.nullcontext()) as trace:
        map_path = args.map or Path(tmp) / "map.db"
        kept = _kept(map_path, key) if args.map else None
        if kept is None:
            for stale in (map_path, *_beside(map_path)):
                stale.unlink(missing_ok=True)
            places, refs, stats = _first_pass(cfg, scenario, map_path, trace)
            if args.map:
                _references(map_path).write_text(json.dumps(
                    {"key": key, "references": refs, "stats": stats}))
        else:
            refs, stats = kept
            with MapStore.open(map_path, geometry_checksum(cfg.projection, cfg.panorama),
                               readonly=True) as store:
                places = store.load().places
        coverage, frames = _second_pass(cfg, scenario, places, refs, args, trace)
    spacing = min((math.dist(a[:2], b[:2]) for i, a in enumerate(refs) for b in refs[i + 1:]),
                  default=float("nan"))
    return {
        "world": {"spec": world_spec(args)},
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
            "first_pass_done": stats["tour_done"],
            "wall_s": round(stats["wall_s"], 1),
        },
    }


def _references(map_path: Path) -> Path:
    return map_path.with_suffix(".references.json")


def _beside(map_path: Path) -> list[Path]:
    return [map_path.with_name(map_path.name + suffix) for suffix in ("-wal", "-shm")] + [
        _references(map_path)]


def _kept(map_path: Path, key: str
          ) -> tuple[list[tuple[float, float, float]], dict[str, Any]] | None:
    """The references and first-pass figures of a map built before with ``key``."""
    path = _references(map_path)
    if not map_path.exists() or not path.exists():
        return None
    data = json.loads(path.read_text())
    if data.get("key") != key:
        return None
    return [tuple(r) for r in data["references"]], data["stats"]


def _first_pass(cfg: PlacecellConfig, scenario: Scenario, map_path: Path,
                trace: IO[str] | None = None
                ) -> tuple[list[Place], list[tuple[float, float, float]], dict[str, Any]]:
    t_wall = time.perf_counter()
    camera, base, robot = _devices(cfg, scenario)
    acq = dataclasses.replace(cfg.mapping.acquisition, enabled=True)
    store = MapStore.open(map_path, geometry_checksum(cfg.projection, cfg.panorama))
    mapper = Mapper(store, cfg.odometry, cfg.mapping.learn_threads)
    session = MappingSession(mapper, acq, cfg.localisation)
    localiser = Localiser(cfg.projection, cfg.panorama, acquisition=acq,
                          known_map=session.holder, mount=cfg.mount)

    def odometry(samples: list[Any]) -> None:
        localiser.add_odometry(samples)
        mapper.on_odometry(samples)

    sensors = DeviceSensors(camera, base, cfg.tbl, cfg.base.read_timeout_s,
                            on_odometry=odometry, mount=cfg.mount)
    refs: list[tuple[float, float, float]] = []
    learn_s: list[float] = []
    failures, path_m = 0, 0.0
    retry_at_m = 0.0  # after a learn failed: not before this far along the tour
    last_pose = robot.true_pose()
    # The tour's own time, with room to spare, plus each Turn Back and Look's and the
    # pause after it: a long tour learns a hundred places (2800 s of learning).
    deadline_s = scenario.end_time_s() * 2 + 600.0
    with store:
        while not robot.autopilot_done() and robot.now_ns() / 1e9 < deadline_s:
            frame, _ = sensors.frame()
            pose = robot.true_pose()
            path_m += math.dist(pose[:2], last_pose[:2])
            last_pose = pose
            belief, updates = localiser.process_frame(frame)
            if trace is not None:
                trace.write(json.dumps(_traced_first(pose, path_m, belief, updates,
                                                     localiser)) + "\n")
            session.observe(belief, updates)  # as the daemon does with every frame
            why = session.wants_place(belief, localiser.odometry.latest, job_running=False)
            if why is None or path_m < retry_at_m:
                if belief.acquisition is not None:  # not now: acquisition asks again
                    localiser.learning_not_started()
                continue
            links: list[Link] = []
            start_ns = frame.stamp_ns
            session.learning_started()
            localiser.learning(True)  # as the daemon does while a learn job runs
            try:
                tbl = drive_tbl(sensors, base, localiser.unwarper, cfg.tbl,
                                on_start=functools.partial(_begin, session, links, localiser),
                                mount=cfg.mount, ahead=session.learn_ahead())
            except LearningError:
                session.cancel_place()
                localiser.learning_not_started()
                failures += 1
                retry_at_m = path_m + RETRY_AFTER_M
                continue
            finally:
                localiser.learning(False)
            learn_s.append((robot.now_ns() - start_ns) / 1e9)
            deadline_s += learn_s[-1] + (scenario.resume_after_s or 0.0)
            ref = _reference_pose(robot)
            learned = session.store_place(Place(
                tbl.result(), tbl.reference_panorama, created_unix_s=time.time(),
                local_space=localiser.place_profile(tbl.reference_panorama)), links, tbl.views,
                seen_at_end=localiser.reliable_estimate())
            refs.append(ref)
            localiser.place_learned(learned.place.id)  # as the daemon does after a learn
            last_pose = robot.true_pose()
        places = mapper.graph.places
        tour_done = robot.autopilot_done()
    camera.close()
    base.close()
    return places, refs, {"path_m": path_m, "learn_s": learn_s, "failures": failures,
                          "tour_done": tour_done, "wall_s": time.perf_counter() - t_wall}


def _traced_first(pose: tuple[float, float, float], path_m: float, belief: Any,
                  updates: MapUpdates, localiser: Localiser) -> dict[str, Any]:
    """One first-pass frame: the true pose, what the acquisition made of it, and where
    the Localiser puts the robot."""
    assert localiser.watch is not None
    acq = localiser.watch.acquisition

    def r(v: float | None) -> float | None:
        return None if v is None else round(v, 4)

    decision = belief.acquisition
    return {"pass": 1, "x": round(pose[0], 3), "y": round(pose[1], 3),
            "path_m": round(path_m, 3), "watched": belief.recent_place,
            "lrp": r(belief.recent_place_lrp), "smoothed": r(acq.smoothed_lrp),
            "expected": r(acq.expected_background), "distance_m": r(acq.distance_m),
            "decision": None if decision is None else {
                "place": decision.place_id, "background": r(decision.background_lrp),
                "lrp": r(decision.lrp)},
            "backgrounds": [[p, r(b)] for p, b in updates.backgrounds],
            "state": belief.state, "place": belief.place_id,
            "pose_in_place": None if belief.pose_in_place is None else [
                round(v, 3) for v in belief.pose_in_place]}


def _begin(session: MappingSession, links: list[Link], localiser: Localiser, start: Any
           ) -> None:
    links.extend(session.begin_place(start, localiser.reliable_estimate()))


def _reference_pose(robot: SimRobot) -> tuple[float, float, float]:
    """The true pose at a reference frame: TBL drives the cross back to it, so the pose
    when the cross is done is the reference pose (the simulator executes moves exactly)."""
    return robot.true_pose()


def _second_pass(cfg: PlacecellConfig, scenario: Scenario, places: list[Place],
                 refs: list[tuple[float, float, float]], args: argparse.Namespace,
                 trace: IO[str] | None = None) -> tuple[float, int]:
    """Coverage of the tour by the finished map."""
    if not places:
        return 0.0, 0
    robot = build_sim_robot(cfg, scenario)
    # The finished map, with the backgrounds the first pass measured.
    localiser = Localiser(cfg.projection, cfg.panorama, settings=cfg.localisation,
                          known_map=MapHolder(KnownMap.of(places)))
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
        scores = localiser.recognise(Frame(raw, robot.now_ns(), total), near, estimated=True)
        best = max((sc.lead for sc in scores), default=-1.0)
        covered += int(best >= args.margin)
        total += 1
        if trace is not None:
            trace.write(json.dumps(_traced(pose, scores, refs, places, args.margin)) + "\n")
    return covered / max(total, 1), total


def _traced(pose: tuple[float, float, float], scores: tuple[Any, ...],
            refs: list[tuple[float, float, float]], places: list[Place], margin: float
            ) -> dict[str, Any]:
    """One second-pass frame: the true pose, the best place's lead, and the nearest
    place (by true distance) with its LRP and background here."""
    best = max(scores, key=lambda sc: sc.lead, default=None)
    out: dict[str, Any] = {"pass": 2, "x": round(pose[0], 3), "y": round(pose[1], 3),
                           "yaw": round(pose[2], 4),
                           "covered": best is not None and best.lead >= margin,
                           "best": None if best is None else best.place_id,
                           "best_lead": None if best is None else round(best.lead, 4)}
    if refs:
        i = min(range(len(refs)), key=lambda k: math.dist(refs[k][:2], pose[:2]))
        near = next((sc for sc in scores if sc.place_id == places[i].id), None)
        out |= {"nearest": places[i].id, "nearest_m": round(math.dist(refs[i][:2], pose[:2]), 3)}
        if near is not None:
            out |= {"nearest_lrp": round(near.lrp, 4),
                    "nearest_background": round(near.lrp - near.lead, 4)}
    return out
