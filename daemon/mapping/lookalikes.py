"""Look-alike places and their disambiguating features, when a place is learned (design
§5; thesis chapter 6).

A place already in the map is a *look-alike* of the one being learned when, over the new
place's views (its reference and views half-way out along the arms of its Turn Back
and Look cross), the lower
level recognises it nearly as well as the new place itself: its LRP minus background
within ``margin`` of the new place's. For each look-alike the pair's features are found
(daemon/vision/disambiguation.py): the new place's against the other's reference view,
scored over the new place's views so it survives small moves; the other's against the
new place's views. Pure: the service's mapper stores what this returns.
"""

from __future__ import annotations

import numpy as np

from daemon.vision.disambiguation import PairFeatures, find_feature
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates


def lookalikes(views: list[np.ndarray], own: PreparedTemplates, own_background: float,
               others: dict[int, tuple[PreparedTemplates, float]], margin: float,
               limit: int) -> list[int]:
    """The places of ``others`` (id → templates, background LRP) recognised in the grey
    ``views`` within ``margin`` of the new place (``own``), at most ``limit``, the
    closest first."""
    if not others:
        return []
    matcher = FastMatcher()
    prepared = [PreparedPanorama.of(v) for v in views]
    ids = list(others)
    lrps = np.array([matcher.lrps(p, [own] + [others[i][0] for i in ids]) for p in prepared])
    leads = lrps.mean(axis=0) - np.array([own_background] + [others[i][1] for i in ids])
    gap = leads[0] - leads[1:]  # how far each other place stands below the new one
    order = np.argsort(gap)
    return [ids[k] for k in order[:limit] if gap[k] <= margin]


def pair_features(new_id: int, new_views: list[np.ndarray], other_id: int,
                  other_reference: np.ndarray, margin: int) -> PairFeatures:
    """The features of the new place (views: its reference first) and a look-alike."""
    return PairFeatures(new_id, other_id,
                        find_feature(new_views, [other_reference], margin),
                        find_feature([other_reference], new_views, margin))
