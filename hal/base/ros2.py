"""The `ros2` base backend: a ROS 2 robot's odometry in and velocity commands out, over
rmw_zenoh, no ROS install (hal/ros2_wire.py; docs/design.md §11).

Odometry is ``nav_msgs/msg/Odometry`` from ``odom_topic`` (the base driver's, usually
``/odom``): its pose in the plane, stamped with its header stamp carried onto the
daemon's monotonic clock (as the ros2 camera does, so frames and odometry of one robot are
associated by their message stamps). Motion is ``geometry_msgs/msg/Twist`` on
``cmd_vel_topic``, published by a node ``placecell_base`` that the ROS graph sees.

``move_relative`` (Turn Back and Look's legs, design §3) is closed on that odometry by a
control loop at ``control_rate_hz``: a differential base drives along its heading or turns
in place, one at a time (sideways motion is refused, as the simulated differential base
does), slowing down over the last ``slow_down_m`` / ``slow_down_rad``; the move is done
within ``position_tolerance_m`` and ``yaw_tolerance_rad``. ``velocity`` holds for
``command_timeout_s`` unless repeated.

The watchdog stops the robot (a zero Twist, the move abandoned, ``fault`` in the status
until odometry comes back) when odometry goes quiet for ``odometry_timeout_s`` while it is
moving, and when the daemon goes quiet: a ``velocity`` not repeated in time, and on
``close``. (A daemon killed outright publishes nothing more: the base driver's own
``cmd_vel`` timeout stops the robot, as for any ROS 2 teleop.)
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from hal.base.base import BaseInfo, BaseStatus
from hal.base.settings import Ros2BaseSettings
from hal.ros2_wire import (
    TYPESTORE,
    Publisher,
    mangled_type,
    monotonic_of,
    node_token,
    open_session,
    quaternion,
    ros_time,
    stamp_of,
    yaw_of,
)
from kernel.angles import wrap_angle
from kernel.errors import CommandRejectedError, DeviceInitError, DeviceTimeoutError
from kernel.types import Odometry

log = logging.getLogger(__name__)

ODOMETRY = "nav_msgs/msg/Odometry"
TWIST = "geometry_msgs/msg/Twist"
NODE_NAME = "placecell_base"


def decode_odometry(payload: bytes) -> tuple[float, float, float, int]:
    """(x, y, yaw, header stamp in ns since the UNIX epoch) of a CDR nav_msgs/Odometry;
    ValueError naming what is wrong."""
    try:
        msg: Any = TYPESTORE.deserialize_cdr(payload, ODOMETRY)
    except Exception as e:  # noqa: BLE001 - rosbags raises several kinds on bad bytes
        raise ValueError(f"not a {ODOMETRY}: {e}") from e
    p = msg.pose.pose.position
    yaw = yaw_of(msg.pose.pose.orientation)
    if not all(math.isfinite(v) for v in (p.x, p.y, yaw)):
        raise ValueError(f"a {ODOMETRY} whose pose is not finite")
    return float(p.x), float(p.y), yaw, stamp_of(msg.header.stamp)


def odometry_message(x: float, y: float, yaw: float, stamp_ns: int) -> Any:
    """A nav_msgs/Odometry of a pose in the plane (odom -> base_link, ROS time), as a base
    driver publishes it; twist and covariances zero (what the simulated bases send)."""
    t = TYPESTORE.types
    zeros = np.zeros(36)
    return t[ODOMETRY](
        header=t["std_msgs/msg/Header"](stamp=ros_time(stamp_ns), frame_id="odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=quaternion(yaw)), covariance=zeros),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist(0.0, 0.0, 0.0),
                                                         covariance=zeros))


def twist(vx: float, vy: float, w: float) -> Any:
    t = TYPESTORE.types
    v3 = t["geometry_msgs/msg/Vector3"]
    return t[TWIST](linear=v3(x=vx, y=vy, z=0.0), angular=v3(x=0.0, y=0.0, z=w))


AT_REST_M = 0.002  # odometry this still over [base.ros2] at_rest_s: the robot stands
AT_REST_RAD = 0.005


def at_rest(recent: list[Odometry], window_s: float) -> bool:
    """Whether odometry samples (oldest first) show the robot still: the samples cover
    ``window_s`` up to the last one and all lie within AT_REST_M and AT_REST_RAD of it;
    too few to cover the window: not known to be still. No odometry at all: no motion
    known either (a learn then fails on the missing odometry)."""
    if not recent:
        return True
    if recent[0].stamp_ns > recent[-1].stamp_ns - int(window_s * 1e9):
        return False
    last = recent[-1]
    return all(math.hypot(o.x - last.x, o.y - last.y) <= AT_REST_M
               and abs(math.remainder(o.yaw - last.yaw, 2 * math.pi)) <= AT_REST_RAD
               for o in recent)


@dataclass(frozen=True)
class Goal:
    """A relative move's goal in the odometry frame."""

    x: float
    y: float
    yaw: float
    speed: float


