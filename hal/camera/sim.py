"""The `sim` camera backend: raw donut frames rendered from the shared simulated robot."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hal.camera.base import CameraInfo, Frame
from hal.camera.settings import SimCameraSettings
from hal.sim.factory import shared_sim_robot
from hal.sim.robot import SimRobot
from kernel.errors import DeviceTimeoutError


class SimCamera:
    def __init__(self, settings: SimCameraSettings, context: Any) -> None:
        self._settings = settings
        self._context = context
        self._robot: SimRobot | None = None
        self._frames = 0
        self._timeouts = 0

    def open(self) -> None:
        self._robot = shared_sim_robot(self._context)

    def close(self) -> None:
        self._robot = None

    @property
    def info(self) -> CameraInfo:
        s = self._robot.camera if self._robot else self._settings
        return CameraInfo("sim", "simulated mirror camera", s.image_width, s.image_height,
                          s.rate_hz)

    def read(self, timeout: float) -> Frame:
        if self._robot is None:
            raise DeviceTimeoutError("sim camera is not open")
        frame = self._robot.next_frame(timeout)
        if frame is None:
            self._timeouts += 1
            raise DeviceTimeoutError(f"no simulated frame within {timeout:.2f} s")
        self._frames += 1
        return frame

    def stats(self) -> Mapping[str, float]:
        return {"frames": self._frames, "timeouts": self._timeouts}
