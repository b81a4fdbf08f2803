"""Global localisation through the running daemon (design §9): started on a learned map
with no pose it finds the robot by itself; carried off (a scenario kidnap, odometry
unaware) it declares the loss and relocalises; ``placecellctl relocalise`` starts a
search on request. The daemon runs as a subprocess, every client in its own process, the
truth read only from the simulator's truth file."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

from tests.conftest import OfficeMap
from tests.daemon_harness import (
    REPO,
    read_json_lines,
    running_daemon,
    venv_bin,
    wait_for,
    write_config,
)
from tests.test_learn_e2e import Truth

_read = read_json_lines  # a follower's file, the line being written skipped
START = (4.75, 10.15, 0.4)  # near place "b"
KIDNAP_AT_S = 14.0
RELEASE = (3.2, 9.85, -1.0)  # near place "a", turned


def _scenario(tmp: Path) -> Path:
    path = tmp / "kidnap.toml"
    path.write_text("\n".join([
        'name = "stand-and-kidnap"', 'world = "generate:office:1"',
        f"start_pose = {list(START)}", "[trajectory]", 'kind = "waypoints"', "speed = 0.3",
        "start_after_s = 100000.0", "waypoints = [[6.0, 10.0]]", "[[kidnap]]",
        f"t_s = {KIDNAP_AT_S}", f"pose = {list(RELEASE)}"]) + "\n")
    return path


def _follow(config: Path, leaf: str, out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([venv_bin("placecellctl"), "--config", str(config), leaf,
                             "--follow", "--json", "--duration", "90"], cwd=REPO,
                            stdout=out.open("w"), stderr=subprocess.STDOUT, text=True)


def _ctl(config: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([venv_bin("placecellctl"), "--config", str(config), *args],
                          cwd=REPO, capture_output=True, text=True, timeout=60)


def test_the_daemon_localises_by_itself_and_recovers_from_a_kidnap(
        tmp_path: Path, office_map: OfficeMap) -> None:
    refs = office_map(tmp_path / "map.db")
    truth = Truth(tmp_path / "truth.jsonl")
    config, _ = write_config(tmp_path, {"robot": {"name": "e2e"}, "mapping": {
        "mode": "localisation"}, "sim": {"scenario": str(_scenario(tmp_path)),
                                         "truth_out": str(truth.path)}})
    events_file, poses_file = tmp_path / "events.jsonl", tmp_path / "poses.jsonl"
    with running_daemon(config) as daemon:
        followers = [_follow(config, "events", events_file), _follow(config, "pose", poses_file)]
        try:
            def relocalised(n: int) -> bool:
                return sum(e.get("event") == "relocalised" for e in _read(events_file)) >= n

            assert wait_for(lambda: relocalised(2), 75, 0.5), (
                _read(events_file), daemon.poll(), _read(poses_file)[-3:])
            names = {pid: label for label, pid in _place_ids(config).items()}
            events = [e for e in _read(events_file) if e.get("event") in ("lost", "relocalised")]
            first, lost, second = events[:3]
            # Started on the map without a pose: found in the place it stands nearest.
            assert first["event"] == "relocalised" and names[first["place"]] == "b", events
            assert first["how"] == "global" and first["frames"] <= 20, first
            # Carried off: the loss, then the place it was carried to.
            assert lost["event"] == "lost" and names[lost["place"]] == "b", events
            assert second["event"] == "relocalised" and names[second["place"]] == "a", events
            assert second["frames"] <= 15, second
            assert wait_for(lambda: _read(poses_file)[-1]["state"] == "tracking", 10, 0.2)
            pose = _read(poses_file)[-1]
            assert names[pose["place"]["id"]] == "a"
            true_in_a = refs["a"].between(truth.at(pose["stamp_ns"]))
            assert math.hypot(pose["x"] - true_in_a.x, pose["y"] - true_in_a.y) <= 0.20, (
                pose, true_in_a)
            # On request: the pose forgotten and found again.
            asked = _ctl(config, "relocalise", "--json")
            assert asked.returncode == 0, asked.stderr
            assert json.loads(asked.stdout)["relocalising"] is True
            assert wait_for(lambda: relocalised(3), 30, 0.5), _read(events_file)
            third = [e for e in _read(events_file) if e.get("event") == "relocalised"][2]
            assert names[third["place"]] == "a" and third["how"] == "global", third
            # An operator who starts following now still sees how it got here: the
            # daemon keeps its last events for late subscribers.
            late = _ctl(config, "events", "--follow", "--json", "--duration", "3")
            seen = [json.loads(line) for line in late.stdout.splitlines()]
            assert [e["stamp_ns"] for e in seen if e["event"] == "relocalised"][:3] == [
                e["stamp_ns"] for e in _read(events_file)
                if e.get("event") == "relocalised"][:3], seen
        finally:
            for f in followers:
                f.terminate()
                f.wait(10)


def _place_ids(config: Path) -> dict[str, int]:
    listed = _ctl(config, "places", "--json")
    assert listed.returncode == 0, listed.stderr
    return {p["label"]: p["id"] for p in json.loads(listed.stdout)["places"]}


def test_relocalise_is_refused_on_an_empty_map(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path, {"robot": {"name": "e2e"}})
    with running_daemon(config):
        def answered() -> subprocess.CompletedProcess[str] | None:
            out = _ctl(config, "relocalise")
            return out if out.returncode != 3 else None  # 3: not reachable yet

        assert wait_for(answered, 60, 0.5)
        refused = _ctl(config, "relocalise")
        assert refused.returncode == 4 and "no places" in refused.stderr, refused
