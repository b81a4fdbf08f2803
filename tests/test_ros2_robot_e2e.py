"""The daemon on a ROS 2 robot (issue 33): ``placecell-sim ros2-robot`` plays a
differential-drive ROS 2 robot over rmw_zenoh (mirror images, /odom, /cmd_vel) in its own
process; the daemon, with the ``ros2`` camera and base backends connecting to it, learns
a place by Turn Back and Look driven through /cmd_vel and tracks in it. No truth reaches
the daemon: it sees only the robot's topics."""

from __future__ import annotations

import json
import subprocess
import threading
from pathlib import Path
from typing import Any

import pytest

from tests.api_schema import check
from tests.daemon_harness import (
    REPO,
    client_session,
    free_port,
    running_daemon,
    venv_bin,
    wait_for,
    write_config,
)

pytestmark = pytest.mark.xdist_group("realtime")


def _ctl(config: Path, *args: str, timeout: float = 240.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([venv_bin("placecellctl"), "--config", str(config), *args],
                          cwd=REPO, capture_output=True, text=True, timeout=timeout)


@pytest.mark.timeout(420)
def test_a_ros2_differential_robot_learns_a_place_through_its_topics(tmp_path: Path) -> None:
    robot_port = free_port()
    log_path = tmp_path / "robot.log"
    with log_path.open("w") as log:
        robot = subprocess.Popen(
            [venv_bin("placecell-sim"), "ros2-robot", "--listen",
             f"tcp/127.0.0.1:{robot_port}", "--start", "3.0", "10.0", "0.0",
             "--duration", "400"], cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    connect = [f"tcp/127.0.0.1:{robot_port}"]
    config, port = write_config(tmp_path, {
        "robot": {"name": "turtle"},
        "camera": {"backend": "ros2", "ros2": {"connect": connect}},
        "base": {"backend": "ros2", "ros2": {"connect": connect}}})
    poses: list[dict[str, Any]] = []
    lock = threading.Lock()
    try:
        with running_daemon(config) as proc:
            def ready() -> bool:  # images and odometry arriving over the ROS topics
                st = _ctl(config, "status", "--json", timeout=30)
                if st.returncode != 0:
                    return False
                status = check(json.loads(st.stdout))
                return bool(status["healthy"]) and status["rates"]["frames_hz"] > 0 \
                    and status["rates"]["odometry_hz"] > 0
            assert wait_for(ready, 120, interval_s=0.5), "no frames or odometry from ROS 2"

            learned = _ctl(config, "learn", "--label", "dock", "--json")
            assert learned.returncode == 0, (learned.stdout[-2000:], learned.stderr[-2000:])
            last = check(json.loads(learned.stdout.splitlines()[-1]))
            assert last.get("place", {}).get("label") == "dock" or "dock" in learned.stdout

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
            assert proc.poll() is None
    except BaseException:
        print("--- the ROS 2 robot's log:")
        print("\n".join(log_path.read_text(errors="replace").splitlines()[-40:]))
        raise
    finally:
        robot.terminate()
        robot.wait(15)
