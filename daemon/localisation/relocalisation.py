"""Relocalisation: the state machine of global localisation (design §9, thesis §9.3).

States (``Mode``): ``search`` (the whole map searched for the most likely place),
``confirm`` (tracking from a place the search chose, from the pose saved at the last
stop, or from a guess when tracking passed to a place with no transition from the last,
until the estimate is reliable), ``track``, ``recover`` (a loss: the steps of
§9.3.2 — particles around the estimate, then over the whole place — before the search).

Per frame :meth:`Relocalisation.supervise` runs the search in the background while the
loss detector is suspicious, declares a loss (the sensor output low, §9.3.1, or another
place leading the search, design §9) and moves between the states. The decisions are the
pure functions below (``after_tracking``, ``after_confirming``, ``after_recovering``),
each tested on crafted inputs; the machine asks the localiser, which owns the trackers
and the map snapshot, for what only it can do (:class:`Trackers`): score places, tell
look-alikes apart, start tracking in a place, spread the particles for a recovery step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

from daemon.localisation.belief import LocalisationEvent, PlaceScore
from daemon.localisation.global_localisation import LeadWatch, LossDetector, PlaceSearch
from daemon.localisation.settings import LocalisationSettings

Mode = Literal["search", "confirm", "track", "recover"]
RECOVERY_STEPS = {1: "local", 2: "place"}  # §9.3.2; step 3 is the global search


# ------------------------------------------------------------------ the decision rules
def after_tracking(lost_now: bool, led: bool) -> Literal["track", "lost"]:
    """Tracking goes on unless the sensor output declared a loss (§9.3.1) or another
    place led the background search for ``led_frames`` (design §9)."""
    return "lost" if lost_now or led else "track"


def after_confirming(found: bool, lost_now: bool, frames: int,
                     settings: LocalisationSettings) -> Literal["relocalised", "reject", "wait"]:
    """A place chosen by the search (or resumed) is confirmed by a reliable estimate
    there; a loss, or ``confirm_frames`` without one, rejects it (the search goes on
    without it)."""
    if found:
        return "relocalised"
    if frames >= settings.confirm_frames or lost_now:
        return "reject"
    return "wait"


def after_recovering(found: bool, leader: int | None, step: int, frames: int,
                     settings: LocalisationSettings
                     ) -> Literal["found", "leader", "next step", "global", "wait"]:
    """One frame of recovery step ``step`` (§9.3.2): found again; a place leading the
    search clearly (``leader``: straight to it); after ``recovery_frames`` the next step
    (step 2 after step 1, then the global search); or wait."""
    if found:
        return "found"
    if leader is not None:
        return "leader"
    if frames >= settings.recovery_frames:
        return "next step" if step == 1 else "global"
    return "wait"


def contradicted(support: float | None, confidence: float,
                 settings: LocalisationSettings, switched: bool = False) -> bool:
    """A tracked frame whose view contradicts the estimate: the output over the usable
    landmarks below ``doubt_output``, or no landmark seen agreeing at all (confidence 0).
    Such a frame is not published ``tracking`` (issue 31: a robot carried off was
    published tracking 3.3 m off for the 4 frames before the loss rule fired); ``None``
    support (too few landmarks usable: no evidence either way) contradicts nothing. A frame
    that ``switched`` places scored the place it left, whose output says nothing of the
    new one: only confidence 0 counts then (office 2 published such a frame tracking)."""
    if switched:
        return confidence <= 0.0
    return confidence <= 0.0 or (support is not None and support < settings.doubt_output)


def left_view(by_sensor: bool, blind: bool, only_faded: bool) -> bool:
    """Whether a loss is the robot leaving the place's view on its own, its estimate right
    up to it: no evidence over blind travel (the output rule's blind clause), or a view
    that ``only_faded`` (``LossDetector.faded``: through the run of low frames the
    output never fell below ``doubt_output``) — whichever rule declared the loss, the
    output or another place leading the search. Office 5's endurance run drove from a
    place of one segment into the view of another's, 0.02 m off, the output fading
    (0.12-0.14), and was lost by the lead twice: no transition joined the segments
    (issue 31). A robot carried off gives 0.00-0.02 at once (offices 1-5's kidnaps)."""
    return (by_sensor and blind) or only_faded


def loss_contradicts(left: bool, guessing: bool) -> bool:
    """Whether a loss is evidence the robot may have been carried off (the odometry run
    from the last place learned then measures nothing, design §6): the view contradicted
    the estimate — by the sensor output or by another place leading the search — unless
    the robot ``left`` the place's view on its own (:func:`left_view`: on office 3 the
    mapping robot lost each place it had just learned 0.8-1 m on, output 0.07-0.14, and
    holding the odometry to the next place split its map), and not while the tracker
    started from a guess has not yet found the robot: then the guess was wrong, not the
    odometry (cyclic over ROS 2, notes of 2026-12-06: a switch coming round the loop
    started 2 m off, was lost 5 frames later, and the place learned next lost its
    link)."""
    return not (guessing or left)


# ------------------------------------------------------------------ the machine
class Trackers(Protocol):
    """What the machine asks of the localiser (daemon/localisation/localiser.py)."""

    def search_step(self, places: list[int], first: tuple[int, ...]) -> list[PlaceScore]:
        """One frame's budget of the search recognised (the search observes them)."""
        ...

    def tell_apart(self, best: int, places: list[int], at_once: bool = False) -> int | None:
        """The search's pick once look-alikes are told apart (design §5); None: wait."""
        ...

    def start_in(self, place_id: int) -> None:
        """Track in ``place_id`` from its reference (σ ``recovery_sigma_m``, §9.3.2);
        the machine then waits for the estimate to confirm it."""
        ...

    def lost(self, left: bool) -> None:
        """A loss was just declared, before any recovery starts; ``left``: the robot left
        the place's view on its own (:func:`left_view`), the last estimate a fix to
        build on."""
        ...

    def spread(self, step: int) -> None:
        """Recovery step ``step``'s particles: around the estimate (1), over the place (2)."""
        ...


@dataclass(frozen=True)
class Supervised:
    """One frame of supervision: the places the search recognised and the event the
    frame brings, if any."""

    scores: list[PlaceScore]
    event: LocalisationEvent | None = None


class Relocalisation:
    """The state of global localisation (module docstring): its mode, the recovery step,
    the search, the loss detector and the episode (when the loss or search began)."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.settings = settings
        self.mode: Mode = "search"
        self.step = 0  # the recovery step under way (mode "recover")
        self.mode_frames = 0  # frames in this mode or recovery step
        self.episode: tuple[int, int] | None = None  # (stamp, frame) the loss/search began
        self.confirming = "global"  # how the place being confirmed was chosen
        self.search = PlaceSearch(settings)
        self.loss = LossDetector(settings)
        self.lead_watch = LeadWatch(settings)
        self.undecided: int | None = None  # the search's pick while look-alikes stand tied
        self.ambiguous_frames = 0  # the search's pick ambiguous this many frames in a row
        # The tracker was started from a guess (a place entered with no transition from
        # the last: its reference, the orientation from the bearings) and has not found
        # the robot yet: a loss now says the guess was wrong, not that the robot moved,
        # and its estimate joins no place to the map (Localiser.reliable_estimate).
        self.guessing = False
        self.found_frames = 0  # frames in a row with the estimate found

    # -------------------------------------------------------------- transitions
    def begin_search(self, stamp_ns: int, frame: int, rejected: set[int] | None = None,
                     keep_episode: bool = False) -> None:
        self.mode, self.mode_frames = "search", 0
        self.search.reset(stamp_ns, rejected)
        self.loss.reset()
        self.undecided = None
        self.ambiguous_frames = 0
        if not keep_episode or self.episode is None:
            self.episode = (stamp_ns, frame)

    def _start(self, trackers: Trackers, place_id: int) -> None:
        """Global relocalisation's pick: tracked from its reference, to be confirmed."""
        trackers.start_in(place_id)
        self.mode, self.mode_frames, self.confirming = "confirm", 0, "global"
        self.loss.reset()
        self.ambiguous_frames = 0

    def _recover(self, trackers: Trackers, step: int) -> None:
        trackers.spread(step)
        self.mode, self.step, self.mode_frames = "recover", step, 0
        self.loss.reset()
        self.ambiguous_frames = 0

    def told(self, stamp_ns: int, frame: int, confirm: str | None) -> None:
        """A pose set from outside: ``confirm`` None, the operator knows it; else how it
        came (``resumed``), to be confirmed as a global pick is."""
        self.loss.reset()
        self.search.reset(None)
        self.guessing = False
        if confirm is not None:
            self.mode, self.mode_frames, self.confirming = "confirm", 0, confirm
            self.episode = (stamp_ns, frame)
        else:
            self.mode, self.mode_frames, self.episode = "track", 0, None

    def switched(self, guessed: bool = False) -> None:
        """Tracking passed to another place: its own evidence from here on. ``guessed``:
        the new tracker starts from a guess rather than the estimate carried over; an
        estimate carried over from a guess is still one (cyclic over ROS 2, notes of
        2026-12-06: a switch coming round the loop guessed place 2, a neighbour switch
        carried that to place 1 half a second later, and a place learned then was
        joined to place 1 by it, the lap's cycle never closed)."""
        self.loss.reset()
        self.lead_watch.reset()
        self.guessing = guessed or self.guessing
        self.found_frames = 0

    def handed_over(self, stamp_ns: int, frame: int) -> None:
        """Tracking passed to a place with no transition from the one left (through the
        graph's path, a cycle, a revisit): the new tracker starts from a guess, and is
        confirmed as the search's pick is before its pose is published ``tracking``
        (issue 31: office 2's endurance run handed over 34 → 25 through a path 1 m
        adrift, the filter settled 1.7 m off on a ridge of the bearings, and the pose,
        carried on from place to place, was published tracking 0.8-1.8 m off for 87
        frames with σ 0.05 m). No support, no confirmation: the search goes on."""
        self.switched(guessed=True)
        self.mode, self.mode_frames, self.confirming = "confirm", 0, "handover"
        self.loss.reset()
        if self.episode is None:
            self.episode = (stamp_ns, frame)

    def _relocalised(self, place_id: int, how: str, stamp_ns: int, frame: int
                     ) -> LocalisationEvent:
        began_ns, began_frame = self.episode or (stamp_ns, frame)
        self.episode = None
        self.mode, self.mode_frames = "track", 0
        self.loss.reset()
        self.search.reset(None)
        return LocalisationEvent("relocalised", place_id, how,
                                 max(0.0, (stamp_ns - began_ns) / 1e9), frame - began_frame)

    # -------------------------------------------------------------- per frame
    def leader(self, trackers: Trackers, current: int, places: list[int],
               margin: float | None = None) -> int | None:
        """The place the search finds ahead of ``current`` by ``margin`` (by default
        ``search_margin``: clearly, a kidnap), told apart from its look-alikes when their
        features are clear (the leader itself while they are not); None while none leads."""
        leader = self.search.leader_over(current, places, margin)
        if leader is None:
            return None
        told = trackers.tell_apart(leader.place_id, places, at_once=True)
        return leader.place_id if told is None else told

    def searching(self, trackers: Trackers, places: list[int], stamp_ns: int, frame: int,
                  current: int | None) -> list[PlaceScore]:
        """Mode ``search``: one frame of it; the pick, once look-alikes are told apart,
        is tracked and confirmed."""
        if self.episode is None:
            self.episode = (stamp_ns, frame)
        found_in = trackers.search_step(places, () if current is None else (current,))
        best = self.search.best(places)
        pick = None if best is None else trackers.tell_apart(best.place_id, places)
        # Waiting on look-alikes' features (design §5): the lower levels' pick is the
        # most likely place meanwhile.
        self.undecided = best.place_id if best is not None and pick is None else None
        if pick is not None:
            self._start(trackers, pick)
        return found_in

    def supervise(self, trackers: Trackers, places: list[int], neighbours: tuple[int, ...],
                  current: int, support: float, found: bool, travelled_m: float,
                  stamp_ns: int, frame: int) -> Supervised:
        """Modes ``track``, ``confirm``, ``recover`` for one frame, tracking in ``current``
        (``support``: the raw sensor output, ``found``: the estimate reliable and well
        supported; ``travelled_m``: odometry since the last frame, 0 while learning)."""
        s = self.settings
        lost_now = self.loss.observe(support, travelled_m)
        self.mode_frames += 1
        # A guess holds once the estimate is found for reliable_frames frames in a row,
        # as a cycle's transition is measured (§7.1.3): one frame can fit a wrong mode.
        self.found_frames = self.found_frames + 1 if found else 0
        if self.found_frames >= s.reliable_frames:
            self.guessing = False
        scored: list[PlaceScore] = []
        if self.mode != "confirm" and (self.loss.suspicious or self.mode == "recover"):
            if not self.search.running:
                self.search.reset(stamp_ns)
            scored = trackers.search_step(places, (current, *neighbours))
        elif self.mode == "track":
            self.search.reset(None)  # confident again: no background search
        if self.mode == "track":
            led = self.lead_watch.observe(self.search, current, places, bool(scored),
                                          neighbours)
            if after_tracking(lost_now, led) == "track":
                return Supervised(scored)
            self.episode = (stamp_ns, frame)
            left = left_view(lost_now, self.loss.blind, self.loss.faded)
            event = LocalisationEvent("lost", current, self.loss.why if lost_now else
                                      f"another place led the search by "
                                      f"{s.search_margin} for {s.led_frames} frames",
                                      contradicted=loss_contradicts(left, self.guessing))
            trackers.lost(left)
            self.lead_watch.reset()
            leader = self.leader(trackers, current, places)
            if leader is not None:
                self._start(trackers, leader)
            else:
                self._recover(trackers, 1)
            return Supervised(scored, event)
        if self.mode == "confirm":
            confirmed = after_confirming(found, lost_now, self.mode_frames, s)
            if confirmed == "relocalised":
                return Supervised(scored, self._relocalised(current, self.confirming,
                                                            stamp_ns, frame))
            if confirmed == "reject":
                self.begin_search(stamp_ns, frame, rejected={current}, keep_episode=True)
            return Supervised(scored)
        # mode "recover": steps 1 and 2 of §9.3.2
        leader = None if found else self.leader(trackers, current, places)
        verdict = after_recovering(found, leader, self.step, self.mode_frames, s)
        if verdict == "found":
            # A pose found again where the search ranks another place above this one is a
            # look-alike's (design §9: in the aliased corridor every such recovery after a
            # kidnap was wrong, the true place at the top of the search on most).
            ahead = self.leader(trackers, current, places, s.recovered_margin)
            if ahead is not None:
                self._start(trackers, ahead)
                return Supervised(scored)
            # Found in a place with look-alikes is found in one of them: the view of this
            # place cannot say which, their features can (design §5). Only features that
            # clearly name another place move the robot there; unclear ones do not hold
            # the recovery up (waiting cost the office's kidnaps their 10-frame mark).
            told = trackers.tell_apart(current, places, at_once=True)
            if told is not None and told != current:
                self._start(trackers, told)
                return Supervised(scored)
            return Supervised(scored, self._relocalised(current, RECOVERY_STEPS[self.step],
                                                        stamp_ns, frame))
        if verdict == "leader":
            assert leader is not None
            self._start(trackers, leader)
        elif verdict == "next step":
            self._recover(trackers, 2)
        elif verdict == "global":  # step 3: the most likely place elsewhere, or search on
            best = self.search.best([p for p in places if p != current])
            if best is not None:
                self._start(trackers, best.place_id)
            else:
                self.begin_search(stamp_ns, frame, rejected={current}, keep_episode=True)
        return Supervised(scored)
