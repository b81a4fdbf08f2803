"""The daemon as a process of its own: a configuration written for it, and its CPU and
memory read from ``/proc`` (the benchmarks and the end-to-end tests run it this way)."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = REPO / "config" / "placecell.toml"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening_session(port: int) -> zenoh.Session:
    """A session listening on 127.0.0.1:``port`` for a daemon configured to connect to
    it: up before the daemon starts, it hears the daemon's very first messages."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def read_json_lines(path: Path) -> list[dict[str, Any]]:
    """The JSON objects of a file a follower writes (the line being written skipped;
    none before the file exists)."""
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # being written, or a client's own message
    return out


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over``'s values, tables merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def dump_toml(data: dict[str, Any], prefix: str = "") -> str:
    lines = []
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict)}
    if prefix and scalars:
        lines.append(f"[{prefix}]")
    lines += [f"{k} = {_toml(v)}" for k, v in scalars.items()]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(dump_toml(v, f"{prefix}.{k}" if prefix else k))
    return "\n".join(lines) + "\n"


def write_daemon_config(path: Path, overrides: dict[str, Any]) -> None:
    """The default configuration (config/placecell.toml) with ``overrides``, at ``path``."""
    data = merge(tomllib.loads(DEFAULT_CONFIG.read_text()), overrides)
    path.write_text(dump_toml(data))


@dataclass(frozen=True)
class ProcessUsage:
    cpu_s: float  # user + system time of all its threads
    rss_mb: float


def usage(pid: int) -> ProcessUsage:
    """The CPU time a process has used and its resident memory, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    cpu_s = (int(fields[11]) + int(fields[12])) / ticks  # utime, stime (stat fields 14, 15)
    rss_kb = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss_kb = int(line.split()[1])
    return ProcessUsage(cpu_s, rss_kb / 1024)


def unpinned(proc: subprocess.Popen[bytes]) -> subprocess.Popen[bytes]:
    """A child process free to run on every core (a benchmark pins itself to one, and a
    child inherits that; it has started no thread of its own yet)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(proc.pid, range(os.cpu_count() or 1))
    return proc


@contextlib.contextmanager
def busy_loops(n: int = 2) -> Iterator[None]:
    """``n`` processes spinning on the CPU, on any core: a robot's computer is never
    idle (the tests that must hold under load, and the daemon bench's loaded run)."""
    procs = [unpinned(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
             for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait(10)
