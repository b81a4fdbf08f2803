"""Experiments on the ``ros2`` backends (``--backends ros2``, issue 33): the simulated
robot runs as a ROS 2 robot in its own process (``placecell-sim ros2-robot``, real time,
holonomic so the experiments drive the same moves), and the experiment's :class:`Run`
reads its camera and drives its base through the daemon's ``ros2`` camera and base
backends over rmw_zenoh, as a daemon on a ROS 2 robot does. Only the evaluator asks the
robot's process for the truth (its ``--truth-service``): the true and odometry poses at the
stamp of the last frame the run read, and kidnaps.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import zenoh

from daemon.config import PlacecellConfig
from hal.ros2_wire import open_session
from kernel.errors import PlacecellError
from kernel.types import Frame
from tools.simcmd.ros2_robot import KIDNAP_KEY, TRUTH_KEY

REPO = Path(__file__).resolve().parents[2]
# How long the robot's process may take to come up (imports, the world's renderer).
START_TIMEOUT_S = 120.0
# A run's pauses between frames (a learn's storing) are not a dead link here.
ODOMETRY_TIMEOUT_S = 10.0


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RemoteSimRobot:
    """The simulator's truth interface of a robot in another process: what the
    experiments ask of :class:`~hal.sim.robot.SimRobot` (``true_pose``,
    ``odometry_pose``, ``kidnap``), at the last frame the run read."""

    def __init__(self, session: zenoh.Session, timeout_s: float) -> None:
        self._session, self._timeout_s = session, timeout_s
        self.frame_stamp_ns: int | None = None  # of the last frame read (None: now)

    def _ask(self, key: str, body: dict[str, Any]) -> dict[str, Any]:
        for reply in self._session.get(key, payload=json.dumps(body),
                                       timeout=self._timeout_s):
            if reply.ok is not None:
                return dict(json.loads(reply.ok.payload.to_bytes()))
            if reply.err is not None:
                raise PlacecellError(f"{key}: {reply.err.payload.to_string()}")
        raise PlacecellError(f"{key}: the ROS 2 robot's process did not answer")

    def _truth(self) -> dict[str, Any]:
        return self._ask(TRUTH_KEY, {"stamp_ns": self.frame_stamp_ns})

    def true_pose(self) -> tuple[float, float, float]:
        x, y, yaw = self._truth()["pose"]
        return float(x), float(y), float(yaw)

    def odometry_pose(self) -> tuple[float, float, float]:
        x, y, yaw = self._truth()["odometry"]
        return float(x), float(y), float(yaw)

    def kidnap(self, x: float, y: float, yaw: float) -> None:
        self._ask(KIDNAP_KEY, {"pose": [x, y, yaw]})
        self.frame_stamp_ns = None  # the truth is the new pose until a frame comes

    def watch(self, camera: Any) -> Any:
        """``camera`` whose reads set the stamp the truth is asked at."""
        return _WatchedCamera(camera, self)


class _WatchedCamera:
    def __init__(self, camera: Any, robot: RemoteSimRobot) -> None:
        self._camera, self._robot = camera, robot

    def read(self, timeout: float) -> Frame:
        frame: Frame = self._camera.read(timeout)
        self._robot.frame_stamp_ns = frame.stamp_ns
        return frame

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)


def ros2_config(cfg: PlacecellConfig, endpoint: str) -> PlacecellConfig:
    """``cfg`` on the ros2 camera and a holonomic ros2 base connecting to ``endpoint``."""
    camera = dataclasses.replace(cfg.camera, backend="ros2", ros2=dataclasses.replace(
        cfg.camera.ros2, connect=[endpoint]))
    base = dataclasses.replace(cfg.base, backend="ros2", ros2=dataclasses.replace(
        cfg.base.ros2, connect=[endpoint], kinematics="holonomic",
        odometry_timeout_s=ODOMETRY_TIMEOUT_S))
    return dataclasses.replace(cfg, camera=camera, base=base)


@contextlib.contextmanager
def ros2_robot(cfg: PlacecellConfig) -> Iterator[tuple[PlacecellConfig, RemoteSimRobot]]:
    """The robot of ``cfg``'s [sim] (world, start pose, seed) in its own process; yields
    ``cfg`` on the ros2 backends connecting to it and the robot's truth interface."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    start = [str(v) for v in cfg.sim.start_pose]
    with tempfile.TemporaryFile("w+") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "tools.sim_cli", "ros2-robot", "--listen", endpoint,
             "--world", cfg.sim.world, "--seed", str(cfg.sim.seed), "--start", *start,
             "--holonomic", "--truth-service"],
            cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
        session = open_session(connect=[endpoint])
        try:
            robot = RemoteSimRobot(session, cfg.base.read_timeout_s + 5.0)
            deadline = time.monotonic() + START_TIMEOUT_S
            while True:
                try:
                    robot.true_pose()
                    break
                except PlacecellError:
                    if process.poll() is not None or time.monotonic() > deadline:
                        log.seek(0)
                        raise PlacecellError("the ROS 2 robot's process did not come up: "
                                             + log.read()[-2000:]) from None
                    time.sleep(0.2)  # polling a process that is starting
            yield ros2_config(cfg, endpoint), robot
        finally:
            session.close()
            process.terminate()
            process.wait(15)
