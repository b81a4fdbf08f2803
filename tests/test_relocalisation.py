"""The relocalisation state machine (daemon/localisation/relocalisation.py, design §9):
its decision rules on crafted inputs, and the machine driven through a loss, the two
recovery steps of §9.3.2 and the global step, with crafted search scores."""

from __future__ import annotations

from daemon.localisation.belief import PlaceScore
from daemon.localisation.relocalisation import (
    Relocalisation,
    after_confirming,
    after_recovering,
    after_tracking,
    contradicted,
    left_view,
    loss_contradicts,
)
from daemon.localisation.settings import LocalisationSettings

S = LocalisationSettings()


def test_tracking_ends_on_a_loss_or_a_leader_only() -> None:
    assert after_tracking(lost_now=False, led=False) == "track"
    assert after_tracking(lost_now=True, led=False) == "lost"
    assert after_tracking(lost_now=False, led=True) == "lost"


def test_a_chosen_place_is_confirmed_by_a_reliable_estimate_or_rejected() -> None:
    assert after_confirming(True, False, 1, S) == "relocalised"
    assert after_confirming(True, True, S.confirm_frames, S) == "relocalised"  # found wins
    assert after_confirming(False, False, S.confirm_frames - 1, S) == "wait"
    assert after_confirming(False, False, S.confirm_frames, S) == "reject"
    assert after_confirming(False, True, 1, S) == "reject"  # lost while confirming


def test_recovery_steps_go_in_the_order_of_9_3_2() -> None:
    assert after_recovering(True, 7, 1, 0, S) == "found"  # found first, leader or not
    assert after_recovering(False, 7, 1, 0, S) == "leader"  # a clear leader: go there
    assert after_recovering(False, None, 1, S.recovery_frames - 1, S) == "wait"
    assert after_recovering(False, None, 1, S.recovery_frames, S) == "next step"
    assert after_recovering(False, None, 2, S.recovery_frames, S) == "global"


def test_a_frame_whose_view_contradicts_the_estimate_is_not_tracking() -> None:
    # Office 1's endurance run: kidnapped frames gave 0.000-0.013, tracked ones 0.11 up.
    assert contradicted(0.007, 0.6, S)  # confident in the few it sees, but carried off
    assert not contradicted(0.11, 0.4, S)
    assert contradicted(0.5, 0.0, S)  # no landmark seen agrees: confidence 0
    assert not contradicted(None, 0.3, S)  # too few usable landmarks: no evidence
    # A frame that switched places: the output is the left place's; confidence 0 is
    # still never published tracking.
    assert contradicted(0.5, 0.0, S, switched=True)
    assert not contradicted(0.007, 0.6, S, switched=True)


class Scripted:
    """The localiser's side (relocalisation.Trackers) with crafted search scores."""

    def __init__(self, machine: Relocalisation, leads: dict[int, float]) -> None:
        self.machine, self.leads = machine, leads
        self.calls: list[tuple[str, int]] = []

    def search_step(self, places: list[int], first: tuple[int, ...]) -> list[PlaceScore]:
        scored = [PlaceScore(p, 0.7 + self.leads.get(p, 0.0), self.leads.get(p, 0.0))
                  for p in self.machine.search.to_score(places, first)]
        self.machine.search.observe(scored)
        return scored

    def tell_apart(self, best: int, places: list[int], at_once: bool = False) -> int | None:
        return best  # no look-alikes

    def start_in(self, place_id: int) -> None:
        self.calls.append(("start_in", place_id))

    def spread(self, step: int) -> None:
        self.calls.append(("spread", step))

    def lost(self, left: bool) -> None:
        self.calls.append(("lost", int(left)))


def _frames(machine: Relocalisation, t: Scripted, n: int, support: float, found: bool,
            places: list[int], current: int, first_frame: int) -> list:
    events = []
    for k in range(n):
        out = machine.supervise(t, places, (), current, support, found, 0.05,
                                (first_frame + k) * 100_000_000, first_frame + k)
        events.append(out.event)
    return events


