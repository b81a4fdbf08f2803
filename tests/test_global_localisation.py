"""The global search and loss detection (daemon/localisation/global_localisation.py) on
crafted recognition scores."""

from __future__ import annotations

from daemon.localisation.belief import PlaceScore
from daemon.localisation.global_localisation import (
    LeadWatch,
    LossDetector,
    PlaceSearch,
    faded,
)
from daemon.localisation.settings import LocalisationSettings

PLACES = list(range(1, 51))


def _lead(place: int, true_place: int) -> float:
    return 0.25 if place == true_place else 0.01 * (place % 3)


def test_every_place_is_recognised_within_its_budget_then_the_best_is_named() -> None:
    search = PlaceSearch(LocalisationSettings(search_places_per_frame=12))
    search.reset(0)
    seen: set[int] = set()
    for frame in range(5):
        chosen = search.to_score(PLACES, first=(7,))
        assert len(chosen) <= 12 and chosen[0] == 7
        assert search.best(PLACES) is None  # not before every place has been looked at
        search.observe([PlaceScore(p, 0.7, _lead(p, 33)) for p in chosen])
        seen |= set(chosen)
        if frame < 4:
            assert len(seen) == min(50, 1 + 11 * (frame + 1))
    assert seen == set(PLACES)  # 1 + 11 x 5 >= 50: nothing left out
    best = search.best(PLACES)
    assert best is not None and best.place_id == 33
    # Once covered, the budget goes to the best so far again.
    assert 33 in search.to_score(PLACES)


def test_no_place_is_named_below_the_minimum_lead_and_rejected_ones_come_last() -> None:
    s = LocalisationSettings(search_places_per_frame=100, search_min_lead=0.05)
    search = PlaceSearch(s)
    search.reset(0)
    search.observe([PlaceScore(p, 0.7, 0.02) for p in PLACES])
    assert search.best(PLACES) is None
    search.reset(0, rejected={4})
    search.observe([PlaceScore(p, 0.7, {4: 0.3, 9: 0.1}.get(p, 0.0)) for p in PLACES])
    assert search.best(PLACES).place_id == 9  # type: ignore[union-attr]
    search.reset(0, rejected={4})
    search.observe([PlaceScore(p, 0.7, 0.3 if p == 4 else 0.0) for p in PLACES])
    assert search.best(PLACES).place_id == 4  # type: ignore[union-attr]  # nothing else


def test_a_place_clearly_ahead_of_the_current_one_is_a_kidnap() -> None:
    search = PlaceSearch(LocalisationSettings(search_places_per_frame=100, search_margin=0.05))
    search.reset(0)
    search.observe([PlaceScore(p, 0.7, {2: 0.20, 5: 0.24}.get(p, 0.0)) for p in PLACES])
    assert search.leader_over(2, PLACES) is None  # 0.04 ahead: not clearly
    search.observe([PlaceScore(5, 0.8, 0.30)])
    leader = search.leader_over(2, PLACES)
    assert leader is not None and leader.place_id == 5
    assert search.leader_over(5, PLACES) is None


def test_a_pose_found_again_yields_to_any_place_ranked_above_it() -> None:
    """Recovery's found pose (design §9) asks leader_over with recovered_margin 0: any
    lead at all, not the kidnap's 0.05, and none while the current place is level."""
    search = PlaceSearch(LocalisationSettings(search_places_per_frame=100))
    search.reset(0)
    search.observe([PlaceScore(p, 0.7, {2: 0.20, 5: 0.21}.get(p, 0.0)) for p in PLACES])
    assert search.leader_over(2, PLACES) is None  # not a kidnap's lead
    ahead = search.leader_over(2, PLACES, margin=0.0)
    assert ahead is not None and ahead.place_id == 5
    search.observe([PlaceScore(2, 0.7, 0.21)])
    assert search.leader_over(2, PLACES, margin=0.0) is None  # level: the found pose stands


