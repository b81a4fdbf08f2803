"""Look-alike places and their disambiguating features, when a place is learned (design
§5; thesis chapter 6).

A place already in the map is a *look-alike* of the one being learned when the lower
level tells them apart by less than ``margin`` (LRP minus background) either way: over
the new place's views (its reference and views half-way out along the arms of its Turn
Back and Look cross) the old place scores nearly as well as the new one, or in the old
place's reference view the new place scores nearly as well as the old one. Both ways,
because backgrounds differ from place to place: in the aliased corridor (seed 1) a door
place learned first stands 0.19 below a plain place in the plain place's views, yet
level with it in its own (design §5). The pairs' features are found
(daemon/vision/disambiguation.py): the new place's one feature against every
look-alike's reference view at once, scored over the new place's views so it survives
small moves; each look-alike's against the new place's views, scored over the
look-alike's own learning views (kept with the map since schema 8). Pure: the service's
mapper stores what this returns.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from daemon.vision.disambiguation import Feature, PairFeatures, find_feature, prepared
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from daemon.vision.signature import signature, similarity

T = TypeVar("T")
R = TypeVar("R")
# Runs a function on each item, results in the items' order: in turn, or over threads
# (the mapper's Mapper.spread).
Spread = Callable[[Callable[[T], R], Sequence[T]], list[R]]


def in_turn(work: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``work`` on each item in turn, in the caller's thread (a Spread)."""
    return [work(item) for item in items]


@dataclass(frozen=True)
class MappedPlace:
    """What the look-alike search needs of a place already in the map."""

    templates: PreparedTemplates
    background: float  # LRP
    lrp_at_home: float  # its landmarks' LRP in its own reference view
    new_lrp_at_home: float  # the new place's landmarks' LRP there


def likeliest(views: list[np.ndarray], margin: int, signatures: dict[int, np.ndarray | None],
              limit: int) -> list[int]:
    """The places of ``signatures`` (id → the place's signature, design §9) to look at for
    look-alikes of a new place seen in the grey ``views`` (wrap ``margin``): all when there
    are at most ``limit``, else the ``limit`` most like any of the views, in id order. A
    look-alike is what the global search ranks near the new place, and its cue is this
    similarity; so a learn's work stops growing with the map (placecell-bench --only
    daemon: 28 s on a 1000-place map with every place looked at). A place without a
    signature is kept."""
    ids = sorted(signatures)
    if len(ids) <= limit:
        return ids
    known = [i for i in ids if signatures[i] is not None]
    rows = np.array([signatures[i] for i in known])
    best = np.max([similarity(signature(v, margin), rows) for v in views], axis=0)
    keep = {known[k] for k in np.argsort(-best, kind="stable")[:limit]}
    return [i for i in ids if i in keep or signatures[i] is None]


def lookalikes(lrps: np.ndarray, own_background: float, others: dict[int, MappedPlace],
               margin: float, limit: int) -> list[int]:
    """The places of ``others`` that the lower level tells from the new place by at most
    ``margin`` either way, at most ``limit``, the closest first. ``lrps``: (views, 1 +
    places) the LRP of the new place's landmarks (column 0) and of each of ``others``'
    (in its order) in each of the new place's views (:func:`lrps_in_views`)."""
    if not others:
        return []
    ids = list(others)
    leads = lrps.mean(axis=0) - np.array([own_background] + [others[i].background
                                                             for i in ids])
    gap = leads[0] - leads[1:]  # how far each old place stands below the new one here
    for k, i in enumerate(ids):  # and the new one below the old one in the old one's view
        theirs, mine = others[i].lrp_at_home, others[i].new_lrp_at_home
        gap[k] = min(gap[k], (theirs - others[i].background) - (mine - own_background))
    order = np.argsort(gap)
    return [ids[k] for k in order[:limit] if gap[k] <= margin]


def lrps_in_views(views: list[np.ndarray], places: list[PreparedTemplates],
                  known: Callable[[int, int], float | None] = lambda _place, _view: None,
                  spread: Spread = in_turn) -> np.ndarray:
    """(views, places) each place's LRP in each grey view: ``known(place index, view
    index)`` when it has it (measured during the drive, daemon/service/learn_ahead.py),
    else measured here, one matrix product per view for all the missing. ``spread``: how
    the views are run (in turn, or over threads; the same answer)."""
    matcher = FastMatcher()

    def row(k: int) -> list[float]:
        have = {q: known(q, k) for q in range(len(places))}
        missing = [q for q, lrp in have.items() if lrp is None]
        measured = dict(zip(missing, matcher.lrps(PreparedPanorama.of(views[k]),
                                                  [places[q] for q in missing]), strict=True)
                        ) if missing else {}
        return [measured[q] if lrp is None else lrp for q, lrp in have.items()]

    return np.array(spread(row, list(range(len(views)))))


@dataclass(frozen=True)
class Foreseen:
    """Features found during a learn's drive for the look-alikes it foresaw
    (daemon/service/learn_ahead.py): each one's against the new place's views, and the
    new place's against all of them."""

    theirs: dict[int, Feature]
    mine: Feature

    @property
    def lookalikes(self) -> set[int]:
        return set(self.theirs)


def pair_features(new_id: int, new_views: list[np.ndarray],
                  lookalike_views: dict[int, list[np.ndarray]], margin: int,
                  spread: Spread = in_turn, foreseen: Foreseen | None = None
                  ) -> list[PairFeatures]:
    """The features of the new place (views: its reference first) and each look-alike
    (id → its grey views, the reference first, then its learning views if the map kept
    them): the new place's one feature (:func:`own_feature`), and each look-alike's
    against the new place's views, scored over the look-alike's own views. A feature
    scored on its reference alone counts on matching as it does there (own NCC 1), and
    a robot a little off the reference sees it match far less: on aliased-corridor
    seed 101 every older place's vote fell below the newest one's, and the decisions
    named the newest place on 3 of 32 ambiguous frames where it was 4-5 m away.

    ``foreseen``: features found for the same views already, taken as they are (a
    feature is a function of the two places' views alone; the new place's, of the set of
    look-alikes' views, whatever their order)."""
    if not lookalike_views:
        return []
    known = foreseen.theirs if foreseen is not None else {}
    mine_known = foreseen.mine if foreseen is not None and \
        foreseen.lookalikes == set(lookalike_views) else None
    against_new = prepared(new_views)  # once for every look-alike's search
    searches: dict[int | None, Callable[[], Feature]] = {}
    if mine_known is None:
        searches[None] = lambda: own_feature(new_views, list(lookalike_views.values()),
                                             margin)
    for other_id, views in lookalike_views.items():
        if other_id not in known:
            searches[other_id] = functools.partial(find_feature, views, against_new, margin)
    found = dict(zip(searches, spread(lambda search: search(), list(searches.values())),
                     strict=True))
    mine = mine_known if mine_known is not None else found[None]
    return [PairFeatures(new_id, other_id, mine,
                         known[other_id] if other_id in known else found[other_id])
            for other_id in lookalike_views]


def own_feature(new_views: list[np.ndarray], lookalike_views: list[list[np.ndarray]],
                margin: int) -> Feature:
    """The new place's feature against every look-alike's views at once: a patch that
    tells it from one look-alike but is seen at another would vote for it there (seed 2
    of the aliased corridor: a 16 px patch of its far end, 0.82 at home, 0.92 between
    two other places)."""
    return find_feature(new_views, [v for views in lookalike_views for v in views], margin)
