"""A map of places learned along a tour of a world, for the global localisation
experiments (design §9, §10; thesis §9.2: a path through a 50-place map).

The simulated robot (lock-step) follows the world's tour (hal/sim/tour.py) keeping its
heading, and learns a place with the daemon's Turn Back and Look loop every
``spacing_m`` along it (:meth:`~tools.eval.lockstep.Run.learn`: the Mapper stores each
place with its transition in a real map file). The evaluator steers by the simulator's
truth (as a scenario's autopilot does) and keeps each place's true reference pose; the
method sees neither. With ``map_path`` the map and its references (a JSON file beside it)
are kept and reused by later runs with the same world and settings.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
from collections.abc import Iterator
from pathlib import Path

from daemon.config import load
from daemon.localisation.belief import Belief
from hal.sim.tour import plan_tour
from hal.sim.world import World, load_world
from kernel.se2 import SE2
from tools.eval.lockstep import (
    Run,
    add_localisation_arguments,
    localisation_settings,
    lockstep_config,
    open_run,
)

Point = tuple[float, float]


def along(points: list[Point], spacing_m: float) -> list[Point]:
    """Points every ``spacing_m`` along the polyline ``points`` (its first included)."""
    out = [points[0]]
    carried = 0.0
    for (x0, y0), (x1, y1) in zip(points, points[1:], strict=False):
        seg = math.dist((x0, y0), (x1, y1))
        d = spacing_m - carried
        while d <= seg + 1e-9:
            t = d / seg
            out.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0)))
            d += spacing_m
        carried = seg - (d - spacing_m)
    return out


def drive_to(run: Run, target: Point, speed: float, heading: float | None = None
             ) -> Iterator[Belief]:
    """Drive straight to ``target`` (world x, y), every frame processed; the heading kept,
    or turned to ``heading`` (world yaw) on the way: the evaluator steers by the truth, so
    a base that closes its moves on drifting odometry (the ros2 one) keeps the tour's
    heading as the exact simulated base does."""
    x, y, yaw = run.robot.true_pose()
    dx, dy = target[0] - x, target[1] - y
    if math.hypot(dx, dy) < 1e-3:
        return
    c, s = math.cos(yaw), math.sin(yaw)
    dyaw = 0.0 if heading is None else math.remainder(heading - yaw, math.tau)
    yield from run.drive(c * dx + s * dy, -s * dx + c * dy, dyaw, speed)


def tour_points(world: World, spacing_m: float) -> list[Point]:
    return along(plan_tour(world), spacing_m)


def learn_along(run: Run, stops: list[Point], places: int, speed: float) -> dict[int, SE2]:
    """Learn a place at each of ``stops`` in turn — but not within 0.75 x the spacing of
    a place learned already (a tour comes back along corridors) — up to ``places``: the
    true reference pose of each (by place id). The robot keeps the start's heading."""
    heading = run.robot.true_pose()[2]
    spacing = min((math.dist(a, b) for a, b in zip(stops, stops[1:], strict=False)),
                  default=1.0)
    for stop in stops:
        if len(run.references) >= places:
            break
        if any(math.dist(stop, (r.x, r.y)) < 0.75 * spacing for r in run.references.values()):
            continue
        for _ in drive_to(run, stop, speed, heading):
            pass
        run.learn(f"p{len(run.references) + 1}")
    return dict(run.references)


def save_references(map_path: Path, references: dict[int, SE2], key: str) -> None:
    path = map_path.with_suffix(".references.json")
    path.write_text(json.dumps({"key": key, "references": {
        str(k): list(v.as_tuple()) for k, v in references.items()}}))


def load_references(map_path: Path, key: str) -> dict[int, SE2] | None:
    """The references of a map built before with the same ``key``, if any."""
    path = map_path.with_suffix(".references.json")
    if not map_path.exists() or not path.exists():
        return None
    data = json.loads(path.read_text())
    if data.get("key") != key:
        return None
    return {int(k): SE2(*v) for k, v in data["references"].items()}


def right_place(references: dict[int, SE2], place_id: int | None, truth: Point,
                slack_m: float = 0.5) -> bool:
    """The place whose reference is nearest the true position, or one no more than
    ``slack_m`` farther than it (design §9)."""
    if place_id is None or place_id not in references:
        return False
    dist = {p: math.dist((r.x, r.y), truth) for p, r in references.items()}
    return dist[place_id] <= min(dist.values()) + slack_m


def add_map_arguments(p: argparse.ArgumentParser, places: int) -> None:
    p.add_argument("--places", type=int, default=places, help="places learned along the tour")
    p.add_argument("--spacing", type=float, default=1.0, help="metres between places")
    p.add_argument("--speed", type=float, default=0.3, help="m/s along the tour")
    p.add_argument("--map", type=Path, help="keep the map (and its references) here and "
                   "reuse it when built before with the same world and settings")
    p.add_argument("--floor", help="give the world one of the hard floors of "
                   "hal/sim/worldgen.py FLOORS (default: its own, nearly flat)")
    add_localisation_arguments(p)


@contextlib.contextmanager
def mapped_run(args: argparse.Namespace) -> Iterator[tuple[Run, list[Point]]]:
    """A lock-step run whose map holds the places learned along the tour (built, or
    reused from ``--map``), with a new Localiser on it as the daemon starts one: no pose.
    Yields the run and the tour's points every 0.1 m."""
    base = load(None)
    world_spec = f"generate:{args.world_kind}:{args.world_seed}"
    if getattr(args, "floor", None):
        world_spec += f":{args.floor}"
    world = load_world(world_spec)
    settings = localisation_settings(base.localisation, args)
    camera_model = getattr(args, "camera_model", "mirror")
    cfg = lockstep_config(args.seed, world=world_spec, start_pose=world.start_pose,
                          localisation=settings, camera_model=camera_model)
    backends = getattr(args, "backends", "sim")
    key = f"{world_spec} places={args.places} spacing={args.spacing} speed={args.speed} v3"
    if backends != "sim":  # a map learned through the ros2 backends is another map
        key += f" backends={backends}"
    if camera_model != "mirror":
        key += f" camera={camera_model}"
    known = load_references(args.map, key) if args.map else None
    if args.map and known is None:
        args.map.unlink(missing_ok=True)
    tour = plan_tour(world)  # once: planning costs seconds on a large world
    with open_run(cfg, backends, map_path=args.map) as run:
        if known is None:
            known = learn_along(run, along(tour, args.spacing), args.places, args.speed)
            if args.map:
                save_references(args.map, known, key)
        run.references = known
        run.restart_localiser()
        yield run, along(tour, 0.1)
