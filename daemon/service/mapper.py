"""The map as the running daemon keeps it: the map file, the map in memory, and the run of
odometry since the last place learned (design §6).

Thread-safe: odometry arrives on the processing thread, places from the learn job, queries
from zenoh's threads. A place is stored with its transition in one transaction
(daemon/store) before the map in memory shows it.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.backgrounds import views_of
from daemon.mapping.embedding import embed
from daemon.mapping.graph import TopologicalMap
from daemon.mapping.lookalikes import (
    Foreseen,
    MappedPlace,
    in_turn,
    likeliest,
    lookalikes,
    lrps_in_views,
    pair_features,
)
from daemon.mapping.odometry_chain import OdometryChain, held_verdict
from daemon.mapping.place import Place, with_cues
from daemon.mapping.settings import OdometryNoiseSettings
from daemon.mapping.transition import Transition, TransitionSource
from daemon.store.sqlite_store import MapStore, PlaceSummary
from daemon.vision.disambiguation import PairFeatures
from daemon.vision.floor import FloorModel
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from kernel.panorama import to_grey
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry

log = logging.getLogger(__name__)
T = TypeVar("T")
R = TypeVar("R")


def background_of(place: Place, default: float) -> float:
    """The place's background LRP: measured, else the estimate made when it was
    learned, else ``default`` (design §9)."""
    for value in (place.background_lrp, place.background_estimate):
        if value is not None:
            return value
    return default


@dataclasses.dataclass(frozen=True)
class Link:
    """Where a place being learned stands from the last place: T_last_new from odometry,
    or from odometry and the local estimate fused ("vision")."""

    from_id: int
    T_from_new: UncertainSE2
    source: TransitionSource = "odometry"


# The localiser's estimate of the robot in a place: (place id, T_place_robot).
Seen = tuple[int, UncertainSE2]

# A place learned while tracked in another place of the map is joined to it only from
# this near its reference: further out the estimate is more often a wrong mode than a
# pose. Office 3's first pass learned 22 places tracked in another place than the last;
# of the 15 with the estimate within 2 m of that place's reference, 13 were right to
# 0.1 m (one stood in a look-alike 10 m away, one was still relocalising: not reliable);
# of the 7 beyond, 6 were 1.3-15 m off.
CLOSING_MAX_M = 2.0

# Grey reference panoramas kept decoded (90 kB each at 752 x 120): every learn reads the
# first CROSS_VIEWS places' (its cross background) and its look-alike candidates'.
REFERENCES_KEPT = 128
# LRPs of one place's landmarks in another's reference view kept (a learn reads up to 200:
# its own in its cross background's views and its candidates', each candidate's in its own).
LRPS_KEPT = 4096


def _closing(seen: Seen) -> list[Link]:
    """The link from the place the robot is tracked in, when it is not the last place
    learned: none when the estimate stands too far from that place's reference."""
    place_id, T_place_robot = seen
    near = math.hypot(T_place_robot.mean.x, T_place_robot.mean.y) <= CLOSING_MAX_M
    return [Link(place_id, T_place_robot, "vision")] if near else []


