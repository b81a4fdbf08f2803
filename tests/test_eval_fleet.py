"""The fleet experiment's rules (tools/eval/fleet.py): the stretches A and B drive, the
propagation it times and the duplicates it counts. The experiment itself (routers and
daemons) is ``placecell-eval fleet``; its parts run for real in tests/test_fleet_*.py."""

from __future__ import annotations

import math

from tools.eval.fleet import along, duplicate_pairs, propagation_s, stretch

L_PATH = [(0.0, 0.0), (4.0, 0.0), (4.0, 3.0)]  # 4 m east, then 3 m north


def test_a_point_along_a_polyline_is_measured_along_its_legs() -> None:
    assert along(L_PATH, 0.0) == (0.0, 0.0)
    assert along(L_PATH, 2.5) == (2.5, 0.0)
    assert along(L_PATH, 5.0) == (4.0, 1.0)
    assert along(L_PATH, 99.0) == (4.0, 3.0)  # clamped to the end


def test_a_stretch_keeps_the_corner_and_runs_backwards_when_asked() -> None:
    forward = stretch(L_PATH, 3.0, 6.0, step_m=0.5)
    assert forward[0] == (3.0, 0.0) and forward[-1] == (4.0, 2.0)
    assert (4.0, 0.0) in forward  # the corner, so the robot drives round it
    legs = [math.dist(p, q) for p, q in zip(forward, forward[1:], strict=False)]
    assert all(0.1 <= leg <= 0.5 + 1e-9 for leg in legs)
    assert stretch(L_PATH, 6.0, 3.0, step_m=0.5) == forward[::-1]


def test_propagation_pairs_a_learned_place_with_the_other_robots_adoption() -> None:
    learned = {"a": [{"place": 1, "stamp_ns": 1_000_000_000},
                     {"place": 2, "stamp_ns": 5_000_000_000}],
               "b": [{"place": 1, "stamp_ns": 2_000_000_000}]}
    adopted = {"a": [{"robot": "b", "origin_id": 1, "stamp_ns": 2_250_000_000}],
               "b": [{"robot": "a", "origin_id": 1, "stamp_ns": 1_100_000_000},
                     {"robot": "c", "origin_id": 2, "stamp_ns": 9_000_000_000}]}
    # a's place 2 never reached b (c's place 2 is another place): left out
    assert propagation_s(learned, adopted) == [0.1, 0.25]


def test_duplicates_are_pairs_of_references_nearer_than_the_bound() -> None:
    assert duplicate_pairs([(0.0, 0.0), (0.2, 0.0), (0.0, 0.25), (5.0, 5.0)]) == 2  # 0.2-0.25: 0.32
    assert duplicate_pairs([(0.0, 0.0), (0.31, 0.0)]) == 0
