"""A learn's matching done while the robot drives its cross (design §13).

After the drive a learn measures its landmarks in other places' reference views (its
cross background, design §9; the look-alike candidates' views, §5) and the candidate
look-alikes' landmarks in its own views (§5). All of that is known before the drive
ends but which 16 of the 32 candidates are kept (thesis §4.3): the candidates as the
cross starts (§4.2), the reference view then, a view half-way out along each arm as the
robot passes it. An LRP is the mean of each template's best NCC (thesis §4.4, design
§3), so each candidate's best NCC in a view is measured meanwhile, and after the drive
the place's LRP there is the mean over the kept ones: what measuring the kept templates
gives, to the last digit. The places likeliest to look alike (by signature, design §5)
are taken again with each view over the views so far, so the last list is the one the
mapper will take, with a few spare for the places the map will put near the new one
(left out of its list); a place that drops out of the list was measured for nothing.
With the last view the look-alike test is run on the candidates the cross would keep
were it to end there, and the features of the look-alikes it finds are found: the
features of a pair depend on the two places' views alone, so after the drive those the
test finds again are taken as they are.

What the drive did not foresee (a place adopted from the fleet meanwhile, a near place's
successor in the list) is measured after it, as before; the mapper takes from here only
what is here. The work runs in a thread of its own, so the drive's frames wait for none
of it; at the end the learn waits for what is still queued (counted in its computing
time, ``place_learned.compute_s``).
"""

from __future__ import annotations

import logging
import math
import queue
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.backgrounds import views_of
from daemon.mapping.lookalikes import Foreseen, likeliest, pair_features
from daemon.mapping.place import Place
from daemon.service.mapper import Link, Mapper
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.recognition import (
    FastMatcher,
    PreparedPanorama,
    PreparedTemplates,
    best_ncc_elsewhere,
)
from kernel.panorama import to_grey
from kernel.se2 import SE2

log = logging.getLogger(__name__)

NOT_STORED = -1  # the new place's id while it is not in the map
# Places beyond the ``lookalike_candidates`` likeliest taken ahead: the final list
# leaves out the places the map puts near the new one, and takes the next instead.
SPARE_CANDIDATES = 8


@dataclass
class Measured:
    """What a learn measured while its cross was driven."""

    candidates: LandmarkSet  # the cross's candidates, in selection order (§4.2)
    # place id → each candidate's best NCC in that place's reference view
    in_place_views: dict[int, np.ndarray] = field(default_factory=dict)
    # own view (0 = the reference, then the views half-way out) → each candidate's best NCC
    in_own_views: dict[int, np.ndarray] = field(default_factory=dict)
    # (place id, own view) → that place's landmarks' LRP in the view
    places_in_own_views: dict[tuple[int, int], float] = field(default_factory=dict)
    # the features of the look-alikes foreseen with the last view (None: none foreseen)
    foreseen: Foreseen | None = None

    def kept(self, landmarks: LandmarkSet) -> np.ndarray | None:
        """The candidates' indices of a place's landmarks, in the landmarks' order; None
        when one is not among the candidates."""
        index = {(lm.col, lm.row): i for i, lm in enumerate(self.candidates.landmarks)}
        kept = []
        for lm in landmarks.landmarks:
            i = index.get((lm.col, lm.row))
            if i is None or not np.array_equal(self.candidates.landmarks[i].template,
                                               lm.template):
                return None
            kept.append(i)
        return np.array(kept, dtype=np.int64)

    def lrps(self, place: Place) -> tuple[dict[tuple[int, int], float],
                                          dict[tuple[int, int], float]]:
        """The LRPs measured for ``place`` (stored: its id, its kept landmarks): in other
        places' reference views, (landmarks' place, view's place) → LRP, the new place's
        and the likely places' in the new one's reference view (Mapper.remember_lrps);
        and in the new place's own views, (place, view) → LRP (Mapper.learn_features).
        Nothing when its landmarks are not among the candidates."""
        kept = self.kept(place.landmarks)
        if kept is None:
            return {}, {}
        in_views = {(place.id, v): lrp_of(best, kept) for v, best in self.in_place_views.items()}
        in_views |= {(q, place.id): lrp for (q, k), lrp in self.places_in_own_views.items()
                     if k == 0}
        in_own = {(place.id, k): lrp_of(best, kept) for k, best in self.in_own_views.items()}
        return in_views, in_own | self.places_in_own_views


