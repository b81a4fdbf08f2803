"""A short history of odometry samples, interpolated at frame stamps."""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterable

from kernel.angles import wrap_angle
from kernel.types import Odometry


class OdometryBuffer:
    """Keeps the last ``capacity`` samples in stamp order; rejects samples older than the
    newest one (time going backwards is a device fault, counted, never trusted)."""

    def __init__(self, capacity: int = 500) -> None:
        self._samples: deque[Odometry] = deque(maxlen=capacity)
        self.rejected_out_of_order = 0

    def extend(self, samples: Iterable[Odometry]) -> None:
        for s in samples:
            if self._samples and s.stamp_ns <= self._samples[-1].stamp_ns:
                self.rejected_out_of_order += 1
                continue
            self._samples.append(s)

    @property
    def latest(self) -> Odometry | None:
        return self._samples[-1] if self._samples else None

    def at(self, stamp_ns: int, max_extrapolation_ns: int = 0) -> Odometry | None:
        """The odometry pose at ``stamp_ns`` (linear interpolation), or None when the
        buffer does not cover that time: motion is never invented."""
        if not self._samples:
            return None
        stamps = [s.stamp_ns for s in self._samples]
        i = bisect.bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            return self._samples[i]
        if i == 0:
            first = self._samples[0]
            return first if first.stamp_ns - stamp_ns <= max_extrapolation_ns else None
        if i == len(stamps):
            last = self._samples[-1]
            return last if stamp_ns - last.stamp_ns <= max_extrapolation_ns else None
        a, b = self._samples[i - 1], self._samples[i]
        f = (stamp_ns - a.stamp_ns) / (b.stamp_ns - a.stamp_ns)
        yaw = a.yaw + f * float(wrap_angle(b.yaw - a.yaw))
        return Odometry(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), float(wrap_angle(yaw)),
                        stamp_ns, a.seq)


def relative_motion(a: Odometry, b: Odometry) -> tuple[float, float, float]:
    """Motion from pose ``a`` to pose ``b`` in the robot frame at ``a``: (dx, dy, dyaw)."""
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    gx, gy = b.x - a.x, b.y - a.y
    return c * gx + s * gy, -s * gx + c * gy, float(wrap_angle(b.yaw - a.yaw))
