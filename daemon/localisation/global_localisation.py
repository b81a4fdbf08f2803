"""Global localisation: the search for the most likely place, and loss detection (design
§9; thesis §9.2-9.4).

:class:`PlaceSearch` recognises the map's places a frame's budget at a time (every place
not yet recognised in this search first — best first by the cheap cue when there is one
— then the best so far again) and names the most likely place — the highest LRP minus
background, §9.2 — once every place of the *active set* has been recognised since the
search began: the places whose cue is within ``cue_margin`` of the best cue, plus the
current place and its neighbours (§9.4.2; without a cue, every place). The others are
still recognised on later frames while no place is named (nothing is dropped for good).
:class:`LossDetector` declares a loss when the raw sensor-model output at the estimate,
over the place's landmarks usable from there (``LocalResult.support``), stays below a
threshold for a number of frames in a row (§9.3.1); :class:`LeadWatch` declares one
while the sensor output still holds, when another place leads the current one in the
background search for a few frames in a row. The recovery that follows, in the order of
§9.3.2, is the localiser's (daemon/localisation/localiser.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from daemon.localisation.belief import PlaceScore
from daemon.localisation.settings import LocalisationSettings


@dataclass(frozen=True)
class Candidate:
    place_id: int
    lead: float  # LRP minus background when last recognised
    frame: int  # the search frame it was recognised in


class PlaceSearch:
    """The most likely place over the whole map, a budget of places per frame."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.settings = settings
        self.scores: dict[int, Candidate] = {}
        self.frames = 0
        self.started_ns: int | None = None
        self.rejected: set[int] = set()  # tried and not confirmed in this search
        self.cue: dict[int, float] = {}  # this frame's cue per place (signature similarity)
        self.active: set[int] | None = None  # the active set (None: every place)
        self._turn = 0

    def reset(self, stamp_ns: int | None = None, rejected: set[int] | None = None) -> None:
        """A new search from the frame at ``stamp_ns`` on; places in ``rejected`` are
        chosen only when no other place qualifies (they stay recognised and reported)."""
        self.scores.clear()
        self.cue, self.active = {}, None
        self.frames = 0
        self.started_ns = stamp_ns
        self.rejected = set(rejected or ())

    def set_cue(self, cue: dict[int, float], always: tuple[int, ...] = (),
                local: dict[int, float] | None = None) -> None:
        """This frame's cue per place; the active set is every place within
        ``cue_margin`` of the best, and ``always`` (the previous most likely place, its
        nearest neighbours). ``local``: each place's local space match (design §4; a
        place without a profile is left out of it): of the cue's places, only those
        within ``local_space_margin`` of the best match, or without one, stay (thesis
        §9.4.1's local space set)."""
        self.cue = cue
        if not cue:
            self.active = None
            return
        active = near_best(cue, self.settings.cue_margin)
        if local:
            matched = near_best(local, self.settings.local_space_margin)
            active = {p for p in active if p not in local or p in matched}
        self.active = active | set(always)

    @property
    def running(self) -> bool:
        return self.started_ns is not None

    def to_score(self, places: list[int], first: tuple[int, ...] = ()) -> list[int]:
        """The places to recognise in this frame, at most ``search_places_per_frame``:
        ``first`` (e.g. the current place and its neighbours), then the places of the
        active set not yet recognised in this search, best cue first — once they all
        are, the others in turn — then the best so far again."""
        budget = self.settings.search_places_per_frame
        known = set(places)
        chosen = [p for p in dict.fromkeys(first) if p in known][:budget]
        unseen = [p for p in places if p not in self.scores and p not in chosen]
        if self.active is not None and any(p in self.active for p in unseen):
            unseen = [p for p in unseen if p in self.active]  # the active set first
        if unseen and self.cue:  # best first by the cue
            unseen.sort(key=lambda p: -self.cue.get(p, -math.inf))
            chosen += unseen[:budget - len(chosen)]
        elif unseen:
            start = self._turn % len(unseen)
            take = (unseen[start:] + unseen[:start])[:budget - len(chosen)]
            self._turn += len(take)
            chosen += take
        if len(chosen) < budget:
            best = sorted((c for c in self.scores.values() if c.place_id not in chosen),
                          key=lambda c: -c.lead)
            chosen += [c.place_id for c in best[:budget - len(chosen)]]
        return chosen

    def observe(self, scores: list[PlaceScore]) -> None:
        self.frames += 1
        for sc in scores:
            self.scores[sc.place_id] = Candidate(sc.place_id, sc.lead, self.frames)

    def covered(self, places: list[int]) -> bool:
        """Every place of the active set (every one of ``places`` without a cue) has
        been recognised in this search."""
        needed = places if self.active is None else [p for p in places if p in self.active]
        return all(p in self.scores for p in needed)

    def ranked(self) -> list[Candidate]:
        return sorted(self.scores.values(), key=lambda c: -c.lead)

    def best(self, places: list[int]) -> Candidate | None:
        """The most likely place (§9.2) once every place has been recognised, if it
        stands at least ``search_min_lead`` above its background; None before."""
        if not places or not self.covered(places):
            return None
        known = set(places)
        good = [c for c in self.ranked() if c.lead >= self.settings.search_min_lead
                and c.place_id in known]
        fresh = [c for c in good if c.place_id not in self.rejected]
        if not fresh and good:  # only a place tried before: try it again
            self.rejected.clear()
        chosen = fresh or good
        return chosen[0] if chosen else None

    def leader_over(self, current: int, places: list[int], margin: float | None = None
                    ) -> Candidate | None:
        """A place other than ``current`` leading it by ``margin`` (``search_margin``
        unless given): the robot is no longer where the estimate says (a kidnap), so
        recovery goes global at once."""
        best = self.best(places)
        here = self.scores.get(current)
        if best is None or best.place_id == current or here is None:
            return None
        margin = self.settings.search_margin if margin is None else margin
        return best if best.lead > here.lead + margin else None