def lrp_of(best: np.ndarray, kept: np.ndarray) -> float:
    """LRP (thesis §4.4) of the kept templates from every candidate's best NCC: the mean
    over them, in their order, as FastMatcher.lrps takes it."""
    return float(best[kept].mean())


class LearnAhead:
    """The matching of one learn, fed by its drive (daemon/service/learning.py:
    ``drive_tbl`` calls ``begin`` once the candidates are chosen, ``view`` with each view
    the cross takes and ``foresee`` with the last; MappingSession.begin_place tells it the
    place's transitions, ``joined``), read once the place is stored (``finish``)."""

    def __init__(self, mapper: Mapper, settings: LocalisationSettings) -> None:
        self._mapper = mapper
        self._settings = settings
        self._tasks: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self._thread: threading.Thread | None = None
        self._cancelled = threading.Event()
        self._measured: Measured | None = None
        self._failed = False
        self._matcher = FastMatcher()
        self._candidates: PreparedTemplates | None = None
        self._greys: list[np.ndarray] = []  # own views
        self._views: list[PreparedPanorama] = []  # the same, prepared once
        self._elsewhere: np.ndarray | None = None  # each candidate's best NCC elsewhere
        self._links: list[tuple[int, SE2]] = []  # (place, T_place_new) it will be stored with
        self._likely: list[int] = []  # every place listed as a likely look-alike so far
        self._margin = 0

    # ------------------------------------------------------------ from the drive
    def begin(self, candidates: LandmarkSet, reference: np.ndarray) -> None:
        """The cross's candidates and its reference panorama (colour or grey)."""
        if self._thread is not None:
            raise RuntimeError("a learn's matching ahead was begun twice")
        self._measured = Measured(candidates)
        self._margin = candidates.margin
        self._tasks.put(("reference", to_grey(reference)))
        self._thread = threading.Thread(target=self._work, name="placecell-ahead",
                                        daemon=True)
        self._thread.start()

    def view(self, grey: np.ndarray) -> None:
        """A view the cross took half-way out along an arm (grey, as it is stored)."""
        if self._thread is not None:
            self._tasks.put(("view", grey))

    def joined(self, links: list[Link]) -> None:
        """The transitions the new place will be stored with (MappingSession.begin_place):
        the places the map will put near it are neighbours, not look-alikes (design §5)."""
        self._links = [(link.from_id, link.T_from_new.mean) for link in links]

    def foresee(self, kept: list[int]) -> None:
        """The candidates the cross would keep were it to end now, told with its last
        view: the look-alikes they give are foreseen, and their features found."""
        if self._thread is not None:
            self._tasks.put(("foresee", kept))

    # ------------------------------------------------------------ after the drive
    def finish(self) -> Measured | None:
        """What was measured, once the queued work is done; None when the drive never
        began or the work failed (the mapper then measures all of it)."""
        if self._thread is None:
            return None
        self._tasks.put(None)
        self._thread.join()
        return None if self._failed or self._cancelled.is_set() else self._measured

    def cancel(self) -> None:
        """The learn ended without a place: stop after the current step."""
        self._cancelled.set()
        if self._thread is not None:
            self._tasks.put(None)

    # ------------------------------------------------------------ the work
    def _work(self) -> None:
        try:
            while (task := self._tasks.get()) is not None:
                if self._cancelled.is_set():
                    return
                kind, data = task
                if kind == "foresee":
                    self._foresee(np.array(data, dtype=np.int64))
                    continue
                self._own_view(data)
                if kind == "reference":
                    self._cross_views()
        except Exception:  # noqa: BLE001 - the mapper measures after the drive instead
            log.exception("a learn's matching during its drive failed; done after it")
            self._failed = True

    def _places(self) -> tuple[list[int], dict[int, np.ndarray | None]]:
        with self._mapper.lock:
            places = self._mapper.graph.places
            return [p.id for p in places], {p.id: p.signature for p in places}

    def _in_place_view(self, place_id: int, at_home: bool = False) -> None:
        """Every candidate's best NCC in a place's reference view; ``at_home``: the place's
        own LRP there too (kept by the mapper), from the one preparation of the view."""
        measured = self._measured
        assert measured is not None and self._candidates is not None
        if self._cancelled.is_set():
            return
        pano = None
        if place_id not in measured.in_place_views:
            pano = PreparedPanorama.of(self._mapper.grey_reference(place_id))
            measured.in_place_views[place_id] = self._matcher.best_ncc(pano,
                                                                       self._candidates)
        if at_home:
            self._mapper.lrps_in_view(place_id, [place_id], view_prepared=pano)

    def _cross_views(self) -> None:
        """The views the new place's cross background will average (its id comes after
        every place's in the map: the first CROSS_VIEWS of them)."""
        ids, _ = self._places()
        for place_id in views_of(-1, ids):
            self._in_place_view(place_id)

    def _own_view(self, grey: np.ndarray) -> None:
        """One own view: every candidate's best NCC in it, the likeliest look-alikes over
        the views so far (design §5) and every likely place's LRP in it, the newly likely
        places' in the views before; their own LRP at home, and the candidates' there."""
        measured = self._measured
        assert measured is not None
        if self._candidates is None:
            self._candidates = PreparedTemplates.of(measured.candidates.templates())
        k = len(self._views)
        pano = PreparedPanorama.of(grey)
        self._greys.append(grey)
        self._views.append(pano)
        measured.in_own_views[k] = self._matcher.best_ncc(pano, self._candidates)
        if self._settings.max_lookalikes == 0:
            return
        _, signatures = self._places()
        likely = likeliest(self._greys, self._margin, signatures,
                           self._settings.lookalike_candidates + SPARE_CANDIDATES)
        before = set(self._likely)
        new = [p for p in likely if p not in before]
        self._likely += new
        for j, view in enumerate(self._views):
            places = self._likely if j == k else new
            if self._cancelled.is_set() or not places:
                continue
            templates = [self._mapper.templates(p) for p in places]
            for p, lrp in zip(places, self._matcher.lrps(view, templates), strict=True):
                measured.places_in_own_views[(p, j)] = lrp
        for p in new:
            self._in_place_view(p, at_home=True)

    def _near(self) -> set[int]:
        """The places the map will put within ``lookalike_min_distance_m`` of the new one,
        by the transitions it will be stored with."""
        near = set()
        with self._mapper.lock:
            graph = self._mapper.graph
            for from_id, T_from_new in self._links:
                if from_id not in graph:
                    continue
                T_new_from = T_from_new.inverse()
                for p, T_from_p in [(from_id, SE2()), *graph.reached(from_id).items()]:
                    T = T_new_from.compose(T_from_p)
                    if math.hypot(T.x, T.y) < self._settings.lookalike_min_distance_m:
                        near.add(p)
        return near

    def _foresee(self, kept: np.ndarray) -> None:
        """The look-alike test as the mapper will run it once the place is stored
        (Mapper.find_lookalikes), on the candidates the cross would keep now, and the
        features of the look-alikes it finds (pair_features): taken after the drive for
        those it finds again."""
        measured = self._measured
        if measured is None or self._settings.max_lookalikes == 0 or self._cancelled.is_set():
            return
        if self._elsewhere is None:  # the background estimate's, per candidate
            self._elsewhere = best_ncc_elsewhere(
                self._greys[0], self._margin, measured.candidates.templates(),
                measured.candidates.cols(), measured.candidates.rows())
        own = PreparedTemplates.of(measured.candidates.templates()[kept])

        def at_home(p: int) -> list[float]:
            self._in_place_view(p, at_home=True)
            return [*self._mapper.lrps_in_view(p, [p]),
                    lrp_of(measured.in_place_views[p], kept)]

        def known(p: int, k: int) -> float | None:
            if p == NOT_STORED:
                return lrp_of(measured.in_own_views[k], kept)
            return measured.places_in_own_views.get((p, k))

        found = self._mapper.find_lookalikes(
            NOT_STORED, self._greys, self._margin, own, lrp_of(self._elsewhere, kept),
            self._near(), self._settings, at_home=at_home, known=known)
        if self._cancelled.is_set() or not found:
            return
        views = {o: [self._mapper.grey_reference(o), *self._mapper.store.views(o)]
                 for o in found}
        pairs = pair_features(NOT_STORED, self._greys, views, self._margin,
                              self._mapper.spread)
        measured.foreseen = Foreseen({pair.b_id: pair.b for pair in pairs}, pairs[0].a)
