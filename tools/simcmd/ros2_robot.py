"""``placecell-sim ros2-robot``: the simulated robot as a ROS 2 robot over rmw_zenoh
(issue 33): the configured world seen through the simulated mirror camera, published as
``sensor_msgs/Image`` (bgr8, or ``CompressedImage`` png with ``--compressed``) on
``--image-topic``; its base, differential unless ``--holonomic``, publishing
``nav_msgs/Odometry`` on ``/odom`` and ``odom -> base_link`` on ``/tf`` (with the
simulator's odometry drift) and driven by
``geometry_msgs/Twist`` on ``/cmd_vel`` (stopped when no command came within
``--cmd-timeout``, as ROS base drivers do). It runs in real time, listening on
``--listen`` (loopback by default), until SIGTERM/SIGINT or ``--duration``.

``--truth-service`` adds the simulator's truth interface for an evaluator in another
process (``placecell-eval … --backends ros2``; never for the daemon, which sees only the
ROS topics): the zenoh queryable ``placecell_sim/truth`` answers ``{"stamp_ns": N}`` (a
stamp on the monotonic clock, as frames carry after the ros2 backends' conversion) with
the true and odometry poses of the simulation step nearest it (``null``: now), and
``placecell_sim/kidnap`` answers ``{"pose": [x, y, yaw]}`` by carrying the robot there
(odometry knows nothing of it).

A daemon configured with ``camera.backend = "ros2"`` and ``base.backend = "ros2"``
connecting there runs the whole method on it, Turn Back and Look included: what a ROS 2
robot would give it, with the simulator's truth kept out of the daemon.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import signal
import threading
import time
from typing import Any

import cv2
import numpy as np
import zenoh

from daemon.service.ros2 import TF_QOS_KEYEXPR, TF_TYPE, tf_cdr
from hal import ros2_wire as wire
from hal.base.ros2 import ODOMETRY, TWIST, odometry_message
from hal.sim.factory import build_sim_robot
from hal.sim.robot import SimRobot
from kernel.errors import CommandRejectedError
from kernel.se2 import SE2
from tools.simcmd import load_config

log = logging.getLogger(__name__)

TRUTH_KEY, KIDNAP_KEY = "placecell_sim/truth", "placecell_sim/kidnap"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="daemon configuration for the world, mirror and camera "
                                    "(default: config/placecell.toml or built-in)")
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="zenoh endpoint to listen on")
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID")
    p.add_argument("--image-topic", default="/camera/image_raw")
    p.add_argument("--compressed", action="store_true",
                   help="publish CompressedImage (png) instead of Image (bgr8)")
    p.add_argument("--holonomic", action="store_true", help="a holonomic base (default: "
                   "differential, as most ROS 2 robots)")
    p.add_argument("--cmd-timeout", type=float, default=0.5,
                   help="stop when no Twist came within this, s")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this, s (0: never)")
    p.add_argument("--scenario", default="", help="a scenario TOML whose world, start pose "
                   "and faults to use (its autopilot would drive against /cmd_vel; default: "
                   "the configured world, the robot waiting for commands)")
    p.add_argument("--start", type=float, nargs=3, metavar=("X", "Y", "YAW"),
                   help="start pose in the world (default: the world's)")
    p.add_argument("--world", default="", help="world spec (default: the configured one)")
    p.add_argument("--seed", type=int, default=None, help="the simulator's seed (default: "
                   "the configured one)")
    p.add_argument("--truth-service", action="store_true",
                   help="answer placecell_sim/truth and placecell_sim/kidnap (evaluators)")
    p.add_argument("--truth-out", default="", help="append the true pose per step here "
                   "(JSON lines, for tests; never published)")


class Ros2SimRobot:
    """The simulated robot's camera and base as ROS 2 topics (module docstring)."""

    def __init__(self, robot: SimRobot, session: zenoh.Session, domain_id: int,
                 image_topic: str, compressed: bool, cmd_timeout_s: float) -> None:
        self.robot, self.session = robot, session
        self.compressed, self.cmd_timeout_s = compressed, cmd_timeout_s
        zid = str(session.zid())
        self._entities: list[Any] = [session.liveliness().declare_token(
            wire.node_token(domain_id, zid, 0, "sim_robot"))]
        self._odom = wire.Publisher(session, domain_id, 0, 1, "sim_robot", "/odom", ODOMETRY)
        self._image = wire.Publisher(session, domain_id, 0, 2, "sim_robot", image_topic,
                                     COMPRESSED if compressed else IMAGE)
        self._tf = wire.Publisher(session, domain_id, 0, 3, "sim_robot", "/tf", TF_TYPE,
                                  TF_QOS_KEYEXPR)
        self._entities.append(session.declare_subscriber(
            f"{domain_id}/cmd_vel/{wire.mangled_type(TWIST)}/*", self._on_twist))
        self._command_at: float | None = None
        self._stop = threading.Event()
        # The simulator's clock is the monotonic one (realtime); ROS time is the UNIX one.
        self._offset_ns = time.time_ns() - time.monotonic_ns()

    def serve_truth(self, kept_s: float = 30.0) -> None:
        """The truth interface of the module docstring, for ``kept_s`` of steps."""
        self.robot.keep_truth(kept_s)
        self._entities += [self.session.declare_queryable(TRUTH_KEY, self._on_truth),
                           self.session.declare_queryable(KIDNAP_KEY, self._on_kidnap)]

    def _on_truth(self, query: zenoh.Query) -> None:
        try:
            stamp = json.loads(query.payload.to_bytes() if query.payload else b"")["stamp_ns"]
            stamp_ns = None if stamp is None else int(stamp)
        except (ValueError, KeyError, TypeError) as e:
            query.reply_err(f"{TRUTH_KEY}: expected {{\"stamp_ns\": N or null}}: {e}")
            return
        found = (self.robot.now_ns(), self.robot.true_pose(), self.robot.odometry_pose()) \
            if stamp_ns is None else self.robot.truth_at(stamp_ns)
        if found is None:
            query.reply_err(f"{TRUTH_KEY}: no step kept near {stamp_ns}")
            return
        at, pose, odo = found
        query.reply(TRUTH_KEY, json.dumps({"stamp_ns": at, "pose": pose, "odometry": odo}))

    def _on_kidnap(self, query: zenoh.Query) -> None:
        try:
            x, y, yaw = (float(v) for v in json.loads(
                query.payload.to_bytes() if query.payload else b"")["pose"])
        except (ValueError, KeyError, TypeError) as e:
            query.reply_err(f"{KIDNAP_KEY}: expected {{\"pose\": [x, y, yaw]}}: {e}")
            return
        self.robot.kidnap(x, y, yaw)
        query.reply(KIDNAP_KEY, "{}")

    def _on_twist(self, sample: zenoh.Sample) -> None:
        try:
            msg: Any = wire.TYPESTORE.deserialize_cdr(sample.payload.to_bytes(), TWIST)
            self.robot.velocity(float(msg.linear.x), float(msg.linear.y), float(msg.angular.z))
            self._command_at = time.monotonic()
        except CommandRejectedError as e:
            log.warning("cmd_vel refused: %s", e)
        except Exception as e:  # noqa: BLE001 - a bad sample from someone else's node
            log.warning("cmd_vel: not a Twist: %s", e)

    def _odometry_loop(self) -> None:
        while not self._stop.is_set():
            for o in self.robot.wait_odometry(0.1):
                with contextlib.suppress(Exception):  # zenoh shutting down
                    self._odom.put_message(odometry_message(o.x, o.y, o.yaw,
                                                            o.stamp_ns + self._offset_ns))
                    self._tf.put(tf_cdr([("odom", "base_link", SE2(o.x, o.y, o.yaw),
                                          o.stamp_ns + self._offset_ns)]))
            at = self._command_at
            if at is not None and time.monotonic() - at > self.cmd_timeout_s:
                self._command_at = None
                self.robot.stop()  # the daemon went quiet: a base driver stops

    def _camera_loop(self) -> None:
        t = wire.TYPESTORE.types
        while not self._stop.is_set():
            frame = self.robot.next_frame(0.5)
            if frame is None:
                continue
            image = frame.image if frame.image.ndim == 3 else cv2.cvtColor(
                frame.image, cv2.COLOR_GRAY2BGR)
            header = t["std_msgs/msg/Header"](
                stamp=wire.ros_time(frame.stamp_ns + self._offset_ns), frame_id="camera")
            if self.compressed:
                ok, data = cv2.imencode(".png", image)
                msg = t[COMPRESSED](header=header, format="png",
                                    data=np.asarray(data, np.uint8).ravel())
            else:
                h, w = image.shape[:2]
                msg = t[IMAGE](header=header, height=h, width=w, encoding="bgr8",
                               is_bigendian=0, step=3 * w,
                               data=np.ascontiguousarray(image).ravel())
            with contextlib.suppress(Exception):  # zenoh shutting down
                self._image.put_message(msg)

    def run(self, duration_s: float = 0.0) -> None:
        threads = [threading.Thread(target=f, name=n, daemon=True) for f, n in
                   ((self._odometry_loop, "ros2-odom"), (self._camera_loop, "ros2-camera"))]
        for th in threads:
            th.start()
        self._stop.wait(duration_s if duration_s > 0 else None)
        self._stop.set()
        for th in threads:
            th.join(timeout=2.0)

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        self.stop()
        for entity in self._entities:
            with contextlib.suppress(Exception):
                entity.undeclare()
        for publisher in (self._odom, self._image, self._tf):
            publisher.close()


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    base = dataclasses.replace(config.base.sim, kinematics="holonomic" if args.holonomic
                               else "differential")
    sim = dataclasses.replace(config.sim, realtime=True, scenario=args.scenario,
                              start_pose=list(args.start) if args.start else [0.0, 0.0, 0.0],
                              truth_out=args.truth_out,
                              world=args.world or config.sim.world,
                              seed=config.sim.seed if args.seed is None else args.seed)
    config = dataclasses.replace(config, sim=sim,
                                 base=dataclasses.replace(config.base, sim=base))
    robot = build_sim_robot(config)
    session = wire.open_session(listen=[args.listen])
    node = Ros2SimRobot(robot, session, args.domain, args.image_topic, args.compressed,
                        args.cmd_timeout)
    if args.truth_service:
        node.serve_truth()
    signal.signal(signal.SIGTERM, lambda *_: node.stop())
    signal.signal(signal.SIGINT, lambda *_: node.stop())
    log.info("ROS 2 robot on %s: %s, /odom, /cmd_vel (domain %d)", args.listen,
             args.image_topic, args.domain)
    try:
        node.run(args.duration)
    finally:
        node.close()
        session.close()
    return 0
