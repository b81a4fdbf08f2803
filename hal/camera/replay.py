"""The `replay` camera backend: frames of an MCAP recording at recorded or other rate."""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from typing import Any

from hal.camera.base import CameraInfo, Frame
from hal.camera.settings import ReplayCameraSettings
from hal.recording import TOPIC_FRAMES, Message, RecordingReader, decode_frame
from hal.replay import ReplayClock, shared_clock
from kernel.errors import DeviceInitError, DeviceIOError, DeviceTimeoutError


class ReplayCamera:
    def __init__(self, settings: ReplayCameraSettings, context: Any) -> None:
        self._settings = settings
        self._context = context
        self._messages: Iterator[Message] | None = None
        self._pending: Message | None = None
        self._clock: ReplayClock | None = None
        self._frames = 0
        self._shape = (0, 0)

    def open(self) -> None:
        if not self._settings.file:
            raise DeviceInitError("camera.replay.file is empty: name an MCAP recording")
        reader = RecordingReader(self._settings.file)
        self._clock = shared_clock(self._context, self._settings.file, self._settings.speed)
        if self._clock.finished and not self._settings.loop:
            raise DeviceInitError(f"end of recording {self._settings.file}")
        self._messages = reader.messages([TOPIC_FRAMES])
        self._pending = None

    def close(self) -> None:
        self._messages = None

    @property
    def info(self) -> CameraInfo:
        return CameraInfo("replay", self._settings.file, self._shape[1], self._shape[0], 0.0,
                          {"speed": str(self._settings.speed)})

    def _next(self) -> Message:
        if self._pending is None:
            assert self._messages is not None  # set by open()
            msg = next(self._messages, None)
            if msg is None:
                if not self._settings.loop:
                    assert self._clock is not None
                    self._clock.finished = True
                    raise DeviceIOError(f"end of recording {self._settings.file}")
                self.open()
                return self._next()
            self._pending = msg
        return self._pending

    def read(self, timeout: float) -> Frame:
        if self._messages is None or self._clock is None:
            raise DeviceIOError("replay camera is not open")
        msg = self._next()
        wait = self._clock.due_in_s(msg.log_time_ns)
        if wait > timeout:
            time.sleep(timeout)
            raise DeviceTimeoutError(f"no recorded frame due within {timeout:.2f} s")
        if wait > 0:
            time.sleep(wait)
        self._pending = None
        frame = decode_frame(msg.body)
        self._clock.release(msg.log_time_ns)
        self._frames += 1
        self._shape = frame.image.shape[:2]
        return frame

    def stats(self) -> Mapping[str, float]:
        return {"frames": self._frames}