def test_a_place_leading_the_search_three_frames_in_a_row_is_a_loss() -> None:
    """Tracking (design §9): the background search's leader by search_margin, three
    search frames in a row; a frame without the search, or level, breaks the run."""
    search = PlaceSearch(LocalisationSettings(search_places_per_frame=100))
    watch = LeadWatch(LocalisationSettings(led_frames=3, search_margin=0.05))
    search.reset(0)

    def frame(lead_of_5: float, searched: bool = True) -> bool:
        search.observe([PlaceScore(p, 0.7, {2: 0.10, 5: lead_of_5}.get(p, 0.0))
                        for p in PLACES])
        return watch.observe(search, 2, PLACES, searched)

    assert [frame(0.2), frame(0.2), frame(0.2, searched=False)] == [False] * 3
    assert [frame(0.2), frame(0.14)] == [False, False]  # 0.04 ahead: not a lead
    assert [frame(0.2), frame(0.2), frame(0.2)] == [False, False, True]
    watch.reset()
    never = LeadWatch(LocalisationSettings(led_frames=0))
    assert not any(never.observe(search, 2, PLACES, True) for _ in range(10))


def test_a_neighbour_leading_the_search_is_no_loss() -> None:
    """A place joined to the current one by a transition leading it is left to the
    switcher (§8.2); a place beyond it leading is still a loss, with the neighbour
    ahead of it too."""
    search = PlaceSearch(LocalisationSettings(search_places_per_frame=100))
    watch = LeadWatch(LocalisationSettings(led_frames=3, search_margin=0.05))
    search.reset(0)
    leads = {2: 0.10, 5: 0.30}
    search.observe([PlaceScore(p, 0.7, leads.get(p, 0.0)) for p in PLACES])
    assert not any(watch.observe(search, 2, PLACES, True, neighbours=(5,))
                   for _ in range(5))
    leads[3] = 0.20  # a place two on leads too (office 2: tracked in a place it had left)
    search.observe([PlaceScore(p, 0.7, leads.get(p, 0.0)) for p in PLACES])
    assert [watch.observe(search, 2, PLACES, True, neighbours=(5,))
            for _ in range(3)] == [False, False, True]


def test_a_loss_is_declared_on_the_fifth_low_frame_in_a_row() -> None:
    loss = LossDetector(LocalisationSettings(loss_output=0.15, loss_frames=5))
    assert [loss.observe(c) for c in (0.1, 0.1, 0.5, 0.1, 0.1, 0.1, 0.1)] == [False] * 7
    assert loss.suspicious
    assert loss.observe(0.149) is True
    assert loss.observe(0.1) is False  # declared once
    loss.reset()
    assert not loss.suspicious


def test_no_usable_landmark_is_no_evidence_of_a_loss() -> None:
    loss = LossDetector(LocalisationSettings(loss_output=0.15, loss_frames=2))
    assert loss.observe(0.1) is False
    assert loss.observe(float("nan")) is False and loss.low_frames == 1
    assert loss.observe(0.1) is True


def test_travel_with_no_evidence_at_all_is_a_loss_of_its_own() -> None:
    """Issue 31: odometry alone, far from the place (NaN output every frame), was
    published ``tracking`` for ever, 11 m off after a kidnap. ``blind_m`` of travel with
    NaN frames only is a loss; a frame with evidence starts the count again; standing
    still adds nothing."""
    nan = float("nan")
    loss = LossDetector(LocalisationSettings(loss_frames=5, blind_m=1.0))
    assert [loss.observe(nan, 0.3) for _ in range(3)] == [False] * 3  # 0.9 m
    assert loss.observe(0.6, 0.3) is False and loss.blind_m == 0.0  # evidence: again
    assert [loss.observe(nan, d) for d in (0.5, 0.0, 0.0, 0.45)] == [False] * 4
    assert loss.observe(nan, 0.1) is True and "no evidence over 1.0 m" in loss.why
    assert loss.blind  # nothing contradicted: the odometry run from the last place stands
    assert loss.observe(nan, 0.3) is False  # declared once
    never = LossDetector(LocalisationSettings(blind_m=0.0))
    assert not any(never.observe(nan, 1.0) for _ in range(100))


