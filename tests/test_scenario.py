"""Scenario files: strict parsing, illumination schedules, walkers, kidnaps, autopilot."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from hal.sim.factory import build_sim_robot
from hal.sim.scenario import Walker, load_scenario, scenario_from_dict
from kernel.errors import ConfigError
from tests.daemon_harness import REPO
from tests.sim_helpers import lockstep_config


@pytest.mark.parametrize("path", sorted((REPO / "config" / "scenarios").glob("*.toml")))
def test_shipped_scenarios_load(path: Path) -> None:
    s = load_scenario(path)
    assert s.end_time_s() > 0 and s.world


def test_illumination_schedule_is_piecewise_linear() -> None:
    s = scenario_from_dict({"world": "generate:office:1",
                            "illumination": {"schedule": [[0, 1.0], [10, 0.5], [20, 1.5]]}})
    assert s.gain_at(0) == 1.0 and s.gain_at(5) == pytest.approx(0.75)
    assert s.gain_at(15) == pytest.approx(1.0) and s.gain_at(99) == 1.5


def test_walker_goes_back_and_forth() -> None:
    w = Walker(((0.0, 0.0), (4.0, 0.0)), speed=1.0)
    assert w.position(1.0) == pytest.approx((1.0, 0.0))
    assert w.position(5.0) == pytest.approx((3.0, 0.0))  # on the way back
    late = Walker(((0.0, 0.0), (4.0, 0.0)), start_s=10.0)
    assert late.position(5.0) is None


def test_autopilot_follows_the_loop_and_kidnap_teleports() -> None:
    s = load_scenario(REPO / "config" / "scenarios" / "kidnap.toml")
    robot = build_sim_robot(lockstep_config(), s)
    robot.advance_to(int(24e9))
    x, y, _ = robot.true_pose()
    assert math.hypot(x - 9.0, y - 10.0) < 0.03  # reached its waypoint
    odo = robot.odometry_pose()
    robot.advance_to(int(26e9))
    assert robot.true_pose() == pytest.approx((15.0, 4.0, 1.57))
    assert robot.odometry_pose() == odo


@pytest.mark.parametrize(("doc", "message"), [
    ({}, "scenario.world"),
    ({"world": "generate:office:1", "speed": 1}, "scenario: unknown key 'speed'"),
    ({"world": "generate:office:1", "trajectory": {"kind": "spiral"}}, "trajectory.kind"),
    ({"world": "generate:office:1", "trajectory": {"kind": "tbl"}}, "needs scenario.start_pose"),
    ({"world": "generate:office:1", "illumination": {"schedule": [[0, 1], [0, 2]]}},
     "times must increase"),
    ({"world": "generate:office:1", "kidnap": [{"t_s": 1, "pose": [1, 2]}]}, "kidnap[0].pose"),
    ({"world": "generate:office:1", "people": [{"path": [[0, 0]], "sped": 1}]},
     "people[0]: unknown key 'sped'"),
    ({"world": "generate:office:1", "drift": {"scale": 0.1}}, "drift: unknown key 'scale'"),
])
def test_bad_scenarios_name_the_key(doc: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        scenario_from_dict(doc)
    assert message in str(e.value)


def test_scenario_overrides_reach_the_robot(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('world = "generate:open-room:1"\nstart_pose = [1.0, 1.0, 0.5]\n'
                    'frame_rate_hz = 4.0\n[drift]\nscale_error = 0.05\n')
    robot = build_sim_robot(lockstep_config(scenario=str(path)))
    assert robot.true_pose() == (1.0, 1.0, 0.5)
    assert robot.camera.rate_hz == 4.0 and robot.base.scale_error == 0.05
