"""Transitions: the edges of the topological map (docs/design.md §6).

A transition from place a to place b is ``T_a_b``, b's reference frame expressed in a's,
an SE(2) transform with the 3 x 3 covariance of (x, y, yaw) -- the thesis stored only a
distance and an angle (§7.1.2). It is stored both ways: the reverse is the inverse with
its covariance propagated (kernel/se2.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.se2 import UncertainSE2

# How a transition was measured: odometry between two places learned in one unbroken run
# (§7.1.2); that odometry fused with the local estimate in the last place at the new
# place's reference ("vision"); or a cycle closed by local estimates in both places (§7.1.3).
TransitionSource = Literal["odometry", "vision", "cycle"]


@dataclass(frozen=True)
class Transition:
    from_id: int
    to_id: int
    T_from_to: UncertainSE2
    source: TransitionSource = "odometry"

    def __post_init__(self) -> None:
        if self.from_id == self.to_id:
            raise ValueError(f"a transition joins two places, not place {self.from_id} to "
                             "itself")

    def reversed(self) -> Transition:
        return Transition(self.to_id, self.from_id, self.T_from_to.inverse(), self.source)

    def both_ways(self) -> tuple[Transition, Transition]:
        return self, self.reversed()
