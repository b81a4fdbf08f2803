"""Two processes: the daemon in a subprocess, a client here, talking over real zenoh."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import zenoh

from tests.daemon_harness import (
    REPO,
    client_session,
    running_daemon,
    venv_bin,
    wait_for,
    write_config,
)

# Held to wall-clock limits: one worker runs these modules one after another (tests/conftest.py).
pytestmark = pytest.mark.xdist_group("realtime")


def test_liveliness_status_ctl_and_clean_stop(tmp_path: Path) -> None:
    config, port = write_config(tmp_path, {"robot": {"name": "testbot"}})
    statuses: list[dict] = []
    alive_events: list[str] = []
    lock = threading.Lock()

    def on_status(sample: zenoh.Sample) -> None:
        with lock:
            statuses.append(json.loads(sample.payload.to_bytes()))

    def on_alive(sample: zenoh.Sample) -> None:
        with lock:
            alive_events.append(str(sample.kind))

    session = client_session(port)
    try:
        session.declare_subscriber("placecell/testbot/status", on_status)
        session.liveliness().declare_subscriber("placecell/testbot/alive", on_alive,
                                                history=True)
        with running_daemon(config) as proc:
            assert wait_for(lambda: any("PUT" in e for e in alive_events), 60), \
                "no liveliness token seen"
            tokens = [r.ok.key_expr for r in session.liveliness().get("placecell/*/alive")
                      if r.ok is not None]
            assert [str(k) for k in tokens] == ["placecell/testbot/alive"]
            # Nonzero frame and odometry rates once devices run.
            assert wait_for(lambda: any(
                s["rates"]["frames_hz"] > 0 and s["rates"]["odometry_hz"] > 0
                for s in statuses), 60), statuses[-1:] or "no status message"
            st = statuses[-1]
            assert st["schema"] == "placecell.status/1"
            assert st["robot"] == "testbot"
            assert set(st["components"]) == {"camera", "base", "processing"}
            assert st["versions"]["placecell"]
            # The operator CLI, from a third process.
            ctl = subprocess.run(
                [venv_bin("placecellctl"), "--config", str(config), "status", "--json"],
                cwd=REPO, capture_output=True, text=True, timeout=30)
            assert ctl.returncode == 0, ctl.stderr
            ctl_status = json.loads(ctl.stdout)
            assert ctl_status["robot"] == "testbot" and ctl_status["rates"]["frames_hz"] > 0
            human = subprocess.run(
                [venv_bin("placecellctl"), "--config", str(config), "status"],
                cwd=REPO, capture_output=True, text=True, timeout=30)
            assert "robot testbot" in human.stdout and "camera" in human.stdout
            # SIGTERM: gone within 2 s, exit code 0, token withdrawn.
            t0 = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(10)
            elapsed = time.monotonic() - t0
            assert code == 0
            assert elapsed < 2.0, f"stopped after {elapsed:.2f} s"
        assert wait_for(lambda: any("DELETE" in e for e in alive_events), 10), alive_events
    finally:
        session.close()


def test_ctl_says_when_no_daemon_answers(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path)
    ctl = subprocess.run(
        [venv_bin("placecellctl"), "--config", str(config), "--timeout", "1", "status"],
        cwd=REPO, capture_output=True, text=True, timeout=30)
    assert ctl.returncode == 3
    assert "no placecell daemon answered" in ctl.stderr
