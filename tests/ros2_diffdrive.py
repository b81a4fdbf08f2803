"""A simulated ROS 2 differential-drive base, as rmw_zenoh carries it (issue 33): it takes
``geometry_msgs/Twist`` on ``/cmd_vel`` and publishes ``nav_msgs/Odometry`` on ``/odom``
at ``rate_hz``, as a TurtleBot's base driver does, over a real zenoh session on loopback.
It stops by itself when no command came within ``cmd_timeout_s`` (as base drivers do).
The hardware-in-the-loop tests of the ``ros2`` base backend drive it; its odometry is its
truth (no drift), so what a test checks is the backend's control, not odometry error.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Any

import zenoh

from hal import ros2_wire as wire
from hal.base.ros2 import ODOMETRY, TWIST, odometry_message


class Ros2DiffDriveRobot:
    """A differential-drive base node listening on 127.0.0.1:``port`` (module docstring)."""

    def __init__(self, port: int, rate_hz: float = 50.0, cmd_timeout_s: float = 0.5,
                 domain_id: int = 0, odom_topic: str = "/odom",
                 cmd_vel_topic: str = "/cmd_vel", coast_s: float = 0.0) -> None:
        self.session = wire.open_session(listen=[f"tcp/127.0.0.1:{port}"])
        self.rate_hz, self.cmd_timeout_s = rate_hz, cmd_timeout_s
        self.coast_s = coast_s  # a zero Twist takes effect this late (a robot decelerating)
        self._coast_until = 0.0
        self.stopped_at: float | None = None  # monotonic: when the last coast ended
        self._lock = threading.Lock()
        self.pose = (0.0, 0.0, 0.0)  # x, y, yaw in the odometry frame (its truth)
        self.command = (0.0, 0.0)  # v, w being driven
        self.commands: list[tuple[float, float, float]] = []  # every Twist (vx, vy, w)
        self._command_at = 0.0
        self.publishing = True  # False: odometry goes quiet (a driver that hung)
        self._odom = wire.Publisher(self.session, domain_id, 0, 1, "base_driver", odom_topic,
                                    ODOMETRY)
        self._sub = self.session.declare_subscriber(
            f"{domain_id}/{cmd_vel_topic.strip('/')}/{wire.mangled_type(TWIST)}/*",
            self._on_twist)
        self._running = True
        self._thread = threading.Thread(target=self._run, name="ros2-robot", daemon=True)
        self._thread.start()

    def _on_twist(self, sample: zenoh.Sample) -> None:
        msg: Any = wire.TYPESTORE.deserialize_cdr(sample.payload.to_bytes(), TWIST)
        with self._lock:
            self.commands.append((msg.linear.x, msg.linear.y, msg.angular.z))
            command = (float(msg.linear.x), float(msg.angular.z))  # no sideways wheels
            now = time.monotonic()
            if command == (0.0, 0.0) and self.command != (0.0, 0.0) and self.coast_s > 0:
                self._coast_until = now + self.coast_s  # keeps going a while
            elif now >= self._coast_until:
                self.command = command
            self._command_at = now

    def _run(self) -> None:
        last = time.monotonic()
        period = 1.0 / self.rate_hz
        while self._running:
            now = time.monotonic()
            dt, last = now - last, now
            with self._lock:
                if now - self._command_at > self.cmd_timeout_s or (
                        self._coast_until and now >= self._coast_until):
                    if self._coast_until:
                        self._coast_until, self.stopped_at = 0.0, now
                    self.command = (0.0, 0.0)
                v, w = self.command
                x, y, yaw = self.pose
                self.pose = (x + v * math.cos(yaw) * dt, y + v * math.sin(yaw) * dt,
                             math.remainder(yaw + w * dt, 2 * math.pi))
                pose, publishing = self.pose, self.publishing
            if publishing:
                self._publish(pose)
            time.sleep(max(0.0, period - (time.monotonic() - now)))

    def _publish(self, pose: tuple[float, float, float]) -> None:
        with contextlib.suppress(Exception):  # zenoh shutting down
            self._odom.put_message(odometry_message(*pose, time.time_ns()))

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=2.0)
        self._sub.undeclare()
        self._odom.close()
        self.session.close()