def move_command(here: tuple[float, float, float], goal: Goal, kinematics: str,
                 s: Ros2BaseSettings) -> tuple[float, float, float] | None:
    """The velocity (vx, vy, w) in the robot frame that brings ``here`` to ``goal``, or
    None once within the tolerances. A differential base first drives to the goal's
    position along its heading (forwards or backwards, whichever the goal lies on),
    steering only to stay on the line, then turns to the goal's heading; a holonomic one
    does both at once. Speeds fall off linearly over the last slow_down_m / slow_down_rad."""
    x, y, yaw = here
    dx, dy = goal.x - x, goal.y - y
    ahead = dx * math.cos(yaw) + dy * math.sin(yaw)  # the goal in the robot frame
    left = -dx * math.sin(yaw) + dy * math.cos(yaw)
    dyaw = float(wrap_angle(goal.yaw - yaw))
    distance = math.hypot(dx, dy)
    w_max = s.max_yaw_rate_rad_s
    turn = math.copysign(min(w_max, w_max * abs(dyaw) / s.slow_down_rad), dyaw)
    if kinematics == "holonomic":
        if distance <= s.position_tolerance_m and abs(dyaw) <= s.yaw_tolerance_rad:
            return None
        v = min(goal.speed, goal.speed * distance / s.slow_down_m)
        scale = v / distance if distance > 1e-9 else 0.0
        return ahead * scale, left * scale, turn
    if distance > s.position_tolerance_m:
        v = math.copysign(min(goal.speed, goal.speed * abs(ahead) / s.slow_down_m), ahead)
        # Keep on the line to the goal: steer by the bearing error (backwards: reversed).
        bearing = math.atan2(left, ahead) if ahead >= 0 else math.atan2(-left, -ahead)
        return v, 0.0, max(-w_max, min(w_max, 2.0 * bearing))
    if abs(dyaw) > s.yaw_tolerance_rad:
        return 0.0, 0.0, turn
    return None


