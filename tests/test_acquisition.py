"""Autonomous acquisition (daemon/mapping/acquisition.py): the decision depends on the
distance travelled, not on the speed; standing or turning adds nothing; an LRP below the
default background decides at once; the background is the level the LRP settles at."""

from __future__ import annotations

import math

import pytest

from daemon.localisation.acquisition_watch import reference_in_odometry
from daemon.mapping.acquisition import (
    AcquisitionDecision,
    BackgroundMeter,
    PlaceAcquisition,
    taken_over,
)
from daemon.mapping.settings import AcquisitionSettings
from kernel.types import Odometry

SETTINGS = AcquisitionSettings(enabled=True)


def _lrp(distance: float, background: float = 0.76) -> float:
    """A place's LRP falling from 0.95 to its background with distance (1/e at 1 m)."""
    return background + (0.95 - background) * math.exp(-distance)


def _drive(speed_m_s: float, frame_rate_hz: float = 10.0, background: float = 0.76,
           turn_every: int = 0) -> float | None:
    """Drive straight away from the place; the distance at which the decision comes."""
    acq = PlaceAcquisition(SETTINGS)
    acq.reset(7)
    x, t = 0.0, 0
    for i in range(20000):
        t += int(1e9 / frame_rate_hz)
        if not (turn_every and i % turn_every == 0):
            x += speed_m_s / frame_rate_hz
        decision = acq.observe(_lrp(x, background), Odometry(x, 0.0, 0.01 * i, t, i))
        if decision is not None:
            assert decision.place_id == 7
            return decision.distance_m
    return None


def test_decision_depends_on_distance_not_speed() -> None:
    slow, fast = _drive(0.1), _drive(0.6)
    assert slow is not None and fast is not None
    assert abs(slow - fast) <= 2 * SETTINGS.sample_step_m + 0.06
    assert 1.5 < slow < 8.0  # once the LRP has levelled off, not while it falls


def test_standing_and_turning_frames_add_nothing() -> None:
    plain = _drive(0.3)
    with_stops = _drive(0.3, turn_every=2)  # every other frame the robot only turns
    assert plain is not None and with_stops is not None
    assert abs(plain - with_stops) <= 2 * SETTINGS.sample_step_m + 0.03


def test_below_the_default_background_decides_at_once() -> None:
    low = _drive(0.3, background=0.5)
    high = _drive(0.3, background=0.76)
    assert low is not None and high is not None
    assert low < high
    # the LRP crosses 0.7 at ln(0.45 / 0.2) = 0.81 m; the decision follows by a window
    assert low <= math.log(0.45 / 0.2) + SETTINGS.window_m + 0.1


def test_no_decision_without_a_watched_place_or_odometry() -> None:
    acq = PlaceAcquisition(SETTINGS)
    assert acq.observe(0.2, Odometry(0, 0, 0, 0, 0)) is None
    acq.reset(3)
    assert all(acq.observe(0.2, None) is None for _ in range(100))


def test_background_meter_takes_the_settled_median() -> None:
    meter = BackgroundMeter(4, window_m=2.0, skip_m=1.0)
    values = []
    for i in range(1, 100):
        lrp = 0.9 if 0.05 * i < 1.0 else 0.62 + 0.01 * (i % 3)  # not settled in the skip
        v = meter.observe(lrp, Odometry(0.05 * i, 0, 0, i, i))
        if v is not None:
            values.append(v)
            break
    assert values == [pytest.approx(0.63)]


def test_no_decision_nearer_the_place_than_min_distance() -> None:
    """A tour into a doorway and back: 0.5 m out, back past the place, 0.5 m beyond.
    2 m travelled with the LRP at 0.6 all along, but never 0.75 m from the place: no
    decision; on along the way, one as soon as the robot is 0.75 m from it."""
    acq = PlaceAcquisition(SETTINGS)
    acq.reset(9)
    xs = [0.01 * i for i in range(51)] + [0.5 - 0.01 * i for i in range(1, 101)]
    xs += [-0.5 + 0.01 * i for i in range(1, 101)]
    assert all(acq.observe(0.6, Odometry(x, 0.0, 0.0, i, i)) is None
               for i, x in enumerate(xs))
    decision = None
    for i in range(1, 100):
        decision = acq.observe(0.6, Odometry(0.5 + 0.01 * i, 0.0, 0.0, 300 + i, 300 + i))
        if decision is not None:
            break
    assert decision is not None and decision.away_m == pytest.approx(0.75, abs=0.011)
    assert decision.distance_m > 2.0