def near_best(scores: dict[int, float], margin: float) -> set[int]:
    """The places scoring within ``margin`` of the best: the active set's rule for the
    cue and for the local space match alike (§9.4.1: B = 0.075 kept the true place in the
    local space set on 98 % of frames)."""
    top = max(scores.values())
    return {p for p, score in scores.items() if score >= top - margin}


def faded(least_low_output: float, settings: LocalisationSettings) -> bool:
    """Whether a loss by the output rule is a view *fading* as the robot drives out of
    its place's range, the estimate still right: through the whole run of low frames the
    output stayed at or above ``doubt_output``, where a view replaced by another (a
    robot carried off) gives 0.00-0.02 at once (the endurance runs' kidnaps, offices
    1-5). Such a loss is no evidence of a kidnap (``loss_contradicts``): on office 3 the
    mapping robot lost each place it had just learned 0.8-1 m on (output 0.07-0.14), and
    holding the odometry to the next place split its map (cyclic, the fleet)."""
    return least_low_output >= settings.doubt_output


class LossDetector:
    """Loss of tracking: the raw output below ``loss_output`` for ``loss_frames`` frames
    in a row (§9.3.1); or no evidence at all — too few of the place's landmarks usable
    from the estimate (NaN output) — over ``blind_m`` of odometry travel in a row: the
    pose is then odometry alone, ever farther from the place, and would stay ``tracking``
    however wrong (a robot carried off while on odometry was published tracking 11 m
    off, issue 31). Measured in metres, not frames: passing between places on odometry
    for a metre or two is what tracking does (the revisit check ends such a stretch)."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.settings = settings
        self.low_frames = 0
        self.blind_m = 0.0  # odometry travel since the last frame with evidence
        self.least_low = math.inf  # the lowest output of the current run of low frames
        self.why = ""  # the reason of the last loss declared
        self.blind = False  # ...declared by the blind rule (no evidence, nothing contradicted)

    def reset(self) -> None:
        self.low_frames = 0
        self.least_low = math.inf
        self.blind_m = 0.0

    def observe(self, output: float, travelled_m: float = 0.0) -> bool:
        """True on the frame the loss is declared (``why`` says which rule);
        ``travelled_m``: the odometry travel since the last frame. NaN is no evidence
        either way for the output rule; it counts towards the blind rule."""
        s = self.settings
        if math.isnan(output):
            was = self.blind_m
            self.blind_m += travelled_m
            if 0 < s.blind_m <= self.blind_m and was < s.blind_m:
                self.why = (f"no evidence over {s.blind_m:.1f} m: fewer than "
                            f"{s.evidence_landmarks} of the place's landmarks usable from "
                            "the estimate (odometry alone)")
                self.blind = True
                return True
            return False
        self.blind_m = 0.0
        low = output < s.loss_output
        self.low_frames = self.low_frames + 1 if low else 0
        self.least_low = min(self.least_low, output) if low else math.inf
        if self.low_frames == s.loss_frames:
            self.why = f"sensor output below {s.loss_output} for {s.loss_frames} frames"
            self.blind = False
            return True
        return False

    @property
    def faded(self) -> bool:
        """The current run of low frames only faded (:func:`faded`): whichever rule
        declares the loss on it, the output rule or another place leading the search."""
        return faded(self.least_low, self.settings)

    @property
    def suspicious(self) -> bool:
        """At least one low frame: worth searching the map in the background."""
        return self.low_frames > 0


class LeadWatch:
    """Tracking: another place leading the current one in the background search by
    ``search_margin`` for ``led_frames`` search frames in a row is a loss at once — the
    robot carried off, or tracked in a place it has left (design §9: office 2 tracked
    one 24 frames in a place two behind, the true place leading by 0.08-0.14).

    A neighbour (a place joined to the current one by a transition) leading is no loss:
    the switcher weighs it with the estimate's position (§8.2) and carries the estimate
    over. Office 1's endurance run lost a right estimate so (0.02 m off, 0.86 m from the
    neighbour that led by 0.05, just learned, its background not yet measured), and
    relocalising took 30 frames; a robot carried off near a neighbour is still lost by
    the sensor output."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.settings = settings
        self.frames = 0  # search frames in a row another place led

    def observe(self, search: PlaceSearch, current: int, places: list[int],
                searched: bool, neighbours: tuple[int, ...] = ()) -> bool:
        """``searched``: the search ran in this frame (a frame without it breaks the
        run); ``neighbours``: the current place's. True once the run reaches
        ``led_frames``."""
        led = searched and search.leader_over(
            current, [p for p in places if p not in neighbours]) is not None
        self.frames = self.frames + 1 if led else 0
        return 0 < self.settings.led_frames <= self.frames

    def reset(self) -> None:
        self.frames = 0
