"""Synthetic places for map tests: random templates in a random panorama (seeded)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from daemon.mapping.place import Place
from daemon.store.sqlite_store import MapStore
from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet, centre_bearing
from kernel.se2 import SE2, UncertainSE2

WIDTH, HEIGHT, MARGIN = 720, 120, 16


def synthetic_place(rng: np.random.Generator, label: str = "", n: int = 16,
                    width: int = WIDTH, height: int = HEIGHT, margin: int = MARGIN) -> Place:
    """``n`` landmarks cut from a random panorama of ``height`` x (``width`` + 2 ``margin``)."""
    pano = rng.integers(0, 256, (height, width + 2 * margin, 3), dtype=np.uint8)
    landmarks = []
    for i in range(n):
        col = int(i * width / n)
        row = int(rng.integers(0, height - TEMPLATE))
        template = pano[row:row + TEMPLATE, margin + col:margin + col + TEMPLATE, 1].copy()
        cov = np.array([[0.04, 0.001], [0.001, math.radians(0.5) ** 2]])
        landmarks.append(Landmark(template, row, col, centre_bearing(col, width),
                                  depth=float(rng.uniform(0.5, 5.0)), covariance=cov,
                                  score=float(rng.uniform(0.0, 0.2))))
    return Place(LandmarkSet(tuple(landmarks), width, margin), pano, label=label,
                 created_unix_s=1.7e9 + float(rng.uniform(0, 1e6)))


def write_places_until_killed(path: str, geometry: str, seed: int, writing: Any) -> None:
    """A writer process: places (each linked to the previous one) until it is killed;
    sets ``writing`` once the map is open."""
    rng = np.random.default_rng(seed)
    store = MapStore.open(path, geometry)
    last = max((s.id for s in store.summaries()), default=None)
    writing.set()
    while True:
        links = [] if last is None else [
            (last, UncertainSE2(SE2(1.0, 0.0, 0.1), np.eye(3) * 1e-3), "odometry")]
        last = store.add_place(synthetic_place(rng, n=4, width=64, height=24, margin=0),
                               links).id
