"""The topological map in memory: places as nodes, transitions as edges (docs/design.md §6, ch. 7).

Pure: the service loads it from the map file and adds what it stores. Every transition is
held both ways, so neighbours are one dictionary lookup.
"""

from __future__ import annotations

import collections
from collections.abc import Iterable

from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.vision.disambiguation import PairFeatures
from daemon.vision.floor import FloorModel
from kernel.se2 import SE2, UncertainSE2


class TopologicalMap:
    def __init__(self, places: Iterable[Place] = (), transitions: Iterable[Transition] = (),
                 features: Iterable[PairFeatures] = (), floor: FloorModel | None = None
                 ) -> None:
        self.floor = floor  # the floor the places' local space profiles were made with
        self._places: dict[int, Place] = {}
        self._edges: dict[int, dict[int, Transition]] = {}
        self._features: dict[frozenset[int], PairFeatures] = {}  # look-alike pairs (§5)
        for p in places:
            self.add_place(p)
        for t in transitions:
            self.add_transition(t)
        for f in features:
            self.add_features(f)

    def add_features(self, pair: PairFeatures) -> None:
        """The disambiguating features of two look-alike places (design §5); replaces
        the pair's earlier ones."""
        if pair.a_id not in self._places or pair.b_id not in self._places:
            raise KeyError(f"features of {pair.a_id} and {pair.b_id}: both places must be "
                           "in the map")
        self._features[frozenset((pair.a_id, pair.b_id))] = pair

    @property
    def features(self) -> list[PairFeatures]:
        return list(self._features.values())

    def add_place(self, place: Place) -> None:
        if place.id <= 0:
            raise ValueError("a place joins the map with the id the map file gave it")
        self._places[place.id] = place
        self._edges.setdefault(place.id, {})

    def add_transition(self, transition: Transition) -> None:
        """Adds it and its reverse; replaces an earlier measurement between the same two."""
        for t in transition.both_ways():
            if t.from_id not in self._places or t.to_id not in self._places:
                raise KeyError(f"transition {t.from_id} -> {t.to_id}: both places must be in "
                               "the map")
            self._edges[t.from_id][t.to_id] = t

    def place(self, place_id: int) -> Place:
        return self._places[place_id]

    def __contains__(self, place_id: object) -> bool:
        return place_id in self._places

    def __len__(self) -> int:
        return len(self._places)

    @property
    def places(self) -> list[Place]:
        return list(self._places.values())

    @property
    def transitions(self) -> list[Transition]:
        """Every transition, both directions."""
        return [t for edges in self._edges.values() for t in edges.values()]

    def neighbours(self, place_id: int) -> list[Transition]:
        """Transitions out of ``place_id``."""
        return list(self._edges.get(place_id, {}).values())

    def reached(self, start: int, max_places: int = 64) -> dict[int, SE2]:
        """T_start_p of the places nearest ``start`` by transitions (breadth first, the
        first path found composed along it), up to ``max_places``; ``start`` excluded."""
        found = {start: SE2()}
        queue = [start]
        while queue and len(found) < max_places:
            a = queue.pop(0)
            for b, t in self._edges.get(a, {}).items():
                if b not in found:
                    found[b] = found[a].compose(t.T_from_to.mean)
                    queue.append(b)
        del found[start]
        return found

    def path(self, start: int, end: int) -> UncertainSE2 | None:
        """T_start_end composed along the path of fewest transitions (breadth first),
        with its covariance; None when no path joins them."""
        found = {start: UncertainSE2(SE2())}
        queue = collections.deque([start])
        while queue:
            a = queue.popleft()
            if a == end:
                return found[a]
            for b, t in self._edges.get(a, {}).items():
                if b not in found:
                    found[b] = found[a].compose(t.T_from_to)
                    queue.append(b)
        return None

    def transition(self, from_id: int, to_id: int) -> Transition | None:
        return self._edges.get(from_id, {}).get(to_id)

    def segments(self) -> dict[int, int]:
        """Each place's *segment*: the connected part of the map it is in, named by its
        lowest place id (design §6). A place learned after a loss in unmapped space
        starts a segment of its own; a transition measured between two segments joins
        them. Only the segment of the lowest id is embedded in the `map` frame."""
        segment: dict[int, int] = {}
        for start in sorted(self._places):
            if start in segment:
                continue
            segment[start] = start
            stack = [start]
            while stack:
                a = stack.pop()
                for b in self._edges.get(a, {}):
                    if b not in segment:
                        segment[b] = start
                        stack.append(b)
        return segment
