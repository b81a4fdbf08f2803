"""A fleet router as a process of its own (docs/fleet.md): zenohd with the storage manager
plugin and ``config/fleet/router.json5``, listening on one loopback port and connected to
the other routers of the site, for the tests and the fleet experiment. zenohd and the plugin
are built by ``tools/build-zenohd.sh`` (``make test`` runs it)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import zenoh

from tools.daemon_process import REPO

CONFIG = REPO / "config" / "fleet" / "router.json5"
BUILD = REPO / "tools" / "build-zenohd.sh"
STORAGE = "placecell_fleet"  # the storage's name in CONFIG


def _built(*args: str) -> str:
    done = subprocess.run([str(BUILD), *args], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        raise RuntimeError(f"{BUILD.name} {' '.join(args)}: {done.stderr.strip()} "
                           "(make test builds zenohd and its storage manager plugin)")
    return done.stdout.strip()


class FleetRouter:
    """One router: ``start`` and ``stop`` it as often as a test needs (the same port, the
    same zenoh id, an empty storage each start, as a restarted router has)."""

    def __init__(self, port: int, peers: list[int], zid: str, log_path: Path,
                 config: Path = CONFIG, scheme: str = "tcp") -> None:
        """``config``: the router's configuration (CONFIG; a site's with TLS and access
        control, config/fleet/router-secure.json5, with ``scheme`` "tls")."""
        self.port, self.peers, self.zid, self.log_path = port, peers, zid, log_path
        self.config, self.scheme = config, scheme
        self.endpoint = f"{scheme}/127.0.0.1:{port}"
        self._proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout_s: float) -> None:
        """Start zenohd and return once it listens (``timeout_s``: at most this long)."""
        args = [_built("--path"), "-c", str(self.config), "--plugin-search-dir",
                _built("--plugin-dir"), "-i", self.zid, "-l", self.endpoint]
        for peer in self.peers:
            args += ["-e", f"{self.scheme}/127.0.0.1:{peer}"]
        with self.log_path.open("a") as log:
            self._proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        end = time.monotonic() + timeout_s
        while not self._listening():
            if self._proc.poll() is not None or time.monotonic() > end:
                self.stop()
                raise RuntimeError(f"zenohd {self.endpoint} did not start: "
                                   f"{self.log_path.read_text()[-2000:]}")
            time.sleep(0.05)

    def _listening(self) -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def stop(self) -> None:
        """Kill it (as a router that goes away does: no goodbye)."""
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait(10)
            self._proc = None

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None


@contextlib.contextmanager
def fleet_routers(ports: list[int], folder: Path, timeout_s: float
                  ) -> Iterator[list[FleetRouter]]:
    """Routers on ``ports``, each connected to every other, started and stopped together;
    their logs in ``folder``."""
    routers = [FleetRouter(p, [q for q in ports if q != p], f"f1ee7{k + 1:03x}", folder /
                           f"router-{p}.log") for k, p in enumerate(ports)]
    try:
        for router in routers:
            router.start(timeout_s)
        yield routers
    finally:
        for router in routers:
            router.stop()


def client_session(endpoint: str) -> zenoh.Session:
    """A zenoh client of the router at ``endpoint`` (loopback, no scouting)."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def stored(session: zenoh.Session, key_expr: str, timeout_s: float = 10.0
           ) -> dict[str, dict[str, str]]:
    """What each router's storage holds under ``key_expr`` (every storage asked), by the
    router's zenoh id: key -> the digest of the sample stored there."""
    out: dict[str, dict[str, str]] = {}
    for reply in session.get(key_expr, target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
        if reply.ok is not None and reply.replier_id is not None:
            out.setdefault(str(reply.replier_id.zid), {})[str(reply.ok.key_expr)] = \
                hashlib.sha1(reply.ok.payload.to_bytes()).hexdigest()
    return out
