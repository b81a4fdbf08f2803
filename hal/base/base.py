"""The mobile base interface (design §1, §12): odometry samples, status and motion commands."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from kernel.types import Odometry


@dataclass(frozen=True)
class BaseStatus:
    """Status flags of the base controller (docs/design.md §12 bit layout)."""

    moving: bool = False
    move_done: bool = False
    estop: bool = False
    fault: bool = False

    def to_flags(self) -> int:
        return (
            int(self.moving) | int(self.move_done) << 1 | int(self.estop) << 2
            | int(self.fault) << 3
        )

    @classmethod
    def from_flags(cls, flags: int) -> BaseStatus:
        return cls(bool(flags & 1), bool(flags & 2), bool(flags & 4), bool(flags & 8))


@dataclass(frozen=True)
class BaseInfo:
    backend: str
    device: str
    can_move: bool
    odometry_rate_hz: float
    # True when a re-opened link reads on in the same odometry frame (the simulated robot
    # lives on in the process); False when it may start from anywhere (a base power-cycled
    # while the link was down, a replay started again).
    odometry_kept_on_reopen: bool = False
    # "holonomic": moves along any direction of the robot's frame (the XR4000);
    # "differential": along its heading or turning in place only (Turn Back and Look then
    # drives its cross with turns, design §3).
    kinematics: str = "holonomic"


@runtime_checkable
class Base(Protocol):
    """A mobile base: odometry in, motion commands out."""

    def open(self) -> None:
        """Open the link; raises DeviceInitError (or BackendUnavailableError)."""

    def close(self) -> None:
        """Release the link; safe to call twice. Does not command a stop by itself."""

    @property
    def info(self) -> BaseInfo: ...

    def read(self, timeout: float) -> list[Odometry]:
        """All samples received since the last call, oldest first. Waits up to ``timeout``
        seconds for at least one; raises DeviceTimeoutError when none came."""

    def status(self) -> BaseStatus:
        """The latest status flags."""

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        """Start a relative move in the robot frame (m, m, rad) at ``speed`` m/s.
        Returns once accepted; completion shows as ``status().move_done``.
        Raises CommandRejectedError when the base cannot move or refused."""

    def velocity(self, vx: float, vy: float, w: float) -> None:
        """Command a velocity in the robot frame (m/s, m/s, rad/s)."""

    def stop(self) -> None:
        """Stop all motion."""

    def stats(self) -> Mapping[str, float]:
        """Counters for status: samples delivered, malformed, dropped, reconnects."""
