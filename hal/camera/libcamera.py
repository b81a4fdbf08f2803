"""The `libcamera` camera backend (Raspberry Pi cameras) through picamera2.

picamera2 is imported with this module, so choosing the backend without it installed is a
BackendUnavailableError naming the package (``pip install picamera2``, or Debian's
``python3-picamera2`` on Raspberry Pi OS), never a silent fallback.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from picamera2 import Picamera2

from hal.camera.base import CameraInfo, Frame
from hal.camera.settings import LibcameraSettings
from kernel.errors import DeviceInitError, DeviceIOError, DeviceTimeoutError


class LibcameraCamera:
    def __init__(self, settings: LibcameraSettings, context: Any) -> None:
        self._settings = settings
        self._cam: Any = None
        self._seq = 0
        self._frames = 0

    def open(self) -> None:
        s = self._settings
        try:
            self._cam = Picamera2(s.camera_index)
            config = self._cam.create_video_configuration(
                main={"size": (s.width, s.height), "format": "RGB888"},
                controls={"FrameRate": s.rate_hz}, buffer_count=2)
            self._cam.configure(config)
            self._cam.start()
        except Exception as e:
            raise DeviceInitError(f"cannot open libcamera camera {s.camera_index}: {e}") from e

    def close(self) -> None:
        if self._cam is not None:
            try:
                self._cam.stop()
                self._cam.close()
            finally:
                self._cam = None

    @property
    def info(self) -> CameraInfo:
        s = self._settings
        return CameraInfo("libcamera", f"camera {s.camera_index}", s.width, s.height, s.rate_hz)

    def read(self, timeout: float) -> Frame:
        if self._cam is None:
            raise DeviceIOError("libcamera camera is not open")
        job = self._cam.capture_request(wait=False)
        try:
            request = self._cam.wait(job, timeout=timeout)
        except TimeoutError as e:
            raise DeviceTimeoutError(f"libcamera: no frame for {timeout:.2f} s") from e
        try:
            # SensorTimestamp is CLOCK_MONOTONIC in ns at the start of exposure.
            stamp = int(request.get_metadata().get("SensorTimestamp", time.monotonic_ns()))
            image = request.make_array("main")
        finally:
            request.release()
        self._seq += 1
        self._frames += 1
        # "RGB888" in libcamera is BGR byte order in memory: already OpenCV's layout.
        return Frame(image=image, stamp_ns=stamp, seq=self._seq)

    def stats(self) -> Mapping[str, float]:
        return {"frames": self._frames}
