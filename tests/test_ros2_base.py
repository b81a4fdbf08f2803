"""The `ros2` base backend (hal/base/ros2.py, issue 33): nav_msgs/Odometry in, Twist out,
moves closed on that odometry, and the watchdog; against a simulated ROS 2
differential-drive base (tests/ros2_diffdrive.py) over a real zenoh session on loopback."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from daemon.config import load
from hal.base.ros2 import Goal, Ros2Base, at_rest, move_command
from hal.base.settings import BaseSettings, Ros2BaseSettings
from hal.registry import HalContext, create_base
from kernel.errors import CommandRejectedError, ConfigError
from kernel.types import Odometry
from tests.daemon_harness import free_port, wait_for
from tests.ros2_diffdrive import Ros2DiffDriveRobot

S = Ros2BaseSettings()
# Waits scale with the settings they wait on (a busy machine slows the control loop).
MOVE_WAIT_S = 60 * S.odometry_timeout_s


def test_a_differential_move_drives_on_the_line_then_turns() -> None:
    ahead = move_command((0.0, 0.0, 0.0), Goal(1.0, 0.0, 0.0, 0.2), "differential", S)
    assert ahead is not None and ahead[0] == pytest.approx(0.2) and ahead[1:] == (0.0, 0.0)
    behind = move_command((0.0, 0.0, 0.0), Goal(-1.0, 0.0, 0.0, 0.2), "differential", S)
    assert behind is not None and behind[0] == pytest.approx(-0.2) and behind[2] == 0.0
    # Off the line to the left: steer left while driving (and backwards, the other way).
    steer = move_command((0.0, -0.05, 0.0), Goal(1.0, 0.0, 0.0, 0.2), "differential", S)
    assert steer is not None and steer[2] > 0
    back = move_command((0.0, -0.05, 0.0), Goal(-1.0, 0.0, 0.0, 0.2), "differential", S)
    assert back is not None and back[0] < 0 and back[2] < 0
    # At the goal's position: turn only, slowing over the last slow_down_rad.
    turn = move_command((1.0, 0.0, 0.0), Goal(1.0, 0.0, math.pi / 2, 0.2), "differential", S)
    assert turn == (0.0, 0.0, S.max_yaw_rate_rad_s)
    near = move_command((1.0, 0.0, 1.5), Goal(1.0, 0.0, math.pi / 2, 0.2), "differential", S)
    assert near is not None and 0 < near[2] < S.max_yaw_rate_rad_s
    assert move_command((1.0, 0.005, 1.57), Goal(1.0, 0.0, 1.5708, 0.2),
                        "differential", S) is None
    # Slowing down over the last slow_down_m.
    slow = move_command((0.95, 0.0, 0.0), Goal(1.0, 0.0, 0.0, 0.2), "differential", S)
    assert slow is not None and slow[0] == pytest.approx(0.2 * 0.05 / S.slow_down_m)


def test_a_holonomic_move_goes_straight_for_the_goal() -> None:
    cmd = move_command((0.0, 0.0, math.pi / 2), Goal(0.0, 1.0, math.pi / 2, 0.2),
                       "holonomic", S)
    assert cmd is not None and cmd[0] == pytest.approx(0.2) and abs(cmd[1]) < 1e-9
    cmd = move_command((0.0, 0.0, 0.0), Goal(0.0, 1.0, 0.0, 0.2), "holonomic", S)
    assert cmd is not None and cmd[1] == pytest.approx(0.2)  # sideways


def test_at_rest_needs_the_whole_window_still() -> None:
    def odo(t_s: float, x: float, yaw: float = 0.0) -> Odometry:
        return Odometry(x, 0.0, yaw, int(t_s * 1e9), 0)

    still = [odo(0.0, 1.0), odo(0.1, 1.001), odo(0.2, 1.0)]
    assert at_rest(still, 0.2)
    assert not at_rest(still[1:], 0.2)  # 0.1 s of samples: not known yet
    assert not at_rest([odo(0.0, 0.99), *still[1:]], 0.2)  # 1 cm at the window's start
    assert not at_rest([*still[:2], odo(0.2, 1.0, 0.01)], 0.2)  # still turning
    assert at_rest([], 0.2)  # no odometry: no motion known


def test_topics_that_are_not_ros2_names_are_refused(tmp_path: object) -> None:
    path = tmp_path / "bad.toml"  # type: ignore[operator]
    path.write_text('[base]\nbackend = "ros2"\n[base.ros2]\ncmd_vel_topic = "cmd vel"\n')
    with pytest.raises(ConfigError, match="base.ros2.cmd_vel_topic"):
        load(path)


@pytest.fixture
def robot_and_base() -> Iterator[tuple[Ros2DiffDriveRobot, Ros2Base]]:
    port = free_port()
    robot = Ros2DiffDriveRobot(port)
    base = create_base(BaseSettings(backend="ros2", ros2=Ros2BaseSettings(
        connect=[f"tcp/127.0.0.1:{port}"])), HalContext(load(None)))
    assert isinstance(base, Ros2Base)
    base.open()
    try:
        yield robot, base
    finally:
        base.close()
        robot.close()


def test_odometry_comes_in_and_moves_are_driven_to_within_the_tolerances(
        robot_and_base: tuple[Ros2DiffDriveRobot, Ros2Base]) -> None:
    robot, base = robot_and_base
    samples = base.read(MOVE_WAIT_S)  # the subscription reached the robot
    assert samples and all(math.isfinite(o.x) for o in samples)
    assert base.info.kinematics == "differential"
    with pytest.raises(CommandRejectedError, match="differential"):
        base.move_relative(0.0, 0.2, 0.0, 0.2)  # sideways
    with pytest.raises(CommandRejectedError, match="one at a time"):
        base.move_relative(0.2, 0.0, 0.5, 0.2)

    base.move_relative(0.4, 0.0, 0.0, 0.2)
    assert wait_for(lambda: base.status().move_done, MOVE_WAIT_S), base.status()
    x, y, yaw = robot.pose
    assert abs(x - 0.4) < 2 * S.position_tolerance_m + 0.01 and abs(y) < 0.02, robot.pose
    base.move_relative(0.0, 0.0, math.pi / 2, 0.2)
    assert wait_for(lambda: base.status().move_done, MOVE_WAIT_S), base.status()
    assert abs(math.remainder(robot.pose[2] - math.pi / 2, 2 * math.pi)) < 0.05, robot.pose
    base.move_relative(-0.2, 0.0, 0.0, 0.2)  # backwards, along the new heading
    assert wait_for(lambda: base.status().move_done, MOVE_WAIT_S), base.status()
    assert abs(robot.pose[0] - 0.4) < 0.03 and abs(robot.pose[1] + 0.2) < 0.03, robot.pose
    assert base.read(MOVE_WAIT_S)[-1].seq > samples[-1].seq  # odometry flowed throughout


def test_the_watchdog_stops_the_robot_when_odometry_or_the_daemon_goes_quiet(
        robot_and_base: tuple[Ros2DiffDriveRobot, Ros2Base]) -> None:
    robot, base = robot_and_base
    base.read(MOVE_WAIT_S)
    # A velocity not repeated: stopped after command_timeout_s (a zero Twist sent).
    base.velocity(0.1, 0.0, 0.0)
    assert wait_for(lambda: base.stats()["watchdog_stops"] == 1, MOVE_WAIT_S)
    assert robot.commands[-1] == (0.0, 0.0, 0.0)
    assert wait_for(lambda: not base.status().moving, MOVE_WAIT_S)  # once odometry is still
    # Odometry stops while a move is under way: stopped, fault until it is back.
    base.move_relative(2.0, 0.0, 0.0, 0.2)
    assert wait_for(lambda: any(c[0] > 0 for c in robot.commands[-3:]), MOVE_WAIT_S)
    robot.publishing = False
    assert wait_for(lambda: base.status().fault, MOVE_WAIT_S), base.status()
    assert robot.commands[-1] == (0.0, 0.0, 0.0) and not base.status().moving
    assert base.stats()["watchdog_stops"] == 2
    robot.publishing = True
    assert wait_for(lambda: not base.status().fault, MOVE_WAIT_S)
    assert not base.status().move_done  # the move was abandoned, not done


def test_a_stopped_robot_counts_as_moving_until_its_odometry_is_still() -> None:
    """Turn Back and Look takes its reference frames once the base stands (§4.2): a ROS 2
    base decelerates after the zero Twist, so `moving` holds until odometry has stayed
    within 2 mm for [base.ros2] at_rest_s (cyclic over ROS 2 took references while the
    robot still slid on, notes of 2026-12-06)."""
    port = free_port()
    robot = Ros2DiffDriveRobot(port, coast_s=0.4)
    base = create_base(BaseSettings(backend="ros2", ros2=Ros2BaseSettings(
        connect=[f"tcp/127.0.0.1:{port}"])), HalContext(load(None)))
    assert isinstance(base, Ros2Base)
    base.open()
    try:
        base.read(MOVE_WAIT_S)
        assert wait_for(lambda: not base.status().moving, MOVE_WAIT_S)  # standing
        base.velocity(0.2, 0.0, 0.0)
        assert wait_for(lambda: robot.pose[0] > 0.02, MOVE_WAIT_S)
        base.stop()
        assert base.status().moving  # the zero Twist sent; the robot coasts on
        assert wait_for(lambda: not base.status().moving, MOVE_WAIT_S)
        assert robot.stopped_at is not None  # still only once the coast had ended
        at = robot.pose
        assert wait_for(lambda: base.read(MOVE_WAIT_S)[-1].stamp_ns > 0, MOVE_WAIT_S)
        assert math.hypot(robot.pose[0] - at[0], robot.pose[1] - at[1]) < 1e-9
    finally:
        base.close()
        robot.close()
