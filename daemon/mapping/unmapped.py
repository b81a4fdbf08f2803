"""Unmapped space (design §6, "Segments"): relocalisation that has found no known place
for a while, as the robot moved, means the robot stands where the map has never been —
carried off (a kidnap) or driven off the map. In mapping mode a place is learned there
and starts a new segment; localisation mode searches on. ORB-SLAM3 starts a new map when
tracking is lost and merges maps when it recognises one in another; the thesis has
nothing for this."""

from __future__ import annotations

import math

from daemon.mapping.settings import AcquisitionSettings
from kernel.types import Odometry


def unmapped(frames: int, travelled_m: float, settings: AcquisitionSettings) -> bool:
    """The decision rule: searched ``frames`` frames in a row without finding a place,
    over ``travelled_m`` of odometry."""
    return frames >= settings.unmapped_after_frames and \
        travelled_m >= settings.unmapped_after_m


class UnmappedWatch:
    """Counts the frames and odometry travel of the current search (any frame not
    ``tracking``), and says when the robot is in unmapped space."""

    def __init__(self, settings: AcquisitionSettings) -> None:
        self.settings = settings
        self.frames = 0
        self.travelled_m = 0.0
        self._last: Odometry | None = None

    def observe(self, tracking: bool, odometry: Odometry | None) -> bool:
        if tracking:
            self.reset()
            return False
        self.frames += 1
        if odometry is not None:
            if self._last is not None:
                self.travelled_m += math.hypot(odometry.x - self._last.x,
                                               odometry.y - self._last.y)
            self._last = odometry
        return unmapped(self.frames, self.travelled_m, self.settings)

    def reset(self) -> None:
        self.frames, self.travelled_m, self._last = 0, 0.0, None
