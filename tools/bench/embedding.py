"""The `map` frame at scale (design §6): a 1000-place map embedded by least squares.

The places stand on a 25 × 40 lattice 1 m apart, driven row by row (a serpentine chain of
odometry transitions whose heading drifts 0.01 rad a leg), and every fifth column's places
are joined to the row above by a precise cycle transition: 1000 places, about 1190
transitions, 190 cycles. Figure: ``embed1000_s``, one optimisation from dead reckoning
(what the Mapper's embedding thread does after each place learned).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from daemon.mapping.embedding import embed
from daemon.mapping.graph import TopologicalMap
from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.vision.landmarks import LandmarkSet
from kernel.se2 import SE2, UncertainSE2
from tools.bench.timing import median_seconds

ROWS, COLUMNS = 25, 40
ODOMETRY = np.diag([0.02 ** 2, 0.02 ** 2, 0.01 ** 2])
CYCLE = np.diag([0.01 ** 2, 0.01 ** 2, 0.005 ** 2])


def lattice_map() -> TopologicalMap:
    order = [(r, c if r % 2 == 0 else COLUMNS - 1 - c) for r in range(ROWS)
             for c in range(COLUMNS)]
    ids = {cell: i + 1 for i, cell in enumerate(order)}
    truth = {cell: SE2(float(cell[1]), float(cell[0]), 0.0) for cell in order}
    empty = Place(LandmarkSet((), 720, 0), None)
    graph = TopologicalMap([dataclasses.replace(empty, id=i) for i in ids.values()])
    for prev, cell in zip(order, order[1:], strict=False):
        true = truth[prev].between(truth[cell])
        drifted = SE2(true.x, true.y, true.yaw + 0.01)
        graph.add_transition(Transition(ids[prev], ids[cell], UncertainSE2(drifted, ODOMETRY)))
    for r in range(ROWS - 1):
        for c in range(0, COLUMNS, 5):
            a, b = (r, c), (r + 1, c)
            graph.add_transition(Transition(ids[a], ids[b], UncertainSE2(
                truth[a].between(truth[b]), CYCLE), "cycle"))
    return graph


def run(repeats: int) -> dict[str, float]:
    graph = lattice_map()
    return {"embed1000_s": median_seconds(lambda: embed(graph), max(3, repeats // 3))}
