"""Which place to position in (design §8) and closing a cycle (§6, thesis §7.1.3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.localisation.belief import PlaceScore
from daemon.localisation.place_switching import (
    CycleClosure,
    PlaceSwitcher,
    Switch,
    beyond,
    carried_over,
    nearest_place,
    places_near,
)
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.odometry_chain import OdometryChain
from daemon.mapping.settings import OdometryNoiseSettings
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry

S = LocalisationSettings()


def scores(**leads: float) -> list[PlaceScore]:
    return [PlaceScore(int(k[1:]), 0.7 + v, v) for k, v in leads.items()]


def test_a_neighbour_whose_recognition_rises_above_takes_over() -> None:
    sw = PlaceSwitcher(S)
    # §8.2: the neighbour leads by the margin and the estimate is no nearer here.
    assert sw.decide(1, [2], scores(p1=0.10, p2=0.13), {1: 1.0, 2: 0.9}).place_id == 2
    # Within the margin: stay.
    assert sw.decide(1, [2], scores(p1=0.10, p2=0.11), {1: 1.0, 2: 0.9}) is None


def test_a_place_recognised_everywhere_does_not_pull_the_estimate_back() -> None:
    sw = PlaceSwitcher(S)
    # Place 1's LRP stays high all along a corridor; the robot is nearer place 2's reference.
    assert sw.decide(2, [1], scores(p1=0.13, p2=0.05), {2: 0.3, 1: 1.0}) is None


def test_hand_over_to_the_nearer_neighbour_recognised_nearly_as_well() -> None:
    sw = PlaceSwitcher(S)
    assert sw.decide(1, [2], scores(p1=0.10, p2=0.02), {1: 2.0, 2: 0.9}).place_id == 2
    # Not if it is not recognised nearly as well, or not nearer by handover_m and at most
    # handover_ratio (half) of the current place's distance.
    assert sw.decide(1, [2], scores(p1=0.10, p2=-0.05), {1: 2.0, 2: 0.9}) is None
    assert sw.decide(1, [2], scores(p1=0.10, p2=0.05), {1: 1.6, 2: 1.3}) is None


def test_a_place_without_transition_needs_a_streak_and_a_clear_lead() -> None:
    sw = PlaceSwitcher(S)
    strong = scores(p4=0.0, p3=0.01, p1=0.25)
    assert sw.decide(4, [3], strong) is None
    assert sw.decide(4, [3], strong) is None
    switch = sw.decide(4, [3], strong)
    assert switch is not None and switch.kind == "cycle" and switch.place_id == 1
    # Leading, but not standing cycle_min_lead above its own background: never.
    weak = scores(p4=-0.02, p3=-0.05, p1=0.13)
    assert all(sw.decide(4, [3], weak) is None for _ in range(5))


def test_a_place_the_map_puts_far_from_the_estimate_never_starts_a_streak() -> None:
    """Office 5: tracked 0.01 m off in a place, the robot was handed over to a look-alike
    the map's transitions put 9 m away. Place 1 is 9 m off by the graph (drift 0.2 m),
    place 5 2 m off: only place 5's lead counts; place 6, which no path reaches, is not
    ruled out."""
    through = {3: UncertainSE2(SE2(1.0, 0.0, 0.0), np.diag([1e-4, 1e-4, 1e-4])),
               1: UncertainSE2(SE2(9.0, 0.0, 0.0), np.diag([0.01, 0.01, 1e-3])),
               5: UncertainSE2(SE2(0.0, 2.0, 0.0), np.diag([0.01, 0.01, 1e-3]))}
    far = beyond(4, (0.0, 0.0, 0.0), through, S.cycle_within_m)
    assert far == {1}
    assert beyond(4, (0.0, 0.0, 0.0), through, 0.0) == set()  # 0: no limit
    sw = PlaceSwitcher(S)
    assert all(sw.decide(4, [3], scores(p4=0.0, p3=0.01, p1=0.25), far=far) is None
               for _ in range(5))
    for leader in (5, 6):
        sw = PlaceSwitcher(S)
        strong = scores(p4=0.0, p3=0.01, p1=0.25, **{f"p{leader}": 0.3})
        switches = [sw.decide(4, [3], strong, far=far) for _ in range(S.cycle_checks)]
        assert switches[-1] is not None and switches[-1].place_id == leader


def test_a_switch_to_a_place_the_graph_reaches_carries_the_estimate() -> None:
    through = {3: UncertainSE2(SE2(1.0, 0.0, 0.0), np.diag([1e-4, 1e-4, 1e-4])),
               7: UncertainSE2(SE2(2.0, 0.5, 0.0), np.diag([0.01, 0.01, 1e-3]))}
    assert carried_over(Switch("neighbour", 3), through)
    assert carried_over(Switch("graph", 7), through)
    assert carried_over(Switch("cycle", 7), through)  # a streak's lead, the graph reaches it
    assert not carried_over(Switch("cycle", 9), through)  # no path: from its reference


def test_other_places_are_tried_in_turn() -> None:
    sw = PlaceSwitcher(LocalisationSettings(others_per_check=2))
    seen = set()
    for _ in range(3):
        checked = sw.to_check(1, [2], [1, 2, 3, 4, 5, 6])
        assert checked[:2] == [1, 2] and len(checked) == 4
        seen |= set(checked[2:])
    assert seen == {3, 4, 5, 6}


def test_cycle_closure_composes_estimates_and_odometry() -> None:
    """T_from_to = T_from_robot(switch) ∘ odometry ∘ T_to_robot(now)⁻¹, once reliable."""
    T_from_to_true = SE2(4.0, 1.0, 0.5)
    at_switch = SE2(3.0, 0.5, 0.2)  # robot in the old place when it switched
    moved = SE2(0.8, 0.1, 0.1)  # odometry meanwhile
    robot_now_in_old = at_switch.compose(moved)
    robot_now_in_new = T_from_to_true.inverse().compose(robot_now_in_old)
    chain = OdometryChain(Odometry(0.0, 0.0, 0.0, 0, 0), OdometryNoiseSettings())
    for k in range(1, 11):  # the motion in 10 steps
        f = k / 10
        step = SE2(moved.x * f, moved.y * f, moved.yaw * f)
        chain.add(Odometry(step.x, step.y, step.yaw, k * 50_000_000, k))
    closure = CycleClosure(5, 1, UncertainSE2(at_switch, np.diag([1e-4, 1e-4, 1e-5])), chain,
                           LocalisationSettings(reliable_frames=3))
    now = UncertainSE2(robot_now_in_new, np.diag([4e-4, 4e-4, 1e-4]))
    assert closure.observe(now, 0.9) is None and closure.observe(now, 0.9) is None
    assert closure.observe(now, 0.2) is None  # not confident: the count starts again
    for _ in range(2):
        assert closure.observe(now, 0.9) is None
    t = closure.observe(now, 0.9)
    assert t is not None and (t.from_id, t.to_id, t.source) == (5, 1, "cycle")
    m = t.T_from_to.mean
    assert (m.x, m.y) == pytest.approx((4.0, 1.0), abs=1e-6)
    assert m.yaw == pytest.approx(0.5, abs=1e-6)
    assert np.all(np.linalg.eigvalsh(t.T_from_to.covariance) > 0)


def test_fusing_two_estimates_weighs_by_information() -> None:
    a = UncertainSE2(SE2(1.0, 0.0, math.pi - 0.01), np.diag([0.01, 0.01, 0.01]))
    b = UncertainSE2(SE2(1.2, 0.0, -math.pi + 0.01), np.diag([0.01, 0.01, 0.01]) / 4)
    f = a.fuse(b)
    assert f.mean.x == pytest.approx(1.0 + 0.2 * 4 / 5)
    assert abs(math.remainder(f.mean.yaw - math.pi, 2 * math.pi)) < 0.01  # across ±π
    assert f.covariance[0, 0] == pytest.approx(0.01 / 5)


def test_coming_round_a_loop_closes_the_cycle_at_once() -> None:
    """The graph puts place 1 within cycle_near_m (through the sum round the loop) and it
    is recognised above the current place and its neighbours: no streak needed."""
    sw = PlaceSwitcher(S)
    switch = sw.decide(5, [4], scores(p5=0.05, p4=0.0, p1=0.10), {5: 0.9, 4: 1.6, 1: 0.6})
    assert switch is not None and (switch.kind, switch.place_id) == ("cycle", 1)
    # Far by the graph, or not recognised above: the streak rule alone applies.
    assert sw.decide(5, [4], scores(p5=0.05, p4=0.0, p1=0.10), {5: 0.9, 4: 1.6, 1: 2.5}) \
        is None
    assert sw.decide(5, [4], scores(p5=0.09, p4=0.0, p1=0.10), {5: 0.9, 4: 1.6, 1: 0.6}) \
        is None


def test_a_place_the_graph_puts_near_is_checked_every_time_and_handed_over_to() -> None:
    sw = PlaceSwitcher(LocalisationSettings(others_per_check=1))
    known = list(range(1, 11))
    for _ in range(5):  # in every check, whatever the rotation through the others
        assert 7 in sw.to_check(1, [2], known, near=[7])
    # Nearer by the graph (0.4 m against 0.9 m: handover_m, no ratio for a place met
    # again) and recognised nearly as well: through the graph's path, since there is no
    # transition 1 -> 7.
    switch = sw.decide(1, [2], scores(p1=0.10, p2=0.0, p7=0.05), {1: 0.9, 2: 1.4, 7: 0.4},
                       near=[7])
    assert switch is not None and (switch.kind, switch.place_id) == ("graph", 7)
    # Not when the graph does not put it near (it is not in ``near``).
    assert sw.decide(1, [2], scores(p1=0.10, p2=0.0, p7=0.05), {1: 0.9, 2: 1.4, 7: 0.4}
                     ) is None


def test_acquisition_takes_back_only_places_the_map_puts_near_the_estimate() -> None:
    """A corridor of places 1 m apart: from an estimate 0.5 m past place 1, places 0-3
    are within 3 m through the chain of transitions, and the far end (a look-alike of
    place 1 in an aliased corridor) is not; a path's drift widens the gate."""
    step = UncertainSE2(SE2(1.0, 0.0, 0.0), np.diag([1e-4, 1e-4, 1e-6]))
    through = {0: step.inverse()}  # T_1_p: place 0 behind place 1, 2-19 ahead
    here = UncertainSE2(SE2(), np.zeros((3, 3)))
    for pid in range(2, 20):
        here = here.compose(step)
        through[pid] = here
    assert places_near(1, (0.5, 0.0, 0.0), through, within_m=3.0) == {0, 1, 2, 3, 4}
    # Beyond the gate ahead, the same chain with a drift of 2 m (1 sigma) at place 6.
    loose = dict(through)
    loose[6] = UncertainSE2(through[6].mean, np.diag([2.0, 2.0, 0.01]))
    assert 6 in places_near(1, (0.5, 0.0, 0.0), loose, within_m=3.0)
    # The current place itself only while the estimate is within the gate of it.
    assert 1 not in places_near(1, (4.0, 0.0, 0.0), through, within_m=3.0)


