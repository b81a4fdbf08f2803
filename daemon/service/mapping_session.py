"""The one place where the map changes (design §6): what a belief, a learned place or a
closed cycle does to it, for the daemon and for every experiment alike.

The map has one owner, as RTAB-Map's ``Memory`` owns its map while ``Rtabmap::process``
drives: the session holds the :class:`~daemon.service.mapper.Mapper` (the map file and
the graph the queries read) and the :class:`~daemon.localisation.known_map.MapHolder`
the localiser reads, and every change goes through it to both — stored first, then
shown to the localiser as a new snapshot. Callers (the daemon's processing thread and
learn job, ``tools/eval/lockstep.py``) hand it beliefs and learned places and publish the
events it returns; they keep no copy of the map.

In localisation mode the map is read only: a belief changes nothing (a closed cycle, a
background measured are logged and dropped) and no place is learned.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from daemon.localisation.belief import Belief, MapUpdates, PlaceScore
from daemon.localisation.known_map import KnownMap
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.acquisition import taken_over
from daemon.mapping.place import Place
from daemon.mapping.settings import AcquisitionSettings
from daemon.mapping.transition import Transition
from daemon.mapping.unmapped import UnmappedWatch
from daemon.service.learn_ahead import LearnAhead
from daemon.service.mapper import Link, Mapper, Seen
from daemon.service.pipeline import holder_of
from daemon.vision.recognition import PreparedTemplates
from kernel.errors import PlacecellError
from kernel.se2 import SE2
from kernel.types import Odometry

log = logging.getLogger(__name__)

Mode = Literal["mapping", "localisation"]
# What a change of the map tells subscribers: (event kind, fields), design §11.
Event = tuple[str, dict[str, Any]]


@dataclass(frozen=True)
class Learned:
    """A place stored by :meth:`MappingSession.store_place`."""

    place: Place  # without its reference panorama
    transitions: list[Transition]  # its transitions, both ways
    lookalikes: list[int] = field(default_factory=list)  # places it was told apart from
    events: list[Event] = field(default_factory=list)


def segment_events(new_place: int | None, before: dict[int, int], after: dict[int, int],
                   by: dict[str, Any]) -> list[Event]:
    """What a change of the map did to its segments (design §6): a place learned with
    no transition starts one; a transition between two joins them."""
    count = len(set(after.values()))
    events: list[Event] = []
    if new_place is not None and after.get(new_place) == new_place and before \
            and list(after.values()).count(new_place) == 1:
        events.append(("segment_started", {
            "place": new_place, "segments": count,
            "reason": "learned with no transition to a known place: unmapped space, or the "
                      "robot's pose was unknown"}))
    merged: dict[int, set[int]] = {}
    for place, segment in before.items():
        if place in after:
            merged.setdefault(after[place], set()).add(segment)
    for segment, parts in sorted(merged.items()):
        if len(parts) > 1:
            log.info("segments %s joined into segment %d (%d left)", sorted(parts), segment,
                     count)
            events.append(("segments_joined", {"segment": segment, "joined": sorted(parts),
                                               "segments": count, "by": by}))
    return events


def _held_events(confirmed: list[Transition]) -> list[Event]:
    """One `transition_added` a held odometry transition the map confirmed (both ways
    given, each announced once)."""
    return [("transition_added", {"source": "odometry", "held": True, "from": t.from_id,
                                  "to": t.to_id})
            for t in confirmed[::2]]


class MappingSession:
    """The map's owner (module docstring). ``mode`` may change while it runs (cmd/mode)."""

    def __init__(self, mapper: Mapper, acquisition: AcquisitionSettings,
                 localisation: LocalisationSettings, mode: Mode = "mapping") -> None:
        self.mapper = mapper
        self.acquisition = acquisition
        self.localisation = localisation
        self.mode: Mode = mode
        self._lock = threading.Lock()  # one change of the map at a time
        with mapper.lock:
            self.holder = holder_of(mapper.graph)
        mapper.prepared_elsewhere = self._prepared
        self.unmapped = UnmappedWatch(acquisition)
        self._taken_before: set[int] = set()  # places taken from the fleet at begin_place
        self._ahead: LearnAhead | None = None  # the place in work's matching, as it drives

    def _prepared(self, place_id: int) -> PreparedTemplates | None:
        known = self.holder.current.places.get(place_id)
        return None if known is None else known.templates

    @property
    def known(self) -> KnownMap:
        """The map as the localiser reads it now."""
        return self.holder.current

    @property
    def mapping(self) -> bool:
        return self.mode == "mapping"

    # ------------------------------------------------------------ per frame
    def observe(self, belief: Belief, updates: MapUpdates) -> list[Event]:
        """What a frame does to the map (``updates``, found beside ``belief``): the floor
        model learned, backgrounds measured as the robot left places, a cycle closed
        (§7.1.3), the watched place's background reached (design §6); a loss where the
        view contradicted the estimate ends the odometry run from the last place learned
        (a loss by blind travel does not: between places out of view, odometry is the
        link, §7.1.2). Returns the events to publish."""
        if belief.event is not None and belief.event.kind == "lost" \
                and belief.event.contradicted:
            self.mapper.odometry_doubted()  # carried off? odometry cannot tell
        if not self.mapping:
            if updates.closed_transition is not None:
                t = updates.closed_transition
                log.info("cycle %d -> %d measured; not stored in localisation mode",
                         t.from_id, t.to_id)
            return []
        events: list[Event] = []
        mapper = self.mapper
        if updates.floor_learned is not None and mapper.graph.floor is None:
            mapper.save_floor(updates.floor_learned)
            log.info("floor model learned from the first colour frame and stored with the "
                     "map (gradient threshold %.3f)", updates.floor_learned.gradient_threshold)
        backgrounds = list(updates.backgrounds)
        if belief.acquisition is not None:
            backgrounds.append((belief.acquisition.place_id,
                                belief.acquisition.background_lrp))
        for place_id, background in backgrounds:
            self._set_background(place_id, background)
        for place_id, background in updates.backgrounds:
            events.append(("background_measured", {"place": place_id,
                                                   "background_lrp": round(background, 4)}))
        decision = belief.acquisition
        if decision is not None:
            events.append(("background_reached", {"place": decision.place_id,
                                                  "lrp": round(decision.lrp, 4),
                                                  "distance_m": round(decision.distance_m, 3)}))
        if updates.closed_transition is not None:
            events += self.add_cycle(updates.closed_transition)
        return events

    def _set_background(self, place_id: int, background: float) -> None:
        with self._lock:
            self.mapper.set_background(place_id, background)
            if place_id in self.holder.current:
                self.holder.replace(lambda m: m.with_background(place_id, background))

    def add_cycle(self, transition: Transition) -> list[Event]:
        """A cycle closed by local estimates in both places (design §6, §7.1.3): stored,
        and the `map` frame embedded again."""
        m = transition.T_from_to.mean
        return self._add_transition(transition, "the cycle's", {
            "source": "cycle", "x": round(m.x, 4), "y": round(m.y, 4),
            "yaw": round(m.yaw, 5)})

    def _add_transition(self, transition: Transition, whose: str,
                        fields: dict[str, Any]) -> list[Event]:
        """A transition measured while localising, stored both ways (mapping mode only),
        with the held odometry it confirmed; its segments joined, `transition_added`
        with ``fields``."""
        if not self.mapping:
            return []
        with self._lock:
            before = dict(self.mapper.segment_of)
            try:
                confirmed = self.mapper.add_transition(transition)
            except (PlacecellError, KeyError) as e:
                log.error("could not store %s transition: %s", whose, e)
                return []
            self.holder.replace(lambda m: m.with_transitions([transition, *confirmed]))
            after = dict(self.mapper.segment_of)
        ends = {"from": transition.from_id, "to": transition.to_id}
        by = {**ends, **({"robot": fields["robot"]} if "robot" in fields else {})}
        return [*segment_events(None, before, after, by),
                ("transition_added", {**fields, **ends}), *_held_events(confirmed)]

    # ------------------------------------------------------------ the fleet
    def adopt_place(self, place: Place, views: list[np.ndarray], robot: str,
                    origin_id: int) -> list[Event]:
        """A place another robot learned, taken from the fleet (docs/fleet.md): stored
        and shown to the localiser (mapping mode only: in localisation mode the map is
        read-only). Returns the events to publish."""
        if not self.mapping:
            return []
        with self._lock:
            stored = self.mapper.adopt_place(place, views, robot, origin_id)
            self.holder.replace(lambda m: m.with_places([stored]))
        return [("place_adopted", {"place": stored.id, "robot": robot,
                                   "origin_id": origin_id})]

    def adopt_transition(self, transition: Transition, robot: str) -> list[Event]:
        """A transition ``robot`` measured between two places both in this map now
        (their ids here): stored both ways, the `map` frame embedded again (as a closed
        cycle's, add_cycle). Returns the events to publish."""
        return self._add_transition(transition, f"robot {robot}'s",
                                    {"source": transition.source, "robot": robot})

    def site_tie(self) -> tuple[str, SE2] | None:
        """The map frame's pose in a site's map (its frame name), if tied (design §11)."""
        tie = self.mapper.store.site_tie()
        return None if tie is None else (tie[0], SE2(*tie[1:]))

    def tie_site(self, frame: str, T_site_map: SE2) -> None:
        """Tie the map frame to a site's map ``frame`` (nav2's occupancy map): the map
        frame's pose in it, stored with the map (in either mode: no place changes).
        PlacecellError when the map file cannot be written."""
        with self._lock:
            self.mapper.store.save_site_tie(frame, T_site_map.x, T_site_map.y, T_site_map.yaw)

    # ------------------------------------------------------------ the autopilot
    def wants_place(self, belief: Belief, latest_odometry: Odometry | None,
                    job_running: bool) -> str | None:
        """Why autonomous acquisition learns a place now (design §6), None: not now. The
        first place on an empty map as soon as the robot can learn; then each time the
        watched place's background is reached while the robot is tracked; and, on a map
        with places, in unmapped space after a search that found nothing (a new
        segment: a restart resumes, it never re-learns)."""
        lost_in_unmapped_space = self.unmapped.observe(
            belief.state in ("tracking", "uninitialised") or job_running, latest_odometry)
        decision = belief.acquisition
        if not self.mapping or not self.acquisition.enabled or job_running \
                or not belief.odometry_ok or (decision is not None
                                              and belief.state != "tracking"):
            return None
        if decision is not None:
            return f"place {decision.place_id}'s background reached"
        if self.mapper.place_count() == 0:
            return "the first one"
        if not lost_in_unmapped_space:
            return None
        # A segment of its own: the odometry from the last place held until the map can
        # check it (the robot may have been carried), no link from an estimate.
        why = (f"unmapped space: no known place found in {self.unmapped.frames} frames "
               f"over {self.unmapped.travelled_m:.2f} m; a new segment")
        self.mapper.odometry_doubted("no known place found")
        return why

    def learning_started(self) -> None:
        self.unmapped.reset()

    # ------------------------------------------------------------ learning
    def learn_ahead(self) -> LearnAhead:
        """The matching of the place about to be learned, done while its cross is driven
        (daemon/service/learn_ahead.py; hand it to ``drive_tbl``); store_place reads it,
        cancel_place stops it."""
        if self._ahead is not None:
            self._ahead.cancel()
        self._ahead = LearnAhead(self.mapper, self.localisation)
        return self._ahead

    def begin_place(self, reference: Odometry, seen: Seen | None) -> list[Link]:
        """A place is being learned at the pose where odometry read ``reference``
        (Mapper.begin_place)."""
        with self.mapper.lock:
            self._taken_before = set(self.mapper.origins)
        links = self.mapper.begin_place(reference, seen)
        if self._ahead is not None:
            self._ahead.joined(links)
        return links

    def taken_meanwhile(self, score: Callable[[list[int]], list[PlaceScore]]
                        ) -> tuple[int, str] | None:
        """A place taken from the fleet while this one was being learned (since
        begin_place) that stands out in the new place's reference view, scored by
        ``score`` (LRP and lead over its background there), by the rule by which the
        autopilot takes a known place over instead of learning (``taken_over``, design
        §6): (its id here, the robot that learned it), else None. Two robots that
        reached one spot within a learn's drive of each other each learned a place
        there (the fleet experiment on 3 m stretches: two places 0.29 m apart); the one
        that started second, and so finishes second, has the other's place by then."""
        with self.mapper.lock:
            meanwhile = sorted(set(self.mapper.origins) - self._taken_before)
            robots = {p: self.mapper.origins[p][0] for p in meanwhile}
        if not meanwhile:
            return None
        taken = taken_over({sc.place_id: sc.lead for sc in score(meanwhile)},
                           self.acquisition)
        return None if taken is None else (taken, robots[taken])

    def cancel_place(self) -> None:
        if self._ahead is not None:
            self._ahead.cancel()
            self._ahead = None
        self.mapper.cancel_place()

    def store_place(self, place: Place, links: list[Link], views: list[np.ndarray],
                    on_stored: Callable[[Place], None] = lambda _: None,
                    seen_at_end: Seen | None = None) -> Learned:
        """A place just learned: stored with its transitions, then its backgrounds in
        other places' views and its look-alikes' features (design §5, §9), then shown
        to the localiser. ``on_stored``: called once the place itself is in the map file
        (a failure after that loses only cues that can be redone); ``seen_at_end``: the
        localiser's reliable estimate once the cross is driven (Mapper.late_link)."""
        ahead, self._ahead = self._ahead, None
        if not self.mapping:
            if ahead is not None:
                ahead.cancel()
            raise PlacecellError("the map is read-only in localisation mode")
        with self._lock:
            before = dict(self.mapper.segment_of)
            try:
                stored, transitions = self.mapper.add_place(place, links, seen_at_end)
                on_stored(stored)
            except Exception:
                if ahead is not None:
                    ahead.cancel()
                raise
            changed: list[Place] = []
            pairs = []
            try:
                measured = None if ahead is None else ahead.finish()
                in_views, in_own_views = ({}, {}) if measured is None else \
                    measured.lrps(stored)
                self.mapper.remember_lrps(in_views)
                changed = self.mapper.measure_cross_backgrounds(stored.id)
                pairs = self.mapper.learn_features(
                    stored.id, views, self.localisation, in_own_views,
                    None if measured is None else measured.foreseen)
            except Exception:  # noqa: BLE001 - the place is stored; cues can be redone
                log.exception("place %d: its backgrounds or look-alikes' features were not "
                              "found", stored.id)
            self.holder.replace(lambda m: m.with_places([stored, *changed])
                                .with_transitions(transitions).with_features(pairs))
            after = dict(self.mapper.segment_of)
        events = segment_events(stored.id, before, after, {"place_learned": stored.id})
        events += [("transition_added", {"source": t.source, "from": t.from_id,
                                         "to": t.to_id})
                   for t in transitions if t.from_id == stored.id]
        events += _held_events([t for t in transitions if stored.id not in
                                (t.from_id, t.to_id)])
        return Learned(stored, transitions, [p.b_id for p in pairs], events)

