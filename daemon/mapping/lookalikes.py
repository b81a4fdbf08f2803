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


def lookalikes(views: list[np.ndarray], own: PreparedTemplates, own_background: float,
               others: dict[int, MappedPlace], margin: float, limit: int,
               spread: Spread = in_turn) -> list[int]:
    """The places of ``others`` that the lower level tells from the new place (``own``,
    seen in the grey ``views``) by at most ``margin`` either way, at most ``limit``, the
    closest first. ``spread``: how the views' matching is run (in turn, or over threads;
    the same answer)."""
    if not others:
        return []
    matcher = FastMatcher()
    ids = list(others)
    templates = [own] + [others[i].templates for i in ids]
    lrps = np.array(spread(lambda v: matcher.lrps(PreparedPanorama.of(v), templates), views))
    leads = lrps.mean(axis=0) - np.array([own_background] + [others[i].background
                                                             for i in ids])
    gap = leads[0] - leads[1:]  # how far each old place stands below the new one here
    for k, i in enumerate(ids):  # and the new one below the old one in the old one's view
        theirs, mine = others[i].lrp_at_home, others[i].new_lrp_at_home
        gap[k] = min(gap[k], (theirs - others[i].background) - (mine - own_background))
    order = np.argsort(gap)
    return [ids[k] for k in order[:limit] if gap[k] <= margin]


def pair_features(new_id: int, new_views: list[np.ndarray],
                  lookalike_views: dict[int, list[np.ndarray]], margin: int,
                  spread: Spread = in_turn) -> list[PairFeatures]:
    """The features of the new place (views: its reference first) and each look-alike
    (id → its grey views, the reference first, then its learning views if the map kept
    them): the new place's one feature (:func:`own_feature`), and each look-alike's
    against the new place's views, scored over the look-alike's own views. A feature
    scored on its reference alone counts on matching as it does there (own NCC 1), and
    a robot a little off the reference sees it match far less: on aliased-corridor
    seed 101 every older place's vote fell below the newest one's, and the decisions
    named the newest place on 3 of 32 ambiguous frames where it was 4-5 m away."""
    if not lookalike_views:
        return []
    against_new = prepared(new_views)  # once for every look-alike's search
    searches: list[Callable[[], Feature]] = [
        lambda: own_feature(new_views, list(lookalike_views.values()), margin),
        *[functools.partial(find_feature, views, against_new, margin)
          for views in lookalike_views.values()]]
    mine, *theirs = spread(lambda search: search(), searches)
    return [PairFeatures(new_id, other_id, mine, feature)
            for other_id, feature in zip(lookalike_views, theirs, strict=True)]


def own_feature(new_views: list[np.ndarray], lookalike_views: list[list[np.ndarray]],
                margin: int) -> Feature:
    """The new place's feature against every look-alike's views at once: a patch that
    tells it from one look-alike but is seen at another would vote for it there (seed 2
    of the aliased corridor: a 16 px patch of its far end, 0.82 at home, 0.92 between
    two other places)."""
    return find_feature(new_views, [v for views in lookalike_views for v in views], margin)
