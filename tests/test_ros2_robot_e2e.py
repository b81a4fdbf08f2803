"""The daemon on a ROS 2 robot (issue 33): ``placecell-sim ros2-robot`` plays a
differential-drive ROS 2 robot over rmw_zenoh (mirror images, /odom, odom -> base_link on
/tf, /cmd_vel) in its own process; the daemon, with the ``ros2`` camera and base backends
connecting to it and ``[ros2]`` on, learns a place by Turn Back and Look driven through
/cmd_vel and tracks in it. An independent client (rosbags and a plain zenoh session, none
of the project's code) drives the robot on with Twists and composes the daemon's
``map -> odom`` with the robot's ``odom -> base_link``: the true pose. No truth reaches the
daemon: it sees only the robot's topics."""

from __future__ import annotations

import json
import math
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from tests.api_schema import check
from tests.daemon_harness import (
    REPO,
    client_session,
    ctl,
    free_port,
    running_daemon,
    venv_bin,
    wait_for,
    wait_ready,
    write_config,
)

pytestmark = pytest.mark.xdist_group("realtime")

TS = get_typestore(Stores.ROS2_JAZZY)
START = (3.0, 10.0, 0.0)  # the robot's start in the world: where the place is learned


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _compose(a: tuple[float, float, float], b: tuple[float, float, float]
             ) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


class Tf:
    """The last transform per (parent, child) heard on /tf, decoded by rosbags."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.last: dict[tuple[str, str], tuple[float, float, float]] = {}

    def heard(self, sample: Any) -> None:
        msg = TS.deserialize_cdr(sample.payload.to_bytes(), "tf2_msgs/msg/TFMessage")
        with self.lock:
            for t in msg.transforms:
                tr = t.transform
                self.last[(t.header.frame_id, t.child_frame_id)] = (
                    tr.translation.x, tr.translation.y, _yaw(tr.rotation))

    def map_base(self) -> tuple[float, float, float] | None:
        with self.lock:
            map_odom, odom_base = self.last.get(("map", "odom")), \
                self.last.get(("odom", "base_link"))
        return None if map_odom is None or odom_base is None else \
            _compose(map_odom, odom_base)


def _drive(session: zenoh.Session, v: float, seconds: float) -> None:
    """Twists on /cmd_vel at 10 Hz for ``seconds`` (a teleop), then one stop."""
    key = f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TS.hash_rihs01('geometry_msgs/msg/Twist')}"
    v3 = TS.types["geometry_msgs/msg/Vector3"]

    def twist(x: float) -> bytes:
        return bytes(TS.serialize_cdr(TS.types["geometry_msgs/msg/Twist"](
            linear=v3(x=x, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)),
            "geometry_msgs/msg/Twist"))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        session.put(key, twist(v))
        time.sleep(0.1)  # a teleop's publishing rate, not a wait for the daemon
    session.put(key, twist(0.0))


def _rows(path: Path, n: int) -> list[dict[str, float]]:
    """The last ``n`` whole lines of the simulator's truth file (it is being written)."""
    out = []
    for line in path.read_text().splitlines()[-n - 1:] if path.exists() else []:
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out[-n:]


def _truth(path: Path) -> tuple[float, float, float]:
    last = _rows(path, 1)[-1]
    return float(last["x"]), float(last["y"]), float(last["yaw"])


def _plain(port: int) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def _at_rest(path: Path) -> bool:
    """The last second of truth moved less than a millimetre."""
    rows = _rows(path, 60)
    return len(rows) > 10 and math.dist((rows[0]["x"], rows[0]["y"]),
                                        (rows[-1]["x"], rows[-1]["y"])) < 1e-3


@pytest.mark.timeout(420)
def test_a_ros2_differential_robot_learns_a_place_through_its_topics(tmp_path: Path) -> None:
    robot_port = free_port()
    log_path, truth_path = tmp_path / "robot.log", tmp_path / "truth.jsonl"
    with log_path.open("w") as log:
        robot = subprocess.Popen(
            [venv_bin("placecell-sim"), "ros2-robot", "--listen",
             f"tcp/127.0.0.1:{robot_port}", "--start", *map(str, START),
             "--truth-out", str(truth_path), "--duration", "400"],
            cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    connect = [f"tcp/127.0.0.1:{robot_port}"]
    config, port = write_config(tmp_path, {
        "robot": {"name": "turtle"},
        "zenoh": {"connect": connect},  # as a ROS node: to the robot's zenoh (its router)
        "ros2": {"enabled": True},
        "camera": {"backend": "ros2", "ros2": {"connect": connect}},
        "base": {"backend": "ros2", "ros2": {"connect": connect}}})
    poses: list[dict[str, Any]] = []
    lock = threading.Lock()
    try:
        with running_daemon(config) as proc:
            wait_ready(config, 120, "no frames or odometry from ROS 2")

            learned = ctl(config, "learn", "--label", "dock", "--json")
            assert learned.returncode == 0, (learned.stdout[-2000:], learned.stderr[-2000:])
            last = check(json.loads(learned.stdout.splitlines()[-1]))
            assert last["kind"] == "result" and last["place"]["label"] == "dock", last

            session = client_session(port)
            try:
                def on_pose(sample: Any) -> None:
                    with lock:
                        poses.append(check(json.loads(sample.payload.to_bytes())))

                session.declare_subscriber("placecell/turtle/pose", on_pose)

                def tracking() -> bool:
                    with lock:
                        return any(p["state"] == "tracking" for p in poses[-5:])
                assert wait_for(tracking, 60), poses[-1:]
            finally:
                session.close()

            # An independent ROS 2 client: teleop 1 m on, then map -> odom (the daemon's)
            # composed with odom -> base_link (the robot's) against the truth, both in the
            # map frame (the first place's reference: where the robot started).
            ros = zenoh.open(_plain(robot_port))
            tf = Tf()
            try:
                ros.declare_subscriber("0/tf/*/*", tf.heard)
                assert wait_for(lambda: tf.map_base() is not None, 60), tf.last
                _drive(ros, 0.25, 4.0)
                assert wait_for(lambda: _at_rest(truth_path), 60)
                wx, wy, wyaw = _truth(truth_path)
                c, s = math.cos(-START[2]), math.sin(-START[2])
                truth = (c * (wx - START[0]) - s * (wy - START[1]),
                         s * (wx - START[0]) + c * (wy - START[1]))
                assert math.hypot(*truth) > 0.8  # the teleop moved it

                def agrees() -> bool:
                    got = tf.map_base()
                    return got is not None and math.dist(got[:2], truth) <= 0.05
                assert wait_for(agrees, 30), (tf.map_base(), truth)
            finally:
                ros.close()
            assert proc.poll() is None
    except BaseException:
        print("--- the ROS 2 robot's log:")
        print("\n".join(log_path.read_text(errors="replace").splitlines()[-40:]))
        raise
    finally:
        robot.terminate()
        robot.wait(15)