def test_a_loss_goes_through_both_recovery_steps_then_to_the_best_place_elsewhere() -> None:
    places = [1, 2, 3]
    machine = Relocalisation(S)
    machine.told(0, 0, None)  # the operator set the pose in place 1
    assert machine.mode == "track"
    # Place 2 stands above its background, but never ahead of place 1 by search_margin.
    t = Scripted(machine, {1: 0.2, 2: 0.2 + S.search_margin / 2, 3: -0.3})
    events = _frames(machine, t, S.loss_frames, 0.01, False, places, 1, 1)
    assert [e is not None for e in events] == [False] * (S.loss_frames - 1) + [True]
    lost = events[-1]
    assert lost.kind == "lost" and lost.place_id == 1 and "sensor output" in lost.how
    assert lost.contradicted  # the view said no: maybe carried off
    assert machine.mode == "recover" and machine.step == 1
    assert t.calls == [("lost", 0), ("spread", 1)]  # no bridge from before a carry
    _frames(machine, t, S.recovery_frames, 0.01, False, places, 1, 10)
    assert machine.step == 2 and t.calls[-1] == ("spread", 2)
    _frames(machine, t, S.recovery_frames, 0.01, False, places, 1, 20)
    assert t.calls[-1] == ("start_in", 2)  # step 3: the most likely place but this one
    assert machine.mode == "confirm"
    events = _frames(machine, t, 1, 0.6, True, places, 2, 30)
    assert events[0].kind == "relocalised" and events[0].how == "global"
    # From the loss (frame 5) to the confirmation, by stamps and frames.
    assert events[0].frames == 30 - S.loss_frames and machine.mode == "track"


def test_a_clear_leader_sends_a_loss_straight_to_it() -> None:
    places = [1, 2, 3]
    machine = Relocalisation(S)
    machine.told(0, 0, None)
    t = Scripted(machine, {1: -0.2, 2: 0.3, 3: -0.3})
    events = [e for e in _frames(machine, t, S.loss_frames, 0.01, False, places, 1, 1) if e]
    # The search ran from the first low frame; place 2 led it for led_frames before the
    # sensor rule's loss_frames: lost by the lead, and straight to place 2.
    assert len(events) == 1 and "another place led" in events[0].how
    assert events[0].contradicted
    assert t.calls == [("lost", 0), ("start_in", 2)] and machine.mode == "confirm"


def test_a_rejected_pick_searches_on_without_it_and_found_again_in_step_one() -> None:
    places = [1, 2]
    machine = Relocalisation(S)
    machine.told(0, 0, "resumed")
    assert machine.mode == "confirm" and machine.confirming == "resumed"
    t = Scripted(machine, {})
    _frames(machine, t, S.confirm_frames, 0.5, False, places, 1, 1)
    assert machine.mode == "search" and machine.search.rejected == {1}
    # Tracking again; a brief low output is found again at recovery step 1.
    machine.told(0, 100, None)
    _frames(machine, t, S.loss_frames, 0.01, False, places, 1, 101)
    assert machine.mode == "recover"
    events = _frames(machine, t, 1, 0.6, True, places, 1, 110)
    assert events[0].kind == "relocalised" and events[0].how == "local"


def test_a_loss_contradicts_odometry_only_after_the_robot_was_found_and_not_blind() -> None:
    assert loss_contradicts(left=False, guessing=False)
    assert not loss_contradicts(left=True, guessing=False)
    assert not loss_contradicts(left=False, guessing=True)
    assert not left_view(by_sensor=True, blind=False, only_faded=False)  # the view said no
    assert not left_view(by_sensor=False, blind=True, only_faded=False)  # a leader
    assert left_view(by_sensor=True, blind=True, only_faded=False)  # no evidence either way
    # an output that only faded: the robot drove out of the place's range, whichever
    # rule declared it
    assert left_view(by_sensor=True, blind=False, only_faded=True)
    assert left_view(by_sensor=False, blind=False, only_faded=True)


def test_a_leader_while_the_view_only_fades_is_a_loss_the_robot_drove_into() -> None:
    """Another place (of another segment, no transition) leading the search while the
    output only fades — never below doubt_output — is the robot driving into its view:
    lost by the lead, but not contradicted, and the last fix may bridge to it; the same
    lead with the view contradicting the estimate (a carry) leaves no bridge."""
    places = [1, 2, 3]
    fading = (S.doubt_output + S.loss_output) / 2
    for support, left in ((fading, True), (S.doubt_output / 2, False)):
        machine = Relocalisation(S)
        machine.told(0, 0, None)
        t = Scripted(machine, {1: -0.2, 2: 0.3, 3: -0.3})
        events = [e for e in _frames(machine, t, S.loss_frames, support, False, places, 1, 1)
                  if e]
        assert len(events) == 1 and "another place led" in events[0].how
        assert events[0].contradicted is not left
        assert t.calls == [("lost", int(left)), ("start_in", 2)]


