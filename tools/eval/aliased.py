"""``placecell-eval aliased``: telling look-alike places apart in the aliased corridor
(design §5; thesis §9.5 found the active search too slow and unreliable to use online).

On a map of ``--places`` places along the aliased corridor's tour (tools/eval/tour_map.py;
identical doors every 3 m, a small sign beside each), each of ``--trials`` trials carries
the robot to a random point of the mapped tour at a random heading, starts a new
Localiser there with no pose (as the daemon starts) and drives on along the tour for
``--frames`` frames. Every trial runs twice from the same start: with the disambiguating
features the Mapper found when the places were learned, and with ``[localisation]
disambiguation = false`` (the lower levels alone). A frame's place is *right* when its
reference is the nearest to the truth, or no more than 0.5 m farther (design §9).

Metrics: ``trials``, ``frames`` (per run), ``pairs`` (look-alike pairs with features in
the map), ``ambiguous_frames`` (frames at which the top two stayed within
``ambiguity_margin`` for ``ambiguity_frames`` and the features decided),
``ambiguous_trials`` (the share of trials with at least one), ``disambiguation_accuracy``
(the share of those decisions naming a right place), ``mlp_accuracy_with`` and
``mlp_accuracy_without`` (the belief's place right, over every frame of every trial),
``mlp_gain`` (with minus without), ``right_at_end_with`` / ``right_at_end_without``
(right at the trial's last frame),
``disambiguation_ms`` (median time of one decision, per pair of look-alikes compared:
a decision among k places compares every pair of them that has features).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tools.eval.lockstep import Run
from tools.eval.tour_map import Point, add_map_arguments, mapped_run, right_place

SEED_COLUMNS = ("ambiguous_frames", "disambiguation_accuracy", "mlp_accuracy_with",
                "mlp_accuracy_without", "mlp_gain", "right_at_end_with",
                "right_at_end_without")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_map_arguments(p, places=8)
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--frames", type=int, default=25, help="frames per trial")


@dataclass(frozen=True)
class Frame:
    right: bool  # the belief's place
    told_right: bool | None  # the features' decision at this frame, if one was made
    decision_ms: float | None  # per pair of look-alikes compared


def _trial(r: Run, tour: list[Point], start: int, yaw: float, frames: int,
           speed: float, noise_seed: int) -> list[Frame]:
    """From tour point ``start`` at heading ``yaw``, no pose: each frame's outcome. The
    simulated noise is drawn from ``noise_seed``, so a trial run with the features and
    without sees the same odometry and camera noise (before, the second run drew on
    where the first had left the generators: on aliased-corridor seeds 1-4 the figures
    without the features moved by up to 0.016 when only the features' rule changed)."""
    x, y = tour[start]
    r.base.stop()
    r.robot.reseed(noise_seed)
    r.robot.kidnap(x, y, yaw)
    r.restart_localiser()
    ahead = tour[min(start + 30, len(tour) - 1)]  # drive on along the tour
    dx, dy = ahead[0] - x, ahead[1] - y
    c, s = math.cos(yaw), math.sin(yaw)
    r.base.move_relative(c * dx + s * dy, -s * dx + c * dy, 0.0, speed)
    out = []
    for _ in range(frames):
        _, belief = r.step()
        tx, ty, _ = r.robot.true_pose()
        told = belief.disambiguation
        out.append(Frame(right_place(r.references, belief.place_id, (tx, ty)),
                         None if told is None else right_place(r.references, told.place_id,
                                                               (tx, ty)),
                         None if told is None else told.elapsed_ms / told.pairs))
    r.base.stop()
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    rng = np.random.default_rng(args.seed)
    with mapped_run(args) as (r, tour):
        covered = [i for i, p in enumerate(tour) if min(
            math.dist(p, (ref.x, ref.y)) for ref in r.references.values()) <= 0.5]
        starts = [(int(rng.choice(covered)), float(rng.uniform(-math.pi, math.pi)))
                  for _ in range(args.trials)]
        pairs = len(r.mapper.graph.features)
        with_features = r.cfg
        runs: dict[str, list[list[Frame]]] = {}
        for name, disambiguation in (("with", True), ("without", False)):
            r.cfg = dataclasses.replace(with_features, localisation=dataclasses.replace(
                with_features.localisation, disambiguation=disambiguation))
            runs[name] = [_trial(r, tour, i, yaw, args.frames, args.speed,
                                 noise_seed=args.seed * 100_003 + k)
                          for k, (i, yaw) in enumerate(starts)]
        r.cfg = with_features
        decisions = [f for t in runs["with"] for f in t if f.told_right is not None]
        n = len(starts)

        def accuracy(name: str) -> float:
            return round(float(np.mean([f.right for t in runs[name] for f in t])), 4)

        return {"metrics": {
            "trials": n,
            "frames": n * args.frames,
            "places": len(r.references),
            "pairs": pairs,
            "ambiguous_frames": len(decisions),
            "ambiguous_trials": round(sum(any(f.told_right is not None for f in t)
                                          for t in runs["with"]) / n, 4),
            "disambiguation_accuracy": round(float(np.mean([f.told_right for f in decisions])),
                                             4) if decisions else None,
            "mlp_accuracy_with": accuracy("with"),
            "mlp_accuracy_without": accuracy("without"),
            "mlp_gain": round(accuracy("with") - accuracy("without"), 4),
            "right_at_end_with": round(sum(t[-1].right for t in runs["with"]) / n, 4),
            "right_at_end_without": round(sum(t[-1].right for t in runs["without"]) / n, 4),
            "disambiguation_ms": round(float(np.median([f.decision_ms for f in decisions])),
                                       3) if decisions else None,
        }, "config": {"places": args.places, "spacing_m": args.spacing,
                      "trials": args.trials, "frames": args.frames,
                      "ambiguity_margin": r.cfg.localisation.ambiguity_margin,
                      "ambiguity_frames": r.cfg.localisation.ambiguity_frames}}
