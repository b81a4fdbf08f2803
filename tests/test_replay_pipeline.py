"""One recording replayed through the daemon twice gives the same poses, and
``placecell-eval replay`` gives the daemon's (design §1 one pipeline, §10 replay):
lock-step replay (``camera.replay.speed = 0``) skips no frame and waits for the odometry
up to each frame; the particle filter's generator is seeded from the configuration."""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path
from typing import Any

from hal.recording import TOPIC_FRAMES, RecordingReader
from tests.daemon_harness import client_session, running_daemon, wait_for, write_config
from tools.eval.cli import main as eval_main
from tools.eval.lockstep import Run, lockstep_config
from tools.sim_cli import main as sim_main

START = (3.0, 10.0, 0.0)  # office 1, the corridor


def _learned_map(tmp: Path) -> Path:
    """A map with one place learned at START (the daemon's TBL, lock-step)."""
    path = tmp / "learned.db"
    with Run(lockstep_config(1, world="generate:office:1", start_pose=START),
             map_path=path) as r:
        r.learn("start")
    return path


def _recording(tmp: Path) -> Path:
    scenario = tmp / "drive.toml"
    scenario.write_text(f'name = "drive"\nworld = "generate:office:1"\n'
                        f"start_pose = [{START[0]}, {START[1]}, {START[2]}]\n"
                        '[trajectory]\nkind = "waypoints"\nspeed = 0.3\n'
                        "waypoints = [[4.2, 10.1]]\n")
    out = tmp / "drive.mcap"
    assert sim_main(["record", str(scenario), "--out", str(out), "--duration", "5"]) == 0
    return out


def _daemon_poses(tmp: Path, recording: Path, map_file: Path, name: str
                  ) -> list[dict[str, Any]]:
    run_dir = tmp / name
    run_dir.mkdir()
    shutil.copy(map_file, run_dir / "map.db")
    config, port = write_config(run_dir, {
        "robot": {"name": "replay"},
        "camera": {"backend": "replay", "replay": {"file": str(recording), "speed": 0.0}},
        "base": {"backend": "replay"},
        "mapping": {"mode": "localisation"},
        "localisation": {"initial_place": 1}})
    out = run_dir / "beliefs.mcap"
    session = client_session(port)
    try:
        with running_daemon(config, extra_args=["--record", str(out)]) as proc:
            def ended() -> bool:
                replies = [json.loads(r.ok.payload.to_bytes())
                           for r in session.get("placecell/replay/status", timeout=2.0)
                           if r.ok is not None]
                camera = replies[0]["components"]["camera"] if replies else {}
                return "end of recording" in str(camera.get("last_error"))
            assert wait_for(ended, 120, 0.5), "the replay never reached its end"
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(15) == 0
    finally:
        session.close()
    return [{"stamp_ns": m.body["stamp_ns"], "state": m.body["state"],
             "place_id": m.body["place_id"], "pose_in_place": m.body["pose_in_place"]}
            for m in RecordingReader(out).messages(["/placecell/belief"])]


def test_a_recording_gives_the_same_poses_twice_and_in_the_evaluator(tmp_path: Path) -> None:
    map_file = _learned_map(tmp_path)
    recording = _recording(tmp_path)
    frames = sum(1 for _ in RecordingReader(recording).messages([TOPIC_FRAMES]))
    first = _daemon_poses(tmp_path, recording, map_file, "first")
    second = _daemon_poses(tmp_path, recording, map_file, "second")
    assert len(first) == frames, (len(first), frames)  # lock-step: no frame skipped
    assert all(p["state"] == "tracking" and p["place_id"] == 1 for p in first)
    moved = max(abs(p["pose_in_place"][0]) for p in first)
    assert moved > 0.8  # the robot drove ~1.2 m: the poses say something
    assert first == second
    poses = tmp_path / "eval-poses.jsonl"
    assert eval_main(["replay", "--recording", str(recording), "--map", str(map_file),
                      "--config", str(tmp_path / "first" / "placecell.toml"),
                      "--poses", str(poses), "--json"]) == 0
    evaluated = [json.loads(line) for line in poses.read_text().splitlines()]
    assert evaluated == first
