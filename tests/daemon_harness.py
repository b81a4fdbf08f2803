"""Helpers to run placecelld in a subprocess with a private configuration and zenoh port."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import zenoh

from tests.api_schema import check
from tools.daemon_process import DEFAULT_CONFIG, merge
from tools.daemon_process import REPO as REPO
from tools.daemon_process import busy_loops as busy_loops
from tools.daemon_process import dump_toml as dump_toml
from tools.daemon_process import free_port as free_port
from tools.daemon_process import listening_session as listening_session
from tools.daemon_process import read_json_lines as read_json_lines


def write_config(tmp: Path, overrides: dict[str, Any] | None = None, *,
                 demo: bool = False) -> tuple[Path, int]:
    """The default configuration with a free zenoh port, a private map, and ``overrides``;
    unless ``demo`` (what ``make run`` shows), a still robot that learns no place on its
    own."""
    port = free_port()
    data = merge(tomllib.loads(DEFAULT_CONFIG.read_text()), {
        "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]},
        "map": {"path": str(tmp / "map.db")},
    })
    if not demo:
        data = merge(data, {"sim": {"scenario": ""},
                             "mapping": {"acquisition": {"enabled": False}}})
    data = merge(data, overrides or {})
    path = tmp / "placecell.toml"
    path.write_text(dump_toml(data))
    return path, port


def venv_bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


@contextlib.contextmanager
def running_daemon(config: Path, env: dict[str, str] | None = None,
                   extra_args: list[str] | None = None,
                   wrapper: list[str] | None = None) -> Iterator[subprocess.Popen[str]]:
    """The daemon in a subprocess (run through ``wrapper``, a command prefix, if given),
    its log in ``daemon.log`` beside ``config`` (a file, not
    a pipe nobody reads: a full pipe would block the daemon's logging); the log's tail is
    printed when the test fails inside."""
    log_path = config.with_name("daemon.log")
    with log_path.open("a") as log_file:
        proc = subprocess.Popen(
            [*(wrapper or []), sys.executable, "-m", "daemon", "--config", str(config),
             *(extra_args or [])],
            cwd=REPO, env={**os.environ, **(env or {})}, stdout=log_file,
            stderr=subprocess.STDOUT, text=True)
    try:
        yield proc
    except BaseException:
        print(f"--- the daemon's log ({log_path}), last lines:")
        print("\n".join(log_path.read_text(errors="replace").splitlines()[-60:]))
        raise
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
        proc.wait(10)


def client_session(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def wait_for(predicate: Any, timeout_s: float, interval_s: float = 0.05) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval_s)
    return bool(predicate())


def ctl(config: Path, *args: str, timeout: float = 240.0) -> subprocess.CompletedProcess[str]:
    """placecellctl in its own process against the daemon ``config`` describes."""
    return subprocess.run([venv_bin("placecellctl"), "--config", str(config), *args],
                          cwd=REPO, capture_output=True, text=True, timeout=timeout)


def wait_ready(config: Path, timeout_s: float, what: str) -> None:
    """Until ``status`` says every component runs and frames and odometry flow (each
    status checked against its schema); AssertionError ``what`` after ``timeout_s``."""
    def ready() -> bool:
        st = ctl(config, "status", "--json", timeout=30)
        if st.returncode != 0:
            return False
        status = check(json.loads(st.stdout))
        return bool(status["healthy"]) and status["rates"]["frames_hz"] > 0 \
            and status["rates"]["odometry_hz"] > 0
    assert wait_for(ready, timeout_s, interval_s=0.5), what
