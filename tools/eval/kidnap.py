"""``placecell-eval kidnap``: the kidnapped robot, many times over (design §9; thesis
§9.6 shows one: right place, 0.156 m).

On a map of ``--places`` places along the world's tour (tools/eval/tour_map.py), each of
``--kidnaps`` trials draws a start and a release pose at random along the tour (at least
``--apart`` m apart, any heading): the robot stands at the start and the localiser is
told where it is (the trial's set-up, as an operator would), 5 frames are processed, the
robot is carried to the release pose without odometry knowing, and ``--after`` frames
follow as it drives on along the tour from there. Truth (the simulator's) only scores.

Metrics (fractions of the trials): ``kidnaps``, ``detected_within_5`` (a loss declared
within 5 frames of the release), ``right_place_within_10`` (the belief's place right at
the 10th frame: its reference nearest the truth, or within 0.5 m of the nearest),
``error_within_0p2_at_10`` (and the position error there at most 0.2 m),
``right_place_within_15`` (the belief's place right at the 15th frame; None when
``--after`` is shorter),
``mean_active_fraction`` (places recognised per frame over the map's size while lost or
relocalising), ``error_m_median_at_10``.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from daemon.localisation.belief import Belief
from tools.eval.lockstep import Run
from tools.eval.tour_map import Point, add_map_arguments, mapped_run, right_place

CAMERA_MODELS = True  # --camera-model M: any of kernel/camera_models.py MODEL_NAMES

START_FRAMES = 5
SEED_COLUMNS = ("detected_within_5", "right_place_within_10", "right_place_within_15",
                "error_within_0p2_at_10", "error_m_median_at_10")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_map_arguments(p, places=50)
    p.add_argument("--kidnaps", type=int, default=100)
    p.add_argument("--apart", type=float, default=2.0, help="min start-release distance, m")
    p.add_argument("--after", type=int, default=15, help="frames after the release")


def _nearest_place(r: Run) -> int:
    x, y, _ = r.robot.true_pose()
    return min(r.references, key=lambda p: math.dist((r.references[p].x,
                                                      r.references[p].y), (x, y)))


def _trial(r: Run, tour: list[Point], start: int, release: int, yaws: tuple[float, float],
           after: int, speed: float) -> dict[str, Any]:
    sx, sy = tour[start]
    r.base.stop()
    r.robot.kidnap(sx, sy, yaws[0])
    place = _nearest_place(r)
    r.localiser.set_pose(place, r.truth_in(place).as_tuple(), 0.05, 0.05)
    for _ in range(START_FRAMES):
        r.step()
    rx, ry = tour[release]
    r.robot.kidnap(rx, ry, yaws[1])  # odometry knows nothing of it
    ahead = tour[min(release + 20, len(tour) - 1)]  # drive on along the tour
    x, y, yaw = r.robot.true_pose()
    dx, dy = ahead[0] - x, ahead[1] - y
    c, s = math.cos(yaw), math.sin(yaw)
    r.base.move_relative(c * dx + s * dy, -s * dx + c * dy, 0.0, speed)
    beliefs: list[Belief] = []
    lost_at, at_10, right_15 = None, None, None
    active = []
    for k in range(1, after + 1):
        _, belief = r.step()
        beliefs.append(belief)
        if lost_at is None and belief.event is not None and belief.event.kind == "lost":
            lost_at = k
        if belief.state in ("lost", "relocalising"):
            active.append(len(belief.scores) / len(r.references))
        if k == 15:
            tx, ty, _ = r.robot.true_pose()
            right_15 = right_place(r.references, belief.place_id, (tx, ty))
        if k == 10:
            tx, ty, _ = r.robot.true_pose()
            error = r.error_m(belief)
            at_10 = (right_place(r.references, belief.place_id, (tx, ty)),
                     math.inf if error is None else error)
    r.base.stop()
    assert at_10 is not None
    return {"detected": lost_at is not None and lost_at <= 5, "right": at_10[0],
            "right_15": right_15,
            "error": at_10[1], "active": active}


def run(args: argparse.Namespace) -> dict[str, Any]:
    rng = np.random.default_rng(args.seed)
    with mapped_run(args) as (r, tour):
        # Only the part of the tour the map covers: within 0.5 m of some place.
        covered = [i for i, p in enumerate(tour) if min(
            math.dist(p, (ref.x, ref.y)) for ref in r.references.values()) <= 0.5]
        trials = []
        for _ in range(args.kidnaps):
            start = int(rng.choice(covered))
            far = [i for i in covered if math.dist(tour[i], tour[start]) >= args.apart]
            release = int(rng.choice(far)) if far else int(rng.choice(covered))
            yaws = (float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(-math.pi,
                                                                               math.pi)))
            trials.append(_trial(r, tour, start, release, yaws, args.after, args.speed))
        n = len(trials)
        active = [a for t in trials for a in t["active"]]
        errors = [t["error"] for t in trials if t["right"]]
        return {"metrics": {
            "kidnaps": n,
            "places": len(r.references),
            "detected_within_5": round(sum(t["detected"] for t in trials) / n, 4),
            "right_place_within_10": round(sum(t["right"] for t in trials) / n, 4),
            "error_within_0p2_at_10": round(sum(t["right"] and t["error"] <= 0.2
                                                for t in trials) / n, 4),
            "right_place_within_15": round(sum(bool(t["right_15"]) for t in trials) / n, 4)
            if args.after >= 15 else None,
            "error_m_median_at_10": round(float(np.median(errors)), 4) if errors else None,
            "mean_active_fraction": round(float(np.mean(active)), 4) if active else 0.0,
        }, "config": {"places": args.places, "spacing_m": args.spacing,
                      "apart_m": args.apart, "after": args.after}}