def test_a_loss_of_a_tracker_started_from_a_guess_is_no_evidence_of_a_kidnap() -> None:
    """Coming round a loop, the tracker starts over at the place's reference (a guess):
    lost before it ever found the robot for reliable_frames frames in a row, the guess
    was wrong — also when a neighbour switch carried the guess on; once found, a loss
    again says the robot may have been carried off."""
    places = [1, 2]
    machine = Relocalisation(S)
    machine.told(0, 0, None)
    t = Scripted(machine, {1: 0.0, 2: 0.0})
    machine.switched(guessed=True)
    [lost] = [e for e in _frames(machine, t, S.loss_frames, 0.01, False, places, 2, 1) if e]
    assert lost.kind == "lost" and not lost.contradicted
    machine.told(0, 10, None)  # tracked again (the operator)
    assert not machine.guessing
    machine.switched(guessed=True)
    _frames(machine, t, S.reliable_frames - 1, 0.6, True, places, 2, 11)
    machine.switched()  # on to a neighbour, the guess carried over the transition
    assert machine.guessing
    _frames(machine, t, S.reliable_frames - 1, 0.6, True, places, 1, 30)
    assert machine.guessing  # found, but not yet for reliable_frames in a row
    _frames(machine, t, 1, 0.6, True, places, 1, 40)
    assert not machine.guessing  # the guess held
    [lost] = [e for e in _frames(machine, t, S.loss_frames, 0.01, False, places, 1, 41) if e]
    assert lost.contradicted
    machine.told(0, 20, None)
    machine.switched()  # the estimate carried over a transition: no guess
    [lost] = [e for e in _frames(machine, t, S.loss_frames, 0.01, False, places, 2, 21) if e]
    assert lost.contradicted


def test_a_place_handed_over_from_a_guess_is_confirmed_before_it_is_tracked() -> None:
    """Tracking passed to a place with no transition from the last (a cycle, a path
    through the graph): the pose there starts from a guess, so the place is confirmed as
    the search's pick is — by a reliable, supported estimate within confirm_frames, else
    passed over by the search — and only then tracked."""
    places = [1, 2, 3]
    machine = Relocalisation(S)
    machine.told(0, 0, None)
    t = Scripted(machine, {})
    machine.handed_over(100_000_000, 1)
    assert machine.mode == "confirm" and machine.confirming == "handover"
    assert machine.guessing
    _frames(machine, t, 3, 0.6, False, places, 2, 2)
    assert machine.mode == "confirm"  # not yet found: relocalising, not tracking
    [event] = _frames(machine, t, 1, 0.6, True, places, 2, 5)
    assert event.kind == "relocalised" and event.how == "handover"
    assert event.frames == 4 and machine.mode == "track"
    assert machine.guessing  # the estimate found once, not yet reliable_frames in a row
    # Handed over again, to a place that never gives a reliable estimate: passed over.
    machine.handed_over(1_000_000_000, 10)
    events = _frames(machine, t, S.confirm_frames, 0.2, False, places, 3, 11)
    assert not any(events) and t.calls == []
    assert machine.mode == "search" and machine.search.rejected == {3}


def test_a_switch_to_a_neighbour_starts_the_lead_watch_over() -> None:
    """The output fading as the robot leaves a place runs the background search, where
    another place may lead for a frame or two before the switcher carries the estimate
    over (a neighbour switch): the run of led frames counted against the place left is
    not held against the new one."""
    places = [1, 2, 3]
    machine = Relocalisation(S)
    machine.told(0, 0, None)
    t = Scripted(machine, {1: 0.0, 2: S.search_margin + 0.05})
    # Low output: the search runs; place 2 leads place 1 for all but the last led frame.
    events = _frames(machine, t, S.led_frames - 1, 0.1, True, places, 1, 1)
    assert not any(events) and machine.lead_watch.frames == S.led_frames - 1
    machine.switched()  # into place 2, over the transition
    assert machine.lead_watch.frames == 0 and machine.mode == "track"
    events = _frames(machine, t, S.led_frames, 0.1, True, places, 2, 10)
    assert not any(events) and machine.mode == "track"  # place 2 leads no one here
    # Without the switch the same frames are a loss by the lead.
    machine = Relocalisation(S)
    machine.told(0, 0, None)
    t = Scripted(machine, {1: 0.0, 2: S.search_margin + 0.05})
    events = [e for e in _frames(machine, t, S.led_frames, 0.1, True, places, 1, 1) if e]
    assert len(events) == 1 and "another place led" in events[0].how
