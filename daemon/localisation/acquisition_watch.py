"""The acquisition watch (design §6, thesis §7.1): per frame, the LRP of the place learned
last (or taken over), whether to learn a new place, the backgrounds measured as the robot
leaves places behind, and a known place recognised again on the way (a revisit).

Its decision rules are pure functions elsewhere (daemon/mapping/acquisition.py:
``PlaceAcquisition``, ``BackgroundMeter``, ``taken_over``); this module keeps the watch's
state between frames and asks the map (a ``KnownMap`` snapshot) and the frame's scores.
The localiser hands it what the tracker knows (:class:`Tracked`) and moves the tracker
itself when a revisit is found.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon.localisation.belief import PlaceScore
from daemon.localisation.known_map import KnownMap
from daemon.localisation.place_switching import nearest_place, places_near
from daemon.mapping.acquisition import (
    AcquisitionDecision,
    BackgroundMeter,
    PlaceAcquisition,
    taken_over,
)
from daemon.mapping.settings import AcquisitionSettings
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from daemon.vision.signature import signature, similarity
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry

# LRP and lead over the estimated background (§9.2) of some places in this frame.
Scorer = Callable[[list[int]], list[PlaceScore]]


@dataclass
class Tracked:
    """What the tracker says in this frame: its place (any mode), whether it tracks, and
    then its estimate in that place (None without one)."""

    known: KnownMap
    place_id: int | None
    tracking: bool
    pose: tuple[float, float, float] | None = None

    @functools.cached_property
    def through(self) -> dict[int, UncertainSE2] | None:
        """T_place_p of every place the map's transitions reach from the tracked place
        (made when first asked); None: not tracking with an estimate."""
        if self.place_id is None or self.pose is None or not self.tracking:
            return None
        return self.known.through_graph(self.place_id)


@dataclass(frozen=True)
class WatchStep:
    """One frame of the watch."""

    recent: int | None = None  # the place watched...
    recent_lrp: float | None = None  # ...and its LRP in this frame
    decision: AcquisitionDecision | None = None  # learn a new place here
    backgrounds: tuple[tuple[int, float], ...] = ()  # (place, background) measured now
    revisited: PlaceScore | None = None  # a known place recognised where the robot is


def revisitable(known: KnownMap, watched: int, tracked: Tracked, within_m: float
                ) -> list[int]:
    """The places a revisit may find (design §6): all but the watched and the tracked
    one and those the map's transitions put within ``within_m`` of the estimate (the path's
    drift at 2 sigma allowed). Those are the place switcher's (design §8), which hands
    over to them with the estimate carried through the transition; taken for a revisit,
    one was tracked from its reference instead, where the robot was not (office 1: a
    neighbour 1.46 m off, tracked 0.9 m and 30 degrees wrong for 25 frames)."""
    near = set() if tracked.place_id is None or tracked.pose is None \
        or tracked.through is None else places_near(tracked.place_id, tracked.pose,
                                                    tracked.through, within_m)
    return [p for p in known.places if p not in (watched, tracked.place_id) and p not in near]


def reference_in_odometry(odo: Odometry, pose: tuple[float, float, float]) -> Odometry:
    """Where the reference of the place the robot is tracked in stands in the odometry
    frame: T_odom_place = T_odom_robot ∘ T_place_robot⁻¹ (``pose``: the estimate in the
    place), stamped as ``odo``."""
    ref = SE2(odo.x, odo.y, odo.yaw).compose(SE2.of(pose).inverse())
    return Odometry(ref.x, ref.y, ref.yaw, odo.stamp_ns, odo.seq)


class AcquisitionWatch:
    def __init__(self, settings: AcquisitionSettings, matcher: FastMatcher,
                 wrap_margin: int, default_background: float) -> None:
        self.acquisition = PlaceAcquisition(settings, default_background)
        self.settings = settings
        self._matcher = matcher
        self._wrap_margin = wrap_margin
        self._default_background = default_background
        self._watched: tuple[int, PreparedTemplates] | None = None
        self._awaiting_place = False  # a decision was made: the new place comes next
        self._watched_learned = False  # learned where it began to be watched (its reference)
        self._watch_next: int | None = None  # set from other threads
        self._meters: list[BackgroundMeter] = []  # places being left behind
        self._fresh = True  # no place watched yet: a start on the map (a restart)

    def watch_next(self, place_id: int) -> None:
        """Watch ``place_id`` (the one just learned) from the next frame on. Safe to call
        from another thread."""
        self._watch_next = place_id

    def not_started(self) -> None:
        """The place asked for was not learned: watch the tracked place again, ask again
        once that one has faded. Safe to call from another thread."""
        self._awaiting_place = False

    # ------------------------------------------------------------------ per frame
    def observe(self, known: KnownMap, prepare: Callable[[], PreparedPanorama],
                grey: np.ndarray, odo: Odometry | None, tracked: Tracked,
                score: Scorer) -> WatchStep:
        """The watched place's LRP in this frame, whether to learn a new place, a
        background LRP measured as the robot left a place behind, and a revisit."""
        learned = self._watch_next  # set from other threads
        if learned is not None and learned in known:  # else stored after this frame's map
            self._watch_next = None
            self._watch(known, learned, learned=True)
            self._awaiting_place = False
        if self._watched is None and not self._awaiting_place and tracked.tracking \
                and tracked.place_id is not None:
            # Nothing watched and no place coming: after a restart on a map with places,
            # or a decision whose learn did not happen. The place the robot is tracked
            # in is watched from here, so acquisition goes on (never a "first" place on
            # a map that has places: issue 31) — after a restart, from its reference: the
            # robot may stand well past it (office 3 resumed 0.7 m past a place, and
            # counting the distances from there left 1.34 m to the next place, a stretch
            # where neither stood out).
            reference = None
            if self._fresh and tracked.pose is not None and odo is not None:
                reference = reference_in_odometry(odo, tracked.pose)
            self._watch(known, tracked.place_id, learned=False, reference=reference)
        if self._watched is None and not self._meters:
            return WatchStep()
        prepared = prepare()
        background = self._measure_backgrounds(known, prepared, odo)
        if self._watched is None:
            return WatchStep(backgrounds=background)
        place_id, templates = self._watched
        lrp = self._matcher.lrp(prepared, templates)
        # Asked every frame: the place's estimates come in after it is learned.
        self.acquisition.expected_background = known.estimated_background(place_id)
        decision = self.acquisition.observe(lrp, odo)
        if decision is None:
            return self._or_revisit(WatchStep(place_id, lrp, None, background), known, grey,
                                    tracked, score)
        # The watched place is behind us: measure the level its LRP settles at...
        acq = self.settings
        self._meters.append(BackgroundMeter(
            place_id, acq.background_window_m, acq.background_skip_m, decision.origin,
            decision.away_m))
        # ...and back on a known path another place may be recognised here (the most
        # likely place, §7.1): watch that one instead of learning.
        again = self._most_likely(known, grey, tracked, place_id, score)
        if again is None:
            again = self._crowded(known, tracked, acq.min_distance_m,
                                  exclude=place_id if self._watched_learned else None)
        if again is not None:
            self._watch(known, again, learned=False)
            return self._or_revisit(WatchStep(place_id, lrp, None, background), known, grey,
                                    tracked, score)
        self._watched = None  # until the new place is learned and watched
        self._awaiting_place = True
        self.acquisition.reset(None)
        return WatchStep(place_id, lrp, decision, background)

    def _or_revisit(self, step: WatchStep, known: KnownMap, grey: np.ndarray,
                    tracked: Tracked, score: Scorer) -> WatchStep:
        """``step``, or the revisit found in this frame (the watch moved to it)."""
        assert step.recent_lrp is not None
        revisited = self._revisit(known, grey, tracked, step.recent_lrp, score)
        if revisited is None:
            return step
        return WatchStep(revisited.place_id, revisited.lrp, None, step.backgrounds, revisited)

    def _revisit(self, known: KnownMap, grey: np.ndarray, tracked: Tracked,
                 watched_lrp: float, score: Scorer) -> PlaceScore | None:
        """Back at a known place that neither acquisition nor the tracker watches (design
        §6): the ``revisit_candidates`` places whose signatures are most like the view
        are recognised in every frame, and one standing ``certain_lead`` above its
        background, and above the watched place, is where the robot is: acquisition
        watches it from here (and the localiser has the tracker start in it) — of the
        places :func:`revisitable`. Without this a tour coming back along a corridor
        never recognised the places of its first pass there: the tracker followed the
        new places, and the map's long chain put the old ones metres away (office 3: new
        places learned 0.29 and 0.41 m from old ones, the robot passing within 0.01 m of
        one)."""
        assert self._watched is not None
        watched = self._watched[0]
        top = self._most_like_view(known, grey, revisitable(
            known, watched, tracked, self.settings.known_within_m))
        if not top:
            return None
        best = max(score(top), key=lambda sc: sc.lead)
        watched_lead = watched_lrp - known.background(watched, self._default_background,
                                                      estimated=True)
        if best.lead < max(self.settings.certain_lead, watched_lead):
            return None
        self._watch(known, best.place_id, learned=False)
        return best

    def _watch(self, known: KnownMap, place_id: int, learned: bool,
               reference: Odometry | None = None) -> None:
        """Acquisition watches ``place_id`` from here: ``learned`` there (its reference
        is where the watch begins), or a known place taken over — counted from
        ``reference`` when given (PlaceAcquisition.reset)."""
        self._watched = (place_id, known.places[place_id].templates)
        self._watched_learned = learned
        self._fresh = False
        self.acquisition.reset(place_id, reference=reference)

    def _most_like_view(self, known: KnownMap, grey: np.ndarray, candidates: list[int]
                        ) -> list[int]:
        """The ``revisit_candidates`` of ``candidates`` whose signatures are most like the
        view (design §9's cue), most like first; places without a signature left out."""
        k = self.settings.revisit_candidates
        signed = [p for p in candidates if known.place(p).signature is not None]
        if not signed or k == 0:
            return []
        here = signature(grey, self._wrap_margin)
        cue = similarity(here, np.stack([known.place(p).signature  # type: ignore[misc]
                                         for p in signed]))
        return [signed[i] for i in np.argsort(-cue)[:k]]

    def _crowded(self, known: KnownMap, tracked: Tracked, within_m: float,
                 exclude: int | None) -> int | None:
        """The place the map puts nearest the tracked estimate, if nearer than
        ``within_m``: no new place is learned there, that one is watched instead —
        ``min_distance_m`` holds for every place, not only the last (corridor 1's way back
        learned places 0.23 m from known ones standing too little above their high,
        aliased backgrounds to be taken over). The watched place ``exclude`` is left out:
        odometry has put the robot far enough from it, where the tracked estimate may lag
        by centimetres — only a place learned there: one taken over was first watched
        wherever it stood out, maybe a metre before its reference, and the robot may pass
        it on the way (office 3 learned a place 0.48 m from one it had taken over 1.01 m
        before it). None: not tracking, or no place so near."""
        if tracked.place_id is None or tracked.pose is None or tracked.through is None:
            return None
        nearest = nearest_place(tracked.place_id, tracked.pose, tracked.through, exclude)
        return nearest[0] if nearest is not None and nearest[1] < within_m \
            and nearest[0] in known else None

    def _near_estimate(self, known: KnownMap, tracked: Tracked, within_m: float
                       ) -> set[int] | None:
        """The places the map's transitions put within ``within_m`` of the tracked
        estimate, and those no path of transitions reaches (nothing to rule them out);
        None: not tracking, nothing to go by."""
        if tracked.place_id is None or tracked.pose is None or tracked.through is None:
            return None
        current, through = tracked.place_id, tracked.through
        unreached = {p for p in known.places if p != current and p not in through}
        return unreached | places_near(current, tracked.pose, through, within_m)

    def _measure_backgrounds(self, known: KnownMap, prepared: PreparedPanorama,
                             odo: Odometry | None) -> tuple[tuple[int, float], ...]:
        done: list[tuple[int, float]] = []
        for meter in list(self._meters):
            place = known.places.get(meter.place_id)
            if place is None:
                self._meters.remove(meter)
                continue
            value = meter.observe(self._matcher.lrp(prepared, place.templates), odo)
            if value is not None:  # the map's owner stores it (MapUpdates.backgrounds)
                self._meters.remove(meter)
                done.append((meter.place_id, value))
        return tuple(done)

    def _most_likely(self, known: KnownMap, grey: np.ndarray, tracked: Tracked,
                     exclude: int, score: Scorer) -> int | None:
        """The known place to watch instead of learning a new one here, if any
        (``taken_over``): each place's lead is its LRP minus its own background,
        estimated until measured (§9.2, design §6). Recognised: the places the map puts
        near the estimate, and of the others those most like the view (as for a
        revisit), which count only by ``certain_lead``."""
        near = self._near_estimate(known, tracked, self.settings.known_within_m)
        ids = [p for p in known.places if p != exclude and (near is None or p in near)]
        ids += self._most_like_view(known, grey, [p for p in known.places
                                                  if p != exclude and p not in ids])
        return taken_over({sc.place_id: sc.lead for sc in score(ids)}, self.settings, near)