def test_the_place_nearest_an_estimate_by_the_map() -> None:
    """Acquisition learns no place nearer than min_distance_m to a known one: the
    nearest by the map's transitions is found whichever place the estimate is in."""
    step = UncertainSE2(SE2(1.0, 0.0, 0.0), np.diag([1e-4, 1e-4, 1e-6]))
    through = {0: step.inverse(), 2: step, 3: step.compose(step)}  # T_1_p: 0, (1), 2, 3

    def nearest(pose: tuple[float, float, float], links: dict[int, UncertainSE2],
                current: int = 1, exclude: int | None = None) -> tuple[int, float] | None:
        found = nearest_place(current, pose, links, exclude)
        return None if found is None else (found[0], round(found[1], 6))

    assert nearest((0.2, 0.1, 0.0), through) == (1, round(math.hypot(0.2, 0.1), 6))
    assert nearest((1.3, 0.0, 0.0), through) == (2, 0.3)  # place 2 at 1 m, 3 at 2 m
    assert nearest((1.8, 0.0, 0.0), through) == (3, 0.2)
    assert nearest((-0.6, 0.0, 0.0), through) == (0, 0.4)
    assert nearest((0.0, 0.0, 0.0), {}) == (1, 0.0)
    # The watched place left out: odometry has already put the robot far enough from it.
    assert nearest((0.2, 0.1, 0.0), through, exclude=1) == (2, round(math.hypot(0.8, 0.1), 6))
    assert nearest((0.1, 0.0, 0.0), {1: step.inverse()}, current=2, exclude=2) == (1, 1.1)
    assert nearest((0.0, 0.0, 0.0), {}, exclude=1) is None
