"""Which place to position in (design §8, §6 cycles; thesis §8.2, §7.1.3).

Every few frames the current place, its neighbours (by transition) and, in turn, a few
other places are recognised (LRP minus background). A neighbour that leads the current
place by ``switch_margin`` takes over — unless the estimate is nearer the current place's
reference — and so does one whose reference the estimate is ``handover_m`` nearer to, if
recognised nearly as well: the estimate passes through the transition. A place with no
transition from here that the graph puts within ``cycle_near_m`` is recognised every
check and handed over to the same way when the estimate is nearer its reference (through
the graph's path, the direct transition then measured); any other must lead by
``cycle_margin``, and stand ``cycle_min_lead`` above its background, on ``cycle_checks``
checks in a row; the estimate then restarts in it, and once
it is reliable the cycle's transition is measured (:class:`CycleClosure`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from daemon.localisation.belief import PlaceScore
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.odometry_chain import OdometryChain
from daemon.mapping.transition import Transition
from kernel.se2 import UncertainSE2


@dataclass(frozen=True)
class Switch:
    kind: Literal["neighbour", "graph", "cycle"]  # graph: through a path of transitions
    place_id: int


class PlaceSwitcher:
    def __init__(self, settings: LocalisationSettings) -> None:
        self.settings = settings
        self._turn = 0  # where the rotation through the other places stands
        self._streak: tuple[int, int] | None = None  # (place, checks in a row)

    def to_check(self, current: int, neighbours: list[int], known: list[int],
                 near: list[int] | None = None) -> list[int]:
        """The places to recognise now: the current one, its neighbours, the places the
        graph puts near (``near``), and the next ``others_per_check`` of the rest in
        turn (none is left out for good)."""
        near = [p for p in near or [] if p != current and p not in neighbours]
        others = [p for p in known if p != current and p not in neighbours and p not in near]
        k = min(self.settings.others_per_check, len(others))
        chosen = [others[(self._turn + i) % len(others)] for i in range(k)] if others else []
        self._turn = (self._turn + k) % max(len(others), 1)
        if self._streak is not None and self._streak[0] in others \
                and self._streak[0] not in chosen:
            chosen.append(self._streak[0])  # a place on a streak is checked every time
        return [current, *neighbours, *near, *chosen]

    def decide(self, current: int, neighbours: list[int], scores: list[PlaceScore],
               distance: dict[int, float] | None = None, near: list[int] | None = None,
               far: set[int] | frozenset[int] = frozenset()) -> Switch | None:
        """``distance``: from the estimate to the reference of the current place and of
        other places reached through the transitions (neighbours directly, others along
        the graph: a loop's places through the drifted sum round it). ``near``: places
        with no transition from here that the graph puts within ``cycle_near_m``;
        ``far``: places it puts beyond ``cycle_within_m`` (:func:`beyond`), look-alikes
        whose lead never starts a streak."""
        s = self.settings
        lead = {sc.place_id: sc.lead for sc in scores}
        here = lead.get(current, -1.0)
        dist = distance or {}
        d_here = dist.get(current, 0.0)
        # §8.2: the neighbour's LRP rose above the current place's — if the estimate is no
        # nearer the current place's reference (a place whose LRP stays high all along a
        # corridor must not pull the estimate back to it).
        rising = [p for p in neighbours if p in lead and lead[p] >= here + s.switch_margin
                  and dist.get(p, 0.0) <= d_here]
        # Beyond the thesis: positioning is most precise near a place's reference; hand
        # over to a neighbour the estimate is handover_m nearer to, recognised nearly as
        # well (a place's LRP may stay at its background until the robot is almost there).
        nearer = [p for p in [*neighbours, *(near or [])] if p in lead and p in dist
                  and dist[p] + s.handover_m <= d_here
                  and (dist[p] <= s.handover_ratio * d_here or p not in neighbours)
                  and lead[p] >= here - s.handover_tolerance]
        best_nb = max(rising or nearer, key=lambda p: lead[p], default=None)
        if best_nb is not None:
            self._streak = None
            return Switch("neighbour" if best_nb in neighbours else "graph", best_nb)
        ceiling = max([here] + [lead[p] for p in neighbours if p in lead])
        others = [sc for sc in scores if sc.place_id != current
                  and sc.place_id not in neighbours and sc.place_id not in far]
        # Coming round a loop: the graph puts a place without a transition from here
        # within cycle_near_m, and it is recognised above everything nearer by the graph.
        coming_round = [sc for sc in others if dist.get(sc.place_id, math.inf) <= s.cycle_near_m
                        and sc.lead >= ceiling + s.switch_margin
                        and dist[sc.place_id] <= d_here]
        if coming_round:
            self._streak = None
            return Switch("cycle", max(coming_round, key=lambda sc: sc.lead).place_id)
        best = max(others, key=lambda sc: sc.lead, default=None)
        if best is None or best.lead < max(ceiling + s.cycle_margin, s.cycle_min_lead):
            if best is not None and self._streak is not None \
                    and self._streak[0] == best.place_id:
                self._streak = None
            return None
        count = self._streak[1] + 1 if self._streak and self._streak[0] == best.place_id else 1
        self._streak = (best.place_id, count)
        if count >= s.cycle_checks:
            self._streak = None
            return Switch("cycle", best.place_id)
        return None


def carried_over(switch: Switch, through: dict[int, UncertainSE2]) -> bool:
    """Whether the estimate passes to the switch's place through the map's transitions
    (T_current_p in ``through``) — to a neighbour, along a path of them, and also after
    a streak's lead (a "cycle" switch) to a place the graph reaches — rather than
    starting over around the place's reference (σ ``recovery_sigma_m``): started so,
    office 1's tracker settled 1.36 m off in a place two transitions away, published
    tracking, and its cycle was stored."""
    return switch.kind in ("neighbour", "graph") or switch.place_id in through


def places_near(current: int, pose: tuple[float, float, float],
                through: dict[int, UncertainSE2], within_m: float) -> set[int]:
    """The places whose reference lies within ``within_m`` of ``pose`` (an estimate in
    place ``current``), each reached through the map's transitions (``through``:
    T_current_p) and allowed the path's drift at 2 sigma. Autonomous acquisition takes a
    known place back over only from these: a look-alike across the map is no path back."""
    x, y = pose[0], pose[1]
    near = {current} if math.hypot(x, y) <= within_m else set()
    for pid, T in through.items():
        drift = 2.0 * math.sqrt(max(T.covariance[0, 0] + T.covariance[1, 1], 0.0))
        if math.hypot(T.mean.x - x, T.mean.y - y) <= within_m + drift:
            near.add(pid)
    return near


def beyond(current: int, pose: tuple[float, float, float],
           through: dict[int, UncertainSE2], within_m: float) -> set[int]:
    """The places the map's transitions put farther than ``within_m`` from ``pose`` (an
    estimate in place ``current``), the path's drift at 2 sigma allowed: where the map
    says the robot is not (:func:`places_near`'s complement among those reached; a place
    no path reaches is not among them). ``within_m`` 0: none."""
    if within_m <= 0:
        return set()
    return set(through) - places_near(current, pose, through, within_m)


def nearest_place(current: int, pose: tuple[float, float, float],
                  through: dict[int, UncertainSE2], exclude: int | None = None
                  ) -> tuple[int, float] | None:
    """The place but ``exclude`` whose reference the map puts nearest ``pose`` (an
    estimate in place ``current``; ``through``: T_current_p), and how far, metres (the
    means, no drift); None: no other place."""
    x, y = pose[0], pose[1]
    best = None if current == exclude else (current, math.hypot(x, y))
    for pid, T in through.items():
        d = math.hypot(T.mean.x - x, T.mean.y - y)
        if pid != exclude and pid != current and (best is None or d < best[1]):
            best = (pid, d)
    return best


def reliable(covariance: np.ndarray, confidence: float, s: LocalisationSettings) -> bool:
    """An estimate to build on: its xy std within ``reliable_sigma_m`` and its confidence
    at least ``reliable_confidence`` (a cycle's transition, a new place's link)."""
    return confidence >= s.reliable_confidence and \
        (covariance[0, 0] + covariance[1, 1]) / 2 <= s.reliable_sigma_m**2


class CycleClosure:
    """A cycle being closed (§7.1.3, design §6): the robot left place ``from_id`` for place
    ``to_id``, which has no transition from it. T_from_to = (estimate in from) ∘ (odometry
    since) ∘ (estimate in to)⁻¹, taken once the estimate in ``to`` is reliable."""

    def __init__(self, from_id: int, to_id: int, T_from_robot: UncertainSE2,
                 odometry: OdometryChain, settings: LocalisationSettings) -> None:
        self.from_id, self.to_id = from_id, to_id
        self.T_from_robot = T_from_robot
        self.odometry = odometry
        self.settings = settings
        self.reliable_frames = 0

    def observe(self, T_to_robot: UncertainSE2, confidence: float) -> Transition | None:
        """The estimate in ``to`` this frame; the transition once it has been reliable
        for ``reliable_frames`` frames in a row."""
        ok = reliable(T_to_robot.covariance, confidence, self.settings)
        self.reliable_frames = self.reliable_frames + 1 if ok else 0
        if self.reliable_frames < self.settings.reliable_frames or self.odometry.broken:
            return None
        T = self.T_from_robot.compose(self.odometry.relative()).compose(T_to_robot.inverse())
        return Transition(self.from_id, self.to_id, T, "cycle")