def test_a_loss_whose_output_only_faded_is_told_from_a_view_replaced() -> None:
    """Driving out of a place's range the output fades through loss_output and stays
    above doubt_output (office 3: 0.07-0.14); a robot carried off gives 0.00-0.02 at
    once. A run of low frames with one such frame in it is not a fade."""
    s = LocalisationSettings(loss_output=0.15, loss_frames=3, doubt_output=0.05)
    assert faded(0.07, s) and faded(0.05, s) and not faded(0.049, s)
    loss = LossDetector(s)
    assert [loss.observe(v) for v in (0.3, 0.14, 0.09, 0.07)] == [False] * 3 + [True]
    assert loss.faded and not loss.blind
    kidnapped = LossDetector(s)
    assert [kidnapped.observe(v) for v in (0.5, 0.0, 0.01, 0.02)] == [False] * 3 + [True]
    assert not kidnapped.faded
    # a contradicting frame of an earlier run of low frames does not count
    mixed = LossDetector(s)
    assert [mixed.observe(v) for v in (0.01, 0.4, 0.1, 0.1, 0.12)] == [False] * 4 + [True]
    assert mixed.faded
    dipped = LossDetector(s)
    assert [dipped.observe(v) for v in (0.12, 0.02, 0.1)] == [False, False, True]
    assert not dipped.faded


def test_the_reason_of_a_loss_names_its_rule() -> None:
    loss = LossDetector(LocalisationSettings(loss_output=0.15, loss_frames=2))
    assert [loss.observe(v) for v in (0.1, 0.1)] == [False, True]
    assert loss.why == "sensor output below 0.15 for 2 frames" and not loss.blind


def test_with_a_cue_the_active_set_is_searched_best_first_and_decides() -> None:
    s = LocalisationSettings(search_places_per_frame=5, cue_margin=0.05)
    search = PlaceSearch(s)
    search.reset(0)
    cue = {p: 0.9 - 0.01 * abs(p - 20) for p in PLACES}  # best at 20; 16..24 within 0.05
    search.set_cue(cue, always=(3,))
    assert search.active == set(range(15, 26)) | {3}
    chosen = search.to_score(PLACES, first=(3,))
    assert chosen == [3, 20, 19, 21, 18]  # the current place, then best cue first
    search.observe([PlaceScore(p, 0.7, 0.2 if p == 21 else 0.0) for p in chosen])
    assert search.best(PLACES) is None  # 15..25 not all recognised yet
    for _ in range(2):
        search.observe([PlaceScore(p, 0.7, 0.2 if p == 21 else 0.0)
                        for p in search.to_score(PLACES, first=(3,))])
    assert search.covered(PLACES) and not all(p in search.scores for p in PLACES)
    assert search.best(PLACES).place_id == 21  # type: ignore[union-attr]


def test_the_local_space_set_narrows_the_cue_set_but_keeps_places_without_a_profile(
        ) -> None:
    """Thesis §9.4.1 (design §4): of the cue's places only those whose local space
    matches within the margin of the best stay; one with no profile is not ruled out, and
    the current place stays whatever its match."""
    search = PlaceSearch(LocalisationSettings(cue_margin=0.05, local_space_margin=0.075))
    search.reset(0)
    cue = {p: 0.9 - 0.01 * abs(p - 20) for p in PLACES}  # 15..25 within the margin
    local = {p: 0.95 - 0.02 * abs(p - 18) for p in PLACES if p != 24}  # 15..21 within
    search.set_cue(cue, always=(3,), local=local)
    assert search.active == set(range(15, 22)) | {24, 3}
    search.set_cue(cue, always=(3,), local={})  # no profile at all: the cue alone
    assert search.active == set(range(15, 26)) | {3}
