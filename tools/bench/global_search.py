"""Global relocalisation speed (design §9): ``global{10,50,100,1000}_ms``.

One full relocalisation decision over a map of N places: the ``Localiser`` (default
settings: 25 places recognised per frame) is told to relocalise and processes frames of
one view until it has chosen a place — each frame the signature against every place's
(the cue), then the active set's landmarks recognised best cue first, and at last the
chosen place positioned in. The figure is the sum of those frames' ``search`` times,
the median over ``repeats`` views at different places; ``globalN_frames`` is how many
frames it took, ``active_fraction_N`` the share of the map recognised, and
``globalN_right`` the share of decisions that chose the place the view was rendered
0.14 m from (or one within 0.5 m of it).

The places are cut from panoramas rendered every 0.5 m along the tours of generated
office worlds (seed 1, 2, ... until N places), 16 templates each at the most textured
windows apart in azimuth (static selection costs 0.2 s a place: too slow to build a
thousand for a benchmark; the search's cost does not depend on how they were chosen).
"""

from __future__ import annotations

import math
import statistics
from typing import Any

import cv2
import numpy as np

from daemon.config import load
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.place import Place
from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet, centre_bearing
from daemon.vision.signature import signature
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.panorama import add_wrap_margin, to_grey
from kernel.types import Frame
from tools.eval.tour_map import tour_points

SIZES = (10, 50, 100, 1000)
LANDMARKS = 16


def _landmarks(grey: np.ndarray, margin: int) -> LandmarkSet:
    """16 windows of the highest grey-level spread, at least W / 32 columns apart."""
    core = grey[:, margin:grey.shape[1] - margin].astype(np.float32)
    h, w = core.shape
    mean = cv2.boxFilter(core, -1, (TEMPLATE, TEMPLATE), anchor=(0, 0),
                         borderType=cv2.BORDER_CONSTANT)[:h - TEMPLATE + 1, :w - TEMPLATE + 1]
    square = cv2.boxFilter(core * core, -1, (TEMPLATE, TEMPLATE), anchor=(0, 0),
                           borderType=cv2.BORDER_CONSTANT)[:h - TEMPLATE + 1, :w - TEMPLATE + 1]
    spread = np.sqrt(np.maximum(square - mean * mean, 0.0))
    order = np.argsort(-spread, axis=None)
    best = [(0.0, int(i // spread.shape[1]), int(i % spread.shape[1])) for i in order[:4000]]
    chosen: list[tuple[int, int]] = []
    for _, r, c in best:
        if all(min(abs(c - c2), w - abs(c - c2)) >= w // 32 for _, c2 in chosen):
            chosen.append((r, c))
        if len(chosen) == LANDMARKS:
            break
    lms = tuple(Landmark(grey[r:r + TEMPLATE, margin + c:margin + c + TEMPLATE].copy(), r, c,
                         centre_bearing(c, w), depth=2.0,
                         covariance=np.diag([0.04, 1e-4])) for r, c in chosen)
    return LandmarkSet(lms, w, margin)


def _places(count: int) -> tuple[list[Place], list[tuple[str, tuple[float, float, float]]]]:
    config = load(None)
    margin = config.panorama.wrap_margin
    places: list[Place] = []
    poses = []
    seed = 1
    while len(places) < count:
        world = f"generate:office:{seed}"
        renderer = Renderer(load_world(world), config.projection, config.panorama, (640, 480))
        for x, y in tour_points(load_world(world), 0.5):
            if len(places) == count:
                break
            pose = (x, y, 0.0)
            grey = to_grey(add_wrap_margin(renderer.panorama(pose), margin))
            places.append(Place(_landmarks(grey, margin), None, id=len(places) + 1,
                                signature=signature(grey, margin)))
            poses.append((world, pose))
        seed += 1
    return places, poses


def decision_ms(places: list[Place], poses: list[tuple[str, tuple[float, float, float]]],
                repeats: int) -> tuple[float, float, float, float]:
    """(median ms, mean frames, mean share of the map recognised) to a decision, and the
    share of decisions that chose a right place (within 0.5 m of the nearest one)."""
    config = load(None)
    localiser = Localiser(config.projection, config.panorama, settings=LocalisationSettings(),
                          known_map=MapHolder(KnownMap.of(places)))
    rng = np.random.default_rng(0)
    renderers: dict[str, Renderer] = {}
    times, frames, fractions, right = [], [], [], []
    stamp = 0
    for k in range(repeats + 1):  # the first compiles and warms up
        world, (x, y, _) = poses[int(rng.integers(len(poses)))]
        if world not in renderers:
            renderers[world] = Renderer(load_world(world), config.projection, config.panorama,
                                        (640, 480))
        view = (x + 0.1, y - 0.1)
        raw = renderers[world].donut((*view, float(rng.uniform(-3, 3))))
        localiser.relocalise()
        spent, n, scored = 0.0, 0, 0
        while n < 100:  # frames of the same view until a place is chosen
            stamp += 100_000_000
            belief, _ = localiser.process_frame(Frame(raw, stamp, n))
            spent, n, scored = spent + belief.timings_ms["search"], n + 1, scored + len(
                belief.scores)
            if localiser.mode != "search":
                break
        if k:
            times.append(spent)
            frames.append(n)
            fractions.append(scored / len(places))
            dist = [math.dist(view, pose[:2]) if w == world else math.inf
                    for w, pose in poses]
            chosen = None if localiser.tracker is None else localiser.tracker.place.id
            right.append(chosen is not None and dist[chosen - 1] <= min(dist) + 0.5)
    return (statistics.median(times), float(np.mean(frames)), float(np.mean(fractions)),
            float(np.mean(right)))


def run(repeats: int) -> dict[str, Any]:
    places, poses = _places(max(SIZES))
    out: dict[str, Any] = {}
    for n in SIZES:
        ms, frames, fraction, right = decision_ms(places[:n], poses[:n], repeats)
        out[f"global{n}_right"] = round(right, 3)
        out[f"global{n}_ms"] = round(ms, 2)
        out[f"global{n}_frames"] = round(frames, 2)
        out[f"active_fraction_{n}"] = round(fraction, 3)
    return out
