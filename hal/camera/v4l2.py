"""The `v4l2` camera backend: a Video4Linux2 device through OpenCV (``CAP_V4L2``).

A grab thread keeps only the newest frame (driver buffer of one, a one-slot mailbox), so
latency stays low; the frame's stamp is taken right after ``grab()`` returns, the closest
to capture OpenCV allows. A device that stops delivering is noticed by ``read``'s timeout
(DeviceTimeoutError) and one that fails by ``grab`` returning False (DeviceIOError).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from hal.camera.base import CameraInfo, Frame
from hal.camera.settings import V4L2Settings
from kernel.errors import DeviceInitError, DeviceIOError, DeviceTimeoutError

log = logging.getLogger(__name__)


class Capture(Protocol):
    """The part of ``cv2.VideoCapture`` the backend uses (a video file serves in tests)."""

    def isOpened(self) -> bool: ...  # noqa: N802 - OpenCV's name
    def grab(self) -> bool: ...
    def retrieve(self) -> tuple[bool, np.ndarray]: ...
    def get(self, prop: int) -> float: ...
    def release(self) -> None: ...


def open_v4l2(settings: V4L2Settings) -> Capture:
    """Open and configure the device; DeviceInitError naming the path when it cannot."""
    if not Path(settings.device).exists():
        raise DeviceInitError(f"camera device {settings.device} does not exist (is the camera "
                              "plugged in? `v4l2-ctl --list-devices` lists them)")
    cap = cv2.VideoCapture(settings.device, cv2.CAP_V4L2)
    if not cap.isOpened():
        raise DeviceInitError(f"cannot open camera device {settings.device} with V4L2 "
                              "(permissions? the placecell user needs the video group)")
    if len(settings.pixel_format) == 4:
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*settings.pixel_format))
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, settings.width)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, settings.height)
    cap.set(cv2.CAP_PROP_FPS, settings.rate_hz)
    cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
    return cap


class V4L2Camera:
    def __init__(self, settings: V4L2Settings, context: Any,
                 open_capture: Callable[[V4L2Settings], Capture] = open_v4l2) -> None:
        self._settings = settings
        self._open_capture = open_capture
        self._cap: Capture | None = None
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._fault: DeviceIOError | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._seq = 0
        self._counts = {"frames": 0, "skipped": 0, "timeouts": 0}

    def open(self) -> None:
        self._cap = self._open_capture(self._settings)
        self._running = True
        self._fault = None
        self._frame = None
        self._thread = threading.Thread(target=self._grab_loop, name="v4l2-grab", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    @property
    def info(self) -> CameraInfo:
        s = self._settings
        if self._cap is None:
            return CameraInfo("v4l2", s.device, s.width, s.height, s.rate_hz)
        return CameraInfo("v4l2", s.device, int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                          int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                          float(self._cap.get(cv2.CAP_PROP_FPS)),
                          {"pixel_format": s.pixel_format})

    def _grab_loop(self) -> None:
        cap = self._cap
        assert cap is not None  # set by open()
        while self._running:
            if not cap.grab():
                self._set_fault(DeviceIOError(f"camera {self._settings.device} stopped "
                                              "delivering frames (grab failed: unplugged?)"))
                return
            stamp = time.monotonic_ns()  # right after the driver handed the frame over
            ok, image = cap.retrieve()
            if not ok or image is None:
                self._set_fault(DeviceIOError(f"camera {self._settings.device}: cannot "
                                              "decode a frame"))
                return
            self._seq += 1
            with self._cond:
                if self._frame is not None:
                    self._counts["skipped"] += 1
                self._frame = Frame(image=image, stamp_ns=stamp, seq=self._seq)
                self._cond.notify_all()

    def _set_fault(self, fault: DeviceIOError) -> None:
        with self._cond:
            self._fault = fault
            self._cond.notify_all()

    def read(self, timeout: float) -> Frame:
        end = time.monotonic() + timeout
        with self._cond:
            while self._frame is None and self._fault is None:
                left = end - time.monotonic()
                if left <= 0:
                    self._counts["timeouts"] += 1
                    raise DeviceTimeoutError(f"camera {self._settings.device}: no frame for "
                                             f"{timeout:.2f} s (stalled)")
                self._cond.wait(left)
            if self._frame is None:
                assert self._fault is not None
                raise self._fault
            frame, self._frame = self._frame, None
        self._counts["frames"] += 1
        return frame

    def stats(self) -> Mapping[str, float]:
        return dict(self._counts)