class Ros2Base:
    """A ROS 2 robot's base (module docstring)."""

    def __init__(self, settings: Ros2BaseSettings, context: Any) -> None:
        self._settings = settings
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self._cmd: Publisher | None = None
        self._cond = threading.Condition()
        self._samples: list[Odometry] = []
        self._latest: Odometry | None = None
        # The samples of the last at_rest_s (and the one before): is the robot still?
        self._recent: collections.deque[Odometry] = collections.deque()
        self._latest_arrival = 0.0  # monotonic s
        self._seq = 0
        self._goal: Goal | None = None
        self._velocity: tuple[float, float, float] | None = None
        self._velocity_until = 0.0
        self._moving = False
        self._move_done = False
        self._fault = False
        self._running = False
        self._closing = threading.Event()  # wakes the control loop to end it
        self._thread: threading.Thread | None = None
        self._counts = {"samples": 0, "malformed": 0, "commands": 0, "watchdog_stops": 0}

    # ---------------------------------------------------------------- link
    def open(self) -> None:
        s = self._settings
        try:
            session = self._session = open_session(s.connect)
            self._entities.append(session.liveliness().declare_token(
                node_token(s.domain_id, str(session.zid()), 0, NODE_NAME)))
            self._entities.append(session.declare_subscriber(
                f"{s.domain_id}/{s.odom_topic.strip('/')}/{mangled_type(ODOMETRY)}/*",
                self._received))
            self._cmd = Publisher(session, s.domain_id, 0, 1, NODE_NAME, s.cmd_vel_topic, TWIST)
        except Exception as e:  # noqa: BLE001 - zenoh's errors carry no common type
            self.close()
            raise DeviceInitError(f"ros2 base: cannot open a zenoh session to "
                                  f"{list(s.connect)}: {e}") from e
        self._running = True
        self._closing.clear()
        self._thread = threading.Thread(target=self._control_loop, name="ros2-base",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._closing.set()
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._cmd is not None:
            with contextlib.suppress(Exception):
                self._cmd.put_message(twist(0.0, 0.0, 0.0))  # the daemon goes quiet: stop
                self._cmd.close()
            self._cmd = None
        for entity in self._entities:
            with contextlib.suppress(Exception):  # the session already closed
                entity.undeclare()
        self._entities = []
        if self._session is not None:
            self._session.close()
            self._session = None

    @property
    def info(self) -> BaseInfo:
        s = self._settings
        return BaseInfo("ros2", f"{s.odom_topic} -> {s.cmd_vel_topic} (domain {s.domain_id})",
                        s.can_move, 0.0, odometry_kept_on_reopen=True,
                        kinematics=s.kinematics)

    def _received(self, sample: zenoh.Sample) -> None:
        try:
            x, y, yaw, stamp_ns = decode_odometry(sample.payload.to_bytes())
        except ValueError as e:
            with self._cond:
                self._counts["malformed"] += 1
                first = self._counts["malformed"] == 1
            if first:
                log.warning("%s: %s; dropped (reported once, counted in malformed)",
                            self._settings.odom_topic, e)
            return
        stamp_ns = monotonic_of(stamp_ns)  # ROS time onto the daemon's clock
        with self._cond:
            self._seq += 1
            odo = Odometry(x, y, yaw, stamp_ns, self._seq)
            self._samples.append(odo)
            self._latest, self._latest_arrival = odo, time.monotonic()
            self._recent.append(odo)
            while len(self._recent) > 2 and self._recent[1].stamp_ns <= stamp_ns - int(
                    self._settings.at_rest_s * 1e9):
                self._recent.popleft()
            self._counts["samples"] += 1
            if self._fault:
                log.info("%s: odometry again", self._settings.odom_topic)
            self._fault = False
            self._cond.notify_all()

    def read(self, timeout: float) -> list[Odometry]:
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._samples), timeout):
                raise DeviceTimeoutError(f"no odometry on ROS 2 topic "
                                         f"{self._settings.odom_topic} within {timeout:.2f} s")
            out, self._samples = self._samples, []
        return out

    def status(self) -> BaseStatus:
        """``moving`` while a command is under way and, after it, until the odometry shows
        the robot still (``at_rest``): a stop is obeyed over the robot's deceleration.
        Odometry quiet past odometry_timeout_s tells nothing: the commands alone count."""
        with self._cond:
            fresh = time.monotonic() - self._latest_arrival <= self._settings.odometry_timeout_s
            still = not fresh or at_rest(list(self._recent), self._settings.at_rest_s)
            return BaseStatus(moving=self._moving or not still, move_done=self._move_done,
                              fault=self._fault)

    def stats(self) -> Mapping[str, float]:
        with self._cond:
            return dict(self._counts)

    # ---------------------------------------------------------------- commands
    def _check_motion(self, what: str, *values: float) -> None:
        s = self._settings
        if not s.can_move:
            raise CommandRejectedError("the ros2 base is configured with can_move = false")
        if self._cmd is None:
            raise CommandRejectedError("the ros2 base is not open")
        if not all(math.isfinite(v) for v in values):
            raise CommandRejectedError(f"invalid {what} {values}")

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        self._check_motion("move", dx, dy, dyaw, speed)
        s = self._settings
        if speed <= 0:
            raise CommandRejectedError(f"invalid move ({dx}, {dy}, {dyaw}) at {speed} m/s")
        if s.kinematics == "differential" and (dy != 0.0 or (dx != 0.0 and dyaw != 0.0)):
            raise CommandRejectedError(
                f"move ({dx}, {dy}, {dyaw}): a differential base drives along its heading "
                "or turns in place, one at a time")
        with self._cond:
            odo = self._latest
            if odo is None or time.monotonic() - self._latest_arrival > s.odometry_timeout_s:
                raise CommandRejectedError(f"no odometry on {s.odom_topic} within "
                                           f"{s.odometry_timeout_s} s: cannot close a move on it")
            c, si = math.cos(odo.yaw), math.sin(odo.yaw)
            self._goal = Goal(odo.x + dx * c - dy * si, odo.y + dx * si + dy * c,
                              float(wrap_angle(odo.yaw + dyaw)), min(speed, s.max_speed_m_s))
            self._velocity = None
            self._moving, self._move_done = True, False
            self._counts["commands"] += 1
            self._cond.notify_all()

    def velocity(self, vx: float, vy: float, w: float) -> None:
        self._check_motion("velocity", vx, vy, w)
        s = self._settings
        if s.kinematics == "differential" and vy != 0.0:
            raise CommandRejectedError(f"velocity vy = {vy}: a differential base has no "
                                       "sideways motion")
        with self._cond:
            self._goal = None
            self._velocity = (vx, vy, w)
            self._velocity_until = time.monotonic() + s.command_timeout_s
            self._moving, self._move_done = True, False
            self._counts["commands"] += 1
            self._cond.notify_all()

    def stop(self) -> None:
        with self._cond:
            was = self._goal is not None or self._velocity is not None
            self._goal, self._velocity = None, None
            self._moving = False
            self._move_done = was or self._move_done
        self._publish(0.0, 0.0, 0.0)

    def _publish(self, vx: float, vy: float, w: float) -> None:
        cmd = self._cmd
        if cmd is not None:
            with contextlib.suppress(Exception):  # zenoh shutting down
                cmd.put_message(twist(vx, vy, w))

    # ---------------------------------------------------------------- control
    def _control_loop(self) -> None:
        period = 1.0 / self._settings.control_rate_hz
        next_tick = time.monotonic()
        while self._running:
            command = self._control_step(time.monotonic())
            if command is not None:
                self._publish(*command)
            # At control_rate_hz (odometry samples do not wake it), late ticks not caught up.
            next_tick = max(next_tick + period, time.monotonic())
            self._closing.wait(max(0.0, next_tick - time.monotonic()))

    def _control_step(self, now: float) -> tuple[float, float, float] | None:
        """The Twist to publish now (None: nothing): the move or velocity under way, or a
        stop from the watchdog."""
        s = self._settings
        with self._cond:
            if self._goal is None and self._velocity is None:
                return None
            if self._latest is None or now - self._latest_arrival > s.odometry_timeout_s:
                if not self._fault:
                    log.warning("%s quiet for %.2f s while moving: stopped",
                                s.odom_topic, s.odometry_timeout_s)
                self._fault = True
                self._goal, self._velocity, self._moving = None, None, False
                self._counts["watchdog_stops"] += 1
                return 0.0, 0.0, 0.0
            if self._velocity is not None:
                if now > self._velocity_until:  # the daemon went quiet: stop
                    self._velocity, self._moving = None, False
                    self._counts["watchdog_stops"] += 1
                    return 0.0, 0.0, 0.0
                return self._velocity
            assert self._goal is not None
            odo = self._latest
            command = move_command((odo.x, odo.y, odo.yaw), self._goal, s.kinematics, s)
            if command is None:
                self._goal, self._moving, self._move_done = None, False, True
                return 0.0, 0.0, 0.0
            return command
