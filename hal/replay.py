"""The replay clock shared by the `replay` camera and base playing one MCAP recording."""

from __future__ import annotations

import threading
import time
from typing import Any


class ReplayClock:
    """Maps recorded log time to now. ``speed`` 1 plays at the recorded rate, 2 twice as
    fast; 0 plays as fast as the camera is read (the clock then stands at the newest frame
    released)."""

    # With speed 0 the base may deliver odometry this far past the newest frame, so the
    # pipeline can interpolate odometry at the frame's stamp.
    LOOKAHEAD_NS = 100_000_000

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self._lock = threading.Lock()
        self._t0_wall: int | None = None
        self._t0_log: int | None = None
        self.released_ns: int | None = None
        self.finished = False

    def anchor(self, log_ns: int) -> None:
        """Start the clock at the first message anyone plays."""
        with self._lock:
            if self._t0_wall is None:
                self._t0_wall = time.monotonic_ns()
                self._t0_log = log_ns

    def due_in_s(self, log_ns: int) -> float:
        """Seconds until ``log_ns`` is due (<= 0: due now)."""
        self.anchor(log_ns)
        if self.speed == 0:
            return 0.0
        assert self._t0_wall is not None and self._t0_log is not None  # set by anchor()
        due = self._t0_wall + (log_ns - self._t0_log) / self.speed
        return (due - time.monotonic_ns()) / 1e9

    def release(self, log_ns: int) -> None:
        with self._lock:
            self.released_ns = log_ns if self.released_ns is None else max(self.released_ns,
                                                                            log_ns)

    def horizon_ns(self) -> int | None:
        """Newest log time that may be played now."""
        if self.speed == 0:
            return None if self.released_ns is None else self.released_ns + self.LOOKAHEAD_NS
        if self._t0_wall is None or self._t0_log is None:
            return None
        return int(self._t0_log + (time.monotonic_ns() - self._t0_wall) * self.speed)


def shared_clock(context: Any, path: str, speed: float) -> ReplayClock:
    clock: ReplayClock = context.shared(f"replay.clock:{path}", lambda: ReplayClock(speed))
    return clock
