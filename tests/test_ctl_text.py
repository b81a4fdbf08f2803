"""What placecellctl prints for a person (issue: human output): beliefs without the state
said twice and with the frame's timings, events with their time and fields in words,
degrees for angles typed and shown, the map's size with its write-ahead log and proper
plurals, a quiet end when the reader of its output goes away, help for users."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from kernel.se2 import SE2
from tests.daemon_harness import REPO, venv_bin
from tests.test_map_file import _two_places
from tools.ctl import format_belief, format_event, main, make_parser, set_pose_request


def test_belief_says_the_state_once_with_leads_and_timings() -> None:
    line = format_belief({
        "state": "tracking", "place_id": 1, "reason": "tracking in place 1",
        "confidence": 0.84, "scores": [{"place": 1, "lead": 0.12}, {"place": 3, "lead": 0.04}],
        "timings_ms": {"unwarp": 3.7, "recognition": 44.0, "positioning": 10.0}})
    assert line == ("tracking in place 1; confidence 0.84; leads over background: place 1 "
                    "+0.120, place 3 +0.040; frame 57.7 ms (unwarp 3.7, recognition 44.0, "
                    "positioning 10.0)")
    lost = format_belief({"state": "relocalising", "place_id": None, "confidence": 0.0,
                          "reason": "global relocalisation: 0 of 2 places recognised",
                          "scores": [], "timings_ms": {}})
    assert lost == ("relocalising (global relocalisation: 0 of 2 places recognised); "
                    "confidence 0.00; leads over background: none")


def test_events_carry_their_time_and_read_as_words() -> None:
    line = format_event({"schema": "placecell.event/1", "event": "place_learned",
                         "stamp_ns": 5, "place": 3, "label": "door", "landmarks": 12,
                         "lookalikes": [], "reference_stamp_ns": 4}, "12:03:04.120")
    assert line == ("12:03:04.120 place_learned: place 3, label 'door', landmarks 12, "
                    "lookalikes none, reference stamp ns 4")
    assert format_event({"event": "relocalised", "places": [1, 2], "healthy": True}) == \
        "relocalised: places 1, 2, healthy yes"


def test_set_pose_takes_degrees_and_sends_radians() -> None:
    args = make_parser().parse_args(["set-pose", "1.5", "-0.25", "90", "--place", "2",
                                     "--sigma-yaw", "5"])
    request = set_pose_request(args)
    assert request == {"place": 2, "x": 1.5, "y": -0.25, "yaw": pytest.approx(math.pi / 2),
                       "sigma_yaw": pytest.approx(math.radians(5))}


def test_map_info_counts_the_write_ahead_log_and_speaks_in_plurals(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = _two_places(tmp_path / "map.db")  # open: its places still in the WAL
    try:
        wal = Path(f"{tmp_path / 'map.db'}-wal")
        assert wal.exists() and wal.stat().st_size > 0
        assert main(["map", "info", str(tmp_path / "map.db"), "--json"]) == 0
        import json
        info = json.loads(capsys.readouterr().out)
        assert info["bytes"] >= (tmp_path / "map.db").stat().st_size + wal.stat().st_size
        assert main(["map", "info", str(tmp_path / "map.db")]) == 0
        text = capsys.readouterr().out
        assert ", 2 places, 2 transitions (both ways), " in text, text
        assert " kB;" in text and "0 look-alike pairs with features" in text, text
    finally:
        store.close()


def test_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    _two_places(tmp_path / "map.db").close()
    proc = subprocess.Popen([venv_bin("placecellctl"), "map", "info", str(tmp_path / "map.db")],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # `| head -0`: the reader is gone before anything is written
    err = proc.stderr.read().decode()
    assert proc.wait(60) == 0 and "Traceback" not in err, err


def test_poses_in_logs_are_plain_numbers() -> None:
    pose = SE2(np.float64(1.25), np.float64(-0.5), np.float64(math.pi / 2))
    assert str(pose) == "x +1.250 m, y -0.500 m, yaw +90.0 deg"
    assert "np." not in repr(pose) and repr(pose).startswith("SE2(x=1.25, y=-0.5, yaw=")


@pytest.mark.parametrize("tool", ["placecellctl", "placecell-eval", "placecell-bench",
                                  "placecell-sim"])
def test_help_is_written_for_users(tool: str) -> None:
    out = subprocess.run([venv_bin(tool), "--help"], cwd=REPO, capture_output=True, text=True,
                         timeout=60).stdout
    assert "usage:" in out
    for developer_note in ("tools/", "add_arguments", "dispatches", ".py"):
        assert developer_note not in out, (tool, developer_note)