def test_background_meter_ignores_the_way_back_past_the_place() -> None:
    """The decision came 1.5 m from the place; the tour turns back past it (where its
    LRP is high) and on 4 m beyond: only the frames at least 1.5 m from the place count."""
    origin = Odometry(0.0, 0.0, 0.0, 0, 0)
    meter = BackgroundMeter(4, window_m=2.0, skip_m=0.5, origin=origin,
                            min_away_m=1.5)
    xs = [1.5 + 0.05 * i for i in range(1, 11)]  # on 0.5 m, then back the way it came
    xs += [2.0 - 0.05 * i for i in range(1, 121)]  # ...past the place to x = -4
    value = None
    for i, x in enumerate(xs):
        lrp = 0.95 - 0.1 * abs(x) if abs(x) < 1.5 else 0.64
        value = meter.observe(lrp, Odometry(x, 0.0, 0.0, i, i)) if value is None else value
    assert value == pytest.approx(0.64)
    # Without the origin the view near the place is taken for its background.
    blind = BackgroundMeter(4, window_m=2.0, skip_m=0.5)
    value = None
    for i, x in enumerate(xs):
        lrp = 0.95 - 0.1 * abs(x) if abs(x) < 1.5 else 0.64
        value = blind.observe(lrp, Odometry(x, 0.0, 0.0, i, i)) if value is None else value
    assert value is not None and value > 0.8


def _first_decision(acq: PlaceAcquisition, background: float) -> AcquisitionDecision | None:
    """Drive straight on in 2 cm steps until ``acq`` decides (None: within 40 m it does not)."""
    for i in range(1, 2000):
        x = 0.02 * i
        decision = acq.observe(_lrp(x, background=background), Odometry(x, 0.0, 0.0, i, i))
        if decision is not None:
            return decision
    return None


def test_an_early_decision_estimates_the_background_as_the_places_around() -> None:
    """With backgrounds measured nearby (0.72), the next place is learned while the LRP
    still stands within coverage_margin of them; the LRP there has not settled, so the
    first estimate of the place's background is the measured one, not the LRP."""
    acq = PlaceAcquisition(SETTINGS)
    acq.reset(5, expected_background=0.72)
    decision = _first_decision(acq, background=0.74)
    assert decision is not None and decision.place_id == 5
    assert acq.smoothed_lrp is not None and acq.smoothed_lrp > 0.72
    assert decision.background_lrp == pytest.approx(0.72)
    assert decision.away_m == pytest.approx(decision.distance_m)  # straight on from it
    # Where the LRP has settled (the thesis's rule), the estimate is the LRP itself.
    acq.reset(6)
    decision = _first_decision(acq, background=0.74)
    assert decision is not None and decision.place_id == 6
    assert decision.background_lrp == pytest.approx(acq.smoothed_lrp)
    assert decision.background_lrp == pytest.approx(0.74, abs=0.02)


def test_a_known_place_is_taken_over_only_if_it_would_be_kept() -> None:
    """Back on a known path, the decision watches the known place standing highest above
    its background instead of learning — only if it stands by the coverage margin too:
    below it, the place would be left again as soon as the robot is min_distance_m on."""
    assert SETTINGS.coverage_margin > SETTINGS.recognition_margin
    between = (SETTINGS.coverage_margin + SETTINGS.recognition_margin) / 2
    assert taken_over({3: between, 4: between - 0.01}, SETTINGS) is None
    assert taken_over({3: between, 4: SETTINGS.coverage_margin + 0.01}, SETTINGS) == 4
    assert taken_over({}, SETTINGS) is None
    thesis = AcquisitionSettings(enabled=True, coverage_margin=0.0)  # the thesis's rule
    assert taken_over({3: between, 4: between - 0.01}, thesis) == 3


