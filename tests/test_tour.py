"""Tours (hal/sim/tour.py): through every room, clear of walls by the asked clearance
(checked against the wall geometry itself, not the planner's grid), deterministic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.sim.scenario import scenario_from_dict
from hal.sim.tour import close_lap, plan_tour
from hal.sim.world import World, load_world


def _wall_distance(world: World, points: np.ndarray) -> np.ndarray:
    """Distance from each (x, y) to the nearest wall or obstacle segment."""
    best = np.full(len(points), np.inf)
    for wall in world.walls:
        for (ax, ay), (bx, by) in wall.segments():
            a, b = np.array([ax, ay]), np.array([bx, by])
            ab = b - a
            t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


def _along(waypoints: list[tuple[float, float]], step: float = 0.02) -> np.ndarray:
    out = []
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        n = max(2, int(math.dist(a, b) / step) + 1)
        out.append(np.linspace(a, b, n))
    return np.concatenate(out)


@pytest.mark.parametrize("spec", ["generate:office:1", "generate:corridor:2",
                                  "generate:open-room:3"])
def test_tour_keeps_its_clearance_and_returns(spec: str) -> None:
    world = load_world(spec)
    tour = plan_tour(world, clearance=0.4)
    assert tour == plan_tour(world, clearance=0.4)  # deterministic
    assert _wall_distance(world, _along(tour)).min() >= 0.4
    assert math.dist(tour[0], world.start_pose[:2]) < 0.05
    assert math.dist(tour[-1], world.start_pose[:2]) < 0.05
    assert max(math.dist(a, b) for a, b in zip(tour[:-1], tour[1:], strict=True)) <= 0.51


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_tour_cut_short_comes_back_round_the_walls(seed: int) -> None:
    """The endurance experiment's ``--waypoints N``: the first N waypoints, then back to
    the first one; laps of it repeated. Cut from the office tour, the straight line from
    the 120th waypoint to the start crosses walls (16 m on office 2); the lap keeps the
    tour's clearance all the way round, the step into the next lap included."""
    world = load_world(f"generate:office:{seed}")
    cut = plan_tour(world, clearance=0.4)[:120]
    lap = close_lap(world, cut, clearance=0.4)
    assert lap[:120] == cut and lap == close_lap(world, cut, clearance=0.4)
    laps = [*lap, *lap]
    assert _wall_distance(world, _along(laps)).min() >= 0.4
    assert max(math.dist(a, b) for a, b in zip(laps[:-1], laps[1:], strict=True)) <= 0.51
    if seed == 2:  # what closing the lap is for: the straight way back runs into walls
        assert _wall_distance(world, _along([cut[-1], cut[0]])).min() < 0.05


def test_office_tour_enters_every_room() -> None:
    world = load_world("generate:office:1")
    points = _along(plan_tour(world))
    # Rooms of the generated office: 5 of 6 x 9 m on each side of the corridor y in [9, 11].
    for i in range(5):
        for y0, y1 in ((0.0, 9.0), (11.0, 20.0)):
            inside = ((points[:, 0] > i * 6 + 1) & (points[:, 0] < i * 6 + 5)
                      & (points[:, 1] > y0 + 1) & (points[:, 1] < y1 - 1))
            assert inside.any(), f"room {i} at y {y0}..{y1} not visited"


def test_corridor_tour_reaches_both_ends() -> None:
    points = _along(plan_tour(load_world("generate:corridor:1")))
    assert points[:, 0].min() < 3.5 and points[:, 0].max() > 26.5


def test_scenario_tour_kind_with_laps() -> None:
    one = scenario_from_dict({"world": "generate:open-room:1",
                              "trajectory": {"kind": "tour", "speed": 0.4}})
    two = scenario_from_dict({"world": "generate:open-room:1",
                              "trajectory": {"kind": "tour", "laps": 2, "speed": 0.4}})
    assert len(two.waypoints) == 2 * len(one.waypoints)
    assert all(w.speed == 0.4 for w in one.waypoints)
