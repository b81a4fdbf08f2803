"""``placecell-eval robustness``: landmark sets under changed light and occlusion
(docs/design.md §3; issue: visual landmarks, point 3).

Places are learned by Turn Back and Look along the office corridor. At each reference
pose the LRP of its own set is measured under illumination gain 0.5 and 1.5; and with a
person standing 1 m in front of the robot, the LRP of every place's set is compared: the
true place must score highest.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from daemon.config import load
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser
from daemon.mapping.place import Place
from hal.sim.render import Person
from kernel.types import Frame
from tools.eval.places import learn


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--places", type=int, default=5)


def run(args: argparse.Namespace) -> dict[str, Any]:
    config = load(None)
    world = f"generate:office:{args.world_seed}"
    xs = np.linspace(3.0, 27.0, args.places)
    places = [learn(world, (float(x), 10.0, 0.0), args.seed) for x in xs]
    # The daemon's recognition of the places.
    known = KnownMap.of(Place(p.tbl, None, id=k + 1) for k, p in enumerate(places))
    localiser = Localiser(config.projection, config.panorama, settings=config.localisation,
                          known_map=MapHolder(known))
    ids = list(range(1, len(places) + 1))
    rng = np.random.default_rng(args.seed)
    gains: dict[float, list[float]] = {0.5: [], 1.5: []}
    correct, margins = 0, []

    def frame(place: Any, **view: Any) -> Frame:
        return Frame(place.renderer.donut(place.pose, noise_sigma=2.0, rng=rng, **view), 0, 0)

    for k, place in enumerate(places):
        for gain in gains:
            gains[gain].append(localiser.recognise(frame(place, gain=gain), [k + 1])[0].lrp)
        x, y, yaw = place.pose
        person = Person(x + math.cos(yaw), y + math.sin(yaw))  # 1 m ahead: ~28° hidden
        lrps = [sc.lrp for sc in localiser.recognise(frame(place, people=(person,)), ids)]
        correct += int(int(np.argmax(lrps)) == k)
        margins.append(lrps[k] - max(v for j, v in enumerate(lrps) if j != k))
    return {
        "world": {"kind": "office", "seed": args.world_seed},
        "config": {"places": args.places},
        "metrics": {
            "lrp_gain_0_5_min": round(min(gains[0.5]), 4),
            "lrp_gain_1_5_min": round(min(gains[1.5]), 4),
            "occluded_true_place_best_fraction": round(correct / len(places), 4),
            "occluded_min_margin": round(min(margins), 4),
        },
    }
