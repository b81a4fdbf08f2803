"""``placecell-eval floor``: floor detection and local space profiles against the
simulator's ground-truth floor masks (design §4; thesis §5.1.4, Table 5.2; §5.2).

The world (office by default) is given each of the hard floors in ``DEFAULT_FLOORS``
(hal/sim/worldgen.py) — a
patterned carpet, glossy tiles that mirror the walls, and a carpet the colour of the
cabinets (``wall-coloured``, the colour of the walls, on request) — all with shadows
along walls and under obstacles. At ``--poses`` random free
poses the robot stands for 5 frames (the camera's noise differs per frame) and the
daemon's own floor grid (daemon/vision/floor.py) is fed the unwarped colour panoramas:
with the colour model alone, the gradient boundary alone, and both fused. The colour
model is learned once per world, at the start pose, from the floor in front of the
robot (the panorama's bottom rows within ±20° of ahead), as the robot would at
start-up.

Error (thesis eq. 5.5, as a fraction): the share of the pixels below the horizon whose
floor / not-floor call differs from the truth. Metrics (means over poses and floors):
``mae_colour_1``, ``mae_gradient_1``, ``mae_fused_1`` after 1 frame and the same with
``_5`` after 5; ``mae_fused_5_gain_0p5`` and ``mae_fused_5_gain_1p5`` under half and
one-and-a-half times the light (the colour model still from gain 1). ``by_floor``
holds the same per floor.

Local space (point 2 of the issue): the fused grid's profile after 10 frames is the
place's; ``person_match_change_max`` is the largest drop of its match
(daemon/vision/local_space.py) while a person walks past 1 m in front (8 frames, the
grid running on); ``move_1m_match_change_min`` / ``_median`` the drop for the profile
from a fresh grid after 10 frames 1 m away (free direction chosen at random), with
``move_1m_over_0p1`` the share of poses where it exceeds 0.1, and
``move_1m_over_0p1_true_floor`` the same between the true floors of the two poses (what
a perfect floor detector gives: the profile's own limit). The profile is in metres
(``profile_m``, capped at 5 m); the same with ``_rows`` for docs/design.md §4's rows.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import cv2
import numpy as np

from daemon.config import load
from daemon.vision.floor import FloorGrid, FloorModel
from daemon.vision.local_space import CAP_M, LocalSpace, match, profile, profile_m
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Person, Renderer
from hal.sim.world import World, load_world
from hal.sim.worldgen import FLOORS, with_floor
from kernel.panorama import core_of

DEFAULT_FLOORS = ("carpet", "glossy-tiles", "obstacle-coloured")  # wall-coloured: design §4
METHODS = {"colour": ("colour",), "gradient": ("gradient",), "fused": ("colour", "gradient")}
FRAMES = 5
PROFILE_FRAMES = 10
PERSON_FRAMES = 8
CLEARANCE_M = 0.5  # a pose this far from every wall and obstacle at least


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--poses", type=int, default=12, help="random free poses per floor")
    p.add_argument("--floors", default=",".join(DEFAULT_FLOORS),
                   help=f"comma-separated, from {', '.join(FLOORS)}")


def _clearance(world: World, x: float, y: float) -> float:
    """Distance from (x, y) to the nearest wall or obstacle; 0 inside a closed one."""
    best = math.inf
    for wall in world.walls:
        for (ax, ay), (bx, by) in wall.segments():
            dx, dy = bx - ax, by - ay
            t = min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)))
            best = min(best, math.hypot(x - ax - t * dx, y - ay - t * dy))
        if wall.closed:
            poly = np.array(wall.points, np.float32)
            if cv2.pointPolygonTest(poly, (x, y), False) >= 0:
                return 0.0
    return best


def free_poses(world: World, n: int, rng: np.random.Generator
               ) -> list[tuple[float, float, float]]:
    """``n`` random poses at least ``CLEARANCE_M`` clear of everything, inside the world,
    each with a free point 1 m away (for the move)."""
    x0, y0, x1, y1 = world.bounds()
    out: list[tuple[float, float, float]] = []
    while len(out) < n:
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if _clearance(world, x, y) >= CLEARANCE_M:
            out.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
    return out


def _moved(world: World, pose: tuple[float, float, float], rng: np.random.Generator
           ) -> tuple[float, float, float] | None:
    """A pose 1 m from ``pose`` in a random free direction (heading kept), straight-line
    reachable; None if no direction tried is free."""
    for a in rng.permutation(np.linspace(-math.pi, math.pi, 16, endpoint=False)):
        steps = [(pose[0] + s * math.cos(a), pose[1] + s * math.sin(a))
                 for s in (0.25, 0.5, 0.75, 1.0)]
        if all(_clearance(world, x, y) >= 0.3 for x, y in steps):
            return steps[-1][0], steps[-1][1], pose[2]
    return None


class _Eye:
    """One world's camera through the daemon's unwarping: colour core panoramas."""

    def __init__(self, world: World, config: Any, rng: np.random.Generator) -> None:
        self.renderer = Renderer(world, config.projection, config.panorama,
                                 (config.camera.sim.image_width, config.camera.sim.image_height))
        self.unwarper = Unwarper(config.projection, config.panorama)
        self.margin = config.panorama.wrap_margin
        self.noise = config.camera.sim.noise_sigma
        self.rng = rng

    def view(self, pose: tuple[float, float, float], **kw: Any) -> np.ndarray:
        raw = self.renderer.donut(pose, noise_sigma=self.noise, rng=self.rng, **kw)
        return core_of(self.unwarper.unwarp(raw), self.margin)


def _error(mask: np.ndarray, truth: np.ndarray, below: int) -> float:
    return float(np.mean(mask[below:] != truth[below:]))


def _profiles(mask: np.ndarray, distance: np.ndarray) -> dict[str, tuple[np.ndarray, float]]:
    """The local space profile in metres (capped at ``CAP_M``) and in rows (docs/design.md §4), each
    with its largest possible bin value."""
    rows = float(np.count_nonzero(np.isfinite(distance)))
    return {"m": (profile_m(mask, distance, CAP_M), CAP_M), "rows": (profile(mask), rows)}


def _drops(now: dict[str, tuple[np.ndarray, float]],
           place: dict[str, tuple[np.ndarray, float]]) -> dict[str, float]:
    return {u: 1.0 - match(now[u][0], place[u][0], place[u][1]) for u in place}


def _floor_run(eye: _Eye, world: World, learned: FloorModel,
               poses: list[Any], horizon: int, rng: np.random.Generator
               ) -> dict[str, list[float]]:
    model, step = learned.colour, learned.gradient_threshold
    distance = eye.unwarper.floor_distance_of_rows()
    below = horizon + 1
    shape = (eye.renderer.pano.height, eye.renderer.pano.width)
    out: dict[str, list[float]] = {}
    for pose in poses:
        truth = eye.renderer.floor_mask(pose)
        for gain in (1.0, 0.5, 1.5):
            grids = {m: FloorGrid(shape, horizon, gradient_threshold=step)
                     for m in METHODS if gain == 1.0 or m == "fused"}
            for k in range(FRAMES):
                bgr = eye.view(pose, gain=gain)
                for m, grid in grids.items():
                    grid.update(bgr, model, METHODS[m])
                    if k + 1 in (1, FRAMES):
                        tag = f"{m}_{k + 1}" if gain == 1.0 else f"{m}_{k + 1}_gain_{gain}"
                        out.setdefault(tag, []).append(_error(grid.mask(), truth, below))
        # local space: the place's profile, a person walking past, a 1 m move
        grid = FloorGrid(shape, horizon, gradient_threshold=step)
        for _ in range(PROFILE_FRAMES):
            grid.update(eye.view(pose), model)
        place = _profiles(grid.mask(), distance)
        x, y, yaw = pose
        drops: dict[str, list[float]] = {}
        for k in range(PERSON_FRAMES):  # across the view 1 m ahead, 0.25 m per frame
            side = (k - PERSON_FRAMES / 2) * 0.25
            person = Person(x + math.cos(yaw) - side * math.sin(yaw),
                            y + math.sin(yaw) + side * math.cos(yaw))
            grid.update(eye.view(pose, people=(person,)), model)
            for unit, drop in _drops(_profiles(grid.mask(), distance), place).items():
                drops.setdefault(unit, []).append(drop)
        for unit, values in drops.items():
            out.setdefault(f"person_drop_{unit}", []).append(max(values))
        moved = _moved(world, pose, rng)
        if moved is not None:
            fresh = FloorGrid(shape, horizon, gradient_threshold=step)
            for _ in range(PROFILE_FRAMES):
                fresh.update(eye.view(moved), model)
            for unit, drop in _drops(_profiles(fresh.mask(), distance), place).items():
                out.setdefault(f"move_drop_{unit}", []).append(drop)
            # The same with the true floor at both poses: what a perfect detector gives
            for unit, drop in _drops(_profiles(eye.renderer.floor_mask(moved), distance),
                                     _profiles(truth, distance)).items():
                out.setdefault(f"move_truth_drop_{unit}", []).append(drop)
    return out


def _learn_floor(eye: _Eye, world: World, horizon: int) -> FloorModel:
    """The floor in front of the robot at start-up, as the method learns it
    (``LocalSpace.learn_floor``): its colour model and the step its texture does not
    make."""
    local = LocalSpace((eye.renderer.pano.height, eye.renderer.pano.width), horizon,
                       eye.unwarper.floor_distance_of_rows())
    local.learn_floor(eye.view(world.start_pose))
    assert local.floor is not None
    return local.floor


def run(args: argparse.Namespace) -> dict[str, Any]:
    config = load(None)
    names = [n.strip() for n in args.floors.split(",") if n.strip()]
    unknown = [n for n in names if n not in FLOORS]
    if unknown or not names:
        raise SystemExit(f"placecell-eval floor: unknown floor {unknown[0] if unknown else ''!r}"
                         f" (known: {', '.join(FLOORS)})")
    base = load_world(f"generate:{args.world_kind}:{args.world_seed}")
    unwarper = Unwarper(config.projection, config.panorama)
    horizon = int(math.floor(unwarper.horizon_row()))
    rng = np.random.default_rng(args.seed)
    poses = free_poses(base, args.poses, rng)
    by_floor: dict[str, dict[str, float]] = {}
    pooled: dict[str, list[float]] = {}
    for name in names:
        world = with_floor(base, name)
        eye = _Eye(world, config, np.random.default_rng([args.seed, len(by_floor)]))
        learned = _learn_floor(eye, world, horizon)
        got = _floor_run(eye, world, learned, poses, horizon,
                         np.random.default_rng([args.seed, 7]))
        by_floor[name] = {k.replace(".", "p"): round(float(np.mean(v)), 4)
                          for k, v in got.items()}
        for k, v in got.items():
            pooled.setdefault(k, []).extend(v)
    mean = {k: round(float(np.mean(v)), 4) for k, v in pooled.items()}
    metrics: dict[str, Any] = {f"mae_{k.replace('.', 'p')}": v for k, v in mean.items()
                               if "_drop" not in k}
    for unit, tag in (("m", ""), ("rows", "_rows")):
        moves = np.array(pooled.get(f"move_drop_{unit}", [np.nan]))
        metrics.update({
            f"person_match_change_max{tag}": round(float(np.max(pooled[f"person_drop_{unit}"])),
                                                   4),
            f"move_1m_match_change_min{tag}": round(float(np.nanmin(moves)), 4),
            f"move_1m_match_change_median{tag}": round(float(np.nanmedian(moves)), 4),
            f"move_1m_over_0p1{tag}": round(float(np.mean(moves > 0.1)), 4),
            f"move_1m_over_0p1_true_floor{tag}": round(float(np.mean(np.array(
                pooled.get(f"move_truth_drop_{unit}", [np.nan])) > 0.1)), 4)})
    metrics.update(poses=len(poses), floors=len(names), by_floor=by_floor)
    return {
        "world": {"kind": args.world_kind, "seed": args.world_seed},
        "config": {"poses": args.poses, "floors": names, "frames": FRAMES},
        "metrics": metrics,
    }
