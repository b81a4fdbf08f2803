"""The map frame (daemon/mapping/embedding.py): the places of a topological map embedded by
least squares over its transitions, on a crafted square loop whose odometry drifts."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from daemon.mapping.embedding import embed
from daemon.mapping.graph import TopologicalMap
from daemon.mapping.transition import Transition
from kernel.se2 import SE2, UncertainSE2
from tests.map_fixtures import synthetic_place

# Eight places round a 4 m x 4 m square, each facing along it.
TRUTH = [SE2(x, y, yaw) for x, y, yaw in [
    (0, 0, 0), (2, 0, 0), (4, 0, math.pi / 2), (4, 2, math.pi / 2), (4, 4, math.pi),
    (2, 4, math.pi), (0, 4, -math.pi / 2), (0, 2, -math.pi / 2)]]
ODOMETRY = np.diag([0.02 ** 2, 0.02 ** 2, 0.03 ** 2])  # per 2 m leg
CLOSURE = np.diag([0.01 ** 2, 0.01 ** 2, 0.005 ** 2])  # a cycle closed by vision


def _graph(heading_bias: float, close: bool) -> TopologicalMap:
    rng = np.random.default_rng(3)
    places = [dataclasses.replace(synthetic_place(rng, n=2, width=64, height=24, margin=0),
                                  id=i + 1, reference_panorama=None) for i in range(8)]
    graph = TopologicalMap(places)
    for i in range(7):  # odometry with a heading bias: every leg turned a little more
        true = TRUTH[i].between(TRUTH[i + 1])
        drifted = SE2(true.x, true.y, true.yaw + heading_bias)
        graph.add_transition(Transition(i + 1, i + 2, UncertainSE2(drifted, ODOMETRY)))
    if close:  # back at the first place: the loop measured by local estimates
        graph.add_transition(Transition(8, 1, UncertainSE2(TRUTH[7].between(TRUTH[0]),
                                                           CLOSURE), "cycle"))
    return graph


def _errors(poses: dict[int, SE2]) -> list[float]:
    return [math.hypot(poses[i + 1].x - t.x, poses[i + 1].y - t.y)
            for i, t in enumerate(TRUTH)]


def test_a_chain_is_the_composition_of_its_transitions() -> None:
    graph = _graph(0.0, close=False)
    poses = embed(graph)
    assert poses[1] == SE2(0.0, 0.0, 0.0)
    assert max(_errors(poses)) < 1e-9


def test_closing_the_loop_spreads_the_drift_over_it() -> None:
    open_loop = embed(_graph(0.03, close=False))  # dead reckoning: 1.0 m off at the end
    closed = embed(_graph(0.03, close=True))
    assert max(_errors(open_loop)) > 0.5
    assert max(_errors(closed)) <= 0.10, _errors(closed)
    assert max(_errors(closed)) < 0.25 * max(_errors(open_loop))
    last, true = closed[8].between(closed[1]), TRUTH[7].between(TRUTH[0])
    assert math.hypot(last.x - true.x, last.y - true.y) < 0.02  # the precise closure kept


def test_places_not_joined_to_the_first_are_left_out() -> None:
    graph = _graph(0.0, close=False)
    rng = np.random.default_rng(4)
    graph.add_place(dataclasses.replace(synthetic_place(rng, n=2, width=64, height=24,
                                                        margin=0), id=9))
    assert set(embed(graph)) == set(range(1, 9))
    assert embed(TopologicalMap()) == {}


def test_reached_composes_the_first_path_out_to_each_place() -> None:
    """TopologicalMap.reached: what the Mapper uses to keep neighbours out of look-alikes."""
    graph = _graph(0.0, close=False)
    reached = graph.reached(1)
    assert sorted(reached) == [2, 3, 4, 5, 6, 7, 8]
    for i, t in enumerate(TRUTH[1:], start=2):
        expected = TRUTH[0].between(t)
        assert (reached[i].x, reached[i].y) == (
            pytest.approx(expected.x, abs=1e-9), pytest.approx(expected.y, abs=1e-9))
    assert sorted(graph.reached(1, max_places=3)) == [2, 3]


def test_a_thousand_place_lattice_with_cycles_is_straightened() -> None:
    """The bench's map (tools/bench/embedding.py): a serpentine of 1000 places whose
    heading drifts 0.01 rad a leg, cycles closed between rows every fifth column. Dead
    reckoning ends metres off; the embedding puts every place near its lattice point."""
    from tools.bench.embedding import COLUMNS, lattice_map

    graph = lattice_map()
    poses = embed(graph)
    assert len(poses) == len(graph) == 1000

    def error(pid: int, pose: SE2) -> float:
        row, k = divmod(pid - 1, COLUMNS)
        col = k if row % 2 == 0 else COLUMNS - 1 - k
        return math.hypot(pose.x - col, pose.y - row)

    from daemon.mapping.embedding import _dead_reckoning
    drifted = _dead_reckoning(graph, 1)
    assert max(error(p, x) for p, x in drifted.items()) > 5.0
    assert max(error(p, x) for p, x in poses.items()) < 0.5
