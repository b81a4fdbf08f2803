"""Honest health (issue 31, point 5): processing that keeps less than the configured share
of the camera's frames is degraded, and the human status shows the mode and the job."""

from __future__ import annotations

import pytest

from daemon.service.health import processing_state
from tools.ctl import format_status


@pytest.mark.parametrize(("state", "processed", "frames", "expected"), [
    ("running", 10.0, 10.0, "running"),
    ("running", 8.0, 10.0, "running"),       # exactly the share: kept
    ("running", 7.9, 10.0, "degraded"),
    ("running", 3.5, 10.0, "degraded"),      # issue 31: "healthy" at 3.5 Hz of 10
    ("running", 0.0, 0.0, "running"),        # no frames: the camera's fault, said there
    ("backoff", 0.0, 10.0, "backoff"),       # a restarting step is not merely degraded
    ("starting", 0.0, 10.0, "starting"),
])
def test_processing_is_degraded_below_its_share(state: str, processed: float, frames: float,
                                               expected: str) -> None:
    assert processing_state(state, processed, frames, 0.8) == expected


def _status(**over: object) -> dict:
    st = {"robot": "r", "healthy": False, "uptime_s": 12.0,
          "versions": {"placecell": "0.1.0"},
          "rates": {"frames_hz": 10.0, "odometry_hz": 50.0, "processed_hz": 3.5},
          "belief": {"state": "tracking", "reason": "ok"},
          "map": {"places": 1, "path": "var/m.db", "mode": "mapping", "writable": True,
                  "readonly_reason": None},
          "job": {"kind": "learn_place", "phase": "+x", "fraction": 0.25,
                  "started_by": "operator"},
          "components": {"processing": {"state": "degraded", "rate_hz": 3.5,
                                        "restarts": 0, "last_error": None}}}
    st.update(over)
    return st


def test_the_human_status_shows_mode_job_and_degraded_processing() -> None:
    text = format_status(_status())
    assert "DEGRADED" in text.splitlines()[0]
    assert "1 place in var/m.db, mapping mode" in text
    assert "job: learn_place (+x, 25%) started by operator" in text
    assert "processing degraded" in text


def test_the_human_status_says_a_read_only_map_and_no_job() -> None:
    text = format_status(_status(
        job=None, map={"places": 3, "path": "m.db", "mode": "localisation",
                       "writable": False, "readonly_reason": "the map file cannot be "
                       "written"}))
    assert "3 places in m.db, localisation mode; READ-ONLY: the map file cannot" in text
    assert "job: none" in text


@pytest.mark.parametrize(("reply", "command"), [
    ({"code": "busy", "reason": "job_running"}, "placecellctl abort"),
    ({"code": "refused", "reason": "localisation_mode"}, "placecellctl mode mapping"),
    ({"code": "refused", "reason": "empty_map"}, "placecellctl learn"),
    ({"code": "not_found"}, "placecellctl places"),
])
def test_refusals_name_the_command_to_run(reply: dict, command: str) -> None:
    from tools.ctl import hint

    advice = hint(reply)
    assert advice is not None and command in advice


def test_no_hint_where_there_is_nothing_to_run() -> None:
    from tools.ctl import hint

    assert hint({"code": "bad_request", "message": "req.x: ..."}) is None
    assert hint({"code": "failed"}) is None


def test_a_repeated_fault_is_reported_once_then_summarised() -> None:
    from daemon.service.supervisor import next_fault

    s = 1_000_000_000
    run, report = next_fault(None, "FileNotFoundError: /dev/video9", 0, 60.0)
    assert report and run.count == 1 and run.first_ns == 0
    for t in range(1, 60):  # once a second for a minute: quiet
        run, report = next_fault(run, "FileNotFoundError: /dev/video9", t * s, 60.0)
        assert not report, t
    run, report = next_fault(run, "FileNotFoundError: /dev/video9", 60 * s, 60.0)
    assert report and run.count == 61 and run.first_ns == 0  # the summary: 61 in 60 s
    run, report = next_fault(run, "FileNotFoundError: /dev/video9", 61 * s, 60.0)
    assert not report
    # Another error is news at once, and starts its own run.
    run, report = next_fault(run, "OSError: device busy", 62 * s, 60.0)
    assert report and run.count == 1 and run.first_ns == 62 * s
