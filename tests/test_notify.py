"""systemd's notify protocol: READY, WATCHDOG while healthy, STOPPING on shutdown."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import time
from pathlib import Path

from daemon.service.notify import Notifier
from tests.daemon_harness import running_daemon, write_config


def _bind(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.2)
    return sock


def test_notifier_is_a_no_op_without_socket() -> None:
    n = Notifier(environ={})
    assert not n.enabled and n.watchdog_interval_s is None
    n.ready()
    n.watchdog()


def test_notifier_sends_datagrams(tmp_path: Path) -> None:
    sock = _bind(tmp_path / "notify.sock")
    n = Notifier(environ={"NOTIFY_SOCKET": str(tmp_path / "notify.sock"),
                          "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())})
    assert n.watchdog_interval_s == 2.0
    n.ready("devices up")
    n.watchdog()
    n.stopping()
    assert sock.recv(512) == b"READY=1\nSTATUS=devices up"
    assert sock.recv(512) == b"WATCHDOG=1"
    assert sock.recv(512) == b"STOPPING=1"


def test_watchdog_for_another_pid_is_ignored() -> None:
    n = Notifier(environ={"NOTIFY_SOCKET": "/nonexistent", "WATCHDOG_USEC": "1000000",
                          "WATCHDOG_PID": "1"})
    assert n.watchdog_interval_s is None


def test_daemon_speaks_notify_in_order(tmp_path: Path) -> None:
    sock_path = tmp_path / "notify.sock"
    sock = _bind(sock_path)
    config, _ = write_config(tmp_path)
    messages: list[str] = []
    env = {"NOTIFY_SOCKET": str(sock_path), "WATCHDOG_USEC": "400000"}
    with running_daemon(config, env=env) as proc:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and messages.count("WATCHDOG=1") < 3:
            try:
                messages.append(sock.recv(512).decode().split("\n")[0])
            except TimeoutError:
                assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        proc.send_signal(signal.SIGTERM)
        end = time.monotonic() + 5
        while time.monotonic() < end and "STOPPING=1" not in messages:
            with contextlib.suppress(TimeoutError):
                messages.append(sock.recv(512).decode().split("\n")[0])
        assert proc.wait(5) == 0
    assert messages[0] == "READY=1", messages
    assert messages.count("WATCHDOG=1") >= 3
    assert messages[-1] == "STOPPING=1"
    assert messages.index("STOPPING=1") > max(
        i for i, m in enumerate(messages) if m == "WATCHDOG=1")
