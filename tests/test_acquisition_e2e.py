"""Places learned on the robot's own through the running daemon (design §6, thesis §7.1):
the daemon in a subprocess with autonomous acquisition on, the robot driven along the
office corridor by the scenario's autopilot, no learn command sent; what it did is read
by other processes (`placecellctl events --follow`, `placecellctl place`), the truth from
the simulator's own truth file (the daemon never sees it)."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import pytest

from kernel.se2 import SE2
from tests.api_schema import check
from tests.daemon_harness import (
    REPO,
    read_json_lines,
    running_daemon,
    venv_bin,
    wait_for,
    write_config,
)
from tests.test_learn_e2e import NO_DRIFT, Truth

# Held to wall-clock limits: one worker runs these modules one after another (tests/conftest.py).
pytestmark = pytest.mark.xdist_group("realtime")


def _scenario(tmp: Path) -> Path:
    """The robot waits in the office corridor until its first place is learned, then
    drives 4.5 m along it (exact odometry: the transition can be held to the truth)."""
    path = tmp / "drive-on.toml"
    path.write_text("\n".join([
        'name = "drive-on"', 'world = "generate:office:1"', "start_pose = [3.0, 10.0, 0.0]",
        "[trajectory]", 'kind = "waypoints"', "speed = 0.3", "start_after_s = 100000.0",
        "resume_after_s = 3.0", "waypoints = [[7.5, 10.0]]", "[drift]",
        *(f"{k} = {v!r}" for k, v in NO_DRIFT.items())]) + "\n")
    return path


def _ctl_json(config: Path, *args: str) -> dict[str, Any]:
    done = subprocess.run([venv_bin("placecellctl"), "--config", str(config), *args, "--json"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return check(json.loads(done.stdout))


@pytest.mark.timeout(240)
def test_the_daemon_learns_places_on_its_own_as_the_robot_drives(tmp_path: Path) -> None:
    truth = Truth(tmp_path / "truth.jsonl")
    config, _ = write_config(tmp_path, {
        "robot": {"name": "auto"}, "mapping": {"acquisition": {"enabled": True}},
        "sim": {"scenario": str(_scenario(tmp_path)), "truth_out": str(truth.path)}})
    events_file = tmp_path / "events.jsonl"
    with running_daemon(config):
        follower = subprocess.Popen(
            [venv_bin("placecellctl"), "--config", str(config), "events", "--follow",
             "--json", "--duration", "200"], cwd=REPO, stdout=events_file.open("w"),
            stderr=subprocess.STDOUT, text=True)
        try:
            def learned() -> list[dict[str, Any]]:
                return [e for e in read_json_lines(events_file)
                        if e.get("event") == "place_learned"]

            assert wait_for(lambda: len(learned()) >= 2, 200, 0.5), read_json_lines(events_file)
            events = [check(e) for e in read_json_lines(events_file) if "event" in e]
            first, second = learned()[:2]
            shown = {p["place"]: _ctl_json(config, "place", str(p["place"]))
                     for p in (first, second)}
        finally:
            follower.terminate()
            follower.wait(10)
    # The first place at once; then the robot drove on until that place's view had faded
    # to its background, and learned the second there.
    kinds = [(e["event"], e.get("place")) for e in events]
    reached = next(e for e in events if e["event"] == "background_reached")
    assert reached["place"] == first["place"], kinds
    assert reached["distance_m"] >= 0.75, reached  # [mapping.acquisition] min_distance_m
    assert kinds.index(("place_learned", first["place"])) < kinds.index(
        ("background_reached", first["place"])) < kinds.index(("place_learned", second["place"]))
    assert first["landmarks"] == second["landmarks"] == 16
    # Linked both ways, as the truth has the two reference poses.
    forward = [t for t in shown[first["place"]]["transitions"] if t["to"] == second["place"]]
    back = [t for t in shown[second["place"]]["transitions"] if t["to"] == first["place"]]
    assert len(forward) == len(back) == 1, shown
    true = truth.at(first["reference_stamp_ns"]).between(truth.at(second["reference_stamp_ns"]))
    assert math.hypot(true.x, true.y) >= 0.75, true
    measured = SE2(forward[0]["x"], forward[0]["y"], forward[0]["yaw"])
    assert math.hypot(measured.x - true.x, measured.y - true.y) <= 0.05, (measured, true)
    assert abs(math.degrees(math.remainder(measured.yaw - true.yaw, 2 * math.pi))) <= 1.0
    inverse = SE2(back[0]["x"], back[0]["y"], back[0]["yaw"]).compose(measured)
    assert math.hypot(inverse.x, inverse.y) <= 1e-4 and abs(inverse.yaw) <= 1e-4  # rounded
