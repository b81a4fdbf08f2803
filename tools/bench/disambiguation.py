"""Disambiguating features (design §5): ``disambiguation_precompute_s`` (both features of
a pair of look-alike places), ``disambiguation_ms`` (one decision in a current view),
and ``disambiguation_right`` (the share of decisions that name the place a view was
rendered near, over views up to 0.3 m off either reference at any heading).

The pair: two stretches of the aliased corridor 3 m apart (identical doors, a small
sign beside each, hal/sim/worldgen.py), each seen from its reference and from the four
ends of a 0.25 m cross (the Turn Back and Look frames).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from daemon.config import load
from daemon.vision.disambiguation import decide, find_feature
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.panorama import add_wrap_margin, to_grey
from tools.bench.timing import median_seconds

WORLD = "generate:aliased-corridor:1"
REFERENCES = ((4.0, 1.2), (7.0, 1.2))  # 3 m apart: the door spacing
CROSS_M = 0.25
VIEWS = 40


def run(repeats: int) -> dict[str, Any]:
    config = load(None)
    margin = config.panorama.wrap_margin
    renderer = Renderer(load_world(WORLD), config.projection, config.panorama, (640, 480))

    def view(x: float, y: float, yaw: float) -> np.ndarray:
        return to_grey(add_wrap_margin(renderer.panorama((x, y, yaw)), margin))

    places = []
    for x, y in REFERENCES:
        places.append([view(x, y, 0.0)] + [view(x + dx, y + dy, 0.0) for dx, dy in (
            (CROSS_M, 0.0), (-CROSS_M, 0.0), (0.0, CROSS_M), (0.0, -CROSS_M))])
    a, b = places

    def precompute() -> tuple[Any, Any]:
        return find_feature(a, b[:1], margin), find_feature(b, a[:1], margin)

    t0 = time.perf_counter()
    fa, fb = precompute()
    precompute_s = time.perf_counter() - t0
    if repeats > 1:  # the pair's features cost seconds: a few runs are enough
        precompute_s = median_seconds(precompute, min(repeats, 3), warmup=0)
    rng = np.random.default_rng(1)
    right, current = 0, view(*REFERENCES[0], 0.0)
    for k in range(VIEWS):
        which = k % 2
        x, y = REFERENCES[which]
        r, phi = rng.uniform(0.0, 0.3), rng.uniform(-math.pi, math.pi)
        seen = view(x + r * math.cos(phi), y + r * math.sin(phi), rng.uniform(-math.pi, math.pi))
        right += decide(seen, fa, fb).winner == "ab"[which]
        current = seen
    decide_s = median_seconds(lambda: decide(current, fa, fb), repeats, inner=20)
    return {"disambiguation_precompute_s": round(precompute_s, 3),
            "disambiguation_ms": round(decide_s * 1e3, 3),
            "disambiguation_right": round(right / VIEWS, 3)}
