"""The odometry between two reference poses, with the covariance it has earned (docs/design.md §6).

When a place is learned after another in one unbroken run of odometry, the transition
between them is the odometry motion from the first reference pose to the second (§7.1.2:
accurate over short distances). Its covariance is propagated along every odometry step
with the noise model of :class:`OdometryNoiseSettings`: the state is the pose relative to
the first reference, (x, y, θ), augmented by the two unknown systematic errors (scale s
and heading drift per metre b) whose effect grows with the distance, not its root.

For an odometry step u = (dx, dy, dθ) in the robot frame, of length ds, the true step is
u_true = (dx (1 − s), dy (1 − s), dθ − b ds) + w,  w ~ N(0, diag(σt² ds, σt² ds, σr² ds)),
so with J₁, J₂ the Jacobians of X ⊕ u (kernel/se2.py) and G = ∂u_true/∂(s, b):

    P' = F P Fᵀ + [J₂ Q J₂ᵀ 0; 0 0],    F = [J₁  J₂ G; 0  I].
"""

from __future__ import annotations

import math

import numpy as np

from daemon.mapping.settings import OdometryNoiseSettings
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry


class OdometryChain:
    """Motion from a reference odometry sample, fed every later sample in order."""

    def __init__(self, start: Odometry, noise: OdometryNoiseSettings) -> None:
        self.start = start
        self.noise = noise
        self._last = start
        self._pose = SE2()
        self._P = np.zeros((5, 5))
        self._P[3, 3] = noise.scale_sigma ** 2
        self._P[4, 4] = noise.heading_drift_sigma_rad_per_m ** 2
        self.distance_m = 0.0
        self.broken_by: str | None = None  # why no transition is measured any more
        # Why its transition is held until the map can check it (design §6): a loss
        # where the view contradicted the estimate (the robot may have been carried,
        # which odometry cannot see), or a search that found no known place.
        self.doubted_by: str | None = None

    @property
    def broken(self) -> bool:
        return self.broken_by is not None

    def break_off(self, why: str) -> None:
        """No transition is measured across what happened (the first reason is kept)."""
        if self.broken_by is None:
            self.broken_by = why

    def doubt(self, why: str) -> None:
        """What it measures may be wrong, or not (the first reason is kept)."""
        if self.doubted_by is None:
            self.doubted_by = why

    @property
    def last(self) -> Odometry:
        return self._last

    def add(self, sample: Odometry) -> None:
        """One more odometry sample; a gap longer than ``max_gap_s`` or time going
        backwards breaks the chain for good."""
        if self.broken:
            return
        gap_s = (sample.stamp_ns - self._last.stamp_ns) / 1e9
        if gap_s <= 0.0:
            return  # a repeat or out of order: the odometry buffer counts those
        if gap_s > self.noise.max_gap_s:
            self.break_off(f"odometry silent for {gap_s:.2f} s, over [odometry] max_gap_s")
            return
        a = SE2(self._last.x, self._last.y, self._last.yaw)
        u = a.between(SE2(sample.x, sample.y, sample.yaw))
        self._step(u)
        self._last = sample

    def _step(self, u: SE2) -> None:
        n = self.noise
        ds = math.hypot(u.x, u.y)
        j1, j2 = self._pose.compose_jacobians(u)
        G = np.array([[-u.x, 0.0], [-u.y, 0.0], [0.0, -ds]])  # ∂u_true/∂(s, b)
        F = np.eye(5)
        F[:3, :3] = j1
        F[:3, 3:] = j2 @ G
        Q = np.diag([n.translation_m_per_sqrt_m ** 2 * ds, n.translation_m_per_sqrt_m ** 2 * ds,
                     n.heading_rad_per_sqrt_m ** 2 * ds])
        self._P = F @ self._P @ F.T
        self._P[:3, :3] += j2 @ Q @ j2.T
        self._pose = self._pose.compose(u)
        self.distance_m += ds

    def relative(self) -> UncertainSE2:
        """The last sample's pose in the start sample's frame, with its covariance."""
        return UncertainSE2(self._pose, self._P[:3, :3].copy())

    def relative_at(self, sample: Odometry) -> UncertainSE2:
        """The pose at ``sample`` (a moment before or after the last one fed) in the start
        sample's frame: the mean moved by the odometry between the two; the covariance of
        the last sample (that moment adds nothing measurable)."""
        last = SE2(self._last.x, self._last.y, self._last.yaw)
        residual = last.between(SE2(sample.x, sample.y, sample.yaw))
        return UncertainSE2(self._pose.compose(residual), self._P[:3, :3].copy())


def held_verdict(held: UncertainSE2, path: UncertainSE2 | None) -> bool | None:
    """Whether a transition measured by doubted odometry (``OdometryChain.doubted_by``)
    is what the robot drove (design §6): None while no path through the map joins its
    two places, then whether the path's T_a_b and the odometry's can be one pose (χ² at
    99.9 %; a robot carried metres off, as the kidnaps of the endurance experiment,
    disagrees by far more than a lap's covariance)."""
    if path is None:
        return None
    return held.agrees_with(path)
