"""What the devices hand to the method: camera frames and odometry samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One camera frame.

    image: ``uint8`` raw camera image, ``(H, W, 3)`` BGR or ``(H, W)`` grey.
    stamp_ns: capture time on the monotonic clock shared with odometry (``time.monotonic_ns``
      on the robot; the simulated clock in lock-step simulation).
    seq: the device's frame counter; a jump means frames were lost.
    """

    image: np.ndarray
    stamp_ns: int
    seq: int


@dataclass(frozen=True)
class Odometry:
    """Absolute odometry pose of the base in its odometry frame.

    x, y in metres, yaw in radians wrapped to (-pi, pi]; stamp_ns on the monotonic clock
    shared with the camera; seq is the controller's sample counter.
    """

    x: float
    y: float
    yaw: float
    stamp_ns: int
    seq: int
