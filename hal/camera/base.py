"""The camera interface (docs/design.md §1): frames with a monotonic stamp and a sequence number."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from kernel.types import Frame


@dataclass(frozen=True)
class CameraInfo:
    backend: str
    device: str
    width: int
    height: int
    rate_hz: float
    extra: Mapping[str, str] = field(default_factory=dict)


@runtime_checkable
class Camera(Protocol):
    """A source of raw mirror-camera frames."""

    def open(self) -> None:
        """Open the device; raises DeviceInitError (or BackendUnavailableError)."""

    def close(self) -> None:
        """Release the device; safe to call twice."""

    @property
    def info(self) -> CameraInfo: ...

    def read(self, timeout: float) -> Frame:
        """The next frame; raises DeviceTimeoutError after ``timeout`` seconds without one,
        DeviceIOError when the device failed."""

    def stats(self) -> Mapping[str, float]:
        """Counters for status: frames delivered, dropped, errors."""
