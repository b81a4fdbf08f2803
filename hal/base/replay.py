"""The `replay` base backend: odometry of an MCAP recording, in step with the replay camera.
It cannot move: motion commands are refused."""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from typing import Any

from hal.base.base import BaseInfo, BaseStatus, Odometry
from hal.base.settings import ReplayBaseSettings
from hal.recording import TOPIC_ODOMETRY, Message, RecordingReader, decode_odometry
from hal.replay import ReplayClock, shared_clock
from kernel.errors import CommandRejectedError, DeviceInitError, DeviceIOError, DeviceTimeoutError


class ReplayBase:
    def __init__(self, settings: ReplayBaseSettings, context: Any) -> None:
        self._settings = settings
        self._context = context
        self._file = settings.file
        self._messages: Iterator[Message] | None = None
        self._pending: Message | None = None
        self._clock: ReplayClock | None = None
        self._samples = 0

    def open(self) -> None:
        if not self._file:
            camera = self._context.config.camera.replay if self._context.config else None
            self._file = camera.file if camera else ""
        if not self._file:
            raise DeviceInitError("base.replay.file and camera.replay.file are empty")
        reader = RecordingReader(self._file)
        speed = self._settings.speed
        if self._context.config is not None and self._context.config.camera.backend == "replay":
            speed = self._context.config.camera.replay.speed  # one clock, the camera's rate
        self._clock = shared_clock(self._context, self._file, speed)
        self._messages = reader.messages([TOPIC_ODOMETRY])
        self._pending = None

    def close(self) -> None:
        self._messages = None

    @property
    def info(self) -> BaseInfo:
        return BaseInfo("replay", self._file, False, 0.0)

    def read(self, timeout: float) -> list[Odometry]:
        if self._messages is None or self._clock is None:
            raise DeviceIOError("replay base is not open")
        end = time.monotonic() + timeout
        out: list[Odometry] = []
        while True:
            if self._pending is None:
                self._pending = next(self._messages, None)
                if self._pending is None:
                    if out:
                        break
                    raise DeviceIOError(f"end of recording {self._file}")
                self._clock.anchor(self._pending.log_time_ns)
            horizon = self._clock.horizon_ns()
            if horizon is not None and self._pending.log_time_ns <= horizon:
                out.append(decode_odometry(self._pending.body))
                self._pending = None
                continue
            if out or time.monotonic() >= end:
                break
            time.sleep(0.005)
        if not out:
            raise DeviceTimeoutError(f"no recorded odometry due within {timeout:.2f} s")
        self._samples += len(out)
        return out

    def status(self) -> BaseStatus:
        return BaseStatus()

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        raise CommandRejectedError("the replay base cannot move (it plays a recording)")

    def velocity(self, vx: float, vy: float, w: float) -> None:
        raise CommandRejectedError("the replay base cannot move (it plays a recording)")

    def stop(self) -> None:
        """Nothing moves during replay; stopping is always satisfied."""

    def stats(self) -> Mapping[str, float]:
        return {"samples": self._samples}
