"""Only the robot speaks for the robot (docs/security.md, config/zenoh/): the daemon, an
operator and a viewer with the shipped configurations, each its own process, and three
forgers (a viewer, a stranger whose certificate another CA signed, a second robot of the
site) putting poses (also on the ROS 2 topic) and events, answering status and map
queries and holding liveliness tokens — in peer mode, in client mode and through the
site's router (zenohd). Nothing forged reaches any receiver, the robot's own traffic
still flows, commands stay the operator's, and placecellctl shows only what the robot
said."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext, suppress
from pathlib import Path
from typing import IO

import pytest

from daemon.service.zenoh_link import robot_zid
from tests.daemon_harness import REPO, free_port, running_daemon, venv_bin, wait_for, write_config

SHIPPED = REPO / "config" / "zenoh"
FORGED_PER_FORGER = 20
FORGERS = ("viewer", "stranger", "sim2")


def _certs(*args: str) -> None:
    done = subprocess.run([venv_bin("placecell-certs"), *args], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr


def _site(tmp: Path) -> Path:
    """The site's CA and identities, made as docs/security.md says; a stranger's from a CA
    of its own."""
    tls = tmp / "tls"
    _certs("ca", str(tls))
    _certs("issue", str(tls), "sim1", "operator", "viewer", "router", "sim2")
    _certs("ca", str(tmp / "elsewhere"))
    _certs("issue", str(tmp / "elsewhere"), "stranger")
    return tls


def _shipped(tmp: Path, name: str, tls: Path, port: int | None = None) -> Path:
    """A shipped configuration with the certificates where the test has them."""
    text = (SHIPPED / f"{name}.json5").read_text().replace("/etc/placecell/tls", str(tls))
    if port is not None:
        text = text.replace("tls/127.0.0.1:7448", f"tls/127.0.0.1:{port}")
    path = tmp / f"{name}.json5"
    path.write_text(text)
    return path


def _bare(tmp: Path, who: str, tls: Path) -> Path:
    """A node with a certificate and no rules of its own: a forger (or the control)."""
    path = tmp / f"bare-{who}-{tls.name}.json5"
    path.write_text(json.dumps({"transport": {"link": {"tls": {
        "root_ca_certificate": str(tls / "ca.pem"),
        "listen_certificate": str(tls / f"{who}.pem"),
        "listen_private_key": str(tls / f"{who}.key"),
        "connect_certificate": str(tls / f"{who}.pem"),
        "connect_private_key": str(tls / f"{who}.key"),
        "enable_mtls": True, "verify_name_on_connect": False}}}}))
    return path


def _client(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "tests.acl_clients", *args], cwd=REPO,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _line(stream: IO[str] | None) -> str:
    assert stream is not None
    return stream.readline().strip()


def _ctl(config: Path, client: Path, connect: str, *args: str
         ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([venv_bin("placecellctl"), "--config", str(config), "--zenoh-config",
                           str(client), "--connect", connect, *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


@contextmanager
def _router(tmp: Path, tls: Path) -> Iterator[str]:
    port = free_port()
    zenohd = subprocess.run([str(REPO / "tools" / "build-zenohd.sh"), "--path"],
                            capture_output=True, text=True, timeout=60)
    assert zenohd.returncode == 0, f"zenohd is built by make test: {zenohd.stderr}"
    with (tmp / "zenohd.log").open("w") as log:
        proc = subprocess.Popen([zenohd.stdout.strip(), "-c",
                                 str(_shipped(tmp, "router", tls, port))],
                                stdout=log, stderr=subprocess.STDOUT)
    try:
        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0

        assert wait_for(listening, 60, 0.05), (tmp / "zenohd.log").read_text()[-2000:]
        yield f"tls/127.0.0.1:{port}"
    finally:
        proc.kill()
        proc.wait(10)


@pytest.mark.parametrize("topology", ["peer", "client", "router"])
def test_only_the_robot_speaks_for_the_robot(tmp_path: Path, topology: str) -> None:
    tls = _site(tmp_path)
    with nullcontext() if topology != "router" else _router(tmp_path, tls) as router:
        port = free_port()
        robot_zenoh = {"config_file": str(_shipped(tmp_path, "robot", tls))}
        if router is None:
            endpoint = f"tls/127.0.0.1:{port}"
            robot_zenoh |= {"listen": [endpoint]}
        else:
            endpoint = router
            robot_zenoh |= {"mode": "client", "listen": [], "connect": [router]}
        config, _ = write_config(tmp_path, {"zenoh": robot_zenoh, "ros2": {"enabled": True}})
        operator = _shipped(tmp_path, "operator", tls)
        viewer = _shipped(tmp_path, "viewer", tls)
        mode = "peer" if topology == "peer" else "client"
        with running_daemon(config):
            assert wait_for(lambda: _ctl(config, operator, endpoint, "mode", "--json"
                                         ).returncode == 0, 60, 0.2), "never answered"
            receivers = {who: _client("receive", str(path), mode, endpoint, "sim1")
                         for who, path in (("operator", operator), ("viewer", viewer))}
            if topology == "peer":  # the control: a receiver without the rules
                receivers["control"] = _client("receive", str(_bare(tmp_path, "operator", tls)),
                                               mode, endpoint, "sim1")
            for who, proc in receivers.items():
                assert _line(proc.stdout) == "ready", who
            files = {"viewer": _bare(tmp_path, "viewer", tls),
                     "stranger": _bare(tmp_path, "stranger", tmp_path / "elsewhere"),
                     "sim2": _bare(tmp_path, "sim2", tls)}
            forgers = {who: _client("forge", str(files[who]), mode, endpoint, "sim1", who,
                                    str(FORGED_PER_FORGER),
                                    *(["wait"] if topology == "peer" and who == "viewer"
                                      else []))
                       for who in FORGERS}
            try:
                for proc in forgers.values():
                    assert proc.stdin is not None
                    with suppress(BrokenPipeError):  # a refused client is gone
                        proc.stdin.write("go\n")
                        proc.stdin.flush()
                for who, proc in forgers.items():
                    said = _line(proc.stdout)  # a stranger's client may be refused outright
                    assert said == f"forged {FORGED_PER_FORGER}" or (
                        who == "stranger" and said.startswith("refused")), (who, said)
                heard = {}
                for who, proc in receivers.items():
                    assert proc.stdin is not None
                    proc.stdin.write("check\n")
                    proc.stdin.flush()
                    heard[who] = json.loads(_line(proc.stdout))
                # What placecellctl shows each of them, while the forgers still answer.
                shown = {who: [_ctl(config, path, endpoint, *args).stdout
                               for args in (("status", "--json"), ("places", "--json"))]
                         for who, path in (("operator", operator), ("viewer", viewer))}
                commands = {who: _ctl(config, path, endpoint, "--timeout", "2", "mode",
                                      "--json")
                            for who, path in (("operator", operator), ("viewer", viewer))}
                stranger = _ctl(config, _bare(tmp_path, "stranger", tmp_path / "elsewhere"),
                                endpoint, "--timeout", "2", "status", "--json")
            finally:
                for proc in forgers.values():
                    if proc.stdin is not None:
                        with suppress(BrokenPipeError):
                            proc.stdin.close()
                    proc.wait(30)
                for proc in receivers.values():
                    proc.wait(30)

    sent = FORGED_PER_FORGER * len(FORGERS)
    for who in ("operator", "viewer"):
        got = heard[who]
        forged = got["forged_poses"] + got["forged_events"]
        assert forged == [], f"{who} heard {len(forged)} of {3 * sent} forged samples: {forged}"
        assert got["real_poses"] >= 6, got  # the robot's own poses still flow
        # (its ROS 2 pose waits for a place to track; its ROS 2 tokens are there at once)
        ros_zids = {key.split("/")[2] for key in got["ros_tokens"]}
        assert ros_zids == {robot_zid("sim1")}, (who, got["ros_tokens"])
        for leaf, replies in got["replies"].items():
            assert replies and all(r is None for r in replies), (who, leaf, replies)
        assert got["alive"]["placecell/sim1/**"] == ["placecell/sim1/alive"], (who, got)
        tokens = set(got["tokens"]) | set(got["alive"]["placecell/**"])
        assert tokens <= {"placecell/sim1/alive"}, (who, tokens)
        for out in shown[who]:
            assert out and "FORGED" not in out and "forged" not in out, (who, out)
    if topology == "peer":  # the forgeries were real: a node without the rules hears them
        control = Counter(heard["control"]["forged_poses"])
        assert control["viewer"] >= FORGED_PER_FORGER, control
    # Commands stay the operator's; a stranger's certificate opens nothing.
    assert commands["operator"].returncode == 0, commands["operator"].stderr
    assert json.loads(commands["operator"].stdout)["mode"] == "mapping"
    assert commands["viewer"].returncode == 3, commands["viewer"]
    assert stranger.returncode == 3, stranger
    # The daemon names who it refused: sim2's links (peer, client); through the router it
    # sees the router only, which refused them itself.
    access = json.loads(shown["operator"][0])["access"]
    if topology == "router":
        assert access["links_by_role"] == {"routers": 1} and access["refused_links"] == 0, access
    else:
        assert access["refused_links"] >= 1 and access["last_refused"] == "sim2", access
