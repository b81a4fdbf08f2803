"""Health bookkeeping of the supervised components: rates, states, last errors."""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import Any


class RateMeter:
    """Events per second over a sliding window of monotonic stamps."""

    def __init__(self, window_s: float = 2.0) -> None:
        self._window_ns = int(window_s * 1e9)
        self._stamps: collections.deque[int] = collections.deque()
        self._lock = threading.Lock()
        self.total = 0

    def tick(self, n: int = 1, now_ns: int | None = None) -> None:
        now = time.monotonic_ns() if now_ns is None else now_ns
        with self._lock:
            self.total += n
            for _ in range(n):
                self._stamps.append(now)
            self._trim(now)

    def rate_hz(self, now_ns: int | None = None) -> float:
        now = time.monotonic_ns() if now_ns is None else now_ns
        with self._lock:
            self._trim(now)
            return len(self._stamps) * 1e9 / self._window_ns

    def _trim(self, now: int) -> None:
        while self._stamps and now - self._stamps[0] > self._window_ns:
            self._stamps.popleft()


@dataclass
class ComponentHealth:
    """What the status message says about one component."""

    name: str
    state: str = "starting"  # starting | running | backoff | stopped
    restarts: int = 0
    last_error: str | None = None
    last_error_mono_ns: int | None = None
    heartbeat_ns: int = field(default_factory=time.monotonic_ns)
    rate: RateMeter = field(default_factory=RateMeter)
    detail: dict[str, Any] = field(default_factory=dict)

    def beat(self) -> None:
        self.heartbeat_ns = time.monotonic_ns()

    def as_dict(self, now_ns: int) -> dict[str, Any]:
        return {
            "state": self.state,
            "restarts": self.restarts,
            "last_error": self.last_error,
            "last_error_age_s": None if self.last_error_mono_ns is None
            else round((now_ns - self.last_error_mono_ns) / 1e9, 3),
            "rate_hz": round(self.rate.rate_hz(now_ns), 2),
            **self.detail,
        }


def processing_state(state: str, processed_hz: float, frames_hz: float,
                     min_share: float) -> str:
    """The processing step's state as status reports it: ``degraded`` while it runs but
    keeps less than ``min_share`` of the frames the camera delivers (the rest skipped:
    a busy CPU), else its supervisor state."""
    if state == "running" and frames_hz > 0.0 and processed_hz < min_share * frames_hz:
        return "degraded"
    return state
