"""The `sim` base backend: odometry and motion commands of the shared simulated robot."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hal.base.base import BaseInfo, BaseStatus, Odometry
from hal.base.settings import SimBaseSettings
from hal.sim.factory import shared_sim_robot
from hal.sim.robot import SimRobot
from kernel.errors import CommandRejectedError, DeviceTimeoutError


class SimBase:
    def __init__(self, settings: SimBaseSettings, context: Any) -> None:
        self._settings = settings
        self._context = context
        self._robot: SimRobot | None = None
        self._samples = 0

    def open(self) -> None:
        self._robot = shared_sim_robot(self._context)

    def close(self) -> None:
        self._robot = None

    @property
    def info(self) -> BaseInfo:
        return BaseInfo("sim", f"simulated {self._settings.kinematics} base",
                        self._settings.can_move, self._settings.odometry_rate_hz,
                        odometry_kept_on_reopen=True, kinematics=self._settings.kinematics)

    def _open_robot(self) -> SimRobot:
        if self._robot is None:
            raise CommandRejectedError("sim base is not open")
        return self._robot

    def read(self, timeout: float) -> list[Odometry]:
        samples = self._open_robot().wait_odometry(timeout)
        if not samples:
            raise DeviceTimeoutError(f"no simulated odometry within {timeout:.2f} s")
        self._samples += len(samples)
        return samples

    def status(self) -> BaseStatus:
        return self._open_robot().status()

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        self._open_robot().move_relative(dx, dy, dyaw, speed)

    def velocity(self, vx: float, vy: float, w: float) -> None:
        self._open_robot().velocity(vx, vy, w)

    def stop(self) -> None:
        self._open_robot().stop()

    def stats(self) -> Mapping[str, float]:
        return {"samples": self._samples}
