"""The map as the localiser reads it (design §6): places with their prepared landmark
templates, transitions both ways, look-alike pairs' features — one immutable snapshot.

The map has one owner (the service's ``MappingSession``); the localiser reads the snapshot
it holds through a :class:`MapHolder` and never edits it. A change makes a new snapshot
(``with_*``, sharing what did not change: a place's templates are prepared once) that
replaces the old one whole under the holder's lock; a reader takes ``holder.current`` once
and reads that, so a frame sees one map however many changes arrive meanwhile.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType

import numpy as np

from daemon.mapping.backgrounds import Levels, levels, place_background, search_background
from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.vision.disambiguation import PairFeatures
from daemon.vision.recognition import PreparedTemplates
from kernel.se2 import SE2, UncertainSE2

EMPTY: Mapping = MappingProxyType({})


@dataclass(frozen=True)
class KnownPlace:
    place: Place  # without its reference panorama
    templates: PreparedTemplates


class KnownMap:
    """One snapshot of the map (module docstring). Build with :meth:`of`; change with
    the ``with_*`` methods, which return a new snapshot."""

    def __init__(self, places: Mapping[int, KnownPlace] = EMPTY,
                 links: Mapping[int, Mapping[int, UncertainSE2]] = EMPTY,
                 features: Mapping[frozenset[int], PairFeatures] = EMPTY) -> None:
        self.places: Mapping[int, KnownPlace] = MappingProxyType(dict(places))
        self.links: Mapping[int, Mapping[int, UncertainSE2]] = MappingProxyType(
            {a: MappingProxyType(dict(b)) for a, b in links.items()})  # from -> to -> T
        self.features: Mapping[frozenset[int], PairFeatures] = MappingProxyType(dict(features))

    @classmethod
    def of(cls, places: Iterable[Place], transitions: Iterable[Transition] = (),
           features: Iterable[PairFeatures] = ()) -> KnownMap:
        known = {p.id: _known(p) for p in sorted(places, key=lambda p: p.id)}
        links: dict[int, dict[int, UncertainSE2]] = {}
        for transition in transitions:
            for t in transition.both_ways():
                links.setdefault(t.from_id, {})[t.to_id] = t.T_from_to
        return cls(known, links, {frozenset((f.a_id, f.b_id)): f for f in features})

    def __len__(self) -> int:
        return len(self.places)

    def __contains__(self, place_id: object) -> bool:
        return place_id in self.places

    def place(self, place_id: int) -> Place:
        return self.places[place_id].place

    # ------------------------------------------------------------------ changes
    def with_places(self, places: Iterable[Place]) -> KnownMap:
        """Places added or replaced; a place whose landmarks did not change keeps its
        prepared templates (a background or cue changed)."""
        known = dict(self.places)
        for p in places:
            before = known.get(p.id)
            known[p.id] = KnownPlace(_bare(p), before.templates) \
                if before is not None and before.place.landmarks is p.landmarks else _known(p)
        return KnownMap(known, self.links, self.features)

    def with_transitions(self, transitions: Iterable[Transition]) -> KnownMap:
        """Transitions added (each both ways), replacing earlier ones between the same
        two places."""
        links = {a: dict(b) for a, b in self.links.items()}
        for transition in transitions:
            for t in transition.both_ways():
                links.setdefault(t.from_id, {})[t.to_id] = t.T_from_to
        return KnownMap(self.places, links, self.features)

    def with_features(self, pairs: Iterable[PairFeatures]) -> KnownMap:
        features = dict(self.features)
        for pair in pairs:
            features[frozenset((pair.a_id, pair.b_id))] = pair
        return KnownMap(self.places, self.links, features)

    def with_background(self, place_id: int, background_lrp: float) -> KnownMap:
        """The place's background LRP, measured as the robot left it (design §6)."""
        known = self.places[place_id]
        return self.with_places([replace(known.place, background_lrp=background_lrp)])

    # ------------------------------------------------------------------ reading
    @functools.cached_property
    def levels(self) -> Levels | None:
        """The map's background levels in the places' own and other views (design §9),
        made once per snapshot."""
        return levels(k.place for k in self.places.values())

    def background(self, place_id: int, default: float, estimated: bool) -> float:
        """The place's background LRP (daemon/mapping/backgrounds.py: ``place_background``):
        measured; else, ``estimated`` (the global search, which compares every place with
        every other), its estimate on the map's own-view level; else ``default``.
        Tracking between places compares a place with its neighbours, where the default
        measured best (cyclic, office 1: 0.013 m mean against 0.066 with the estimates)."""
        return place_background(self.places[place_id].place, default,
                                self.levels if estimated else None, estimated)

    def estimated_background(self, place_id: int) -> float | None:
        """Measured, else the search's estimate; None: the place has neither (or is not
        in the map)."""
        known = self.places.get(place_id)
        return None if known is None else search_background(known.place, self.levels)

    def neighbours(self, place_id: int) -> Mapping[int, UncertainSE2]:
        return self.links.get(place_id, EMPTY)

    def through_graph(self, start: int, max_places: int | None = None
                      ) -> dict[int, UncertainSE2]:
        """T_start_p of the places nearest ``start`` by transitions (breadth first, the
        first path found, its covariance composed along it), up to ``max_places`` (every
        place it reaches when None); ``start`` excluded."""
        limit = len(self.places) if max_places is None else max_places
        found = {start: UncertainSE2(SE2(), np.zeros((3, 3)))}
        queue = [start]
        while queue and len(found) < limit:
            a = queue.pop(0)
            for b, T in self.links.get(a, EMPTY).items():
                if b not in found:
                    found[b] = found[a].compose(T)
                    queue.append(b)
        del found[start]
        return found


def _bare(place: Place) -> Place:
    return place if place.reference_panorama is None else replace(place,
                                                                  reference_panorama=None)


def _known(place: Place) -> KnownPlace:
    return KnownPlace(_bare(place), PreparedTemplates.of(place.landmarks.templates()))


class MapHolder:
    """The current :class:`KnownMap`, replaced whole under one lock (module docstring):
    its owner changes it with :meth:`replace`; readers take :attr:`current`."""

    def __init__(self, known: KnownMap | None = None) -> None:
        self._lock = threading.Lock()
        self._current = known or KnownMap()

    @property
    def current(self) -> KnownMap:
        return self._current

    def replace(self, change: Callable[[KnownMap], KnownMap]) -> KnownMap:
        """The map after ``change`` (applied to the current one, under the lock)."""
        with self._lock:
            self._current = change(self._current)
            return self._current
