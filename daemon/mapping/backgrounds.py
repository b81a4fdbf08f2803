"""The background LRP the global search ranks places by (design §9; thesis §7.1, §9.2).

A place's background is the LRP its landmarks settle at away from it. It is measured as
the robot leaves the place (daemon/mapping/acquisition.py); until then the global search,
which ranks every place by LRP minus background, needs an estimate for each, and the
estimates must be comparable from place to place. Two are made:

- in the place's own view (``Place.background_estimate``, daemon/mapping/place.py): each
  landmark's best NCC away from where it was cut, in its own reference panorama;
- in the other places' views (``Place.background_cross``): the mean LRP of its landmarks
  in the reference panoramas of the first ``CROSS_VIEWS`` other places of the map.

The own view says how high a background stands on the whole — the search's thresholds
(``search_min_lead``) were set on it — but ranks places badly where they look alike: in
the aliased corridor a door repeated in a place's own view raises its estimate, and the
place under the robot loses to its look-alikes (the right place first at 0.72 / 0.73 /
0.74 of random poses on seeds 1-3, every place's LRP against its own-view background;
0.92 / 0.87 / 0.90 against the other views'). The other views rank well but stand higher
on the whole (they include neighbours and look-alikes; 0.85 against 0.80 on the
corridor). So the search takes the other views' estimate re-centred on the own views'
level: b = cross − mean(cross) + mean(own), the means over the map's places with both.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from daemon.mapping.place import Place

CROSS_VIEWS = 50  # the other places' views a place's cross background averages


def views_of(place_id: int, ids: Iterable[int], limit: int = CROSS_VIEWS) -> list[int]:
    """The places whose reference views ``place_id``'s cross background averages: the
    first ``limit`` of the map's other places, in id order — settled once the map holds
    ``limit + 1`` places, so a new place then changes no older place's background."""
    return [p for p in sorted(ids) if p != place_id][:limit]


@dataclass(frozen=True)
class Levels:
    """The map's mean background estimate in the places' own views and in the others'."""

    own: float
    cross: float


def levels(places: Iterable[Place]) -> Levels | None:
    """Over the places with both estimates; None while there is none."""
    both = [(p.background_estimate, p.background_cross) for p in places
            if p.background_estimate is not None and p.background_cross is not None]
    if not both:
        return None
    own, cross = np.mean(np.array(both, dtype=float), axis=0)
    return Levels(float(own), float(cross))


def search_background(place: Place, map_levels: Levels | None) -> float | None:
    """The background the global search ranks ``place`` by: measured, else its cross
    estimate re-centred on the own views' level (module docstring), else its own-view
    estimate; None when the place has none of them."""
    if place.background_lrp is not None:
        return place.background_lrp
    if place.background_cross is not None and map_levels is not None:
        return place.background_cross - map_levels.cross + map_levels.own
    return place.background_estimate


def place_background(place: Place, default: float, map_levels: Levels | None,
                     estimated: bool) -> float:
    """The one rule for a place's background LRP (design §9): measured, when it has been;
    else, ``estimated``, ``search_background`` (the cross estimate on ``map_levels``,
    else the own-view estimate: with ``map_levels`` None, the own view only, as
    look-alikes are found, daemon/mapping/lookalikes.py); else ``default`` (the
    ``[localisation] background_lrp`` tracking between neighbours uses)."""
    if place.background_lrp is not None:
        return place.background_lrp
    value = search_background(place, map_levels) if estimated else None
    return default if value is None else value