def test_a_place_the_map_puts_far_is_taken_over_only_when_certain() -> None:
    """Outside the places the map puts near the estimate, a look-alike is no path back —
    but a place standing ``certain_lead`` above its background is where the robot is,
    whatever the map's drift says (office 1 learned a place 0.06 m from one at a lead
    of 0.22 that a long chain of transitions put far away)."""
    strong = SETTINGS.coverage_margin + 0.01
    assert taken_over({3: strong}, SETTINGS, near={4}) is None
    assert taken_over({3: strong, 4: strong - 0.005}, SETTINGS, near={4}) == 4
    assert taken_over({3: SETTINGS.certain_lead, 4: strong}, SETTINGS, near={4}) == 3
    assert taken_over({3: strong}, SETTINGS, near=None) == 3  # not tracking: no map to go by


def test_the_early_decision_follows_the_lrp_here_not_half_a_window_behind() -> None:
    """An LRP falling to its background over 0.7 m (1/e) crosses the coverage margin at
    0.7 ln(0.21 / 0.08) = 0.68 m: the decision comes as min_distance_m allows (0.75 m).
    The thesis's 0.5 m average, 0.25 m behind, crosses it only at 0.94 m."""
    def lrp(x: float) -> float:
        return 0.74 + 0.21 * math.exp(-x / 0.7)

    def decide(settings: AcquisitionSettings) -> float | None:
        acq = PlaceAcquisition(settings)
        acq.reset(5, expected_background=0.74)
        for i in range(1, 500):
            x = 0.01 * i
            decision = acq.observe(lrp(x), Odometry(x, 0.0, 0.0, i, i))
            if decision is not None:
                return decision.distance_m
        return None

    here = decide(SETTINGS)
    assert here is not None and here <= SETTINGS.min_distance_m + 2 * SETTINGS.sample_step_m
    lagging = decide(AcquisitionSettings(enabled=True, coverage_window_m=SETTINGS.window_m))
    assert lagging is not None and lagging >= 0.9


def test_a_watch_begun_past_the_place_counts_from_its_reference() -> None:
    """A restart resumed 0.7 m past place 5 (its reference at x = 0): given where the
    reference stands, the distances count from it and the coverage rule needs only its
    own short window — the decision comes at the distance it would have come at had the
    place been watched all along (here min_distance_m, 0.75 m), where counting from the
    restart waited for min_distance_m more and a full window (1.45 m)."""
    def lrp(x: float) -> float:
        return 0.74 + 0.21 * math.exp(-x / 0.7)

    def decide(reference: Odometry | None) -> tuple[float, float] | None:
        acq = PlaceAcquisition(SETTINGS)
        acq.reset(5, expected_background=0.74, reference=reference)
        for i in range(70, 500):
            x = 0.01 * i
            decision = acq.observe(lrp(x), Odometry(x, 0.0, 0.0, i, i))
            if decision is not None:
                return x, decision.away_m
        return None

    seeded = decide(Odometry(0.0, 0.0, 0.0, 0, 0))
    assert seeded is not None
    at, away = seeded
    assert SETTINGS.min_distance_m <= at <= SETTINGS.min_distance_m + 0.2
    assert away == pytest.approx(at, abs=0.01)  # from the reference, not the restart
    unseeded = decide(None)
    assert unseeded is not None and unseeded[0] >= 0.7 + SETTINGS.min_distance_m


def test_the_reference_in_the_odometry_frame_is_behind_the_robot_by_its_estimate() -> None:
    # Robot at odometry (2, 1) heading +y, 0.5 m ahead of the place's reference along
    # its heading and turned 90 degrees from it: the reference is 0.5 m behind, at (2, 0.5),
    # and the place's x axis points along odometry +x.
    ref = reference_in_odometry(Odometry(2.0, 1.0, math.pi / 2, 7, 3), (0.0, 0.5, math.pi / 2))
    assert (ref.x, ref.y) == (pytest.approx(2.0), pytest.approx(0.5))
    assert ref.yaw == pytest.approx(0.0, abs=1e-12) and (ref.stamp_ns, ref.seq) == (7, 3)