class Mapper:
    def __init__(self, store: MapStore, noise: OdometryNoiseSettings, threads: int = 1) -> None:
        """``threads``: how many threads a learn's matching is spread over (spread)."""
        self.store = store
        self.noise = noise
        self._pool = None if threads <= 1 else concurrent.futures.ThreadPoolExecutor(
            threads, thread_name_prefix="placecell-match")
        self._lock = threading.RLock()
        self._references: collections.OrderedDict[int, np.ndarray] = \
            collections.OrderedDict()  # grey, by place id, the last used last
        self._lrps: collections.OrderedDict[tuple[int, int], float] = \
            collections.OrderedDict()  # (landmarks' place, view's place) → LRP, as above
        # A place's templates as the localiser's map already holds them prepared (the
        # MappingSession's KnownMap), None for a place it does not hold: not prepared
        # twice, nor kept twice (20 kB a place).
        self.prepared_elsewhere: Callable[[int], PreparedTemplates | None] = lambda _: None
        self.graph: TopologicalMap = store.load()
        # The places taken from other robots: id here → (robot, its id there).
        self.origins: dict[int, tuple[str, int]] = store.origins()
        # ...and the other way: (robot, its id there) → id here, so a fleet sample finds
        # its place at once (a thousand taken places, a start's sync of each of them).
        self.taken: dict[tuple[str, int], int] = {o: p for p, o in self.origins.items()}
        # Each place's segment (design §6), replaced whole on every change of the map.
        self.segment_of: dict[int, int] = self.graph.segments()
        self._fill_cues()
        # design §6: each place's pose in the `map` frame; empty until first optimised
        # (off the caller's thread: seconds on a map of a thousand places).
        self.map_frame: dict[int, SE2] = {}
        self._embedding = 0  # the last optimisation asked for
        self._embedded = 0  # the one map_frame holds
        self._last_place: int | None = None  # learned in this run of odometry
        self._chain: OdometryChain | None = None  # from that place's reference pose
        self._pending: OdometryChain | None = None  # from the reference of a place in work
        # Odometry transitions measured across a doubt (odometry_doubted), each waiting
        # for a path through the map between its places to check it; the place in work's
        # own, until it is stored. Kept in memory: a restart breaks the odometry anyway.
        self._held: list[Transition] = []
        self._held_pending: Link | None = None
        self._recent: collections.deque[Odometry] = collections.deque(maxlen=500)
        self.reembed()

    def _fill_cues(self) -> None:
        """Places stored before the map held the global search's cues (schema 2) get
        them from their reference panoramas, once (a read-only map is left as it is)."""
        if self.store.readonly:
            return
        for place in list(self.graph.places):
            if place.background_estimate is None or place.signature is None:
                full = with_cues(self.store.place(place.id, panorama=True))
                assert full.background_estimate is not None and full.signature is not None
                self.store.set_cues(place.id, full.background_estimate, full.signature)
                self.graph.add_place(dataclasses.replace(full, reference_panorama=None))
                log.info("place %d: background LRP estimated at %.3f", place.id,
                         full.background_estimate)
        missing = [p.id for p in self.graph.places if p.background_cross is None]
        if missing and len(self.graph) > 1:
            self._store_cross_backgrounds(missing)

    # ------------------------------------------------------------ odometry
    def on_odometry(self, samples: list[Odometry]) -> None:
        with self._lock:
            for s in samples:
                self._recent.append(s)
                for chain in (self._chain, self._pending):
                    if chain is not None:
                        chain.add(s)

    def odometry_restarted(self) -> None:
        """The base was opened again: its odometry may start from anywhere, so no
        transition is measured across the restart."""
        with self._lock:
            for chain in (self._chain, self._pending):
                if chain is not None:
                    chain.break_off("the base was opened again")

    def odometry_doubted(self, why: str = "tracking was lost, the view contradicting the "
                                          "estimate") -> None:
        """The robot may have been carried off, which odometry cannot see: the run of
        odometry from the last place learned is held, not trusted (office 2: the next
        place linked to it by 4.7 m of odometry across a kidnap put a place 9.8 m off,
        and the tracker switched there). A place learned before the run ends gets its
        odometry transition only once a path through the map checks it
        (:meth:`_settle_held`). A place being learned keeps its own run: its job
        watches the robot."""
        with self._lock:
            if self._chain is not None:
                self._chain.doubt(why)

    # ------------------------------------------------------------ learning
    def begin_place(self, reference: Odometry, seen: Seen | None = None) -> list[Link]:
        """A place is being learned at the pose where odometry read ``reference``: start
        measuring from it, and say where it stands from the places it joins (none: no
        unbroken run of odometry from the last place, and no estimate). ``seen``: the
        localiser's reliable estimate of the robot there. In the last place it is fused
        with the odometry (the odometry alone drifts over every Turn Back and Look cross
        driven since); in another place of the map it joins the new place to that one
        as well — the robot is back where the map has been, and the link closes the
        cycle there (§7.1.3) — or alone, when odometry cannot."""
        with self._lock:
            self._pending = OdometryChain(reference, self.noise)
            for s in self._recent:
                if s.stamp_ns > reference.stamp_ns:
                    self._pending.add(s)
            chain, last = self._chain, self._last_place
            odometry = None if chain is None or last is None or chain.broken \
                or last not in self.graph else Link(last, chain.relative_at(reference))
            self._held_pending = None
            if odometry is not None and chain is not None and chain.doubted_by is not None:
                self._held_pending, odometry = odometry, None
            if seen is None or seen[0] not in self.graph:
                if odometry is None and last is not None and last in self.graph:
                    # Joined to the map only when a cycle is later closed to it (which
                    # checks the held odometry too); the localiser reaches it meanwhile
                    # as it reaches an unjoined place.
                    why = "no odometry run"
                    if chain is not None:
                        why = chain.broken_by or (
                            f"{chain.doubted_by}: its odometry held until the map checks it"
                            if chain.doubted_by else why)
                    log.warning("place being learned: no transition from place %d (%s) and "
                                "no reliable estimate to join it by yet", last, why)
                return [] if odometry is None else [odometry]
            if odometry is None:
                return [Link(seen[0], seen[1], "vision")]
            if odometry.from_id != seen[0]:
                return [odometry, *_closing(seen)]
            if not odometry.T_from_new.agrees_with(seen[1]):
                # A confident estimate the odometry contradicts: one of them is wrong, and
                # fusing would make a link no one measured; odometry fails gracefully.
                log.warning("place being learned: the estimate in place %d %s disagrees "
                            "with the odometry %s; linked by odometry alone", seen[0],
                            seen[1].mean, odometry.T_from_new.mean)
                return [odometry]
            return [Link(seen[0], odometry.T_from_new.fuse(seen[1]), "vision")]

    def late_link(self, seen: Seen) -> list[Link]:
        """The link of a place in work that began with none (its odometry run from the
        last place ended by a loss or a gap, and no reliable estimate then), from the
        robot seen reliably in ``seen[0]`` at the end of its cross: Turn Back and Look
        ends where it began (§4.3), so with the odometry run of the cross from the
        reference to here, T_seen_reference = T_seen_robot ⊕ T_reference_robot⁻¹. A
        loss just before a learn may end in relocalisation during it; without this the
        place starts a segment of its own beside the map until a cycle is closed to it.
        As at the start, only near the seen place's reference (``_closing``)."""
        with self._lock:
            pending = self._pending
            if pending is None or pending.broken or seen[0] not in self.graph:
                return []
            T_seen_reference = seen[1].compose(pending.relative().inverse())
            links = _closing((seen[0], T_seen_reference))
        if links:
            log.info("place being learned: joined to place %d by the estimate at the end of "
                     "its cross", seen[0])
        return links

    def cancel_place(self) -> None:
        with self._lock:
            self._pending = self._held_pending = None

    def add_place(self, place: Place, links: list[Link], seen_at_end: Seen | None = None
                  ) -> tuple[Place, list[Transition]]:
        """Store a learned place (with its transitions from the places it joins, both
        ways) and make it the one the next place is measured from. ``seen_at_end``: the
        localiser's reliable estimate once the cross is driven; a place that began with
        no link is joined by it (:meth:`late_link`)."""
        if place.reference_panorama is not None and (
                place.background_estimate is None or place.signature is None):
            place = with_cues(place)
        with self._lock:
            if not links and seen_at_end is not None:
                links = self.late_link(seen_at_end)
            stored = self.store.add_place(
                place, [(link.from_id, link.T_from_new, link.source) for link in links])
            # In memory without its panorama: the map file has it (design §6).
            self.graph.add_place(dataclasses.replace(stored, reference_panorama=None))
            added: list[Transition] = []
            for link in links:
                t = Transition(link.from_id, stored.id, link.T_from_new, link.source)
                self.graph.add_transition(t)
                added.extend(t.both_ways())
            held = self._held_pending
            if held is not None:  # checked by _settle_held, now or once a path joins
                self._held.append(Transition(held.from_id, stored.id, held.T_from_new))
            self._held_pending = None
            self._last_place, self._chain, self._pending = stored.id, self._pending, None
            self.segment_of = self.graph.segments()
            added += self._settle_held()
        self.reembed()
        return stored, added

    def adopt_place(self, place: Place, views: list[np.ndarray], robot: str,
                    origin_id: int) -> Place:
        """Store a place another robot of the fleet learned (its ``origin_id`` there),
        a segment of its own until a transition joins it (docs/fleet.md); it does not
        change which place this robot's odometry runs from."""
        if place.background_estimate is None or place.signature is None:
            place = with_cues(place)
        with self._lock:
            stored = self.store.adopt_place(place, views, robot, origin_id)
            self.graph.add_place(dataclasses.replace(stored, reference_panorama=None))
            self.origins[stored.id] = (robot, origin_id)
            self.taken[(robot, origin_id)] = stored.id
            self.segment_of = self.graph.segments()
        return stored

    def measure_cross_backgrounds(self, place_id: int) -> list[Place]:
        """The backgrounds in other places' views (daemon/mapping/backgrounds.py) that a
        place just learned brings: its own, and those of the places whose views it joins
        (while the map is smaller than CROSS_VIEWS + 1 places); stored and in the map.
        A place whose views only gain the new one gets that view's LRP added to its mean
        (one panorama read, not its every view again). Returns the places whose
        background changed (a read-only map: none)."""
        if self.store.readonly:
            return []
        with self._lock:
            ids = [p.id for p in self.graph.places]
            others = [q for q in ids if q != place_id]
            full, grown = [place_id], {}
            for q in others:
                cross = self.graph.place(q).background_cross
                if cross is None:
                    full.append(q)
                    continue
                after = views_of(q, ids)
                if place_id not in after:
                    continue  # its views are as they were
                before = views_of(q, others)
                if sorted([*before, place_id]) == after:
                    grown[q] = (cross, len(before))
                else:  # the new view pushed another out
                    full.append(q)
        if len(ids) < 2:
            return []
        return self._store_cross_backgrounds(full) + self._grow_cross_backgrounds(
            place_id, grown)

    def _grow_cross_backgrounds(self, view: int, grown: dict[int, tuple[float, int]]
                                ) -> list[Place]:
        """Each place of ``grown`` (its mean over n views) with one view more: ``view``'s
        reference panorama."""
        if not grown:
            return []
        values = {q: (mean * n + lrp) / (n + 1) for (q, (mean, n)), lrp in zip(
            grown.items(), self.lrps_in_view(view, list(grown)), strict=True)}
        return self._keep_cross_backgrounds(values)

    def _store_cross_backgrounds(self, place_ids: list[int]) -> list[Place]:
        """Each place's mean LRP in its views (views_of), measured, stored and in the
        map: each view's panorama is read and prepared once for all the places."""
        with self._lock:
            ids = [p.id for p in self.graph.places]
            templates = {q: self.templates(q) for q in place_ids}
        views = {q: views_of(q, ids) for q in place_ids}
        sums = dict.fromkeys(place_ids, 0.0)
        seen_in = sorted({v for vs in views.values() for v in vs})
        users = {v: [q for q in place_ids if v in views[q]] for v in seen_in}
        measured = self.spread(lambda v: self.lrps_in_view(v, users[v], templates), seen_in)
        for v, lrps in zip(seen_in, measured, strict=True):  # summed in view order
            for q, lrp in zip(users[v], lrps, strict=True):
                sums[q] += lrp
        return self._keep_cross_backgrounds(
            {q: sums[q] / len(views[q]) for q in place_ids if views[q]})

    def lrps_in_view(self, view: int, place_ids: list[int],
                     prepared: dict[int, PreparedTemplates] | None = None,
                     view_prepared: PreparedPanorama | None = None) -> list[float]:
        """The LRP of each place's landmarks in place ``view``'s reference panorama, each
        measured once while among the LRPS_KEPT used last (neither ever changes): a learn
        asks for its own landmarks in its cross background's views and again in its
        look-alike candidates' (the same places until the map passes CROSS_VIEWS), and
        for each candidate's in its own view at every learn it is a candidate in.
        ``prepared``: the places' templates, ``view_prepared``: the view's panorama, if
        the caller has them prepared."""
        with self._lock:
            known = {q: self._lrps[(q, view)] for q in place_ids if (q, view) in self._lrps}
            missing = [q for q in place_ids if q not in known]
            given = prepared or {}
            templates = [given[q] if q in given else self.templates(q) for q in missing]
        if missing:
            pano = view_prepared or PreparedPanorama.of(self.grey_reference(view))
            known.update(zip(missing, FastMatcher().lrps(pano, templates), strict=True))
        self.remember_lrps({(q, view): known[q] for q in place_ids})
        return [known[q] for q in place_ids]

    def remember_lrps(self, lrps: dict[tuple[int, int], float]) -> None:
        """LRPs kept among the LRPS_KEPT used last, (landmarks' place, view's place) →
        LRP: lrps_in_view's own, and a learn's measured during its drive
        (daemon/service/learn_ahead.py)."""
        with self._lock:
            for key, lrp in lrps.items():
                self._lrps[key] = lrp
                self._lrps.move_to_end(key)
            while len(self._lrps) > LRPS_KEPT:
                self._lrps.popitem(last=False)

    def _keep_cross_backgrounds(self, values: dict[int, float]) -> list[Place]:
        with self._lock:
            self.store.set_cross_backgrounds(values)
            changed = [dataclasses.replace(self.graph.place(q), background_cross=value)
                       for q, value in values.items()]
            for place in changed:
                self.graph.add_place(place)
        log.info("%d places: backgrounds in other places' views measured", len(changed))
        return changed

    def learn_features(self, place_id: int, views: list[np.ndarray],
                       settings: LocalisationSettings,
                       in_own_views: dict[tuple[int, int], float] | None = None,
                       foreseen: Foreseen | None = None) -> list[PairFeatures]:
        """The disambiguating features of a place just learned and each of its look-alikes
        (design §5), stored and in the map; ``views``: grey panoramas taken half-way out
        along the arms of its Turn Back and Look cross, stored with the place so that a
        later look-alike's features are scored over them too; ``in_own_views``: LRPs in
        those views measured during the drive, (place, view: 0 the reference, then
        ``views``) → LRP, and ``foreseen``: the features found for the look-alikes the drive
        foresaw (daemon/service/learn_ahead.py). A read-only map gets none."""
        if self.store.readonly or settings.max_lookalikes == 0:
            return []
        with self._lock:
            place = self.graph.place(place_id)
            # Places this near through the map are neighbours, told apart by the pose
            # carried between them; look-alikes that matter stand farther off.
            near = {p for p, T in self.graph.reached(place_id).items()
                    if math.hypot(T.x, T.y) < settings.lookalike_min_distance_m}
        own_views = [self.grey_reference(place_id), *views]
        margin = place.landmarks.margin
        prepared = self.templates(place_id)
        known = in_own_views or {}
        found = self.find_lookalikes(
            place_id, own_views, margin, prepared,
            background_of(place, settings.background_lrp), near | {place_id}, settings,
            at_home=lambda p: self.lrps_in_view(p, [p, place_id], {place_id: prepared}),
            known=lambda q, k: known.get((q, k)))
        self.store.put_views(place_id, views)
        pairs = pair_features(place_id, own_views,
                              {o: [self.grey_reference(o), *self.store.views(o)] for o in found},
                              margin, self.spread, foreseen)
        for pair in pairs:
            with self._lock:
                self.store.put_features(pair)
                self.graph.add_features(pair)
            log.info("place %d looks like place %d: features %d px at column %d against "
                     "%d px at %d", place_id, pair.b_id, pair.a.size, pair.a.col, pair.b.size,
                     pair.b.col)
        return pairs

    def find_lookalikes(self, new_id: int, views: list[np.ndarray], margin: int,
                        own: PreparedTemplates, own_background: float, excluded: set[int],
                        settings: LocalisationSettings, *,
                        at_home: Callable[[int], list[float]],
                        known: Callable[[int, int], float | None]) -> list[int]:
        """The look-alike test of a new place (design §5; daemon/mapping/lookalikes.py)
        among the ``lookalike_candidates`` places of the map likeliest by signature, but
        ``excluded`` (itself, the places the map puts near it). ``new_id``: its id (-1
        while it is not stored: a learn foreseeing its look-alikes during the drive);
        ``views``: its grey views (wrap ``margin``), the reference first; ``own``: its
        templates; ``at_home(p)``: place p's LRP in its own reference view and the new
        place's there; ``known(p, k)``: p's LRP in view k, when measured already."""
        with self._lock:
            signatures = {p.id: p.signature for p in self.graph.places
                          if p.id not in excluded}
            candidates = [self.graph.place(pid) for pid in likeliest(
                views, margin, signatures, settings.lookalike_candidates)
                if pid in self.graph]
        at = self.spread(lambda p: at_home(p.id), candidates)
        prepared = {p.id: self.templates(p.id) for p in candidates} | {new_id: own}
        others = {p.id: MappedPlace(prepared[p.id], background_of(p, settings.background_lrp),
                                    *lrps) for p, lrps in zip(candidates, at, strict=True)}
        ids = [new_id, *others]
        lrps = lrps_in_views(views, [prepared[q] for q in ids],
                             lambda q, k: known(ids[q], k), self.spread)
        return lookalikes(lrps, own_background, others, settings.lookalike_margin,
                          settings.max_lookalikes)

    def spread(self, work: Callable[[T], R], items: Sequence[T]) -> list[R]:
        """``work`` on each item, over the learn's matching threads (``threads``; the
        caller's alone with one), results in the items' order. A learn's matching after
        the drive is many independent searches — views, candidates, look-alikes — whose
        OpenCV, numpy and numba inner loops release the GIL."""
        if self._pool is None or len(items) < 2:
            return in_turn(work, items)
        return list(self._pool.map(work, items))

    def templates(self, place_id: int) -> PreparedTemplates:
        """A place's landmark templates prepared for matching (prepared_elsewhere, else
        here)."""
        with self._lock:
            prepared = self.prepared_elsewhere(place_id)
            return prepared if prepared is not None else PreparedTemplates.of(
                self.graph.place(place_id).landmarks.templates())

    def grey_reference(self, place_id: int) -> np.ndarray:
        """A place's reference panorama in grey, decoded once while it is among the
        REFERENCES_KEPT used last (a stored panorama never changes)."""
        with self._lock:
            grey = self._references.get(place_id)
            if grey is not None:
                self._references.move_to_end(place_id)
                return grey
        grey = to_grey(self.store.reference_panorama(place_id))
        with self._lock:
            self._references[place_id] = grey
            while len(self._references) > REFERENCES_KEPT:
                self._references.popitem(last=False)
        return grey

    def add_transition(self, transition: Transition) -> list[Transition]:
        """A transition measured while localising (a closed cycle, §7.1.3), both ways; the
        `map` frame is optimised again over it. Returns the held odometry transitions
        the new path confirmed (:meth:`_settle_held`), both ways."""
        with self._lock:
            self.store.add_transition(transition)
            self.graph.add_transition(transition)
            self.segment_of = self.graph.segments()
            confirmed = self._settle_held()
        self.reembed()
        return confirmed

    def _settle_held(self) -> list[Transition]:
        """Each held odometry transition (odometry_doubted) whose places a path through
        the map now joins: stored when the path agrees with it (the robot was not
        carried: a false loss at the edge of a place's view, as on the ROS 2 robot's
        cyclic tour, no longer leaves a cycle open), dropped when it does not (it was).
        One pass: a stored one joins places already joined, so it changes no segment and
        lets no other held one settle. Returns those stored, both ways. Called with the
        lock held."""
        stored: list[Transition] = []
        for held in list(self._held):
            a, b = held.from_id, held.to_id
            if a not in self.graph or b not in self.graph \
                    or self.graph.transition(a, b) is not None:
                self._held.remove(held)  # measured otherwise since
                continue
            verdict = held_verdict(held.T_from_to, self.graph.path(a, b))
            if verdict is None:
                continue
            self._held.remove(held)
            if not verdict:
                log.warning("held odometry %d -> %d refused: it disagrees with the map "
                            "(the robot was carried)", a, b)
                continue
            self.store.add_transition(held)
            self.graph.add_transition(held)
            stored.extend(held.both_ways())
            log.info("held odometry %d -> %d confirmed by the map's path and stored", a, b)
        return stored

    def drawn(self) -> tuple[dict[int, tuple[SE2, str]], list[tuple[int, int]]]:
        """What a map view draws: the places embedded in the `map` frame with their
        labels, and each linked pair once."""
        with self._lock:
            frame = self.map_frame
            places = {p.id: (frame[p.id], p.label) for p in self.graph.places if p.id in frame}
            pairs = sorted({(min(t.from_id, t.to_id), max(t.from_id, t.to_id))
                            for t in self.graph.transitions})
        return places, pairs

    def reembed(self) -> threading.Thread:
        """Optimise the `map` frame over the map as it is now, on a thread of its own
        (the processing loop closes cycles; a large map takes seconds); a later
        optimisation's result is never replaced by an earlier one's."""
        with self._lock:
            self._embedding += 1
            job = (self._embedding, TopologicalMap(self.graph.places, self.graph.transitions))
        thread = threading.Thread(target=self._embed, args=job, name="placecell-embed",
                                  daemon=True)
        thread.start()
        return thread

    def _embed(self, generation: int, graph: TopologicalMap) -> None:
        frame = embed(graph)
        with self._lock:
            if generation > self._embedded:
                self.map_frame, self._embedded = frame, generation

    def set_background(self, place_id: int, background_lrp: float) -> None:
        """The place's background LRP, measured as the robot left it (design §6)."""
        with self._lock:
            self.store.set_background(place_id, background_lrp)
            if place_id in self.graph:
                self.graph.add_place(dataclasses.replace(self.graph.place(place_id),
                                                         background_lrp=background_lrp))

    def save_floor(self, floor: FloorModel) -> None:
        """The floor model the localiser learned (design §4): kept with the map, so the
        places' local space profiles are compared under one model in every run."""
        with self._lock:
            self.store.save_floor(floor, time.time())
            self.graph.floor = floor

    @property
    def last_place(self) -> int | None:
        """The place learned last in this run of the daemon (autonomous acquisition
        watches it)."""
        return self._last_place

    # ------------------------------------------------------------ reading
    def summaries(self) -> list[PlaceSummary]:
        with self._lock:
            return [PlaceSummary(p.id, p.label, p.created_unix_s, p.landmark_count,
                                 p.background_lrp) for p in self.graph.places]

    def transitions(self) -> list[Transition]:
        with self._lock:
            return self.graph.transitions

    def place(self, place_id: int, *, panorama: bool = False) -> Place:
        """A place of the map (KeyError if none); its reference panorama read from the map
        file if asked (the graph in memory holds none)."""
        with self._lock:
            if not panorama:
                return self.graph.place(place_id)
            return self.store.place(place_id, panorama=True)

    def neighbours(self, place_id: int) -> list[Transition]:
        with self._lock:
            return self.graph.neighbours(place_id)

    @property
    def lock(self) -> threading.RLock:
        """Held while the map is read as a whole (the graph changes under other threads)."""
        return self._lock

    def has_place(self, place_id: int) -> bool:
        with self._lock:
            return place_id in self.graph

    def place_count(self) -> int:
        with self._lock:
            return len(self.graph)

    def transition_count(self) -> int:
        with self._lock:
            return len(self.graph.transitions)
